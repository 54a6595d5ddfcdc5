"""Writing a fitted plant into a rig file (``write_plant``): comments, layout, atomicity."""

from __future__ import annotations

import dataclasses
import os
import stat
import tomllib
from pathlib import Path

import pytest
from conftest import EXAMPLE_RIG

import servotune as st
from servotune.plant import Plant
from servotune.resonance import Mode
from servotune.rig import EXAMPLE_RIG_PATH, PlantFit, write_plant

# Awkward numbers, as a fit produces them (not the example rig's values).
FITTED = Plant(
    gain_cps_per_v=12288.049999999999,
    tau_s=0.026234567891,
    delay_s=0.00091234567,
    offset_v=-0.0048123456,
    coulomb_v=0.00213,
)
FITTED_KEYS = ("gain_cps_per_v", "tau_s", "delay_s", "offset_v", "coulomb_v")
PROVENANCE = "fitted by servotune 0.1.0 from log.csv, structure delay+coulomb, fit 98.1 %"


def _copy_example(tmp_path: Path, name: str = "rig.toml") -> Path:
    p = tmp_path / name
    p.write_bytes(EXAMPLE_RIG.read_bytes())
    return p


def _comments(text: str) -> list[str]:
    # the example rig has no '#' inside strings, so everything from '#' on is a comment
    return [line[line.index("#") :] for line in text.splitlines() if "#" in line]


def _split_at_table(text: str, header: str) -> tuple[str, str, str]:
    """(lines before the table header, the table, lines from the next header on)."""
    lines = text.splitlines(keepends=True)
    start = next(i for i, line in enumerate(lines) if line.startswith(header))
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("[")), len(lines))
    return "".join(lines[:start]), "".join(lines[start:end]), "".join(lines[end:])


def test_example_template_is_the_example_rig() -> None:
    # the package's copy (an installed wheel has no plants/), the same bytes as plants/'s
    assert EXAMPLE_RIG_PATH.parent == Path(st.__file__).resolve().parent / "examples"
    assert EXAMPLE_RIG_PATH.read_bytes() == EXAMPLE_RIG.read_bytes()


STALE = "# 600 r/min at 10 V with 12288 counts/rev"  # the example's gain: true of 12288 only


def test_comments_survive(tmp_path: Path) -> None:
    p = _copy_example(tmp_path)
    before = p.read_text()
    assert len(_comments(before)) > 10  # full-line and trailing comments of the example rig
    assert _comments(before).count(STALE) == 1
    write_plant(p, "master", FITTED)
    # every comment but the one that stated the replaced gain's old value
    assert _comments(p.read_text()) == [c for c in _comments(before) if c != STALE]
    # the same value written again: the comment beside it stays true, and stays
    p.write_bytes(EXAMPLE_RIG.read_bytes())
    write_plant(p, "master", st.load_rig(EXAMPLE_RIG).axis("master").plant)
    assert p.read_text() == before


def test_only_the_target_table_changes(tmp_path: Path) -> None:
    p = _copy_example(tmp_path)
    before = p.read_text()
    write_plant(p, "master", FITTED, provenance=PROVENANCE)
    after = p.read_text()
    assert after != before
    # every other table holds the same data
    old, new = tomllib.loads(before), tomllib.loads(after)
    old_plant = old["axis"]["master"].pop("plant")
    new_plant = new["axis"]["master"].pop("plant")
    assert new == old
    assert new_plant["max_speed_rpm"] == old_plant["max_speed_rpm"] == 700  # kept
    assert new_plant["noise_counts"] == old_plant["noise_counts"] == 0.3  # kept
    # and every line outside [axis.master.plant] is byte-identical
    head_old, table_old, tail_old = _split_at_table(before, "[axis.master.plant]")
    head_new, table_new, tail_new = _split_at_table(after, "[axis.master.plant]")
    assert (head_new, tail_new) == (head_old, tail_old)
    assert table_new != table_old
    # a replaced entry keeps a trailing comment naming the quantity, at the same column where
    # it fits; one stating the old value (600 r/min at 10 V is 12288 counts/s/V) goes
    assert "offset_v = -0.004812346   # analog zero drift\n" in table_new  # same column as
    assert "offset_v = 0.005          # analog zero drift\n" in table_old  # before
    assert f"gain_cps_per_v = 12288.0  {STALE}\n" in table_old
    assert "gain_cps_per_v = 12288.05\n" in table_new


