"""The fit record in the rig's plant section (docs/decisions.md#6-the-fit-record): written by ``fit
-o``, read back.

``[axis.<name>.plant.fit]`` holds each estimated parameter's 95 % interval, the method, the
structure, the friction form and the adequacy; the rig reader accepts exactly those keys.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest
from conftest import EXAMPLE_RIG

import servotune as st
from servotune.errors import RigError
from servotune.plant import Plant
from servotune.rig import PlantFit, write_plant

FITTED = Plant(gain_cps_per_v=12290.123456789, tau_s=0.02501, delay_s=0.00079, offset_v=0.0049,
               coulomb_v=0.0021)  # fmt: skip
RECORD = PlantFit(
    method="iv",
    structure=("gain_cps_per_v", "tau_s", "delay_s", "offset_v", "coulomb_v"),
    friction="sym",
    adequate=False,
    reason="the innovations are not white (Ljung-Box p = 0.001)",
    interval="moving-block bootstrap of the iv estimating equations",
    ci95={"gain_cps_per_v": (12250.000000001, 12330.0), "tau_s": (0.0248, 0.0252),
          "delay_s": (0.0007, 0.0009), "offset_v": (0.004, 0.006), "coulomb_v": (0.0, 0.004)},
)  # fmt: skip


def test_the_record_is_written_beside_the_plant_and_reads_back(tmp_path: Path) -> None:
    out = tmp_path / "fitted.toml"
    write_plant(out, "master", FITTED, provenance="fitted by a test", fit=RECORD)
    ax = st.load_rig(out).axis("master")
    assert ax.plant.gain_cps_per_v == 12290.12  # 7 significant digits
    rec = ax.plant_fit
    assert rec is not None
    assert (rec.method, rec.friction, rec.adequate) == ("iv", "sym", False)
    assert rec.structure == RECORD.structure and rec.reason == RECORD.reason
    assert rec.ci95["gain_cps_per_v"] == (12250.0, 12330.0)  # rounded like the values
    assert rec.ci95["coulomb_v"] == (0.0, 0.004)
    data = tomllib.loads(out.read_text())
    table = data["axis"]["master"]["plant"]["fit"]
    assert set(table) == {
        "method",
        "structure",
        "friction",
        "adequate",
        "reason",
        "interval",
        "ci95",
    }
    # the slave, not fitted, has no record; the rest of the file is the template's
    assert st.load_rig(out).axis("slave").plant_fit is None
    assert st.load_rig(EXAMPLE_RIG).axis("master").plant_fit is None


def test_a_refit_replaces_the_record_and_a_plain_write_removes_it(tmp_path: Path) -> None:
    out = tmp_path / "fitted.toml"
    write_plant(out, "master", FITTED, fit=RECORD)
    again = PlantFit(
        method="oe",
        structure=("gain_cps_per_v", "tau_s"),
        friction="sym",
        adequate=True,
        ci95={"gain_cps_per_v": (1.0, 2.0), "tau_s": (0.1, 0.2)},
    )
    write_plant(out, "master", FITTED, fit=again)
    assert st.load_rig(out).axis("master").plant_fit == again
    assert out.read_text().count("[axis.master.plant.fit]") == 1
    # values written without a record are not described by the old one: it goes
    write_plant(out, "master", FITTED)
    assert st.load_rig(out).axis("master").plant_fit is None
    assert "plant.fit" not in out.read_text()


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        ('method = "iv"', ("axis.master.plant.fit.method", "iv, oe", "'pem'")),
        ('friction = "sym"', ("axis.master.plant.fit.friction", "sym, asym")),
        ("adequate = false", ("axis.master.plant.fit.adequate", "true or false")),
        ("[axis.master.plant.fit.ci95]", ("axis.master.plant.fit.ci95.gain_neg_cps_per_v",)),
    ],
)
def test_a_bad_record_is_refused_with_the_field_named(
    tmp_path: Path, edit: str, words: tuple[str, ...]
) -> None:
    out = tmp_path / "fitted.toml"
    write_plant(out, "master", FITTED, fit=RECORD)
    text = out.read_text()
    bad = {
        'method = "iv"': 'method = "pem"',
        'friction = "sym"': 'friction = "both"',
        "adequate = false": 'adequate = "no"',
        "[axis.master.plant.fit.ci95]": "[axis.master.plant.fit.ci95]\n"
        "gain_neg_cps_per_v = [1.0, 2.0]",
    }[edit]
    assert edit in text
    out.write_text(text.replace(edit, bad, 1))
    with pytest.raises(RigError) as info:
        st.load_rig(out)
    for w in words:
        assert w in str(info.value), str(info.value)


def test_unknown_keys_in_the_record_get_a_did_you_mean(tmp_path: Path) -> None:
    out = tmp_path / "fitted.toml"
    write_plant(out, "master", FITTED, fit=RECORD)
    out.write_text(out.read_text().replace('friction = "sym"', 'friction = "sym"\nadequat = 1'))
    with pytest.raises(RigError, match="adequat") as info:
        st.load_rig(out)
    assert "adequate" in str(info.value)


def test_record_validation_in_python() -> None:
    with pytest.raises(ValueError, match=r"ci95.tau_s must be \[low, high\]"):
        PlantFit(
            method="iv",
            structure=("gain_cps_per_v", "tau_s"),
            friction="sym",
            adequate=True,
            ci95={"tau_s": (0.3, 0.2)},
        )
    with pytest.raises(ValueError, match="structure must be a list of plant parameters"):
        PlantFit(method="iv", structure=("gain", "tau_s"), friction="sym", adequate=True)
