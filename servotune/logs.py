"""Log files (SPEC §5): what ``servotune simulate`` writes and ``servotune fit`` reads.

All log parsing and writing lives here. A log is CSV: optional ``# key: value`` metadata lines,
one header row, then one row per tick. Time is ``time_s`` and/or ``tick``; per axis, columns
prefixed ``<axis>.``: the command (``dac_code`` or ``cmd_v``), the position (``counter`` raw
register or ``pos_counts`` unwrapped) and optionally ``ref_counts`` and ``mode``
(``lock`` / ``task`` / ``open``). Writes are atomic (temp file, then rename).
"""

from __future__ import annotations

import csv
import io
import math
import os
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from servotune.errors import LogFormatError
from servotune.hw import counter as hw_counter
from servotune.hw import dac as hw_dac
from servotune.laws.axis import MODE_NAMES

__all__ = ["AxisLog", "Log", "atomic_write_text", "format_log", "read_log", "write_log"]

_AXIS_COLUMNS = ("dac_code", "cmd_v", "counter", "pos_counts", "ref_counts", "mode")


@dataclass(frozen=True, slots=True, kw_only=True)
class AxisLog:
    """One axis's columns, converted to physical units.

    Attributes
    ----------
    cmd_v : ndarray
        D/A output [V] (from ``dac_code`` through the D/A, or ``cmd_v`` as it is).
    pos_counts : ndarray of int64
        Unwrapped position [counts] (``counter`` unwrapped with the runtime's high-byte rule,
        or ``pos_counts`` as it is).
    dac_code, counter : ndarray or None
        Raw columns when the log has them.
    ref_counts : ndarray or None
    mode : ndarray of int8 or None
        ``MODE_*`` values.
    counter_faults : ndarray of int64
        Rows where the unwrap flagged a counter fault (empty when none).
    """

    cmd_v: np.ndarray
    pos_counts: np.ndarray
    dac_code: np.ndarray | None = None
    counter: np.ndarray | None = None
    ref_counts: np.ndarray | None = None
    mode: np.ndarray | None = None
    counter_faults: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


