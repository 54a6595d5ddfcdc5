"""Input shaping of a move's reference: ZV, ZVD and EI shapers on the tick grid, and their
integer step (docs/runtime.md#input-shaping).

A shaper convolves the reference with a short train of impulses whose amplitudes sum to 1 and
whose residual vibration at a lightly damped mode ``(f, ζ)`` vanishes. With ``s = ζω + jω_d``
(``ω = 2πf``, ``ω_d = ω√(1 − ζ²)``) an impulse train ``A_i`` at times ``t_i`` leaves, relative to
a single unit impulse, the vibration

    V(f, ζ) = e^{−ζω t_N} · |Σ_i A_i e^{s t_i}|

(Singer and Seering's percentage residual vibration, as a fraction). The textbook shapers put
their impulses at multiples of the half damped period, which the runtime cannot: it shifts the
reference by whole ticks. Here every impulse time is a whole number of ticks and the amplitudes
are **re-solved** on that grid so that the constraints still hold exactly:

* ``zv`` — ``V = 0`` at the mode (the sum ``Σ A_i e^{s t_i}`` is zero: two real equations);
* ``zvd`` — also its derivative in frequency (``Σ A_i t_i e^{s t_i} = 0``), flat around the mode;
* ``ei`` — extra-insensitive: ``V = 0`` at ``f (1 ± β)`` instead, ``β`` the undamped EI's zeros
  for the tolerance :data:`EI_TOLERANCE` (``cos πβ' = −(1 − V)/(1 + V)``, ``β = 1 − β'``), so that
  ``V`` stays near that tolerance over the whole band between them;

plus ``Σ A_i = 1`` (the shaped move ends where the move ends) and ``A_i ≥ 0`` (the shaped
reference of a monotone move stays monotone). The amplitudes are the ones closest to the
textbook shaper's impulses split linearly onto the two ticks around them (a weighted least
squares with the constraints, bounded-variable least squares for ``A ≥ 0``, then the equality
constraints polished exactly on the support). Two or more modes: the product (convolution) of
one shaper per mode. The move gets longer by the shaper's length, ``(N − 1)`` ticks.

**Integer step.** The amplitudes are Q15 integers (:data:`SHAPER_FRAC_BITS`) summing to exactly
``2^15`` (rounded down, then the missing units to the largest remainders), and the shaped
reference of tick ``k`` is ``shift_round(Σ_i a_i · r[k − i], 15)`` over the last ``N``
references (the runtime's rounding, half away from zero): a constant reference passes
unchanged, to the count. Before the first tick the history holds the first reference (an axis
at rest stays at rest). :func:`shaper_step` is the one home of that step; the C mirror
(``servotune_shaper.h``) and the HAL component run the same integers.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from servotune._numba_cache import jit
from servotune.errors import SpecError
from servotune.fixed import shift_round
from servotune.validate import show_value

__all__ = [
    "EI_TOLERANCE",
    "KINDS",
    "MAX_REFERENCE",
    "MAX_SHAPER_TAPS",
    "MIN_SPREAD",
    "RESIDUAL_GOAL",
    "SHAPER_FRAC_BITS",
    "Shaper",
    "check_taps",
    "choose_shaper",
    "design_shaper",
    "residual_vibration",
    "shape_reference",
    "shaper_for_modes",
    "shaper_state",
    "shaper_step",
]

KINDS = ("zv", "zvd", "ei")
"""Shaper kinds, shortest (least robust) first."""
EI_TOLERANCE = 0.03
"""The EI shaper's design tolerance: the residual vibration it allows at the mode [fraction]."""
SHAPER_FRAC_BITS = 15
"""Fraction bits of the integer amplitudes (Q15: they sum to 2^15)."""
MAX_SHAPER_TAPS = 1024
"""Longest impulse train [ticks] (the delay line of the runtime's step)."""
RESIDUAL_GOAL = 0.05
"""Residual vibration :func:`choose_shaper` aims for over a mode's frequency range [fraction of
the unshaped move's]."""
MIN_SPREAD = 0.05
"""Smallest relative frequency range :func:`choose_shaper` designs for (±5 %), also where a
mode's 95 % interval is narrower or not known."""
MAX_REFERENCE = 1 << 47
"""Largest |reference| [counts] the step's int64 sum holds (``2^15 · 2^47 < 2^63``)."""


