"""``servotune autotune CONFIG`` live, in real HAL (docs/autotune.md#the-live-run): the plant
component standing in for the machine, closed by the stock pid through the guard
(tests/hal/autotune_machine.py), servotune run beside the session as it would be by the
machine's user.

- end to end: the run loads verified gains equal to those of fit → tune → verify → export run
  by hand on its own capture, the validation move matches the prediction, the session's
  wiring is as before, and the record's digests are the files'; on the resonant rig too, its
  mode fitted from the capture's frequency response;
- a reversed encoder stops at the wiring check (no closed-loop motion) with the previous pins;
- a drive with 10× the model's gain passes the wiring check and is stopped by the guard in the
  real-time thread (the output 0 from the period of the breach, read from the capture);
- SIGTERM in the experiment: the guard's output 0 and the previous pins back;
- ``--dry-run`` in the session changes no pin.
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the shared HAL harness
import autotune_machine as m
import halrun

from servotune.cli import main
from servotune.digest import bytes_sha256

PLANT = "statplant"  # names no other test's components use
PLANT10 = "statplant10"
PLANT_BELT = "statbelt"
BELT = "belt-axis"  # the example rig with a belt mode in its master's plant
GUARD_FE = "servotune_guard_fe"
FE_LIMIT = 800.0
"""A following-error limit below the experiment's (the plan predicts about 1400 counts for the
example rig's excitation) and above the wiring check's (about 400)."""
AFTER = ("show pin pid.0", "show pin servotune-guard", "show sig")


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> dict[str, Path]:
    halrun.hal_available()
    w = tmp_path_factory.mktemp("autotune_build")
    plant_so, guard_so = m.build(w, PLANT)
    master = m.rig().axis("master").plant
    ten = dataclasses.replace(master, gain_cps_per_v=10 * master.gain_cps_per_v)
    if ten.gain_neg_cps_per_v is not None:
        ten = dataclasses.replace(ten, gain_neg_cps_per_v=10 * master.gain_neg_cps_per_v)
    w10 = tmp_path_factory.mktemp("autotune_build10")
    plant10_so, _ = m.build(w10, PLANT10, plant=ten)
    wfe = tmp_path_factory.mktemp("autotune_build_fe")
    _, guard_fe_so = m.build(
        wfe, PLANT, envelope={"following_error_counts": FE_LIMIT}, guard=GUARD_FE
    )
    wbelt = tmp_path_factory.mktemp("autotune_build_belt")
    belt_so, _ = m.build(wbelt, PLANT_BELT, plant=m.rig(BELT).axis("master").plant)
    return {
        PLANT: plant_so,
        PLANT10: plant10_so,
        PLANT_BELT: belt_so,
        "guard": guard_so,
        GUARD_FE: guard_fe_so,
    }


def _run(built, tmp_path, plant, argv, capsys, *, fb_sign=1.0, seconds=12.0, previous=None):
    m.workspace(tmp_path, m.config_text(seconds))
    halrun.share(tmp_path)
    with halrun.installed_component(built[plant]), halrun.installed_component(built["guard"]):
        with m.machine(
            tmp_path, plant, after=AFTER, fb_sign=fb_sign, previous=previous or m.PREVIOUS
        ) as session:
            rc = main(["autotune", str(tmp_path / "at.toml"), *argv, *m.hal_user_args()])
    cap = capsys.readouterr()
    return rc, cap, m.pin_values(session.result.stdout), session.result.stdout


def _previous_pins_back(pins: dict[str, str], previous: dict[str, float] = m.PREVIOUS) -> None:
    for k, v in previous.items():
        assert float(pins[f"pid.0.{k}"]) == v, (k, pins[f"pid.0.{k}"])


def _wiring_as_before(stdout: str) -> None:
    # the command and the guard's command back on the machine's signal; nothing of the run's
    assert "x-cmd" in stdout and "servotune-at" not in stdout and "streamer" not in stdout
    lines = [ln.split() for ln in stdout.splitlines()]
    cmd = [f for f in lines if len(f) >= 7 and f[4] == "pid.0.command"]
    assert cmd and cmd[0][6] == "x-cmd"


def _by_hand_equals_loaded(tmp_path, out, rec, capsys, rig_name="pc-dual-servo", fit_args=()):
    """fit → tune → verify → export run by hand on the run's own capture: the HAL file's
    setp lines are the pins the run loaded, bit for bit."""
    pid = ("--format", "linuxcnc-hal", "--position-scale", str(m.SCALE), "--pid", "pid.0")
    hal = m.by_hand(tmp_path, out, capsys, pid, "pid.hal", rig_name=rig_name, fit_args=fit_args)
    setp = [ln.split() for ln in hal.read_text().splitlines()]
    by_hand = {f[1].split(".", 2)[2]: f[2] for f in setp if f[:1] == ["setp"]}
    loaded = rec["loaded"]
    assert by_hand.keys() == loaded.keys()
    for k, v in by_hand.items():
        assert (v == "true") is loaded[k] if v in ("true", "false") else float(v) == loaded[k], k


def _validated(rec) -> None:
    """The validation move matched the prediction within the stated tolerances, and moved."""
    v = rec["validation"]
    assert v["passed"] and v["problems"] == []
    for key, (rel, ab) in v["tolerance"].items():
        assert abs(v["measured"][key] - v["predicted"][key]) <= rel * abs(v["predicted"][key]) + ab
    assert v["measured"]["following_error"] > 10  # the move moved


def test_end_to_end_loads_the_by_hand_gains_and_validates(built, tmp_path, capsys):
    out = tmp_path / "out"
    t0 = time.monotonic()
    rc, cap, pins, stdout = _run(built, tmp_path, PLANT, ["-o", str(out), "--json"], capsys)
    wall = time.monotonic() - t0
    assert rc == 0, cap.err
    rec = json.loads(cap.out)
    assert rec == json.loads((out / "autotune.json").read_text())
    # the pins loaded are the record's, and differ from the previous ones
    for k, v in rec["loaded"].items():
        if k != "error-previous-target":
            assert float(pins[f"pid.0.{k}"]) == pytest.approx(v, rel=1e-6), k
    assert float(pins["pid.0.Pgain"]) != m.PREVIOUS["Pgain"]
    _wiring_as_before(stdout)
    _by_hand_equals_loaded(tmp_path, out, rec, capsys)
    _validated(rec)
    assert rec["fit"]["modes"] == []  # a rigid rig: no modes asked for, none fitted
    # the record binds the files by their SHA-256
    for name, sha in rec["files_sha256"].items():
        assert bytes_sha256((out / name).read_bytes()) == sha
    assert {"capture.txt", "fitted-rig.toml", "tuning.json", "pid.hal"} <= set(rec["files_sha256"])
    assert rec["seconds"]["machine_s"] < 300
    page = (out / "autotune.html").read_text()
    assert "servotune autotune: loaded and validated" in page and page.count("<img") == 3
    print(f"autotune end to end: wall {wall:.0f} s, machine {rec['seconds']['machine_s']:.1f} s")


def test_end_to_end_on_the_resonant_rig_fits_its_mode(built, tmp_path, capsys):
    """The belt-driven rig (examples/belt-axis.toml: a 35 Hz mode, damping 0.04, gain 0.5),
    its plant component ringing as the engine's: the run plays a periodic multisine (the
    rig has modes, so the config's default is ``modes = "auto"``, 8 periods), keeps the whole
    periods of the capture, fits the rigid plant and the mode from the frequency response,
    and loads what fit --modes auto → tune → verify → export give by hand on that capture."""
    out = tmp_path / "out"
    m.workspace(tmp_path, m.config_text(12.0, rig_name=BELT), rig_name=BELT)
    halrun.share(tmp_path)
    t0 = time.monotonic()
    with halrun.installed_component(built[PLANT_BELT]), halrun.installed_component(built["guard"]):
        with m.machine(tmp_path, PLANT_BELT, after=AFTER):
            argv = ["autotune", str(tmp_path / "at.toml"), "-o", str(out), "--json"]
            rc = main([*argv, *m.hal_user_args()])
    wall = time.monotonic() - t0
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    rec = json.loads(cap.out)
    # the capture is the 8 whole periods of 375 ticks, and its mode is the plant's
    assert len((out / "capture.txt").read_text().splitlines()) == 8 * 375
    (mode,) = rec["fit"]["modes"]
    assert mode["freq_hz"] == pytest.approx(35.0, rel=0.01)
    assert mode["damping"] == pytest.approx(0.04, rel=0.2)
    # the record states the plant written (gain and tau from the frequency-domain fit, its
    # whole-log velocity fit), not the rigid time-domain fit's (12120 counts/s/V, 37 %)
    assert rec["fit"]["params"]["gain_cps_per_v"] == pytest.approx(12288.0, rel=0.005)
    assert rec["fit"]["params"]["tau_s"] == pytest.approx(0.025, rel=0.01)
    assert rec["fit"]["velocity_fit_pct"] > 90
    _by_hand_equals_loaded(tmp_path, out, rec, capsys, rig_name=BELT, fit_args=("--modes", "auto"))
    _validated(rec)
    assert rec["seconds"]["machine_s"] < 300
    print(
        f"autotune on the resonant rig: mode {mode['freq_hz']:.3f} Hz, damping "
        f"{mode['damping']:.4f}; wall {wall:.0f} s, machine {rec['seconds']['machine_s']:.1f} s"
    )


def test_a_reversed_encoder_stops_at_the_wiring_check(built, tmp_path, capsys):
    rc, cap, pins, stdout = _run(
        built, tmp_path, PLANT, ["-o", str(tmp_path / "o")], capsys, fb_sign=-1.0, previous=m.IDLE
    )
    assert rc == 1
    line = cap.err.strip().splitlines()[-1]
    assert "wiring check" in line and "reversed" in line and "nothing ran in closed loop" in line
    assert not (tmp_path / "o" / "experiment.txt").exists()
    rec = json.loads((tmp_path / "o" / "autotune.json").read_text())
    assert rec["status"] == "stopped" and "reversed" in rec["stopped"] and not rec["loaded"]
    assert (
        "servotune autotune: stopped: wiring check"
        in (tmp_path / "o" / "autotune.html").read_text()
    )
    _previous_pins_back(pins, m.IDLE)
    _wiring_as_before(stdout)


def test_a_drive_ten_times_too_strong_is_stopped_by_the_guard(built, tmp_path, capsys):
    out = tmp_path / "o"
    rc, cap, pins, stdout = _run(built, tmp_path, PLANT10, ["-o", str(out)], capsys)
    assert rc == 1
    line = cap.err.strip().splitlines()[-1]
    assert "the guard tripped on" in line and "previous parameters are restored" in line, line
    _previous_pins_back(pins)
    assert pins["servotune-guard.fault"] == "TRUE"
    assert pins["servotune-guard.volts-out"] in ("0", "-0")
    # from the capture: the output is 0 from the period the fault is seen on
    rec = np.loadtxt(out / "experiment.txt", ndmin=2)
    fault = np.flatnonzero(rec[:, 6] > 0.5)
    assert fault.size, "the capture does not show the trip"
    assert np.all(rec[fault[0] :, 2] == 0.0)
    assert np.any(rec[: fault[0], 2] != 0.0)
    _wiring_as_before(stdout)


def test_a_following_error_limit_the_experiment_exceeds_is_stopped_by_the_guard(
    built, tmp_path, capsys
):
    m.workspace(tmp_path, m.config_text(12.0, {"following_error_counts": FE_LIMIT}))
    halrun.share(tmp_path)
    out = tmp_path / "o"
    argv = ["autotune", str(tmp_path / "at.toml"), "-o", str(out), "--guard-name", GUARD_FE]
    with halrun.installed_component(built[PLANT]), halrun.installed_component(built[GUARD_FE]):
        with m.machine(tmp_path, PLANT, after=AFTER, guard=GUARD_FE) as session:
            rc = main([*argv, *m.hal_user_args()])
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc == 1
    assert "the guard tripped on following error" in line and "into the experiment" in line, line
    pins = m.pin_values(session.result.stdout)
    _previous_pins_back(pins)
    g = GUARD_FE.replace("_", "-")
    assert pins[f"{g}.fault"] == "TRUE" and pins[f"{g}.reason"] == "3"
    # from the capture: |command - position| first beyond the limit in the period of the trip,
    # and the output 0 from that period on
    rec = np.loadtxt(out / "experiment.txt", ndmin=2)
    fe = np.abs(rec[:, 3] - rec[:, 1]) * m.SCALE
    first = int(np.flatnonzero(fe > FE_LIMIT)[0])
    assert rec[first, 6] == 1 and rec[first - 1, 6] == 0
    assert np.all(rec[first:, 2] == 0.0) and rec[first - 1, 2] != 0.0


def test_sigterm_in_the_experiment_leaves_output_zero_and_previous_pins(built, tmp_path):
    m.workspace(tmp_path, m.config_text(30.0))
    halrun.share(tmp_path)
    argv = [
        sys.executable,
        "-m",
        "servotune.cli",
        "autotune",
        str(tmp_path / "at.toml"),
        "-o",
        str(tmp_path / "o"),
        *m.hal_user_args(),
    ]
    with halrun.installed_component(built[PLANT]), halrun.installed_component(built["guard"]):
        with m.machine(tmp_path, PLANT, after=AFTER) as session:
            err = tmp_path / "err.txt"
            with open(err, "w") as fh:
                proc = subprocess.Popen(
                    argv, stdout=subprocess.DEVNULL, stderr=fh, env={**os.environ}
                )
                end = time.monotonic() + 240
                while "experiment" not in err.read_text() and time.monotonic() < end:
                    assert proc.poll() is None, err.read_text()
                    time.sleep(0.2)
                time.sleep(2.0)
                proc.send_signal(signal.SIGTERM)
                rc = proc.wait(timeout=120)
    assert rc == 128 + signal.SIGTERM, err.read_text()
    pins = m.pin_values(session.result.stdout)
    _previous_pins_back(pins)
    assert pins["servotune-guard.fault"] == "TRUE" and pins["servotune-guard.reason"] == "5"
    assert pins["servotune-guard.volts-out"] in ("0", "-0")
    _wiring_as_before(session.result.stdout)


def test_dry_run_changes_nothing_in_the_session(built, tmp_path, capsys):
    m.workspace(tmp_path, m.config_text(6.0))
    halrun.share(tmp_path)
    before_file = tmp_path / "before.txt"
    with halrun.installed_component(built[PLANT]), halrun.installed_component(built["guard"]):
        with m.machine(tmp_path, PLANT, after=AFTER) as session:
            from servotune.io.halcmd import Halcmd

            hal = Halcmd(user=halrun.HAL_USER if os.geteuid() == 0 else None)
            before = hal("show", "pin") + hal("show", "sig")
            before_file.write_text(before)
            rc = main(["autotune", str(tmp_path / "at.toml"), "--dry-run"])
            after = hal("show", "pin") + hal("show", "sig")
    assert rc == 0
    out = capsys.readouterr().out
    assert "the HAL session's pins and thread: as the config says" in out

    def state(text: str) -> list[tuple[str, ...]]:
        """Every pin (type, direction, link) with the value of each one a user sets (an
        unlinked input, not a timing counter), and every signal with its pins."""
        out = []
        for f in (ln.split() for ln in text.splitlines()):
            if len(f) >= 5 and f[1] in ("bit", "float", "s32", "u32"):
                # (an unlinked pid's *-deriv inputs hold what the pid computes: not settings)
                settable = (
                    f[2] in ("IN", "I/O") and len(f) == 5 and not f[4].endswith((".time", "-deriv"))
                )
                out.append((*f[1:3], f[4], *f[5:], f[3] if settable else ""))
            elif len(f) >= 3 and f[0] in ("bit", "float", "s32", "u32"):
                out.append((f[0], *f[2:]))  # a signal: its type, name and pins, not its value
        return out

    signals = {x[1]: x for x in state(before) if x[0] == "float" and len(x) > 2}
    assert len(state(before)) > 50 and "pid.0.command" in signals["x-cmd"]
    assert state(before) == state(after)
    assert session.result is not None
