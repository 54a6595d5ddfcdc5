"""``servotune autotune`` with ``target = "component"`` live, in real HAL
(docs/autotune.md#the-component-target): the stand-in machine of tests/hal/autotune_machine.py
(the plant component closed by the stock pid through the guard), the run loading the verified
servotune runtime component in the pid's place.

- end to end: the component built and installed by the run, placed in the servo thread just
  before the guard, driving the guard's input in task mode on the machine's command and
  counts; its source the by-hand ``export-table --format linuxcnc-comp`` one but for the
  provenance comments (the same tables' SHA-256); the validation move within tolerance of
  the engine's run of the same law; the pid's pins as they were, the session's wiring restored;
- a validation that does not match (the prediction shifted by the test) removes it: the
  guard's input back on the pid's output, the component unloaded, the pid's pins as they were.

Each run holds HAL's session about 1.5 minutes (halcompile of the runtime, the experiment,
fit → tune → verify): ``make test-study``, which .ci/run runs after ``make test``.
"""

from __future__ import annotations

import json
import re
import sys
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the shared HAL harness
import autotune_machine as m
import halrun

from servotune import autotune_component
from servotune.cli import main
from servotune.digest import bytes_sha256

pytestmark = pytest.mark.study

PLANT = "statplantc"  # names no other test's components use
GUARD = "servotune_guard_cmp"
GUARD_HAL = GUARD.replace("_", "-")
RT = "servotune_rt_stat"  # the runtime component the run installs
RT_HAL = RT.replace("_", "-")
AFTER = ("show pin pid.0", f"show pin {GUARD_HAL}", f"show pin {RT_HAL}", "show sig")
AFTER += ("show thread servo-thread",)


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> dict[str, Path]:
    halrun.hal_available()
    w = tmp_path_factory.mktemp("component_build")
    plant_so, guard_so = m.build(w, PLANT, guard=GUARD)
    return {"plant": plant_so, "guard": guard_so}


def _run(built, tmp_path: Path, capsys) -> tuple[int, str, str, Path]:
    """The component-target run on the machine; the module directory left as it was."""
    installed = halrun.MODULE_DIR / f"{RT}.so"
    assert not installed.exists(), f"{installed} exists already: not overwriting it"
    text = m.config_text(12.0).replace(
        "seconds = 12.0", f'seconds = 12.0\ntarget = "component"\ncomponent = "{RT}"'
    )
    m.workspace(tmp_path, text.replace("[envelope]", f'counts_pin = "{PLANT}.counts"\n[envelope]'))
    halrun.share(tmp_path)
    out = tmp_path / "out"
    try:
        with halrun.installed_component(built["plant"]), halrun.installed_component(built["guard"]):
            with m.machine(tmp_path, PLANT, after=AFTER, guard=GUARD) as session:
                argv = ["autotune", str(tmp_path / "at.toml"), "-o", str(out), "--json"]
                rc = main([*argv, "--guard-name", GUARD, *m.hal_user_args()])
    finally:
        installed.unlink(missing_ok=True)
    return rc, capsys.readouterr(), session.result.stdout, out


def _links(stdout: str) -> dict[str, str]:
    """Pin → its signal, as ``show pin`` prints them."""
    lines = [ln.split() for ln in stdout.splitlines()]
    return {f[4]: f[6] for f in lines if len(f) >= 7 and f[5] in ("<==", "==>")}


def _pid_as_before(pins: dict[str, str]) -> None:
    for k, v in m.PREVIOUS.items():
        assert float(pins[f"pid.0.{k}"]) == v, (k, pins[f"pid.0.{k}"])


def _by_hand(tmp_path: Path, out: Path, capsys) -> str:
    """fit → tune → verify → export-table --format linuxcnc-comp by hand on the run's capture."""
    comp = ("--format", "linuxcnc-comp", "--name", RT, "--position-scale", str(m.SCALE))
    return m.by_hand(tmp_path, out, capsys, comp, f"{RT}.comp").read_text()