@dataclass(frozen=True, slots=True)
class Shaper:
    """An impulse train on the tick grid (module docstring).

    Attributes
    ----------
    kind : str
        ``zv``, ``zvd`` or ``ei``; a product of several is named ``zvd×zv`` and so on.
    modes : tuple of (float, float)
        The modes designed for, ``(freq_hz, damping)``.
    period_s : float
        The tick [s] (the achieved period).
    amplitudes : tuple of float
        Amplitude of the impulse ``i`` ticks late, ``i = 0 … N − 1`` (zeros included).
    amplitudes_q : tuple of int
        The same in Q15, summing to exactly ``2^15``.
    """

    kind: str
    modes: tuple[tuple[float, float], ...]
    period_s: float
    amplitudes: tuple[float, ...]
    amplitudes_q: tuple[int, ...]

    @property
    def n_taps(self) -> int:
        """Length of the impulse train [ticks]."""
        return len(self.amplitudes_q)

    @property
    def added_time_s(self) -> float:
        """How much longer a shaped move takes [s]: the last impulse's delay."""
        return (self.n_taps - 1) * self.period_s

    def residual(self, freq_hz: float, damping: float) -> float:
        """Residual vibration of the quantised shaper at a mode, as a fraction of the unshaped
        move's (module docstring)."""
        return residual_vibration(
            np.asarray(self.amplitudes_q, dtype=float) / (1 << SHAPER_FRAC_BITS),
            self.period_s,
            freq_hz,
            damping,
        )

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready record: kind, modes, the Q15 taps, the added time and the residual at
        each mode and at ±15 % of it."""
        return {
            "kind": self.kind,
            "modes": [{"freq_hz": f, "damping": z} for f, z in self.modes],
            "period_s": self.period_s,
            "frac_bits": SHAPER_FRAC_BITS,
            "amplitudes_q": list(self.amplitudes_q),
            "added_time_s": self.added_time_s,
            "residual": [
                {
                    "freq_hz": f,
                    "at_mode": self.residual(f, z),
                    "worst_within_15_percent": self.worst_residual(f, z, 0.15),
                }
                for f, z in self.modes
            ],
        }

    def worst_residual(self, freq_hz: float, damping: float, spread: float) -> float:
        """Largest residual vibration for a mode anywhere within ``freq_hz · (1 ± spread)``
        (121 frequencies)."""
        return max(
            self.residual(freq_hz * r, damping) for r in np.linspace(1 - spread, 1 + spread, 121)
        )


def residual_vibration(
    amplitudes: np.ndarray, period_s: float, freq_hz: float, damping: float
) -> float:
    """``V(f, ζ)`` of impulses ``amplitudes[i]`` at ``i · period_s`` (module docstring)."""
    a = np.asarray(amplitudes, dtype=float)
    w = 2 * math.pi * freq_hz
    t = np.arange(a.size) * period_s
    s = damping * w + 1j * w * math.sqrt(1 - damping * damping)
    return float(abs(np.sum(a * np.exp(s * (t - t[-1])))))


def _check(freq_hz: float, damping: float, period_s: float) -> None:
    for name, v, ok, want in (
        ("period_s", period_s, lambda x: x > 0, "> 0 [s]"),
        ("freq_hz", freq_hz, lambda x: 0 < x < 0.5 / period_s, f"in (0, {0.5 / period_s:g}) Hz"),
        ("damping", damping, lambda x: 0 <= x < 1, "in [0, 1)"),
    ):
        good = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
        if not (good and ok(v)):
            raise SpecError(f"shaper: {name} must be {want}, got {show_value(v)}")


def _textbook(kind: str, freq_hz: float, damping: float) -> tuple[np.ndarray, np.ndarray]:
    """The continuous-time shaper's amplitudes and times [s]."""
    wd = 2 * math.pi * freq_hz * math.sqrt(1 - damping * damping)
    half = math.pi / wd
    k = math.exp(-damping * math.pi / math.sqrt(1 - damping * damping))
    if kind == "zv":
        a, t = np.array([1.0, k]), np.array([0.0, half])
    elif kind == "zvd":
        a, t = np.array([1.0, 2 * k, k * k]), np.array([0.0, half, 2 * half])
    else:
        v = EI_TOLERANCE
        a, t = np.array([(1 + v) / 4, (1 - v) / 2, (1 + v) / 4]), np.array([0.0, half, 2 * half])
    return a / a.sum(), t


