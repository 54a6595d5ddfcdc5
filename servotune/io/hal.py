"""LinuxCNC HAL captures (``halsampler`` output, halscope's saved data) and CSV logs with
their own column names, read into a log through a mapping.

LinuxCNC users log a servo loop in one of two ways, and servotune reads both (one reader per
format, :func:`read_halsampler` and :func:`read_halscope`, each into a :class:`HalCapture`):

``halsampler`` (the realtime ``sampler`` component and the ``halsampler`` user program)
    One line per sample, the values separated by single spaces, a trailing space, no header.
    Float pins print with ``%f`` (6 decimals), s32/u32 pins as integers, bits as 0/1. With
    ``halsampler -t`` the first field is the sample number (0, 1, 2, …). The columns are the
    sampler's ``cfg`` order (``sampler.0.pin.0``, ``.pin.1``, …): the file does not name them,
    nor does it carry the sample period.
halscope "save data" (``write_log_file`` in LinuxCNC's ``scope_files.c``)
    Line 1 ``# Sampling period is <ns> ns``; line 2 the channels' names (pins, signals or
    parameters) separated by ``;``; then the comment lines ``# Position: …`` and
    ``# Scale: …`` (the display settings); then one line per sample, the values printed with
    ``%.14f`` (bits and integers too) and separated by ``;``.

Lost samples
------------
A sample lost between the realtime ``sampler`` and ``halsampler`` (the FIFO full) would be a
silent jump in time, so every witness of one is refused, naming the first: a gap in the ``-t``
sample numbers, the line ``overrun`` that ``halsampler`` prints at a gap, and a change in the
sampler's own ``sampler.N.overruns`` pin recorded as a column (mapping key ``overruns``). On
LinuxCNC 2.9 only the last one sees a loss: its sampler drops the record of a full FIFO
without advancing the stream's sample number, so the ``-t`` numbers stay consecutive and no
``overrun`` line is printed (checked with halsampler 2.9 and a FIFO left to fill:
``tests/io/test_hal_logs.py``). Record ``sampler.0.overruns`` (an ``s`` pin in ``cfg``) to
be sure.

A :class:`HalSettings` (:mod:`servotune.io.hal_map`, re-exported here) says which column is
what (the mapping: servotune's ``cmd`` or ``code``, ``pos`` or ``counts``, optionally ``ref``,
``exc`` and ``overruns``, each a pin name or a 0-based column number) and gives LinuxCNC's
scales; :meth:`HalCapture.to_log` converts the mapped columns to servotune's units and builds
the :class:`servotune.logs.Log` that :func:`servotune.fit` takes, as
:meth:`servotune.io.emps.EmpsLog.to_log` does for the EMPS files. :func:`read_hal_log` does
both steps; :func:`hal_settings` (also :mod:`servotune.io.hal_map`'s) builds the settings from
``servotune fit``'s options.

Units (LinuxCNC's terms → servotune's)
---------------------------------------
============  ==============================  ============================================
mapping key   the HAL pin holds               servotune gets
============  ==============================  ============================================
``cmd``       the drive command in pid        ``cmd_v = cmd / output_scale`` [V]
              output units (``pid.0.output``)
``code``      a D/A code (s32), offset binary ``dac_code`` [codes] → volts through the D/A
              0 … 2^bits − 1 (the log's)      (``dac_bits``, ``dac_range_v``)
``pos``       position in machine units       ``pos_counts = rint(pos · position_scale)``
              (``encoder.0.position``)        [counts]
``counts``    raw encoder counts              ``pos_counts`` as they are [counts]
              (``encoder.0.counts``)
``ref``       commanded position in machine   ``ref_counts = rint(ref · position_scale)``
              units (``pid.0.command``)       [counts]
``exc``       the excitation added to the     ``exc_code`` [D/A codes, relative to the zero
              command, in the command's       code]: ``rint(exc / output_scale / LSB)``
              units (pid output units, or     for ``cmd``, as it is for ``code``
              codes)
``overruns``  ``sampler.N.overruns``          nothing: a change between two rows is refused
                                              (samples lost there)
============  ==============================  ============================================

``position_scale`` and ``output_scale`` are the settings' scales (:mod:`servotune.io.hal_map`):
the encoder's ``position-scale`` [counts per machine unit] and the pid output units per volt at
the D/A [units/V].

CSV logs with their own column names
------------------------------------
A machine's own logger writes CSV with its own column names (``t,drive_volts,encoder,…``).
The same mapping reads it (:func:`read_mapped_csv`): each key names a column of the header
(or its 0-based number), the keys and their units are the table's, with two differences and
two additions. Without ``position_scale``, ``pos`` and ``ref`` are in counts (with it, in
machine units as above); counts (``pos``, ``counts``, ``ref``, and ``code``, ``overruns``)
may be written as numbers (``0.0``) but must be whole within 1e-9, as the log reader's
``pos_counts`` and ``ref_counts``. A position in counts is taken as it is: unwrapped (a raw
counter register that wraps is a log's ``counter`` column, read without ``--map``). ``time``
maps the time column [s] and ``tick`` the sample number; columns named ``time_s`` or ``tick``
are the time base without being mapped; the other columns the mapping does not name are
ignored. The rest is the log format's: ``# key: value`` metadata (``period_s``, ``dac_bits``,
``dac_range_v``, ``compute_s``, kept as the log's metadata), the period from the option, else
``# period_s:``, else the time column, all checked as a log's.

Which reader a file needs is read from its content (:func:`capture_format`): halscope's
first line, halsampler's rows of numbers, or a CSV's header naming its columns.
"""

