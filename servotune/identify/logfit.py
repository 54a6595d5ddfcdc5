"""A log file (a LinuxCNC HAL capture, or a CSV log mapped with ``--map``) read and one axis
identified: what ``servotune fit LOG`` runs.

Here rather than in :mod:`servotune.pipeline` so that the fit verb imports the identifier and
the log reader only (the pipeline imports every subsystem: seconds of a one-verb process).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from servotune.errors import IdentificationError, LogFormatError, SpecError
from servotune.identify.fitting import MIN_SAMPLES, fit
from servotune.identify.result import FitResult
from servotune.io.hal import HalSettings, capture_format, read_hal_log
from servotune.io.log import Log
from servotune.io.log_header import read_metadata
from servotune.logs import read_log
from servotune.resonance import MAX_MODES
from servotune.rig import Rig

if TYPE_CHECKING:
    from servotune.analysis.frf import Frf

__all__ = [
    "check_lines_for_modes",
    "check_modes_request",
    "fit_log",
    "fit_log_modes",
    "measure_for_modes",
    "read_fit_log",
]


def fit_log(
    log_path: str | Path,
    *,
    axis: str | None = None,
    rig: Rig | None = None,
    structure: str | None = None,
    counter_bits: int | None = None,
    dac_bits: int | None = None,
    dac_range_v: tuple[float, float] | None = None,
    period_s: float | None = None,
    compute_s: float | None = None,
    method: str = "auto",
    friction: str = "auto",
    invert_encoder: bool = False,
    need_axis_name: bool = False,
    strict: bool = False,
    hal: HalSettings | None = None,
    progress: Callable[[str], None] | None = None,
    modes: int | str | None = None,
) -> tuple[FitResult, Log, str]:
    """Read a log and identify one axis (what ``servotune fit`` runs).

    Settings come from the keyword options, then the log's metadata, then the rig
    (docs/formats.md#metadata).
    ``structure``, ``method``, ``friction`` and ``invert_encoder`` are
    :func:`servotune.identify.fit_arrays`'s. ``need_axis_name``: the caller will write the
    model under the axis's name (``fit -o``), so a log without axis prefixes and no ``axis``
    is refused before the fit runs. ``strict``: an unknown metadata key is an error
    (:func:`servotune.logs.read_log`).

    ``hal``: the file is read with these settings (:func:`servotune.io.hal.read_hal_log`): a
    LinuxCNC HAL capture (``halsampler`` output or halscope's saved data) or a CSV log with its
    own column names, told apart by their content (:func:`servotune.io.hal.capture_format`).
    ``period_s`` overrides the settings' period. For a capture the D/A settings and
    ``compute_s`` come from the options, else the rig (a capture has no metadata; the rig's
    period is not used: the capture's is LinuxCNC's servo thread's). For a CSV they come, with
    the period, as for a log: the options, else its ``# key: value`` lines, else the rig.
    Its one axis is unnamed (``axis`` names it). ``progress`` gets lines while a large
    capture is read.

    ``modes`` (``"auto"`` or a number; ``fit --modes``): the plant's lightly damped modes too,
    fitted to the log's frequency response (:func:`fit_log_modes`); None or 0: the rigid
    model alone, as without it.

    Returns
    -------
    result : FitResult
    log : Log
    axis : str
        The axis name (for an unprefixed log: ``axis`` if given, else ``""``).

    Raises
    ------
    LogFormatError
        If the log cannot be read (:func:`servotune.logs.read_log`,
        :func:`servotune.io.hal.read_hal_log`), a HAL capture has fewer than
        :data:`~servotune.identify.MIN_SAMPLES` samples or ``counter_bits`` is given for one
        (it has no counter register column), or ``need_axis_name`` and nothing names its axis.
    IdentificationError
        If the data do not identify the model; the message names the log.
    SpecError
        With ``modes``: as :func:`fit_log_modes`.
    """
    check_modes_request(modes)
    if hal is not None:
        result, log, name = _fit_hal_log(
            log_path,
            hal,
            axis=axis,
            rig=rig,
            counter_bits=counter_bits,
            dac_bits=dac_bits,
            dac_range_v=dac_range_v,
            period_s=period_s,
            compute_s=compute_s,
            need_axis_name=need_axis_name,
            strict=strict,
            progress=progress,
            fit_options={
                "structure": structure,
                "method": method,
                "friction": friction,
                "invert_encoder": invert_encoder,
            },
            modes=modes,
        )
        return result, log, name
    log, compute_s = read_fit_log(
        log_path,
        rig=rig,
        counter_bits=counter_bits,
        dac_bits=dac_bits,
        dac_range_v=dac_range_v,
        period_s=period_s,
        compute_s=compute_s,
        strict=strict,
    )
    log_axis = None if list(log.axes) == [""] else axis
    if need_axis_name and axis is None and list(log.axes) == [""]:
        raise LogFormatError(
            f"log {str(log_path)!r} has no axis prefix in its column names: give the axis's "
            "name (--axis NAME), under which its model is written"
        )
    measured = measure_for_modes(log, log_axis, modes)  # before the fit: a bad log fails early
    try:
        result = fit(
            log,
            axis=log_axis,
            structure=structure,
            compute_s=compute_s,
            method=method,
            friction=friction,
            invert_encoder=invert_encoder,
        )
    except IdentificationError as exc:  # the data do not allow it: name the log
        raise IdentificationError(f"log {str(log_path)!r}: {exc}") from None
    name = axis if axis is not None else (log_axis or next(iter(log.axes)))
    return fit_log_modes(result, log, log_axis, modes, measured=measured), log, name


def check_modes_request(modes: object) -> None:
    """Refuse a ``modes`` request other than None, ``"auto"`` or a whole number in
    0 … :data:`~servotune.resonance.MAX_MODES` (a plant carries at most that many).

    Raises
    ------
    SpecError
        ``"modes must be auto or a number of modes in 0..4, got 7"``.
    """
    if modes is None or modes == "auto":
        return
    if not (type(modes) is int and 0 <= modes <= MAX_MODES):
        raise SpecError(
            f"modes must be auto or a number of modes in 0..{MAX_MODES} (a plant carries at "
            f"most {MAX_MODES}), got {modes!r}"
        )


def measure_for_modes(log: Log, axis: str | None, modes: int | str | None) -> Frf | None:
    """The frequency response :func:`fit_log_modes` fits the modes to: the velocity response
    of ``log``'s ``axis`` (:func:`servotune.analysis.frf.frf`, the first excitation period
    skipped as the loop's transient); None when ``modes`` asks for none.

    Raises
    ------
    LogFormatError, SpecError
        As :func:`fit_log_modes`.
    """
    check_modes_request(modes)
    if modes is None or modes == 0:
        return None
    from servotune.analysis.frf import frf  # here: only --modes needs the frequency domain

    measured = frf(log, axis)
    check_lines_for_modes(measured, modes)
    return measured


def check_lines_for_modes(measured: Frf, modes: int | str) -> None:
    """Refuse a measured response with too few lines for ``modes``
    (:func:`servotune.identify.modes.lines_needed`), saying what the excitation gave.

    Raises
    ------
    SpecError
        ``"the log's excitation cannot measure modes: its response has 5 lines (1 … 9 Hz,
        median coherence 0.012), 6 needed …"``.
    """
    from servotune.identify.modes import lines_needed  # here: only --modes needs it

    lines = measured.freq_hz[~np.asarray(measured.aliased, dtype=bool)]
    need = lines_needed(modes)
    if lines.size >= need:
        return
    span = f"{lines.min():.3g} … {lines.max():.3g} Hz, " if lines.size else ""
    raise SpecError(
        f"the log's excitation cannot measure modes: its response has {lines.size} lines not "
        f"flagged aliased ({span}median coherence {float(np.median(measured.coherence)):.2g}), "
        f"{need} needed for {'choosing the order' if modes == 'auto' else f'{modes} modes'}; "
        "log a periodic multisine over the band the modes may lie in (servotune excite --kind "
        "multisine --periods P --band F1:F2)"
    )


def fit_log_modes(
    result: FitResult,
    log: Log,
    axis: str | None,
    modes: int | str | None,
    *,
    measured: Frf | None = None,
) -> FitResult:
    """``result`` (the time-domain fit of ``log``'s ``axis``) with the plant's lightly damped
    modes (``servotune fit --modes``; docs/frf.md#modes).

    The log must carry a periodic excitation (its ``exc_code``, as ``servotune frf`` needs):
    its velocity response is measured (:func:`measure_for_modes`; ``measured``: already
    measured so) and the rigid plant and ``modes`` modes are fitted to it
    (:func:`servotune.identify.modes.fit_modes`; ``"auto"``: 0 … 3 chosen by the held-out
    error), started from ``result``'s rigid plant, with ``result``'s compute time. The modes,
    with their 95 % intervals, become :attr:`FitResult.mode_fit`, so :attr:`FitResult.plant`
    carries them (``fit -o`` writes them into the rig file). When at least one mode is found,
    the plant written is :attr:`FitResult.written`: gain, tau and delay from the
    frequency-domain fit, offset and friction re-estimated with them and the modes fixed
    (:func:`servotune.identify.resonant.written_plant`); with none, the time-domain fit's, as
    without ``modes``. An encoder fitted inverted (``--invert-encoder``) is inverted here too.

    Parameters
    ----------
    result : FitResult
    log : Log
    axis : str or None
        The axis of ``log`` (None: its one unnamed axis).
    modes : "auto", int or None
        How many modes; None or 0: ``result`` as it is (no frequency response is needed).

    Raises
    ------
    LogFormatError
        The log has no ``exc_code`` column for the axis (the messages of ``servotune frf``).
    SpecError
        A bad ``modes``; the excitation is constant or not periodic, fewer than two periods
        after the first; too few lines for the modes asked for.
    """
    check_modes_request(modes)
    if modes is None or modes == 0:
        return result
    if measured is None:
        measured = measure_for_modes(log, axis, modes)
    from servotune.identify.modes import fit_modes  # here: only --modes needs it

    if result.inverted_encoder:  # the position the time-domain fit saw: the negated one
        measured = dataclasses.replace(measured, response=-measured.response)
    fitted = fit_modes(measured, n_modes=modes, rigid=result.plant, compute_s=result.compute_s)
    if not fitted.modes:
        return dataclasses.replace(result, mode_fit=fitted)
    from servotune.identify.resonant import written_plant

    ax = log.axis(axis)
    pos = -ax.pos_counts.astype(np.int64) if result.inverted_encoder else ax.pos_counts
    exc = [] if ax.exc_code is None else [("exc_code", ax.exc_code * log.dac_lsb_v)]
    written = written_plant(result, fitted, ax.cmd_v, pos, signals=exc)
    return dataclasses.replace(result, mode_fit=fitted, written=written)


def read_fit_log(
    log_path: str | Path,
    *,
    hal: HalSettings | None = None,
    rig: Rig | None = None,
    counter_bits: int | None = None,
    dac_bits: int | None = None,
    dac_range_v: tuple[float, float] | None = None,
    period_s: float | None = None,
    compute_s: float | None = None,
    strict: bool = False,
    progress: Callable[[str], None] | None = None,
) -> tuple[Log, float | None]:
    """A log file read as ``servotune fit`` reads it, and the compute time that applies.

    A servotune log (:func:`servotune.logs.read_log`), or with ``hal`` a LinuxCNC HAL capture
    or a CSV log with its own column names (:func:`servotune.io.hal.read_hal_log`). Each setting
    comes from the keyword options, then the log's metadata, then the rig (a capture has no
    metadata, and its period is LinuxCNC's servo thread's, not the rig's) — as
    :func:`fit_log` describes.

    Raises
    ------
    LogFormatError
        The log cannot be read, or ``counter_bits`` is given for a mapped file.
    """
    if hal is not None:
        return _read_hal(
            log_path,
            hal,
            rig=rig,
            counter_bits=counter_bits,
            dac_bits=dac_bits,
            dac_range_v=dac_range_v,
            period_s=period_s,
            compute_s=compute_s,
            strict=strict,
            progress=progress,
        )
    if rig is not None:
        counter_bits, dac_bits, dac_range_v, period_s, compute_s = _from_rig(
            rig,
            read_metadata(log_path),
            counter_bits=counter_bits,
            dac_bits=dac_bits,
            dac_range_v=dac_range_v,
            period_s=period_s,
            compute_s=compute_s,
        ).values()
    log = read_log(
        log_path,
        counter_bits=counter_bits,
        dac_bits=dac_bits,
        dac_range_v=dac_range_v,
        period_s=period_s,
        compute_s=compute_s,  # validated with the other options (finite, >= 0, < period)
        strict=strict,
    )
    return log, compute_s


def _read_hal(
    log_path: str | Path,
    hal: HalSettings,
    *,
    rig: Rig | None,
    counter_bits: int | None,
    dac_bits: int | None,
    dac_range_v: tuple[float, float] | None,
    period_s: float | None,
    compute_s: float | None,
    strict: bool,
    progress: Callable[[str], None] | None,
) -> tuple[Log, float | None]:
    """:func:`read_fit_log` of a HAL capture or a mapped CSV log."""
    src = str(log_path)
    csv = hal.format is None and capture_format(log_path) == "csv"
    noun = "log" if csv else "HAL capture"
    if counter_bits is not None:
        raise LogFormatError(
            f"{noun} {src!r}: counter_bits (--counter-bits) is for a log's raw counter "
            f"column; a mapped position is pos ({'counts, or ' if csv else ''}machine units) "
            "or counts, taken as they are (unwrapped)"
        )
    if rig is not None:
        meta = read_metadata(log_path) if csv else {}  # a CSV's own lines come first
        dac_bits, dac_range_v, compute_s = _from_rig(
            rig, meta, dac_bits=dac_bits, dac_range_v=dac_range_v, compute_s=compute_s
        ).values()
        if csv and hal.period_s is None:  # as for a log: checked against its time column
            (period_s,) = _from_rig(rig, meta, period_s=period_s).values()
    log = read_hal_log(
        log_path,
        hal,
        period_s=period_s,
        dac_bits=dac_bits,
        dac_range_v=dac_range_v,
        compute_s=compute_s,
        strict=strict,
        progress=progress,
    )
    return log, compute_s


def _from_rig(rig: Rig, meta: dict[str, Any], **given: Any) -> dict[str, Any]:
    """Each setting in ``given`` as given, else (when the log's metadata ``meta`` does not
    state it) the rig's, in the order given."""
    rig_values = {
        "counter_bits": rig.counter.bits,
        "dac_bits": rig.dac.bits,
        "dac_range_v": rig.dac.range_v,
        "period_s": rig.period_s,
        "compute_s": rig.timer.compute_s,
    }
    return {k: v if v is not None or k in meta else rig_values[k] for k, v in given.items()}


def _fit_hal_log(
    log_path: str | Path,
    hal: HalSettings,
    *,
    axis: str | None,
    rig: Rig | None,
    counter_bits: int | None,
    dac_bits: int | None,
    dac_range_v: tuple[float, float] | None,
    period_s: float | None,
    compute_s: float | None,
    need_axis_name: bool,
    strict: bool,
    fit_options: dict,
    progress: Callable[[str], None] | None = None,
    modes: int | str | None = None,
) -> tuple[FitResult, Log, str]:
    """:func:`fit_log` of a HAL capture or a mapped CSV log."""
    src = str(log_path)
    csv = hal.format is None and capture_format(log_path) == "csv"
    noun = "log" if csv else "HAL capture"
    log, compute_s = read_fit_log(
        log_path,
        hal=hal,
        rig=rig,
        counter_bits=counter_bits,
        dac_bits=dac_bits,
        dac_range_v=dac_range_v,
        period_s=period_s,
        compute_s=compute_s,
        strict=strict,
        progress=progress,
    )
    if log.n_samples < MIN_SAMPLES:
        longer = "log longer" if csv else "capture longer: halsampler -n N, or halscope's "
        longer += "" if csv else "record length"
        raise LogFormatError(
            f"{noun} {src!r} has {log.n_samples} samples; a fit needs at least "
            f"{MIN_SAMPLES} ({longer})"
        )
    if need_axis_name and axis is None:
        raise LogFormatError(
            f"{noun} {src!r} does not name its axis: give the axis's name (--axis NAME), "
            "under which its model is written"
        )
    measured = measure_for_modes(log, None, modes)
    try:
        result = fit(log, axis=None, compute_s=compute_s, **fit_options)
    except IdentificationError as exc:  # the data do not allow it: name the capture
        raise IdentificationError(f"{noun} {src!r}: {exc}") from None
    return fit_log_modes(result, log, None, modes, measured=measured), log, axis or ""