def test_round_trip_through_load_rig(tmp_path: Path) -> None:
    p = _copy_example(tmp_path)
    write_plant(p, "master", FITTED)
    rig = st.load_rig(p)
    got = rig.axis("master").plant
    for key in FITTED_KEYS:
        assert getattr(got, key) == pytest.approx(getattr(FITTED, key), rel=1e-6), key
    assert got.max_speed_rpm == 700  # hardware settings the fit does not estimate stay
    assert got.noise_counts == 0.3
    assert rig.axis("slave").plant == st.load_rig(EXAMPLE_RIG).axis("slave").plant


def test_floats_are_rounded_to_seven_significant_digits(tmp_path: Path) -> None:
    p = _copy_example(tmp_path)
    write_plant(p, "master", FITTED)
    _, table, _ = _split_at_table(p.read_text(), "[axis.master.plant]")
    assert "gain_cps_per_v = 12288.05\n" in table  # not 12288.049999999999
    assert "tau_s = 0.02623457\n" in table
    assert "delay_s = 0.0009123457\n" in table
    assert "coulomb_v = 0.00213\n" in table
    # an entry that already holds the value keeps its text (0.030, not 0.03)
    write_plant(p, "slave", dataclasses.replace(FITTED, tau_s=0.03))
    _, table, _ = _split_at_table(p.read_text(), "[axis.slave.plant]")
    assert "tau_s = 0.030\n" in table


def test_plant_settings_replace_kept_values_when_set(tmp_path: Path) -> None:
    p = _copy_example(tmp_path)
    write_plant(p, "master", dataclasses.replace(FITTED, max_speed_rpm=650.0, noise_counts=0.5))
    got = st.load_rig(p).axis("master").plant
    assert (got.max_speed_rpm, got.noise_counts) == (650.0, 0.5)


def test_asymmetric_plant_round_trip_and_back_to_symmetric(tmp_path: Path) -> None:
    # the negative direction's gain and Coulomb level are written when set, read back, and
    # removed again when a symmetric plant is written (the file records the structure)
    p = _copy_example(tmp_path)
    asym = dataclasses.replace(FITTED, gain_neg_cps_per_v=10987.654321, coulomb_neg_v=0.0041234567)
    write_plant(p, "master", asym)
    got = st.load_rig(p).axis("master").plant
    assert got.gain_neg_cps_per_v == 10987.65  # 7 significant digits
    assert got.coulomb_neg_v == 0.004123457
    _, table, _ = _split_at_table(p.read_text(), "[axis.master.plant]")
    assert "gain_neg_cps_per_v = 10987.65\n" in table and "coulomb_neg_v = 0.004123457\n" in table
    assert st.load_rig(p).axis("slave").plant.symmetric  # the other axis untouched
    write_plant(p, "master", FITTED)
    text = p.read_text()
    assert "_neg_" not in text
    assert st.load_rig(p).axis("master").plant.symmetric
    # and the symmetric write is the same bytes as writing into the untouched example
    q = _copy_example(tmp_path, "fresh.toml")
    write_plant(q, "master", FITTED)
    assert q.read_bytes() == p.read_bytes()


def test_missing_file_is_created_from_the_template(tmp_path: Path) -> None:
    new = tmp_path / "new-rig.toml"
    write_plant(new, "slave", FITTED, provenance=PROVENANCE)
    copy = _copy_example(tmp_path)
    write_plant(copy, "slave", FITTED, provenance=PROVENANCE)
    assert new.read_bytes() == copy.read_bytes()
    rig = st.load_rig(new)
    assert rig.name == "pc-dual-servo"  # the template's [rig] name
    assert rig.axis("slave").plant.tau_s == pytest.approx(FITTED.tau_s, rel=1e-6)


