"""Auto-tuning a live LinuxCNC axis: its config, the safety envelope, and the plan
(docs/autotune.md).

An autotune config (TOML) names the rig file whose axis model is the current one, the spec to
verify against, the HAL side (the servo thread and its period, the pins that carry the loop's
command, the feedback position, the controller's output and the enable, the feedback's scale in
counts) and the axis's **safety envelope** for the experiment: a travel window relative to
where the axis stands, a speed limit, a following-error limit and the largest output voltage.
:func:`load_autotune_config` reads and checks it: one line naming the key for a bad value, and
an envelope wider than the rig's own limits or a thread slower than the rig's period is
refused.

:func:`plan_autotune` is what ``servotune autotune CONFIG --dry-run`` prints, computed from the
current model alone and touching nothing: the wiring check's pulses, the experiment's
excitation (designed within the envelope by :func:`servotune.excite.design_excitation`, played
with the lock module's gain as the conservative starting loop, whose margins are checked
first), the motion the current model predicts for it (the engine's closed-loop run: largest
travel, speed and following error against the envelope), then fit → tune → verify → export and
the validation move.

The envelope is enforced in the real-time thread, not in Python: the component of
:func:`servotune.export.hal_component.guard_component` checks it every servo period and zeroes
the output in the period of a breach.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from servotune.errors import ConfigError
from servotune.io.files import read_toml
from servotune.io.halcmd import HalSession
from servotune.rig import Rig, load_rig
from servotune.validate import check_keys, check_number, show_value

__all__ = [
    "COMPONENT_NAME",
    "DEFAULT_PERIODS",
    "EXCITATION_KINDS",
    "OUTPUT_SHARE",
    "TARGETS",
    "AutotuneConfig",
    "AutotunePlan",
    "Envelope",
    "HalSide",
    "check_session",
    "format_plan",
    "load_autotune_config",
    "plan_autotune",
    "with_target",
]

TARGETS = ("pid", "component")
"""What the tuning is loaded as: the stock ``pid``'s parameters, or the verified component."""
EXCITATION_KINDS = ("multisine", "prbs", "steps")
PERIOD_TOLERANCE = 0.01
"""How far the thread's period may lie from the rig's achieved period (a timer's divisor
makes them differ slightly) [fraction]."""
PULSE_TRAVEL_SHARE = 0.01
"""The wiring check's pulse moves the axis by this share of the travel window (model)."""
PULSE_S = 0.1
"""Length of each wiring-check pulse [s]."""
_HAL_NAME = re.compile(r"[A-Za-z0-9_.\-]+")
COMPONENT_NAME = re.compile(r"[a-z][a-z0-9_]{0,40}")
"""A component's name as halcompile takes it (HAL calls it with ``_`` as ``-``)."""


@dataclass(frozen=True, slots=True)
class Envelope:
    """The experiment's safety envelope, in counts (the feedback times ``position_scale``).

    Attributes
    ----------
    travel_counts : (float, float)
        Travel window relative to the position at the start [counts], low < 0 < high.
    speed_cps : float
        Largest |speed| [counts/s].
    following_error_counts : float
        Largest |command − position| [counts].
    max_volts : float
        Largest |output| [V].
    """

    travel_counts: tuple[float, float]
    speed_cps: float
    following_error_counts: float
    max_volts: float


@dataclass(frozen=True, slots=True)
class HalSide:
    """The HAL pins and thread of the axis (names as ``halcmd show pin`` prints them)."""

    thread: str
    period_s: float
    command_pin: str
    feedback_pin: str
    output_pin: str
    enable_pin: str
    position_scale: float
    counts_pin: str | None = None


@dataclass(frozen=True, slots=True)
class AutotuneConfig:
    """A checked autotune config (module docstring)."""

    path: Path
    rig_path: Path
    rig: Rig
    axis: str
    spec_path: Path | None
    target: str
    excitation: str
    seconds: float
    hal: HalSide
    envelope: Envelope
    modes: int | str | None = None
    periods: int | None = None
    band_hz: tuple[float, float] | None = None
    component: str = "servotune_rt"


def _path(base: Path, v: object, key: str) -> Path:
    if not isinstance(v, str) or not v:
        raise ConfigError(f"{key} must be a file name, got {show_value(v)}")
    p = Path(v)
    return p if p.is_absolute() else base / p


