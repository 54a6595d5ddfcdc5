"""LinuxCNC HAL captures: ``halsampler`` output and halscope's saved data, read into a log.

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
              0 … 2^bits − 1 (SPEC §5's)      (``dac_bits``, ``dac_range_v``)
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
"""

from __future__ import annotations

import difflib
import re
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypedDict, Unpack

import numpy as np

from servotune.errors import LogFormatError
from servotune.hw import dac as hw_dac
from servotune.io.hal_map import (
    HAL_FORMATS,
    MAP_KEYS,
    HalSettings,
    _check_own_columns,
    _show_target,
    hal_settings,
    parse_hal_map,
    read_hal_map,
)
from servotune.io.log_header import (
    PERIOD_RANGE_S,
    _option,
    _parse_compute,
    _parse_dac_bits,
    _parse_period,
    _parse_range,
    _read_text,
    naming,
)
from servotune.logs import MIN_ROWS, AxisLog, Log
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
    "hal_settings",
    "parse_hal_map",
    "read_hal_capture",
    "read_hal_log",
    "read_hal_map",
    "read_halsampler",
    "read_halscope",
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
        ``"halsampler"`` or ``"halscope"``.
    values : ndarray of float, shape (n, m)
        The samples, one row per line, one column per pin (the sample number not included),
        in the units HAL printed them.
    names : tuple of str or None
        The columns' pin (signal, parameter) names: halscope's header, or the ``columns``
        given for a halsampler capture; None when nothing names them.
    lines : ndarray of int64
        The 1-based file line of each row (for the messages).
    sample_numbers : ndarray of int64 or None
        halsampler ``-t``'s sample numbers (consecutive: a gap is refused on reading).
    period_s : float or None
        The sample period [s] from halscope's header (halsampler records none).
    path : str
        Where it was read from.
    """

    format: str
    values: np.ndarray
    names: tuple[str, ...] | None = None
    lines: np.ndarray
    sample_numbers: np.ndarray | None = None
    period_s: float | None = None
    path: str = ""

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

    def _label(self, j: int) -> str:
        return f"column {j} ({self.names[j]})" if self.names is not None else f"column {j}"

    def _refuse_first(self, bad: np.ndarray, j: int, problem: Callable[[int], str]) -> None:
        """Raise for the first row ``k`` that is ``bad``, naming its line and column ``j``:
        ``problem(k)`` says what is wrong there."""
        if bad.any():
            k = int(np.argmax(bad))
            raise LogFormatError(f"line {self.lines[k]}, {self._label(j)}: {problem(k)}")

    def column_index(self, target: str | int, key: str = "") -> int:
        """The 0-based column of a pin name or column number.

        Raises
        ------
        LogFormatError
            A column number out of range, a name when nothing names the columns, a name not
            among them (with the closest one), a name on two columns.
        """
        who = f"map {key}: " if key else ""
        if isinstance(target, int):
            if not 0 <= target < self.n_columns:
                raise LogFormatError(
                    f"{who}column {target} is out of range: the capture has {self.n_columns} "
                    f"value column{'s' if self.n_columns != 1 else ''} (0..{self.n_columns - 1})"
                )
            return target
        if self.names is None:
            raise LogFormatError(
                f"{who}pin {target!r}: a halsampler capture does not name its columns; give "
                "the sampler's pin order (--hal-columns pid.0.output,encoder.0.position, or "
                "columns = [...] under [hal]) or map by column number (pos=1)"
            )
        hits = [j for j, n in enumerate(self.names) if n == target]
        if not hits:
            listed = ", ".join(self.names[:_SHOW_NAMES])
            more = (
                f" and {len(self.names) - _SHOW_NAMES} more"
                if len(self.names) > _SHOW_NAMES
                else ""
            )
            near = difflib.get_close_matches(target, self.names, n=1)
            hint = f"; did you mean {near[0]!r}?" if near else ""
            raise LogFormatError(
                f"{who}pin {target!r} is not in the capture's columns: {listed}{more}{hint}"
            )
        if len(hits) > 1:
            raise LogFormatError(
                f"{who}pin {target!r} is in {len(hits)} columns ({', '.join(map(str, hits))}): "
                "map it by column number"
            )
        return hits[0]

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
            Sample → D/A write time [s] (SPEC §4), >= 0 and below the period.

        Returns
        -------
        Log
            The capture as a servotune log (SPEC §5 columns).

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
            raise LogFormatError(f"HAL capture {self.path!r}: {exc}") from None

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
        period = self._period(settings, period_s)
        if compute_s is not None:
            compute_s = _option("compute_s", compute_s, _parse_compute)
            if compute_s >= period:
                raise LogFormatError(
                    f"compute_s must be shorter than the sample period {period:.6g} s [s], "
                    f"got {compute_s!r}"
                )
        m = settings.mapping
        cols = {key: self.column_index(target, key) for key, target in m.items()}
        _check_own_columns(cols, self._label)
        if "overruns" in m:
            self._check_overruns(cols["overruns"])
        if dac_bits is not None:
            dac_bits = _option("dac_bits", dac_bits, _parse_dac_bits)
        if dac_range_v is not None:
            dac_range_v = _option("dac_range_v", dac_range_v, _parse_range)
        if "code" in m:
            if dac_bits is None or dac_range_v is None:
                raise LogFormatError(
                    f"map code ({_show_target(m['code'])}) is a D/A code: give the D/A's "
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
            if key in m and scale is None:
                raise LogFormatError(
                    f"map {key} ({_show_target(m[key])}) is in machine units: give the "
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
        if "pos" in m:
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
            assert scale is not None
            ref = self._counts("ref", cols["ref"], scale)
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
        axis = AxisLog(cmd_v=np.ascontiguousarray(cmd_v, dtype=float), pos_counts=pos,
                       dac_code=dac_code, ref_counts=ref, exc_code=exc, name="")  # fmt: skip
        meta = {"kind": f"LinuxCNC {self.format} capture", "period_s": f"{period!r}"}
        return Log(period_s=period, axes={"": axis}, metadata=meta, dac_bits=dac_bits,
                   dac_range_v=dac_range_v, compute_s=compute_s, path=self.path)  # fmt: skip

    def _period(self, settings: HalSettings, period_s: float | None) -> float:
        given, source = settings.period_s, "the map's period_s"
        if period_s is not None:
            given, source = _option("period_s", period_s, _parse_period), "--period-s"
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
        """Column ``j`` as int64, refusing values that are not whole numbers."""
        a = self.values[:, j]
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
) -> HalCapture:
    """Read ``halsampler`` output (module docstring).

    Parameters
    ----------
    path : str or Path
        The file (halsampler's stdout, redirected).
    columns : sequence of str, optional
        The sampler's pin names in its ``cfg`` order; the rows must have that many values.
    sample_number : bool
        The file was written with ``halsampler -t``: the first field is the sample number
        (not a column); the numbers must run on by one.

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
    """
    src = str(path)
    with naming(src, "HAL capture"):
        names = None if columns is None else tuple(columns)
        text = _read_text(Path(path), src, "HAL capture")
        lines = text.split("\n")
        first = next((i for i, ln in enumerate(lines) if ln.strip()), None)
        if first is not None and lines[first].lstrip().startswith("#"):
            hint = (
                " (halscope's saved data: --hal-format halscope)"
                if lines[first].startswith(HALSCOPE_PERIOD_LINE)
                else ""
            )
            raise LogFormatError(
                f"line {first + 1} is a comment; halsampler writes only numbers{hint}"
            )
        lead = 1 if sample_number else 0

        def label(j: int) -> str:
            if j < lead:
                return "field 1 (the sample number)"
            c = j - lead
            known = names is not None and c < len(names)
            return f"column {c} ({names[c]})" if known else f"column {c}"  # type: ignore[index]

        if "overrun" in text:  # halsampler's mark of a gap, on a line by itself
            k = next((i for i, ln in enumerate(lines) if ln.strip() == "overrun"), None)
            if k is not None:
                raise LogFormatError(
                    f"lost samples: line {k + 1} is halsampler's 'overrun' mark (the sampler's "
                    f"FIFO was full; {_MORE_DEPTH})"
                )
        values, rows = _numbers(lines, 0, None, "halsampler", label)
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
        _check_rows(values, rows, names)
        return HalCapture(format="halsampler", values=np.ascontiguousarray(values), names=names,
                          lines=rows, sample_numbers=numbers, path=src)  # fmt: skip


def read_halscope(path: str | Path) -> HalCapture:
    """Read halscope's saved data (module docstring; LinuxCNC ``scope_files.c``).

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
        text = _read_text(Path(path), src, "HAL capture")
        lines = text.split("\n")
        if not text.strip():
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
            raise LogFormatError(
                f"line 1: the sampling period {ns} ns is outside {lo:g} … {hi:g} s"
            )
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
        values, rows = _numbers(
            lines, start, ";", "halscope",
            lambda j: f"column {j} ({names[j]})" if j < len(names) else f"field {j + 1}",
        )  # fmt: skip
        if values.shape[1] != len(names):
            raise LogFormatError(
                f"line {rows[0]} has {values.shape[1]} fields; line 2 names {len(names)} "
                f"channels ({', '.join(names[:_SHOW_NAMES])})"
            )
        _check_rows(values, rows, names)
        return HalCapture(format="halscope", values=values, names=names, lines=rows,
                          period_s=period_s, path=src)  # fmt: skip


def read_hal_capture(
    path: str | Path,
    *,
    format: str | None = None,
    columns: Sequence[str] | None = None,
    sample_number: bool = False,
) -> HalCapture:
    """Read a HAL capture in either format; ``format`` None detects it from the first line
    (halscope's begins with ``# Sampling period is``, halsampler's with numbers)."""
    if format is None:
        format = "halsampler"
        try:
            with open(path, "rb") as fh:
                if (
                    fh.read(len(HALSCOPE_PERIOD_LINE) + 3)
                    .lstrip(b"\xef\xbb\xbf")
                    .startswith(HALSCOPE_PERIOD_LINE.encode())
                ):
                    format = "halscope"
        except OSError:
            pass  # the reader names the problem
    if format == "halscope":
        if columns is not None or sample_number:
            what = "columns (--hal-columns)" if columns is not None else "--sample-number"
            raise LogFormatError(
                f"HAL capture {str(path)!r} is halscope's saved data, which names its channels "
                f"(line 2) and has no sample numbers: {what} is for halsampler captures"
            )
        return read_halscope(path)
    if format != "halsampler":
        raise LogFormatError(f"format must be one of {', '.join(HAL_FORMATS)}, got {format!r}")
    return read_halsampler(path, columns=columns, sample_number=sample_number)


class HalLogOptions(TypedDict, total=False):
    """The keywords of :meth:`HalCapture.to_log`, which :func:`read_hal_log` passes on:
    ``period_s``, ``dac_bits``, ``dac_range_v`` and ``compute_s``."""

    period_s: float | None
    dac_bits: int | None
    dac_range_v: tuple[float, float] | None
    compute_s: float | None


def read_hal_log(path: str | Path, settings: HalSettings, **options: Unpack[HalLogOptions]) -> Log:
    """Read a HAL capture (:func:`read_hal_capture`) and convert it
    (:meth:`HalCapture.to_log`, whose keywords it takes): what ``servotune fit CAPTURE --map …``
    reads.

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
    cap = read_hal_capture(path, format=settings.format, columns=settings.columns,
                           sample_number=settings.sample_number)  # fmt: skip
    return cap.to_log(settings, **options)


# --- parsing helpers -------------------------------------------------------------------------

_NUMBER_RE = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


def _numbers(
    lines: list[str],
    start: int,
    delimiter: str | None,
    what: str,
    label: Callable[[int], str],
) -> tuple[np.ndarray, np.ndarray]:
    """The non-blank lines from ``start`` as an (n, m) float array, and their 1-based line
    numbers. Bulk-parsed by ``numpy.loadtxt``; on failure the lines are scanned one by one to
    name the first bad one (``label(j)`` names field ``j``)."""
    idx = [i for i in range(start, len(lines)) if lines[i].strip()]
    if not idx:
        raise LogFormatError(f"the {what} capture is empty (no samples)")
    rows = np.asarray(idx, dtype=np.int64) + 1
    body = [lines[i] for i in idx]
    try:
        values = np.loadtxt(body, dtype=float, delimiter=delimiter, comments=None, ndmin=2)
    except ValueError:
        _first_bad(body, rows, delimiter, label)
        raise  # pragma: no cover  (_first_bad raises: loadtxt refused something it finds)
    if values.shape[0] < MIN_ROWS:
        raise LogFormatError(
            f"{values.shape[0]} sample{'s' if values.shape[0] != 1 else ''}; at least "
            f"{MIN_ROWS} are needed"
        )
    return values, rows


def _split(line: str, delimiter: str | None) -> list[str]:
    return line.split() if delimiter is None else [t.strip() for t in line.split(delimiter)]


def _first_bad(
    body: list[str], rows: np.ndarray, delimiter: str | None, label: Callable[[int], str]
) -> None:
    width = len(_split(body[0], delimiter))
    for k, line in enumerate(body):
        fields = _split(line, delimiter)
        if len(fields) != width:
            raise LogFormatError(
                f"line {rows[k]} has {len(fields)} field{'s' if len(fields) != 1 else ''}, "
                f"the rows before it {width} (line {rows[0]})"
            )
        for j, tok in enumerate(fields):
            if not _NUMBER_RE.fullmatch(tok) and tok.lower().lstrip("+-") not in ("nan", "inf"):
                raise LogFormatError(
                    f"line {rows[k]}, {label(j)}: {show_value(tok)} is not a number"
                )
    raise LogFormatError(f"line {rows[0]}: the rows are not numbers numpy can read")


def _check_rows(values: np.ndarray, rows: np.ndarray, names: Sequence[str] | None) -> None:
    bad = ~np.isfinite(values)
    if bad.any():
        k, j = (int(x) for x in np.argwhere(bad)[0])
        label = f"column {j}" if names is None else f"column {j} ({names[j]})"
        raise LogFormatError(f"line {rows[k]}, {label}: {values[k, j]} is not finite")


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