def test_explicit_template(tmp_path: Path) -> None:
    template = tmp_path / "template.toml"
    template.write_text(EXAMPLE_RIG.read_text().replace('name = "pc-dual-servo"', 'name = "lab"'))
    out = tmp_path / "out.toml"
    write_plant(out, "master", FITTED, template=template)
    assert st.load_rig(out).name == "lab"
    with pytest.raises(st.RigError, match="cannot read template rig file"):
        write_plant(tmp_path / "other.toml", "master", FITTED, template=tmp_path / "nope.toml")
    assert not (tmp_path / "other.toml").exists()


def test_unknown_axis_names_the_axes_there_are(tmp_path: Path) -> None:
    p = _copy_example(tmp_path)
    before = p.read_bytes()
    with pytest.raises(st.RigError, match=r"no axis 'spindle' .*axes: \['master', 'slave'\]"):
        write_plant(p, "spindle", FITTED)
    assert p.read_bytes() == before
    with pytest.raises(st.RigError, match="no axis 'spindle'"):
        write_plant(tmp_path / "new.toml", "spindle", FITTED)
    assert sorted(os.listdir(tmp_path)) == ["rig.toml"]


def test_missing_directory_raises_and_creates_nothing(tmp_path: Path) -> None:
    missing = tmp_path / "no" / "such"
    with pytest.raises(FileNotFoundError, match="directory does not exist") as info:
        write_plant(missing / "rig.toml", "master", FITTED)
    assert str(missing) in str(info.value)
    assert info.value.filename == str(missing)
    assert os.listdir(tmp_path) == []


def test_provenance_is_replaced_not_accumulated(tmp_path: Path) -> None:
    p = _copy_example(tmp_path)
    write_plant(p, "master", FITTED, provenance="fitted from first.csv")
    first = p.read_text()
    assert "[axis.master.plant]  # fitted from first.csv\n" in first
    write_plant(p, "master", FITTED, provenance="fitted from second.csv")
    second = p.read_text()
    assert "first.csv" not in second
    assert second.count("fitted from") == 1
    assert len(second.splitlines()) == len(first.splitlines())
    # the same bytes as a single write with the second provenance
    once = _copy_example(tmp_path, "once.toml")
    write_plant(once, "master", FITTED, provenance="fitted from second.csv")
    assert once.read_text() == second
    # "" removes it, None leaves it as it is
    write_plant(p, "master", FITTED, provenance=None)
    assert p.read_text() == second
    write_plant(p, "master", FITTED, provenance="")
    assert "fitted from" not in p.read_text()
    assert "[axis.master.plant]\n" in p.read_text()


def test_provenance_must_be_one_line(tmp_path: Path) -> None:
    p = _copy_example(tmp_path)
    before = p.read_bytes()
    with pytest.raises(st.RigError, match="provenance must be one line"):
        write_plant(p, "master", FITTED, provenance="fitted\n[timer]")
    assert p.read_bytes() == before


def test_same_inputs_same_bytes(tmp_path: Path) -> None:
    a = _copy_example(tmp_path, "a.toml")
    b = _copy_example(tmp_path, "b.toml")
    write_plant(a, "master", FITTED, provenance=PROVENANCE)
    write_plant(b, "master", FITTED, provenance=PROVENANCE)
    assert a.read_bytes() == b.read_bytes()
    once = a.read_bytes()
    write_plant(a, "master", FITTED, provenance=PROVENANCE)  # idempotent
    assert a.read_bytes() == once


def test_result_that_would_not_load_is_not_written(tmp_path: Path) -> None:
    p = tmp_path / "rig.toml"
    p.write_text(EXAMPLE_RIG.read_text().replace("period_s = 0.004 ", "period_s = -0.004 ", 1))
    before = p.read_bytes()
    with pytest.raises(st.RigError, match=r"would not load .*timer\.period_s.*nothing written"):
        write_plant(p, "master", FITTED)
    assert p.read_bytes() == before
    assert os.listdir(tmp_path) == ["rig.toml"]


def test_not_toml_is_a_rig_error(tmp_path: Path) -> None:
    p = tmp_path / "rig.toml"
    p.write_text("[timer\n")
    with pytest.raises(st.RigError, match="not valid TOML"):
        write_plant(p, "master", FITTED)
    assert p.read_text() == "[timer\n"