def _pin(d: dict[str, Any], key: str) -> str:
    v = d[key]
    if not isinstance(v, str) or not _HAL_NAME.fullmatch(v):
        raise ConfigError(f"hal.{key} must be a HAL pin or thread name, got {show_value(v)}")
    return v


def _envelope(d: dict[str, Any], rig: Rig, axis: str) -> Envelope:
    d = check_keys(
        d,
        "envelope",
        ("travel_counts", "speed_cps", "following_error_counts", "max_volts"),
        error=ConfigError,
    )
    t = d["travel_counts"]
    ok = isinstance(t, list) and len(t) == 2
    ok = ok and all(isinstance(x, int | float) and not isinstance(x, bool) for x in t)
    if not ok or not (math.isfinite(t[0]) and math.isfinite(t[1]) and t[0] < 0 < t[1]):
        raise ConfigError(
            f"envelope.travel_counts must be [low, high] with low < 0 < high [counts, from the "
            f"start position], got {show_value(t)}"
        )
    for key, unit in (("speed_cps", "counts/s"), ("following_error_counts", "counts")):
        check_number(f"envelope.{key}", d[key], unit, strict=True, error=ConfigError)
    check_number("envelope.max_volts", d["max_volts"], "V", strict=True, error=ConfigError)
    ax = rig.axis(axis)
    speed_limit = ax.speed_limit_rpm / 60.0 * rig.counts_per_rev
    wider = []
    if d["speed_cps"] > speed_limit:
        wider.append(f"speed_cps {d['speed_cps']:g} > the axis's limit {speed_limit:g} counts/s")
    if ax.travel_counts is not None and t[1] - t[0] > ax.travel_counts[1] - ax.travel_counts[0]:
        span = ax.travel_counts[1] - ax.travel_counts[0]
        wider.append(f"travel {t[1] - t[0]:g} counts > the axis's travel {span} counts")
    fe = ax.following_error_limit_counts
    if fe and d["following_error_counts"] > fe:
        wider.append(f"following_error_counts {d['following_error_counts']:g} > the axis's {fe}")
    half = 0.5 * (rig.dac.range_v[1] - rig.dac.range_v[0])
    if d["max_volts"] > half:
        wider.append(f"max_volts {d['max_volts']:g} > the D/A's ±{half:g} V")
    if wider:
        raise ConfigError(f"envelope is wider than rig {axis!r} allows: {'; '.join(wider)}")
    return Envelope(
        travel_counts=(float(t[0]), float(t[1])),
        speed_cps=float(d["speed_cps"]),
        following_error_counts=float(d["following_error_counts"]),
        max_volts=float(d["max_volts"]),
    )


def _check_target(target: object, counts_pin: str | None) -> str:
    if target not in TARGETS:
        raise ConfigError(
            f"autotune.target must be one of {', '.join(TARGETS)}, got {show_value(target)}"
        )
    if target == "component" and counts_pin is None:
        raise ConfigError(
            'hal.counts_pin is needed for target = "component": the raw encoder count (an s32 '
            "pin) the runtime component reads, with feedback_pin = counts / position_scale"
        )
    return str(target)


def with_target(cfg: AutotuneConfig, target: str) -> AutotuneConfig:
    """``cfg`` with another ``target`` (``autotune --target``), checked as the file's.

    Raises
    ------
    ConfigError
        An unknown target, or ``component`` without ``hal.counts_pin``.
    """
    try:
        return replace(cfg, target=_check_target(target, cfg.hal.counts_pin))
    except ConfigError as exc:
        raise ConfigError(f"{cfg.path}: {exc}") from None


def load_autotune_config(path: str | Path) -> AutotuneConfig:
    """Read and check an autotune config (module docstring); file names in it are relative to
    its directory.

    Raises
    ------
    ConfigError
        One line naming the file and the key: a missing or unknown key, a bad value, a rig
        without the axis, a thread slower than the rig's period, an envelope wider than the
        rig's limits.
    """
    p = Path(path)
    doc = read_toml(p, ConfigError, "autotune config")
    try:
        return _config(p, doc)
    except ConfigError as exc:
        raise ConfigError(f"{p}: {exc}") from None


