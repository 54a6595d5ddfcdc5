"""The autotune config and its dry-run plan (servotune.autotune, docs/autotune.md).

The plan's predicted motion is checked against an independent simulation: the axis model
integrated by scipy ``solve_ivp`` under the planned excitation with the lock module's P law
closed around it (no friction or offset: the test's own loop), not the engine.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from servotune.autotune import (
    DEFAULT_PERIODS,
    OUTPUT_SHARE,
    load_autotune_config,
    plan_autotune,
)
from servotune.cli import main
from servotune.errors import ConfigError
from servotune.examples import EXAMPLES_DIR
from servotune.fixed import quantize

CONFIG = EXAMPLES_DIR / "linuxcnc-autotune.toml"
sys.path.insert(0, str(Path(__file__).resolve().parent / "hal"))  # the shared HAL harness
import halrun  # noqa: E402


@pytest.fixture(autouse=True)
def _no_hal_session() -> Iterator[None]:
    """No HAL session runs during these tests (the real-HAL tests of another worker wait):
    the dry run reads a running session and would check this config against theirs."""
    with halrun.hal_lock():
        yield


def _edit(tmp_path: Path, old: str, new: str) -> Path:
    text = CONFIG.read_text()
    assert old in text, old
    for name in ("pc-dual-servo.toml", "pc-dual-servo.spec.toml"):
        (tmp_path / name).write_bytes((EXAMPLES_DIR / name).read_bytes())
    p = tmp_path / "at.toml"
    p.write_text(text.replace(old, new))
    return p


def test_the_example_config_loads() -> None:
    cfg = load_autotune_config(CONFIG)
    assert cfg.axis == "master" and cfg.hal.position_scale == 2000.0
    assert cfg.envelope.travel_counts == (-40000.0, 40000.0)
    assert cfg.rig.name == "pc-dual-servo" and cfg.spec_path.name == "pc-dual-servo.spec.toml"


@pytest.mark.parametrize(
    ("old", "new", "words"),
    [
        ("period_s = 0.004  ", "period_s = 0.008  ", "slower than the rig's period"),
        ("period_s = 0.004  ", "period_s = 0.001  ", "faster than the rig's period"),
        ("speed_cps = 40000.0", "speed_cps = 2e5", "speed_cps 200000 > the axis's limit"),
        ("max_volts = 4.0", "max_volts = 12.0", "max_volts 12 > the D/A's ±10 V"),
        ("travel_counts = [-40000, 40000]", "travel_counts = [-3e6, 3e6]", "travel"),
        ("travel_counts = [-40000, 40000]", "travel_counts = [10, 40000]", "low < 0 < high"),
        ('output_pin = "pid.0.output"', 'output_pin = "pid 0"', "hal.output_pin"),
        ('enable_pin = "pid.0.enable"\n', "", "missing"),
        ('axis = "master"', 'axis = "z"', "autotune.axis must be one of"),
        ('target = "pid"', 'target = "drive"', "autotune.target"),
        ('rig = "pc-dual-servo.toml"', 'rig = "nope.toml"', "autotune.rig"),
        ('target = "pid"', 'target = "component"', "hal.counts_pin is needed"),
        ('# component = "servotune_rt"', 'component = "Rt-1"', "autotune.component must be"),
        ('# counts_pin = "encoder.0.rawcounts"', 'counts_pin = "enc 0"', "hal.counts_pin"),
    ],
)
def test_a_bad_config_is_one_line_exit_3(tmp_path: Path, capsys, old, new, words) -> None:
    p = _edit(tmp_path, old, new)
    with pytest.raises(ConfigError, match=None) as e:
        load_autotune_config(p)
    assert words in str(e.value) and str(p) in str(e.value), str(e.value)
    assert main(["autotune", str(p), "--dry-run"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err


def test_the_dry_run_prints_the_plan_and_writes_nothing(tmp_path: Path, capsys) -> None:
    p = _edit(tmp_path, "seconds = 40.0", "seconds = 8.0")
    before = sorted(x.name for x in tmp_path.iterdir())
    assert main(["autotune", str(p), "--dry-run", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert sorted(x.name for x in tmp_path.iterdir()) == before
    assert doc["excitation"]["kind"] == "multisine" and doc["excitation"]["seconds"] > 7.9
    assert doc["excitation"]["amplitude_volts"] <= 4.0
    for key in ("travel_counts", "speed_cps", "following_error_counts", "output_volts"):
        assert doc["predicted"][key]["share"] <= 1.0, key
    assert doc["starting_loop"]["phase_margin_deg"] > 30
    assert len(doc["steps"]) == 5 and "wiring check" in doc["steps"][1]
    assert doc["session_checked"] is False
    assert main(["autotune", str(p), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "dry run: nothing in HAL is touched" in out and "predicted speed" in out
    assert "no HAL session runs here (or no halcmd): the pins were not checked" in out


def test_the_target_flag_overrides_the_config_and_is_checked_as_it(tmp_path: Path, capsys):
    """``--target component`` needs ``hal.counts_pin`` as the file's target does: one line,
    exit 3; with it the plan says it builds and places the runtime component."""
    p = _edit(tmp_path, "seconds = 40.0", "seconds = 8.0")
    assert main(["autotune", str(p), "--dry-run", "--target", "component"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "hal.counts_pin is needed" in err[0] and str(p) in err[0], err
    text = p.read_text().replace('# counts_pin = "encoder.0.rawcounts"', 'counts_pin = "enc.raw"')
    p.write_text(text)
    assert main(["autotune", str(p), "--dry-run", "--json", "--target", "component"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert "build the verified runtime component servotune_rt" in doc["steps"][-1]
    assert "its counts from enc.raw" in doc["steps"][-1]
    assert main(["autotune", str(p), "--dry-run", "--json"]) == 0  # the file's: pid
    assert doc["steps"][-1] != json.loads(capsys.readouterr().out)["steps"][-1]


def _independent_run(cfg, codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions [counts] at each tick start and the D/A's output [V] each tick: the axis
    model integrated by solve_ivp, the D/A code written ``compute_s`` after the tick start
    and acting ``delay_s`` later, the lock module's P law (its quantised gain, rounded half
    away from zero) on the latched floor(position), the excitation's codes added."""
    from scipy.integrate import solve_ivp

    rig = cfg.rig
    ax = rig.axis(cfg.axis)
    pl = ax.plant
    t_s, lag = rig.period_s, rig.timer.compute_s + pl.delay_s
    zero = 1 << (rig.dac.bits - 1)
    kp = float(quantize(ax.lock_gain_codes_per_count).value)

    def rhs(_t, x, volts):  # x = position, speed
        return [x[1], (pl.gain_cps_per_v * (volts + pl.offset_v) - x[1]) / pl.tau_s]

    x = np.zeros(2)
    pos = np.empty(codes.size)
    out = np.empty(codes.size)
    prev = 0.0
    for k in range(codes.size):
        pos[k] = x[0]
        e = -np.floor(x[0])
        u = kp * e
        code = int(np.clip(zero + np.sign(u) * np.floor(abs(u) + 0.5) + codes[k], 0, 2 * zero - 1))
        volts = (code - zero) * rig.dac.lsb_v
        out[k] = volts
        x = solve_ivp(rhs, (0, lag), x, args=(prev,), rtol=1e-10, atol=1e-9).y[:, -1]
        x = solve_ivp(rhs, (lag, t_s), x, args=(volts,), rtol=1e-10, atol=1e-9).y[:, -1]
        prev = volts
    return pos, out