def test_failed_replace_leaves_file_and_no_temp_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    p = _copy_example(tmp_path)
    before = p.read_bytes()

    def fail(src: object, dst: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError, match="No space left"):
        write_plant(p, "master", FITTED)
    assert p.read_bytes() == before
    assert os.listdir(tmp_path) == ["rig.toml"]


def test_file_mode_is_kept(tmp_path: Path) -> None:
    p = _copy_example(tmp_path)
    p.chmod(0o640)
    write_plant(p, "master", FITTED)
    assert stat.S_IMODE(p.stat().st_mode) == 0o640


def test_inline_plant_table(tmp_path: Path) -> None:
    text = EXAMPLE_RIG.read_text()
    head, _, tail = _split_at_table(text, "[axis.slave.plant]")
    p = tmp_path / "rig.toml"
    inline = "dac_channel = 1\nplant = { tau_s = 0.03, gain_cps_per_v = 11700.0 }\n"
    p.write_text(head.replace("dac_channel = 1\n", inline) + tail)
    write_plant(p, "slave", FITTED, provenance=PROVENANCE)
    assert st.load_rig(p).axis("slave").plant.gain_cps_per_v == 12288.05
    assert p.read_text().startswith(head[: head.index("[axis.slave]")])


# --- modes (docs/formats.md#modes) ----------------------------------------------------------

BELT = Mode(
    freq_hz=35.0123456789,
    damping=0.0412345678,
    gain=0.5123456789,
    freq_hz_95=(34.91234567, 35.11234567),
    damping_95=(0.0351234567, 0.0481234567),
    gain_95=(0.4812345678, 0.5412345678),
)
"""A fitted mode, awkward numbers with their 95 % intervals."""
HIGH = Mode(freq_hz=80.0, damping=0.1, gain=-0.2)  # no intervals (a hand-written mode)


def _rounded(m: Mode) -> Mode:
    """``m`` as written: every number to 7 significant digits."""

    def r(x: float) -> float:
        return float(f"{x:.7g}")

    pairs = {
        k: None if getattr(m, k) is None else (r(getattr(m, k)[0]), r(getattr(m, k)[1]))
        for k in ("freq_hz_95", "damping_95", "gain_95")
    }
    return Mode(freq_hz=r(m.freq_hz), damping=r(m.damping), gain=r(m.gain), **pairs)


def test_modes_round_trip_through_load_rig(tmp_path: Path) -> None:
    p = _copy_example(tmp_path)
    write_plant(p, "master", dataclasses.replace(FITTED, modes=(BELT, HIGH)), provenance=PROVENANCE)
    got = st.load_rig(p).axis("master").plant
    assert got.modes == (_rounded(BELT), HIGH)
    assert got.modes[0].freq_hz_95 == (34.91235, 35.11235)
    assert st.load_rig(p).axis("slave").plant.modes == ()
    # an array of tables after the plant's entries, intervals only where the mode has them
    modes = p.read_text().split("[axis.master.plant]", 1)[1].split("[axis.slave]")[0]
    assert modes.count("[[axis.master.plant.modes]]\n") == 2
    first = modes.split("[[axis.master.plant.modes]]\n")[1]
    assert first == (
        "freq_hz = 35.01235\ndamping = 0.04123457\ngain = 0.5123457\n"
        "freq_hz_95 = [34.91235, 35.11235]\ndamping_95 = [0.03512346, 0.04812346]\n"
        "gain_95 = [0.4812346, 0.5412346]\n\n"
    )
    second = modes.split("[[axis.master.plant.modes]]\n")[2]
    assert second == "freq_hz = 80.0\ndamping = 0.1\ngain = -0.2\n\n"
    # every line outside the master's plant and its modes is the example's
    head_old, _, tail_old = _split_at_table(EXAMPLE_RIG.read_text(), "[axis.master.plant]")
    assert p.read_text().startswith(head_old)
    assert p.read_text().endswith(tail_old)


