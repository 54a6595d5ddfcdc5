"""LinuxCNC's stock ``pid`` HAL component, its law in floating point.

servotune exports the master axis's verified PI law as parameters of LinuxCNC's stock ``pid``
component (:mod:`servotune.export.linuxcnc`). To say what that loop does we need the component's
law exactly, so it is written here once, as a pure step function that mirrors ``calc_pid()`` of
LinuxCNC's ``src/hal/components/pid.c`` statement by statement, in the same order and in the
same (IEEE double) arithmetic: Python's ``float`` is the C ``double`` the component computes in,
and every sum and product below is evaluated in the order the C expression evaluates it, so a
step here and a step in HAL give the same bits (``tests/hal/test_pid_export.py`` checks it
against the installed component).

The component is the one of LinuxCNC 2.9 (the auto-tuner merged in, with ``FF3`` and
``maxcmdDDD``; its pins: ``halcmd show pin pid.x`` after ``loadrt pid names=pid.x``). Every
gain and limit is an input *pin* (they were parameters before 2.7; ``setp`` sets either). Per
call, with ``period`` the thread period [ns] the function receives::

    periodfp = period * 1e-9;  periodrecip = 1 / periodfp
    e = (error-previous-target ? prev_cmd : command) - feedback     (the error pin)
    e = clamp(e, ±maxerror)                     (if maxerror != 0)
    e = e ∓ deadband, or 0 inside ±deadband
    if enable: errorI += e * periodfp unless e * limit_state > 0 (output on a limit, e pushing
               further); errorI = clamp(errorI, ±maxerrorI) (if != 0)
    else:      errorI = 0
    commandv = (command - prev_cmd) * periodrecip,  feedbackv = (feedback - prev_fb) * periodrecip
    errorD = commandv - feedbackv, clamped to ±maxerrorD
    commandD = commandv (±maxcmdD), commandDD = Δ commandD * periodrecip (±maxcmdDD),
    commandDDD = Δ commandDD * periodrecip (±maxcmdDDD)
    output = bias + Pgain*e + Igain*errorI + Dgain*errorD
             + (command*FF0 + commandD*FF1 + commandDD*FF2 + commandDDD*FF3)
    output = clamp(output, ±maxoutput), limit_state = ±1 on a limit, else 0 (if maxoutput != 0)
    if not enable: output = 0, limit_state = 0

What is not modelled: the auto-tuner (``tune-mode`` must be false, its default), and
``command-deriv`` / ``feedback-deriv`` connected to signals (unconnected, as the exported HAL
file leaves them, they read the derivatives the component computes itself); the
``saturated*`` pins are outputs only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

from servotune.validate import show_value

__all__ = ["HAL_PIN_NAMES", "PidParameters", "PidState", "pid_step", "thread_period_ns"]

_LIMITS = ("deadband", "maxerror", "maxerrorI", "maxerrorD", "maxcmdD", "maxcmdDD", "maxcmdDDD",
           "maxoutput")  # fmt: skip

_UNITS = {
    "Pgain": "output units per machine unit",
    "Igain": "output units per machine unit·s",
    "Dgain": "output units per machine unit/s",
    "bias": "output units",
    "FF0": "output units per machine unit",
    "FF1": "output units per machine unit/s",
    "FF2": "output units per machine unit/s²",
    "FF3": "output units per machine unit/s³",
    "deadband": "machine units",
    "maxerror": "machine units",
    "maxerrorI": "machine unit·s",
    "maxerrorD": "machine units/s",
    "maxcmdD": "machine units/s",
    "maxcmdDD": "machine units/s²",
    "maxcmdDDD": "machine units/s³",
    "maxoutput": "output units",
}


@dataclass(frozen=True, slots=True, kw_only=True)
class PidParameters:
    """The settable pins of one stock ``pid`` instance (their HAL names; 0 = no limit).

    The defaults are the component's own after ``loadrt pid`` (``Pgain`` 1, everything else
    0, ``error-previous-target`` true).

    "Machine units" are the units of the ``command`` and ``feedback`` pins (mm, inch, degree:
    the encoder's ``position-scale`` is counts per machine unit); "output units" those of the
    ``output`` pin.

    Parameters
    ----------
    Pgain : float
        Proportional gain [output units per machine unit].
    Igain : float
        Integral gain [output units per machine unit·s].
    Dgain : float
        Derivative gain [output units per machine unit/s].
    bias : float
        Constant added to the output [output units].
    FF0, FF1, FF2, FF3 : float
        Feedforward of the command and its first three derivatives [output units per machine
        unit, per machine unit/s, per machine unit/s², per machine unit/s³].
    deadband : float
        Error ignored around zero [machine units], >= 0.
    maxerror : float
        Limit on the error [machine units], >= 0.
    maxerrorI : float
        Limit on the error integral [machine unit·s], >= 0.
    maxerrorD : float
        Limit on the error derivative [machine units/s], >= 0.
    maxcmdD, maxcmdDD, maxcmdDDD : float
        Limits on the command's derivatives [machine units/s, /s², /s³], >= 0.
    maxoutput : float
        Limit on the output [output units], >= 0; also the anti-windup's trigger.
    error_previous_target : bool
        The ``error-previous-target`` pin (the component's default is true): the error is the
        previous tick's command minus the feedback; false: this tick's command minus it.
    """

    Pgain: float = 1.0
    Igain: float = 0.0
    Dgain: float = 0.0
    bias: float = 0.0
    FF0: float = 0.0
    FF1: float = 0.0
    FF2: float = 0.0
    FF3: float = 0.0
    deadband: float = 0.0
    maxerror: float = 0.0
    maxerrorI: float = 0.0
    maxerrorD: float = 0.0
    maxcmdD: float = 0.0
    maxcmdDD: float = 0.0
    maxcmdDDD: float = 0.0
    maxoutput: float = 0.0
    error_previous_target: bool = True

    def __post_init__(self) -> None:
        for name, unit in _UNITS.items():
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise ValueError(f"{name} must be a finite number [{unit}], got {show_value(v)}")
            if name in _LIMITS and v < 0:
                raise ValueError(f"{name} must be >= 0 [{unit}] (0 = no limit), got {v!r}")
            object.__setattr__(self, name, float(v))
        if not isinstance(self.error_previous_target, bool):
            raise ValueError(
                f"error_previous_target must be True or False, got "
                f"{show_value(self.error_previous_target)}"
            )

    def hal_pins(self) -> tuple[tuple[str, float | bool], ...]:
        """``(pin suffix, value)`` per field, in field order (``error-previous-target`` for
        :attr:`error_previous_target`): what ``setp <name>.<suffix> <value>`` sets."""
        return tuple((HAL_PIN_NAMES[f.name], getattr(self, f.name)) for f in fields(self))

    def to_dict(self) -> dict[str, Any]:
        """Plain dict keyed by the HAL pin names."""
        return dict(self.hal_pins())


HAL_PIN_NAMES: dict[str, str] = {
    f.name: ("error-previous-target" if f.name == "error_previous_target" else f.name)
    for f in fields(PidParameters)
}
"""Field of :class:`PidParameters` → its pin's name after ``<instance>.``."""


@dataclass(frozen=True, slots=True, kw_only=True)
class PidState:
    """What one ``pid`` instance keeps between calls (all zero at ``loadrt``).

    Parameters
    ----------
    prev_ie : bool
        Last call's ``index-enable``.
    error_i : float
        ``errorI``: the error integral [machine unit·s].
    error_d : float
        ``errorD``: the error derivative [machine units/s].
    prev_cmd, prev_fb : float
        Last call's command and feedback [machine units].
    limit_state : float
        +1 / −1 if the last output was on the ``maxoutput`` limit, else 0.
    cmd_d, cmd_dd, cmd_ddd : float
        ``commandD``, ``commandDD``, ``commandDDD`` [machine units/s, /s², /s³].
    commandv, feedbackv : float
        The ``command-deriv`` and ``feedback-deriv`` pins, unconnected: the derivatives the
        component last computed [machine units/s].
    """

    prev_ie: bool = False
    error_i: float = 0.0
    error_d: float = 0.0
    prev_cmd: float = 0.0
    prev_fb: float = 0.0
    limit_state: float = 0.0
    cmd_d: float = 0.0
    cmd_dd: float = 0.0
    cmd_ddd: float = 0.0
    commandv: float = 0.0
    feedbackv: float = 0.0


def thread_period_ns(period_s: float) -> int:
    """The HAL thread period [ns] closest to a tick of ``period_s`` [s] (what ``loadrt threads
    period1=…`` takes, and what ``do-pid-calcs`` receives as ``period``).

    Examples
    --------
    >>> thread_period_ns(0.0040002346670242545)  # the example rig's 8253 tick
    4000235
    """
    if not (isinstance(period_s, int | float) and math.isfinite(period_s) and period_s > 0):
        raise ValueError(f"period_s must be a finite number > 0 [s], got {show_value(period_s)}")
    ns = round(period_s * 1e9)
    if not 1 <= ns <= 2**31 - 1:
        raise ValueError(f"period_s {period_s!r} s is not a HAL thread period (1 ns … 2.1 s)")
    return int(ns)


def _clamp(x: float, limit: float) -> float:
    """pid.c's limit blocks: ``±limit`` unless ``limit`` is 0 (comparisons as written there)."""
    if limit != 0.0:
        if x > limit:
            return limit
        if x < -limit:
            return -limit
    return x


def pid_step(
    p: PidParameters,
    s: PidState,
    command: float,
    feedback: float,
    period_ns: int,
    *,
    enable: bool = True,
    index_enable: bool = False,
) -> tuple[float, float, PidState]:
    """One call of the stock pid's ``do-pid-calcs``: ``calc_pid()`` of pid.c, line by line.

    Parameters
    ----------
    p : PidParameters
        The pins set by the HAL file.
    s : PidState
        The state after the previous call (``PidState()`` after ``loadrt``).
    command, feedback : float
        The ``command`` and ``feedback`` pins [machine units].
    period_ns : int
        The thread period the function receives [ns] (``loadrt threads period1=…``).
    enable, index_enable : bool
        The ``enable`` and ``index-enable`` pins.

    Returns
    -------
    output : float
        The ``output`` pin [output units].
    error : float
        The ``error`` pin [machine units] (before the limits and the deadband).
    state : PidState
        The state for the next call.

    Examples
    --------
    >>> p = PidParameters(Pgain=2.0, error_previous_target=False)
    >>> out, err, st = pid_step(p, PidState(), 1.0, 0.25, 1_000_000)
    >>> out, err
    (1.5, 0.75)
    """
    periodfp = float(period_ns) * 0.000000001
    periodrecip = 1.0 / periodfp
    # the error; "previous target" only when no index-enable falling edge just happened
    index_reset = s.prev_ie and not index_enable
    if (not index_reset) and p.error_previous_target:
        tmp1 = s.prev_cmd - feedback
    else:
        tmp1 = command - feedback
    error = tmp1
    tmp1 = _clamp(tmp1, p.maxerror)
    if tmp1 > p.deadband:
        tmp1 -= p.deadband
    elif tmp1 < -p.deadband:
        tmp1 += p.deadband
    else:
        tmp1 = 0.0
    error_i = s.error_i
    if enable:
        if (tmp1 * s.limit_state) <= 0.0:  # no wind-up while the output is on a limit
            error_i = error_i + tmp1 * periodfp
        error_i = _clamp(error_i, p.maxerrorI)
    else:
        error_i = 0.0
    commandv, feedbackv = s.commandv, s.feedbackv
    if not index_reset:
        commandv = (command - s.prev_cmd) * periodrecip
        feedbackv = (feedback - s.prev_fb) * periodrecip
    error_d = _clamp(commandv - feedbackv, p.maxerrorD)
    tmp2 = s.cmd_d
    cmd_d = _clamp(commandv, p.maxcmdD)
    tmp3 = s.cmd_dd
    cmd_dd = _clamp((cmd_d - tmp2) * periodrecip, p.maxcmdDD)
    cmd_ddd = _clamp((cmd_dd - tmp3) * periodrecip, p.maxcmdDDD)
    limit_state = s.limit_state
    if enable:
        out = p.bias + p.Pgain * tmp1 + p.Igain * error_i + p.Dgain * error_d
        out += command * p.FF0 + cmd_d * p.FF1 + cmd_dd * p.FF2 + cmd_ddd * p.FF3
        if p.maxoutput != 0.0:
            if out > p.maxoutput:
                out = p.maxoutput
                limit_state = 1.0
            elif out < -p.maxoutput:
                out = -p.maxoutput
                limit_state = -1.0
            else:
                limit_state = 0.0
    else:
        out = 0.0
        limit_state = 0.0
    state = PidState(
        prev_ie=bool(index_enable),
        error_i=error_i,
        error_d=error_d,
        prev_cmd=command,
        prev_fb=feedback,
        limit_state=limit_state,
        cmd_d=cmd_d,
        cmd_dd=cmd_dd,
        cmd_ddd=cmd_ddd,
        commandv=commandv,
        feedbackv=feedbackv,
    )
    return out, error, state
