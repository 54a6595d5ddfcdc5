"""Excitation files (docs/formats.md#excitation-file): what ``servotune excite`` writes and
``servotune simulate`` plays.

An excitation file is a log-format CSV with the columns ``tick,time_s,<axis>.dac_code``
(absolute D/A codes) and metadata saying how it was designed. :func:`write_excitation` writes
one with :func:`servotune.logs.format_log`; :func:`read_excitation` reads one with the log
reader (:func:`servotune.logs.read_table`) and checks it against the rig it is to be played on
(which is why it sits beside the rig, above :mod:`servotune.io`). The excitation itself is
designed in :mod:`servotune.excite`, which re-exports both.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Protocol

import numpy as np

from servotune._version import __version__
from servotune.errors import LogFormatError, SpecError
from servotune.io.files import MAX_NUMBER_CHARS, atomic_write_text
from servotune.io.log import format_log
from servotune.io.log_rows import INT_RE, to_float
from servotune.io.log_table import Table, read_table
from servotune.rig import Rig
from servotune.validate import show_value

__all__ = ["MIN_TICKS", "ExcitationLike", "read_excitation", "write_excitation"]


class ExcitationLike(Protocol):
    """What :func:`write_excitation` reads of an excitation
    (:class:`servotune.excite.Excitation` is one; named here by its shape, so that this
    file format does not import the module that designs excitations, which imports it)."""

    axis: str
    kind: str
    seed: int
    zero_code: int
    period_s: float
    amplitude_codes: int
    limited_by: str
    predicted_max_speed_rpm: float
    predicted_travel_counts: tuple[float, float]
    periods: int | None  # the rest: a periodic multisine's (None for any other excitation)
    period_ticks: int | None
    band_hz: tuple[float, float] | None
    phases: str | None
    crest_factor: float | None
    excited_lines: int | None
    detection_lines: int | None

    @property
    def absolute_codes(self) -> np.ndarray: ...

    def to_columns(self) -> dict[str, np.ndarray]: ...


MIN_TICKS = 10
"""Shortest excitation [ticks]."""

_PERIOD_RTOL = 1e-3  # a file's period may differ from the rig's by 0.1 % (docs/formats.md#sampling)


def _check_period(period_s: float, rig: Rig, where: str, error: type[Exception]) -> None:
    if not abs(period_s - rig.period_s) <= _PERIOD_RTOL * rig.period_s:
        raise error(
            f"{where} period {show_value(period_s)} s differs from rig "
            f"{show_value(rig.name)}'s achieved period "
            f"{show_value(rig.period_s)} s by more than 0.1 %"
        )


def write_excitation(path: str | Path, excitation: ExcitationLike, rig: Rig) -> None:
    """Write an excitation as a log-format CSV (atomic; same inputs give the same bytes).

    Metadata lines ``rig``, ``period_s`` (repr of the achieved period), ``axis``, ``kind``,
    ``seed``, ``amplitude_codes``, ``dac_bits``, ``dac_range_v``, the predictions and the
    servotune version; a periodic multisine's also ``periods``, ``period_ticks``, ``band_hz``,
    ``phases``, ``crest_factor``, ``excited_lines`` and ``detection_lines``. Columns
    ``tick,time_s,<axis>.dac_code`` with absolute D/A codes.

    Parameters
    ----------
    path : str or Path
        File to write.
    excitation : Excitation
        Any :class:`ExcitationLike`.
    rig : Rig
        The rig it was designed for.

    Raises
    ------
    SpecError
        If the excitation does not fit the rig (axis, period, 0 V code, code range).
    OSError
        If the file cannot be written.
    """

    rig.axis(excitation.axis)
    _check_period(excitation.period_s, rig, "the excitation's", SpecError)
    if excitation.zero_code != rig.dac.zero_code:
        raise SpecError(
            f"the excitation's zero_code {excitation.zero_code} is not rig "
            f"{show_value(rig.name)}'s "
            f"0 V code {rig.dac.zero_code}"
        )
    absolute = excitation.absolute_codes
    if absolute.min() < 0 or absolute.max() > rig.dac.code_max:
        raise SpecError(f"excitation codes leave the D/A range 0..{rig.dac.code_max}")
    lo, hi = rig.dac.range_v
    t_lo, t_hi = excitation.predicted_travel_counts
    meta = {
        "rig": rig.name,
        "period_s": repr(rig.period_s),
        "axis": excitation.axis,
        "kind": excitation.kind,
        "seed": excitation.seed,
        "amplitude_codes": excitation.amplitude_codes,
        "limited_by": excitation.limited_by,
        **_periodic_meta(excitation),
        "dac_bits": rig.dac.bits,
        "dac_range_v": f"{lo:g},{hi:g}",
        "predicted_max_speed_rpm": f"{excitation.predicted_max_speed_rpm:.6g}",
        "predicted_travel_counts": f"{t_lo:.6g},{t_hi:.6g}",
        "servotune_version": __version__,
    }
    atomic_write_text(
        path, format_log(period_s=rig.period_s, columns=excitation.to_columns(), metadata=meta)
    )


def _periodic_meta(excitation: ExcitationLike) -> dict[str, str]:
    """A periodic multisine's metadata (docs/formats.md#excitation-file); none for another."""
    if excitation.periods is None or excitation.band_hz is None:
        return {}
    f1, f2 = excitation.band_hz
    return {
        "periods": f"{excitation.periods}",
        "period_ticks": f"{excitation.period_ticks}",
        "band_hz": f"{f1:.6g},{f2:.6g}",
        "phases": f"{excitation.phases}",
        "crest_factor": f"{excitation.crest_factor:.6g}",
        "excited_lines": f"{excitation.excited_lines}",
        "detection_lines": f"{excitation.detection_lines}",
    }


