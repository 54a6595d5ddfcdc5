"""The live autotune run in a running HAL session (docs/autotune.md#the-live-run).

:func:`run_autotune` is ``servotune autotune CONFIG`` without ``--dry-run``. It works on a
session the machine's own configuration started, with the safety envelope's component (the
guard, :func:`servotune.export.hal_component.guard_component`) already between the stock
``pid``'s output and the D/A driver, and changes it only through ``halcmd``
(:class:`servotune.io.halcmd.Halcmd`):

1. **take over**: the pid's pins as they are (restored at the end whatever happens), a
   ``streamer`` (two channels: the position command, the excitation in volts into the guard's
   ``excitation``) and a ``sampler`` (feedback, the guard's output, command, excitation, the
   sampler's overruns, the guard's fault), the command pin (and the guard's) moved from its
   signal to the streamer's, which holds the position the axis was commanded to;
2. **wiring check**, open loop (every pid gain 0): one pulse each way
   (:data:`servotune.autotune.PULSE_S`); the feedback must move with the output, by the model's
   ``gain · volts · length`` within a factor :data:`SCALE_FACTOR` (a reversed encoder or output,
   or a feedback scale off by more, stops here, before any closed-loop motion);
3. **experiment**: the plan's excitation (:func:`servotune.autotune.plan_autotune`) added to
   the loop closed by the lock module's gain as a pid ``Pgain``, captured with ``halsampler``
   into ``capture.txt`` (with its map ``capture.map.toml``: ``servotune fit`` reads the two);
4. **fit → tune → verify → export**: ``fit`` of the capture into ``fitted-rig.toml``, ``tune``
   of that rig against the spec (``tuning.json``), ``verify`` (its record beside it), the
   stock pid's parameters (``pid.hal``);
5. **load and validate**: the parameters set with ``halcmd setp``, then a move out and back
   (:func:`validation_move`) whose measured following error is compared with the prediction
   of the verified model (:func:`servotune.sim.linuxcnc_pid.simulate_pid_loop` on the fitted
   plant and the recorded command): a mismatch beyond :data:`TOLERANCE` restores the
   previous parameters; with ``target = "component"`` the verified runtime component is built,
   loaded before the guard and switched in instead, held to the engine's run of its law
   (:mod:`servotune.autotune_component`), and removed on a mismatch;
6. **record** (``autotune.json``): every file's SHA-256 (capture, map, fitted rig, tuning,
   verification record, pid file, the component's source), the pins before and after, the
   wiring check's and the validation's numbers.

The guard checks the envelope every servo period in the real-time thread; when it trips (its
output held at 0 from that period), the run stops, restores the previous parameters, and says
which limit was hit, with its value and the period. SIGINT and SIGTERM end the run the same
way, with the guard tripped by its ``stop`` pin (output 0). Any stop is an
:class:`~servotune.errors.AutotuneStopped`, one line.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from servotune._version import __version__
from servotune.autotune import (
    PULSE_S,
    AutotuneConfig,
    AutotunePlan,
    check_session,
    plan_autotune,
)
from servotune.autotune_component import (
    ComponentSwitch,
    Predict,
    attempt_each,
    component_prediction,
    install_component,
)
from servotune.digest import bytes_sha256
from servotune.errors import AutotuneStopped, ConfigError
from servotune.io.files import atomic_write_bytes, atomic_write_text
from servotune.io.halcmd import Halcmd
from servotune.laws.linuxcnc_pid import HAL_PIN_NAMES, PidParameters, thread_period_ns

__all__ = [
    "GUARD_REASONS",
    "SCALE_FACTOR",
    "TOLERANCE",
    "AutotuneResult",
    "format_result",
    "run_autotune",
    "validation_move",
    "whole_periods",
]

SCALE_FACTOR = 20.0
"""The wiring check's pulses must move the feedback by the model's travel within this factor
either way: a feedback scale off by more (a unit mistaken: mm for inch, units for counts)
stops the run; a drive gain off by less (10×) is the real-time guard's to stop."""
SETTLE_S = 0.4
"""Hold after each pulse and at each end of a phase [s]."""
VALIDATION_SHARE = 0.2
"""The validation move's length: this share of the smaller side of the travel window."""
TOLERANCE = {"following_error": (0.25, 5.0), "overshoot": (0.25, 5.0)}
"""Measured vs predicted in the validation move: (relative, absolute [counts]) allowances for
the largest |following error| and the overshoot past the move's end: ``|m − p| ≤ rel·|p| +
abs``."""
GUARD_REASONS = {1: "travel", 2: "speed", 3: "following error", 4: "output", 5: "stop"}
GUARD_UNITS = {1: "counts", 2: "counts/s", 3: "counts", 4: "V", 5: ""}
CHANNELS = (
    ("feedback", "f"),
    ("volts", "f"),
    ("command", "f"),
    ("excitation", "f"),
    ("overruns", "s"),
    ("fault", "b"),
)
"""The sampler's channels in order, each with its type (``cfg`` letter): the feedback [machine
units], the guard's output [V], the command [machine units], the excitation [V], the sampler's
overruns, the guard's fault. A phase's rows (``halsampler -t``): the sample number, then these
(:data:`COLUMN`); the record names them (``capture_channels``)."""
SAMPLER_PIN = {name: f"sampler.0.pin.{k}" for k, (name, _) in enumerate(CHANNELS)}
COLUMN = {name: k + 1 for k, (name, _) in enumerate(CHANNELS)}
_SIG = "servotune-at-"


