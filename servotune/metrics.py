"""Step-response and tracking metrics.

Plain functions on sampled responses. :func:`step_info` follows the definitions of MATLAB
``stepinfo``. By default it reads them at the samples, as MATLAB ``stepinfo`` and python-control's
``step_info`` do for a discrete-time system (the response of a sampled loop is known only at its
ticks); ``refine=True`` instead interpolates crossings and refines extrema between the samples,
for densely sampled continuous-like data. :func:`tracking_metrics` summarises a tracking-error
sequence sampled once per tick.
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass, fields
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["StepInfo", "TrackingMetrics", "step_info", "tracking_metrics"]

_MIN_SAMPLES = 3


@dataclass(frozen=True, slots=True, kw_only=True)
class StepInfo:
    """Step-response characteristics, as returned by :func:`step_info`.

    Every field is a plain ``float``; a characteristic that the response does not reach is NaN.
    Times and values are read at the samples, or between them with ``refine=True`` (see
    :func:`step_info`).

    Parameters
    ----------
    rise_time_s : float
        Time from the first crossing of the lower rise limit to the first crossing of the
        upper rise limit [s]. NaN if the response never reaches the upper limit.
    settling_time_s : float
        Time, measured from ``t[0]``, after which the response stays within the settling band
        around ``y_final`` [s]. NaN if the last sample is still outside the band.
    settling_min : float
        Minimum of ``y`` once the response has risen, i.e. from the upper rise-limit crossing
        on [unit of y]. NaN if the response never rises.
    settling_max : float
        Maximum of ``y`` once the response has risen [unit of y]. NaN if it never rises.
    overshoot_pct : float
        Peak of the normalised response above 1, relative to the step size [%].
    undershoot_pct : float
        Peak of the normalised response below 0 (opposite to the step), relative to the step
        size [%].
    peak : float
        Peak of ``|y - y_init|`` [unit of y].
    peak_time_s : float
        Time at which ``peak`` first occurs, on the time axis of ``t`` [s].
    """

    rise_time_s: float
    settling_time_s: float
    settling_min: float
    settling_max: float
    overshoot_pct: float
    undershoot_pct: float
    peak: float
    peak_time_s: float

    def __post_init__(self) -> None:
        """Store every field as a plain float and check the signs."""
        _coerce_float_fields(self)
        for name in ("rise_time_s", "settling_time_s", "overshoot_pct", "undershoot_pct", "peak"):
            value = getattr(self, name)
            if value < 0.0:  # NaN compares False and is allowed
                raise ValueError(f"{name} must be >= 0 or NaN, got {value!r}")

    def to_dict(self) -> dict[str, float]:
        """Return the characteristics as a dict of plain floats, keyed by field name.

        Returns
        -------
        dict of str to float
            One entry per field; unreached characteristics are ``nan``.
        """
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackingMetrics:
    """Tracking-error summary, as returned by :func:`tracking_metrics`.

    Parameters
    ----------
    max_abs : float
        Largest absolute error [counts].
    rms : float
        Root-mean-square error [counts].
    itae : float
        Integral of time-weighted absolute error, ``sum(k*period_s * |e_k| * period_s)``
        [counts*s^2].
    steady_lag : float
        Mean (signed) error over the steady-state samples [counts].
    """

    max_abs: float
    rms: float
    itae: float
    steady_lag: float

    def __post_init__(self) -> None:
        """Store every field as a plain float and check the values."""
        _coerce_float_fields(self)
        for name in ("max_abs", "rms", "itae"):
            value = getattr(self, name)
            if not value >= 0.0:
                raise ValueError(f"{name} must be >= 0, got {value!r}")
        if not math.isfinite(self.steady_lag):
            raise ValueError(f"steady_lag must be finite, got {self.steady_lag!r}")

    def to_dict(self) -> dict[str, float]:
        """Return the metrics as a dict of plain floats, keyed by field name.

        Returns
        -------
        dict of str to float
            One entry per field.
        """
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}


def step_info(
    t: ArrayLike,
    y: ArrayLike,
    *,
    y_init: float | None = None,
    y_final: float | None = None,
    settling_threshold: float = 0.02,
    rise_limits: tuple[float, float] = (0.1, 0.9),
    refine: bool = False,
) -> StepInfo:
    """Compute step-response characteristics of a sampled response.

    The definitions are those of MATLAB ``stepinfo``, applied to the normalised response
    ``z = (y - y_init) / (y_final - y_init)`` (so a negative step is handled like a positive
    one). By default they are read at the samples, the convention of MATLAB ``stepinfo`` and
    python-control's ``step_info`` for a discrete-time system; ``refine=True`` estimates them
    between the samples instead (see Notes).

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times, strictly increasing [s]. The step is taken to be applied at ``t[0]``.
    y : array_like, shape (n,)
        Response samples [any unit, e.g. counts].
    y_init : float, optional
        Value before the step [unit of y]. Default ``y[0]``.
    y_final : float, optional
        Steady-state value after the step [unit of y]. Default ``y[-1]``.
    settling_threshold : float, optional
        Half-width of the settling band as a fraction of the step size ``|y_final - y_init|``
        [-], in (0, 1). Default 0.02 (2 %).
    rise_limits : tuple of float, optional
        Lower and upper rise levels as fractions of the step [-], ``0 <= low < high <= 1``.
        Default (0.1, 0.9).
    refine : bool, optional
        False (default): read every characteristic at the samples. True: locate level
        crossings by linear interpolation and refine extrema with a parabola, for densely
        sampled data of a continuous response.

    Returns
    -------
    StepInfo
        ``rise_time_s`` [s]: time between the first crossings of the lower and upper rise
        levels. ``settling_time_s`` [s]: time from ``t[0]`` after which
        ``|y - y_final| <= settling_threshold * |y_final - y_init|`` for good; 0 if the
        response never leaves the band, NaN if it is still outside at the last sample.
        ``settling_min``, ``settling_max`` [unit of y]: extrema of ``y`` from the upper rise
        crossing on. ``overshoot_pct``, ``undershoot_pct`` [%]: ``100 * max(0, max(z) - 1)``
        and ``100 * max(0, -min(z))``. ``peak`` [unit of y]: maximum of ``|y - y_init|``;
        ``peak_time_s`` [s]: its (first) time on the axis of ``t``.

    Raises
    ------
    ValueError
        If ``t`` or ``y`` is not a finite 1-D array of at least 3 samples, their lengths
        differ, ``t`` is not strictly increasing, ``y_init`` or ``y_final`` is not finite,
        the step ``y_final - y_init`` is zero, ``settling_threshold`` or ``rise_limits``
        is out of range, or ``refine`` is not a bool.

    Notes
    -----
    **At the samples** (default), as python-control's ``step_info`` computes them (on any
    time grid) and as MATLAB ``stepinfo`` reads a discrete-time system (the times of the 0.2 s
    ``ss`` example of its page are multiples of the sample time):

    - rise time: ``t[i_high] - t[i_low]``, where ``i_low`` and ``i_high`` are the first samples
      with ``z >= low`` and ``z >= high``;
    - settling time: ``t[j + 1] - t[0]``, where ``j`` is the last sample outside the band (the
      first sample of the final run of samples inside it);
    - settling min / max: extrema of the samples from ``i_high`` on;
    - overshoot, undershoot, peak: extreme samples; peak time: time of the first sample of
      largest ``|y - y_init|``.

    With ``y_init = 0`` and ``y_final`` its DC gain, the result equals python-control's
    ``step_info`` of a discrete-time system except in two documented details:

    - ``settling_min`` / ``settling_max`` are extrema of the samples, as MATLAB defines them;
      python-control clips them to ``y_final`` (``min(..., y_final)``, ``max(..., y_final)``),
      which for a response still approaching ``y_final`` at the last sample reports a value
      the response never takes;
    - the settling band is tested as ``|y - y_final| <= threshold * |y_final - y_init|`` on
      the deviation, so a sample exactly on the edge (e.g. integer counts: 980 for a 1000-count
      step and a 2 % band) is inside; python-control tests ``|y / y_final - 1| >= threshold``,
      which decides such ties by the rounding of the division.

    The settling band is relative to the step ``|y_final - y_init|`` (current MATLAB and
    python-control). Older MATLAB releases used 2 % of the peak error ``max|y - y_final|``
    instead, a wider band when that error exceeds the step (a response that starts on the wrong
    side of ``y_init``, or overshoots by more than 100 %): that is why the discrete example of
    the MATLAB page gives settling times one sample earlier on two of its channels.

    **Between the samples** (``refine=True``), an estimate of the continuous response the
    samples come from: level crossings (rise limits, settling band exit) are found by linear
    interpolation between the two samples that bracket the level, as MATLAB does for a
    continuous-time system; extrema (peak, overshoot, undershoot, settling minimum and
    maximum) at an interior sample are refined to the vertex of the parabola through that
    sample and its two neighbours (MATLAB reads them off its simulation grid), and the
    settling extrema start at the interpolated upper rise crossing. Rise and settling times
    then carry an error of order ``dt**2`` times the curvature of the response at the
    crossing; peak values an error of order ``dt**3`` and peak times of order ``dt**2``. In
    both modes the settling test is made on the samples: an excursion out of the band that
    starts and ends between two samples is not seen.

    MATLAB's data syntax ``stepinfo(y, t)`` takes ``y_init = 0``; here the default is ``y[0]``,
    the value the response starts from. Pass ``y_init=0.0`` to reproduce MATLAB and
    python-control (a response with direct feedthrough starts away from 0).

    Examples
    --------
    A first-order lag with time constant 1 s sampled every 50 ms: rise time ln 9 = 2.197 s and
    settling time ln 50 = 3.912 s, read at the samples (the 10 %, 90 % and 2 % levels are first
    reached at the samples 0.15 s, 2.35 s and 3.95 s) or interpolated between them.

    >>> import numpy as np
    >>> t = np.arange(401) * 0.05
    >>> info = step_info(t, 1.0 - np.exp(-t), y_final=1.0)
    >>> round(info.rise_time_s, 3), round(info.settling_time_s, 3)
    (2.2, 3.95)
    >>> fine = step_info(t, 1.0 - np.exp(-t), y_final=1.0, refine=True)
    >>> round(fine.rise_time_s, 3), round(fine.settling_time_s, 3)
    (2.197, 3.912)
    >>> info.overshoot_pct
    0.0
    """
    t_arr = _as_finite_1d("t", t)
    y_arr = _as_finite_1d("y", y)
    _check_same_length(t_arr, y_arr)
    _check_strictly_increasing("t", t_arr)
    y0 = float(y_arr[0]) if y_init is None else _finite_float("y_init", y_init)
    y1 = float(y_arr[-1]) if y_final is None else _finite_float("y_final", y_final)
    step = y1 - y0
    if step == 0.0 or not math.isfinite(step):
        raise ValueError(
            "the step y_final - y_init must be nonzero and finite, "
            f"got y_init={y0!r} and y_final={y1!r}"
        )
    threshold = _finite_float("settling_threshold", settling_threshold)
    if not 0.0 < threshold < 1.0:
        raise ValueError(f"settling_threshold must be in (0, 1), got {threshold!r}")
    low, high = _rise_limits(rise_limits)
    if not isinstance(refine, (bool, np.bool_)):
        raise ValueError(f"refine must be True or False, got {refine!r}")
    levels = _Levels(y0, y1, threshold, low, high)
    return (_step_info_refined if refine else _step_info_sampled)(t_arr, y_arr, levels)


class _Levels(NamedTuple):
    """What :func:`step_info` reads a response against: the initial and final values, the
    settling band (a fraction of the step) and the two rise levels (fractions of it)."""

    y0: float
    y1: float
    threshold: float
    low: float
    high: float


def _step_info_sampled(t: NDArray[np.float64], y: NDArray[np.float64], lv: _Levels) -> StepInfo:
    """:func:`step_info` read at the samples (python-control's ``step_info`` conventions)."""
    y0, y1, threshold, low, high = lv
    step = y1 - y0
    size = abs(step)
    # Deviation from y_init in the direction of the step: it is `size` at y_final. Levels are
    # compared as `dev >= level * size`, which is exactly python-control's
    # `sign * (y - level * y_final) >= 0` when y_init = 0.
    dev = (y - y0) if step > 0.0 else (y0 - y)

    # Rise time: first samples at or beyond the two rise levels.
    i_low = _first_index(dev >= low * size)
    i_high = _first_index(dev >= high * size)
    rise_time = math.nan if i_high < 0 else float(t[i_high] - t[i_low])

    # Settling time: the first sample of the final run of samples inside the band.
    outside = np.flatnonzero(np.abs(y - y1) > threshold * size)
    if outside.size == 0:
        settling_time = 0.0
    elif outside[-1] == y.size - 1:
        settling_time = math.nan
    else:
        settling_time = float(t[outside[-1] + 1] - t[0])

    # Settling min / max: extreme samples from the first one at or beyond the upper level.
    if i_high < 0:
        settling_min = settling_max = math.nan
    else:
        settling_min = float(np.min(y[i_high:]))
        settling_max = float(np.max(y[i_high:]))

    # Overshoot / undershoot: extreme samples of the deviation, relative to the step size.
    overshoot = 100.0 * max(0.0, float(np.max(dev)) - size) / size
    undershoot = 100.0 * max(0.0, -float(np.min(dev))) / size

    # Peak of |y - y_init| and the time of its first sample.
    abs_dev = np.abs(dev)
    i_peak = int(np.argmax(abs_dev))

    return StepInfo(
        rise_time_s=rise_time,
        settling_time_s=settling_time,
        settling_min=settling_min,
        settling_max=settling_max,
        overshoot_pct=overshoot,
        undershoot_pct=undershoot,
        peak=float(abs_dev[i_peak]),
        peak_time_s=float(t[i_peak]),
    )


def _step_info_refined(
    t_arr: NDArray[np.float64], y_arr: NDArray[np.float64], lv: _Levels
) -> StepInfo:
    """:func:`step_info` with interpolated crossings and parabola-refined extrema."""
    y0, y1, threshold, low, high = lv
    z = (y_arr - y0) / (y1 - y0)

    # Rise time: first crossings of the two rise levels.
    t_low = _first_crossing(t_arr, z, low)
    t_high = _first_crossing(t_arr, z, high)

    # Settling min / max: extrema of y from the upper rise crossing on.
    if math.isnan(t_high):
        settling_min = settling_max = math.nan
    else:
        settling_min = -_max_after(t_arr, -y_arr, t_high)
        settling_max = _max_after(t_arr, y_arr, t_high)

    # Overshoot / undershoot of the normalised response.
    _, z_max = _refined_max(t_arr, z, int(np.argmax(z)))
    _, neg_z_min = _refined_max(t_arr, -z, int(np.argmin(z)))

    # Peak of |y - y_init|, refined on the signed deviation to avoid the kink of abs().
    dev = y_arr - y0
    i_peak = int(np.argmax(np.abs(dev)))
    sign = 1.0 if dev[i_peak] >= 0.0 else -1.0
    peak_time, peak = _refined_max(t_arr, sign * dev, i_peak)

    return StepInfo(
        rise_time_s=t_high - t_low,
        # exit from the band after the last sample outside it
        settling_time_s=_settling_time(t_arr, z, threshold),
        settling_min=settling_min,
        settling_max=settling_max,
        overshoot_pct=100.0 * max(0.0, z_max - 1.0),
        undershoot_pct=100.0 * max(0.0, neg_z_min),
        peak=peak,
        peak_time_s=peak_time,
    )


def tracking_metrics(
    error: ArrayLike,
    *,
    period_s: float,
    steady_from: int | None = None,
) -> TrackingMetrics:
    """Summarise a tracking-error sequence sampled once per tick.

    Sample ``k`` is taken at ``k * period_s`` (tick time, ``k = 0 ... n-1``).

    Parameters
    ----------
    error : array_like, shape (n,)
        Tracking error ``e_k`` (e.g. reference - position, or the sync error) [counts].
    period_s : float
        Sampling period (the achieved tick period) [s], > 0.
    steady_from : int, optional
        Index of the first sample counted as steady state, ``0 <= steady_from < n``.
        Default ``(3 * n) // 4``: the last quarter of the samples (rounded up).

    Returns
    -------
    TrackingMetrics
        ``max_abs`` [counts]: ``max |e_k|``. ``rms`` [counts]: ``sqrt(mean(e_k**2))``.
        ``itae`` [counts*s^2]: ``sum(k*period_s * |e_k| * period_s)``. ``steady_lag``
        [counts]: ``mean(e_k)`` for ``k >= steady_from``.

    Raises
    ------
    ValueError
        If ``error`` is not a finite 1-D array of at least 3 samples, ``period_s`` is not
        finite and > 0, or ``steady_from`` is not an integer index into ``error``.

    Examples
    --------
    >>> m = tracking_metrics([0, 1, -2, 2], period_s=0.5)
    >>> m.max_abs, m.rms, m.itae, m.steady_lag
    (2.0, 1.5, 2.75, 2.0)
    """
    e = _as_finite_1d("error", error)
    n = e.size
    period = _finite_float("period_s", period_s)
    if not period > 0.0:
        raise ValueError(f"period_s must be > 0, got {period!r}")
    if steady_from is None:
        start = (3 * n) // 4
    else:
        if isinstance(steady_from, bool):
            raise ValueError(f"steady_from must be an integer index, got {steady_from!r}")
        try:
            start = operator.index(steady_from)
        except TypeError:
            raise ValueError(f"steady_from must be an integer index, got {steady_from!r}") from None
        if not 0 <= start < n:
            raise ValueError(
                f"steady_from must be in [0, {n - 1}] for {n} error samples, got {start}"
            )

    abs_e = np.abs(e)
    k = np.arange(n, dtype=float)
    return TrackingMetrics(
        max_abs=float(abs_e.max()),
        rms=float(np.sqrt(np.mean(e * e))),
        itae=float(np.sum(k * abs_e)) * period * period,
        steady_lag=float(np.mean(e[start:])),
    )


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------


def _coerce_float_fields(obj: object) -> None:
    """Convert every dataclass field of a frozen ``obj`` to a plain float, in place."""
    for f in fields(obj):  # type: ignore[arg-type]
        value = getattr(obj, f.name)
        try:
            as_float = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{f.name} must be a real number, got {value!r}") from None
        object.__setattr__(obj, f.name, as_float)


def _as_finite_1d(name: str, values: ArrayLike) -> NDArray[np.float64]:
    """Return ``values`` as a finite 1-D float array of at least 3 samples."""
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be an array of real numbers ({exc})") from None
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {arr.shape}")
    if arr.size < _MIN_SAMPLES:
        raise ValueError(f"{name} must have at least {_MIN_SAMPLES} samples, got {arr.size}")
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        i = int(bad[0])
        raise ValueError(
            f"{name} must be finite, got {float(arr[i])!r} at index {i} "
            f"({bad.size} non-finite value(s) in total)"
        )
    return arr


def _check_same_length(t: NDArray[np.float64], y: NDArray[np.float64]) -> None:
    if t.size != y.size:
        raise ValueError(f"t and y must have the same length, got len(t)={t.size}, len(y)={y.size}")


def _check_strictly_increasing(name: str, t: NDArray[np.float64]) -> None:
    bad = np.flatnonzero(np.diff(t) <= 0.0)
    if bad.size:
        i = int(bad[0]) + 1
        raise ValueError(
            f"{name} must be strictly increasing, first violation at index {i} "
            f"({name}[{i - 1}]={float(t[i - 1])!r}, {name}[{i}]={float(t[i])!r})"
        )


def _finite_float(name: str, value: object) -> float:
    try:
        result = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(result):
        raise ValueError(f"{name} must be finite, got {result!r}")
    return result


def _rise_limits(rise_limits: tuple[float, float]) -> tuple[float, float]:
    try:
        low, high = (float(v) for v in rise_limits)
    except (TypeError, ValueError):
        raise ValueError(
            f"rise_limits must be two numbers (low, high), got {rise_limits!r}"
        ) from None
    if not 0.0 <= low < high <= 1.0:
        raise ValueError(f"rise_limits must satisfy 0 <= low < high <= 1, got {rise_limits!r}")
    return low, high


def _crossing_time(t0: float, t1: float, v0: float, v1: float, level: float) -> float:
    """Time at which the straight line from (t0, v0) to (t1, v1) takes the value ``level``."""
    return float(t0 + (level - v0) / (v1 - v0) * (t1 - t0))


def _first_index(mask: NDArray[np.bool_]) -> int:
    """Index of the first True in ``mask``; -1 if there is none."""
    hits = np.flatnonzero(mask)
    return int(hits[0]) if hits.size else -1


def _first_crossing(t: NDArray[np.float64], z: NDArray[np.float64], level: float) -> float:
    """Interpolated time at which ``z`` first reaches ``level`` from below; NaN if never."""
    reached = np.flatnonzero(z >= level)
    if reached.size == 0:
        return math.nan
    i = int(reached[0])
    if i == 0:
        return float(t[0])
    return _crossing_time(t[i - 1], t[i], z[i - 1], z[i], level)


def _settling_time(t: NDArray[np.float64], z: NDArray[np.float64], threshold: float) -> float:
    """Time from ``t[0]`` after which ``|z - 1| <= threshold`` for good (interpolated exit)."""
    outside = np.flatnonzero(np.abs(z - 1.0) > threshold)
    if outside.size == 0:
        return 0.0
    j = int(outside[-1])
    if j == z.size - 1:
        return math.nan
    # z[j] is outside the band, z[j + 1] inside: the exit is through the edge on z[j]'s side.
    level = 1.0 + threshold if z[j] > 1.0 else 1.0 - threshold
    return _crossing_time(t[j], t[j + 1], z[j], z[j + 1], level) - float(t[0])


def _refined_max(t: NDArray[np.float64], v: NDArray[np.float64], i: int) -> tuple[float, float]:
    """Refine the maximum of ``v`` at sample ``i`` to the vertex of a parabola.

    The parabola passes through samples ``i - 1``, ``i`` and ``i + 1``. It is used only when
    ``i`` is an interior sample with ``v[i]`` not below either neighbour; its vertex then lies
    between the midpoints of the two intervals and is not below ``v[i]``. Otherwise the sample
    itself is returned. Returns ``(time, value)``.
    """
    if i <= 0 or i >= v.size - 1:
        return float(t[i]), float(v[i])
    t0, t1, t2 = (float(x) for x in t[i - 1 : i + 2])
    v0, v1, v2 = (float(x) for x in v[i - 1 : i + 2])
    if v1 < v0 or v1 < v2:
        return t1, v1
    # Newton form: p(s) = v0 + d01 (s - t0) + a (s - t0)(s - t1).
    d01 = (v1 - v0) / (t1 - t0)
    d12 = (v2 - v1) / (t2 - t1)
    a = (d12 - d01) / (t2 - t0)
    if not a < 0.0:  # three equal values: flat top, nothing to refine
        return t1, v1
    s = 0.5 * (t0 + t1) - d01 / (2.0 * a)
    s = min(max(s, t0), t2)  # guards rounding; the vertex lies in [t0, t2] by construction
    value = v0 + d01 * (s - t0) + a * (s - t0) * (s - t1)
    return s, max(value, v1)


def _max_after(t: NDArray[np.float64], v: NDArray[np.float64], t_start: float) -> float:
    """Maximum of the sampled signal ``v`` over ``t >= t_start``, interpolated and refined.

    Candidates are the linearly interpolated value at ``t_start`` and the largest sample after
    it, refined by :func:`_refined_max` when its vertex does not fall before ``t_start``.
    """
    best = float(np.interp(t_start, t, v))
    k = int(np.searchsorted(t, t_start, side="right"))
    if k < v.size:
        i = k + int(np.argmax(v[k:]))
        s, value = _refined_max(t, v, i)
        if s < t_start:
            value = float(v[i])
        best = max(best, value)
    return best
