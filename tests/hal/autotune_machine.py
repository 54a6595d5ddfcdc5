"""A stand-in LinuxCNC machine for the live autotune tests: the plant component (the example
rig's master, moved as servotune's simulator moves it) closed by the stock ``pid`` through the
safety envelope's guard, in real HAL (tests/hal/halrun.py), and ``servotune autotune`` run in
that session as the HAL user.

The machine: ``plant.counts`` → ``conv_s32_float`` → ``scale`` (1 / position_scale) =
``fb.out`` [machine units] → ``pid.0.feedback`` and the guard's ``position``; ``pid.0.output``
→ the guard's ``volts-in``; the guard's ``volts-out`` → the plant's ``volts``; a ``constant``
(``hold.out``, standing in for the motion controller) → ``pid.0.command`` and the guard's
``command``. The pid starts with :data:`PREVIOUS` (what the machine had before).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import shutil
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import halrun
import pytest

import servotune as st
from servotune.cli import main
from servotune.examples import EXAMPLES_DIR
from servotune.export.hal_component import guard_component, plant_component
from servotune.laws.linuxcnc_pid import thread_period_ns

SCALE = 2000.0  # counts per machine unit
PREVIOUS = {"Pgain": 2.5, "Igain": 0.5, "FF1": 0.01, "maxoutput": 9.0}
"""The pid's pins before the run (values the stock pid does not default to)."""
IDLE = {"Pgain": 0.0, "Igain": 0.0, "FF1": 0.0, "maxoutput": 9.0}
"""A machine just wired, its loop not yet tuned (with a reversed encoder, PREVIOUS would run
away before any test began)."""
ENVELOPE = {
    "travel_counts": [-40000, 40000],
    "speed_cps": 40000.0,
    "following_error_counts": 6000.0,
    "max_volts": 4.0,
}


def config_text(
    seconds: float = 8.0, envelope: dict | None = None, rig_name: str = "pc-dual-servo"
) -> str:
    """The run's config: the example rig ``rig_name`` (and its spec), its master axis."""
    env = {**ENVELOPE, **(envelope or {})}
    return "\n".join(
        [
            "[autotune]",
            f'rig = "{rig_name}.toml"',
            'axis = "master"',
            f'spec = "{rig_name}.spec.toml"',
            f"seconds = {seconds}",
            "[hal]",
            'thread = "servo-thread"',
            "period_s = 0.004",
            'command_pin = "pid.0.command"',
            'feedback_pin = "fb.out"',
            'output_pin = "pid.0.output"',
            'enable_pin = "pid.0.enable"',
            f"position_scale = {SCALE}",
            "[envelope]",
            f"travel_counts = {env['travel_counts']}",
            *(f"{k} = {env[k]}" for k in ("speed_cps", "following_error_counts", "max_volts")),
            "",
        ]
    )


def rig(name: str = "pc-dual-servo") -> st.Rig:
    return st.load_rig(EXAMPLES_DIR / f"{name}.toml")


def build(
    workdir: Path,
    plant_name: str,
    plant: st.Plant | None = None,
    envelope=None,
    guard: str = "servotune_guard",
    noise: bool = False,
) -> tuple[Path, Path]:
    """The machine's two components built in ``workdir`` (the plant: ``plant``, default the
    rig's master; e.g. one with 10× its gain; noiseless unless ``noise``: then with the plant's
    encoder noise, its stream chosen by the component's ``seed``); returns the built modules.
    The fb ``scale``'s sign (``fb_sign`` of :func:`machine`) stands in for a reversed
    encoder."""
    r = rig()
    p = plant if plant is not None else r.axis("master").plant
    if not noise:
        p = dataclasses.replace(p, noise_counts=0.0)
    (workdir / f"{plant_name}.comp").write_text(
        plant_component(p, r.period_s, r.timer.compute_s, name=plant_name)
    )
    env = {**ENVELOPE, **(envelope or {})}
    (workdir / f"{guard}.comp").write_text(
        guard_component(
            name=guard,
            travel_counts=tuple(env["travel_counts"]),
            speed_cps=env["speed_cps"],
            following_error_counts=env["following_error_counts"],
            max_volts=env["max_volts"],
            position_scale=SCALE,
        )
    )
    halrun.share(workdir)
    return (
        halrun.halcompile(workdir / f"{plant_name}.comp"),
        halrun.halcompile(workdir / f"{guard}.comp"),
    )


def workspace(workdir: Path, config: str, rig_name: str = "pc-dual-servo") -> None:
    """The run's files in ``workdir``: the example rig ``rig_name`` and its spec, and the
    config ``at.toml``."""
    for name in (f"{rig_name}.toml", f"{rig_name}.spec.toml"):
        shutil.copyfile(EXAMPLES_DIR / name, workdir / name)
    (workdir / "at.toml").write_text(config)


