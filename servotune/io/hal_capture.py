"""A HAL capture as its file holds it (:class:`HalCapture`: numbered columns of numbers, names
where known) and its conversion to a servotune log (:meth:`HalCapture.to_log`) through the
mapping and scales of a :class:`~servotune.io.hal_map.HalSettings`. The files are read by
:mod:`servotune.io.hal` (whose names these are too); a CSV log with its own column names
(:func:`servotune.io.hal.read_mapped_csv`) converts as a capture does, except that without a
``position_scale`` its ``pos`` and ``ref`` are in counts.

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
"""

from __future__ import annotations

import difflib
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from servotune.errors import LogFormatError
from servotune.hw import dac as hw_dac
from servotune.io.hal_map import HalSettings, check_own_columns, show_target
from servotune.io.log import AxisLog, Log
from servotune.io.log_header import (
    option_value,
    parse_compute,
    parse_dac_bits,
    parse_period,
    parse_range,
)
from servotune.io.log_rows import REL_TOL, not_whole, whole_problem

__all__ = [
    "CMD_LOG_DAC_BITS",
    "CMD_LOG_DAC_RANGE_V",
    "MORE_DEPTH",
    "SHOW_NAMES",
    "HalCapture",
    "HalPrecisionWarning",
    "find_column",
]

CMD_LOG_DAC_BITS = 16
"""D/A resolution the log states when the command is mapped in volts (``cmd``) and no D/A is
given: it sets only the step in which an ``exc`` column is held (0.3 mV)."""
CMD_LOG_DAC_RANGE_V = (-10.0, 10.0)
"""D/A range [V] stated with :data:`CMD_LOG_DAC_BITS`."""
SHOW_NAMES = 8
"""A capture's column names listed in a message."""
MORE_DEPTH = "load sampler with a deeper FIFO, depth=…, or record fewer pins"
"""What a message of lost samples advises."""

_PRINTED_DECIMALS = 6  # halsampler prints float pins with %f
_MAX_COUNTS = 2.0**53  # beyond this a float position is no longer whole counts
_SHOW_CSV_NAMES = 24  # a CSV header's names listed in a message


class HalPrecisionWarning(UserWarning):
    """A capture's printed resolution is coarser than the quantity it carries (halsampler's
    6 decimals of a position in large machine units, coarser than one encoder count)."""


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
        return find_column(self.names, self.n_columns, target, key, self.format)

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
        m = settings.mapping
        period, compute_s = self._timing(settings, period_s, compute_s)
        cols = {key: self.column_index(target, key) for key, target in m.items()}
        check_own_columns(cols, self._label)
        if "overruns" in m:
            self._check_overruns(cols["overruns"])
        dac_bits, dac_range_v = self._dac(m, dac_bits, dac_range_v)
        scale = settings.position_scale
        for key in ("pos", "ref"):
            if key in m and scale is None and self.format != "csv":  # a CSV's: counts
                raise LogFormatError(
                    f"map {key} ({show_target(m[key])}) is in machine units: give the "
                    "encoder's position-scale [counts per machine unit] (--position-scale, or "
                    "position_scale under [hal])"
                )
        cmd_v, dac_code = self._command(settings, cols, dac_bits, dac_range_v)
        pos = self._position(m, cols, scale)
        ref = None
        if "ref" in m:
            j = cols["ref"]
            ref = self._whole("ref", j) if scale is None else self._counts("ref", j, scale)
        exc = None
        if "exc" in m:
            exc = self._excitation(settings, cols["exc"], dac_bits, dac_range_v)
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

    def _timing(
        self, settings: HalSettings, period_s: float | None, compute_s: float | None
    ) -> tuple[float, float | None]:
        """The sample period and the compute time of the log, checked against the capture and
        the settings (:meth:`to_log`'s ``period_s`` and ``compute_s``)."""
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
        return period, compute_s

    def _dac(
        self,
        m: Mapping[str, str | int],
        dac_bits: int | None,
        dac_range_v: tuple[float, float] | None,
    ) -> tuple[int, tuple[float, float]]:
        """The D/A the log states: the options', else a CSV's metadata's, else (a command in
        volts) :data:`CMD_LOG_DAC_BITS` and :data:`CMD_LOG_DAC_RANGE_V`; ``code`` needs one."""
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
        return dac_bits, dac_range_v

    def _command(
        self,
        settings: HalSettings,
        cols: Mapping[str, int],
        dac_bits: int,
        dac_range_v: tuple[float, float],
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """The command [V] and, when ``code`` is mapped, the D/A codes it is converted from."""
        if "code" not in settings.mapping:
            return self.values[:, cols["cmd"]] / settings.output_scale, None
        top = (1 << dac_bits) - 1
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
        return hw_dac.volts_from_code(dac_code, dac_bits, dac_range_v), dac_code

    def _position(
        self, m: Mapping[str, str | int], cols: Mapping[str, int], scale: float | None
    ) -> np.ndarray:
        """The position [counts]: ``pos`` (in machine units, or a CSV's in counts) or
        ``counts``."""
        if "pos" not in m:
            return self._whole("counts", cols["counts"])
        if scale is None:
            return self._whole("pos", cols["pos"])  # a CSV's position in counts
        pos = self._counts("pos", cols["pos"], scale)
        if self.format == "halsampler" and scale * 10.0**-_PRINTED_DECIMALS > 1.0:
            warnings.warn(
                f"HAL capture {self.path!r}: halsampler prints {self._label(cols['pos'])} "
                f"with {_PRINTED_DECIMALS} decimals, a step of "
                f"{scale * 10.0**-_PRINTED_DECIMALS:.3g} counts at position_scale {scale:g}: "
                "coarser than the encoder (log its counts pin, map counts=…)",
                HalPrecisionWarning,
                stacklevel=4,  # to_log's caller
            )
        return pos

    def _excitation(
        self, settings: HalSettings, j: int, dac_bits: int, dac_range_v: tuple[float, float]
    ) -> np.ndarray:
        """The ``exc`` column (``j``) in D/A codes relative to the zero code."""
        top = (1 << dac_bits) - 1
        if "code" in settings.mapping:
            exc = self._whole("exc", j)
        else:
            lsb = hw_dac.lsb_v(dac_bits, dac_range_v)
            exc = np.rint(self.values[:, j] / settings.output_scale / lsb)
        self._refuse_first(
            np.abs(exc) > top,
            j,
            lambda k: (
                f"the excitation is {exc[k]:.0f} D/A codes, beyond the {dac_bits}-bit "
                f"D/A's span (at most ±{top})"
            ),
        )
        return exc.astype(np.int64)

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
                f"sample{'s' if abs(lost) != 1 else ''} lost between them ({MORE_DEPTH})"
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


def find_column(
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
        show = _SHOW_CSV_NAMES if csv else SHOW_NAMES
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
