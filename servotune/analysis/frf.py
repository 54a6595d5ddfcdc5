"""The measured frequency response of a plant from a closed-loop log (docs/frf.md).

The loop is closed (the lock module or the task law holds the axis) and a periodic excitation
``r`` (``exc_code``, the codes the law adds to its output: a multisine of
:func:`servotune.excite.periodic_multisine`) is added at the D/A. The plant's input ``u`` is the
D/A command ``cmd_v`` [V] and its output ``y`` the position [counts] or the velocity, its
backward difference [counts/s]. Both ``u`` and ``y`` carry the loop's noise (the controller
feeds the output noise back into the input), so the open-loop formula ``S_yu / S_uu`` (the H1
estimate of ``scipy.signal.csd`` / ``welch``) is biased towards ``−1 / C``, the inverse of the
controller, wherever the noise dominates. The excitation is known and uncorrelated with the
noise, so the ratio of the cross-spectra *with the excitation*, ``S_yr / S_ur``, is consistent.
With a periodic excitation the same in every period, that ratio is the ratio of the averaged
spectra (R. Pintelon, J. Schoukens, "System Identification: A Frequency Domain Approach", 2nd
ed., Wiley 2012, §2.5 and §7.2):

    G(k) = Ȳ(k) / Ū(k),   Ȳ(k) = (1/P) Σ_p Y_p(k),   Ū(k) = (1/P) Σ_p U_p(k),

``Y_p(k)``, ``U_p(k)`` the DFT of period ``p`` at line ``k``, over the ``P`` periods left after
the first ``skip`` (the transient). The spread from period to period (each period's deviation
from the mean period with its own straight line removed: :func:`_deviations`) gives the noise
variances ``σ²_Y``, ``σ²_U`` and covariance ``σ²_YU``, and so the variance of G to first order:

    var G = |G|² / P · (σ²_Y / |Ȳ|² + σ²_U / |Ū|² − 2 Re(σ²_YU / (Ȳ Ū*))).

The 95 % bound is the circle of radius ``r · std G`` about the estimate, ``r² =
F_0.95(2, 2(P − 1))`` (the variance is itself estimated from ``P − 1`` degrees of freedom; the
quantile tends to ``ln 20`` for many periods). The magnitude and phase bounds are that circle's.

Beside the excited lines: the noise level (``σ_Y / √P`` at each line), the coherence of the output
with the excitation (``|Ȳ|² / mean |Y_p|²``: 1 without noise) and, on the lines a random odd
multisine leaves out, the level of the periodic output there: an odd nonlinearity (friction,
saturation) shows on the unexcited odd lines, an even one on the even lines. Lines above
:data:`ALIAS_FRACTION` of the Nyquist frequency are flagged: a mode above the Nyquist frequency
folds onto them and cannot be told apart.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from servotune.errors import LogFormatError, SpecError

__all__ = [
    "ALIAS_FRACTION",
    "FRF_SCHEMA",
    "OUTPUTS",
    "POOR_COHERENCE",
    "Frf",
    "FrfSource",
    "estimate_frf",
    "find_period",
    "frf",
    "read_frf",
]

FRF_SCHEMA = "servotune.frf/1"
"""Schema of the FRF file (docs/frf.md#file)."""

OUTPUTS = ("velocity", "position")
"""What the response is of: the velocity [counts/s per V] or the position [counts per V]."""

POOR_COHERENCE = 0.5
"""Median coherence below which :meth:`Frf.summary` says the response is mostly noise (the
excitation explains less of the output's variation than the noise does)."""

ALIAS_FRACTION = 0.8
"""Lines above this fraction of the Nyquist frequency are flagged as possibly aliased."""

MIN_PERIOD_TICKS = 16
"""Fewest ticks of an excitation period."""

_EXCITED = 0.1  # a line is excited when its amplitude is above this fraction of the largest


@dataclass(frozen=True, slots=True, kw_only=True)
class Frf:
    """A measured frequency response (what :func:`estimate_frf` returns).

    Attributes
    ----------
    freq_hz : ndarray
        The excited lines [Hz], ascending.
    response : ndarray of complex
        The response at each line: counts/s per V (velocity) or counts per V (position).
    std : ndarray
        Its standard deviation (of the complex estimate: ``E |Ĝ − G|² = std²``).
    radius95 : ndarray
        The radius of its 95 % circle (``r · std``).
    coherence : ndarray
        Of the output with the excitation, per line [-].
    noise : ndarray
        The output's noise level on the averaged spectrum per line (``σ_Y / √P``), in the
        output's units per DFT line.
    output_level : ndarray
        ``|Ȳ|`` per excited line, the same units.
    aliased : ndarray of bool
        Lines above :data:`ALIAS_FRACTION` of the Nyquist frequency.
    odd_hz, odd_level, even_hz, even_level : ndarray
        The unexcited odd lines and the even lines within the band, and ``|Ȳ|`` there.
    odd_noise, even_noise : ndarray
        The noise level there (``σ_Y / √P``).
    output : str
        ``"velocity"`` or ``"position"``.
    period_s : float
        Tick period [s].
    period_ticks : int
        Ticks per excitation period.
    periods : int
        Periods averaged (after ``skipped``).
    skipped : int
        Periods discarded at the start (the transient).
    start_tick : int
        The tick the excitation starts at (0, or after a lead-in without it).
    """

    freq_hz: np.ndarray
    response: np.ndarray
    std: np.ndarray
    radius95: np.ndarray
    coherence: np.ndarray
    noise: np.ndarray
    output_level: np.ndarray
    aliased: np.ndarray
    odd_hz: np.ndarray
    odd_level: np.ndarray
    odd_noise: np.ndarray
    even_hz: np.ndarray
    even_level: np.ndarray
    even_noise: np.ndarray
    output: str
    period_s: float
    period_ticks: int
    periods: int
    skipped: int
    start_tick: int = 0

    @property
    def magnitude_db(self) -> np.ndarray:
        """``20 log10 |G|`` [dB]."""
        return 20.0 * np.log10(np.abs(self.response))

    @property
    def phase_deg(self) -> np.ndarray:
        """Phase of G, unwrapped along the lines [deg]."""
        return np.degrees(np.unwrap(np.angle(self.response)))

    def magnitude_bounds_db(self) -> tuple[np.ndarray, np.ndarray]:
        """The 95 % circle's lowest and highest magnitude [dB] (the lowest −inf where the circle
        holds zero)."""
        mag = np.abs(self.response)
        with np.errstate(divide="ignore"):
            lo = 20.0 * np.log10(np.maximum(mag - self.radius95, 0.0))
        return lo, 20.0 * np.log10(mag + self.radius95)

    def phase_bounds_deg(self) -> tuple[np.ndarray, np.ndarray]:
        """The 95 % circle's phase span about :attr:`phase_deg` [deg] (±180° where the circle
        holds zero)."""
        ratio = self.radius95 / np.abs(self.response)
        half = np.where(ratio < 1.0, np.degrees(np.arcsin(np.minimum(ratio, 1.0))), 180.0)
        return self.phase_deg - half, self.phase_deg + half

    def contains(self, truth: np.ndarray) -> np.ndarray:
        """Whether each line's 95 % circle holds ``truth`` (complex, at :attr:`freq_hz`)."""
        return np.abs(np.asarray(truth) - self.response) <= self.radius95

    def nonlinear_db(self) -> float | None:
        """The RMS level on the unexcited odd lines relative to the excited lines' [dB]: how far
        odd nonlinear distortion sits below the linear response (None without such lines)."""
        if self.odd_level.size == 0:
            return None
        rms_odd = float(np.sqrt(np.mean(self.odd_level**2)))
        rms_exc = float(np.sqrt(np.mean(self.output_level**2)))
        return 20.0 * math.log10(max(rms_odd, 1e-300) / rms_exc)

    def summary(self) -> str:
        """A few lines for a terminal: the lines, the periods, coherence, distortion, aliasing."""
        f = self.freq_hz
        lines = [
            f"frequency response ({self.output}): {f.size} lines, {f[0]:.4g} … {f[-1]:.4g} Hz, "
            f"{self.periods} periods of {self.period_ticks} ticks averaged ({self.skipped} "
            "skipped as transient"
            + (f"; the excitation starts at tick {self.start_tick})" if self.start_tick else ")"),
            f"coherence: median {float(np.median(self.coherence)):.3f}, lowest "
            f"{float(np.min(self.coherence)):.3f} (at {float(f[np.argmin(self.coherence)]):.4g} "
            "Hz)",
        ]
        med = float(np.median(self.coherence))
        if med < POOR_COHERENCE:
            lines.append(
                f"the response is mostly noise (median coherence {med:.3f} < {POOR_COHERENCE:g}): "
                "raise the excitation's amplitude or its number of periods"
            )
        nl = self.nonlinear_db()
        if nl is not None:
            lines.append(f"odd nonlinear distortion: {-nl:.1f} dB below the response's level")
        n_alias = int(np.sum(self.aliased))
        if n_alias:
            lines.append(
                f"{n_alias} line{'s' if n_alias != 1 else ''} above {ALIAS_FRACTION:g} × Nyquist "
                "flagged as possibly aliased"
            )
        return "\n".join(lines)

    def to_frd(self) -> Any:
        """The response as a python-control ``FrequencyResponseData`` (ω in rad/s)."""
        import control

        return control.FrequencyResponseData(
            self.response, 2.0 * np.pi * self.freq_hz, smooth=False
        )

    def columns(self) -> dict[str, np.ndarray]:
        """Per excited line, every figure of the FRF file by name (docs/frf.md#file), in the
        CSV's column order."""
        lo_db, hi_db = self.magnitude_bounds_db()
        lo_ph, hi_ph = self.phase_bounds_deg()
        return {
            "freq_hz": self.freq_hz,
            "magnitude_db": self.magnitude_db,
            "phase_deg": self.phase_deg,
            "re": self.response.real,
            "im": self.response.imag,
            "std": self.std,
            "radius95": self.radius95,
            "magnitude_db_lo": lo_db,
            "magnitude_db_hi": hi_db,
            "phase_deg_lo": lo_ph,
            "phase_deg_hi": hi_ph,
            "coherence": self.coherence,
            "noise": self.noise,
            "aliased": self.aliased,
        }

    def to_dict(self) -> dict[str, Any]:
        """Plain data for the FRF file (docs/frf.md#file)."""
        c = self.columns()
        lines = [
            {
                "freq_hz": float(c["freq_hz"][i]),
                "re": float(c["re"][i]),
                "im": float(c["im"][i]),
                "magnitude_db": float(c["magnitude_db"][i]),
                "phase_deg": float(c["phase_deg"][i]),
                "std": float(c["std"][i]),
                "radius95": float(c["radius95"][i]),
                "magnitude_db_95": [
                    _finite(c["magnitude_db_lo"][i]),
                    float(c["magnitude_db_hi"][i]),
                ],
                "phase_deg_95": [float(c["phase_deg_lo"][i]), float(c["phase_deg_hi"][i])],
                "coherence": float(c["coherence"][i]),
                "noise": float(c["noise"][i]),
                "aliased": bool(c["aliased"][i]),
            }
            for i in range(self.freq_hz.size)
        ]
        return {
            "schema": FRF_SCHEMA,
            "output": self.output,
            "units": "counts/s per V" if self.output == "velocity" else "counts per V",
            "period_s": self.period_s,
            "period_ticks": self.period_ticks,
            "periods": self.periods,
            "skipped": self.skipped,
            "start_tick": self.start_tick,
            "lines": lines,
            "nonlinear_db": self.nonlinear_db(),
            "odd_lines": _levels(self.odd_hz, self.odd_level, self.odd_noise),
            "even_lines": _levels(self.even_hz, self.even_level, self.even_noise),
        }

    def to_csv(self) -> str:
        """One row per excited line (docs/frf.md#file)."""
        c = self.columns()
        aliased = c.pop("aliased")
        rows = [f"# schema: {FRF_SCHEMA}", f"# output: {self.output}", ",".join([*c, "aliased"])]
        for i in range(self.freq_hz.size):
            vals = ",".join(f"{float(col[i]):.9g}" for col in c.values())
            rows.append(f"{vals},{int(aliased[i])}")
        return "\n".join(rows) + "\n"


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _levels(hz: np.ndarray, level: np.ndarray, noise: np.ndarray) -> list[dict[str, float]]:
    return [
        {"freq_hz": float(f), "level": float(a), "noise": float(n)}
        for f, a, n in zip(hz, level, noise, strict=True)
    ]


def find_period(exc: np.ndarray, *, what: str = "the excitation (exc_code)") -> int:
    """The shortest period [ticks] that repeats ``exc`` exactly over its whole length.

    Candidates are the lags of the largest values of its circular autocorrelation (FFT), each
    checked exactly (``exc[n:] == exc[:-n]``), then the divisors of the one found.

    Raises
    ------
    SpecError
        No excitation (all zero), or no lag of :data:`MIN_PERIOD_TICKS` up to half the length
        repeats it: not periodic, or fewer than two periods.
    """
    x = np.asarray(exc)
    if x.size == 0 or not np.any(x != x[0]):
        raise SpecError(f"{what} is constant: the log holds no excitation to measure with")
    n = x.size
    if n < 2 * MIN_PERIOD_TICKS:
        raise SpecError(f"{what} has {n} ticks: too short for two periods")
    z = x.astype(float) - float(np.mean(x))
    spec = np.fft.rfft(z, 2 * n)
    acf = np.fft.irfft(np.abs(spec) ** 2)[: n // 2 + 1]
    lags = np.arange(acf.size)
    ok = lags >= MIN_PERIOD_TICKS
    order = lags[ok][np.argsort(-acf[ok], kind="stable")]

    def repeats(p: int) -> bool:
        return bool(np.array_equal(x[p:], x[:-p]))

    found = next((int(p) for p in order[:16] if repeats(int(p))), None)
    if found is None:
        raise SpecError(
            f"{what} is not periodic (no lag of {MIN_PERIOD_TICKS} … {n // 2} ticks repeats it "
            "exactly over the log, so fewer than two periods or not a periodic signal): a "
            "frequency response needs whole periods of a periodic excitation (servotune excite "
            "--kind multisine --periods P)"
        )
    for d in range(MIN_PERIOD_TICKS, found // 2 + 1):
        if found % d == 0 and repeats(d):
            return d
    return found


def _period(r: np.ndarray, period_ticks: int | None) -> int:
    """The excitation's period [ticks]: found (:func:`find_period`), or the one given, checked."""
    if period_ticks is None:
        return find_period(r)
    n_per = int(period_ticks)
    if n_per < MIN_PERIOD_TICKS or n_per > r.size:
        raise SpecError(
            f"period_ticks must be {MIN_PERIOD_TICKS} … {r.size} (the log's length), "
            f"got {period_ticks!r}"
        )
    whole = (r.size // n_per) * n_per
    if not np.array_equal(r[n_per:whole], r[: whole - n_per]):
        raise SpecError(f"the excitation does not repeat every {n_per} ticks")
    return n_per


def _deviations(x: np.ndarray) -> np.ndarray:
    """The spectra of each period's deviation from the mean period (rows: periods), each
    deviation with its own straight line removed first: a slow disturbance that does not
    repeat (a drifting load) leaks into every line of a period's DFT through its ramp across
    the period, and those ramps largely cancel in the average over periods, so counting them in
    the spread would overstate the noise of the averaged spectrum."""
    dev = x - x.mean(axis=0)
    n = x.shape[1]
    t = np.arange(n, dtype=float) - (n - 1) / 2.0
    slope = dev @ t / float(t @ t)
    dev -= dev.mean(axis=1, keepdims=True) + slope[:, None] * t
    return np.fft.rfft(dev, axis=1)


def estimate_frf(
    u: np.ndarray,
    y: np.ndarray,
    r: np.ndarray,
    *,
    period_s: float,
    output: str = "velocity",
    period_ticks: int | None = None,
    skip: int = 1,
    band_hz: tuple[float, float] | None = None,
) -> Frf:
    """The plant's frequency response from ``u`` (its input [V]) to ``y`` (position [counts]),
    measured with the periodic excitation ``r`` (module docstring).

    Parameters
    ----------
    u : array
        Plant input per tick [V] (the D/A command).
    y : array
        Position per tick [counts].
    r : array
        The excitation per tick (any units: only its lines and periodicity are used).
    period_s : float
        Tick period [s].
    output : str
        ``"velocity"`` (the backward difference of ``y`` over ``period_s``) or ``"position"``.
    period_ticks : int, optional
        Ticks per excitation period; default found from ``r`` (:func:`find_period`).
    skip : int
        Periods discarded at the start (the loop's transient), >= 0.
    band_hz : (float, float), optional
        Only lines within it; default every excited line.

    Returns
    -------
    Frf

    Raises
    ------
    SpecError
        Arrays of different lengths, an unknown output, a non-periodic excitation, fewer than 2
        periods after ``skip``, no excited line (in ``band_hz``), a non-finite sample.
    """
    u, y, r = (np.asarray(a) for a in (u, y, r))
    if not (u.ndim == y.ndim == r.ndim == 1 and u.size == y.size == r.size):
        raise SpecError(
            f"u, y and r must be 1-D of one length, got {u.shape}, {y.shape}, {r.shape}"
        )
    if output not in OUTPUTS:
        raise SpecError(f"output must be one of {', '.join(OUTPUTS)}, got {output!r}")
    if not (isinstance(period_s, float | int) and period_s > 0):
        raise SpecError(f"period_s must be > 0 [s], got {period_s!r}")
    if not isinstance(skip, int) or skip < 0:
        raise SpecError(f"skip must be a whole number of periods >= 0, got {skip!r}")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
        raise SpecError("u and y must be finite")
    a, b = 0, r.size
    try:
        n_per = _period(r, period_ticks)
    except SpecError:  # the log may hold a lead-in and a tail without the excitation
        nz = np.flatnonzero(r)
        if nz.size == 0 or (nz[0] == 0 and nz[-1] == r.size - 1):
            raise
        a, b = int(nz[0]), int(nz[-1]) + 1
        n_per = _period(r[a:b], period_ticks)
    total = (b - a) // n_per
    periods = total - skip
    if periods < 2:
        raise SpecError(
            f"the log holds {total} whole period{'s' if total != 1 else ''} of {n_per} ticks; "
            f"after discarding {skip} as transient at least 2 are needed"
        )
    start = a + skip * n_per
    stop = start + periods * n_per
    yf = y.astype(float)
    if output == "velocity":  # backward difference; the first sample has the one before it
        if start == 0:
            raise SpecError("the velocity needs the sample before the first period: skip >= 1")
        out = (yf[start:stop] - yf[start - 1 : stop - 1]) / period_s
    else:
        out = yf[start:stop]
    u_p = u[start:stop].astype(float).reshape(periods, n_per)
    y_p = out.reshape(periods, n_per)
    U = np.fft.rfft(u_p, axis=1)
    Y = np.fft.rfft(y_p, axis=1)
    R = np.abs(np.fft.rfft(r[a : a + n_per].astype(float)))
    R[0] = 0.0
    bins = np.flatnonzero(R > _EXCITED * R.max())
    f0 = 1.0 / (n_per * period_s)
    if band_hz is not None:
        lo, hi = band_hz
        bins = bins[(bins * f0 >= lo) & (bins * f0 <= hi)]
    if bins.size == 0:
        where = "" if band_hz is None else f" in {band_hz[0]:g}:{band_hz[1]:g} Hz"
        raise SpecError(f"no excited line{where}: the excitation carries no line there")
    Um, Ym = U.mean(axis=0), Y.mean(axis=0)
    dU, dY = _deviations(u_p), _deviations(y_p)
    var_u = np.sum(np.abs(dU) ** 2, axis=0) / (periods - 1)
    var_y = np.sum(np.abs(dY) ** 2, axis=0) / (periods - 1)
    cov_yu = np.sum(dY * np.conj(dU), axis=0) / (periods - 1)
    g = Ym[bins] / Um[bins]
    rel = (
        var_y[bins] / np.abs(Ym[bins]) ** 2
        + var_u[bins] / np.abs(Um[bins]) ** 2
        - 2.0 * np.real(cov_yu[bins] / (Ym[bins] * np.conj(Um[bins])))
    )
    std = np.abs(g) * np.sqrt(np.maximum(rel, 0.0) / periods)
    r95 = math.sqrt(float(stats.f.ppf(0.95, 2, 2 * (periods - 1)))) * std
    power = np.mean(np.abs(Y) ** 2, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        coherence = np.where(power > 0, np.abs(Ym) ** 2 / power, 1.0)
    noise = np.sqrt(var_y / periods)
    nyquist = n_per // 2
    freq = bins * f0
    top = int(bins.max())
    low = int(bins.min())
    others = np.arange(max(1, low), top + 1)
    others = others[~np.isin(others, bins)]
    odd_b = others[others % 2 == 1]
    even_b = others[others % 2 == 0]
    return Frf(
        freq_hz=freq,
        response=g,
        std=std,
        radius95=r95,
        coherence=coherence[bins],
        noise=noise[bins],
        output_level=np.abs(Ym[bins]),
        aliased=bins > ALIAS_FRACTION * nyquist,
        odd_hz=odd_b * f0,
        odd_level=np.abs(Ym[odd_b]),
        odd_noise=noise[odd_b],
        even_hz=even_b * f0,
        even_level=np.abs(Ym[even_b]),
        even_noise=noise[even_b],
        output=output,
        period_s=float(period_s),
        period_ticks=n_per,
        periods=periods,
        skipped=skip,
        start_tick=a,
    )


def frf(
    log: Any,
    axis: str | None = None,
    *,
    output: str = "velocity",
    period_ticks: int | None = None,
    skip: int = 1,
    band_hz: tuple[float, float] | None = None,
) -> Frf:
    """The measured frequency response of one axis of a closed-loop log (what ``servotune frf``
    runs): ``log`` a path (read by :func:`servotune.logs.read_log`) or a
    :class:`~servotune.logs.Log`; ``cmd_v`` in, ``pos_counts`` out, its ``exc_code`` column the
    excitation; the rest as :func:`estimate_frf`.
    :meth:`Frf.to_frd` gives python-control's ``FrequencyResponseData``.

    Examples
    --------
    >>> import numpy as np
    >>> from servotune.excite import periodic_multisine
    >>> m = periodic_multisine(64, 4, 0.004, 100, band_hz=(5, 100), phases="schroeder")
    >>> y = np.cumsum(m.codes * 0.5)  # an integrator: 0.5 counts per tick per V
    >>> f = estimate_frf(m.codes / 1.0, y, m.codes, period_s=0.004)
    >>> bool(np.allclose(f.response, 0.5 / 0.004))  # velocity: 125 counts/s per V
    True

    Raises
    ------
    LogFormatError
        The log cannot be read, or has no ``exc_code`` column for the axis.
    SpecError
        As :func:`estimate_frf`.
    """
    if not hasattr(log, "axis"):
        from servotune.logs import read_log

        log = read_log(log)
    ax = log.axis(axis)
    if ax.exc_code is None:
        raise LogFormatError(
            f"the log has no exc_code column{f' for axis {axis!r}' if axis else ''}: the "
            "frequency response needs the excitation the law added (servotune simulate "
            "--input EXC --closed-loop writes it; a HAL capture maps it with exc=PIN)"
        )
    return estimate_frf(
        ax.cmd_v,
        ax.pos_counts,
        ax.exc_code,
        period_s=log.period_s,
        output=output,
        period_ticks=period_ticks,
        skip=skip,
        band_hz=band_hz,
    )


FrfSource = Frf | str | Path | Mapping[str, Any]
"""An :class:`Frf`, a ``servotune frf`` JSON file's path, or its parsed content."""


def read_frf(source: FrfSource) -> Frf:
    """The :class:`Frf` of ``source``: itself, or read from a ``servotune frf`` JSON file
    (docs/frf.md#file) or its content.

    The file does not keep ``|Ȳ|`` of the excited lines (:attr:`Frf.output_level`): it is NaN
    in what is read back; every figure the report draws is in the file.

    Raises
    ------
    SpecError
        Not a ``servotune.frf/1`` document (a CSV FRF, another schema, a missing field).
    """
    if isinstance(source, Frf):
        return source
    if isinstance(source, Mapping):
        doc, where = source, "the FRF"
    else:
        where = str(source)
        try:
            doc = json.loads(Path(source).read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise SpecError(f"{where}: cannot read an FRF JSON file ({exc})") from None
    if not isinstance(doc, Mapping) or doc.get("schema") != FRF_SCHEMA:
        got = doc.get("schema") if isinstance(doc, Mapping) else type(doc).__name__
        raise SpecError(
            f"{where}: not a {FRF_SCHEMA} file (servotune frf -o FILE.json), got {got!r}"
        )
    try:
        return _frf_from_doc(doc)
    except (KeyError, TypeError, ValueError) as exc:
        raise SpecError(f"{where}: malformed {FRF_SCHEMA} file ({exc!r})") from None


def _frf_from_doc(doc: Mapping[str, Any]) -> Frf:
    lines = doc["lines"]
    if not lines:
        raise ValueError("no lines")

    def col(key: str) -> np.ndarray:
        return np.array([float(ln[key]) for ln in lines])

    def levels(key: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rows = doc.get(key) or []
        hz, level, noise = (
            np.array([float(r[k]) for r in rows]) for k in ("freq_hz", "level", "noise")
        )
        return hz, level, noise

    odd, even = levels("odd_lines"), levels("even_lines")
    return Frf(
        freq_hz=col("freq_hz"),
        response=col("re") + 1j * col("im"),
        std=col("std"),
        radius95=col("radius95"),
        coherence=col("coherence"),
        noise=col("noise"),
        output_level=np.full(len(lines), math.nan),
        aliased=np.array([bool(ln["aliased"]) for ln in lines]),
        odd_hz=odd[0],
        odd_level=odd[1],
        odd_noise=odd[2],
        even_hz=even[0],
        even_level=even[1],
        even_noise=even[2],
        output=str(doc["output"]),
        period_s=float(doc["period_s"]),
        period_ticks=int(doc["period_ticks"]),
        periods=int(doc["periods"]),
        skipped=int(doc["skipped"]),
        start_tick=int(doc.get("start_tick", 0)),
    )