def _config(p: Path, doc: dict[str, Any]) -> AutotuneConfig:
    doc = check_keys(doc, "the config", ("autotune", "hal", "envelope"), error=ConfigError)
    a = check_keys(
        doc["autotune"],
        "autotune",
        ("rig", "axis"),
        ("spec", "target", "component", "excitation", "seconds", "modes", "periods", "band_hz"),
        error=ConfigError,
    )
    rig_path = _path(p.parent, a["rig"], "autotune.rig")
    try:
        rig = load_rig(rig_path)
    except Exception as exc:  # the rig's own one-line error, under this config's name
        raise ConfigError(f"autotune.rig: {exc}") from None
    axis = a["axis"]
    if axis not in rig.axis_names:
        raise ConfigError(
            f"autotune.axis must be one of the rig's axes ({', '.join(rig.axis_names)}), "
            f"got {show_value(axis)}"
        )
    target = a.get("target", "pid")
    component = a.get("component", "servotune_rt")
    if not isinstance(component, str) or not COMPONENT_NAME.fullmatch(component):
        raise ConfigError(
            "autotune.component must be a HAL component name (lower-case letters, digits and "
            f"_, starting with a letter, at most 41 characters), got {show_value(component)}"
        )
    kind = a.get("excitation", "multisine")
    if kind not in EXCITATION_KINDS:
        raise ConfigError(
            f"autotune.excitation must be one of {', '.join(EXCITATION_KINDS)}, "
            f"got {show_value(kind)}"
        )
    seconds = a.get("seconds", 40.0)
    check_number("autotune.seconds", seconds, "s", strict=True, hi=300.0, error=ConfigError)
    modes, periods, band = _frequency_response(a, rig, axis, kind)
    h = check_keys(
        doc["hal"],
        "hal",
        (
            "thread",
            "period_s",
            "command_pin",
            "feedback_pin",
            "output_pin",
            "enable_pin",
            "position_scale",
        ),
        ("counts_pin",),
        error=ConfigError,
    )
    check_number("hal.period_s", h["period_s"], "s", strict=True, error=ConfigError)
    if h["period_s"] > rig.period_s * (1 + PERIOD_TOLERANCE):
        raise ConfigError(
            f"hal.period_s {h['period_s']:g} s is slower than the rig's period "
            f"{rig.period_s:g} s: the loop the tuning is verified for runs faster"
        )
    if h["period_s"] < rig.period_s * (1 - PERIOD_TOLERANCE):
        raise ConfigError(
            f"hal.period_s {h['period_s']:g} s is faster than the rig's period "
            f"{rig.period_s:g} s: give a rig whose timer is this thread's"
        )
    check_number(
        "hal.position_scale", h["position_scale"], "counts per unit", strict=True, error=ConfigError
    )
    hal = HalSide(
        thread=_pin(h, "thread"),
        period_s=float(h["period_s"]),
        command_pin=_pin(h, "command_pin"),
        feedback_pin=_pin(h, "feedback_pin"),
        output_pin=_pin(h, "output_pin"),
        enable_pin=_pin(h, "enable_pin"),
        position_scale=float(h["position_scale"]),
        counts_pin=_pin(h, "counts_pin") if "counts_pin" in h else None,
    )
    target = _check_target(target, hal.counts_pin)
    return AutotuneConfig(
        path=p,
        rig_path=rig_path,
        rig=rig,
        axis=axis,
        spec_path=None if a.get("spec") is None else _path(p.parent, a["spec"], "autotune.spec"),
        target=target,
        excitation=kind,
        seconds=float(seconds),
        hal=hal,
        envelope=_envelope(doc["envelope"], rig, axis),
        modes=modes,
        periods=periods,
        band_hz=band,
        component=component,
    )


DEFAULT_PERIODS = 8
"""Periods of the experiment's multisine when the run fits modes and the config gives none."""