from __future__ import annotations

import difflib
import re
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict, Unpack

import numpy as np

from servotune.errors import LogFormatError
from servotune.hw import dac as hw_dac
from servotune.io.capture_rows import NUMBER_RE, check_rows, stream_rows
from servotune.io.hal_map import (
    HAL_FORMATS,
    MAP_KEYS,
    HalSettings,
    check_own_columns,
    hal_settings,
    parse_hal_map,
    read_hal_map,
    show_target,
)
from servotune.io.log_header import (
    PERIOD_RANGE_S,
    meta_setting,
    naming,
    option_value,
    parse_compute,
    parse_counter_bits,
    parse_dac_bits,
    parse_period,
    parse_range,
)
from servotune.io.log_rows import REL_TOL, RowLines, not_whole, timebase, whole_problem
from servotune.logs import MIN_ROWS, AxisLog, Log, read_table, warn_unknown_metadata
from servotune.validate import show_value

__all__ = [
    "CMD_LOG_DAC_BITS",
    "CMD_LOG_DAC_RANGE_V",
    "HAL_FORMATS",
    "MAP_KEYS",
    "HalCapture",
    "HalLogOptions",
    "HalPrecisionWarning",
    "HalSettings",
    "capture_format",
    "hal_settings",
    "parse_hal_map",
    "read_hal_capture",
    "read_hal_log",
    "read_hal_map",
    "read_halsampler",
    "read_halscope",
    "read_mapped_csv",
]

CMD_LOG_DAC_BITS = 16
"""D/A resolution the log states when the command is mapped in volts (``cmd``) and no D/A is
given: it sets only the step in which an ``exc`` column is held (0.3 mV)."""
CMD_LOG_DAC_RANGE_V = (-10.0, 10.0)
"""D/A range [V] stated with :data:`CMD_LOG_DAC_BITS`."""
HALSCOPE_PERIOD_LINE = "# Sampling period is"
"""How halscope's saved data begin (what the format detection looks for)."""

_HALSCOPE_PERIOD_RE = re.compile(r"# Sampling period is (-?\d+) ns\s*")
_PRINTED_DECIMALS = 6  # halsampler prints float pins with %f
_MAX_COUNTS = 2.0**53  # beyond this a float position is no longer whole counts
_SHOW_NAMES = 8  # column names listed in a message
_SHOW_CSV_NAMES = 24  # a CSV header's names listed in a message
_DETECT_BYTES = 1 << 16  # how much of a file capture_format looks at
_MORE_DEPTH = "load sampler with a deeper FIFO, depth=…, or record fewer pins"


class HalPrecisionWarning(UserWarning):
    """A capture's printed resolution is coarser than the quantity it carries (halsampler's
    6 decimals of a position in large machine units, coarser than one encoder count)."""


