"""The runtime's per-axis tick: counter read and unwrap, modes, faults, and the task law.

Positions are int64 counts relative to each axis's first read (its power-up home).
A controller tick (engine, C runtime) first calls :func:`axis_read` for every axis (so a slave
can use its master's position read in the same tick), then :func:`axis_control` for every axis.
State and constants are small int64 arrays whose layouts (the ``S_*`` and ``C_*`` indices) are
shared with the C runtime's structs.

Modes (``MODE_*``): *lock* (the position-lock module holds the lock target), *task* (the task
law follows the reference), *open* (the output is the additive command alone, for open-loop
experiments). Switches are bumpless (docs/runtime.md#modes-and-bumpless-switches): entering a task
sets ``I := u_last − Kp·e`` and ``e_prev := e``, ``r_prev := r``; leaving it latches the lock target
at the current position. Faults (counter fault, following-error trip) latch: the code goes to 0 V
until a reset.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from servotune._numba_cache import jit
from servotune.errors import SpecError
from servotune.fixed import F_U, Fixed, align, quantize, sat_add, shift_round
from servotune.hw.counter import unwrap_step
from servotune.laws.filters import (
    ACC_LIMIT,
    N_FILTER_STATE,
    Section,
    SectionQ,
    biquad_step,
    state_bound,
)
from servotune.laws.fuzzy_pid import (
    TABLE_NAMES,
    FuzzyPIDConstants,
    feed_terms,
    fuzzy_level,
    scheduled_gain,
)
from servotune.laws.lock import lock_step
from servotune.laws.pi import PIConstants, pi_enter, pi_step
from servotune.laws.shaping import check_taps
from servotune.validate import check_keys, show_value

__all__ = [
    "CONST_HEADER",
    "FILTER_F",
    "FILTER_WORDS",
    "FLAG_COUNTER_FAULT",
    "FLAG_FOLLOWING_ERROR",
    "FLAG_SATURATED",
    "FLAG_SYNC_TRIP",
    "LAW_FUZZY_PID",
    "LAW_NONE",
    "LAW_PI",
    "MAX_FILTERS",
    "MODE_LOCK",
    "MODE_OPEN",
    "MODE_TASK",
    "TASK_LAWS",
    "AxisController",
    "LawWord",
    "TaskLaw",
    "axis_control",
    "axis_read",
    "check_filter_designs",
    "filter_block",
    "filter_chain",
    "filter_input_bound",
    "filter_overflow_problem",
    "law_names",
    "switch_filters",
    "task_law",
]

# modes
MODE_LOCK = 0
MODE_TASK = 1
MODE_OPEN = 2  # a log's mode column names them: servotune.io.log_rows.MODE_NAMES

# task laws (their descriptions: TASK_LAWS, after the constants layout)
LAW_NONE = 0
LAW_PI = 1
LAW_FUZZY_PID = 2

# flags (faults latch; SATURATED is per tick)
FLAG_COUNTER_FAULT = 1
FLAG_FOLLOWING_ERROR = 2
FLAG_SATURATED = 4
FLAG_SYNC_TRIP = 8  # set by the synchronisation monitor (laws.sync): the axis stops
FAULT_MASK = FLAG_COUNTER_FAULT | FLAG_FOLLOWING_ERROR | FLAG_SYNC_TRIP

# state layout (int64)
S_INIT = 0
S_HI_PREV = 1
S_WRAPS = 2
S_Y = 3
S_MODE = 4
S_FAULT = 5
S_LOCK_TARGET = 6
S_INTEG = 7
S_U_LAST = 8
S_E_PREV = 9
S_R_PREV = 10
S_ORIGIN = 11
S_FILT = 12  # MAX_FILTERS sections of N_FILTER_STATE words (laws.filters): x1 x2 y1 y2 r1 r2
N_STATE = 12 + 6 * 4

# output filters (docs/runtime.md#filters-in-the-law)
MAX_FILTERS = 4
"""Filter sections per axis, in series on the law's output before the D/A."""
FILTER_WORDS = 6
"""Constants per section: ``b0 b1 b2 a1 a2 frac_bits`` (a ``laws.filters.SectionQ``)."""
FILTER_F = 16
"""Fraction bits of the filters' input and output [D/A codes]: ``u`` rounded from ``F_U``."""