def read_excitation(path: str | Path, rig: Rig) -> tuple[str, np.ndarray]:
    """Read and validate an excitation file for playing on ``rig``.

    The file is a log (docs/formats.md#log-file) with time columns (``tick`` and/or ``time_s``) and
    exactly one ``<axis>.dac_code`` column (``dac_code`` alone on a one-axis rig); nothing else.

    Parameters
    ----------
    path : str or Path
    rig : Rig

    Returns
    -------
    axis : str
        Axis the codes are for.
    codes : ndarray of int64
        Absolute D/A codes, one per tick.

    Raises
    ------
    LogFormatError
        Naming the first problem: missing or unreadable file, no header, no or more than one
        ``dac_code`` column, any other column, an axis not in the rig or not the metadata's,
        a row with the wrong number of fields, a code that is not an integer or outside
        ``0..code_max``, ticks that do not step by 1, irregular ``time_s``, a period (``time_s``
        or ``period_s`` metadata) more than 0.1 % off the rig's, D/A metadata that disagrees
        with the rig, fewer than 10 rows.
    """
    p = Path(path)
    src = str(p)
    what = "excitation file"

    def check_header(header: list[str], header_line: int) -> None:
        for h in header:
            if h not in ("tick", "time_s") and h.rpartition(".")[2] != "dac_code":
                raise LogFormatError(
                    f"unexpected column {show_value(h)} (line {header_line}); an excitation "
                    f"has only "
                    "tick, time_s and one <axis>.dac_code"
                )
        code_cols = [h for h in header if h.rpartition(".")[2] == "dac_code"]
        if not code_cols:
            raise LogFormatError(f"no <axis>.dac_code column in the header (line {header_line})")
        if len(code_cols) > 1:
            raise LogFormatError(
                f"more than one dac_code column ({', '.join(code_cols)}); an excitation drives "
                "one axis"
            )
        if "tick" not in header and "time_s" not in header:
            raise LogFormatError(
                f"the excitation needs a tick or time_s column (line {header_line})"
            )

    table = read_table(p, what=what, check_header=check_header)
    try:
        return _excitation_codes(table, rig)
    except LogFormatError as exc:
        raise LogFormatError(f"{what} {show_value(src)}: {exc}") from None