@dataclass(slots=True)
class AutotuneResult:
    """What a run loaded and measured, filled step by step (the record, ``autotune.json``);
    ``stopped``: why it stopped (empty: it loaded and validated ``loaded``)."""

    out_dir: Path
    loaded: dict[str, Any]
    previous: dict[str, str]
    wiring: dict[str, float]
    validation: dict[str, Any]
    files: dict[str, str]
    seconds: dict[str, float] = field(default_factory=dict)
    fit: dict[str, Any] = field(default_factory=dict)
    stopped: str = ""
    period_s: float = 0.0
    position_scale: float = 1.0

    def to_dict(self) -> dict[str, Any]:
        """The record (``autotune.json``) as a dict."""
        return {
            "schema": "servotune.autotune/1",
            "servotune": __version__,
            "status": "stopped" if self.stopped else "loaded",
            "period_s": self.period_s,
            "position_scale": self.position_scale,
            "capture_channels": [name for name, _ in CHANNELS],
            "stopped": self.stopped,
            "files_sha256": self.files,
            "previous": self.previous,
            "loaded": self.loaded,
            "wiring_check": self.wiring,
            "fit": self.fit,
            "validation": self.validation,
            "seconds": self.seconds,
        }


def format_result(res: AutotuneResult) -> str:
    """What the run prints when it has loaded the new parameters."""
    w, v = res.wiring, res.validation
    lines = [
        f"autotune: loaded and validated; files in {res.out_dir}",
        f"  wiring check: the feedback moved {w['ratio']:.3g} times the model's travel, "
        "with the output's sign",
        f"  fit: gain {res.fit['params']['gain_cps_per_v']:.6g} counts/s/V, tau "
        f"{res.fit['params']['tau_s']:.4g} s (velocity fit {res.fit['velocity_fit_pct']:.1f} %)",
        "  loaded: " + ", ".join(f"{k} {res.loaded[k]:.6g}" for k in ("Pgain", "Igain", "FF1")),
    ]
    for key in TOLERANCE:
        m, p = v["measured"][key], v["predicted"][key]
        lines.append(f"  validation {key.replace('_', ' ')}: {m:.1f} counts (predicted {p:.1f})")
    lines.append(
        f"  machine time {res.seconds['machine_s']:.1f} s, wall time {res.seconds['total_s']:.1f} s"
    )
    return "\n".join(lines)


