"""Experiment design: D/A excitations an axis can play safely, and their files.

An *excitation* is a sequence of D/A code offsets (what is added to the 0 V code, one per tick)
for one axis, designed for identification: ``prbs`` (a maximum-length binary sequence held about
one time constant per bit), ``multisine`` (a Schroeder-phased sum of sines on a log-spaced grid
from about 0.2 Hz to 0.4 · Nyquist; with ``periods``, :func:`periodic_multisine`'s whole periods
for a frequency response) or ``steps`` (+A, −A/2, +A/2, −A, ... with reversals).

:func:`design_excitation` scales the amplitude down until the sequence fits the D/A range and
the motion the rig's nominal plant predicts for it stays within 90 % of the axis speed limit and
of its travel (10 % margin for friction, drift and model error). The prediction is the exact
response of the linear axis model (docs/formats.md#axis-model) to the held codes, with the analog
drift ``offset_v`` acting from the start and Coulomb friction left out (it only slows the axis):
:mod:`servotune.excite_design`.

Files (:func:`write_excitation`, :func:`read_excitation`, both in
:mod:`servotune.excitation_file`) are log-format CSV (docs/formats.md#excitation-file) with the
columns ``tick,time_s,<axis>.dac_code`` (absolute codes); :func:`excitation_inputs` turns codes into
engine inputs, open loop or with the lock module active.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from servotune.budget import check_memory, format_count
from servotune.errors import SpecError
from servotune.excitation_file import MIN_TICKS, read_excitation, write_excitation
from servotune.excite_design import MARGIN, fit_amplitude
from servotune.fixed import round_half_away
from servotune.laws.axis import MODE_LOCK, MODE_OPEN
from servotune.rig import Axis, Rig
from servotune.scenarios import Inputs, prbs_codes, step_codes
from servotune.validate import show_value

__all__ = [
    "KINDS",
    "MARGIN",
    "MIN_TICKS",
    "PHASES",
    "Excitation",
    "PeriodicMultisine",
    "design_excitation",
    "excitation_inputs",
    "multisine_bins",
    "multisine_codes",
    "periodic_multisine",
    "read_excitation",
    "write_excitation",
]

KINDS = ("multisine", "prbs", "steps")
"""Excitation kinds :func:`design_excitation` makes."""

_MULTISINE_F_LO_HZ = 0.2
_MULTISINE_F_HI_NYQ = 0.4
_STEP_LEVEL_S = 0.25  # step level duration, as the ``steps`` scenario
_STEP_LEVEL_TAUS = 8.0  # ... but at least this many time constants, to settle
_DESIGN_BYTES_PER_TICK = 512  # patterns, predictions, candidate codes and the file's text
_PERIODIC_F_LO_HZ = 0.5  # a periodic multisine's default band starts here (or 2 lines up)


@dataclass(frozen=True, slots=True, kw_only=True)
class Excitation:
    """A designed excitation for one axis (what :func:`design_excitation` returns).

    Parameters
    ----------
    codes : ndarray of int64
        Per tick, the offset added to the 0 V code [D/A codes]; the runtime writes
        ``zero_code + codes[k]`` at tick ``k``.
    zero_code : int
        The rig's 0 V code [D/A code].
    period_s : float
        Tick period the codes are played at (the rig's achieved period) [s].
    axis : str
        Axis the excitation is for.
    kind : str
        ``"prbs"``, ``"multisine"`` or ``"steps"``.
    seed : int
        Seed of the design (it draws the PRBS windows; multisine and steps do not use it).
    amplitude_codes : int
        Largest ``|codes|`` [D/A codes].
    limited_by : str
        What set the amplitude: ``"requested"``, ``"dac"``, ``"speed"`` or ``"travel"``.
    predicted_max_speed_rpm : float
        Largest speed the nominal plant predicts (drift included, friction left out) [r/min].
    predicted_travel_counts : tuple of float
        (min, max) position the nominal plant predicts, relative to the start, including the
        coast-down after the last tick [counts].
    periods, period_ticks, band_hz, phases, crest_factor, excited_lines, detection_lines
        A periodic multisine's, else ``None``: periods, ticks a period, band (F1, F2) [Hz],
        phases, peak over RMS of ``codes`` [-], how many lines carry the signal and how many are
        left out to detect distortion (:class:`PeriodicMultisine`).
    """

    codes: np.ndarray
    zero_code: int
    period_s: float
    axis: str
    kind: str
    seed: int = 0
    amplitude_codes: int
    limited_by: str
    predicted_max_speed_rpm: float
    predicted_travel_counts: tuple[float, float]
    periods: int | None = None
    period_ticks: int | None = None
    band_hz: tuple[float, float] | None = None
    phases: str | None = None
    crest_factor: float | None = None
    excited_lines: int | None = None
    detection_lines: int | None = None

    def __post_init__(self) -> None:
        codes = np.asarray(self.codes)
        if codes.ndim != 1 or codes.size < MIN_TICKS:
            raise SpecError(
                f"codes must be a 1-D array of at least {MIN_TICKS} ticks, got shape {codes.shape}"
            )
        if not np.issubdtype(codes.dtype, np.integer):
            raise SpecError(f"codes must be integers [D/A codes], got dtype {codes.dtype}")
        codes = np.array(codes, dtype=np.int64)
        codes.setflags(write=False)
        object.__setattr__(self, "codes", codes)
        if not (isinstance(self.period_s, float | int) and self.period_s > 0):
            raise SpecError(f"period_s must be > 0 [s], got {show_value(self.period_s)}")
        if self.kind not in KINDS:
            raise SpecError(f"kind must be one of {', '.join(KINDS)}, got {show_value(self.kind)}")
        if self.limited_by not in ("requested", "dac", "speed", "travel"):
            raise SpecError(
                f"limited_by must be requested, dac, speed or travel, got "
                f"{show_value(self.limited_by)}"
            )
        if int(np.max(np.abs(codes))) != self.amplitude_codes:
            raise SpecError(
                f"amplitude_codes must equal max |codes| = {int(np.max(np.abs(codes)))}, "
                f"got {show_value(self.amplitude_codes)}"
            )
        lo, hi = self.predicted_travel_counts
        if not lo <= hi:
            raise SpecError(
                f"predicted_travel_counts must be (min, max), got "
                f"{show_value(self.predicted_travel_counts)}"
            )
        object.__setattr__(self, "predicted_travel_counts", (float(lo), float(hi)))
        if self.periods is not None and self.periods * (self.period_ticks or 0) != codes.size:
            raise SpecError(f"periods × period_ticks must be the {codes.size} ticks of codes")

    @property
    def n_ticks(self) -> int:
        """Length [ticks]."""
        return int(self.codes.size)

    @property
    def absolute_codes(self) -> np.ndarray:
        """The D/A codes the runtime writes, ``zero_code + codes`` [D/A codes]."""
        return self.codes + self.zero_code

    def to_columns(self) -> dict[str, np.ndarray]:
        """Log columns (docs/formats.md#columns): ``{"<axis>.dac_code": absolute codes}``
        (int64)."""
        return {f"{self.axis}.dac_code": self.absolute_codes}

    def to_dict(self) -> dict[str, Any]:
        """Summary as a plain dict (JSON-ready; the codes themselves are left out)."""
        return {
            "amplitude_codes": self.amplitude_codes,
            "axis": self.axis,
            "kind": self.kind,
            "limited_by": self.limited_by,
            "n_ticks": self.n_ticks,
            "period_s": self.period_s,
            "predicted_max_speed_rpm": self.predicted_max_speed_rpm,
            "predicted_travel_counts": list(self.predicted_travel_counts),
            "seed": self.seed,
        } | (self.periodic_fields() if self.periods is not None else {})

    def periodic_fields(self) -> dict[str, Any]:
        """The periodic multisine's fields (those defaulting to ``None``), by name."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.default is None}


# --- signals -------------------------------------------------------------------------------


def multisine_codes(
    n_ticks: int,
    period_s: float,
    amplitude_codes: float,
    f_lo_hz: float = _MULTISINE_F_LO_HZ,
    f_hi_hz: float | None = None,
    lines_per_decade: int = 10,
) -> np.ndarray:
    """Schroeder-phased multisine on a log-spaced grid [D/A codes, rounded half away from zero].

    The lines are whole periods of the record (frequencies ``k / (n_ticks · period_s)``, so the
    signal is periodic in the record and has no DC), about ``lines_per_decade`` per decade from
    ``f_lo_hz`` to ``f_hi_hz``, equal amplitudes, Schroeder phases
    ``φ_i = −π i (i − 1) / M`` for line ``i`` of ``M`` (M. R. Schroeder, "Synthesis of low-peak-
    factor signals and binary sequences with low autocorrelation", IEEE Trans. Inf. Theory 16,
    1970), normalised so the peak is ``amplitude_codes``.

    Parameters
    ----------
    n_ticks : int
        Length [ticks], >= 2.
    period_s : float
        Tick period [s].
    amplitude_codes : float
        Peak [D/A codes].
    f_lo_hz : float
        Lowest line [Hz] (raised to the record's resolution ``1 / (n_ticks · period_s)``).
    f_hi_hz : float, optional
        Highest line [Hz]; default 0.4 · Nyquist.
    lines_per_decade : int
        Grid density.

    Returns
    -------
    ndarray of int64

    Examples
    --------
    >>> c = multisine_codes(1000, 0.004, 100)
    >>> int(np.max(np.abs(c)))
    100
    """
    if n_ticks < 2:
        raise SpecError(f"a multisine needs at least 2 ticks, got {n_ticks}")
    bins = multisine_bins(n_ticks, period_s, f_lo_hz, f_hi_hz, lines_per_decade)
    m = bins.size
    phases = -math.pi * np.arange(1, m + 1) * np.arange(0, m) / m
    k = np.arange(n_ticks, dtype=np.int64)
    x = np.zeros(n_ticks)
    for b, ph in zip(bins.tolist(), phases.tolist(), strict=True):
        # the argument (b·k mod n) / n is exact, so the record is exactly periodic
        x += np.cos(2.0 * math.pi * ((b * k) % n_ticks) / n_ticks + ph)
    x *= amplitude_codes / np.max(np.abs(x))
    return round_half_away(x).astype(np.int64)


def multisine_bins(
    n_ticks: int,
    period_s: float,
    f_lo_hz: float = _MULTISINE_F_LO_HZ,
    f_hi_hz: float | None = None,
    lines_per_decade: int = 10,
) -> np.ndarray:
    """DFT bins (whole periods per record) of the multisine lines, ascending, unique.

    Line ``b`` has frequency ``b / (n_ticks · period_s)`` [Hz]; see :func:`multisine_codes`.
    """
    if not period_s > 0:
        raise SpecError(f"period_s must be > 0 [s], got {show_value(period_s)}")
    if f_hi_hz is None:
        f_hi_hz = _MULTISINE_F_HI_NYQ * 0.5 / period_s
    if not 0 < f_lo_hz < f_hi_hz:
        raise SpecError(
            f"multisine needs 0 < f_lo_hz < f_hi_hz, got {show_value(f_lo_hz)}, "
            f"{show_value(f_hi_hz)}"
        )
    if lines_per_decade < 1:
        raise SpecError(f"lines_per_decade must be >= 1, got {show_value(lines_per_decade)}")
    f_res = 1.0 / (n_ticks * period_s)
    b_lo = max(1, math.floor(f_lo_hz / f_res + 0.5))
    b_hi = max(b_lo, min(math.floor(f_hi_hz / f_res), (n_ticks - 1) // 2))
    b_hi = max(b_hi, b_lo)
    n_lines = max(2, math.ceil(lines_per_decade * math.log10(b_hi / b_lo)) + 1)
    grid = np.floor(np.geomspace(b_lo, b_hi, n_lines) + 0.5).astype(np.int64)
    return np.unique(grid)


@dataclass(frozen=True, slots=True, kw_only=True)
class PeriodicMultisine:
    """A periodic multisine for frequency-response measurement (:func:`periodic_multisine`).

    Attributes
    ----------
    codes : ndarray of int64
        ``periods`` whole periods of ``period_ticks`` ticks [D/A codes, relative to the 0 V
        code], rounded half away from zero; exactly periodic.
    period_ticks : int
        Ticks per period; line ``b`` is at ``b / (period_ticks · period_s)`` Hz.
    periods : int
        Periods in ``codes``.
    period_s : float
        Tick period [s].
    excited_bins : ndarray of int64
        The DFT bins (of one period) that carry the signal, ascending.
    detection_bins : ndarray of int64
        Odd bins in the band left unexcited to detect odd nonlinear distortion (empty for a
        multisine on every line).
    crest_factor : float
        Peak over RMS of the rounded codes [-].
    phases : str
        ``"schroeder"`` or ``"random"``.
    """

    codes: np.ndarray
    period_ticks: int
    periods: int
    period_s: float
    excited_bins: np.ndarray
    detection_bins: np.ndarray
    crest_factor: float
    phases: str

    @property
    def freq_hz(self) -> np.ndarray:
        """Frequencies of the excited lines [Hz]."""
        return self.excited_bins / (self.period_ticks * self.period_s)


PHASES = ("schroeder", "random")
"""Phase choices of :func:`periodic_multisine`."""

_CREST_ITERATIONS = 100  # clipping passes that lower a Schroeder start's crest factor
_CLIP = (0.6, 0.95)  # the passes clip the peaks to this fraction of the peak, rising pass by pass


def periodic_multisine(
    period_ticks: int,
    periods: int,
    period_s: float,
    amplitude_codes: float,
    *,
    band_hz: tuple[float, float],
    phases: str = "schroeder",
    odd: bool = True,
    detection_every: int = 3,
    seed: int = 0,
) -> PeriodicMultisine:
    """A periodic multisine [D/A codes] for measuring a frequency response.

    One period has ``period_ticks`` ticks; its lines are the DFT bins ``b`` whose frequency
    ``b / (period_ticks · period_s)`` lies in ``band_hz`` (at most 0.9 · Nyquist), equal
    amplitudes. ``odd``: only odd bins, and of every ``detection_every`` consecutive odd bins
    one drawn at random (from ``seed``) is left out as a *detection line*: an odd nonlinearity
    shows there, an even one on the even bins (J. Schoukens, R. Pintelon, Y. Rolain, "Mastering
    System Identification in 100 Exercises", Wiley 2012, §2.7: the random odd multisine).
    ``detection_every`` 0 leaves no line out.

    ``phases``: ``"random"`` (uniform, from ``seed``: the random-phase multisine, crest factor
    about 3) or ``"schroeder"`` (M. R. Schroeder, IEEE Trans. Inf. Theory 16, 1970:
    ``φ_m = −π m (m − 1) / M``) refined by clipping the peaks and restoring the amplitudes
    (E. Van der Ouderaa, J. Schoukens, J. Renneboog, "Peak factor minimization using a
    time-frequency domain swapping algorithm", IEEE Trans. Instrum. Meas. 37, 1988): crest
    factor about 1.6 on such line sets. The signal is scaled so its peak is
    ``amplitude_codes``, rounded half away from zero, and repeated ``periods`` times.

    Raises
    ------
    SpecError
        Fewer than 2 periods or 16 ticks a period, a band outside 0 < F1 < F2 <= 0.9 · Nyquist,
        no line in the band, an unknown phase choice, an amplitude below 1 code.
    """
    if not isinstance(period_ticks, int | np.integer) or period_ticks < 16:
        raise SpecError(f"a period needs at least 16 ticks, got {show_value(period_ticks)}")
    if not isinstance(periods, int | np.integer) or periods < 2:
        raise SpecError(
            f"a frequency response needs at least 2 periods (the first is discarded as "
            f"transient), got {show_value(periods)}"
        )
    if not period_s > 0:
        raise SpecError(f"period_s must be > 0 [s], got {show_value(period_s)}")
    if phases not in PHASES:
        raise SpecError(f"phases must be one of {', '.join(PHASES)}, got {show_value(phases)}")
    if not amplitude_codes >= 1:
        raise SpecError(f"amplitude_codes must be >= 1, got {show_value(amplitude_codes)}")
    f1, f2 = (float(f) for f in band_hz)
    top = 0.9 * 0.5 / period_s
    if not 0 < f1 < f2 <= top * (1 + 1e-12):
        raise SpecError(
            f"the band {f1:g}:{f2:g} Hz must satisfy 0 < F1 < F2 <= 0.9 · Nyquist = {top:g} Hz "
            f"(period {period_s * 1e3:g} ms)"
        )
    f0 = 1.0 / (period_ticks * period_s)
    bins = np.arange(max(1, math.ceil(f1 / f0 - 1e-9)), math.floor(f2 / f0 + 1e-9) + 1)
    bins = bins[bins < period_ticks / 2]
    detection = np.zeros(0, dtype=np.int64)
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    if odd:
        bins = bins[bins % 2 == 1]
        if detection_every > 0 and bins.size >= detection_every:
            drop = np.zeros(bins.size, dtype=bool)
            for g in range(0, bins.size - detection_every + 1, detection_every):
                drop[g + int(rng.integers(detection_every))] = True
            detection, bins = bins[drop], bins[~drop]
    if bins.size < 1:
        raise SpecError(
            f"no {'odd ' if odd else ''}line of a {period_ticks}-tick period "
            f"({f0:.4g} Hz apart) lies in {f1:g}:{f2:g} Hz; lengthen the period or widen the band"
        )
    m = np.arange(1, bins.size + 1)
    if phases == "random":
        phi = rng.uniform(0.0, 2.0 * math.pi, bins.size)
    else:
        phi = -math.pi * m * (m - 1) / bins.size
    spec = np.zeros(period_ticks // 2 + 1, dtype=complex)
    spec[bins] = np.exp(1j * phi)
    x = np.fft.irfft(spec, period_ticks)
    if phases == "schroeder":
        for clip in np.linspace(*_CLIP, _CREST_ITERATIONS).tolist():
            c = clip * float(np.max(np.abs(x)))
            back = np.fft.rfft(np.clip(x, -c, c))
            spec[bins] = np.exp(1j * np.angle(back[bins]))
            x = np.fft.irfft(spec, period_ticks)
    codes = round_half_away(x * (amplitude_codes / np.max(np.abs(x)))).astype(np.int64)
    crest = float(np.max(np.abs(codes)) / np.sqrt(np.mean(codes.astype(float) ** 2)))
    return PeriodicMultisine(
        codes=np.tile(codes, int(periods)),
        period_ticks=int(period_ticks),
        periods=int(periods),
        period_s=float(period_s),
        excited_bins=bins.astype(np.int64),
        detection_bins=detection.astype(np.int64),
        crest_factor=crest,
        phases=phases,
    )


_PRBS_CANDIDATES = 8  # seeded window starts tried; the best balanced one is used


def _unit_pattern(kind: str, n: int, rig: Rig, ax: Axis, seed: int) -> tuple[Any, np.ndarray]:
    """A maker ``amplitude -> codes`` and the unit-amplitude pattern (float, peak 1).

    The patterns are balanced so the position swings about the start: the PRBS window (of
    ``_PRBS_CANDIDATES`` drawn from ``seed``) whose running sum strays least, the multisine
    rotated (it is periodic in the record) to start where its position is mid-range, the steps
    started half-way through the first level.
    """
    period = rig.period_s
    if kind == "prbs":
        hold = max(1, math.floor(ax.plant.tau_s / period + 0.5))
        n_bits = -(-n // hold)
        order = next((o for o in range(5, 12) if 2**o - 1 >= n_bits), 11)
        # SeedSequence hashes the seed the same on every platform and numpy version
        starts = np.random.SeedSequence(seed).generate_state(_PRBS_CANDIDATES, dtype=np.uint64)
        best, best_walk = np.zeros(0, dtype=np.int64), math.inf
        for st in starts.tolist():
            skip = int(st % (2**order - 1)) * hold
            cand = prbs_codes(n + skip, 1, hold_ticks=hold, order=order)[skip:]
            walk = float(np.max(np.abs(np.cumsum(cand))))
            if walk < best_walk:
                best, best_walk = cand, walk
        return (lambda a: best * a), best.astype(float)
    if kind == "steps":
        level = max(
            math.floor(_STEP_LEVEL_S / period + 0.5),
            math.ceil(_STEP_LEVEL_TAUS * ax.plant.tau_s / period),
        )
        level = max(1, min(level, n // 4))
        skip = level // 2

        def make(a: int) -> np.ndarray:
            return step_codes(n + skip, a, level)[skip:]

        unit = np.array([1.0, -0.5, 0.5, -1.0])[((np.arange(n) + skip) // level) % 4]
        return make, unit
    x = multisine_codes(n, period, 1_000_000) / 1_000_000.0
    pos = np.concatenate(([0.0], np.cumsum(x)[:-1]))  # position at each tick start, periodic
    shift = int(np.argmin(np.abs(pos - 0.5 * (pos.max() + pos.min()))))
    return (lambda a: np.roll(multisine_codes(n, period, a), -shift)), np.roll(x, -shift)


def _periodic_pattern(
    rig: Rig, seconds: float, periods: Any, band_hz: Any, phases: str, seed: int
) -> tuple[Any, np.ndarray, Any]:
    """As :func:`_unit_pattern`, for a :func:`periodic_multisine` of ``round(seconds / periods
    / period_s)`` ticks a period (every period rotated alike), and ``amplitude -> its
    Excitation fields`` (:meth:`Excitation.periodic_fields`)."""
    if not isinstance(periods, int | np.integer) or isinstance(periods, bool) or periods < 2:
        raise SpecError(f"a frequency response needs periods >= 2, got {show_value(periods)}")
    period = rig.period_s
    ticks = math.floor(seconds / periods / period + 0.5)
    if band_hz is None:
        f_lo = max(2.0 / (max(ticks, 1) * period), _PERIODIC_F_LO_HZ)
        band_hz = (f_lo, _MULTISINE_F_HI_NYQ * 0.5 / period)
    band = (float(band_hz[0]), float(band_hz[1]))

    def design(a: float) -> PeriodicMultisine:
        return periodic_multisine(ticks, periods, period, a, band_hz=band, phases=phases, seed=seed)

    x = design(1_000_000).codes / 1_000_000.0
    pos = np.concatenate(([0.0], np.cumsum(x[:ticks])[:-1]))  # over one period, at tick starts
    shift = int(np.argmin(np.abs(pos - 0.5 * (pos.max() + pos.min()))))

    def periodic(a: int) -> dict[str, Any]:
        ms = design(a)
        return {
            "periods": ms.periods,
            "period_ticks": ms.period_ticks,
            "band_hz": band,
            "phases": ms.phases,
            "crest_factor": ms.crest_factor,
            "excited_lines": int(ms.excited_bins.size),
            "detection_lines": int(ms.detection_bins.size),
        }

    return (lambda a: np.roll(design(a).codes, -shift)), np.roll(x, -shift), periodic


# --- design --------------------------------------------------------------------------------


def _check_request(
    kind: str,
    seconds: float,
    periods: int | None,
    band_hz: tuple[float, float] | None,
    seed: int,
) -> None:
    """Check :func:`design_excitation`'s options: ``periods`` and ``band_hz`` only for a
    periodic multisine, the seed, the duration.

    Raises
    ------
    SpecError
        One of them is not valid.
    """
    if (periods is not None or band_hz is not None) and kind != "multisine":
        raise SpecError(f"periods and band_hz are for a multisine, not for {show_value(kind)}")
    if band_hz is not None and periods is None:
        raise SpecError("band_hz is for a periodic multisine: give periods too")
    if not isinstance(seed, int | np.integer) or isinstance(seed, bool) or seed < 0:
        raise SpecError(f"seed must be an integer >= 0, got {show_value(seed)}")
    if not (isinstance(seconds, int | float) and math.isfinite(seconds) and seconds > 0):
        raise SpecError(f"seconds must be > 0 [s], got {show_value(seconds)}")


def _design_ticks(rig: Rig, seconds: float) -> int:
    """``seconds`` in whole ticks of the achieved period, checked against the memory the
    design takes.

    Raises
    ------
    SpecError
        Fewer than :data:`MIN_TICKS` ticks.
    """
    period = rig.period_s
    check_memory(
        seconds / period * _DESIGN_BYTES_PER_TICK,
        f"an excitation of {seconds:g} s",
        f"{format_count(seconds / period)} ticks × {_DESIGN_BYTES_PER_TICK} bytes",
    )
    n = math.floor(seconds / period + 0.5)
    if n < MIN_TICKS:
        raise SpecError(
            f"seconds={show_value(seconds)} gives only {n} ticks of {period * 1e3:.6f} ms; "
            f"an excitation needs at least {MIN_TICKS}"
        )
    return n


def _start_amplitude(rig: Rig, amplitude_codes: int | None) -> tuple[int, int, str]:
    """The 0 V code, the amplitude the design starts from (``amplitude_codes``, at most the
    largest symmetric D/A swing, which is the default) and what set it.

    Raises
    ------
    SpecError
        A D/A without both polarities, or an amplitude that is not an integer >= 1.
    """
    zero, cmax = rig.dac.zero_code, rig.dac.code_max
    dac_amp = min(zero, cmax - zero)
    if dac_amp < 1:
        raise SpecError(
            f"the D/A range {show_value(rig.dac.range_v)} V has no room on one side of 0 V; "
            "an excitation needs both polarities"
        )
    if amplitude_codes is None:
        return zero, dac_amp, "dac"
    if (
        not isinstance(amplitude_codes, int | np.integer)
        or isinstance(amplitude_codes, bool)
        or amplitude_codes < 1
    ):
        raise SpecError(
            f"amplitude_codes must be an integer >= 1 [D/A codes], got "
            f"{show_value(amplitude_codes)}"
        )
    amp, limited_by = min(int(amplitude_codes), dac_amp), "requested"
    if amplitude_codes > dac_amp:
        limited_by = "dac"
    return zero, amp, limited_by


def design_excitation(
    rig: Rig,
    axis: str,
    kind: str,
    seconds: float,
    *,
    periods: int | None = None,
    band_hz: tuple[float, float] | None = None,
    phases: str = "schroeder",
    seed: int = 0,
    amplitude_codes: int | None = None,
) -> Excitation:
    """Design a D/A excitation the axis can play within its D/A range, speed limit and travel.

    The amplitude starts at ``amplitude_codes`` (default: the largest symmetric D/A swing) and
    is scaled down until the nominal plant's predicted speed stays within 90 % of the axis speed
    limit and its predicted position (drift included, plus the coast-down after the last tick)
    within 90 % of the axis travel (a rotary axis, ``travel_counts = None``, has no travel
    limit). Every kind is zero-mean or nearly so by construction and reverses direction.

    Parameters
    ----------
    rig : Rig
        The rig (period, D/A, axis limits and nominal plant).
    axis : str
        Axis name.
    kind : str
        ``"prbs"``: maximum-length PRBS (:func:`servotune.scenarios.prbs_codes`), each bit held
        about ``tau_s / period_s`` ticks; of 8 windows of the m-sequence drawn from ``seed``, the
        one whose running sum strays least from zero;
        ``"multisine"``: :func:`multisine_codes` from 0.2 Hz to 0.4 · Nyquist, rotated to
        start where its (periodic) position is mid-range; with ``periods``, the
        :func:`periodic_multisine` for a frequency response (docs/frf.md), rotated alike;
        ``"steps"``: :func:`servotune.scenarios.step_codes`, levels of
        max(0.25 s, 8 · tau_s), starting half-way through the first level.
    seconds : float
        Duration [s]; rounded to whole ticks of the achieved period, at least 10 ticks.
    periods, band_hz, phases : int, (float, float), str, optional
        A multisine only: ``periods`` (>= 2) whole periods of ``round(seconds / periods)``,
        band (default max(2 lines, 0.5 Hz) … 0.4 · Nyquist) and phases of the random odd
        multisine (:func:`periodic_multisine`).
    seed : int
        Design seed (>= 0); same inputs and seed give the same codes.
    amplitude_codes : int, optional
        Largest amplitude wanted [D/A codes]; reduced if a limit requires it.

    Returns
    -------
    Excitation

    Raises
    ------
    SpecError
        Unknown kind, fewer than 10 ticks, a bad amplitude or seed, a D/A without both
        polarities, drift alone leaving 90 % of the travel, or no amplitude of at least one code
        (and enough to overcome drift and friction both ways) fits the limits; ``periods`` for
        another kind, ``band_hz`` without them, what :func:`periodic_multisine` refuses.
    RigError
        If the rig has no such axis.
    """
    if kind not in KINDS:
        raise SpecError(
            f"unknown excitation kind {show_value(kind)}; choose one of {', '.join(KINDS)}"
        )
    ax = rig.axis(axis)
    _check_request(kind, seconds, periods, band_hz, seed)
    n = _design_ticks(rig, seconds)
    zero, amp, limited_by = _start_amplitude(rig, amplitude_codes)
    periodic = None
    if periods is None:
        make, unit = _unit_pattern(kind, n, rig, ax, seed)
    else:
        make, unit, periodic = _periodic_pattern(rig, seconds, periods, band_hz, phases, seed)
    fit = fit_amplitude(rig, ax, make, unit, amp, limited_by, axis=axis, kind=kind, seconds=seconds)
    codes, m, amp = fit.codes, fit.motion, fit.amplitude_codes
    return Excitation(
        codes=codes,
        zero_code=zero,
        period_s=rig.period_s,
        axis=axis,
        kind=kind,
        seed=int(seed),
        amplitude_codes=int(np.max(np.abs(codes))),
        limited_by=fit.limited_by,
        predicted_max_speed_rpm=float(np.max(np.abs(m.speed_cps))) / rig.counts_per_rev * 60.0,
        predicted_travel_counts=(float(m.pos_counts.min()), float(m.pos_counts.max())),
        **({} if periodic is None else periodic(amp)),
    )


# --- playing -------------------------------------------------------------------------------


def excitation_inputs(
    rig: Rig, axis: str, codes: np.ndarray, *, closed_loop: bool = False
) -> Inputs:
    """Engine inputs that play absolute D/A ``codes`` on ``axis``, one per tick.

    Parameters
    ----------
    rig : Rig
    axis : str
        Axis to excite; every other axis is held by the lock module.
    codes : array of int
        Absolute D/A codes (as :func:`read_excitation` returns), in ``0..code_max``.
    closed_loop : bool
        False: open loop (``MODE_OPEN``), the D/A writes exactly ``codes``. True: the lock
        module stays active (``MODE_LOCK``) and ``codes − zero_code`` is added to its output.

    Returns
    -------
    Inputs
        ``dac_add_codes = codes − zero_code`` on the axis, shape (len(codes), n_axes).

    Raises
    ------
    SpecError
        If ``codes`` is not a non-empty 1-D integer array within the D/A range.
    RigError
        If the rig has no such axis.
    """
    rig.axis(axis)
    c = np.asarray(codes)
    if c.ndim != 1 or c.size < 1 or not np.issubdtype(c.dtype, np.integer):
        raise SpecError(
            f"codes must be a non-empty 1-D integer array [D/A codes], got shape {c.shape} "
            f"dtype {c.dtype}"
        )
    if c.min() < 0 or c.max() > rig.dac.code_max:
        raise SpecError(
            f"codes must be within the D/A range 0..{rig.dac.code_max}, "
            f"got {int(c.min())}..{int(c.max())}"
        )
    i = rig.axis_names.index(axis)
    mode = MODE_LOCK if closed_loop else MODE_OPEN
    return Inputs.hold(c.size, len(rig.axes)).replace_axis(
        i, dac_add_codes=c.astype(np.int64) - rig.dac.zero_code, mode=mode
    )
