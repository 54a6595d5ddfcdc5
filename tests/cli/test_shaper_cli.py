"""``servotune shaper`` and ``simulate --shaper`` (docs/runtime.md#input-shaping)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from servotune.analysis.shaping import axis_shaper
from servotune.cli import main
from servotune.cli.machine_parsers import SHAPER_KINDS
from servotune.laws.shaping import KINDS, shape_reference
from servotune.logs import read_log
from servotune.pipeline import default_pi_gains
from servotune.rig import EXAMPLE_RIG_PATH, EXAMPLES_DIR, load_rig

BELT = str(EXAMPLES_DIR / "belt-axis.toml")


def test_the_parsers_kinds_are_the_librarys() -> None:
    assert SHAPER_KINDS == KINDS


def test_auto_takes_the_shortest_kind_that_holds_and_says_why(capsys) -> None:
    """The belt rig's mode has no interval: ±5 %, where zv leaves more than 5 % and zvd not."""
    assert main(["shaper", BELT, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["kind"] == "zvd" and doc["axis"] == "master"
    assert "meets the 5 % goal" in doc["why"][0]
    assert doc["residual"][0]["worst_within_15_percent"] <= 0.055
    assert doc["added_time_s"] == (len(doc["amplitudes_q"]) - 1) * doc["period_s"]


def test_an_axis_without_modes_is_one_line_exit_3(tmp_path: Path, capsys) -> None:
    comp = tmp_path / "s.comp"
    assert main(["shaper", str(EXAMPLE_RIG_PATH), "--hal-output", str(comp)]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "has no modes to shape for" in err[0]
    assert not comp.exists()


def test_simulate_shapes_the_moved_axiss_reference(tmp_path: Path, capsys) -> None:
    plain, shaped = tmp_path / "plain.csv", tmp_path / "shaped.csv"
    args = ["simulate", BELT, "--scenario", "track", "--seconds", "2", "--no-noise"]
    assert main([*args, "-o", str(plain)]) == 0
    assert main([*args, "--shaper", "ei", "-o", str(shaped)]) == 0
    assert "reference shaped" in capsys.readouterr().err
    ref = read_log(plain).axis("master").ref_counts
    got = read_log(shaped).axis("master").ref_counts
    rig = load_rig(BELT)
    sh = axis_shaper(rig, "master", default_pi_gains(rig)[0], "ei")[0]
    assert np.array_equal(got, shape_reference(ref, sh))
    assert not np.array_equal(got, ref) and got[-1] == ref[-1]


def _belt_tuning(kp: float, ki: float) -> object:
    """A tuning of the belt rig whose master runs the PI (kp, ki) in task mode."""
    from servotune.laws.axis import AxisController
    from servotune.laws.pi import PIGains
    from servotune.tuning import Tuning

    rig = load_rig(BELT)
    controllers = tuple(
        AxisController.from_gains(
            lock_gain_codes_per_count=a.lock_gain_codes_per_count,
            task_gains=PIGains(kp=kp, ki=ki) if a.name == "master" else None,
            period_s=rig.period_s,
        )
        for a in rig.axes
    )
    return Tuning.for_rig(rig, controllers, rig_sha256="0" * 64)


def test_a_tuning_gives_the_loop_to_design_for(tmp_path: Path, capsys) -> None:
    """With --tuning the shaper is designed for the closed loop of the tuning's PI: a stiffer
    PI moves the mode further than the default loop shaping does, and the design follows."""
    from servotune.laws.pi import PIGains
    from servotune.tuning import write_tuning

    path = tmp_path / "t.json"
    write_tuning(_belt_tuning(1.5, 4.0), path)
    assert main(["shaper", BELT, "--tuning", str(path), "--kind", "zv", "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    rig = load_rig(BELT)
    tuned = _belt_tuning(1.5, 4.0).controllers[0].task
    gains = PIGains(kp=tuned.kp.value, ki=tuned.ki_t.value / rig.period_s)
    want = axis_shaper(rig, "master", gains, "zv")[0]
    assert got["amplitudes_q"] == list(want.amplitudes_q)
    default = axis_shaper(rig, "master", default_pi_gains(rig)[0], "zv")[0]
    assert got["modes"][0]["freq_hz"] > default.modes[0][0] + 0.3  # 35.57 against 35.10 Hz


def test_a_tuning_of_another_rig_is_one_line(tmp_path: Path, quick_tuning, capsys) -> None:
    from servotune.tuning import write_tuning

    path = tmp_path / "t.json"
    write_tuning(quick_tuning, path)
    assert main(["shaper", BELT, "--tuning", str(path)]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the tuning is for rig 'pc-dual-servo'" in err[0], err


def test_an_unstable_loop_is_refused(tmp_path: Path, capsys) -> None:
    from servotune.tuning import write_tuning

    path = tmp_path / "t.json"
    write_tuning(_belt_tuning(40.0, 0.0), path)
    assert main(["shaper", BELT, "--tuning", str(path)]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is unstable" in err[0], err