# --- the captures ----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class HalCapture:
    """A HAL capture as its file holds it: numbered columns of numbers, names where known.

    Attributes
    ----------
    format : str
        ``"halsampler"``, ``"halscope"`` or ``"csv"`` (a CSV log with its own column names,
        :func:`read_mapped_csv`).
    values : ndarray of float, shape (n, m)
        The samples, one row per line, one column per pin (the sample number not included),
        in the units HAL printed them. A CSV's columns the mapping does not read are NaN.
    names : tuple of str or None
        The columns' pin (signal, parameter) names: halscope's header, or the ``columns``
        given for a halsampler capture, or a CSV's header; None when nothing names them.
    lines : ndarray of int64
        The 1-based file line of each row (for the messages).
    sample_numbers : ndarray of int64 or None
        halsampler ``-t``'s sample numbers (consecutive: a gap is refused on reading).
    period_s : float or None
        The sample period [s] from halscope's header (halsampler records none), or a CSV's
        (its time column, ``# period_s:`` line or the period given when it was read).
    path : str
        Where it was read from.
    metadata : dict of str to str
        A CSV's ``# key: value`` lines (kept as the log's metadata).
    log_settings : dict
        The D/A (``dac_bits``, ``dac_range_v``) and ``compute_s`` a CSV's metadata states:
        used where :meth:`to_log` is given none.
    """

    format: str
    values: np.ndarray
    names: tuple[str, ...] | None = None
    lines: np.ndarray
    sample_numbers: np.ndarray | None = None
    period_s: float | None = None
    path: str = ""
    metadata: dict[str, str] = field(default_factory=dict)
    log_settings: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.values.ndim != 2 or self.lines.shape != (self.values.shape[0],):
            raise LogFormatError(
                f"values must be (n, m) with one line number per row, got {self.values.shape} "
                f"and {self.lines.shape}"
            )
        if self.names is not None and len(self.names) != self.values.shape[1]:
            raise LogFormatError(f"{len(self.names)} names for {self.values.shape[1]} columns")

    @property
    def n_samples(self) -> int:
        """Number of samples (rows)."""
        return int(self.values.shape[0])

    @property
    def n_columns(self) -> int:
        """Number of value columns (the sample number not counted)."""
        return int(self.values.shape[1])

    @property
    def _noun(self) -> str:
        return "log" if self.format == "csv" else "HAL capture"

    def _label(self, j: int) -> str:
        if self.format == "csv" and self.names is not None:
            return f"column {self.names[j]!r}"
        return f"column {j} ({self.names[j]})" if self.names is not None else f"column {j}"

    def _refuse_first(self, bad: np.ndarray, j: int, problem: Callable[[int], str]) -> None:
        """Raise for the first row ``k`` that is ``bad``, naming its line and column ``j``:
        ``problem(k)`` says what is wrong there (a CSV's line is a ``row``, as the log reader
        says)."""
        if bad.any():
            k = int(np.argmax(bad))
            where = "row" if self.format == "csv" else "line"
            raise LogFormatError(f"{where} {self.lines[k]}, {self._label(j)}: {problem(k)}")

    def column_index(self, target: str | int, key: str = "") -> int:
        """The 0-based column of a pin name or column number.

        Raises
        ------
        LogFormatError
            A column number out of range, a name when nothing names the columns, a name not
            among them (with the closest one), a name on two columns.
        """
        return _find_column(self.names, self.n_columns, target, key, self.format)

    def to_log(
        self,
        settings: HalSettings,
        *,
        period_s: float | None = None,
        dac_bits: int | None = None,
        dac_range_v: tuple[float, float] | None = None,
        compute_s: float | None = None,
    ) -> Log:
        """The mapped columns in servotune's units, as a one-axis :class:`~servotune.logs.Log`.

        The axis is unnamed (``""``, as in a log without axis prefixes). Conversions: module
        docstring.

        Parameters
        ----------
        settings : HalSettings
            The mapping and scales.
        period_s : float, optional
            Sample period [s], overriding ``settings.period_s``. halsampler needs one of the
            two; for halscope the header's is used, and a given one must agree with it (within
            its 1 ns resolution).
        dac_bits : int, optional
            D/A resolution; with ``dac_range_v`` required when ``code`` is mapped. Default for
            ``cmd``: :data:`CMD_LOG_DAC_BITS`.
        dac_range_v : (float, float), optional
            D/A range [V]; default for ``cmd``: :data:`CMD_LOG_DAC_RANGE_V`.
        compute_s : float, optional
            Sample → D/A write time [s] (docs/runtime.md#one-tick), >= 0 and below the period.

        Returns
        -------
        Log
            The capture as a servotune log (docs/formats.md#columns).

        Raises
        ------
        LogFormatError
            One line naming the file and, where it applies, the mapping key, the pin or
            column and the line: a pin or column that is not there, no period (halsampler),
            a period that disagrees with halscope's header, no ``position_scale`` where
            ``pos`` or ``ref`` needs it, no D/A where ``code`` needs it, a code outside the
            D/A's range, counts or codes that are not whole numbers, a position beyond the
            float's whole-count range, an excitation beyond the D/A's span, a change in the
            ``overruns`` column (lost samples).

        Warns
        -----
        HalPrecisionWarning
            halsampler's 6 decimals of ``pos`` are coarser than one count.
        """
        try:
            return self._to_log(settings, period_s, dac_bits, dac_range_v, compute_s)
        except LogFormatError as exc:
            if self.path and repr(self.path) in str(exc):
                raise
            raise LogFormatError(f"{self._noun} {self.path!r}: {exc}") from None

    def _to_log(
        self,
        settings: HalSettings,
        period_s: float | None,
        dac_bits: int | None,
        dac_range_v: tuple[float, float] | None,
        compute_s: float | None,
    ) -> Log:
        if settings.format is not None and settings.format != self.format:
            raise LogFormatError(
                f"the settings are for a {settings.format} capture, the file is {self.format}"
            )
        m = settings.mapping
        if self.format != "csv" and ("time" in m or "tick" in m):
            key = "time" if "time" in m else "tick"
            raise LogFormatError(
                f"map {key} names a CSV log's time column; a {self.format} capture has none "
                "(its period: --period-s, period_s under [hal], or halscope's header)"
            )
        period = self._period(settings, period_s)
        if compute_s is None:
            compute_s = self.log_settings.get("compute_s")  # a CSV's '# compute_s:' line
        else:
            compute_s = option_value("compute_s", compute_s, parse_compute)
        if compute_s is not None:
            if compute_s >= period:
                raise LogFormatError(
                    f"compute_s must be shorter than the sample period {period:.6g} s [s], "
                    f"got {compute_s!r}"
                )
        cols = {key: self.column_index(target, key) for key, target in m.items()}
        check_own_columns(cols, self._label)
        if "overruns" in m:
            self._check_overruns(cols["overruns"])
        if dac_bits is not None:
            dac_bits = option_value("dac_bits", dac_bits, parse_dac_bits)
        else:
            dac_bits = self.log_settings.get("dac_bits")  # a CSV's '# dac_bits:' line
        if dac_range_v is not None:
            dac_range_v = option_value("dac_range_v", dac_range_v, parse_range)
        else:
            dac_range_v = self.log_settings.get("dac_range_v")
        if "code" in m:
            if dac_bits is None or dac_range_v is None:
                raise LogFormatError(
                    f"map code ({show_target(m['code'])}) is a D/A code: give the D/A's "
                    "resolution and range (--dac-bits 16 --dac-range-v=-10,10, or --rig)"
                )
        else:
            dac_bits = CMD_LOG_DAC_BITS if dac_bits is None else dac_bits
            dac_range_v = CMD_LOG_DAC_RANGE_V if dac_range_v is None else dac_range_v
        assert dac_bits is not None and dac_range_v is not None
        lsb = hw_dac.lsb_v(dac_bits, dac_range_v)
        top = (1 << dac_bits) - 1
        scale = settings.position_scale
        for key in ("pos", "ref"):
            if key in m and scale is None and self.format != "csv":  # a CSV's: counts
                raise LogFormatError(
                    f"map {key} ({show_target(m[key])}) is in machine units: give the "
                    "encoder's position-scale [counts per machine unit] (--position-scale, or "
                    "position_scale under [hal])"
                )
        dac_code = ref = exc = None
        if "code" in m:
            dac_code = self._whole("code", cols["code"])
            self._refuse_first(
                (dac_code < 0) | (dac_code > top),
                cols["code"],
                lambda k: (
                    f"code {dac_code[k]} is outside the {dac_bits}-bit D/A range 0..{top} "
                    "(map code takes the D/A's offset-binary code, 0 V at mid-scale; map a command "
                    "in volts with cmd)"
                ),
            )
            cmd_v = hw_dac.volts_from_code(dac_code, dac_bits, dac_range_v)
        else:
            cmd_v = self.values[:, cols["cmd"]] / settings.output_scale
        if "pos" in m and scale is None:
            pos = self._whole("pos", cols["pos"])  # a CSV's position in counts
        elif "pos" in m:
            assert scale is not None
            pos = self._counts("pos", cols["pos"], scale)
            if self.format == "halsampler" and scale * 10.0**-_PRINTED_DECIMALS > 1.0:
                warnings.warn(
                    f"HAL capture {self.path!r}: halsampler prints {self._label(cols['pos'])} "
                    f"with {_PRINTED_DECIMALS} decimals, a step of "
                    f"{scale * 10.0**-_PRINTED_DECIMALS:.3g} counts at position_scale {scale:g}: "
                    "coarser than the encoder (log its counts pin, map counts=…)",
                    HalPrecisionWarning,
                    stacklevel=3,
                )
        else:
            pos = self._whole("counts", cols["counts"])
        if "ref" in m:
            j = cols["ref"]
            ref = self._whole("ref", j) if scale is None else self._counts("ref", j, scale)
        if "exc" in m:
            j = cols["exc"]
            if "code" in m:
                exc = self._whole("exc", j)
            else:
                exc = np.rint(self.values[:, j] / settings.output_scale / lsb)
            self._refuse_first(
                np.abs(exc) > top,
                j,
                lambda k: (
                    f"the excitation is {exc[k]:.0f} D/A codes, beyond the {dac_bits}-bit "
                    f"D/A's span (at most ±{top})"
                ),
            )
            exc = exc.astype(np.int64)
        axis = AxisLog(
            cmd_v=np.ascontiguousarray(cmd_v, dtype=float),
            pos_counts=pos,
            dac_code=dac_code,
            ref_counts=ref,
            exc_code=exc,
            name="",
        )
        meta = {"kind": f"LinuxCNC {self.format} capture", "period_s": f"{period!r}"}
        if self.format == "csv":
            meta = dict(self.metadata)  # as the log reader keeps them
        return Log(
            period_s=period,
            axes={"": axis},
            metadata=meta,
            dac_bits=dac_bits,
            dac_range_v=dac_range_v,
            compute_s=compute_s,
            path=self.path,
        )

    def _period(self, settings: HalSettings, period_s: float | None) -> float:
        given, source = settings.period_s, "the map's period_s"
        if period_s is not None:
            given, source = option_value("period_s", period_s, parse_period), "--period-s"
        if self.format == "csv" and self.period_s is not None:
            # chosen when the CSV was read (read_mapped_csv), from this same period if given
            if given is not None and abs(given - self.period_s) > REL_TOL * self.period_s:
                raise LogFormatError(
                    f"{source} {given:.9g} s disagrees with the period the log was read with, "
                    f"{self.period_s:.9g} s (its time column or '# period_s:' line)"
                )
            return self.period_s
        if self.period_s is None:
            if given is None:
                raise LogFormatError(
                    f"a {self.format} capture does not record its sample period: give it "
                    "(--period-s 0.001, or period_s under [hal]: the period of the thread "
                    "sampler runs in)"
                )
            return float(given)
        if given is not None and abs(given - self.period_s) > 0.5e-9:
            raise LogFormatError(
                f"{source} {given:.9g} s disagrees with the halscope header's sampling period "
                f"{self.period_s:.9g} s (line 1)"
            )
        return self.period_s

    def _check_overruns(self, j: int) -> None:
        """Refuse the capture if the sampler's overrun count (column ``j``) changes."""
        o = self._whole("overruns", j)
        step = np.flatnonzero(np.diff(o))
        if step.size:
            k = int(step[0])
            lost = int(o[k + 1] - o[k])
            raise LogFormatError(
                f"lost samples: {self._label(j)}, the sampler's overrun count, goes from {o[k]} "
                f"(line {self.lines[k]}) to {o[k + 1]} (line {self.lines[k + 1]}): {lost} "
                f"sample{'s' if abs(lost) != 1 else ''} lost between them ({_MORE_DEPTH})"
            )

    def _whole(self, key: str, j: int) -> np.ndarray:
        """Column ``j`` as int64, refusing values that are not whole numbers (a CSV's: within
        :data:`~servotune.io.log_rows.WHOLE_TOL`, as the log reader's counts columns)."""
        a = self.values[:, j]
        if self.format == "csv":
            units = {
                "pos": " (in counts; in machine units give --position-scale)",
                "ref": " (in counts; in machine units give --position-scale)",
            }
            self._refuse_first(
                not_whole(a),
                j,
                lambda k: f"map {key}{units.get(key, '')}: {whole_problem(float(a[k]))}",
            )
            return np.rint(a).astype(np.int64)
        self._refuse_first(
            (a != np.rint(a)) | (np.abs(a) > _MAX_COUNTS),
            j,
            lambda k: f"map {key} needs whole numbers (an s32 pin), got {float(a[k])!r}",
        )
        return a.astype(np.int64)

    def _counts(self, key: str, j: int, scale: float) -> np.ndarray:
        """Column ``j`` in machine units as whole counts (``rint(x · scale)``)."""
        c = np.rint(self.values[:, j] * scale)
        self._refuse_first(
            np.abs(c) > _MAX_COUNTS,
            j,
            lambda k: (
                f"map {key} {float(self.values[k, j])!r} machine units is {c[k]:.4g} "
                f"counts at position_scale {scale:g}, beyond whole-count resolution (check "
                "position_scale)"
            ),
        )
        return c.astype(np.int64)