def _frequency_response(
    a: dict[str, Any], rig: Rig, axis: str, kind: str
) -> tuple[int | str | None, int | None, tuple[float, float] | None]:
    """The config's ``modes`` (default ``"auto"`` where the rig's axis has modes, else none),
    ``periods`` and ``band_hz``: a run that fits modes plays a periodic multisine
    (``periods`` whole periods, default :data:`DEFAULT_PERIODS`), so the capture's frequency
    response can be measured (docs/frf.md)."""
    from servotune.identify.logfit import check_modes_request

    modes = a.get("modes", "auto" if rig.axis(axis).plant.modes else None)
    try:
        check_modes_request(modes)
    except Exception as exc:  # SpecError's one line, under this key
        raise ConfigError(f"autotune.{exc}") from None
    periods = a.get("periods")
    if periods is None and modes not in (None, 0):
        periods = DEFAULT_PERIODS
    if periods is not None and not (type(periods) is int and 2 <= periods <= 1000):
        raise ConfigError(
            f"autotune.periods must be a whole number of periods in 2..1000, got "
            f"{show_value(periods)}"
        )
    band = a.get("band_hz")
    ok = band is None or (
        isinstance(band, list)
        and len(band) == 2
        and all(isinstance(x, int | float) and not isinstance(x, bool) for x in band)
        and 0 < band[0] < band[1] < math.inf
    )
    if not ok:
        raise ConfigError(
            f"autotune.band_hz must be [low, high] with 0 < low < high [Hz], got {show_value(band)}"
        )
    if (periods is not None or band is not None) and kind != "multisine":
        raise ConfigError(
            f"autotune.excitation must be multisine for a frequency response (modes, periods "
            f"or band_hz given), got {show_value(kind)}"
        )
    if band is not None and periods is None:
        raise ConfigError("autotune.band_hz needs autotune.periods (a periodic multisine)")
    return modes, periods, None if band is None else (float(band[0]), float(band[1]))


PIN_ROLES = (
    ("command_pin", "float", None, "the loop's position command"),
    ("feedback_pin", "float", None, "the feedback position"),
    ("output_pin", "float", "OUT", "the controller's output"),
    ("enable_pin", "bit", None, "the controller's enable"),
    ("counts_pin", "s32", "OUT", "the raw encoder count"),
)
"""Each configured pin: its key, the type and (if it matters) direction it must have, what it
is."""


def check_session(cfg: AutotuneConfig, session: HalSession) -> None:
    """Check the config's HAL side against a running session (:func:`read_session`): each pin
    there with its type and direction, the thread there at the config's period.

    Raises
    ------
    ConfigError
        One line naming the key and what the session has instead.
    """
    h = cfg.hal
    for key, typ, direction, what in PIN_ROLES:
        name = getattr(h, key)
        if name is None:  # optional: the counts for the component only
            continue
        pin = session.pins.get(name)
        if pin is None:
            raise ConfigError(
                f"{cfg.path}: hal.{key} {name!r} ({what}) is not a pin of the session"
            )
        if pin.type != typ or (direction is not None and pin.dir != direction):
            want = f"a {typ} {direction} pin" if direction else f"a {typ} pin"
            raise ConfigError(
                f"{cfg.path}: hal.{key} {name!r} ({what}) is a {pin.type} {pin.dir} pin; "
                f"it must be {want}"
            )
    period_ns = session.threads.get(h.thread)
    if period_ns is None:
        have = ", ".join(sorted(session.threads)) or "none"
        raise ConfigError(
            f"{cfg.path}: hal.thread {h.thread!r} is not a thread of the session ({have})"
        )
    if abs(period_ns * 1e-9 - h.period_s) > PERIOD_TOLERANCE * h.period_s:
        raise ConfigError(
            f"{cfg.path}: hal.thread {h.thread!r} runs every {period_ns * 1e-6:g} ms, not "
            f"hal.period_s = {h.period_s * 1e3:g} ms"
        )


@dataclass(frozen=True, slots=True)
class AutotunePlan:
    """What an autotune run would do, from the current model (module docstring).

    Attributes
    ----------
    pulse_volts, pulse_s : float
        Each wiring-check pulse (one each way, open loop) and its length.
    pulse_travel_counts : float
        The travel the model predicts for one pulse [counts].
    lock_gain : float
        The starting loop's gain [D/A codes/count] and its margins (``margins``).
    excitation : str
        Kind; ``amplitude_volts`` its largest |output| added to the loop's; ``seconds`` long;
        ``excitation_codes`` the absolute D/A codes it plays, one per tick.
    predicted : dict
        The model's largest travel, speed and following error during the experiment, each with
        its envelope limit and share of it.
    steps : list of str
        The run's steps in order.
    """

    pulse_volts: float
    pulse_s: float
    pulse_travel_counts: float
    lock_gain: float
    margins: dict[str, float]
    excitation: str
    amplitude_volts: float
    seconds: float
    predicted: dict[str, dict[str, float]]
    excitation_codes: np.ndarray
    steps: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "pulse": {
                "volts": self.pulse_volts,
                "seconds": self.pulse_s,
                "travel_counts": self.pulse_travel_counts,
            },
            "starting_loop": {"lock_gain_codes_per_count": self.lock_gain, **self.margins},
            "excitation": {
                "kind": self.excitation,
                "amplitude_volts": self.amplitude_volts,
                "seconds": self.seconds,
            },
            "predicted": self.predicted,
            "steps": self.steps,
        }


