"""The verified runtime loaded as the axis's controller: ``servotune autotune`` with
``target = "component"`` (docs/autotune.md#the-component-target).

After fit → tune → verify, the run exports the verified tuning as the servotune runtime
component (:func:`servotune.export.hal_component.to_string` with ``position_scale``: the
runtime's integer law with the tables compiled in, refusing to load unless their SHA-256 is the
exported one, its command a position in machine units as LinuxCNC gives it), builds and
installs it with ``halcompile --install`` (:func:`install_component`) and switches the axis
over to it (:class:`ComponentSwitch`):

1. **load**: ``loadrt`` the component, its function added to the servo thread just before the
   guard's (its output reaches the guard in the period it was computed, as the stock pid's
   did); its axis reads ``hal.counts_pin`` (the raw encoder count whose ``feedback_pin`` is
   ``counts / position_scale``) and its ``command`` the run's position command; it holds its
   position in lock mode for :data:`SETTLE_PERIODS`;
2. **switch in**: the guard's ``volts-in`` moved from the pid's output to the component's
   ``volts-N``, the axis put in task mode (bumpless: the law's integrator starts from its
   output);
3. the validation move runs through it, held to :func:`predicted_move`, the engine's run of the
   same law on the fitted rig;
4. **kept** (the move matched: its ``command`` then on the machine's command signal, as the
   pid's was), or **removed** (a mismatch, a trip, a signal): the guard's ``volts-in`` back on
   the pid's output, the function deleted, the component unloaded.
"""

from __future__ import annotations

import shutil
import subprocess
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from servotune.autotune import AutotuneConfig
from servotune.errors import AutotuneStopped
from servotune.io.halcmd import Halcmd, parse_thread_functions

__all__ = [
    "ComponentSwitch",
    "Predict",
    "attempt_each",
    "component_prediction",
    "install_component",
    "predicted_move",
]

SETTLE_PERIODS = 8
"""Periods the loaded component runs in lock before its origin is read and it is switched in."""


def attempt_each(hal: Halcmd, steps: Iterable[tuple[str, ...]]) -> list[str]:
    """Each halcmd step of ``steps`` run in ``hal``, every one tried whatever the others did
    (an undo does the rest regardless); the messages of the ones that failed, in order."""
    failed: list[str] = []
    for args in steps:
        try:
            hal(*args)
        except Exception as exc:  # undo the rest regardless; reported together
            failed.append(str(exc))
    return failed


def install_component(source: Path, timeout_s: float = 600.0) -> None:
    """Build and install the component ``source`` (``halcompile --install``, into LinuxCNC's
    module directory: root's right).

    Raises
    ------
    AutotuneStopped
        halcompile is missing or fails (its last message line).
    """
    exe = shutil.which("halcompile")
    if exe is None:
        raise AutotuneStopped(
            "halcompile is not installed (linuxcnc-uspace-dev): cannot build the component; "
            "nothing was loaded"
        )
    try:
        res = subprocess.run(
            [exe, "--install", source.name],
            cwd=source.parent,
            capture_output=True,
            timeout=timeout_s,
        )
    except subprocess.TimeoutExpired:
        raise AutotuneStopped(
            f"halcompile --install {source.name}: no end in {timeout_s:g} s"
        ) from None
    if res.returncode != 0:
        text = (res.stderr or res.stdout).decode(errors="replace").strip().splitlines()
        last = text[-1] if text else f"exit {res.returncode}"
        raise AutotuneStopped(
            f"halcompile --install {source.name} failed ({last}); nothing was loaded (install "
            f"it as root: halcompile --install {source})"
        )


def predicted_move(verified: Any, axis: str, ref_counts: np.ndarray) -> dict[str, np.ndarray]:
    """The engine's run of the verified tuning on its (fitted) rig, noiseless: the axis in
    task mode from rest on ``ref_counts`` (per period, relative to the start), every other
    axis in lock. Returns its ``feedback_counts`` (the counter's reading), ``volts`` and
    ``error_counts``."""
    from servotune.scenarios import Inputs
    from servotune.sim.engine import Loop, simulate

    rig = verified.rig
    axes = tuple(
        replace(a, plant=replace(a.plant, noise_counts=0.0)) if a.name == axis else a
        for a in rig.axes
    )
    rig = replace(rig, axes=axes)
    i = rig.axis_names.index(axis)
    ref = np.rint(np.asarray(ref_counts, dtype=float)).astype(np.int64)
    inputs = Inputs.hold(ref.size, len(axes)).replace_axis(i, ref_counts=ref, mode=1)
    trace = simulate(Loop(rig=rig, controllers=verified.tuning.controllers), inputs)
    return {
        "feedback_counts": trace.pos_counts[:, i].astype(float),
        "volts": trace.volts[:, i],
        "error_counts": trace.err_counts[:, i].astype(float),
    }