# --- reading the files -----------------------------------------------------------------------


def read_halsampler(
    path: str | Path,
    *,
    columns: Sequence[str] | None = None,
    sample_number: bool = False,
    progress: Callable[[str], None] | None = None,
) -> HalCapture:
    """Read ``halsampler`` output (module docstring), a chunk of lines at a time: memory is
    the capture's array and a chunk, not the text (the estimate is checked against the memory
    budget before reading: :func:`~servotune.io.capture_rows.check_capture_memory`).

    Parameters
    ----------
    path : str or Path
        The file (halsampler's stdout, redirected).
    columns : sequence of str, optional
        The sampler's pin names in its ``cfg`` order; the rows must have that many values.
    sample_number : bool
        The file was written with ``halsampler -t``: the first field is the sample number
        (not a column); the numbers must run on by one.
    progress : callable, optional
        Gets a line at each tenth of a large file read.

    Returns
    -------
    HalCapture
        ``period_s`` None (halsampler does not record it).

    Raises
    ------
    LogFormatError
        One line naming the file and the line: unreadable, not text, empty, a row with another
        number of fields than the first (or than ``columns`` names), a field that is not a
        number, a value that is not finite, a sample number that is not a whole number, a gap
        in the sample numbers or halsampler's ``overrun`` line (lost samples: the first one
        named), fewer than :data:`~servotune.logs.MIN_ROWS` samples.
    BudgetError
        The capture's arrays would not fit in the memory budget (nothing read).
    """
    src = str(path)
    with naming(src, "HAL capture"):
        names = None if columns is None else tuple(columns)
        lead = 1 if sample_number else 0

        def label(j: int) -> str:
            if j < lead:
                return "field 1 (the sample number)"
            c = j - lead
            known = names is not None and c < len(names)
            return f"column {c} ({names[c]})" if known else f"column {c}"  # type: ignore[index]

        def each(line0: int, lines: list[str]) -> int:
            if line0 == 0:
                _no_comment(lines, line0)
            if any(ln.strip() == "overrun" for ln in lines):  # halsampler's mark of a gap
                k = next(i for i, ln in enumerate(lines) if ln.strip() == "overrun")
                raise LogFormatError(
                    f"lost samples: line {line0 + k + 1} is halsampler's 'overrun' mark (the "
                    f"sampler's FIFO was full; {_MORE_DEPTH})"
                )
            return 0

        values, rows = stream_rows(Path(path), src, None, "halsampler", label, each, progress)
        if values.shape[0] < MIN_ROWS:
            n = values.shape[0]
            raise LogFormatError(
                f"{n} sample{'s' if n != 1 else ''}; at least {MIN_ROWS} are needed"
            )
        width = values.shape[1]
        expect = None if names is None else len(names) + lead
        if expect is not None and width != expect:
            hint = ""
            if not sample_number and width == len(names) + 1:  # type: ignore[arg-type]
                hint = " (written with halsampler -t? give --sample-number)"
            elif sample_number and width == len(names):  # type: ignore[arg-type]
                hint = " (not written with -t? drop --sample-number)"
            raise LogFormatError(
                f"line {rows[0]} has {width} fields; the {len(names)} columns named "  # type: ignore[arg-type]
                f"({', '.join(names[:_SHOW_NAMES])}){' and the sample number' if lead else ''} "  # type: ignore[index]
                f"need {expect}{hint}"
            )
        if width <= lead:
            raise LogFormatError(f"line {rows[0]} has only the sample number: no pin values")
        numbers = None
        if sample_number:
            numbers = _sample_numbers(values[:, 0], rows)
            values = values[:, 1:]
        check_rows(values, rows, names)
        return HalCapture(
            format="halsampler",
            values=np.ascontiguousarray(values),
            names=names,
            lines=rows,
            sample_numbers=numbers,
            path=src,
        )