def plan_autotune(cfg: AutotuneConfig) -> AutotunePlan:
    """The plan of an autotune run (module docstring): nothing is touched."""
    from servotune.analysis.margins import GainSet, loop_margins, loop_model, margin_grid

    rig, env = cfg.rig, cfg.envelope
    ax = rig.axis(cfg.axis)
    plant = ax.plant
    exc, codes, predicted = _experiment(cfg)
    lag = rig.timer.compute_s + plant.delay_s
    g = GainSet(ax.lock_gain_codes_per_count)
    figures = loop_margins(
        loop_model(plant, g, period_s=rig.period_s, lag_s=lag, lsb_volts=rig.dac.lsb_v),
        margin_grid(plant, rig.period_s),
    )
    margins = {
        "phase_margin_deg": float(figures.phase_margin_deg),
        "gain_margin_db": float(figures.gain_margin_db),
    }
    lo, hi = env.travel_counts
    # the pulse: PULSE_TRAVEL_SHARE of the window in PULSE_S at the model's gain
    pulse_travel = PULSE_TRAVEL_SHARE * min(-lo, hi)
    pulse_volts = min(env.max_volts, pulse_travel / (plant.gain_cps_per_v * PULSE_S))
    h = cfg.hal
    steps = [
        f"load the guard (the envelope, in the real-time thread) between {h.output_pin} and "
        "the D/A driver, in thread " + h.thread,
        f"wiring check: {pulse_volts:.3g} V for {PULSE_S:g} s each way, open loop; the "
        f"feedback {h.feedback_pin} × {h.position_scale:g} must move with the output, about "
        f"{pulse_travel:.0f} counts each way (a reversed sign, or a scale off by more than "
        "20×, stops here)",
        f"experiment: {cfg.excitation} of ±{exc.amplitude_codes * rig.dac.lsb_v:.3g} V added "
        f"to the loop's output for {exc.codes.size * rig.period_s:.1f} s, the loop closed at "
        f"Kp {ax.lock_gain_codes_per_count:g} codes/count, captured with halsampler"
        + (
            ""
            if cfg.periods is None
            else f" ({cfg.periods} periods of {exc.codes.size // cfg.periods} ticks: the "
            "capture keeps these whole periods, for the frequency response)"
        ),
        "fit the capture (servotune fit"
        + ("" if cfg.modes in (None, 0) else f" --modes {cfg.modes}: the rigid plant and its modes")
        + "), tune (servotune tune), verify against "
        + (str(cfg.spec_path) if cfg.spec_path else "the rig's defaults")
        + f", export for the {cfg.target}",
        (
            "load the new parameters"
            if cfg.target == "pid"
            else f"build the verified runtime component {cfg.component} (halcompile --install), "
            f"load it in {cfg.hal.thread} before the guard, its counts from "
            f"{cfg.hal.counts_pin}, its output into the guard instead of the pid's"
        )
        + "; a validation move against the verified model's prediction; "
        "a mismatch restores the previous parameters",
    ]
    return AutotunePlan(
        pulse_volts=pulse_volts,
        pulse_s=PULSE_S,
        pulse_travel_counts=pulse_travel,
        lock_gain=ax.lock_gain_codes_per_count,
        margins=margins,
        excitation=cfg.excitation,
        amplitude_volts=exc.amplitude_codes * rig.dac.lsb_v,
        seconds=exc.codes.size * rig.period_s,
        predicted=predicted,
        excitation_codes=codes,
        steps=steps,
    )


OUTPUT_SHARE = 0.9
"""The experiment's predicted largest |output| (the loop's plus the excitation's, what the
guard limits) stays within this share of the envelope's ``max_volts``."""


