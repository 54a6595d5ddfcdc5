"""Rig files: the example rig and validation messages (field, value, unit)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
from conftest import EXAMPLE_RIG

import servotune as st
from servotune.cli import main
from servotune.resonance import Mode
from servotune.rig import describe_rig


def test_example_rig_facts(rig: st.Rig) -> None:
    f = describe_rig(rig)
    assert f["timer_divisor"] == 4773  # docs/runtime.md#timer-and-achieved-period
    assert f["achieved_period_s"] == pytest.approx(0.004000235, abs=1e-9)
    assert f["period_error_ppm"] == pytest.approx(58.7, abs=0.05)
    assert f["counts_per_rev"] == 12288  # 3072 pulses/rev, x4
    assert f["dac_lsb_mv"] == pytest.approx(4.8828125)  # 20 V / 4096
    assert f["binding_speed_limit"] == "input_frequency"  # 46,875 < 79,995 r/min
    for a in f["axes"].values():
        assert a["speed_limit_ok"]
        assert a["time_to_wrap_at_speed_limit_s"] == pytest.approx(2**24 / 122880)
        assert a["lock_band_within_one_pulse"]
    # the example rig: 600 r/min at 10 V is 12,288 counts/s/V; tau at most ~30 ms; drift about 5 mV
    assert rig.axis("master").plant.gain_cps_per_v == 12288
    assert all(a.plant.tau_s <= 0.030 for a in rig.axes)
    assert rig.axis("master").plant != rig.axis("slave").plant


MODE_TABLE = "\n[[axis.master.plant.modes]]\nfreq_hz = 35.0\ndamping = 0.04\ngain = 0.5\n"
"""One mode of the master's plant (the belt-driven example's, plants/belt-axis.toml)."""


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "rig.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            "period_s = 0.004 ",
            "period_s = -0.004 ",
            r"timer.period_s must be a number > 0 \[s\], got -0.004",
        ),
        ("period_s = 0.004 ", "period_s = 1.0 ", r"timer.period_s.*divisor outside 2..65536"),
        (
            "bits = 24",
            "bits = 20",
            r"counter.bits must be the integer 16, 24 or 32 \[bits\], got "
            r"20",
        ),
        (
            "bits = 24",
            "bits = 24.0",
            r"counter.bits must be the integer 16, 24 or 32 \[bits\], got "
            r"24.0",
        ),
        (
            "bits = 24",
            'bits = "24"',
            r"counter.bits must be the integer 16, 24 or 32 \[bits\], got "
            r"'24'",
        ),
        ("bits = 12", "bits = 12.0", r"dac.bits must be an integer in 8..16 \[bits\], got 12.0"),
        ("bits = 12", "bits = true", r"dac.bits must be an integer in 8..16 \[bits\], got True"),
        (
            "multiplier = 4",
            "multiplier = 3",
            r"counter.multiplier must be the integer 1, 2 or 4 \[-\], got "
            r"3",
        ),
        ("latched = true", 'latched = "yes"', "counter.latched must be true or false, got 'yes'"),
        (
            "lock_gain_codes_per_count = 0.4 ",
            "lock_gain_codes_per_count = 1e10 ",
            r"axis.master.lock_gain_codes_per_count must be a number in \("
            r"0, 65536\] \[codes/count\], got 10000000000.0",
        ),
        (
            "offset_v = 0.005",
            "offset_v = 1000.0",
            r"axis.master.plant.offset_v must be a number in \[-10, 10\] \[V\], got 1000.0",
        ),
        (
            "delay_s = 0.0008",
            "delay_s = 1e300",
            r"axis.master.plant.delay_s must be a number in \[0, 1\] \[s\]",
        ),
        (
            "gain_cps_per_v = 12288.0",
            "gain_cps_per_v = 1" + "0" * 400,
            r"axis.master.plant.gain_cps_per_v must be a number within "
            r"±2\*\*63 \(int64\), got an integer of 401 digits",
        ),
        (
            "max_input_hz = 2.4e6",
            "max_input_hz = 1e300",
            r"counter.max_input_hz must be a number in \(0, 1e\+10\] \[Hz\]",
        ),
        (
            "clock_hz = 1193180",
            "clock_hz = inf",
            r"timer.clock_hz must be a number in \(0, 1e\+10\] \[Hz\], got"
            r" inf",
        ),
        (
            "range_v = [-10.0, 10.0]",
            "range_v = [-1e300, 1e300]",
            r"dac.range_v must be \[low, high\] .*±1000 \[V\]",
        ),
        (
            "range_v = [-10.0, 10.0]",
            "range_v = [-10.0, 0.0, 10.0]",
            r"dac.range_v must be \[low, high\]",
        ),
        (
            "travel_counts = [-2000000, 2000000]",
            "travel_counts = [-2e6, 2e6]",
            r"axis.master.travel_counts must be \[low, high\], integers",
        ),
        (
            "counter_channel = 0",
            "counter_channel = 1e3",
            r"axis.master.counter_channel must be an integer in 0..255 \[c"
            r"hannel\], got 1000.0",
        ),
        ('name = "pc-dual-servo"', "name = 5", "rig.name must be a string, got 5"),
        (
            "period_s = 0.004 ",
            'period_s = "4 ms" ',
            r"timer.period_s must be a number > 0 \[s\], got '4 ms'",
        ),
        ("period_s = 0.004 ", "period_s_typo = 0.004 ", "unknown key timer.period_s_typo"),
        ("tau_s = 0.025", "tau_s = 0", r"axis.master.plant.tau_s must be > 0 \[s\], got 0"),
        (
            "tau_s = 0.025",
            "tau_s = 1e-300",
            r"axis.master.plant.tau_s must be a number in \[1e-06, 1000\]",
        ),
        ("tau_s = 0.025", "tau_sec = 0.025", "unknown key axis.master.plant.tau_sec"),
        ('role = "slave"', 'role = "follower"', "axis.slave.role must be 'master' or 'slave'"),
        (
            "counter_init = 0xFFC000",
            "counter_init = 0x1FFC000",
            "axis.master.counter_init must fit",
        ),
        (
            "pulses_per_rev = 3072",
            "pulses_per_rev = -3072",
            r"encoder.pulses_per_rev must be a number in \(0, 1e\+09\] \[pulses/rev\]",
        ),
        (
            "range_v = [-10.0, 10.0]",
            "range_v = [10.0, -10.0]",
            r"dac.range_v must be \[low, high\]",
        ),
        # the asymmetric model's keys: checked as their positive-direction peers
        (
            "coulomb_v = 0.002",
            "coulomb_v = 0.002\ncoulomb_neg_v = -0.003",
            r"axis.master.plant.coulomb_neg_v must be >= 0 \[V\], got -0.003",
        ),
        (
            "coulomb_v = 0.002",
            "coulomb_v = 0.002\ncoulomb_neg_v = nan",
            r"axis.master.plant.coulomb_neg_v must be a finite number \[V\], got nan",
        ),
        (
            "coulomb_v = 0.002",
            "coulomb_v = 0.002\ncoulomb_neg_v = 11.0",
            r"axis.master.plant.coulomb_neg_v must be a number in \[0, 10\] \[V\], got 11.0",
        ),
        (
            "coulomb_v = 0.002",
            "coulomb_v = 0.002\ngain_neg_cps_per_v = -9000.0",
            r"axis.master.plant.gain_neg_cps_per_v must be > 0 \[counts/s/V\], got -9000.0",
        ),
        (
            "coulomb_v = 0.002",
            "coulomb_v = 0.002\ngain_neg_cps_per_v = inf",
            r"axis.master.plant.gain_neg_cps_per_v must be a finite number \[counts/s/V\], got inf",
        ),
        (
            "coulomb_v = 0.002",
            "coulomb_v = 0.002\ngain_neg_cps_per_v = 1e12",
            r"axis.master.plant.gain_neg_cps_per_v must be a number in \(0, 1e\+09\] "
            r"\[counts/s/V\]",
        ),
        (
            "coulomb_v = 0.002",
            "coulomb_v = 0.002\ncoulomb_negative_v = 0.003",
            r"unknown key axis.master.plant.coulomb_negative_v.*did you mean 'coulomb_neg_v'\?",
        ),
        # the modes (docs/formats.md#modes): each key named with the mode's index
        (
            "noise_counts = 0.3",
            f"noise_counts = 0.3\n{MODE_TABLE.replace('0.04', '-0.1')}",
            r"axis.master.plant.modes\[0\].damping must be a number in \(0, 1\) \[-\], got -0.1",
        ),
        (
            "noise_counts = 0.3",
            f"noise_counts = 0.3\n{MODE_TABLE}{MODE_TABLE.replace('35.0', '0.0')}",
            r"axis.master.plant.modes\[1\].freq_hz must be a number > 0 \[Hz\], got 0.0",
        ),
        (
            "noise_counts = 0.3",
            "noise_counts = 0.3\nmodes = [{freq_hz = 35.0, damping = 0.04, gain = -1.0}]",
            r"axis.master.plant.modes\[0\].gain must be a number > -1 \[-\], got -1.0",
        ),
        # at or above the rig's Nyquist frequency, 0.5 / 4.000235 ms = 124.9927 Hz
        (
            "noise_counts = 0.3",
            f"noise_counts = 0.3\n{MODE_TABLE.replace('35.0', '125.0')}",
            r"axis.master.plant.modes\[0\].freq_hz must be below the rig's Nyquist frequency "
            r"0.5 / period_s = 124.993 \[Hz\], got 125.0",
        ),
        (
            "noise_counts = 0.3",
            f"noise_counts = 0.3\n{MODE_TABLE.replace('35.0', '124.9927')}",
            r"axis.master.plant.modes\[0\].freq_hz must be below the rig's Nyquist frequency",
        ),
        (
            "noise_counts = 0.3",
            f"noise_counts = 0.3\n{MODE_TABLE}ratio = 0.5\n",
            r"unknown key axis.master.plant.modes\[0\].ratio \(allowed: damping, damping_95, "
            r"freq_hz, freq_hz_95, gain, gain_95\)",
        ),
        (
            "noise_counts = 0.3",
            f"noise_counts = 0.3\n{MODE_TABLE}freq_hz_95 = [36.0, 34.0]\n",
            r"axis.master.plant.modes\[0\].freq_hz_95 must be \[low, high\], two numbers with "
            r"low <= high \[Hz\], got \[36.0, 34.0\]",
        ),
        (
            "noise_counts = 0.3",
            "noise_counts = 0.3\nmodes = [35.0]",
            r"axis.master.plant.modes\[0\] must be a table \(freq_hz, damping, gain\), got float",
        ),
        (
            "noise_counts = 0.3",
            "noise_counts = 0.3\nmodes = {freq_hz = 35.0, damping = 0.04, gain = 0.5}",
            r"axis.master.plant.modes must be an array of tables \(\[\[axis.master.plant.modes\]\]",
        ),
        (
            "noise_counts = 0.3",
            "noise_counts = 0.3\n" + MODE_TABLE * 5,
            r"axis.master.plant.modes has 5 modes; a plant carries at most 4",
        ),
        (
            "noise_counts = 0.3",
            f"noise_counts = 0.3\n{MODE_TABLE.replace('damping', 'dampng')}",
            r"unknown key axis.master.plant.modes\[0\].dampng .*did you mean 'damping'\?",
        ),
    ],
)
def test_rig_errors_name_field_value_unit(tmp_path: Path, old: str, new: str, message: str) -> None:
    text = EXAMPLE_RIG.read_text()
    assert old in text
    p = _write(tmp_path, text.replace(old, new, 1))
    with pytest.raises(st.RigError, match=message) as exc:
        st.load_rig(p)
    assert str(exc.value).startswith(f"rig file {str(p)!r}: ")
    # one short line: its length without the file's path (which depends on the test runner)
    assert "\n" not in str(exc.value) and len(str(exc.value).replace(str(p), "")) < 240


def test_asymmetric_plant_keys_are_read(tmp_path: Path) -> None:
    text = EXAMPLE_RIG.read_text().replace(
        "coulomb_v = 0.002",
        "coulomb_v = 0.002\ncoulomb_neg_v = 0.0035\ngain_neg_cps_per_v = 11000.0",
        1,
    )
    rig = st.load_rig(_write(tmp_path, text))
    p = rig.axis("master").plant
    assert (p.gain_neg_cps_per_v, p.coulomb_neg_v) == (11000.0, 0.0035)
    assert p.gains_cps_per_v == (12288.0, 11000.0) and p.coulombs_v == (0.002, 0.0035)
    # left out: None, the symmetric model of the file as it was
    assert rig.axis("slave").plant.gain_neg_cps_per_v is None
    assert rig.axis("slave").plant.symmetric


def test_bom_is_accepted(tmp_path: Path) -> None:
    p = tmp_path / "bom.toml"
    p.write_bytes(b"\xef\xbb\xbf" + EXAMPLE_RIG.read_bytes())
    assert st.load_rig(p).axis("master").plant.tau_s == 0.025


def test_missing_key_and_deep_nesting(tmp_path: Path) -> None:
    text = EXAMPLE_RIG.read_text().replace("period_s = 0.004 ", "# no period ")
    with pytest.raises(st.RigError, match=r"missing key timer\.period_s"):
        st.load_rig(_write(tmp_path, text))
    deep = EXAMPLE_RIG.read_text() + "\n[extra]\nx = " + "[" * 100_000 + "]" * 100_000 + "\n"
    with pytest.raises(st.RigError, match="nested too deeply"):
        st.load_rig(_write(tmp_path, deep))


def test_missing_table_and_bad_toml(tmp_path: Path) -> None:
    with pytest.raises(st.RigError, match=r"missing table \[timer\]"):
        st.load_rig(_write(tmp_path, "[counter]\nbits = 24\n"))
    with pytest.raises(st.RigError, match="not valid TOML"):
        st.load_rig(_write(tmp_path, "[timer\n"))
    with pytest.raises(st.RigError, match="cannot read rig file"):
        st.load_rig(tmp_path / "nope.toml")


def test_cli_rig_text_and_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["rig", str(EXAMPLE_RIG), "--json"]) == 0
    facts = json.loads(capsys.readouterr().out)
    assert facts["timer_divisor"] == 4773
    assert main(["rig", str(EXAMPLE_RIG)]) == 0
    out = capsys.readouterr().out
    assert "4.000235 ms (+58.7 ppm" in out
    assert "lock holding band" in out


def test_cli_rig_lists_the_modes_and_only_when_there_are_any(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["rig", str(EXAMPLE_RIG)]) == 0
    rigid = capsys.readouterr().out
    assert "mode" not in rigid  # a rigid rig: the facts as before
    assert main(["rig", str(EXAMPLE_RIG), "--json"]) == 0
    assert all("modes" not in a for a in json.loads(capsys.readouterr().out)["axes"].values())
    belt = _write(tmp_path, EXAMPLE_RIG.read_text() + MODE_TABLE)  # plants/belt-axis.toml's mode
    assert main(["rig", str(belt)]) == 0
    text = capsys.readouterr().out
    assert text.startswith(rigid.rstrip("\n"))  # the facts as before, then the mode
    assert text.rstrip("\n").splitlines()[-1] == (
        "  axis master mode         35 Hz, damping 0.04, gain 0.5 (anti-resonance 28.58 Hz)"
    )
    assert main(["rig", str(belt), "--json"]) == 0
    axes = json.loads(capsys.readouterr().out)["axes"]
    (mode,) = axes["master"]["modes"]
    assert (mode["freq_hz"], mode["damping"], mode["gain"]) == (35.0, 0.04, 0.5)
    assert mode["antiresonance_hz"] == pytest.approx(35.0 / 1.5**0.5)  # f / sqrt(1 + g)
    assert "modes" not in axes["slave"]


def test_cli_rig_bad_file_is_one_line_exit_3(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    p = _write(tmp_path, EXAMPLE_RIG.read_text().replace("tau_s = 0.025", "tau_s = -1", 1))
    assert main(["rig", str(p)]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "axis.master.plant.tau_s" in err and "Traceback" not in err


def test_modes_are_read_as_tables_or_inline_with_their_intervals(tmp_path: Path) -> None:
    text = EXAMPLE_RIG.read_text()
    tables = text.replace(
        "noise_counts = 0.3",
        f"noise_counts = 0.3\n{MODE_TABLE}damping_95 = [0.03, 0.05]\n"
        "\n[[axis.master.plant.modes]]\nfreq_hz = 80\ndamping = 0.1\ngain = -0.2\n",
        1,
    )
    inline = text.replace(
        "noise_counts = 0.3",
        "noise_counts = 0.3\nmodes = [{freq_hz = 35.0, damping = 0.04, gain = 0.5, damping_95 = "
        "[0.03, 0.05]}, {freq_hz = 80, damping = 0.1, gain = -0.2}]",
        1,
    )
    want = (
        Mode(freq_hz=35.0, damping=0.04, gain=0.5, damping_95=(0.03, 0.05)),
        Mode(freq_hz=80.0, damping=0.1, gain=-0.2),
    )
    for variant in (tables, inline):
        rig = st.load_rig(_write(tmp_path, variant))
        modes = rig.axis("master").plant.modes
        assert modes == want
        assert all(isinstance(x, float) for m in modes for x in (m.freq_hz, m.damping, m.gain))
        assert rig.axis("slave").plant.modes == ()
    # to_dict lists them only when there are some (the example rig's plants: none)
    assert st.load_rig(EXAMPLE_RIG).axis("master").plant.to_dict().get("modes") is None


def test_the_belt_driven_example_is_the_example_rig_with_one_mode() -> None:
    belt = st.load_rig(EXAMPLE_RIG.with_name("belt-axis.toml"))
    base = st.load_rig(EXAMPLE_RIG)
    assert belt.name == "belt-axis"
    # the same hardware and axes; the master's plant differs by its mode only
    for part in ("timer", "counter", "dac", "encoder"):
        assert getattr(belt, part) == getattr(base, part)
    assert belt.axis("slave") == base.axis("slave")
    master = belt.axis("master")
    assert master.plant.modes == (Mode(freq_hz=35.0, damping=0.04, gain=0.5),)
    assert dataclasses.replace(master.plant, modes=()) == base.axis("master").plant
    assert dataclasses.replace(master, plant=base.axis("master").plant) == base.axis("master")
    assert master.plant.modes[0].antiresonance_hz == pytest.approx(28.58, abs=0.01)


@pytest.mark.parametrize("verb", [["rig"], ["simulate", "--scenario", "steps", "-o", "x.csv"]])
def test_cli_bad_mode_is_one_line_exit_3(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], verb: list[str]
) -> None:
    text = EXAMPLE_RIG.read_text()
    p = _write(tmp_path, text.replace("noise_counts = 0.3", "noise_counts = 0.3\nmodes = [1]", 1))
    argv = [verb[0], str(p), *verb[1:]]
    if verb[0] == "simulate":
        argv[-1] = str(tmp_path / "x.csv")
    assert main(argv) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "axis.master.plant.modes[0] must be a table" in err
    assert not (tmp_path / "x.csv").exists()


def test_the_package_exports_its_modules_names() -> None:
    """``servotune.rig`` is where the rig is imported from: the names of its model and of its
    files, the very objects; the modules it replaced are gone (no shims)."""
    import importlib.util

    import servotune.rig
    from servotune.rig import file, model

    assert sorted(servotune.rig.__all__) == sorted([*model.__all__, *file.__all__])
    for name in servotune.rig.__all__:
        home = model if name in model.__all__ else file
        assert getattr(servotune.rig, name) is getattr(home, name)
    for gone in ("servotune.rig_model", "servotune.rig_edit", "servotune.io.rig"):
        assert importlib.util.find_spec(gone) is None