# constants layout (int64)
C_LAW = 0
C_LOCK_Q = 1
C_LOCK_F = 2
C_KP_Q = 3
C_KP_F = 4
C_KIT_Q = 5
C_KIT_F = 6
C_FE_LIMIT = 7
C_COUNTER_BITS = 8
C_DAC_ZERO = 9
C_DAC_MAX = 10
C_KDT_Q = 11
C_KDT_F = 12
C_K1T_Q = 13
C_K1T_F = 14
C_KE_Q = 15
C_KE_F = 16
C_KEC_Q = 17
C_KEC_F = 18
C_N = 19
C_TF = 20  # 4 table fraction bits, TABLE_NAMES order
C_NF = 24  # filter sections in use, 0 .. MAX_FILTERS
C_FILT = 25  # MAX_FILTERS sections of FILTER_WORDS: b0 b1 b2 a1 a2 frac_bits
C_TAB = 49  # 4 tables of (2n+1)^2 entries, row-major (row E, column EC), TABLE_NAMES order
N_CONST = C_TAB
"""Length of the constants vector without tables (the fuzzy-PID law appends its tables)."""

CONST_HEADER: tuple[tuple[str, int, bool], ...] = (
    ("law", C_LAW, False),
    ("lock", C_LOCK_Q, True),
    ("kp", C_KP_Q, True),
    ("kit", C_KIT_Q, True),
    ("fe_limit", C_FE_LIMIT, False),
    ("counter_bits", C_COUNTER_BITS, False),
    ("dac_zero", C_DAC_ZERO, False),
    ("dac_max", C_DAC_MAX, False),
    ("kdt", C_KDT_Q, True),
    ("k1t", C_K1T_Q, True),
    ("ke", C_KE_Q, True),
    ("kec", C_KEC_Q, True),
    ("n", C_N, False),
)
"""The constants vector before the tables, as the C runtime's ``st_axis_consts_t`` holds it:
per word its field stem, its slot and whether it is a (q, f) pair (slots ``q``, ``q + 1``; the
fields ``<stem>_q``, ``<stem>_f``) or one integer (the field ``<stem>``). The C layout's part 1
(:mod:`servotune.export.layout`) walks it in this order."""


@dataclass(frozen=True, slots=True)
class LawWord:
    """One gain of a task law: a (q, f) pair of the constants vector.

    Parameters
    ----------
    key : str
        The field of the law's constants and the key in the tables document (``ki_t``).
    slot : int
        Its ``q`` slot (``C_*``; ``f`` is the next); a stem of :data:`CONST_HEADER`.
    title : str
        What it is, with its unit (the C headers' comment).
    """

    key: str
    slot: int
    title: str

    @property
    def stem(self) -> str:
        """The C name stem: the fields ``.<stem>_q``/``_f`` and the macros
        ``ST_<AXIS>_<STEM>_Q``/``_F``."""
        return next(name for name, slot, _ in CONST_HEADER if slot == self.slot)