@pytest.mark.parametrize("max_volts", [4.0, 2.0])
def test_the_predicted_motion_agrees_with_an_independent_simulation(
    tmp_path: Path, max_volts: float
) -> None:
    """The plan's largest travel, speed and output (the engine) against the same experiment
    run by :func:`_independent_run` on the frictionless axis: within 5 % (both quantise the
    counter and the D/A; their rounding of the P law may differ by a code now and then). The
    output (the loop's plus the excitation's) stays within OUTPUT_SHARE of the envelope's
    limit (on the belt rig the plan lowers the excitation for that: the next test)."""
    p = _edit(tmp_path, "seconds = 40.0", "seconds = 4.0")
    p.write_text(p.read_text().replace("max_volts = 4.0", f"max_volts = {max_volts}"))
    cfg = load_autotune_config(p)
    ax = cfg.rig.axis(cfg.axis)
    frictionless = dataclasses.replace(ax, plant=dataclasses.replace(ax.plant, coulomb_v=0.0))
    cfg = dataclasses.replace(
        cfg,
        rig=dataclasses.replace(
            cfg.rig, axes=tuple(frictionless if a.name == cfg.axis else a for a in cfg.rig.axes)
        ),
    )
    plan = plan_autotune(cfg)
    pos, volts = _independent_run(cfg, plan.excitation_codes - (1 << (cfg.rig.dac.bits - 1)))
    travel = float(np.abs(pos - pos[0]).max())
    speed = float(np.abs(np.diff(pos)).max() / cfg.rig.period_s)
    assert plan.predicted["travel_counts"]["value"] == pytest.approx(travel, rel=0.05)
    assert plan.predicted["speed_cps"]["value"] == pytest.approx(speed, rel=0.05)
    output = float(np.abs(volts).max())
    assert plan.predicted["output_volts"]["value"] == pytest.approx(output, rel=0.05)
    assert output <= OUTPUT_SHARE * max_volts + cfg.rig.dac.lsb_v