def by_hand(
    workdir: Path,
    out: Path,
    capsys: pytest.CaptureFixture,
    export: tuple[str, ...],
    output: str,
    *,
    rig_name: str = "pc-dual-servo",
    fit_args: tuple[str, ...] = (),
) -> Path:
    """fit → tune → verify → export-table run by hand on the run's capture (in ``out``), the
    rig ``rig_name`` of the run's files in ``workdir`` as the fit's template and its spec the
    spec, in the directory ``hand`` of ``workdir``; ``fit_args`` more of the fit's arguments,
    ``export`` the export's (its ``--format`` and options), ``output`` the file it writes in
    ``hand``. Fails the test with the messages of a command that fails; returns the file."""
    hand = workdir / "hand"
    hand.mkdir()
    spec = str(workdir / f"{rig_name}.spec.toml")
    fitted = str(hand / f"{rig_name}.toml")
    capture = [str(out / "capture.txt"), "--map", str(out / "capture.map.toml")]
    template = ["--rig", str(workdir / f"{rig_name}.toml"), "--axis", "master"]
    for argv in (
        ["fit", *capture, *template, *fit_args, "-o", fitted],
        ["tune", fitted, "--spec", spec, "-o", str(hand / "t.json"), "-q"],
        ["verify", str(hand / "t.json"), "--spec", spec],
        ["export-table", str(hand / "t.json"), *export, "-o", str(hand / output)],
    ):
        assert main(argv) == 0, (argv, capsys.readouterr().err)
    capsys.readouterr()
    return hand / output


def script(
    plant_name: str,
    *,
    after: tuple[str, ...] = (),
    fb_sign: float = 1.0,
    previous: dict[str, float] = PREVIOUS,
    guard: str = "servotune_guard",
) -> str:
    """The session: the machine, ready (the file ``ready``), waiting for the file ``done``,
    then ``after``; ``guard`` the guard component's name."""
    ns = thread_period_ns(rig().period_s)
    g = guard.replace("_", "-")
    return "\n".join(
        [
            f"loadrt threads name1=servo-thread period1={ns}",
            f"loadrt {plant_name}",
            "loadrt pid num_chan=1",
            "loadrt conv_s32_float names=cnt2f",
            "loadrt scale names=fb",
            "loadrt constant names=hold",
            f"loadrt {guard}",
            f"net x-counts {plant_name}.counts => cnt2f.in",
            "net x-countsf cnt2f.out => fb.in",
            f"setp fb.gain {fb_sign / SCALE!r}",
            f"net x-pos fb.out => pid.0.feedback {g}.position",
            f"net x-out pid.0.output => {g}.volts-in",
            f"net x-dac {g}.volts-out => {plant_name}.volts",
            f"net x-cmd hold.out => pid.0.command {g}.command",
            "setp hold.value 0.0",
            "setp pid.0.enable 1",
            *(f"setp pid.0.{k} {v!r}" for k, v in previous.items()),
            f"addf {plant_name} servo-thread",
            "addf cnt2f servo-thread",
            "addf fb servo-thread",
            "addf hold servo-thread",
            "addf pid.0.do-pid-calcs servo-thread",
            f"addf {g} servo-thread",
            "start",
            "loadusr -w touch ready",
            "loadusr -w sh wait.sh",
            *after,
            "",
        ]
    )


@contextlib.contextmanager
def machine(
    workdir: Path,
    plant_name: str,
    after: tuple[str, ...] = (),
    fb_sign: float = 1.0,
    previous: dict[str, float] = PREVIOUS,
    guard: str = "servotune_guard",
) -> Iterator[Session]:
    """The machine's HAL session running (as the HAL user) for the block: servotune, run in
    the block as root, reaches it with ``--hal-user`` (``RTAPI_FIFO_PATH`` set to the
    session's). After the block the session prints ``after`` (halcmd lines) and ends;
    :attr:`Session.result` is its output then."""
    ready, done = workdir / "ready", workdir / "done"
    ready.unlink(missing_ok=True)
    done.unlink(missing_ok=True)
    (workdir / "wait.sh").write_text("while [ ! -e done ]; do sleep 0.1; done\n")
    text = script(plant_name, after=after, fb_sign=fb_sign, previous=previous, guard=guard)
    session = Session()

    def run() -> None:
        try:
            session.result = halrun.run_hal(text, workdir, timeout=900.0)
        except BaseException as exc:  # reported by the block's end
            session.error = exc

    old = os.environ.get("RTAPI_FIFO_PATH")
    os.environ["RTAPI_FIFO_PATH"] = str(workdir / ".rtapi_fifo")
    th = threading.Thread(target=run, daemon=True)
    th.start()
    try:
        end = time.monotonic() + 300.0
        while not ready.exists():
            if not th.is_alive() or time.monotonic() > end:
                raise AssertionError(f"the HAL session did not start: {session.error}")
            time.sleep(0.1)
        yield session
    finally:
        done.touch()
        th.join(timeout=600.0)
        if old is None:
            os.environ.pop("RTAPI_FIFO_PATH", None)
        else:
            os.environ["RTAPI_FIFO_PATH"] = old
    if session.error is not None:
        raise session.error


@dataclasses.dataclass
class Session:
    result: subprocess.CompletedProcess | None = None
    error: BaseException | None = None


def hal_user_args() -> list[str]:
    """``--hal-user`` where the tests run as root (the session is the HAL user's)."""
    return ["--hal-user", halrun.HAL_USER] if os.geteuid() == 0 else []


def pin_values(text: str) -> dict[str, str]:
    """Pin name → value as ``show pin`` prints them."""
    out = {}
    for line in text.splitlines():
        f = line.split()
        if len(f) >= 5 and f[1] in ("bit", "float", "s32", "u32") and f[2] in ("IN", "OUT", "I/O"):
            out[f[4]] = f[3]
    return out