@dataclass(frozen=True, slots=True)
class TaskLaw:
    """A task law as every consumer of the constants reads it: the one description of its name,
    code, constants and C names (docs/contributing.md#adding-a-control-law).

    Parameters
    ----------
    name : str
        Its name in files (``law`` of the tables document, the tuning document).
    code : int
        ``c[C_LAW]`` and the C runtime's ``ST_LAW_<NAME>``.
    constants : type
        The dataclass of its quantised constants (``to_dict``, ``from_dict``, a
        :class:`~servotune.fixed.Fixed` field per word).
    words : tuple of LawWord
        Its gains, in the order the C headers list them.
    tables : tuple of str
        Its query tables (``n`` levels each side, in ``C_TF``/``C_TAB``), empty if none.
    table_titles : tuple of str
        What each table holds, with its unit (the C headers' comment).
    ideal : bool
        The engine's ideal floating-point mode (design checks) runs it.
    """

    name: str
    code: int
    constants: type
    words: tuple[LawWord, ...]
    tables: tuple[str, ...] = ()
    table_titles: tuple[str, ...] = ()
    ideal: bool = True

    @property
    def macro(self) -> str:
        """The C runtime's name of its code."""
        return f"ST_LAW_{self.name.upper()}"


TASK_LAWS: dict[str, TaskLaw] = {
    "pi": TaskLaw(
        name="pi",
        code=LAW_PI,
        constants=PIConstants,
        words=(
            LawWord("kp", C_KP_Q, "Kp [LSB/count]"),
            LawWord("ki_t", C_KIT_Q, "Ki*T [LSB/count/tick]"),
        ),
    ),
    "fuzzy_pid": TaskLaw(
        name="fuzzy_pid",
        code=LAW_FUZZY_PID,
        constants=FuzzyPIDConstants,
        words=(
            LawWord("kp", C_KP_Q, "Kp0 [LSB/count]"),
            LawWord("ki_t", C_KIT_Q, "Ki0*T [LSB/count/tick]"),
            LawWord("kd_t", C_KDT_Q, "Kd0/T [LSB per count change per tick]"),
            LawWord("k1_t", C_K1T_Q, "K10/T, feedforward [LSB per count change per tick]"),
            LawWord("ke", C_KE_Q, "Ke [levels/count]"),
            LawWord("kec", C_KEC_Q, "Kec [levels per count/tick]"),
        ),
        tables=TABLE_NAMES,
        table_titles=(
            "dKp [LSB/count]",
            "d(Ki*T) [LSB/count/tick]",
            "d(Kd/T) [LSB per count change per tick]",
            "d(K1/T) [LSB per count change per tick]",
        ),
        ideal=False,
    ),
}
"""The task laws by name. A new law adds its description here (and its step: the branch in
:func:`axis_control` and in the C runtime's ``st_tick``); the constants vector, the tables
document, the C headers and the C layout read it from here."""


def law_names() -> tuple[str, ...]:
    """Every law's name a file may give: ``none`` (lock only), then :data:`TASK_LAWS`."""
    return ("none", *TASK_LAWS)


def task_law(task: object) -> TaskLaw:
    """The description of a law's constants (``AxisController.task``).

    Raises
    ------
    TypeError
        If ``task`` is no registered law's constants.
    """
    for law in TASK_LAWS.values():
        if type(task) is law.constants:
            return law
    raise TypeError(f"{type(task).__name__} is no task law's constants (laws.axis.TASK_LAWS)")


def _sections(v: object) -> tuple[SectionQ, ...]:
    if not isinstance(v, list) or not 1 <= len(v) <= MAX_FILTERS:
        raise ValueError(
            f"controller.filters must be a list of 1..{MAX_FILTERS} sections, got {show_value(v)}"
        )
    return tuple(SectionQ.from_dict(x, f"controller.filters[{k}]") for k, x in enumerate(v))