def _halscope_head(lines: list[str]) -> tuple[float, tuple[str, ...], int]:
    """The sampling period [s], the channels' names and the index of the first data line, from
    the first lines of a halscope file."""
    if not any(ln.strip() for ln in lines):
        raise LogFormatError("the file is empty (no samples)")
    head = _HALSCOPE_PERIOD_RE.fullmatch(lines[0])
    if head is None:
        raise LogFormatError(
            f"line 1 is {show_value(lines[0])}, not halscope's '{HALSCOPE_PERIOD_LINE} N ns'"
        )
    ns = int(head.group(1))
    period_s = ns / 1e9
    lo, hi = PERIOD_RANGE_S
    if not lo <= period_s <= hi:
        raise LogFormatError(f"line 1: the sampling period {ns} ns is outside {lo:g} … {hi:g} s")
    if len(lines) < 2 or not lines[1].strip():
        raise LogFormatError("line 2 should name the channels (pins separated by ';')")
    if lines[1].lstrip().startswith("#"):
        raise LogFormatError(
            f"line 2 is a comment, not the channels' names: {show_value(lines[1])}"
        )
    names = tuple(n.strip() for n in lines[1].split(";"))
    if any(not n or len(n.split()) != 1 for n in names):
        raise LogFormatError(
            f"line 2: channel names separated by ';' must be non-empty pin names, got "
            f"{show_value(lines[1], 80)}"
        )
    start = 2
    while start < len(lines) and lines[start].lstrip().startswith("#"):
        start += 1  # '# Position: …', '# Scale: …' (display settings)
    return period_s, names, start