class _Takeover:
    """The run's changes to the session and their undoing (module docstring, step 1)."""

    def __init__(self, hal: Halcmd, cfg: AutotuneConfig, guard: str, depth: int, out: Path) -> None:
        self.hal, self.cfg, self.guard, self.depth, self.out = hal, cfg, guard, depth, out
        self.pid = cfg.hal.output_pin.rsplit(".", 1)[0]
        self.previous: dict[str, str] = {}
        self.links: dict[str, str | None] = {}
        self.loaded: list[str] = []
        self.signals: list[str] = []
        self.base = 0.0
        self.last_capture = ""
        self.component: ComponentSwitch | None = None
        self.kept = False

    def pins(self) -> list[str]:
        return [f"{self.pid}.{n}" for n in HAL_PIN_NAMES.values()]

    def install(self) -> None:
        hal, h, g = self.hal, self.cfg.hal, self.guard
        for pin in self.pins():
            self.previous[pin] = hal.getp(pin)
        session = hal.session()
        for pin in (h.command_pin, f"{g}.command", f"{g}.excitation"):
            self.links[pin] = session.pins[pin].signal
        self.base = hal.get_float(h.command_pin)
        samples = "".join(kind for _, kind in CHANNELS)
        for mod, cfg in (("streamer", "ff"), ("sampler", samples)):
            hal("loadrt", mod, f"depth={self.depth}", f"cfg={cfg}")
            self.loaded.append(mod)
        hal.setp("sampler.0.enable", False)
        hal("addf", "streamer.0", h.thread, "1")
        hal("addf", "sampler.0", h.thread)
        self._play_rows(np.full(4, self.base), np.zeros(4))  # the streamer holds the base
        self._wait_empty(2.0)
        taps = {
            "feedback": h.feedback_pin,
            "volts": f"{g}.volts-out",
            "overruns": "sampler.0.overruns",
            "fault": f"{g}.fault",
        }
        for name, src in taps.items():
            sig = session.pins[src].signal if src in session.pins else None
            if sig is None:
                sig = _SIG + name
                hal("net", sig, src)
                self.signals.append(sig)
            hal("net", sig, SAMPLER_PIN[name])
        for pin in self.links:
            if self.links[pin] is not None:
                hal("unlinkp", pin)
        hal("net", _SIG + "command", "streamer.0.pin.0", h.command_pin, f"{g}.command")
        hal("net", _SIG + "command", SAMPLER_PIN["command"])
        hal("net", _SIG + "excitation", "streamer.0.pin.1", f"{g}.excitation")
        hal("net", _SIG + "excitation", SAMPLER_PIN["excitation"])
        self.signals += [_SIG + "command", _SIG + "excitation"]

    def set_pid(self, params: PidParameters) -> None:
        """Load ``params``, bumpless: the pid's error integral (which it keeps summing even
        with ``Igain`` 0) clamped to ~0 for a few periods first by a tiny ``maxerrorI``, so
        that a new ``Igain`` does not multiply the integral of the previous loop's error."""
        self.hal.setp(f"{self.pid}.maxerrorI", 1e-12)
        time.sleep(4 * self.cfg.hal.period_s)
        for suffix, value in params.hal_pins():
            self.hal.setp(f"{self.pid}.{suffix}", value)

    def restore_pid(self) -> None:
        for pin, value in self.previous.items():
            self.hal("setp", pin, value)

    def undo(self) -> list[str]:
        """Every change undone that can be (each step tried, :func:`attempt_each`); the steps
        that failed."""
        failed: list[str] = []
        if self.component is not None and not self.kept:
            failed += self.component.remove()
        pins = (*self.links, *(SAMPLER_PIN[n] for n in ("feedback", "volts", "overruns")))
        steps: list[tuple[str, ...]] = [("unlinkp", pin) for pin in pins]
        steps += [("net", sig, pin) for pin, sig in self.links.items() if sig is not None]
        for mod in reversed(self.loaded):
            steps += [("delf", f"{mod}.0", self.cfg.hal.thread), ("unloadrt", mod)]
        steps += [("delsig", sig) for sig in self.signals]
        return failed + attempt_each(self.hal, steps)

    def _play_rows(self, command: np.ndarray, excitation: np.ndarray) -> None:
        rows = "".join(
            f"{float(c)!r} {float(e)!r}\n" for c, e in zip(command, excitation, strict=True)
        )
        self.hal.stream(rows, timeout=60.0)

    def _wait_empty(self, timeout_s: float) -> None:
        """Until the streamer has played every row, or the guard has tripped."""
        end = time.monotonic() + timeout_s
        while int(self.hal.getp("streamer.0.curr-depth")) > 0:
            if self.hal.get_bit(f"{self.guard}.fault"):
                self.hal.setp("streamer.0.enable", False)
                return
            if time.monotonic() > end:
                raise AutotuneStopped("the streamer did not play its rows: does the thread run?")
            time.sleep(0.05)

    def play(
        self,
        phase: str,
        command: np.ndarray,
        excitation: np.ndarray,
        params: PidParameters | Callable[[], None] | None = None,
    ) -> np.ndarray:
        """Play one phase (command [units], excitation [V], one per period) and return the
        sampler's records of it (columns :data:`COLUMN`, the sample number first);
        ``params``: loaded into the pid (or, a function, called) once the sampler records
        (what they do is captured)."""
        hal = self.hal
        hal.setp("sampler.0.enable", True)
        stale = int(hal.getp("sampler.0.curr-depth"))
        if stale:
            hal.sample(stale)  # what it held from before: not this phase's
        if callable(params):
            params()
        elif params is not None:
            self.set_pid(params)
        self._play_rows(command, excitation)
        seconds = command.size * self.cfg.hal.period_s
        self._wait_empty(seconds + 30.0)
        time.sleep(4 * self.cfg.hal.period_s)
        hal.setp("sampler.0.enable", False)
        lines = hal.sample(int(hal.getp("sampler.0.curr-depth"))).splitlines()
        # the sampler counts on while disabled: halsampler marks that gap ("overrun") where
        # this phase's records begin; nothing is lost within a phase (the FIFO holds it all)
        gaps = [k for k, ln in enumerate(lines) if not ln[:1].isdigit()]
        lines = lines[gaps[-1] + 1 :] if gaps else lines
        text = "".join(ln + "\n" for ln in lines)
        self.last_capture = text
        atomic_write_text(self.out / (phase.replace(" ", "-") + ".txt"), text)
        rec = np.loadtxt(text.splitlines(), ndmin=2)
        self.check_guard(phase, rec)
        return rec

    def check_guard(self, phase: str, rec: np.ndarray) -> None:
        if not self.hal.get_bit(f"{self.guard}.fault"):
            return
        reason = int(self.hal.getp(f"{self.guard}.reason"))
        value = self.hal.get_float(f"{self.guard}.value")
        tripped = np.flatnonzero(rec[:, COLUMN["fault"]] > 0.5) if rec.size else np.array([])
        when = (
            f"{tripped[0] * self.cfg.hal.period_s:.3f} s into the {phase}"
            if tripped.size
            else f"in the {phase}"
        )
        raise AutotuneStopped(
            f"the guard tripped on {GUARD_REASONS.get(reason, reason)} "
            f"({value:.6g} {GUARD_UNITS.get(reason, '')}) {when}; its output is held at 0 "
            f"(setp {self.guard}.reset to release) and the previous parameters are restored"
        )


