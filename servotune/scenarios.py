"""Scenario inputs for the engine: references, modes, excitation, loads.

:class:`Inputs` holds per-tick arrays of shape (ticks, axes). The builders below make the
experiments of the virtual rig: identification excitations on the D/A (``prbs``, ``steps``,
``chirp``; open loop or with the lock module active) and a PI position loop following a ramp
(``track``). Time is always an integer tick index times the period.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from servotune.budget import check_memory, format_count
from servotune.errors import SpecError
from servotune.laws.axis import MODE_LOCK, MODE_OPEN, MODE_TASK
from servotune.rig import Rig
from servotune.validate import show_value

__all__ = [
    "SCENARIOS",
    "Inputs",
    "Scenario",
    "build_scenario",
    "check_run_memory",
    "chirp_codes",
    "excitation_amplitude_codes",
    "prbs_codes",
    "step_codes",
    "step_inputs",
    "sync_move",
    "trapezoid_ref",
]


@dataclass(frozen=True, slots=True, kw_only=True)
class Inputs:
    """Per-tick engine inputs, arrays of shape (ticks, axes).

    Parameters
    ----------
    ref_counts : ndarray of int64
        Task reference relative to the axis's start position [counts] (ignored for axes whose
        reference is another axis's position).
    mode : ndarray of int64
        Requested mode per tick (``MODE_LOCK`` 0, ``MODE_TASK`` 1, ``MODE_OPEN`` 2).
    reset : ndarray of bool
        Fault reset requests.
    dac_add_codes : ndarray of int64
        Command added to the law's output [D/A codes]; the whole output in open mode.
    load_v : ndarray of float
        Load disturbance as equivalent drive input [V].
    """

    ref_counts: np.ndarray
    mode: np.ndarray
    reset: np.ndarray
    dac_add_codes: np.ndarray
    load_v: np.ndarray

    def __post_init__(self) -> None:
        shape = np.shape(self.mode)
        if len(shape) != 2 or shape[0] < 1 or shape[1] < 1:
            raise SpecError(f"mode must have shape (ticks, axes), got {shape}")
        for name, dtype in (
            ("ref_counts", np.int64),
            ("mode", np.int64),
            ("reset", np.bool_),
            ("dac_add_codes", np.int64),
            ("load_v", np.float64),
        ):
            arr = np.ascontiguousarray(getattr(self, name), dtype=dtype)
            if arr.shape != shape:
                raise SpecError(f"{name} must have shape {shape}, got {arr.shape}")
            if dtype is np.float64 and not np.all(np.isfinite(arr)):
                raise SpecError(f"{name} must be finite")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if np.any((self.mode < MODE_LOCK) | (self.mode > MODE_OPEN)):
            raise SpecError("mode values must be 0 (lock), 1 (task) or 2 (open)")

    @property
    def n_ticks(self) -> int:
        """Number of ticks."""
        return int(self.mode.shape[0])

    @property
    def n_axes(self) -> int:
        """Number of axes."""
        return int(self.mode.shape[1])

    @classmethod
    def hold(cls, n_ticks: int, n_axes: int) -> Inputs:
        """Every axis in lock, no excitation or load."""
        z = np.zeros((n_ticks, n_axes), dtype=np.int64)
        return cls(
            ref_counts=z,
            mode=z,
            reset=np.zeros_like(z, dtype=bool),
            dac_add_codes=z,
            load_v=np.zeros((n_ticks, n_axes)),
        )

    def replace_axis(self, axis: int, **columns: np.ndarray | float | int) -> Inputs:
        """A copy with some columns of one axis replaced (arrays of length ticks or scalars)."""
        arrays = {
            name: np.array(getattr(self, name))
            for name in ("ref_counts", "mode", "reset", "dac_add_codes", "load_v")
        }
        for name, col in columns.items():
            if name not in arrays:
                raise SpecError(f"unknown input column {show_value(name)}")
            arrays[name][:, axis] = col
        return Inputs(**arrays)


# --- excitation signals ---------------------------------------------------------------------


def excitation_amplitude_codes(rig: Rig, axis: str, speed_fraction: float = 0.3) -> int:
    """D/A amplitude [codes] whose steady speed is ``speed_fraction`` of the axis speed limit.

    Counts the drift and Coulomb friction so the axis really moves, and stays within the D/A.
    """
    ax = rig.axis(axis)
    lsb = rig.dac.lsb_v
    v_lim = ax.speed_limit_rpm / 60.0 * rig.counts_per_rev
    volts = speed_fraction * v_lim / ax.plant.gain_cps_per_v + ax.plant.coulomb_v
    codes = math.floor(volts / lsb)
    return max(1, min(codes, rig.dac.zero_code - 1, rig.dac.code_max - rig.dac.zero_code))


def prbs_codes(
    n_ticks: int, amplitude_codes: int, hold_ticks: int = 5, order: int = 9
) -> np.ndarray:
    """Maximum-length PRBS (Fibonacci LFSR) of ±amplitude, each bit held ``hold_ticks``.

    Parameters
    ----------
    n_ticks : int
        Length [ticks].
    amplitude_codes : int
        Level [D/A codes].
    hold_ticks : int
        Ticks per PRBS bit (sets the excited band: up to about 1 / (hold · T) Hz).
    order : int
        LFSR order (period 2**order − 1 bits); taps for orders 5…11.

    Examples
    --------
    >>> prbs_codes(8, 10, hold_ticks=2).tolist()
    [10, 10, -10, -10, -10, -10, -10, -10]
    """
    taps = {5: (5, 3), 6: (6, 5), 7: (7, 6), 8: (8, 6), 9: (9, 5), 10: (10, 7), 11: (11, 9)}
    if order not in taps:
        raise SpecError(f"PRBS order must be in 5..11, got {order}")
    if hold_ticks < 1:
        raise SpecError(f"hold_ticks must be >= 1, got {hold_ticks}")
    t1, t2 = taps[order]
    reg = (1 << order) - 1
    n_bits = -(-n_ticks // hold_ticks)
    bits = np.empty(n_bits, dtype=np.int64)
    for i in range(n_bits):
        bits[i] = reg & 1
        fb = ((reg >> (t1 - 1)) ^ (reg >> (t2 - 1))) & 1
        reg = (reg >> 1) | (fb << (order - 1))
    levels = np.where(bits == 1, amplitude_codes, -amplitude_codes)
    return np.repeat(levels, hold_ticks)[:n_ticks]


def step_codes(n_ticks: int, amplitude_codes: int, period_ticks: int) -> np.ndarray:
    """Steps of several levels with direction reversals: +A, −A/2, +A/2, −A, repeating.

    Each level lasts ``period_ticks``; the pattern has zero mean so the axis stays near home.
    """
    if period_ticks < 1:
        raise SpecError(f"period_ticks must be >= 1, got {period_ticks}")
    a = amplitude_codes
    pattern = np.array([a, -(a // 2), a // 2, -a], dtype=np.int64)
    idx = (np.arange(n_ticks, dtype=np.int64) // period_ticks) % pattern.size
    return pattern[idx]


def chirp_codes(
    n_ticks: int, period_s: float, amplitude_codes: int, f0_hz: float, f1_hz: float
) -> np.ndarray:
    """Logarithmic sine sweep from ``f0_hz`` to ``f1_hz`` [D/A codes, rounded half away]."""
    if not 0 < f0_hz < f1_hz:
        raise SpecError(f"chirp needs 0 < f0_hz < f1_hz, got {f0_hz}, {f1_hz}")
    t = np.arange(n_ticks, dtype=np.int64) * period_s
    dur = max(n_ticks * period_s, period_s)
    rate = math.log(f1_hz / f0_hz) / dur
    phase = 2 * math.pi * f0_hz * np.expm1(rate * t) / rate
    x = amplitude_codes * np.sin(phase)
    return (np.sign(x) * np.floor(np.abs(x) + 0.5)).astype(np.int64)


def trapezoid_ref(
    n_ticks: int,
    period_s: float,
    distance_counts: float,
    speed_cps: float,
    accel_cps2: float,
    start_tick: int = 0,
) -> np.ndarray:
    """Trapezoidal-velocity move of ``distance_counts`` starting at ``start_tick`` [counts].

    Returns the reference rounded to whole counts (int64), holding at the end.
    """
    if speed_cps <= 0 or accel_cps2 <= 0:
        raise SpecError("speed_cps and accel_cps2 must be > 0")
    d = abs(distance_counts)
    sgn = 1.0 if distance_counts >= 0 else -1.0
    t_acc = speed_cps / accel_cps2
    if accel_cps2 * t_acc**2 > d:  # triangular profile
        t_acc = math.sqrt(d / accel_cps2)
        speed_cps = accel_cps2 * t_acc
    t_cruise = (d - accel_cps2 * t_acc**2) / speed_cps
    t = (np.arange(n_ticks, dtype=np.int64) - start_tick) * period_s
    t = np.clip(t, 0.0, None)
    t_end = 2 * t_acc + t_cruise
    s = np.where(
        t < t_acc,
        0.5 * accel_cps2 * t**2,
        np.where(
            t < t_acc + t_cruise,
            0.5 * accel_cps2 * t_acc**2 + speed_cps * (t - t_acc),
            d - 0.5 * accel_cps2 * np.clip(t_end - t, 0.0, None) ** 2,
        ),
    )
    return (sgn * np.floor(s + 0.5)).astype(np.int64)


# --- named scenarios -----------------------------------------------------------------------

RUN_BYTES_PER_TICK_AXIS = 512
"""Memory a simulated run takes per tick and axis [bytes], all told: the inputs (33 bytes and
their copies), the engine's traces (72), the Trace, the log columns and their text (about 60
characters per value, held as Python strings while the log is formatted)."""


def check_run_memory(rig: Rig, n_ticks: float, what: str) -> None:
    """Refuse a run of ``n_ticks`` on ``rig`` before allocating it if it exceeds the memory
    budget (:func:`servotune.budget.check_memory`).

    Raises
    ------
    BudgetError
        ``"simulate 1e+12 s needs about 230 TiB (250,000,000,000,000 ticks × 2 axes × 512
        bytes); over the memory budget of 2 GiB (...)"``.
    """
    n_ax = len(rig.axes)
    check_memory(
        float(n_ticks) * n_ax * RUN_BYTES_PER_TICK_AXIS,
        what,
        f"{format_count(n_ticks)} ticks × {n_ax} axes × {RUN_BYTES_PER_TICK_AXIS} bytes",
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class Scenario:
    """A named experiment: engine inputs plus what the loop needs to run them.

    Attributes
    ----------
    name : str
    axis : str
        The axis the scenario excites or moves.
    inputs : Inputs
    needs_task_law : bool
        True if the axis runs a task law (PI gains needed).
    """

    name: str
    axis: str
    inputs: Inputs
    needs_task_law: bool = False


def _excitation(
    rig: Rig, axis: str, n: int, codes: np.ndarray, closed_loop: bool, name: str
) -> Scenario:
    i = rig.axis_names.index(axis)
    inp = Inputs.hold(n, len(rig.axes))
    # the first 0.2 s the lock holds, then the excitation plays
    lead = min(n // 10, math.floor(0.2 / rig.period_s + 0.5))
    col = np.zeros(n, dtype=np.int64)
    col[lead:] = codes[: n - lead]
    mode = np.full(n, MODE_LOCK if closed_loop else MODE_OPEN, dtype=np.int64)
    mode[:lead] = MODE_LOCK
    return Scenario(name=name, axis=axis, inputs=inp.replace_axis(i, dac_add_codes=col, mode=mode))


def _prbs(rig: Rig, axis: str, n: int, closed_loop: bool) -> Scenario:
    # multi-level PRBS: a two-level one has constant |u|, which confounds Coulomb friction
    # with the gain; the level steps through 100, 40, 70, 25 % every 31 PRBS bits
    amp = excitation_amplitude_codes(rig, axis)
    tau = rig.axis(axis).plant.tau_s
    hold = max(1, math.floor(tau / rig.period_s + 0.5))
    levels = np.array([1.0, 0.4, 0.7, 0.25])
    scale = levels[(np.arange(n, dtype=np.int64) // (31 * hold)) % levels.size]
    codes = np.floor(prbs_codes(n, amp, hold_ticks=hold) * scale + 0.5).astype(np.int64)
    return _excitation(rig, axis, n, codes, closed_loop, "prbs")


def _steps(rig: Rig, axis: str, n: int, closed_loop: bool) -> Scenario:
    amp = excitation_amplitude_codes(rig, axis)
    per = max(2, math.floor(0.25 / rig.period_s + 0.5))
    return _excitation(rig, axis, n, step_codes(n, amp, per), closed_loop, "steps")


def _chirp(rig: Rig, axis: str, n: int, closed_loop: bool) -> Scenario:
    amp = excitation_amplitude_codes(rig, axis)
    f_nyq = 0.5 / rig.period_s
    codes = chirp_codes(n, rig.period_s, amp, 0.5, min(40.0, 0.4 * f_nyq))
    return _excitation(rig, axis, n, codes, closed_loop, "chirp")


def _track(rig: Rig, axis: str, n: int, closed_loop: bool) -> Scenario:
    i = rig.axis_names.index(axis)
    ax = rig.axis(axis)
    v = 0.5 * ax.speed_limit_rpm / 60.0 * rig.counts_per_rev
    acc = v / 0.25
    t_move = max(0.2, 0.5 * n * rig.period_s - 0.3)
    dist = v * t_move
    if ax.travel_counts is not None:
        dist = min(dist, 0.8 * ax.travel_counts[1])
    start = min(n // 10, math.floor(0.2 / rig.period_s + 0.5))
    ref = trapezoid_ref(n, rig.period_s, dist, v, acc, start_tick=start)
    mode = np.full(n, MODE_TASK, dtype=np.int64)
    mode[:start] = MODE_LOCK
    end = n - max(1, n // 10)
    mode[end:] = MODE_LOCK
    inp = Inputs.hold(n, len(rig.axes)).replace_axis(i, ref_counts=ref, mode=mode)
    # slaves of the moved axis follow it in the same window
    if ax.role == "master":
        for j, other in enumerate(rig.axes):
            if other.role == "slave":
                inp = inp.replace_axis(j, mode=mode)
    return Scenario(name="track", axis=axis, inputs=inp, needs_task_law=True)


def sync_move(
    rig: Rig,
    *,
    seconds: float = 2.4,
    speed_fraction: float = 0.5,
    accel_s: float = 0.1,
    load_step_v: float = 0.3,
) -> Scenario:
    """The slave-tuning run: master start, constant speed, stop; a load step on the slave.

    The master moves a trapezoid at ``speed_fraction`` of its speed limit, reaching it in
    ``accel_s``; every slave follows it (task mode) over the same window; halfway through the
    constant-speed part a load of ``load_step_v`` (equivalent drive input) steps onto each slave
    and stays. The first 0.1 s and the last 10 % of the run the axes are in lock.

    Parameters
    ----------
    rig : Rig
    seconds : float
        Run length [s].
    speed_fraction : float
        Cruise speed as a fraction of the master's speed limit, in (0, 1].
    accel_s : float
        Time to reach the cruise speed [s].
    load_step_v : float
        Load step on the slaves [V].

    Returns
    -------
    Scenario
        ``axis`` is the master.
    """
    if not 0 < speed_fraction <= 1:
        raise SpecError(f"speed_fraction must be in (0, 1], got {show_value(speed_fraction)}")
    if not accel_s > 0:
        raise SpecError(f"accel_s must be > 0 [s], got {show_value(accel_s)}")
    if not (isinstance(seconds, int | float) and math.isfinite(seconds) and seconds > 0):
        raise SpecError(f"seconds must be a number > 0 [s], got {show_value(seconds)}")
    check_run_memory(rig, seconds / rig.period_s, f"a sync move of {seconds:g} s")
    n = math.floor(seconds / rig.period_s + 0.5)
    if n < 50:
        raise SpecError(f"seconds={show_value(seconds)} gives only {n} ticks; need at least 50")
    i_m = next((i for i, a in enumerate(rig.axes) if a.role == "master"), None)
    if i_m is None:
        raise SpecError(f"rig {show_value(rig.name)} has no master axis")
    master = rig.axes[i_m]
    start = math.floor(0.1 / rig.period_s + 0.5)
    end = n - max(1, n // 10)
    v = speed_fraction * master.speed_limit_rpm / 60.0 * rig.counts_per_rev
    acc = v / accel_s
    t_move = (end - start) * rig.period_s * 0.8  # stop well before the lock takes over
    dist = v * (t_move - accel_s)
    ref = trapezoid_ref(n, rig.period_s, dist, v, acc, start_tick=start)
    mode = np.full(n, MODE_TASK, dtype=np.int64)
    mode[:start] = MODE_LOCK
    mode[end:] = MODE_LOCK
    t_cruise_mid = start + math.floor((accel_s + 0.5 * (t_move - 2 * accel_s)) / rig.period_s)
    load = np.zeros(n)
    load[t_cruise_mid:] = load_step_v
    inp = Inputs.hold(n, len(rig.axes)).replace_axis(i_m, ref_counts=ref, mode=mode)
    for j, other in enumerate(rig.axes):
        if other.role == "slave":
            inp = inp.replace_axis(j, mode=mode, load_v=load)
    return Scenario(name="sync", axis=master.name, inputs=inp, needs_task_law=True)


_SYNC_MOVE_FIELDS = ("seconds", "speed_fraction", "accel_s", "load_step_v")


def sync_move_for(rig: Rig, run: Any) -> Scenario:
    """:func:`sync_move` with the run ``run`` describes: its ``seconds``, ``speed_fraction``,
    ``accel_s`` and ``load_step_v`` (a slave tuning's ``SlaveTuneSpec``, a verification spec's
    sync ``ScenarioSpec``)."""
    return sync_move(rig, **{name: getattr(run, name) for name in _SYNC_MOVE_FIELDS})


def step_inputs(rig: Rig, *, step_counts: int, seconds: float = 2.0) -> Inputs:
    """A step of the master's reference by ``step_counts`` after 0.1 s of lock; all axes in task.

    Raises
    ------
    SpecError
        If the run is too short.
    """
    if not (isinstance(seconds, int | float) and math.isfinite(seconds) and seconds > 0):
        raise SpecError(f"seconds must be a number > 0 [s], got {show_value(seconds)}")
    check_run_memory(rig, seconds / rig.period_s, f"a step run of {seconds:g} s")
    n = math.floor(seconds / rig.period_s + 0.5)
    lead = math.floor(0.1 / rig.period_s + 0.5)
    if n <= lead + 10:
        raise SpecError(f"seconds must exceed 0.15 s [s], got {show_value(seconds)}")
    master = next((i for i, a in enumerate(rig.axes) if a.role == "master"), 0)
    mode = np.full(n, MODE_TASK, dtype=np.int64)
    mode[:lead] = MODE_LOCK
    ref = np.zeros(n, dtype=np.int64)
    ref[lead:] = int(step_counts)
    inp = Inputs.hold(n, len(rig.axes)).replace_axis(master, ref_counts=ref)
    for i in range(len(rig.axes)):
        inp = inp.replace_axis(i, mode=mode)
    return inp


def _sync(rig: Rig, axis: str, n: int, closed_loop: bool) -> Scenario:
    return sync_move(rig, seconds=n * rig.period_s)


SCENARIOS: dict[str, Callable[[Rig, str, int, bool], Scenario]] = {
    "chirp": _chirp,
    "prbs": _prbs,
    "steps": _steps,
    "sync": _sync,
    "track": _track,
}
"""Named scenarios of the virtual rig."""


def build_scenario(
    rig: Rig, name: str, *, axis: str, seconds: float, closed_loop: bool = False
) -> Scenario:
    """Build a named scenario for ``seconds`` of ticks on ``axis``.

    Raises
    ------
    SpecError
        Unknown scenario or a duration shorter than one tick.
    BudgetError
        If the run would exceed the memory budget (:func:`check_run_memory`).
    """
    if name not in SCENARIOS:
        raise SpecError(
            f"unknown scenario {show_value(name)}; choose one of {', '.join(sorted(SCENARIOS))}"
        )
    rig.axis(axis)
    if not (
        isinstance(seconds, int | float)
        and not isinstance(seconds, bool)
        and math.isfinite(seconds)
        and seconds > 0
    ):
        raise SpecError(f"seconds must be > 0 [s], got {show_value(seconds)}")
    check_run_memory(rig, seconds / rig.period_s, f"simulate {seconds:g} s")
    n = math.floor(seconds / rig.period_s + 0.5)
    if n < 10:
        raise SpecError(f"seconds={show_value(seconds)} gives only {n} ticks; need at least 10")
    return SCENARIOS[name](rig, axis, n, closed_loop)
