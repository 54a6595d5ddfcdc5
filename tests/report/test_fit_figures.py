"""The fit % in the report of ``servotune verify --report``: read from the rig's fit record.

``servotune fit -o`` records the fit figures in ``[axis.<name>.plant.fit]``; ``verify --report``
calls :func:`~servotune.report.write_report` with no fit result of its own (``fits`` not given),
so the report's identification shows the rig's figures, and says they are absent when the rig
records none. The oracle is the written page, for two different recorded figures (the page
follows the file), and the record read back from the file. The tuning is the corpus's small
tuning of the example rig (the report checks only the axes, roles and period against the rig);
a whole ``verify`` run per page would take minutes.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

import servotune as st
from servotune.report import write_report
from servotune.rig import PlantFit, write_plant

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE_RIG = ROOT / "plants" / "pc-dual-servo.toml"
TUNING = ROOT / "tests" / "corpus" / "base" / "tuning.json"  # a tuning of the example rig


def _rig_with_record(path: Path, **figures: float) -> Path:
    """A copy of the example rig (same plants) with a fit record on the master."""
    plant = st.load_rig(EXAMPLE_RIG).axis("master").plant
    ci = {"gain_cps_per_v": (0.99 * plant.gain_cps_per_v, 1.01 * plant.gain_cps_per_v)}
    fit = PlantFit(
        method="iv",
        structure=("gain_cps_per_v", "tau_s"),
        friction="sym",
        adequate=True,
        interval="stand-in",
        ci95=ci,
        **figures,
    )
    write_plant(path, "master", plant, template=EXAMPLE_RIG, fit=fit)
    return path


def _note(page: str, axis: str) -> str:
    """The identification's paragraph about one axis of the example rig."""
    m = re.search(rf"<h3>{axis} \({axis}\)</h3><p>(.*?)</p>", page, re.S)
    assert m is not None, f"no identification paragraph for the {axis}"
    return m.group(1)


def _report(rig: Path, out: Path) -> str:
    """The page ``servotune verify TUNING --rig RIG --report OUT`` writes (no fit results)."""
    out.mkdir()
    return write_report(out, tuning_path=TUNING, rig_path=rig).read_text(encoding="utf-8")


@pytest.mark.parametrize(
    ("velocity", "velocity_cv", "position", "position_cv"),
    [(97.31, 96.42, 99.57, 98.68), (88.14, 85.26, 91.73, 90.05)],
)
def test_the_verify_report_shows_the_fit_figures_the_rig_records(
    tmp_path: Path, velocity: float, velocity_cv: float, position: float, position_cv: float
) -> None:
    rig = _rig_with_record(
        tmp_path / "rig.toml",
        velocity_fit_pct=velocity,
        velocity_fit_cv_pct=velocity_cv,
        position_fit_pct=position,
        position_fit_cv_pct=position_cv,
    )
    table = tomllib.loads(rig.read_text())["axis"]["master"]["plant"]["fit"]
    assert (table["velocity_fit_pct"], table["position_fit_cv_pct"]) == (velocity, position_cv)
    note = _note(_report(rig, tmp_path / "rep"), "master")
    assert (
        f"as recorded in the rig file: speed {velocity:.1f} % on the whole log, "
        f"{velocity_cv:.1f} % cross-validated; position {position:.1f} % / {position_cv:.1f} %"
    ) in note, note
    assert "not recorded" not in note and "not given" not in note


def test_without_recorded_figures_the_report_says_they_are_absent(tmp_path: Path) -> None:
    rig = _rig_with_record(tmp_path / "rig.toml")  # a record without figures on the master
    assert "fit_pct" not in rig.read_text()
    page = _report(rig, tmp_path / "rep")
    master, slave = _note(page, "master"), _note(page, "slave")
    assert "Fit %: not recorded in the rig file" in master, master
    assert "Fit %: none (not fitted)" in slave, slave  # no record at all
    for note in (master, slave):
        assert "cross-validated" not in note and "MATLAB compare" not in note


def test_a_partial_record_reads_back_with_the_rest_absent(tmp_path: Path) -> None:
    rig = _rig_with_record(tmp_path / "rig.toml", velocity_fit_pct=93.5)
    fit = st.load_rig(rig).axis("master").plant_fit
    assert fit is not None
    assert (fit.velocity_fit_pct, fit.velocity_fit_cv_pct) == (93.5, None)
    assert set(fit.to_dict()) & {"velocity_fit_cv_pct", "position_fit_pct"} == set()


@pytest.mark.parametrize("bad", ["100.5", "nan", '"97 %"'])
def test_a_bad_figure_is_refused_naming_the_key(tmp_path: Path, bad: str) -> None:
    rig = _rig_with_record(tmp_path / "rig.toml", velocity_fit_pct=93.5)
    rig.write_text(rig.read_text().replace("velocity_fit_pct = 93.5", f"velocity_fit_pct = {bad}"))
    with pytest.raises(st.RigError, match=r"axis\.master\.plant\.fit\.velocity_fit_pct must be"):
        st.load_rig(rig)