def _no_comment(lines: list[str], line0: int) -> None:
    """halsampler writes only numbers: a first non-blank line that is a comment is refused
    (halscope's saved data, which starts with one, named as such)."""
    first = next((i for i, ln in enumerate(lines) if ln.strip()), None)
    if first is not None and lines[first].lstrip().startswith("#"):
        hint = (
            " (halscope's saved data: --hal-format halscope)"
            if lines[first].startswith(HALSCOPE_PERIOD_LINE)
            else ""
        )
        raise LogFormatError(
            f"line {line0 + first + 1} is a comment; halsampler writes only numbers{hint}"
        )


def read_halscope(path: str | Path, *, progress: Callable[[str], None] | None = None) -> HalCapture:
    """Read halscope's saved data (module docstring; LinuxCNC ``scope_files.c``), a chunk of
    lines at a time as :func:`read_halsampler` reads (``progress`` likewise).

    Returns
    -------
    HalCapture
        ``names`` from line 2, ``period_s`` from line 1.

    Raises
    ------
    LogFormatError
        One line naming the file and the line: unreadable, not text, empty, line 1 not
        ``# Sampling period is N ns`` with N > 0, no channel names (or an empty one), a row
        with another number of fields than there are channels, a field that is not a number,
        a value that is not finite, fewer than :data:`~servotune.logs.MIN_ROWS` samples.
    """
    src = str(path)
    with naming(src, "HAL capture"):
        head: dict[str, Any] = {}

        def each(line0: int, lines: list[str]) -> int:
            if line0 == 0:
                head["period_s"], head["names"], start = _halscope_head(lines)
                return start
            return 0

        def label(j: int) -> str:
            names = head["names"]
            return f"column {j} ({names[j]})" if j < len(names) else f"field {j + 1}"

        values, rows = stream_rows(
            Path(path), src, ";", "halscope", label, each, progress, empty="the file is empty"
        )
        names, period_s = head["names"], head["period_s"]
        if values.shape[0] < MIN_ROWS:
            n = values.shape[0]
            raise LogFormatError(
                f"{n} sample{'s' if n != 1 else ''}; at least {MIN_ROWS} are needed"
            )
        if values.shape[1] != len(names):
            raise LogFormatError(
                f"line {rows[0]} has {values.shape[1]} fields; line 2 names {len(names)} "
                f"channels ({', '.join(names[:_SHOW_NAMES])})"
            )
        check_rows(values, rows, names)
        return HalCapture(
            format="halscope", values=values, names=names, lines=rows, period_s=period_s, path=src
        )