def _experiment(cfg: AutotuneConfig) -> tuple[Any, np.ndarray, dict[str, dict[str, float]]]:
    """The experiment's excitation, its absolute D/A codes and the motion and output the
    engine predicts for it in the closed loop (noiseless): the excitation designed within the
    envelope (:func:`~servotune.excite.design_excitation` on the axis's limits narrowed to it,
    keeping the motion within 90 % of them), then its amplitude lowered until the loop's output
    with it stays within :data:`OUTPUT_SHARE` of ``max_volts``."""
    from servotune.excite import design_excitation, excitation_inputs
    from servotune.sim.engine import Loop, simulate

    rig, env = cfg.rig, cfg.envelope
    ax = rig.axis(cfg.axis)
    lo, hi = env.travel_counts
    narrowed = replace(
        ax,
        speed_limit_rpm=env.speed_cps * 60.0 / rig.counts_per_rev,
        travel_counts=(math.floor(lo), math.ceil(hi)),
    )
    exp_rig = replace(rig, axes=tuple(narrowed if a.name == cfg.axis else a for a in rig.axes))
    noiseless = [replace(a.plant, noise_counts=0.0) for a in rig.axes]
    i = rig.axis_names.index(cfg.axis)
    amp_codes = max(1, math.floor(env.max_volts / rig.dac.lsb_v))
    while True:
        exc = design_excitation(
            exp_rig,
            cfg.axis,
            cfg.excitation,
            cfg.seconds,
            amplitude_codes=amp_codes,
            periods=cfg.periods,
            band_hz=cfg.band_hz,
        )
        codes = exc.zero_code + exc.codes  # absolute D/A codes
        inputs = excitation_inputs(exp_rig, cfg.axis, codes, closed_loop=True)
        tr = simulate(Loop.from_rig(rig), inputs, seed=0, plants=noiseless)
        pos = np.asarray(tr.true_pos_counts)[:, i]
        rel = pos - pos[0]
        volts = rig.dac.range_v[0] + np.asarray(tr.code)[:, i] * rig.dac.lsb_v
        predicted = {
            "travel_counts": _share(float(max(-rel.min(), rel.max())), min(-lo, hi)),
            "speed_cps": _share(float(np.abs(np.diff(pos)).max() / rig.period_s), env.speed_cps),
            "following_error_counts": _share(
                float(np.abs(np.asarray(tr.err_counts)[:, i]).max()), env.following_error_counts
            ),
            "output_volts": _share(float(np.abs(volts).max()), env.max_volts),
        }
        share = predicted["output_volts"]["share"]
        if share <= OUTPUT_SHARE or exc.amplitude_codes <= 1:
            return exc, codes, predicted
        amp_codes = max(
            1, min(exc.amplitude_codes - 1, math.floor(exc.amplitude_codes * OUTPUT_SHARE / share))
        )


def _share(value: float, limit: float) -> dict[str, float]:
    return {"value": value, "limit": float(limit), "share": value / limit}


def format_plan(cfg: AutotuneConfig, plan: AutotunePlan, session_checked: bool) -> str:
    """The plan as ``--dry-run`` prints it; ``session_checked``: whether a running HAL session
    was checked (:func:`check_session`)."""
    lines = [f"autotune {cfg.path} (dry run: nothing in HAL is touched)"]
    lines += [f"  {k + 1}. {s}" for k, s in enumerate(plan.steps)]
    pm, gm = plan.margins["phase_margin_deg"], plan.margins["gain_margin_db"]
    lines.append(f"  starting loop: phase margin {pm:.1f}°, gain margin {gm:.1f} dB")
    for key, unit in (
        ("travel_counts", "counts"),
        ("speed_cps", "counts/s"),
        ("following_error_counts", "counts"),
        ("output_volts", "V"),
    ):
        p = plan.predicted[key]
        value = f"{p['value']:.2f}" if unit == "V" else f"{p['value']:.0f}"
        lines.append(
            f"  predicted {key.rsplit('_', 1)[0].replace('_', ' ')}: {value} {unit} "
            f"({100 * p['share']:.0f} % of the envelope's {p['limit']:g})"
        )
    lines.append(
        "  the HAL session's pins and thread: as the config says"
        if session_checked
        else "  no HAL session runs here (or no halcmd): the pins were not checked"
    )
    return "\n".join(lines)