@dataclass(frozen=True, slots=True, kw_only=True)
class AxisController:
    """What the runtime holds for one axis, every constant quantised.

    Parameters
    ----------
    lock_gain : Fixed
        Position-lock gain [D/A LSB per count].
    task : PIConstants or FuzzyPIDConstants or None
        Task law: PI, or the composite fuzzy-PID + feedforward law; None for an axis that only
        locks or runs open loop.
    following_error_limit_counts : int
        Trip threshold on |e| [counts]; 0 disables it.
    filters : tuple of SectionQ
        Up to :data:`MAX_FILTERS` quantised sections in series on the output before the D/A
        (:mod:`servotune.laws.filters`), in the order they run; empty: no filter.
    shaper : tuple of int
        Q15 amplitudes of the input shaper of the axis's task reference
        (:mod:`servotune.laws.shaping`; docs/runtime.md#shapers-in-the-tables), tick 0 first;
        empty: none. The law does not run it: the firmware (``servotune_shaper.h``) or the HAL
        component shapes the reference it hands the tick.
    """

    lock_gain: Fixed
    task: PIConstants | FuzzyPIDConstants | None = None
    following_error_limit_counts: int = 0
    filters: tuple[SectionQ, ...] = ()
    shaper: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if self.following_error_limit_counts < 0:
            raise ValueError(
                "following_error_limit_counts must be >= 0 [counts], "
                f"got {self.following_error_limit_counts}"
            )
        filter_block(self.filters)  # at most MAX_FILTERS quantised sections
        if self.shaper:
            object.__setattr__(self, "shaper", check_taps(self.shaper, "shaper"))

    @classmethod
    def from_gains(
        cls,
        *,
        lock_gain_codes_per_count: float,
        task_gains: object | None = None,
        period_s: float,
        following_error_limit_counts: int = 0,
        filters: tuple[SectionQ, ...] = (),
    ) -> AxisController:
        """Quantise design gains.

        ``task_gains``: a :class:`~servotune.laws.pi.PIGains` or a
        :class:`~servotune.laws.fuzzy_pid.FuzzyPIDGains` (anything with ``quantize(period_s)``),
        or None for lock only.
        """
        return cls(
            lock_gain=quantize(lock_gain_codes_per_count),
            task=None if task_gains is None else task_gains.quantize(period_s),  # type: ignore[attr-defined]
            following_error_limit_counts=int(following_error_limit_counts),
            filters=tuple(filters),
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain dict: the law's name and every constant as its (q, f) pair; ``filters`` (each
        section's integers) and ``shaper`` (its Q15 amplitudes) only when there are any, so a
        controller without them has the document it had before they existed."""
        d: dict[str, Any] = {
            "following_error_limit_counts": self.following_error_limit_counts,
            "law": "none" if self.task is None else task_law(self.task).name,
            "lock_gain": self.lock_gain.to_dict(),
            "task": None if self.task is None else self.task.to_dict(),
        }
        if self.filters:
            d["filters"] = [s.to_dict() for s in self.filters]
        if self.shaper:
            d["shaper"] = list(self.shaper)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> AxisController:
        """Inverse of :meth:`to_dict` (no re-quantising).

        Raises
        ------
        ValueError
            If a field is missing or malformed (the message names it).
        """
        d = check_keys(
            d,
            "controller",
            ("following_error_limit_counts", "law", "lock_gain", "task"),
            ("filters", "shaper"),
        )
        try:
            law = d["law"]
            if law not in law_names():
                raise ValueError(
                    f"law must be one of {', '.join(law_names())}, got {show_value(law)}"
                )
            task_d = d["task"]
            described = TASK_LAWS.get(law)
            task = None if described is None else described.constants.from_dict(task_d)
            if described is None and task_d is not None:
                raise ValueError(f"task must be null for the law 'none', got {show_value(task_d)}")
            fe = d["following_error_limit_counts"]
            if type(fe) is not int or not 0 <= fe <= 2**31 - 1:
                raise ValueError(
                    f"following_error_limit_counts must be an integer in 0..2**31-1 [counts] "
                    f"(0 = off), got {show_value(fe)}"
                )
            return cls(
                lock_gain=Fixed.from_dict(d["lock_gain"]),
                task=task,
                following_error_limit_counts=fe,
                filters=() if "filters" not in d else _sections(d["filters"]),
                shaper=() if "shaper" not in d else check_taps(d["shaper"], "controller.shaper"),
            )
        except KeyError as exc:
            raise ValueError(f"controller is missing the field {show_value(exc.args[0])}") from None
        except TypeError as exc:
            raise ValueError(f"controller is malformed: {exc}") from None

    @property
    def law(self) -> int:
        """The task law's code (``LAW_*``, :attr:`TaskLaw.code`)."""
        return LAW_NONE if self.task is None else task_law(self.task).code

    def consts(self, *, counter_bits: int, dac_bits: int, dac_zero: int) -> np.ndarray:
        """The constants vector (``C_*`` layout, then the tables) the tick functions read."""
        t = self.task
        law = None if t is None else task_law(t)
        tables = () if law is None else law.tables
        size = (2 * t.n + 1) ** 2 if tables else 0  # type: ignore[union-attr]
        c = np.zeros(N_CONST + len(tables) * size, dtype=np.int64)
        c[C_LAW] = LAW_NONE if law is None else law.code
        c[C_LOCK_Q], c[C_LOCK_F] = self.lock_gain.q, self.lock_gain.f
        for word in () if law is None else law.words:
            value = getattr(t, word.key)
            c[word.slot], c[word.slot + 1] = value.q, value.f
        if tables:
            c[C_N] = t.n  # type: ignore[union-attr]
            for i, (q, f_t) in enumerate(t.tables):  # type: ignore[union-attr]
                c[C_TF + i] = f_t
                c[C_TAB + i * size : C_TAB + (i + 1) * size] = q.reshape(-1)
        c[C_FE_LIMIT] = self.following_error_limit_counts
        c[C_COUNTER_BITS] = counter_bits
        c[C_DAC_ZERO] = dac_zero
        c[C_DAC_MAX] = 2**dac_bits - 1
        c[C_NF:C_TAB] = filter_block(self.filters)
        return c


def filter_block(sections: Sequence[SectionQ]) -> np.ndarray:
    """The constants of an output filter chain as the law holds them, ``c[a, C_NF:C_TAB]``:
    the number of sections, then :data:`MAX_FILTERS` slots of ``b0 b1 b2 a1 a2 frac_bits``
    (unused slots zero). What :func:`switch_filters` takes.

    Raises
    ------
    ValueError
        If there are more than :data:`MAX_FILTERS` sections or one is not a ``SectionQ``.
    """
    sections = tuple(sections)
    if len(sections) > MAX_FILTERS or not all(isinstance(s, SectionQ) for s in sections):
        raise ValueError(
            f"filters must be at most {MAX_FILTERS} quantised sections (SectionQ), "
            f"got {show_value(sections)}"
        )
    block = np.zeros(C_TAB - C_NF, dtype=np.int64)
    block[0] = len(sections)
    for k, sec in enumerate(sections):
        block[1 + k * FILTER_WORDS : 1 + (k + 1) * FILTER_WORDS] = sec.step_args()
    return block


def filter_input_bound(zero: int, code_max: int) -> int:
    """The largest magnitude an output filter's input takes: the law holds it to the D/A's
    range, ``−zero … code_max − zero`` codes, with ``FILTER_F`` fraction bits (at least one
    code)."""
    return max(zero, code_max - zero, 1) << FILTER_F


def check_filter_designs(
    filters: Sequence[Section], name: str = "filters", error: type[Exception] = ValueError
) -> None:
    """An axis's output filters as designed: at most :data:`MAX_FILTERS`
    :class:`~servotune.laws.filters.Section` (``error`` naming ``name`` otherwise)."""
    if len(filters) > MAX_FILTERS or not all(isinstance(f, Section) for f in filters):
        raise error(
            f"{name} must be at most {MAX_FILTERS} filter sections, got {show_value(filters)}"
        )


def filter_overflow_problem(sections: Sequence[SectionQ], zero: int, code_max: int) -> str | None:
    """Why the runtime's sums could overflow in one of an axis's filter sections, or ``None``.

    The law holds each section's input to the D/A's range (``−zero … code_max − zero`` codes,
    ``FILTER_F`` fraction bits: docs/runtime.md#filters-in-the-law); every partial sum of its
    accumulator must then stay within ±2^62 (:func:`~servotune.laws.filters.state_bound`), the
    bound behind the C runtime's promise of no undefined behaviour.
    """
    bound = filter_input_bound(zero, code_max)
    for k, sec in enumerate(sections):
        try:
            acc = state_bound(sec, bound).acc_max
        except SpecError as exc:
            return f"filters[{k}]: {exc}"
        if acc > ACC_LIMIT:
            return (
                f"filters[{k}]: for inputs within the D/A range (±{bound} at 2^-{FILTER_F} "
                f"codes) its sums could reach 2^{acc.bit_length() - 1}, beyond ±2^62"
            )
    return None


@jit(inline="always")
def axis_read(st: np.ndarray, c: np.ndarray, a: int, raw: int, reset: bool) -> int:
    """Read one axis's counter: unwrap with the high-byte rule, flag a counter fault.

    Parameters
    ----------
    st : ndarray of int64, shape (axes, N_STATE)
        Axis states (``S_*`` layout), row ``a`` updated in place.
    c : ndarray of int64, shape (axes, N_CONST)
        Axis constants (``C_*`` layout).
    a : int
        The axis (row).
    raw : int
        Register value assembled from the byte reads.
    reset : bool
        Re-initialise the unwrap from this read (after a fault reset).

    Returns
    -------
    int
        Extended position [counts], relative to the first read (the power-up home), so every
        axis's positions and references share one frame.
    """
    bits = c[a, C_COUNTER_BITS]
    if st[a, S_INIT] == 0:
        st[a, S_ORIGIN] = raw
        st[a, S_WRAPS] = 0
        st[a, S_LOCK_TARGET] = 0
        st[a, S_R_PREV] = 0
        st[a, S_INIT] = 1
        reset = True
    if reset:
        st[a, S_HI_PREV] = (raw >> (bits - 8)) & 0xFF
        y = st[a, S_WRAPS] * (np.int64(1) << bits) + raw - st[a, S_ORIGIN]
        st[a, S_Y] = y
        return y
    ext, hi, wraps, fault = unwrap_step(raw, st[a, S_HI_PREV], st[a, S_WRAPS], bits)
    st[a, S_HI_PREV] = hi
    st[a, S_WRAPS] = wraps
    if fault:
        st[a, S_FAULT] |= FLAG_COUNTER_FAULT
    y = ext - st[a, S_ORIGIN]
    st[a, S_Y] = y
    return y


@jit(inline="always")
def filter_chain(
    st: np.ndarray, c: np.ndarray, a: int, nf: int, x: int, zero: int, cmax: int
) -> tuple[int, bool]:
    """The output filters of axis ``a`` (``nf`` sections, in order) on ``x`` [D/A codes relative
    to the zero, ``FILTER_F`` fraction bits]; returns whole codes relative to the zero, and
    whether a section's input was held at a rail.

    Each section's input is first held to the D/A's range (``−zero … cmax − zero`` codes), the
    input bound its word length and accumulator were sized for
    (:func:`~servotune.laws.filters.state_bound`); the output is rounded half away from zero to
    whole codes. A held input is a saturation as a code on a rail is (``FLAG_SATURATED``).
    """
    lo = -zero * (np.int64(1) << FILTER_F)
    hi = (cmax - zero) * (np.int64(1) << FILTER_F)
    held = False
    row = st[a]
    crow = c[a]
    for k in range(nf):
        if x < lo or x > hi:
            held = True
            x = min(max(x, lo), hi)
        p = C_FILT + k * FILTER_WORDS
        x = biquad_step(
            crow[p],
            crow[p + 1],
            crow[p + 2],
            crow[p + 3],
            crow[p + 4],
            crow[p + 5],
            row,
            S_FILT + k * N_FILTER_STATE,
            x,
        )
    return shift_round(x, FILTER_F), held


@jit(inline="always")
def axis_control(
    st: np.ndarray, c: np.ndarray, a: int, ref: int, mode_cmd: int, reset: bool, u_add: int
) -> tuple[int, int, int]:
    """One axis's control step after :func:`axis_read`.

    Parameters
    ----------
    st, c : ndarray of int64
        Axis states (row ``a`` updated in place) and constants, as in :func:`axis_read`.
    a : int
        The axis (row).
    ref : int
        Task reference this tick [counts, extended].
    mode_cmd : int
        Requested mode (``MODE_LOCK``, ``MODE_TASK``, ``MODE_OPEN``).
    reset : bool
        Clear latched faults; the axis returns to lock at its current position.
    u_add : int
        Command added to the output [D/A codes] (excitation; the whole output in open mode).

    Returns
    -------
    code : int
        D/A code to write.
    flags : int
        ``FLAG_*`` bits: latched faults, and ``FLAG_SATURATED`` if the output hit a rail.
    e : int
        The law's error this tick [counts] (0 in open mode or under a fault).
    """
    zero = c[a, C_DAC_ZERO]
    cmax = c[a, C_DAC_MAX]
    y = st[a, S_Y]
    if reset:
        st[a, S_FAULT] = 0
        st[a, S_MODE] = MODE_LOCK
        st[a, S_LOCK_TARGET] = y
        st[a, S_INTEG] = 0
        st[a, S_U_LAST] = 0
        st[a, S_E_PREV] = 0
        st[a, S_R_PREV] = ref
        st[a, S_FILT : S_FILT + MAX_FILTERS * N_FILTER_STATE] = 0
    if st[a, S_FAULT] != 0:
        st[a, S_U_LAST] = 0
        return zero, st[a, S_FAULT], 0
    if mode_cmd == MODE_TASK and c[a, C_LAW] == LAW_NONE:
        mode_cmd = MODE_LOCK  # no task law: the lock keeps the axis
    entering = mode_cmd == MODE_TASK and st[a, S_MODE] != MODE_TASK
    if mode_cmd == MODE_LOCK and st[a, S_MODE] != MODE_LOCK:
        st[a, S_LOCK_TARGET] = y
    st[a, S_MODE] = mode_cmd
    u_add_q = align(u_add, F_U)
    e = 0
    if mode_cmd == MODE_LOCK:
        e = st[a, S_LOCK_TARGET] - y
        u = sat_add(lock_step(c[a, C_LOCK_Q], c[a, C_LOCK_F], e), u_add_q)
    elif mode_cmd == MODE_TASK:
        e = ref - y
        kp_q = c[a, C_KP_Q]
        kit_q = c[a, C_KIT_Q]
        if c[a, C_LAW] == LAW_FUZZY_PID:
            # composite law: schedule the gains from the query tables at (E, EC), then the PI
            # core with the derivative and feedforward terms added to its output
            ec = 0 if entering else e - st[a, S_E_PREV]
            dr = 0 if entering else ref - st[a, S_R_PREV]
            n = c[a, C_N]
            size = 2 * n + 1
            lv_e = fuzzy_level(e, c[a, C_KE_Q], c[a, C_KE_F], n)
            lv_ec = fuzzy_level(ec, c[a, C_KEC_Q], c[a, C_KEC_F], n)
            cell = C_TAB + (lv_e + n) * size + lv_ec + n
            kp_q = scheduled_gain(kp_q, c[a, C_KP_F], c[a, cell], c[a, C_TF])
            kit_q = scheduled_gain(kit_q, c[a, C_KIT_F], c[a, cell + size * size], c[a, C_TF + 1])
            kd_q = scheduled_gain(
                c[a, C_KDT_Q], c[a, C_KDT_F], c[a, cell + 2 * size * size], c[a, C_TF + 2]
            )
            k1_q = scheduled_gain(
                c[a, C_K1T_Q], c[a, C_K1T_F], c[a, cell + 3 * size * size], c[a, C_TF + 3]
            )
            u_add_q = sat_add(u_add_q, feed_terms(kd_q, c[a, C_KDT_F], k1_q, c[a, C_K1T_F], ec, dr))
        if entering:
            u, st[a, S_INTEG] = pi_enter(
                kp_q, c[a, C_KP_F], st[a, S_U_LAST], e, u_add_q, zero, cmax
            )
        else:
            u, st[a, S_INTEG] = pi_step(
                kp_q,
                c[a, C_KP_F],
                kit_q,
                c[a, C_KIT_F],
                st[a, S_INTEG],
                e,
                u_add_q,
                zero,
                cmax,
            )
    else:
        u = u_add_q
    fe = c[a, C_FE_LIMIT]
    if fe > 0 and (e > fe or e < -fe):
        st[a, S_FAULT] |= FLAG_FOLLOWING_ERROR
        st[a, S_U_LAST] = 0
        return zero, st[a, S_FAULT], e
    st[a, S_U_LAST] = u
    st[a, S_E_PREV] = e
    st[a, S_R_PREV] = ref
    nf = c[a, C_NF]
    flags = st[a, S_FAULT]
    if nf == 0:
        code = shift_round(u, F_U) + zero  # code_from_uq, with the rail flag on the way
    else:
        v, held = filter_chain(st, c, a, nf, shift_round(u, F_U - FILTER_F), zero, cmax)
        code = v + zero
        if held:
            flags |= FLAG_SATURATED
    if code > cmax:
        code = cmax
        flags |= FLAG_SATURATED
    elif code < 0:
        code = 0
        flags |= FLAG_SATURATED
    return code, flags, e


@jit
def switch_filters(st: np.ndarray, c: np.ndarray, a: int, block: np.ndarray) -> None:
    """Switch axis ``a``'s output filters to ``block`` (:func:`filter_block`) between two ticks,
    while it runs: a filter switched in, re-tuned or switched out without a bump.

    The constants ``c[a, C_NF:C_TAB]`` become ``block``; the new sections' state is the
    chain's steady state at its last input and output (``laws.filters.bumpless_state``):
    section 0 ``x1 = x2 = x``, ``y1 = y2 = y``; every later one ``x1 = x2 = y1 = y2 = y``;
    remainders zero. ``x`` is the chain's last input (section 0's, held to the D/A range) and
    ``y`` its last output [D/A codes, ``FILTER_F`` fraction bits]; without filters before, both
    are the last output ``u`` rounded to ``FILTER_F`` fraction bits and held to the range. At a
    steady input the next code is then the last one within 1 LSB (a notch or a low-pass: DC
    gain 1). The caller passes sections realised for the axis's D/A range
    (``Rig.runtime_filters``), as an exported tables document holds them.
    """
    zero = c[a, C_DAC_ZERO]
    lo = -zero * (np.int64(1) << FILTER_F)
    hi = (c[a, C_DAC_MAX] - zero) * (np.int64(1) << FILTER_F)
    nf = c[a, C_NF]
    if nf > 0:
        x = st[a, S_FILT]
        y = st[a, S_FILT + (nf - 1) * N_FILTER_STATE + 2]
    else:
        x = min(max(shift_round(st[a, S_U_LAST], F_U - FILTER_F), lo), hi)
        y = x
    for j in range(C_TAB - C_NF):
        c[a, C_NF + j] = block[j]
    for k in range(MAX_FILTERS):
        o = S_FILT + k * N_FILTER_STATE
        held = x if k == 0 else y
        on = k < block[0]
        st[a, o] = held if on else 0
        st[a, o + 1] = held if on else 0
        st[a, o + 2] = y if on else 0
        st[a, o + 3] = y if on else 0
        st[a, o + 4] = 0
        st[a, o + 5] = 0