def read_mapped_csv(
    path: str | Path,
    mapping: Mapping[str, str | int],
    *,
    period_s: float | None = None,
    strict: bool = False,
) -> HalCapture:
    """Read a CSV log whose header names its columns in its own words, for ``mapping``.

    The file is read by the log reader (:func:`servotune.logs.read_table`: metadata lines,
    header, rows, every check and message of a log) with the mapped columns as numbers (a
    mapped ``tick`` as whole numbers) and the others read but not kept: a column the mapping
    does not name may hold anything. The time base is checked as a log's
    (:func:`servotune.io.log_rows.timebase`): the column mapped as ``time`` [s] (else one
    named ``time_s``) and the one mapped as ``tick`` (else one named ``tick``); the period is
    ``period_s`` if given (checked against the time column within 0.1 %), else the
    ``# period_s:`` line, else the time column's. The ``# dac_bits:``, ``# dac_range_v:`` and
    ``# compute_s:`` lines are kept as :attr:`HalCapture.log_settings`, the metadata as
    :attr:`HalCapture.metadata`. :meth:`HalCapture.to_log` then converts the mapped columns
    as a HAL capture's (module docstring), except that without a ``position_scale`` ``pos``
    and ``ref`` are in counts.

    Parameters
    ----------
    path : str or Path
    mapping : mapping of str to str or int
        :data:`MAP_KEYS` → a column name of the header, or a 0-based column number.
    period_s : float, optional
        Sample period [s].
    strict : bool
        An unknown metadata key is an error (else a
        :class:`~servotune.logs.LogMetadataWarning`).

    Returns
    -------
    HalCapture
        ``format`` ``"csv"``, ``names`` the header, ``period_s`` the period.

    Raises
    ------
    LogFormatError
        One line naming the file: anything the log reader refuses, a mapped column that is not
        in the header (the header's columns listed, the closest named), a time column that
        does not increase regularly, no time column and no period, a period outside
        :data:`~servotune.logs.PERIOD_RANGE_S`.
    """
    src = str(path)
    times: dict[str, int] = {}  # "time", "tick" → the column

    def kinds(header: list[str], line: int) -> list[str]:
        names = tuple(header)
        found = {
            key: _find_column(names, len(names), target, key, "csv", line)
            for key, target in mapping.items()
        }
        out = ["skip"] * len(header)
        for key, j in found.items():
            out[j] = "counts" if key == "tick" else "float"
        for key, name in (("time", "time_s"), ("tick", "tick")):
            if key in found:
                times[key] = found[key]
            elif name in header and out[header.index(name)] == "skip":
                times[key] = header.index(name)
                out[times[key]] = "counts" if key == "tick" else "float"
        return out

    table = read_table(path, what="log", kinds=kinds)
    with naming(src):
        header, cols = table.header, table.columns
        rows = RowLines(None, table.header_line + 1, table.row_lines)
        meta, meta_line = table.metadata, table.metadata_lines
        if table.n_rows < MIN_ROWS:
            raise LogFormatError(
                f"{table.n_rows} data row{'' if table.n_rows == 1 else 's'}; at least "
                f"{MIN_ROWS} are needed"
            )
        settings: dict[str, Any] = {}
        parsers = {
            "counter_bits": parse_counter_bits,
            "dac_bits": parse_dac_bits,
            "dac_range_v": parse_range,
            "compute_s": parse_compute,
        }
        for key, parse in parsers.items():
            value = meta_setting(key, meta, meta_line, parse)  # checked even if not used
            if value is not None and key != "counter_bits":
                settings[key] = value
        meta_period = meta_setting("period_s", meta, meta_line, parse_period)
        if period_s is not None:
            period_s = option_value("period_s", period_s, parse_period)
        warn_unknown_metadata(meta, meta_line, src, strict)
        tick = cols[header[times["tick"]]] if "tick" in times else None
        time_s = cols[header[times["time"]]] if "time" in times else None
        if tick is None and time_s is None and period_s is None and meta_period is None:
            raise LogFormatError(
                "no time column and no period: map the time column (time=COLUMN, in seconds, "
                "or tick=COLUMN), add a '# period_s: <seconds>' line or give --period-s"
            )
        period = timebase(
            tick,
            time_s,
            rows,
            meta_period=meta_period,
            meta_source=f"metadata 'period_s' (line {meta_line.get('period_s')})",
            opt_period=period_s,
            names=(header[times.get("tick", 0)], header[times.get("time", 0)]),
        )
        lo, hi = PERIOD_RANGE_S
        if not lo <= period <= hi:
            raise LogFormatError(
                f"the sample period from the time column, {period:.6g} s, is outside "
                f"{lo:g} … {hi:g} s (is the time column in seconds?)"
            )
        values = np.full((table.n_rows, len(header)), np.nan)
        for j, h in enumerate(header):
            if h in cols:
                values[:, j] = cols[h]
    return HalCapture(
        format="csv",
        values=values,
        names=tuple(header),
        lines=table.row_lines,
        period_s=float(period),
        path=src,
        metadata=dict(meta),
        log_settings=settings,
    )


def _find_column(
    names: tuple[str, ...] | None,
    n_columns: int,
    target: str | int,
    key: str = "",
    format: str = "halsampler",
    header_line: int | None = None,
) -> int:
    """The 0-based column of a pin (a CSV's column) name or column number
    (:meth:`HalCapture.column_index`)."""
    who = f"map {key}: " if key else ""
    csv = format == "csv"
    if isinstance(target, int):
        if not 0 <= target < n_columns:
            what = "log" if csv else "capture"
            raise LogFormatError(
                f"{who}column {target} is out of range: the {what} has {n_columns} "
                f"{'' if csv else 'value '}column{'s' if n_columns != 1 else ''} "
                f"(0..{n_columns - 1})"
            )
        return target
    if names is None:
        raise LogFormatError(
            f"{who}pin {target!r}: a halsampler capture does not name its columns; give "
            "the sampler's pin order (--hal-columns pid.0.output,encoder.0.position, or "
            "columns = [...] under [hal]) or map by column number (pos=1)"
        )
    hits = [j for j, n in enumerate(names) if n == target]
    if not hits:
        show = _SHOW_CSV_NAMES if csv else _SHOW_NAMES
        listed = ", ".join(names[:show])
        more = f" and {len(names) - show} more" if len(names) > show else ""
        near = difflib.get_close_matches(target, names, n=1)
        hint = f"; did you mean {near[0]!r}?" if near else ""
        if csv:
            line = f" (line {header_line})" if header_line is not None else ""
            raise LogFormatError(
                f"{who}column {target!r} is not in the log's header{line}, whose columns are "
                f"{listed}{more}{hint}"
            )
        raise LogFormatError(
            f"{who}pin {target!r} is not in the capture's columns: {listed}{more}{hint}"
        )
    if len(hits) > 1:
        raise LogFormatError(
            f"{who}pin {target!r} is in {len(hits)} columns ({', '.join(map(str, hits))}): "
            "map it by column number"
        )
    return hits[0]