def test_a_resonant_rig_plays_whole_periods_within_the_output_limit(tmp_path: Path) -> None:
    """The belt rig (a mode in its master's plant): the config's default is ``modes = "auto"``
    with a periodic multisine of DEFAULT_PERIODS periods; the excitation's full 4 V would
    drive the loop's output past the envelope (the guard tripped at 4.04 V in real HAL before
    the plan looked at the output), so the plan lowers it until the predicted output is within
    OUTPUT_SHARE of 4 V. tests/hal/test_autotune_live.py runs it in HAL, the guard measuring."""
    for name in ("belt-axis.toml", "belt-axis.spec.toml"):
        (tmp_path / name).write_bytes((EXAMPLES_DIR / name).read_bytes())
    text = CONFIG.read_text().replace("pc-dual-servo", "belt-axis")
    (tmp_path / "at.toml").write_text(text.replace("seconds = 40.0", "seconds = 12.0"))
    cfg = load_autotune_config(tmp_path / "at.toml")
    assert cfg.modes == "auto" and cfg.periods == DEFAULT_PERIODS
    plan = plan_autotune(cfg)
    n = plan.excitation_codes.size
    assert n % DEFAULT_PERIODS == 0
    per = n // DEFAULT_PERIODS
    assert np.array_equal(plan.excitation_codes[per:], plan.excitation_codes[:-per])
    assert plan.amplitude_volts < 0.9 * 4.0
    assert plan.predicted["output_volts"]["share"] <= OUTPUT_SHARE


@pytest.mark.parametrize(
    ("old", "new", "words"),
    [
        ("seconds = 40.0", "seconds = 40.0\nmodes = 7", "autotune.modes must be auto or a number"),
        ("seconds = 40.0", "seconds = 40.0\nperiods = 1", "autotune.periods must be a whole"),
        ('excitation = "multisine"', 'excitation = "prbs"\nperiods = 4', "must be multisine"),
        ("seconds = 40.0", "seconds = 40.0\nband_hz = [5, 1]", "autotune.band_hz must be"),
        ("seconds = 40.0", "seconds = 40.0\nband_hz = [1, 50]", "band_hz needs autotune.periods"),
    ],
)
def test_a_bad_frequency_response_request_is_one_line(
    tmp_path: Path, capsys, old: str, new: str, words: str
) -> None:
    p = _edit(tmp_path, old, new)
    with pytest.raises(ConfigError) as e:
        load_autotune_config(p)
    assert words in str(e.value), str(e.value)
    assert main(["autotune", str(p), "--dry-run"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err


def test_a_live_run_without_its_session_is_one_line(tmp_path: Path, capsys) -> None:
    """No HAL session with the config's pins and a guard here (tests/hal/test_autotune_live.py
    runs it in one; the module's fixture holds the HAL lock): one line, exit 3, nothing
    written."""
    rc = main(["autotune", str(CONFIG), "-o", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 3
    last = err[-1]
    assert last.startswith("servotune autotune: error: ") and (
        "no HAL session runs here" in last or "halcmd is not installed" in last
    ), err
    assert not (tmp_path / "o").exists()


def test_the_guard_written_is_the_configs_envelope(tmp_path: Path, capsys) -> None:
    out = tmp_path / "guard.comp"
    p = _edit(tmp_path, "seconds = 40.0", "seconds = 2.0")
    assert main(["autotune", str(p), "--dry-run", "--guard-output", str(out)]) == 0
    text = out.read_text()
    assert "travel -40000..40000 counts, speed 40000 counts/s, following error 6000" in text
    assert "output 4 V, 2000 counts per feedback unit" in text
    assert "wrote the guard servotune_guard" in capsys.readouterr().err


def _capture(excitation: np.ndarray, lead: int, tail: int) -> tuple[str, np.ndarray]:
    """A halsampler capture (sample number, then autotune_live.CHANNELS) whose excitation
    column holds ``excitation`` after ``lead`` rows of 0, printed with 6 decimals."""
    from servotune.autotune_live import CHANNELS, COLUMN

    n = lead + excitation.size + tail
    rec = np.zeros((n, len(CHANNELS) + 1))
    rec[:, 0] = np.arange(509, 509 + n)
    rec[lead : lead + excitation.size, COLUMN["excitation"]] = excitation
    rec[:, COLUMN["feedback"]] = np.cumsum(rec[:, COLUMN["excitation"]]) * 1e-3
    text = "".join(f"{int(r[0])} " + " ".join(f"{x:.6f}" for x in r[1:5]) + " 0 0 \n" for r in rec)
    return text, np.loadtxt(text.splitlines(), ndmin=2)


def test_whole_periods_keeps_the_rows_that_recorded_the_excitation() -> None:
    """The sampler starts before the streamer by a number of rows that varies: the rows kept
    are found by the excitation's printed values; a capture that lost a row is refused."""
    from servotune.autotune_live import whole_periods
    from servotune.errors import AutotuneStopped

    period = np.round(np.sin(2 * np.pi * np.arange(50) / 50) * 2.0, 6)
    period[0] = 0.0  # an excitation that starts at 0, as a sine does: found all the same
    exc = np.tile(period, 4)
    for lead in (100, 137):
        text, rec = _capture(exc, lead, 100)
        kept = whole_periods(text, rec, exc)
        rows = np.loadtxt(kept.splitlines(), ndmin=2)
        assert rows.shape[0] == exc.size and rows[0, 0] == 509 + lead
        np.testing.assert_array_equal(rows[:, 4], exc)
    lost = np.delete(exc, 120)
    text, rec = _capture(lost, 100, 100)
    with pytest.raises(AutotuneStopped, match="does not hold the excitation"):
        whole_periods(text, rec, exc)