def _zero_gains() -> PidParameters:
    return PidParameters(Pgain=0.0, error_previous_target=False)


def _wiring_check(t: _Takeover, cfg: AutotuneConfig, volts: float) -> dict[str, float]:
    """Step 2 (module docstring): one pulse each way, open loop."""
    rig, h = cfg.rig, cfg.hal
    plant = rig.axis(cfg.axis).plant
    n_pulse = max(1, round(PULSE_S / h.period_s))
    n_settle = round((SETTLE_S + 5 * plant.tau_s) / h.period_s)
    pulse, rest = np.full(n_pulse, volts), np.zeros(n_settle)
    exc = np.concatenate([rest, pulse, rest, -pulse, rest])
    rec = t.play("wiring check", np.full(exc.size, t.base), exc, _zero_gains())
    pos = rec[:, COLUMN["feedback"]] * h.position_scale
    applied = rec[:, COLUMN["excitation"]]
    first = np.flatnonzero(applied > 0.5 * volts)
    second = np.flatnonzero(applied < -0.5 * volts)
    if not (first.size and second.size):
        raise AutotuneStopped("wiring check: the pulses did not reach the sampler")
    before, mid, end = pos[max(first[0] - 1, 0)], pos[second[0] - 1], pos[-1]
    expected = plant.mean_gain_cps_per_v * volts * n_pulse * h.period_s
    up, down = mid - before, end - mid
    ratio = 0.5 * (up - down) / expected
    out = {"volts": volts, "expected_counts": expected, "up_counts": up, "down_counts": down}
    out["ratio"] = ratio
    if up * down > 0 or ratio <= 0:
        raise AutotuneStopped(
            f"wiring check: the feedback moved {up:+.0f} counts for a {volts:+.3g} V pulse and "
            f"{down:+.0f} for {-volts:+.3g} V, where the model expects {expected:+.0f} and "
            f"{-expected:+.0f}: the feedback's sign is reversed (encoder or output); nothing "
            "ran in closed loop"
        )
    if not 1 / SCALE_FACTOR <= ratio <= SCALE_FACTOR:
        raise AutotuneStopped(
            f"wiring check: the feedback moved {ratio:.3g} times the model's {expected:.0f} "
            f"counts per pulse (scale {h.position_scale:g} counts per unit): a scale or gain "
            f"off by more than {SCALE_FACTOR:g}x; nothing ran in closed loop"
        )
    return out