def test_a_plant_without_modes_removes_the_file_s(tmp_path: Path) -> None:
    p = _copy_example(tmp_path)
    write_plant(p, "master", dataclasses.replace(FITTED, modes=(BELT,)), provenance=PROVENANCE)
    assert "modes" in p.read_text()
    write_plant(p, "master", FITTED, provenance=PROVENANCE)
    assert "modes" not in p.read_text()
    assert st.load_rig(p).axis("master").plant.modes == ()
    # the same bytes as the symmetric, mode-free write into the untouched example
    fresh = _copy_example(tmp_path, "fresh.toml")
    write_plant(fresh, "master", FITTED, provenance=PROVENANCE)
    assert p.read_bytes() == fresh.read_bytes()
    # an inline array of modes goes the same way
    q = tmp_path / "inline.toml"
    one = "noise_counts = 0.3\nmodes = [{freq_hz = 35, damping = 0.04, gain = 0.5}]"
    q.write_text(EXAMPLE_RIG.read_text().replace("noise_counts = 0.3", one, 1))
    write_plant(q, "master", FITTED, provenance=PROVENANCE)
    assert q.read_bytes() == fresh.read_bytes()


def test_modes_replace_the_file_s_and_sit_before_the_fit_record(tmp_path: Path) -> None:
    p = tmp_path / "belt.toml"
    p.write_bytes(EXAMPLE_RIG.with_name("belt-axis.toml").read_bytes())
    fit = PlantFit(
        method="iv",
        structure=("gain_cps_per_v", "tau_s"),
        friction="sym",
        adequate=True,
        reason="",
        interval="test",
        ci95={"gain_cps_per_v": (12000.0, 12500.0), "tau_s": (0.024, 0.026)},
    )
    write_plant(p, "master", dataclasses.replace(FITTED, modes=(HIGH, BELT)), fit=fit)
    got = st.load_rig(p).axis("master")
    assert got.plant.modes == (HIGH, _rounded(BELT))
    assert got.plant_fit == fit
    text = p.read_text()
    assert text.count("[[axis.master.plant.modes]]") == 2
    assert text.index("[[axis.master.plant.modes]]") < text.index("[axis.master.plant.fit]")
    assert "# J_load / J_motor" not in text  # the replaced mode's comments went with it
    assert "# The belt." in text  # the lines about the belt, above the modes, stay
    # again with the same plant: the same bytes; with none: no modes, the record stays
    once = p.read_bytes()
    write_plant(p, "master", dataclasses.replace(FITTED, modes=(HIGH, BELT)), fit=fit)
    assert p.read_bytes() == once
    write_plant(p, "master", FITTED, fit=fit)
    assert st.load_rig(p).axis("master").plant.modes == ()
    assert st.load_rig(p).axis("master").plant_fit == fit


def test_modes_in_an_inline_plant_table(tmp_path: Path) -> None:
    text = EXAMPLE_RIG.read_text()
    head, _, tail = _split_at_table(text, "[axis.slave.plant]")
    p = tmp_path / "rig.toml"
    inline = "dac_channel = 1\nplant = { tau_s = 0.03, gain_cps_per_v = 11700.0 }\n"
    p.write_text(head.replace("dac_channel = 1\n", inline) + tail)
    write_plant(p, "slave", dataclasses.replace(FITTED, modes=(BELT,)))
    assert st.load_rig(p).axis("slave").plant.modes == (_rounded(BELT),)
    write_plant(p, "slave", FITTED)
    assert st.load_rig(p).axis("slave").plant.modes == ()
    assert "modes" not in p.read_text()


def test_a_mode_at_or_above_the_rig_s_nyquist_is_not_written(tmp_path: Path) -> None:
    p = _copy_example(tmp_path)
    before = p.read_bytes()
    high = Mode(freq_hz=130.0, damping=0.05, gain=0.3)  # the rig's Nyquist: 124.99 Hz
    with pytest.raises(
        st.RigError, match=r"would not load .*modes\[0\]\.freq_hz must be below .*nothing written"
    ):
        write_plant(p, "master", dataclasses.replace(FITTED, modes=(high,)))
    assert p.read_bytes() == before