def capture_format(path: str | Path) -> str:
    """What a file mapped with ``--map`` is, from its content: ``"halscope"`` (it begins with
    ``# Sampling period is``), ``"csv"`` (its first line that is not blank is a ``#`` line,
    as a CSV log's metadata, or holds a comma, or is not all numbers: a header naming the
    columns) or ``"halsampler"`` (numbers separated by spaces; also an unreadable or empty
    file, whose reader then names the problem)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(_DETECT_BYTES)
    except OSError:
        return "halsampler"
    text = head.decode("utf-8", errors="replace").lstrip("\ufeff")
    if text.startswith(HALSCOPE_PERIOD_LINE):
        return "halscope"
    for line in text.splitlines():
        line = line.strip()
        if not line:
            continue
        if line.startswith("#") or "," in line:
            return "csv"
        if line == "overrun":  # halsampler's mark of lost samples: its reader names it
            return "halsampler"
        numbers = all(
            NUMBER_RE.fullmatch(t) or t.lower().lstrip("+-") in ("nan", "inf") for t in line.split()
        )
        return "halsampler" if numbers else "csv"
    return "halsampler"


def read_hal_capture(
    path: str | Path,
    *,
    format: str | None = None,
    columns: Sequence[str] | None = None,
    sample_number: bool = False,
    mapping: Mapping[str, str | int] | None = None,
    period_s: float | None = None,
    strict: bool = False,
    progress: Callable[[str], None] | None = None,
) -> HalCapture:
    """Read a HAL capture in either format, or a CSV log with its own column names; ``format``
    None detects which from the content (:func:`capture_format`).

    ``mapping``, ``period_s`` and ``strict`` are for a CSV (:func:`read_mapped_csv`): the
    mapping says which columns to read, the period (if given) is checked against its time
    column, ``strict`` refuses unknown metadata keys. ``progress``: lines while a large
    halsampler or halscope capture is read (:func:`read_halsampler`)."""
    if format is None:
        format = capture_format(path)
    if format == "csv":
        if columns is not None or sample_number:
            what = "columns (--hal-columns)" if columns is not None else "--sample-number"
            raise LogFormatError(
                f"log {str(path)!r} is a CSV log whose header names its columns: {what} is for "
                "halsampler captures"
            )
        if mapping is None:
            raise LogFormatError(
                f"log {str(path)!r} is a CSV log: give the mapping of its columns (--map)"
            )
        return read_mapped_csv(path, mapping, period_s=period_s, strict=strict)
    if format == "halscope":
        if columns is not None or sample_number:
            what = "columns (--hal-columns)" if columns is not None else "--sample-number"
            raise LogFormatError(
                f"HAL capture {str(path)!r} is halscope's saved data, which names its channels "
                f"(line 2) and has no sample numbers: {what} is for halsampler captures"
            )
        return read_halscope(path, progress=progress)
    if format != "halsampler":
        raise LogFormatError(f"format must be one of {', '.join(HAL_FORMATS)}, got {format!r}")
    return read_halsampler(path, columns=columns, sample_number=sample_number, progress=progress)


class HalLogOptions(TypedDict, total=False):
    """The keywords of :meth:`HalCapture.to_log`, which :func:`read_hal_log` passes on:
    ``period_s``, ``dac_bits``, ``dac_range_v`` and ``compute_s``."""

    period_s: float | None
    dac_bits: int | None
    dac_range_v: tuple[float, float] | None
    compute_s: float | None


def read_hal_log(
    path: str | Path,
    settings: HalSettings,
    *,
    strict: bool = False,
    progress: Callable[[str], None] | None = None,
    **options: Unpack[HalLogOptions],
) -> Log:
    """Read a HAL capture or a CSV log with its own column names (:func:`read_hal_capture`)
    and convert it (:meth:`HalCapture.to_log`, whose keywords it takes): what
    ``servotune fit FILE --map …`` reads. ``strict``: a CSV's unknown metadata key is an
    error, not a :class:`~servotune.logs.LogMetadataWarning`. ``progress``: lines while a
    large capture is read.

    Examples
    --------
    >>> import os, tempfile
    >>> rows = "".join(f"{k} {0.5 * (k % 2):f} {k * 0.001:f} \\n" for k in range(4))
    >>> with tempfile.TemporaryDirectory() as d:
    ...     f = os.path.join(d, "capture.txt")
    ...     with open(f, "w") as fh:
    ...         _ = fh.write(rows)
    ...     s = HalSettings(mapping={"cmd": "pid.0.output", "pos": "encoder.0.position"},
    ...                     columns=("pid.0.output", "encoder.0.position"), sample_number=True,
    ...                     period_s=0.001, position_scale=2000.0, output_scale=0.5)
    ...     log = read_hal_log(f, s)
    >>> log.axis().cmd_v.tolist(), log.axis().pos_counts.tolist(), log.period_s
    ([0.0, 1.0, 0.0, 1.0], [0, 2, 4, 6], 0.001)
    """
    period = options.get("period_s")
    cap = read_hal_capture(
        path,
        format=settings.format,
        columns=settings.columns,
        sample_number=settings.sample_number,
        mapping=settings.mapping,
        period_s=settings.period_s if period is None else period,
        strict=strict,
        progress=progress,
    )
    return cap.to_log(settings, **options)


# --- parsing helpers -------------------------------------------------------------------------


def _sample_numbers(tags: np.ndarray, rows: np.ndarray) -> np.ndarray:
    bad = ~np.isfinite(tags) | (tags != np.rint(tags)) | (tags < 0)
    if bad.any():
        k = int(np.argmax(bad))
        raise LogFormatError(
            f"line {rows[k]}: the sample number (field 1, halsampler -t) must be a whole "
            f"number >= 0, got {float(tags[k])!r}"
        )
    s = tags.astype(np.int64)
    step = np.diff(s)
    gap = np.flatnonzero(step != 1)
    if gap.size:
        k = int(gap[0])
        if step[k] > 1:
            lost = int(step[k] - 1)
            raise LogFormatError(
                f"lost samples: the sample number jumps from {s[k]} (line {rows[k]}) to "
                f"{s[k + 1]} (line {rows[k + 1]}), {lost} sample{'s' if lost != 1 else ''} "
                f"missing (a sampler FIFO overrun; {_MORE_DEPTH})"
            )
        raise LogFormatError(
            f"the sample number goes from {s[k]} (line {rows[k]}) to {s[k + 1]} "
            f"(line {rows[k + 1]}): not one capture in order"
        )
    return s