def validation_move(cfg: AutotuneConfig, scale: float = 1.0) -> np.ndarray:
    """The validation move [counts, relative to the start], one value per period: out by
    :data:`VALIDATION_SHARE` of the window's smaller side (towards the larger) at a third of
    the envelope's speed, a dwell, and back, each end held; ``scale`` shrinks distance and
    speed."""
    env, dt = cfg.envelope, cfg.hal.period_s
    lo, hi = env.travel_counts
    sign = 1.0 if hi >= -lo else -1.0
    dist = VALIDATION_SHARE * min(-lo, hi) * scale
    speed = env.speed_cps / 3.0 * scale
    ramp = max(dist / speed, 10 * dt)
    n_ramp = math.ceil(ramp / dt)
    s = 0.5 - 0.5 * np.cos(np.pi * np.arange(1, n_ramp + 1) / n_ramp)  # smooth, no jerk step
    hold = np.ones(round(SETTLE_S / dt) * 2)
    path = np.concatenate([np.zeros(25), s, hold, 1 - s, 0 * hold])
    return sign * dist * path


def _prediction(cfg: AutotuneConfig, plant: Any, params: PidParameters, command: np.ndarray):
    from servotune.sim.linuxcnc_pid import simulate_pid_loop

    h, rig = cfg.hal, cfg.rig
    return simulate_pid_loop(
        params,
        replace(plant, noise_counts=0.0),
        rig.period_s,
        command,
        position_scale=h.position_scale,
        compute_s=rig.timer.compute_s,
        period_ns=thread_period_ns(h.period_s),
    )


def _move_metrics(command_counts: np.ndarray, position_counts: np.ndarray) -> dict[str, float]:
    fe = command_counts - position_counts
    target = command_counts[np.argmax(np.abs(command_counts - command_counts[0]))]
    sign = np.sign(target - command_counts[0]) or 1.0
    past = sign * (position_counts - target)
    return {"following_error": float(np.abs(fe).max()), "overshoot": float(max(past.max(), 0.0))}


def _pid_prediction(cfg: AutotuneConfig, plant: Any, params: PidParameters) -> Predict:
    s = cfg.hal.position_scale

    def predict(rel_units: np.ndarray, start_counts: float) -> dict[str, np.ndarray]:
        pred = _prediction(cfg, plant, params, rel_units)  # from rest at the start
        return {
            "command_counts": pred.command_units * s,
            "feedback_counts": pred.feedback_units * s,
            "volts": pred.volts,
            "error_counts": pred.error_units * s,
        }

    return predict


def _validate(
    t: _Takeover,
    cfg: AutotuneConfig,
    predict: Predict,
    load: PidParameters | Callable[[], None],
) -> dict[str, Any]:
    """Step 5's move and comparison (module docstring); ``load`` what ``play`` loads."""
    h, env = cfg.hal, cfg.envelope
    s = h.position_scale
    for k in range(6):  # shrink the move until the prediction stays well inside the envelope
        rel = validation_move(cfg, 0.7**k)
        pred = predict(rel / s, 0.0)
        peak_v = float(np.abs(pred["volts"]).max())
        peak_fe = float(np.abs(pred["error_counts"]).max())
        if peak_v <= 0.7 * env.max_volts and peak_fe <= 0.7 * env.following_error_counts:
            break
    rec = t.play("validation move", t.base + rel / s, np.zeros(rel.size), load)
    command, feedback = rec[:, COLUMN["command"]] - t.base, rec[:, COLUMN["feedback"]] - t.base
    moving = np.flatnonzero(np.abs(command) * s > 0.5)
    start = max(int(moving[0]) - 25, 0) if moving.size else 0
    meas_cmd, meas_pos = command[start:] * s, feedback[start:] * s
    # the model's run on the command as the controller received it, from the start
    pred = predict(command[start:], float(meas_pos[0]))
    measured = _move_metrics(meas_cmd, meas_pos)
    predicted = _move_metrics(pred["command_counts"], pred["feedback_counts"])
    rows = np.column_stack(
        [np.arange(meas_cmd.size) * h.period_s, meas_cmd, meas_pos, pred["feedback_counts"]]
    )
    atomic_write_text(
        t.out / "validation.csv",
        "time_s,command_counts,measured_counts,predicted_counts\n"
        + "".join(",".join(f"{v:.6f}" for v in r) + "\n" for r in rows),
    )
    out: dict[str, Any] = {"measured": measured, "predicted": predicted, "tolerance": TOLERANCE}
    bad = [
        f"{key.replace('_', ' ')} {measured[key]:.1f} counts against {predicted[key]:.1f} "
        f"predicted (allowed ±{rel * abs(predicted[key]) + ab:.1f})"
        for key, (rel, ab) in TOLERANCE.items()
        if abs(measured[key] - predicted[key]) > rel * abs(predicted[key]) + ab
    ]
    out["passed"] = not bad
    out["problems"] = bad
    return out