def _zeros(kind: str, freq_hz: float) -> list[tuple[float, int]]:
    """Where the residual and how many of its frequency derivatives vanish: (f, order)."""
    if kind == "zv":
        return [(freq_hz, 0)]
    if kind == "zvd":
        return [(freq_hz, 0), (freq_hz, 1)]
    v = EI_TOLERANCE
    beta = 1 - math.acos(-(1 - v) / (1 + v)) / math.pi
    return [(freq_hz * (1 - beta), 0), (freq_hz * (1 + beta), 0)]


def _solve(kind: str, freq_hz: float, damping: float, period_s: float) -> np.ndarray:
    """Amplitudes on the tick grid (module docstring)."""
    a_tb, t_tb = _textbook(kind, freq_hz, damping)
    zeros = _zeros(kind, freq_hz)
    n_eq = 1 + 2 * len(zeros)
    n = max(math.floor(t_tb[-1] / period_s + 1e-9) + 2, n_eq)
    if n > MAX_SHAPER_TAPS:
        raise SpecError(
            f"shaper: a {kind} shaper for {freq_hz:g} Hz needs {n} ticks of {period_s:g} s, "
            f"more than {MAX_SHAPER_TAPS}"
        )
    a0, w = np.zeros(n), np.zeros(n)
    for a, t in zip(a_tb, t_tb, strict=True):
        k = math.floor(t / period_s + 1e-9)
        frac = min(max(t / period_s - k, 0.0), 1.0)
        a0[k] += a * (1 - frac)
        a0[k + 1] += a * frac
        w[k] += a
        w[k + 1] += a
    w += 0.1 * w.max()  # every tick may take a share; the ones near an impulse are cheaper
    t = np.arange(n) * period_s
    rows, rhs = [np.ones(n)], [1.0]
    for f, order in zeros:
        wn = 2 * math.pi * f
        s = 1j * wn * math.sqrt(1 - damping * damping)
        c = (t / t[-1]) ** order * np.exp(damping * wn * (t - t[-1]) + s * t)
        rows += [c.real, c.imag]
        rhs += [0.0, 0.0]
    c_mat, d = np.array(rows), np.array(rhs)
    big = 1e4
    from scipy.optimize import lsq_linear  # here: the law's constants import this module

    sol = lsq_linear(
        np.vstack([big * c_mat, np.diag(1 / np.sqrt(w))]),
        np.concatenate([big * d, a0 / np.sqrt(w)]),
        bounds=(0.0, np.inf),
        method="bvls",
        tol=1e-14,
    )
    a = np.where(sol.x > 1e-9, sol.x, 0.0)
    wf = np.where(a > 0, w, 0.0)
    lam = np.linalg.lstsq((c_mat * wf) @ c_mat.T, d - c_mat @ a, rcond=None)[0]
    polished = a + wf * (c_mat.T @ lam)
    if polished.min() >= 0:
        a = polished
    if np.abs(c_mat @ a - d).max() > 1e-9:
        raise SpecError(
            f"shaper: no {kind} shaper with non-negative impulses for {freq_hz:g} Hz at a "
            f"{period_s:g} s tick"
        )
    return a[: int(np.flatnonzero(a)[-1]) + 1]