Predict = Callable[[np.ndarray, float], dict[str, np.ndarray]]
"""A validation move's prediction (for either target): from the command [units] and the
position at the start [counts], both relative to the axis's base, the predicted
``command_counts`` (as the controller receives it), ``feedback_counts`` (relative to the
base), ``volts`` and ``error_counts``."""


def component_prediction(
    cfg: AutotuneConfig, verified: Any, origin_counts: int, base: float
) -> Predict:
    """:func:`predicted_move` in the component's frame: positions from ``origin_counts`` (the
    count of its first period), the reference ``round(command · scale)`` minus it; ``base``
    [units] the position the run's commands are relative to."""
    s = cfg.hal.position_scale
    off = base * s - origin_counts  # the base in the component's frame

    def predict(rel_units: np.ndarray, start_counts: float) -> dict[str, np.ndarray]:
        rel_counts = rel_units * s
        y0 = round(start_counts + off)
        pred = predicted_move(verified, cfg.axis, np.rint(rel_counts + off) - y0)
        return {
            "command_counts": rel_counts,
            "feedback_counts": pred["feedback_counts"] + y0 - off,
            "volts": pred["volts"],
            "error_counts": pred["error_counts"],
        }

    return predict


@dataclass
class ComponentSwitch:
    """The runtime component's loading, switching in, keeping or removal (module docstring)
    in the session of ``hal``: ``index`` the axis's in the tuning, ``command_signal`` the
    signal of the run's position command, ``pid_signal`` the pid's output to the guard
    (restored on removal)."""

    hal: Halcmd
    cfg: AutotuneConfig
    guard: str
    index: int
    command_signal: str
    pid_signal: str | None
    loaded: bool = False
    signals: list[str] = field(default_factory=list)
    switched: bool = False
    origin_counts: int = 0

    @property
    def hal_name(self) -> str:
        return self.cfg.component.replace("_", "-")

    def load(self) -> None:
        """Step 1 (module docstring)."""
        hal, h, comp = self.hal, self.cfg.hal, self.hal_name
        assert h.counts_pin is not None  # the config requires it for this target
        functions = parse_thread_functions(hal("show", "thread", h.thread)).get(h.thread, [])
        if self.guard not in functions:
            raise AutotuneStopped(
                f"the guard {self.guard!r} is not in {h.thread}: cannot place the component "
                "before it; nothing was loaded"
            )
        hal("loadrt", self.cfg.component)
        self.loaded = True
        hal("addf", comp, h.thread, str(functions.index(self.guard) + 1))  # HAL counts from 1
        counts = hal.session().pins[h.counts_pin].signal
        if counts is None:
            counts = self._new_signal("counts")
        hal("net", counts, f"{comp}.counts-{self.index}")
        hal("net", self.command_signal, f"{comp}.command")
        time.sleep(SETTLE_PERIODS * h.period_s)
        # the count of its first period, where its positions start: count now − position now
        raw = int(hal.getp(h.counts_pin))
        self.origin_counts = raw - int(hal.getp(f"{comp}.position-{self.index}"))

    def switch_in(self) -> None:
        """Step 2 (module docstring)."""
        hal, comp = self.hal, self.hal_name
        hal("unlinkp", f"{self.guard}.volts-in")
        self.switched = True
        sig = self._new_signal("volts")
        hal("net", sig, f"{comp}.volts-{self.index}", f"{self.guard}.volts-in")
        hal("setp", f"{comp}.mode-{self.index}", "1")

    def keep(self, command_signal: str | None) -> dict[str, Any]:
        """Step 4, kept: the component's ``command`` on the machine's ``command_signal``
        (None: held at its last value); what was loaded, for the record."""
        comp = self.hal_name
        self.hal("unlinkp", f"{comp}.command")
        if command_signal is not None:
            self.hal("net", command_signal, f"{comp}.command")
        return {
            "component": self.cfg.component,
            "axis_index": self.index,
            "origin_counts": self.origin_counts,
            "counts_pin": self.cfg.hal.counts_pin,
            "before": self.guard,
        }

    def remove(self) -> list[str]:
        """Step 4, removed: every step tried (:func:`attempt_each`); the ones that failed."""
        steps: list[tuple[str, ...]] = []
        if self.switched:
            steps.append(("unlinkp", f"{self.guard}.volts-in"))
            if self.pid_signal is not None:
                steps.append(("net", self.pid_signal, f"{self.guard}.volts-in"))
        if self.loaded:
            steps.append(("delf", self.hal_name, self.cfg.hal.thread))
            steps.append(("unloadrt", self.cfg.component))
        steps += [("delsig", sig) for sig in self.signals]
        return attempt_each(self.hal, steps)

    def _new_signal(self, what: str) -> str:
        sig = f"{self.hal_name}-{what}"
        self.signals.append(sig)
        return sig