PRINT_RESOLUTION = 1e-6
"""halsampler prints floats with 6 decimals: a played value and its record differ by less."""


def whole_periods(capture: str, rec: np.ndarray, excitation: np.ndarray) -> str:
    """The rows of ``capture`` (``rec``: its numbers) that recorded ``excitation`` [V], the
    experiment's periodic part: found in the excitation column by its values (the sampler
    starts before the streamer's first row, by a number of periods that varies).

    Raises
    ------
    AutotuneStopped
        The capture does not hold the excitation as played (rows lost).
    """
    x = rec[:, COLUMN["excitation"]]
    n = excitation.size
    for k in np.flatnonzero(np.abs(x - excitation[0]) <= PRINT_RESOLUTION):
        if k + n <= x.size and np.all(np.abs(x[k : k + n] - excitation) <= PRINT_RESOLUTION):
            lines = capture.splitlines(keepends=True)
            return "".join(lines[k : k + n])
    raise AutotuneStopped(
        "the experiment's capture does not hold the excitation as it was played (rows lost?): "
        "no frequency response; the previous parameters are restored"
    )


def _identify(cfg: AutotuneConfig, out: Path, capture: str, say: Callable[[str], None]):
    """Step 4 (module docstring): the capture's files, fit, tune, verify, export."""
    from servotune.export.linuxcnc import pid_hal_text, pid_parameters
    from servotune.identify.logfit import fit_log
    from servotune.io.hal_map import hal_settings
    from servotune.rig import load_rig, write_plant
    from servotune.tune.slave import tune_spec_from
    from servotune.tune.workflow import tune_rig
    from servotune.tuning import write_tuning
    from servotune.verify.record import load_for_export, verify_files
    from servotune.verify.spec import load_spec

    h = cfg.hal
    atomic_write_text(out / "capture.txt", capture)
    mapping = {
        "pos": "feedback",
        "cmd": "volts",
        "ref": "command",
        "exc": "excitation",
        "overruns": "overruns",
    }
    columns = [name for name, _ in CHANNELS]
    map_text = (
        "# the autotune capture's columns: servotune fit capture.txt --map capture.map.toml\n"
        f'[hal]\nformat = "halsampler"\nperiod_s = {cfg.rig.period_s!r}\n'
        f"position_scale = {h.position_scale!r}\noutput_scale = 1.0\nsample_number = true\n"
        f"columns = {json.dumps(columns)}\n"
        "[hal.map]\n" + "".join(f'{k} = "{v}"\n' for k, v in mapping.items())
    )
    atomic_write_text(out / "capture.map.toml", map_text)
    say("autotune: fit the capture")
    settings = hal_settings(str(out / "capture.map.toml"))  # as the by-hand fit reads it
    result, _, _ = fit_log(
        out / "capture.txt", axis=cfg.axis, rig=cfg.rig, hal=settings, modes=cfg.modes
    )
    fitted = out / "fitted-rig.toml"
    write_plant(
        fitted,
        cfg.axis,
        result.plant,
        template=cfg.rig_path,
        provenance="fitted by servotune autotune from capture.txt",
        fit=result.plant_fit,
    )
    assert cfg.spec_path is not None  # run_autotune checked it
    say("autotune: tune the fitted rig")
    tuning = tune_rig(fitted, seed=0, spec=tune_spec_from(load_spec(cfg.spec_path)))
    tuning_path = out / "tuning.json"
    write_tuning(tuning, tuning_path)
    say("autotune: verify")
    verification, _, _ = verify_files(tuning_path, cfg.spec_path)
    if not verification.passed:
        raise AutotuneStopped(
            "the new tuning failed verification against the spec (tuning.json's record says "
            "which check); nothing was loaded"
        )
    v = load_for_export(tuning_path, spec_path=cfg.spec_path)
    pid_name = h.output_pin.rsplit(".", 1)[0]
    text = pid_hal_text(
        v.tuning,
        position_scale=h.position_scale,
        rig=v.rig,
        verification=v.record,
        pid_name=pid_name,
    )
    atomic_write_text(out / "pid.hal", text)
    if cfg.target == "component":
        from servotune.export.hal_component import to_string as component_text

        source = component_text(
            v.tuning,
            rig=v.rig,
            verification=v.record,
            name=cfg.component,
            position_scale=h.position_scale,
        )
        atomic_write_text(out / f"{cfg.component}.comp", source)
    params = pid_parameters(v.tuning, v.rig, position_scale=h.position_scale)
    return result, load_rig(fitted).axis(cfg.axis).plant, params, v