def _quantize(a: np.ndarray) -> tuple[int, ...]:
    """Q15 amplitudes summing to exactly 2^15: rounded down, the missing units to the largest
    remainders (the earlier tick first on a tie)."""
    scaled = a / a.sum() * (1 << SHAPER_FRAC_BITS)
    q = np.floor(scaled).astype(np.int64)
    short = (1 << SHAPER_FRAC_BITS) - int(q.sum())
    order = np.argsort(-(scaled - q), kind="stable")
    q[order[:short]] += 1
    return tuple(int(x) for x in q)


def design_shaper(kind: str, freq_hz: float, damping: float, period_s: float) -> Shaper:
    """A ``zv``, ``zvd`` or ``ei`` shaper for one mode on the tick grid.

    Parameters
    ----------
    kind : str
    freq_hz : float
        The mode's frequency [Hz], below the Nyquist frequency ``0.5 / period_s``.
    damping : float
        Its damping ratio [-], 0 ≤ ζ < 1.
    period_s : float
        The achieved tick [s].

    Raises
    ------
    SpecError
        An unknown kind, a frequency at or above Nyquist, a damping outside [0, 1), a train
        longer than :data:`MAX_SHAPER_TAPS`.
    """
    return shaper_for_modes(kind, [(freq_hz, damping)], period_s)


def shaper_for_modes(
    kind: str | list[str], modes: list[tuple[float, float]], period_s: float
) -> Shaper:
    """The product of one shaper per mode (``kind`` one for all, or one per mode)."""
    kinds = [kind] * len(modes) if isinstance(kind, str) else list(kind)
    if not modes or len(kinds) != len(modes):
        raise SpecError(f"shaper: {len(kinds)} kinds for {len(modes)} modes")
    a = np.ones(1)
    for k, (f, z) in zip(kinds, modes, strict=True):
        if k not in KINDS:
            raise SpecError(f"shaper: kind must be one of {', '.join(KINDS)}, got {show_value(k)}")
        _check(f, z, period_s)
        a = np.convolve(a, _solve(k, f, z, period_s))
    if a.size > MAX_SHAPER_TAPS:
        raise SpecError(f"shaper: the product is {a.size} ticks long, more than {MAX_SHAPER_TAPS}")
    return Shaper(
        kind="×".join(kinds),
        modes=tuple((float(f), float(z)) for f, z in modes),
        period_s=float(period_s),
        amplitudes=tuple(float(x) for x in a),
        amplitudes_q=_quantize(a),
    )


def check_taps(taps: object, where: str = "shaper") -> tuple[int, ...]:
    """A shaper's Q15 amplitudes as the runtime takes them (``servotune_shaper.h``'s
    ``st_shaper_check``): 1 … :data:`MAX_SHAPER_TAPS` integers, each in 0 … 2^15, summing to
    exactly 2^15.

    Raises
    ------
    ValueError
        Naming ``where`` and what is wrong.
    """
    one = 1 << SHAPER_FRAC_BITS
    if not isinstance(taps, list | tuple) or not 1 <= len(taps) <= MAX_SHAPER_TAPS:
        raise ValueError(
            f"{where} must be a list of 1..{MAX_SHAPER_TAPS} Q15 amplitudes, got {show_value(taps)}"
        )
    for i, a in enumerate(taps):
        if type(a) not in (int, np.int64) or not 0 <= a <= one:
            raise ValueError(f"{where}[{i}] must be an integer in 0..{one}, got {show_value(a)}")
    if sum(int(a) for a in taps) != one:
        raise ValueError(
            f"{where}: the amplitudes must sum to exactly {one} (2^{SHAPER_FRAC_BITS}, so a "
            f"constant reference passes to the count), got {sum(int(a) for a in taps)}"
        )
    return tuple(int(a) for a in taps)


def shaper_state(n_taps: int) -> np.ndarray:
    """A fresh state for :func:`shaper_step`: the delay line (``n_taps`` references), then the
    write position and a primed flag (0: the next reference fills the whole line)."""
    return np.zeros(n_taps + 2, dtype=np.int64)


