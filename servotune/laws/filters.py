"""Second-order filter sections for the law's output before the D/A (docs/runtime.md#filters):
design in continuous time, bilinear transform pre-warped at the section's characteristic
frequency, coefficients quantised to one fraction-bit count, and the integer tick.

Design: :func:`notch`, :func:`lowpass2` and :func:`biquad` return a :class:`Section` (a
continuous-time ``H(s) = (n2 s² + n1 s + n0) / (d2 s² + d1 s + d0)``); :func:`discretize` turns
it into float ``(b0, b1, b2, a1, a2)`` (``a0 = 1``) at the achieved tick period.

Fixed point: :func:`quantize_section` rounds every coefficient half away from zero with
``frac_bits`` fraction bits (``servotune.fixed.quantize``) into int32 mantissas; a notch and a
low-pass then get their middle numerator coefficient adjusted so that the quantised DC gain is
exactly 1. :func:`choose_frac_bits` picks the smallest ``frac_bits`` that meets the response
tolerances, the limit-cycle criterion and the accumulator margin.

The tick, :func:`biquad_step`: Direct Form I in int64 with second-order error feedback
(the rounding remainders ``r`` are fed back through the denominator; both roundings are
:func:`round_acc`, ``shift_round``'s integers in fewer steps within the sums' bound), so that
the quantity ``w = acc · 2^−f`` follows the quantised filter's exact linear recursion up to an
injected error of at most ``2^−(f+1)`` LSB per tick; the output is ``y = round(w)``. With zero
input ``w`` decays to at most ``‖1/A_q‖₁ · 2^−(f+1)`` LSB, which :func:`choose_frac_bits` keeps
at or below 1/4 LSB: the output then reaches 0 and stays there (no zero-input limit cycle).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from servotune._numba_cache import jit
from servotune.errors import SpecError
from servotune.fixed import quantize
from servotune.validate import check_keys, check_number, is_finite, is_number, show_value

__all__ = [
    "INPUT_BOUND_CODES",
    "INPUT_BOUND_WIDE",
    "N_FILTER_STATE",
    "SECTION_WORDS",
    "Section",
    "SectionQ",
    "StateBound",
    "biquad",
    "biquad_step",
    "bumpless_state",
    "chain_response",
    "choose_frac_bits",
    "discretize",
    "filter_run",
    "lowpass2",
    "notch",
    "quantize_section",
    "realize",
    "realized_features",
    "round_acc",
    "section_from_dict",
    "state_bound",
]

INPUT_BOUND_CODES = 2048
"""Largest |input| when the filter runs on whole D/A codes (12-bit, ±2048 around the zero)."""
INPUT_BOUND_WIDE = 2048 << 16
"""Largest |input| on the wider internal scale: D/A codes with 16 fraction bits (2^27)."""
N_FILTER_STATE = 6
"""int64 words of state per section: ``x1, x2, y1, y2, r1, r2``."""
ACC_LIMIT = 2**62
"""Every partial sum of the accumulator must stay within ±2^62: one bit of margin in int64."""
FREQ_TOL = 0.005
"""Relative tolerance of a realised characteristic frequency (notch centre, −3 dB point)."""
GAIN_TOL_DB = 1.0
"""Tolerance of a realised depth or peak [dB]."""
BAND_LO_HZ = 2.0
BAND_HI_NYQ = 0.45
"""The response is measured over ``BAND_LO_HZ … BAND_HI_NYQ · f_s`` (widened to hold the
characteristic frequency)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Section:
    """A continuous-time second-order section ``(n2 s² + n1 s + n0) / (s² + d1 s + d0)``.

    Parameters
    ----------
    kind : str
        ``"notch"``, ``"lowpass2"`` or ``"biquad"``.
    num_s, den_s : tuple of 3 floats
        Coefficients, highest power first [s², s, 1]; ``den_s[0] == 1``.
    warp_hz : float
        The pre-warping frequency [Hz]: the notch centre, the low-pass corner, or a biquad's
        natural frequency ``sqrt(d0)/(2π)`` unless given.
    warp_name : str
        The input that set ``warp_hz``, for messages (``"notch center_hz"``).
    params : tuple of (str, value)
        The design inputs it was made from (``center_hz``, ``width_hz``, ``depth_db`` …), in
        the order :func:`section_from_dict` takes them back.
    """

    kind: str
    num_s: tuple[float, float, float]
    den_s: tuple[float, float, float]
    warp_hz: float
    warp_name: str
    params: tuple[tuple[str, Any], ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """``{"kind": …, <design inputs>}``: what a rig file's ``[[axis.<name>.filters]]`` holds
        (:func:`section_from_dict` reads it back)."""
        return {"kind": self.kind} | {
            k: list(v) if isinstance(v, tuple) else v for k, v in self.params
        }

    def describe(self) -> str:
        """One line: the kind and its design inputs with their units."""
        units = {"center_hz": "Hz", "width_hz": "Hz", "depth_db": "dB", "corner_hz": "Hz"}
        parts = [
            f"{k} {v:g}{' ' + units[k] if k in units else ''}"
            for k, v in self.params
            if isinstance(v, float | int)
        ]
        return f"{self.kind} ({', '.join(parts)})" if parts else self.kind

    @property
    def unity_dc(self) -> bool:
        """True for a notch and a low-pass: DC gain exactly 1, kept after quantising."""
        return self.kind in ("notch", "lowpass2")


def notch(center_hz: float, width_hz: float, depth_db: float) -> Section:
    """A notch ``(s² + 2ζz·ω0·s + ω0²) / (s² + 2ζp·ω0·s + ω0²)``, unity gain at DC and far away.

    ``width_hz`` is the poles' bandwidth ``2ζp·f0`` (the −3 dB width of an infinitely deep
    notch); ``depth_db`` the gain at the centre, ``20·log10(ζz/ζp)`` (< 0).

    Raises
    ------
    SpecError
        A centre or width not > 0 [Hz], or a depth not < 0 [dB].
    """
    check_number("notch center_hz", center_hz, "Hz", strict=True, error=SpecError)
    check_number("notch width_hz", width_hz, "Hz", strict=True, error=SpecError)
    check_number(
        "notch depth_db", depth_db, "dB", lo=-math.inf, hi=0.0, hi_strict=True, error=SpecError
    )
    w0 = 2.0 * math.pi * center_hz
    zp = width_hz / (2.0 * center_hz)
    zz = zp * 10.0 ** (depth_db / 20.0)
    return Section(
        kind="notch",
        num_s=(1.0, 2.0 * zz * w0, w0 * w0),
        den_s=(1.0, 2.0 * zp * w0, w0 * w0),
        warp_hz=float(center_hz),
        warp_name="notch center_hz",
        params=(
            ("center_hz", float(center_hz)),
            ("width_hz", float(width_hz)),
            ("depth_db", float(depth_db)),
        ),
    )


def lowpass2(corner_hz: float, damping: float) -> Section:
    """A second-order low-pass ``ω0² / (s² + 2ζ·ω0·s + ω0²)``, unity DC gain.

    Raises
    ------
    SpecError
        A corner not > 0 [Hz] or a damping not > 0 [-].
    """
    check_number("lowpass2 corner_hz", corner_hz, "Hz", strict=True, error=SpecError)
    check_number("lowpass2 damping", damping, "-", strict=True, error=SpecError)
    w0 = 2.0 * math.pi * corner_hz
    return Section(
        kind="lowpass2",
        num_s=(0.0, 0.0, w0 * w0),
        den_s=(1.0, 2.0 * damping * w0, w0 * w0),
        warp_hz=float(corner_hz),
        warp_name="lowpass2 corner_hz",
        params=(("corner_hz", float(corner_hz)), ("damping", float(damping))),
    )


def _coeffs(name: str, v: object) -> tuple[float, float, float]:
    if not isinstance(v, list | tuple) or not 1 <= len(v) <= 3:
        raise SpecError(f"{name} must be 1 to 3 coefficients [s², s, 1], got {show_value(v)}")
    if not all(is_number(c) and is_finite(c) for c in v):
        raise SpecError(f"{name} must hold finite numbers, got {show_value(v)}")
    c = [0.0] * (3 - len(v)) + [float(x) for x in v]
    return c[0], c[1], c[2]


def biquad(num_s: object, den_s: object, warp_hz: float | None = None) -> Section:
    """A general second-order section from its continuous coefficients (highest power first).

    The denominator must be a stable second-order polynomial (three non-zero coefficients of
    one sign); it is normalised to ``s² + d1·s + d0``. ``warp_hz`` defaults to the natural
    frequency ``sqrt(d0)/(2π)``.

    Raises
    ------
    SpecError
        Malformed coefficients, an unstable or not second-order denominator, a numerator of
        zeros, or a ``warp_hz`` not > 0 [Hz].
    """
    n = _coeffs("biquad num_s", num_s)
    d = _coeffs("biquad den_s", den_s)
    if not (all(c > 0 for c in d) or all(c < 0 for c in d)):
        raise SpecError(
            "biquad den_s must be a stable second-order polynomial (three non-zero "
            f"coefficients of one sign) [s², s, 1], got {show_value(den_s)}"
        )
    if not any(n):
        raise SpecError(f"biquad num_s must not be all zeros, got {show_value(num_s)}")
    n = (n[0] / d[0], n[1] / d[0], n[2] / d[0])
    d = (1.0, d[1] / d[0], d[2] / d[0])
    if warp_hz is None:
        warp_hz = math.sqrt(d[2]) / (2.0 * math.pi)
    check_number("biquad warp_hz", warp_hz, "Hz", strict=True, error=SpecError)
    return Section(
        kind="biquad",
        num_s=n,
        den_s=d,
        warp_hz=float(warp_hz),
        warp_name="biquad warp_hz",
        params=(("num_s", n), ("den_s", d), ("warp_hz", float(warp_hz))),
    )


_DESIGNS = {
    "notch": (notch, ("center_hz", "width_hz", "depth_db"), ()),
    "lowpass2": (lowpass2, ("corner_hz", "damping"), ()),
    "biquad": (biquad, ("num_s", "den_s"), ("warp_hz",)),
}


def section_from_dict(d: object, where: str = "filter") -> Section:
    """A section from its design inputs: ``{"kind": "notch", "center_hz", "width_hz",
    "depth_db"}``, ``{"kind": "lowpass2", "corner_hz", "damping"}`` or ``{"kind": "biquad",
    "num_s", "den_s"[, "warp_hz"]}`` (:meth:`Section.to_dict`).

    Raises
    ------
    SpecError
        One line naming ``where`` and the key or value.
    """
    kind = d.get("kind") if isinstance(d, dict) else None
    if kind not in _DESIGNS:
        raise SpecError(
            f"{where}.kind must be one of {', '.join(_DESIGNS)}, got "
            f"{show_value(kind) if isinstance(d, dict) else 'no table'}"
        )
    make, required, optional = _DESIGNS[kind]
    d = check_keys(d, where, ("kind", *required), optional, error=SpecError)
    try:
        return make(**{k: v for k, v in d.items() if k != "kind"})
    except SpecError as exc:
        raise SpecError(f"{where}: {exc}") from None


@functools.lru_cache(maxsize=256)
def realize(section: Section, period_s: float, input_bound: int = INPUT_BOUND_WIDE) -> SectionQ:
    """The section as the runtime runs it at ``period_s`` (the rig's achieved tick): quantised
    with the fewest fraction bits that meet the tolerances for inputs up to ``input_bound``
    (:func:`choose_frac_bits`; the rig's D/A range on the wide scale:
    ``Rig.runtime_filters``)."""
    f = choose_frac_bits(section, period_s, input_bound=input_bound)
    return quantize_section(section, period_s, f)


def _check_period(section: Section, period_s: float) -> None:
    check_number("period_s", period_s, "s", strict=True, error=SpecError)
    nyq = 0.5 / period_s
    if not section.warp_hz < nyq:
        raise SpecError(
            f"{section.warp_name} must be a number in (0, {nyq:g}) [Hz] (below the Nyquist "
            f"frequency 0.5/period_s), got {show_value(section.warp_hz)}"
        )


def discretize(section: Section, period_s: float) -> tuple[float, float, float, float, float]:
    """Bilinear transform pre-warped at ``section.warp_hz``: float ``(b0, b1, b2, a1, a2)``.

    ``s = K·(1 − z⁻¹)/(1 + z⁻¹)`` with ``K = ωw / tan(ωw·T/2)``, so the analog response at
    ``ωw`` lands exactly at ``ωw`` (a notch keeps its centre and depth exactly).

    Parameters
    ----------
    section : Section
    period_s : float
        The achieved tick period [s] (docs/runtime.md#timer-and-achieved-period).

    Raises
    ------
    SpecError
        A period not > 0 [s] or a characteristic frequency not below 0.5/period_s [Hz].
    """
    _check_period(section, period_s)
    ww = 2.0 * math.pi * section.warp_hz
    k = ww / math.tan(ww * period_s / 2.0)
    k2 = k * k
    n2, n1, n0 = section.num_s
    d2, d1, d0 = section.den_s
    a0 = d2 * k2 + d1 * k + d0
    b0 = (n2 * k2 + n1 * k + n0) / a0
    b1 = 2.0 * (n0 - n2 * k2) / a0
    b2 = (n2 * k2 - n1 * k + n0) / a0
    a1 = 2.0 * (d0 - d2 * k2) / a0
    a2 = (d2 * k2 - d1 * k + d0) / a0
    return b0, b1, b2, a1, a2


_INT32 = 2**31 - 1
SECTION_WORDS = ("b0", "b1", "b2", "a1", "a2", "frac_bits")
"""A realised section's integers in the order the runtime holds them (:meth:`SectionQ.step_args`,
the constants slots of :func:`servotune.laws.axis.filter_block`, the C ``st_section_t``)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class SectionQ:
    """A quantised section as the runtime holds it: int32 mantissas, one fraction-bit count.

    ``H(z) = (b0 + b1 z⁻¹ + b2 z⁻²) / (1 + a1 z⁻¹ + a2 z⁻²)`` with every coefficient
    ``q · 2^−frac_bits``.
    """

    b0: int
    b1: int
    b2: int
    a1: int
    a2: int
    frac_bits: int

    def step_args(self) -> tuple[int, int, int, int, int, int]:
        """``(b0, b1, b2, a1, a2, frac_bits)``: the leading arguments of :func:`biquad_step`."""
        return self.b0, self.b1, self.b2, self.a1, self.a2, self.frac_bits

    def ba(self) -> tuple[np.ndarray, np.ndarray]:
        """The realised coefficients as floats: ``b = [b0, b1, b2]``, ``a = [1, a1, a2]``."""
        s = 2.0**-self.frac_bits
        b = np.array([self.b0, self.b1, self.b2], dtype=float) * s
        return b, np.array([1.0, self.a1 * s, self.a2 * s])

    def to_dict(self) -> dict[str, int]:
        """Plain dict of integers."""
        return {k: int(getattr(self, k)) for k in SECTION_WORDS}

    @classmethod
    def from_dict(cls, d: object, where: str = "filter") -> SectionQ:
        """Inverse of :meth:`to_dict`, checked: int32 mantissas, ``frac_bits`` in 1..30 and a
        stable quantised denominator.

        Raises
        ------
        ValueError
            One line naming ``where`` and the field.
        """
        d = check_keys(d, where, SECTION_WORDS)
        for k in SECTION_WORDS:
            v = d[k]
            lo, hi = (1, 30) if k == "frac_bits" else (-_INT32, _INT32)
            if type(v) is not int or not lo <= v <= hi:
                raise ValueError(
                    f"{where}.{k} must be an integer in {lo}..{hi}, got {show_value(v)}"
                )
        one = 1 << d["frac_bits"]
        if not (abs(d["a2"]) < one and abs(d["a1"]) < one + d["a2"]):
            raise ValueError(
                f"{where} is not stable (a1 = {d['a1']}, a2 = {d['a2']} · 2^-{d['frac_bits']})"
            )
        return cls(**d)


def quantize_section(section: Section, period_s: float, frac_bits: int) -> SectionQ:
    """Discretise and quantise with ``frac_bits`` fraction bits (``servotune.fixed.quantize``).

    For a notch or a low-pass, ``b1`` is then moved (by at most 1.5 of its LSB) so that
    ``b0 + b1 + b2 = 2^f + a1 + a2``: the quantised DC gain is exactly 1, so a steady input
    passes unchanged and switching the section in is bumpless (:func:`bumpless_state`).

    Raises
    ------
    SpecError
        ``frac_bits`` not in 1..30, a coefficient that does not fit int32 with that many fraction
        bits, or a quantised denominator outside the stability triangle.
    """
    if type(frac_bits) is not int or not 1 <= frac_bits <= 30:
        raise SpecError(
            f"frac_bits must be an integer in 1..30 [bits], got {show_value(frac_bits)}"
        )
    names = ("b0", "b1", "b2", "a1", "a2")
    q = {}
    for name, x in zip(names, discretize(section, period_s), strict=True):
        c = quantize(x, bits=32, f_max=frac_bits)
        if c.f != frac_bits:
            raise SpecError(
                f"filter coefficient {name} = {x:.6g} does not fit int32 with {frac_bits} "
                "fraction bits [bits]"
            )
        q[name] = c.q
    if section.unity_dc:
        q["b1"] = (1 << frac_bits) + q["a1"] + q["a2"] - q["b0"] - q["b2"]
        if abs(q["b1"]) > _INT32:
            raise SpecError(
                f"filter coefficient b1 does not fit int32 with {frac_bits} fraction bits"
            )
    one = 1 << frac_bits
    if not (abs(q["a2"]) < one and abs(q["a1"]) < one + q["a2"]):
        raise SpecError(
            f"the quantised filter is not stable with {frac_bits} fraction bits "
            f"(a1 = {q['a1']}, a2 = {q['a2']} · 2^-{frac_bits}): use more fraction bits"
        )
    return SectionQ(frac_bits=frac_bits, **q)


def chain_response(sections: Sequence[SectionQ], w: np.ndarray, period_s: float) -> np.ndarray:
    """``F(e^{jωT})``: the product of the quantised sections' responses on ``w`` [rad/s] (ones
    without sections)."""
    z1 = np.exp(-1j * np.asarray(w, dtype=float) * period_s)
    out = np.ones(z1.shape, dtype=complex)
    for sec in sections:
        b, a = sec.ba()
        out *= (b[0] + z1 * (b[1] + z1 * b[2])) / (1.0 + z1 * (a[1] + z1 * a[2]))
    return out


# --- response features ------------------------------------------------------------------------


def _gain2(b: np.ndarray, a: np.ndarray, f_hz: np.ndarray, period_s: float) -> np.ndarray:
    z1 = np.exp(-2j * np.pi * np.asarray(f_hz) * period_s)
    num = b[0] + z1 * (b[1] + z1 * b[2])
    den = a[0] + z1 * (a[1] + z1 * a[2])
    return np.abs(num) ** 2 / np.abs(den) ** 2


def _band(section: Section, period_s: float) -> tuple[float, float]:
    fs = 1.0 / period_s
    lo = min(BAND_LO_HZ, 0.5 * section.warp_hz)
    hi = max(BAND_HI_NYQ * fs, min(2.0 * section.warp_hz, 0.49999 * fs))
    return lo, hi


def _refine_min(b: np.ndarray, a: np.ndarray, f: np.ndarray, period_s: float) -> float:
    """The frequency of the smallest gain on the grid ``f``, refined twice on finer grids."""
    for _ in range(3):
        i = int(np.argmin(_gain2(b, a, f, period_s)))
        lo, hi = f[max(i - 1, 0)], f[min(i + 1, f.size - 1)]
        f = np.linspace(lo, hi, 2001)
    return float(f[int(np.argmin(_gain2(b, a, f, period_s)))])


def _minus_3db(b: np.ndarray, a: np.ndarray, lo: float, hi: float, period_s: float) -> float:
    """The lowest frequency in (lo, hi] where the gain falls to 1/√2 (bisection on a grid)."""
    while _gain2(b, a, np.array([lo]), period_s)[0] <= 0.5 and lo > 1e-6:
        lo /= 10.0
    f = np.geomspace(lo, hi, 4000)
    below = np.nonzero(_gain2(b, a, f, period_s) <= 0.5)[0]
    if below.size == 0:
        return math.inf
    j = int(below[0])
    f_a, f_b = float(f[j - 1]), float(f[j])
    for _ in range(60):
        m = 0.5 * (f_a + f_b)
        if _gain2(b, a, np.array([m]), period_s)[0] <= 0.5:
            f_b = m
        else:
            f_a = m
    return f_b


def _features(section: Section, b: np.ndarray, a: np.ndarray, period_s: float) -> dict[str, float]:
    lo, hi = _band(section, period_s)
    grid = np.geomspace(lo, hi, 4000)
    g_db = 10.0 * np.log10(np.maximum(_gain2(b, a, grid, period_s), 1e-300))
    if section.kind == "notch":
        fc = _refine_min(b, a, grid, period_s)
        depth = 10.0 * math.log10(max(float(_gain2(b, a, np.array([fc]), period_s)[0]), 1e-300))
        return {"center_hz": fc, "depth_db": depth}
    if section.kind == "lowpass2":
        dc_db = 10.0 * math.log10(float(_gain2(b, a, np.array([0.0]), period_s)[0]))
        peak = max(float(np.max(g_db)), dc_db)  # an overdamped low-pass peaks at DC
        return {"f3db_hz": _minus_3db(b, a, lo, hi, period_s), "peak_db": peak}
    p = np.roots(a)
    pole_hz = float(np.max(np.abs(np.log(p.astype(complex))))) / (2.0 * math.pi * period_s)
    return {"pole_hz": pole_hz, "max_db": float(np.max(g_db)), "min_db": float(np.min(g_db))}


def realized_features(
    section: Section, period_s: float, section_q: SectionQ | None = None
) -> dict[str, float]:
    """The measured features of the design (float) or, given ``section_q``, the realised filter.

    notch: ``center_hz`` (the gain minimum) and ``depth_db``; lowpass2: ``f3db_hz`` (the lowest
    frequency at −3.01 dB) and ``peak_db`` (DC included); biquad: ``pole_hz`` (the poles'
    natural frequency ``|ln p|/(2πT)``), ``max_db`` and ``min_db`` over the band (2 Hz …
    0.45·f_s, widened to hold the characteristic frequency).
    """
    if section_q is None:
        b0, b1, b2, a1, a2 = discretize(section, period_s)
        b, a = np.array([b0, b1, b2]), np.array([1.0, a1, a2])
    else:
        _check_period(section, period_s)
        b, a = section_q.ba()
    return _features(section, b, a, period_s)


# --- bounds -----------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class StateBound:
    """Bounds of a quantised section for inputs ``|x| <= input_bound`` (docs/runtime.md#filters).

    Parameters
    ----------
    l1 : float
        ``‖h_q‖₁``, the L1 norm of the quantised filter's impulse response.
    l1_inv : float
        ``‖1/A_q‖₁``: the gain from the error-feedback rounding to ``w``.
    y_max : int
        Largest |y| [LSB of the signal].
    acc_max : int
        Largest |partial sum| of the accumulator [2^−f LSB].
    headroom_bits : float
        ``63 − log2(acc_max)``.
    """

    l1: float
    l1_inv: float
    y_max: int
    acc_max: int
    headroom_bits: float


def _l1_impulse(b: np.ndarray, a: np.ndarray) -> float:
    """``Σ|h(n)|`` summed until the poles' envelope is below e^−45 of its start."""
    from scipy.signal import lfilter  # imported where used: the rig loads this module early

    rho = float(np.max(np.abs(np.roots(a))))
    if not rho < 1.0:
        raise SpecError(f"the quantised filter is not stable (pole radius {rho:.9g})")
    n = math.ceil(45.0 / -math.log(rho)) + 64 if rho > 0 else 64
    if n > 50_000_000:
        raise SpecError(
            f"the quantised filter's poles are too close to the unit circle ({rho:.9g})"
        )
    total, zi, block = 0.0, np.zeros(2), np.zeros(min(n, 1 << 16))
    block[0], done = 1.0, 0
    while done < n:
        h, zi = lfilter(b, a, block, zi=zi)
        total += float(np.sum(np.abs(h)))
        block[0], done = 0.0, done + block.size
    return total


def state_bound(section_q: SectionQ, input_bound: int = INPUT_BOUND_WIDE) -> StateBound:
    """Largest |y| and |accumulator| of :func:`biquad_step` for ``|x| <= input_bound``.

    ``w = acc·2^−f`` is the quantised filter's output plus the error-feedback rounding
    (≤ 2^−(f+1) per tick through ``1/A_q``), and ``|y − w| <= 1/2``, so
    ``|y| <= ‖h_q‖₁·X + ‖1/A_q‖₁·2^−(f+1) + 1/2``; every partial sum of the accumulator is at
    most ``Σ|b|·X + (|a1|+|a2|)·(Y + 1/2) + 1``. Assumes the state was reached by inputs within
    the bound (zero, or :func:`bumpless_state` at a settled output).
    """
    check_number("input_bound", input_bound, "LSB", strict=True, error=SpecError)
    b, a = section_q.ba()
    l1 = _l1_impulse(b, a)
    l1_inv = _l1_impulse(np.array([1.0, 0.0, 0.0]), a)
    f = section_q.frac_bits
    y_max = math.ceil(l1 * (1.0 + 1e-9) * input_bound + l1_inv * 2.0 ** -(f + 1) + 0.5)
    sb = abs(section_q.b0) + abs(section_q.b1) + abs(section_q.b2)
    sa = abs(section_q.a1) + abs(section_q.a2)
    acc_max = sb * int(input_bound) + sa * y_max + (sa + 1) // 2 + 1
    return StateBound(
        l1=l1, l1_inv=l1_inv, y_max=y_max, acc_max=acc_max, headroom_bits=63.0 - math.log2(acc_max)
    )


def _failures(
    section: Section, period_s: float, section_q: SectionQ, input_bound: int
) -> list[str]:
    """What the realised section misses (empty when it meets every rule of choose_frac_bits)."""
    want = realized_features(section, period_s)
    got = realized_features(section, period_s, section_q)
    out = []
    for key, v in want.items():
        if key.endswith("_hz"):
            if not abs(got[key] - v) <= FREQ_TOL * v:
                out.append(f"{key} {got[key]:.6g} vs {v:.6g} (±{100 * FREQ_TOL:g} %)")
        elif not abs(got[key] - v) <= GAIN_TOL_DB:
            out.append(f"{key} {got[key]:.4g} vs {v:.4g} (±{GAIN_TOL_DB:g} dB)")
    if out:
        return out
    sb = state_bound(section_q, input_bound)
    if not sb.l1_inv <= 2.0 ** (section_q.frac_bits - 1):
        out.append(f"‖1/A‖₁ = {sb.l1_inv:.4g} > 2^(f−1) (the limit-cycle rule)")
    if not sb.acc_max <= ACC_LIMIT:
        out.append(f"accumulator bound 2^{math.log2(sb.acc_max):.2f} > 2^62")
    return out


def choose_frac_bits(
    section: Section,
    period_s: float,
    *,
    f_min: int = 12,
    f_max: int = 30,
    input_bound: int = INPUT_BOUND_WIDE,
) -> int:
    """The smallest fraction-bit count in ``f_min..f_max`` whose realised section passes.

    Passing means: the realised characteristic frequency (notch centre, low-pass −3 dB point,
    biquad pole frequency) within ±0.5 % and the depth / peak (biquad: largest and smallest
    gain) within ±1 dB of the float design, measured over 2 Hz … 0.45·f_s; ``‖1/A_q‖₁ <=
    2^(f−1)`` (no zero-input limit cycle, docs/runtime.md#filters); and every accumulator partial
    sum within ±2^62 for ``|x| <= input_bound``.

    Raises
    ------
    SpecError
        No fraction-bit count passes (the message says what ``f_max`` misses).
    """
    check_number("input_bound", input_bound, "LSB", strict=True, error=SpecError)
    why = ["no fraction-bit count was tried"]
    for f in range(f_min, f_max + 1):
        try:
            sq = quantize_section(section, period_s, f)
        except SpecError as exc:
            why = [str(exc)]
            continue
        why = _failures(section, period_s, sq, input_bound)
        if not why:
            return f
    raise SpecError(
        f"no word length of {f_min}..{f_max} fraction bits realises the {section.kind} at "
        f"{section.warp_hz:g} Hz, period {period_s:g} s: with {f_max}: {'; '.join(why)}"
    )


def bumpless_state(section_q: SectionQ, x_now: int, y_now: int) -> np.ndarray:
    """The state ``[x1, x2, y1, y2, r1, r2]`` for switching a section in, or re-tuning it.

    ``x1 = x2 = x_now`` (the last input), ``y1 = y2 = y_now`` (the last output), ``r = 0``: the
    section's steady state at a steady input when ``y_now`` equals its DC gain times ``x_now``
    (always, for a notch or low-pass whose settled output is its input). The next output is
    ``y_now + b0·(x − x_now) + A_q(1)·(G·x_now − y_now)`` rounded, ``G`` the DC gain: at a steady
    input it equals ``y_now``.
    """
    del section_q  # the rule is the same for every section; kept for the runtime's signature
    return np.array([x_now, x_now, y_now, y_now, 0, 0], dtype=np.int64)


# --- the integer tick -------------------------------------------------------------------------


@jit(inline="always")
def round_acc(x: int, f: int) -> int:
    """``x · 2^−f`` rounded half away from zero for ``|x| <= 2^62`` (a section's sums; the
    same integers as ``servotune.fixed.shift_round``): ``(x + 2^(f−1) − [x < 0]) >> f`` with
    an arithmetic shift, four operations in a row on the chain's critical path instead of the
    magnitude's round trip (``x + 2^(f−1)`` cannot overflow within the bound)."""
    return (x + (np.int64(1) << (f - 1)) - np.int64(x < 0)) >> f


@jit(inline="always")
def biquad_step(
    b0: int, b1: int, b2: int, a1: int, a2: int, f: int, st: np.ndarray, o: int, x: int
) -> int:
    """One tick of a quantised section (Direct Form I, second-order error feedback).

    ``st[o : o + 6]`` is the section's int64 state ``[x1, x2, y1, y2, r1, r2]`` (``o`` its
    offset in ``st``, so a chain's sections share one row without a view each), updated in
    place; ``r`` are the rounding remainders in 2^−f LSB, |r| <= 2^(f−1).

        acc = b0·x + b1·x1 + b2·x2 − a1·y1 − a2·y2 − shift_round(a1·r1 + a2·r2, f)
        y   = shift_round(acc, f)            r = acc − y·2^f

    The caller keeps ``|x| <= input_bound`` of :func:`state_bound`, which keeps every partial
    sum inside ±2^62; all arithmetic is int64, no shift of a negative value.
    """
    x1, x2, y1, y2, r1 = st[o], st[o + 1], st[o + 2], st[o + 3], st[o + 4]
    ef = round_acc(a1 * r1 + a2 * st[o + 5], f)
    acc = b0 * x + b1 * x1 + b2 * x2 - a1 * y1 - a2 * y2 - ef
    y = round_acc(acc, f)
    st[o] = x
    st[o + 1] = x1
    st[o + 2] = y
    st[o + 3] = y1
    st[o + 4] = acc - y * (np.int64(1) << f)
    st[o + 5] = r1
    return y


@jit
def filter_run(
    b0: int,
    b1: int,
    b2: int,
    a1: int,
    a2: int,
    f: int,
    st: np.ndarray,
    xs: np.ndarray,
    ys: np.ndarray,
) -> int:
    """:func:`biquad_step` over ``xs`` into ``ys`` (state ``st`` updated); returns the largest
    |accumulator| seen (``(|y| + 1/2)·2^f`` bounds it; for tests and bounds)."""
    acc_max = 0
    for k in range(xs.size):
        y = biquad_step(b0, b1, b2, a1, a2, f, st, 0, xs[k])
        ys[k] = y
        acc = y * (np.int64(1) << f) + st[4]
        acc = -acc if acc < 0 else acc
        if acc > acc_max:
            acc_max = acc
    return acc_max