@dataclass(frozen=True, slots=True, kw_only=True)
class Log:
    """A parsed log.

    Attributes
    ----------
    period_s : float
        Sample period [s] (from the time column, metadata or the rig).
    axes : dict of str to AxisLog
        Per axis (``""`` for an unprefixed single-axis log).
    metadata : dict of str to str
    """

    period_s: float
    axes: dict[str, AxisLog]
    metadata: dict[str, str]

    @property
    def n_samples(self) -> int:
        """Number of rows."""
        return int(next(iter(self.axes.values())).cmd_v.shape[0])

    def axis(self, name: str | None = None) -> AxisLog:
        """One axis; ``name`` may be omitted when the log has one axis.

        Raises
        ------
        LogFormatError
            If the axis is not in the log or the choice is ambiguous.
        """
        if name is None:
            if len(self.axes) != 1:
                raise LogFormatError(
                    f"the log has axes {sorted(self.axes)}; choose one (--axis NAME)"
                )
            return next(iter(self.axes.values()))
        if name not in self.axes:
            raise LogFormatError(f"no axis {name!r} in the log; axes: {sorted(self.axes)}")
        return self.axes[name]


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temp file in the same directory and a rename.

    Raises
    ------
    OSError
        If the directory does not exist or is not writable (nothing is left behind).
    """
    p = Path(path)
    d = p.parent if str(p.parent) else Path(".")
    if not d.is_dir():
        raise FileNotFoundError(f"directory {str(d)!r} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=d)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
        os.replace(tmp, p)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def format_log(
    *,
    period_s: float,
    columns: Mapping[str, np.ndarray],
    metadata: Mapping[str, str | float | int],
) -> str:
    """Render a log as text (deterministic: fixed float formats, metadata in given order).

    Parameters
    ----------
    period_s : float
        Sample period [s]; the ``tick`` and ``time_s`` columns are written from it.
    columns : mapping of str to ndarray
        Column name → values, in output order. Integer arrays are written as integers; float
        arrays with 9 significant decimals; ``*.mode`` arrays as mode names.
    metadata : mapping
        ``# key: value`` lines.
    """
    n = len(next(iter(columns.values())))
    out = io.StringIO()
    for k, v in metadata.items():
        out.write(f"# {k}: {v}\n")
    names = ["tick", "time_s", *columns]
    out.write(",".join(names) + "\n")
    ticks = np.arange(n, dtype=np.int64)
    cols: list[list[str]] = [[str(t) for t in ticks.tolist()]]
    cols.append([f"{t:.9f}" for t in (ticks * period_s).tolist()])
    for name, arr in columns.items():
        a = np.asarray(arr)
        if name.endswith("mode"):
            cols.append([MODE_NAMES[int(m)] for m in a.tolist()])
        elif np.issubdtype(a.dtype, np.integer):
            cols.append([str(x) for x in a.tolist()])
        else:
            cols.append([f"{x:.9g}" for x in a.tolist()])
    for row in zip(*cols, strict=True):
        out.write(",".join(row) + "\n")
    return out.getvalue()


def write_log(path: str | Path, **kwargs: object) -> None:
    """Format (:func:`format_log`) and write a log atomically."""
    atomic_write_text(path, format_log(**kwargs))  # type: ignore[arg-type]


# --- reading -------------------------------------------------------------------------------


def _float_meta(meta: Mapping[str, str], key: str) -> float | None:
    if key not in meta:
        return None
    try:
        return float(meta[key])
    except ValueError:
        raise LogFormatError(f"metadata {key!r} must be a number, got {meta[key]!r}") from None


def read_log(
    path: str | Path,
    *,
    counter_bits: int | None = None,
    dac_bits: int | None = None,
    dac_range_v: tuple[float, float] | None = None,
    period_s: float | None = None,
) -> Log:
    """Read and validate a log file.

    Options take precedence over the log's metadata (SPEC §5); pass the rig's values as the
    options when a rig is known.

    Parameters
    ----------
    path : str or Path
    counter_bits : int, optional
        Register width to unwrap ``counter`` columns (else metadata ``counter_bits``, else 24).
    dac_bits, dac_range_v : optional
        D/A to convert ``dac_code`` (else metadata, else 12 bits, ±10 V).
    period_s : float, optional
        Sample period when the log has no ``time_s`` (else metadata ``period_s``).

    Returns
    -------
    Log

    Raises
    ------
    LogFormatError
        Naming the first problem: missing file, no header, unknown or duplicate column,
        non-numeric or non-finite value, non-uniform or non-increasing time, counter out of
        range, too few rows.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise LogFormatError(f"cannot read log {str(p)!r}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise LogFormatError(f"log {str(p)!r} is not UTF-8 text") from None
    meta: dict[str, str] = {}
    lines = text.splitlines()
    i = 0
    while i < len(lines) and (lines[i].startswith("#") or not lines[i].strip()):
        line = lines[i][1:].strip() if lines[i].startswith("#") else ""
        if ":" in line:
            k, v = line.split(":", 1)
            meta[k.strip()] = v.strip()
        i += 1
    if i >= len(lines):
        raise LogFormatError(f"log {str(p)!r} is empty (no header row)")
    header_row = i + 1
    rows = list(csv.reader(lines[i:]))
    header = [h.strip() for h in rows[0]]
    body = [r for r in rows[1:] if r and any(c.strip() for c in r)]
    if len(set(header)) != len(header):
        dup = next(h for h in header if header.count(h) > 1)
        raise LogFormatError(f"duplicate column {dup!r} in the header (line {header_row})")
    if not body:
        raise LogFormatError(f"log {str(p)!r} has a header but no data rows")
    if len(body) < 3:
        raise LogFormatError(f"log {str(p)!r} has only {len(body)} rows; need at least 3")
    axes_cols: dict[str, dict[str, int]] = {}
    time_cols: dict[str, int] = {}
    for j, h in enumerate(header):
        if h in ("time_s", "tick"):
            time_cols[h] = j
            continue
        ax, _, col = h.rpartition(".")
        if col not in _AXIS_COLUMNS:
            raise LogFormatError(
                f"unknown column {h!r}; expected time_s, tick and [axis.]"
                f"{{{','.join(_AXIS_COLUMNS)}}}"
            )
        axes_cols.setdefault(ax, {})[col] = j
    if not time_cols:
        raise LogFormatError("the log needs a time_s or tick column")
    if not axes_cols:
        raise LogFormatError("the log has no axis columns (dac_code/cmd_v and counter/pos_counts)")
    n_cols = len(header)
    for r_i, r in enumerate(body):
        if len(r) != n_cols:
            raise LogFormatError(
                f"row {header_row + 1 + r_i} has {len(r)} fields, the header has {n_cols}"
            )

    def column(j: int, name: str, integer: bool) -> np.ndarray:
        vals = []
        for r_i, r in enumerate(body):
            s = r[j].strip()
            try:
                x = float(s) if not integer else _parse_int(s)
            except ValueError:
                kind = "an integer" if integer else "a number"
                raise LogFormatError(
                    f"column {name!r} row {header_row + 1 + r_i}: {s!r} is not {kind}"
                ) from None
            if not integer and not math.isfinite(x):
                raise LogFormatError(
                    f"column {name!r} row {header_row + 1 + r_i}: value {s!r} is not finite"
                )
            vals.append(x)
        return np.asarray(vals, dtype=np.int64 if integer else float)

    period = _period(time_cols, column, header, meta, period_s, header_row)
    bits = counter_bits or int(_float_meta(meta, "counter_bits") or 24)
    d_bits = dac_bits or int(_float_meta(meta, "dac_bits") or 12)
    if dac_range_v is None and "dac_range_v" in meta:
        try:
            lo, hi = (float(x) for x in meta["dac_range_v"].split(","))
        except ValueError:
            raise LogFormatError(
                f"metadata dac_range_v must be 'low,high', got {meta['dac_range_v']!r}"
            ) from None
        dac_range_v = (lo, hi)
    d_range = dac_range_v or (-10.0, 10.0)
    axes: dict[str, AxisLog] = {}
    for ax, cols in axes_cols.items():
        label = f"{ax}." if ax else ""
        who = repr(ax) if ax else "(unprefixed)"
        if ("dac_code" in cols) == ("cmd_v" in cols):
            raise LogFormatError(f"axis {who} needs exactly one of {label}dac_code, {label}cmd_v")
        if ("counter" in cols) == ("pos_counts" in cols):
            raise LogFormatError(
                f"axis {who} needs exactly one of {label}counter, {label}pos_counts"
            )
        dac_code = counter = None
        if "dac_code" in cols:
            dac_code = column(cols["dac_code"], f"{label}dac_code", True)
            bad = (dac_code < 0) | (dac_code > 2**d_bits - 1)
            if bad.any():
                k = int(np.argmax(bad))
                raise LogFormatError(
                    f"column {label}dac_code row {header_row + 1 + k}: code {int(dac_code[k])} "
                    f"outside 0..{2**d_bits - 1}"
                )
            cmd_v = hw_dac.volts_from_code(dac_code, d_bits, d_range)
        else:
            cmd_v = column(cols["cmd_v"], f"{label}cmd_v", False)
        faults = np.zeros(0, dtype=np.int64)
        if "counter" in cols:
            counter = column(cols["counter"], f"{label}counter", True)
            bad = (counter < 0) | (counter > 2**bits - 1)
            if bad.any():
                k = int(np.argmax(bad))
                raise LogFormatError(
                    f"column {label}counter row {header_row + 1 + k}: value {int(counter[k])} "
                    f"outside the {bits}-bit register 0..{2**bits - 1}"
                )
            pos, fault = hw_counter.unwrap(counter, bits)
            pos = pos - pos[0]
            faults = np.flatnonzero(fault)
        else:
            pos = column(cols["pos_counts"], f"{label}pos_counts", True)
        ref = (
            column(cols["ref_counts"], f"{label}ref_counts", True) if "ref_counts" in cols else None
        )
        mode = None
        if "mode" in cols:
            names = [r[cols["mode"]].strip() for r in body]
            bad_m = [m for m in names if m not in MODE_NAMES]
            if bad_m:
                raise LogFormatError(
                    f"column {label}mode: {bad_m[0]!r} is not one of {', '.join(MODE_NAMES)}"
                )
            mode = np.asarray([MODE_NAMES.index(m) for m in names], dtype=np.int8)
        axes[ax] = AxisLog(
            cmd_v=cmd_v,
            pos_counts=pos,
            dac_code=dac_code,
            counter=counter,
            ref_counts=ref,
            mode=mode,
            counter_faults=faults,
        )
    return Log(period_s=period, axes=axes, metadata=meta)


def _parse_int(s: str) -> int:
    if s.lstrip("+-").isdigit():
        return int(s)
    raise ValueError(s)


def _period(time_cols, column, header, meta, period_s, header_row) -> float:
    if "time_s" in time_cols:
        t = column(time_cols["time_s"], "time_s", False)
        dt = np.diff(t)
        bad = dt <= 0
        if bad.any():
            k = int(np.argmax(bad))
            raise LogFormatError(
                f"time_s is not increasing at row {header_row + 2 + k} ({t[k]!r} then {t[k + 1]!r})"
            )
        med = float(np.median(dt))
        off = np.abs(dt - med) > 1e-3 * med
        if off.any():
            k = int(np.argmax(off))
            raise LogFormatError(
                f"irregular sampling at row {header_row + 2 + k}: interval {dt[k]!r} s vs median "
                f"{med!r} s (more than 0.1 %); a dropped sample is not interpolated"
            )
        return period_s or _float_meta(meta, "period_s") or med
    ticks = column(time_cols["tick"], "tick", True)
    dk = np.diff(ticks)
    if np.any(dk != 1):
        k = int(np.argmax(dk != 1))
        raise LogFormatError(f"tick column jumps at row {header_row + 2 + k} (must step by 1)")
    p = period_s or _float_meta(meta, "period_s")
    if p is None or not p > 0:
        raise LogFormatError("the log has no time_s column and no period_s (metadata or option)")
    return p