def run_autotune(
    cfg: AutotuneConfig,
    out_dir: str | Path,
    *,
    guard: str = "servotune-guard",
    hal_user: str | None = None,
    say: Callable[[str], None] = lambda _: None,
) -> AutotuneResult:
    """The live run (module docstring), its files written into ``out_dir``; ``guard`` the
    guard's HAL name, ``hal_user`` the session's owner where servotune runs as root
    (:class:`~servotune.io.halcmd.Halcmd`). The record ``autotune.json`` and the report
    ``autotune.html`` are written whether the run loads its parameters or stops.

    Raises
    ------
    HalError
        No session, or a command it refused.
    ConfigError
        The config does not fit the session (:func:`servotune.autotune.check_session`), no
        guard between the pid and the D/A.
    AutotuneStopped
        The run stopped (module docstring): the previous parameters are back.
    """
    out = Path(out_dir)
    if cfg.spec_path is None:
        raise ConfigError(f"{cfg.path}: autotune.spec is needed for a live run (what to verify)")
    hal = Halcmd(user=hal_user)
    session = hal.session()
    if not session.pins:
        raise ConfigError("no HAL session runs here (start the machine's HAL first)")
    check_session(cfg, session)
    _check_guard(cfg, session, guard)
    plan = plan_autotune(cfg)
    depth = plan.excitation_codes.size + 4 * round(SETTLE_S / cfg.hal.period_s) + 4096
    out.mkdir(parents=True, exist_ok=True)
    t = _Takeover(hal, cfg, guard, depth, out)
    res = AutotuneResult(
        out_dir=out,
        loaded={},
        previous={},
        wiring={},
        validation={},
        files={},
        period_s=cfg.hal.period_s,
        position_scale=cfg.hal.position_scale,
    )
    t0 = time.monotonic()
    try:
        try:
            _steps(t, cfg, plan, res, say)
        except BaseException as exc:
            res.stopped = str(exc) or type(exc).__name__
            try:
                if not isinstance(exc, AutotuneStopped):  # a signal, HAL's error: output 0 first
                    _trip(hal, guard, cfg.hal.period_s)
            finally:
                t.restore_pid()
            raise
        finally:
            failed = t.undo()
            res.previous.update(t.previous)
            if failed and not res.stopped:
                res.stopped = "could not restore the session: " + "; ".join(failed)
                raise AutotuneStopped(res.stopped)
    finally:
        res.seconds["total_s"] = time.monotonic() - t0
        _write_record(res)
    return res


def _steps(
    t: _Takeover,
    cfg: AutotuneConfig,
    plan: AutotunePlan,
    res: AutotuneResult,
    say: Callable[[str], None],
) -> None:
    """Steps 1–5 (module docstring), their numbers into ``res`` as they come."""
    hal, guard, h, rig = t.hal, t.guard, cfg.hal, cfg.rig
    t0 = time.monotonic()
    say("autotune: take over the command and load streamer and sampler")
    t.install()
    hal.setp(f"{guard}.reset", True)
    time.sleep(4 * h.period_s)
    hal.setp(f"{guard}.reset", False)
    say(f"autotune: wiring check ({plan.pulse_volts:.3g} V pulses, open loop)")
    res.wiring.update(_wiring_check(t, cfg, plan.pulse_volts))
    start = PidParameters(
        Pgain=plan.lock_gain * rig.dac.lsb_v * h.position_scale,
        maxoutput=cfg.envelope.max_volts,
        error_previous_target=False,
    )
    hold = np.zeros(round(SETTLE_S / h.period_s))
    excitation = (plan.excitation_codes - rig.dac.zero_code) * rig.dac.lsb_v  # [V]
    exc_v = np.concatenate([hold, excitation, hold])
    say(f"autotune: experiment ({exc_v.size * h.period_s:.1f} s, closed loop)")
    rec = t.play("experiment", np.full(exc_v.size, t.base), exc_v, start)
    res.seconds["machine_s"] = time.monotonic() - t0
    capture = t.last_capture
    if cfg.periods is not None:  # the whole periods only: a frequency response needs them
        capture = whole_periods(capture, rec, excitation)
    result, plant, params, verified = _identify(cfg, t.out, capture, say)
    # the plant written (with modes: gain, tau and delay from the frequency-domain fit) and
    # its whole-log velocity fit, as fitted-rig.toml records them
    written_pct = result.plant_fit.velocity_fit_pct
    res.fit.update(
        params={k: float(getattr(result.plant, k)) for k in result.params},
        velocity_fit_pct=float(
            result.fit_pct["velocity"]["estimation"] if written_pct is None else written_pct
        ),
        modes=[m.to_dict() for m in plant.modes],
    )
    res.files.update(_digests(t.out, cfg))
    if cfg.target == "component":
        predict, load = _load_component(t, cfg, verified, say)
    else:
        predict, load = _pid_prediction(cfg, plant, params), params
    say("autotune: validation move")
    res.validation.update(_validate(t, cfg, predict, load))
    if not res.validation["passed"]:
        raise AutotuneStopped(
            "validation move: "
            + "; ".join(res.validation["problems"])
            + "; the previous parameters are restored"
        )
    if t.component is None:
        res.loaded.update(params.to_dict())
    else:  # the pid drives nothing now: its parameters as they were
        res.loaded.update(t.component.keep(t.links[h.command_pin]))
        t.kept = True
        t.restore_pid()