def _excitation_codes(table: Table, rig: Rig) -> tuple[str, np.ndarray]:
    """The axis and codes of a parsed excitation file, checked against the rig."""
    header, meta, rows = table.header, table.metadata, table.row_lines
    code_name = next(h for h in header if h.rpartition(".")[2] == "dac_code")
    axis = code_name.rpartition(".")[0]
    if not axis:
        if len(rig.axes) != 1:
            raise LogFormatError(
                f"column 'dac_code' has no axis prefix; rig {show_value(rig.name)} has axes "
                f"{list(rig.axis_names)}: name it <axis>.dac_code"
            )
        axis = rig.axes[0].name
    if axis not in rig.axis_names:
        raise LogFormatError(
            f"column {show_value(code_name)}: no axis {show_value(axis)} in rig "
            f"{show_value(rig.name)} "
            f"(axes: {list(rig.axis_names)})"
        )
    if "axis" in meta and meta["axis"] != axis:
        raise LogFormatError(
            f"metadata axis {meta['axis']!r} disagrees with column {show_value(code_name)}"
        )
    _check_dac_meta(meta, rig)
    if table.n_rows < MIN_TICKS:
        raise LogFormatError(f"{table.n_rows} rows; need at least {MIN_TICKS}")

    codes = table.columns[code_name]
    bad = (codes < 0) | (codes > rig.dac.code_max)
    if bad.any():
        r = int(np.argmax(bad))
        raise LogFormatError(
            f"row {rows[r]}, column {show_value(code_name)}: code {int(codes[r])} outside the "
            f"D/A range "
            f"0..{rig.dac.code_max}"
        )
    if "tick" in header:
        ticks = table.columns["tick"]
        jump = np.diff(ticks) != 1
        if jump.any():
            r = int(np.argmax(jump)) + 1
            raise LogFormatError(
                f"row {rows[r]}, column 'tick': {ticks[r]} after {ticks[r - 1]}; ticks must step "
                "by 1"
            )
    checked = False
    if "time_s" in header:
        t = table.columns["time_s"]
        dt = np.diff(t)
        med = float(np.median(dt))
        off = ~(np.abs(dt - med) <= _PERIOD_RTOL * abs(med))
        if not med > 0 or off.any():
            r = int(np.argmax(off)) + 1 if off.any() else 1
            raise LogFormatError(
                f"row {rows[r]}, column 'time_s': irregular or non-increasing time "
                f"(interval {float(dt[r - 1])!r} s vs median {show_value(med)} s)"
            )
        _check_period(med, rig, "the file's time_s", LogFormatError)
        checked = True
    if "period_s" in meta:
        p_meta = _meta_number(meta, "period_s")
        _check_period(p_meta, rig, "the file's metadata", LogFormatError)
        checked = True
    if not checked:
        raise LogFormatError(
            "the excitation has no time_s column and no period_s metadata; "
            "its period cannot be checked against the rig"
        )
    return axis, codes


def _meta_number(meta: dict[str, str], key: str) -> float:
    """A finite number from metadata (at most 64 characters), else a LogFormatError."""
    text = meta[key]
    v = to_float(text)  # a log field's number rule: at most 64 characters, no digit separators
    if v is None or not math.isfinite(v):
        raise LogFormatError(f"metadata {key} must be a finite number, got {show_value(text)}")
    return v


def _check_dac_meta(meta: dict[str, str], rig: Rig) -> None:
    if "dac_bits" in meta:
        text = meta["dac_bits"]
        if len(text) > MAX_NUMBER_CHARS or not INT_RE.fullmatch(text):
            raise LogFormatError(
                f"metadata dac_bits must be an integer [bits], got {show_value(text)}"
            )
        bits = int(text)
        if bits != rig.dac.bits:
            raise LogFormatError(
                f"metadata dac_bits {bits} disagrees with rig {show_value(rig.name)} "
                f"({rig.dac.bits} bits)"
            )
    if "dac_range_v" in meta:
        parts = meta["dac_range_v"].split(",")
        try:
            if len(parts) != 2:
                raise ValueError
            lo, hi = (_meta_number({"x": x.strip()}, "x") for x in parts)
        except (ValueError, LogFormatError):
            raise LogFormatError(
                f"metadata dac_range_v must be 'low,high' in volts, got "
                f"{show_value(meta['dac_range_v'])}"
            ) from None
        r_lo, r_hi = rig.dac.range_v
        if not (math.isclose(lo, r_lo, abs_tol=1e-9) and math.isclose(hi, r_hi, abs_tol=1e-9)):
            raise LogFormatError(
                f"metadata dac_range_v {lo:g},{hi:g} V disagrees with rig {show_value(rig.name)} "
                f"({r_lo:g},{r_hi:g} V)"
            )