@jit
def shaper_step(taps_q: np.ndarray, st: np.ndarray, ref: int) -> int:
    """One tick of the shaper: push ``ref`` and return ``shift_round(Σ a_i r[k − i], 15)``.

    ``st`` is :func:`shaper_state`'s array (updated in place); ``|ref|`` must stay below
    :data:`MAX_REFERENCE`.
    """
    n = taps_q.size
    if st[n + 1] == 0:
        for i in range(n):
            st[i] = ref
        st[n] = 0
        st[n + 1] = 1
    head = st[n]
    st[head] = ref
    acc = 0
    j = head
    for i in range(n):
        acc += taps_q[i] * st[j]
        j = j - 1 if j > 0 else n - 1
    st[n] = head + 1 if head + 1 < n else 0
    return shift_round(acc, 15)


@jit
def _shape_run(taps_q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    st = np.zeros(taps_q.size + 2, dtype=np.int64)
    out = np.empty(ref.size, dtype=np.int64)
    for k in range(ref.size):
        out[k] = shaper_step(taps_q, st, ref[k])
    return out


def shape_reference(ref_counts: np.ndarray, shaper: Shaper | Sequence[int]) -> np.ndarray:
    """A reference [counts] shaped tick by tick as the runtime shapes it (:func:`shaper_step`
    from a fresh state), by a :class:`Shaper` or its Q15 amplitudes (an
    ``AxisController.shaper``). The result has the same length: extend the move by
    ``n_taps − 1`` ticks of its last value to see all of it.

    Raises
    ------
    SpecError
        A reference beyond ±:data:`MAX_REFERENCE` counts.
    """
    ref = np.ascontiguousarray(ref_counts, dtype=np.int64)
    if ref.size and int(np.abs(ref).max()) >= MAX_REFERENCE:
        raise SpecError(f"shaper: the reference exceeds ±2^47 counts ({int(np.abs(ref).max())})")
    taps = shaper.amplitudes_q if isinstance(shaper, Shaper) else shaper
    return _shape_run(np.asarray(taps, dtype=np.int64), ref)


def choose_shaper(modes: Sequence[Any], period_s: float) -> tuple[Shaper, list[str]]:
    """The shortest shaper that holds every mode's residual vibration at or below
    :data:`RESIDUAL_GOAL` over its frequency range, and why.

    Each mode (:class:`servotune.resonance.Mode`: ``freq_hz``, ``damping`` and, where fitted,
    ``freq_hz_95``) is designed for at its nominal frequency; its range is its 95 % interval,
    widened to at least ±:data:`MIN_SPREAD`. Per mode the first of ``zv``, ``zvd``, ``ei`` whose
    worst residual over the range meets the goal is taken (``ei`` where none does, said so);
    several modes get the product.

    Returns
    -------
    (Shaper, list of str)
        The shaper and one line per mode: kind, range, worst residual, added time.

    Raises
    ------
    SpecError
        No modes, or a mode no shaper can be designed for on this tick.
    """
    if not modes:
        raise SpecError("shaper: the axis has no modes to shape for (docs/formats.md#modes)")
    kinds, reasons = [], []
    for m in modes:
        lo, hi = m.freq_hz_95 if m.freq_hz_95 is not None else (m.freq_hz, m.freq_hz)
        spread = max(MIN_SPREAD, 1 - lo / m.freq_hz, hi / m.freq_hz - 1)
        for kind in KINDS:
            one = design_shaper(kind, m.freq_hz, m.damping, period_s)
            worst = one.worst_residual(m.freq_hz, m.damping, spread)
            if worst <= RESIDUAL_GOAL:
                break
        verdict = "meets" if worst <= RESIDUAL_GOAL else "misses (the most robust kind)"
        kinds.append(kind)
        reasons.append(
            f"{m.freq_hz:.4g} Hz: {kind}, worst residual {100 * worst:.1f} % over ±"
            f"{100 * spread:.1f} % {verdict} the {100 * RESIDUAL_GOAL:g} % goal, "
            f"+{1000 * one.added_time_s:.1f} ms"
        )
    return shaper_for_modes(kinds, [(m.freq_hz, m.damping) for m in modes], period_s), reasons