def _load_component(
    t: _Takeover, cfg: AutotuneConfig, verified: Any, say: Callable[[str], None]
) -> tuple[Predict, Callable[[], None]]:
    """The component target's step 5 before the move (:mod:`servotune.autotune_component`):
    built, installed, loaded before the guard; its prediction and its switch-in."""
    say(f"autotune: build and load the runtime component {cfg.component}")
    install_component(t.out / f"{cfg.component}.comp")
    session = t.hal.session()
    t.component = ComponentSwitch(
        hal=t.hal,
        cfg=cfg,
        guard=t.guard,
        index=verified.tuning.axis_names.index(cfg.axis),
        command_signal=_SIG + "command",
        pid_signal=session.pins[cfg.hal.output_pin].signal,
    )
    t.component.load()
    predict = component_prediction(cfg, verified, t.component.origin_counts, t.base)
    return predict, t.component.switch_in


RECORDED_FILES = (
    "capture.txt",
    "capture.map.toml",
    "fitted-rig.toml",
    "tuning.json",
    "tuning.json.verify.json",
    "pid.hal",
)
"""The files the record binds by their SHA-256."""


def _digests(out: Path, cfg: AutotuneConfig) -> dict[str, str]:
    names = list(RECORDED_FILES)
    if cfg.target == "component":
        names.append(f"{cfg.component}.comp")
    return {
        name: bytes_sha256((out / name).read_bytes()) for name in names if (out / name).exists()
    }


def _trip(hal: Halcmd, guard: str, period_s: float) -> None:
    """Trip the guard (its output 0 until ``reset``) by a pulse on its ``stop`` pin."""
    hal.setp(f"{guard}.stop", True)
    time.sleep(3 * period_s)
    hal.setp(f"{guard}.stop", False)


def _check_guard(cfg: AutotuneConfig, session: Any, guard: str) -> None:
    if not cfg.hal.output_pin.endswith(".output"):
        raise ConfigError(f"{cfg.path}: hal.output_pin must be a pid's output (pid.N.output)")
    need = ("volts-in", "volts-out", "excitation", "stop", "fault", "command", "position")
    missing = [p for p in need if f"{guard}.{p}" not in session.pins]
    if missing:
        raise ConfigError(
            f"no guard {guard!r} in the session (pins {', '.join(missing)} missing): load the "
            "component of autotune --guard-output between the pid and the D/A first"
        )
    out_sig = session.pins[cfg.hal.output_pin].signal
    if out_sig is None or session.pins[f"{guard}.volts-in"].signal != out_sig:
        raise ConfigError(
            f"the guard {guard!r} is not wired after the pid: {cfg.hal.output_pin} must drive "
            f"{guard}.volts-in (docs/autotune.md#the-safety-envelope)"
        )


def _write_record(res: AutotuneResult) -> None:
    """``autotune.json`` and its report ``autotune.html`` (:mod:`servotune.report.autotune`)."""
    from servotune.report.autotune import write_autotune_report

    text = json.dumps(res.to_dict(), indent=2, sort_keys=True, default=float) + "\n"
    atomic_write_bytes(res.out_dir / "autotune.json", text.encode())
    write_autotune_report(res.out_dir)