def _law(src: str) -> list[str]:
    """A component's source without its provenance comments (the file's own digest, the rig's
    and the tuning's: the run's fitted rig names the run as its source, a by-hand one the fit
    command)."""
    provenance = ("// sha256 of this file", " * rig: ", " * tuning sha256: ")
    return [ln for ln in src.splitlines() if not ln.startswith(provenance)]


def test_end_to_end_loads_the_verified_component_before_the_guard(built, tmp_path, capsys):
    t0 = time.monotonic()
    rc, cap, stdout, out = _run(built, tmp_path, capsys)
    wall = time.monotonic() - t0
    assert rc == 0, cap.err
    rec = json.loads(cap.out)
    assert rec["status"] == "loaded" and rec["loaded"]["component"] == RT
    assert rec["loaded"]["counts_pin"] == f"{PLANT}.counts"
    pins, link = m.pin_values(stdout), _links(stdout)
    # the component drives the guard, in task mode, on the machine's command and counts
    assert link[f"{GUARD_HAL}.volts-in"] == link[f"{RT_HAL}.volts-0"]
    assert link[f"{RT_HAL}.command"] == "x-cmd" and link[f"{RT_HAL}.counts-0"] == "x-counts"
    assert int(pins[f"{RT_HAL}.mode-0"]) == 1 and int(pins[f"{RT_HAL}.flags-0"]) == 0
    lines = [ln.split() for ln in stdout.splitlines()]
    functs = [f[1] for f in lines if len(f) == 2 and f[0].isdigit()]
    assert functs.index(RT_HAL) == functs.index(GUARD_HAL) - 1, functs
    _pid_as_before(pins)  # the pid drives nothing now: its pins as they were
    assert link["pid.0.command"] == "x-cmd" and "servotune-at" not in stdout
    # the validation move moved, and matched the engine's run of the same law
    v = rec["validation"]
    assert v["passed"] and v["measured"]["following_error"] > 10
    for key, (rel, ab) in v["tolerance"].items():
        assert abs(v["measured"][key] - v["predicted"][key]) <= rel * abs(v["predicted"][key]) + ab
    # the by-hand export: the same law and tables
    hand_src, run_src = _by_hand(tmp_path, out, capsys), (out / f"{RT}.comp").read_text()
    digest = re.compile(r'#define ST_TABLES_SHA256 "([0-9a-f]{64})"')
    assert digest.search(hand_src).group(1) == digest.search(run_src).group(1)
    assert _law(hand_src) == _law(run_src) and len(_law(run_src)) > 500
    assert "pin in float command" in run_src  # the LinuxCNC command, in machine units
    assert rec["files_sha256"][f"{RT}.comp"] == bytes_sha256((out / f"{RT}.comp").read_bytes())
    assert rec["seconds"]["machine_s"] < 300
    print(f"autotune component: wall {wall:.0f} s, machine {rec['seconds']['machine_s']:.1f} s")


def test_a_validation_that_does_not_match_removes_the_component(
    built, tmp_path, capsys, monkeypatch
):
    real = autotune_component.predicted_move

    def off(verified, axis, ref_counts):  # a model 40 % slower than the machine
        pred = real(verified, axis, ref_counts)
        return {**pred, "feedback_counts": np.asarray(pred["feedback_counts"]) * 0.6}

    monkeypatch.setattr(autotune_component, "predicted_move", off)
    rc, cap, stdout, out = _run(built, tmp_path, capsys)
    assert rc == 1
    err = cap.err.strip().splitlines()
    assert err[-1].startswith("servotune autotune: stopped: validation move: ") and (
        "the previous parameters are restored" in err[-1]
    ), err
    rec = json.loads((out / "autotune.json").read_text())
    assert rec["status"] == "stopped" and rec["loaded"] == {}
    pins, link = m.pin_values(stdout), _links(stdout)
    assert link[f"{GUARD_HAL}.volts-in"] == "x-out"  # the pid's output again
    assert not any(p.startswith(f"{RT_HAL}.") for p in pins)  # unloaded
    assert RT_HAL not in stdout.split("Realtime Threads")[-1]  # not in the thread
    _pid_as_before(pins)
    assert link["pid.0.command"] == "x-cmd" and "servotune-at" not in stdout
