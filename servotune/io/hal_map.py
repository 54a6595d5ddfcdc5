"""LinuxCNC HAL captures' settings: which column is what, and LinuxCNC's scales.

A :class:`HalSettings` says how to read a capture of :mod:`servotune.io.hal`: the mapping
(servotune's ``cmd`` or ``code``, ``pos`` or ``counts``, optionally ``ref``, ``exc`` and
``overruns``, each a pin name or a 0-based column number; :data:`MAP_KEYS`), the format
(:data:`HAL_FORMATS`), the sample period, the halsampler columns' names and whether they were
written with ``-t``, and LinuxCNC's scales. :meth:`servotune.io.hal.HalCapture.to_log`
converts the mapped columns with them (the units: :mod:`servotune.io.hal`). The same settings
read a CSV log whose header names its columns in its own words
(:func:`servotune.io.hal.read_mapped_csv`): the keys then name header columns, and ``time``
and ``tick`` its time base.

The settings come from ``servotune fit``'s options, built by :func:`hal_settings`: ``--map``
as ``KEY=PIN,…`` (:func:`parse_hal_map`) or a TOML file with a ``[hal]`` table
(:func:`read_hal_map`), the other options over it.

``position_scale`` is the encoder's ``position-scale`` parameter [counts per machine unit]
(LinuxCNC: position = counts / position-scale); ``output_scale`` is the pid output units per
volt at the D/A [units/V] (1.0: the output is in volts). Both must be > 0: a negative LinuxCNC
scale only reverses a direction (give its magnitude, and ``--invert-encoder`` if the counts
then run against the command).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from servotune.errors import LogFormatError
from servotune.io.files import read_toml
from servotune.io.log_header import option_value, parse_period
from servotune.validate import check_keys, check_number, is_number, show_value

__all__ = [
    "HAL_FORMATS",
    "MAP_KEYS",
    "HalSettings",
    "hal_settings",
    "parse_hal_map",
    "read_hal_map",
]

HAL_FORMATS = ("halsampler", "halscope")
"""The capture formats: ``halsampler`` output and halscope's saved data."""
MAP_KEYS = ("cmd", "code", "pos", "counts", "ref", "exc", "overruns", "time", "tick")
"""Mapping keys (servotune's side): exactly one of ``cmd``/``code``, one of ``pos``/``counts``,
optionally ``ref``, ``exc`` and ``overruns`` (the sampler's overrun count, a loss witness);
for a CSV log also ``time`` (its time column [s]) and ``tick`` (its sample number)."""

_C = TypeVar("_C", bound=Hashable)  # a column: as the settings name it, or its index


@dataclass(frozen=True, slots=True, kw_only=True)
class HalSettings:
    """How to read a HAL capture: which column is what, and LinuxCNC's scales.

    Parameters
    ----------
    mapping : mapping of str to str or int
        :data:`MAP_KEYS` → a HAL pin (or signal) name, or a 0-based column number (for
        halsampler: ``sampler.0.pin.N`` is column N, the sample number not counted); for a
        CSV log (:func:`servotune.io.hal.read_mapped_csv`) a column name of its header.
    format : str, optional
        ``"halsampler"`` or ``"halscope"``; None: detected from the content (halscope's files
        begin with ``# Sampling period is``).
    period_s : float, optional
        Sample period [s]: the period of the thread ``sampler`` runs in (the servo thread).
        Required for halsampler, which does not record it; halscope's header gives it (a
        value here must agree with it).
    position_scale : float, optional
        The encoder's ``position-scale`` [counts per machine unit], > 0; needed when ``pos`` or
        ``ref`` of a HAL capture is mapped (a CSV's are in counts without it).
    output_scale : float
        Pid output units per volt at the D/A [units/V], > 0 (default 1.0: volts).
    columns : tuple of str, optional
        The sampler's pin names in its ``cfg`` order (halsampler only; halscope's file names
        its channels itself).
    sample_number : bool
        The halsampler capture was written with ``halsampler -t``: its first field is the
        sample number, checked for gaps (lost samples: :mod:`servotune.io.hal`).

    Raises
    ------
    LogFormatError
        An unknown mapping key, not exactly one of ``cmd``/``code`` or of ``pos``/``counts``,
        an empty name or a negative column number, two keys on the same column, an unknown
        format, a scale that is not a finite number > 0, duplicate or empty column names,
        ``columns`` or ``sample_number`` with halscope.
    """

    mapping: Mapping[str, str | int]
    format: str | None = None
    period_s: float | None = None
    position_scale: float | None = None
    output_scale: float = 1.0
    columns: tuple[str, ...] | None = None
    sample_number: bool = False

    def __post_init__(self) -> None:
        m = check_keys(self.mapping, "map", (), MAP_KEYS, error=LogFormatError, noun="mapping key")
        for key, target in m.items():
            if isinstance(target, str) and target.strip().isdigit():
                m[key] = int(target)  # "3" on the command line is column 3
            elif isinstance(target, str):
                m[key] = target.strip()
                if not m[key] or len(m[key].split()) != 1:
                    raise LogFormatError(
                        f"map {key} must be a pin or column name (no spaces; a CSV column with "
                        f"spaces by its number) or a column number, got {target!r}"
                    )
            elif type(target) is not int or target < 0:
                raise LogFormatError(
                    f"map {key} must be a HAL pin name or a 0-based column number, got "
                    f"{show_value(target)}"
                )
        for pair in (("cmd", "code"), ("pos", "counts")):
            given = [k for k in pair if k in m]
            if len(given) != 1:
                what = "both" if given else "neither"
                raise LogFormatError(
                    f"map needs exactly one of {pair[0]} or {pair[1]}, got {what} (e.g. "
                    f"{'cmd=pid.0.output' if pair[0] == 'cmd' else 'pos=encoder.0.position'})"
                )
        check_own_columns(m, show_target)
        object.__setattr__(self, "mapping", m)
        if self.format is not None and self.format not in HAL_FORMATS:
            raise LogFormatError(
                f"format must be one of {', '.join(HAL_FORMATS)}, got {show_value(self.format)}"
            )
        if self.period_s is not None:
            object.__setattr__(
                self, "period_s", option_value("period_s", self.period_s, parse_period)
            )
        if self.position_scale is not None:
            check_number(
                "position_scale",
                self.position_scale,
                "counts per machine unit",
                strict=True,
                error=LogFormatError,
            )
        check_number(
            "output_scale",
            self.output_scale,
            "pid output units per V",
            strict=True,
            error=LogFormatError,
        )
        if self.columns is not None:
            cols = tuple(self.columns) if not isinstance(self.columns, str) else (self.columns,)
            for c in cols:
                if not isinstance(c, str) or not c.strip() or len(c.split()) != 1:
                    raise LogFormatError(
                        f"columns must be HAL pin names (no spaces), got {show_value(c)}"
                    )
            cols = tuple(c.strip() for c in cols)
            dup = next((c for i, c in enumerate(cols) if c in cols[:i]), None)
            if dup is not None:
                raise LogFormatError(f"columns names {dup!r} twice")
            object.__setattr__(self, "columns", cols)
        if not isinstance(self.sample_number, bool):
            raise LogFormatError(
                f"sample_number must be true or false, got {show_value(self.sample_number)}"
            )
        if self.format == "halscope" and (self.columns is not None or self.sample_number):
            what = "columns" if self.columns is not None else "sample_number"
            raise LogFormatError(
                f"{what} is for halsampler captures; a halscope file names its channels itself "
                "(line 2) and has no sample numbers"
            )

    def replace(self, **changes: Any) -> HalSettings:
        """A copy with the given fields changed; None values leave a field as it is (how
        command-line options override a map file)."""
        given = {k: v for k, v in changes.items() if v is not None}
        return dataclasses.replace(self, **given) if given else self


def show_target(target: str | int) -> str:
    return f"column {target}" if isinstance(target, int) else f"pin {target!r}"


def check_own_columns(columns: Mapping[str, _C], show: Callable[[_C], str]) -> None:
    """Raise naming the first two mapping keys that read the same column.

    ``columns`` maps each key to its column, as the settings name it (a pin or a number) or as
    a capture resolves it (an index); ``show`` words a column for the message.
    """
    seen: dict[_C, str] = {}
    for key, column in columns.items():
        if column in seen:
            raise LogFormatError(
                f"map {seen[column]} and {key} both read {show(column)}: each mapping key "
                "needs its own column"
            )
        seen[column] = key


# --- the settings: --map and its TOML file ---------------------------------------------------


def parse_hal_map(text: str) -> dict[str, str | int]:
    """The inline mapping ``cmd=pid.0.output,pos=encoder.0.position`` as a dict.

    A value of digits is a 0-based column number (``pos=1``).

    Raises
    ------
    LogFormatError
        A pair without ``=``, an empty key or value, a key given twice.

    Examples
    --------
    >>> parse_hal_map("cmd=pid.0.output, pos=1")
    {'cmd': 'pid.0.output', 'pos': 1}
    """
    out: dict[str, str | int] = {}
    for part in text.split(","):
        key, eq, value = (x.strip() for x in part.partition("="))
        if not eq or not key or not value:
            raise LogFormatError(
                f"--map takes KEY=PIN pairs separated by commas (cmd=pid.0.output,"
                f"pos=encoder.0.position) or a TOML file, got {show_value(part.strip())}"
            )
        if key in out:
            raise LogFormatError(f"--map gives {key} twice")
        out[key] = int(value) if value.isdigit() else value
    return out


_HAL_KEYS = ("format", "period_s", "position_scale", "output_scale", "columns", "sample_number",
             "map")  # fmt: skip


def read_hal_map(path: str | Path) -> HalSettings:
    """Read a capture's map file (TOML): a ``[hal]`` table and its ``[hal.map]``.

    ::

        [hal]
        format = "halsampler"          # or "halscope"; default: detected
        period_s = 0.001               # halsampler: required (here or --period-s)
        position_scale = 2000.0        # counts per machine unit (encoder position-scale)
        output_scale = 1.0             # pid output units per volt
        columns = ["pid.0.output", "encoder.0.position", "pid.0.command"]
        sample_number = true           # written with halsampler -t

        [hal.map]
        cmd = "pid.0.output"
        pos = "encoder.0.position"
        ref = "pid.0.command"

    Raises
    ------
    LogFormatError
        One line naming the file: not readable TOML, an unknown key or table (with the closest
        known one), a value of the wrong type, anything :class:`HalSettings` refuses.
    """
    src = str(path)
    doc = read_toml(path, LogFormatError, "HAL map file")
    try:
        check_keys(doc, "", ("hal",), error=LogFormatError, noun="table")
        hal = check_keys(doc["hal"], "hal", ("map",), _HAL_KEYS, error=LogFormatError)
        mapping = check_keys(
            hal.pop("map"), "hal.map", (), MAP_KEYS, error=LogFormatError, noun="mapping key"
        )
        kw: dict[str, Any] = {"mapping": mapping}
        if "columns" in hal and not isinstance(hal["columns"], list):
            raise LogFormatError(
                f"hal.columns must be a list of pin names, got {show_value(hal['columns'])}"
            )
        for k in ("period_s", "position_scale", "output_scale"):
            if k in hal and not is_number(hal[k]):
                raise LogFormatError(f"hal.{k} must be a number, got {show_value(hal[k])}")
        if "format" in hal and not isinstance(hal["format"], str):
            raise LogFormatError(f"hal.format must be a string, got {show_value(hal['format'])}")
        kw.update(hal)
        if "columns" in kw:
            kw["columns"] = tuple(kw["columns"])
        return HalSettings(**kw)
    except LogFormatError as exc:
        raise LogFormatError(f"HAL map file {src!r}: {exc}") from None


def hal_settings(
    map_: str | None,
    *,
    format: str | None = None,
    columns: str | Sequence[str] | None = None,
    position_scale: float | None = None,
    output_scale: float | None = None,
    sample_number: bool | None = None,
    capture: str | Path | None = None,
) -> HalSettings | None:
    """The settings of ``servotune fit --map …``: the map, then the options over it.

    Parameters
    ----------
    map_ : str or None
        A TOML map file (:func:`read_hal_map`; a path ending in ``.toml`` or an existing
        file) or the inline form ``cmd=pid.0.output,pos=encoder.0.position``
        (:func:`parse_hal_map`). None: the log is not a HAL capture.
    format, columns, position_scale, output_scale, sample_number : optional
        The command line's values (``--hal-format``, ``--hal-columns`` as a comma-separated
        string or a sequence, ``--position-scale`` [counts per machine unit],
        ``--output-scale`` [pid output units per V], ``--sample-number``); each given one
        overrides the map file's.
    capture : str or Path, optional
        The capture the settings are for, named in the messages.

    Returns
    -------
    HalSettings or None
        None when neither a map nor an option is given.

    Raises
    ------
    LogFormatError
        An option without ``--map``, or a map or value the settings refuse (the map file
        named).
    """
    opts = {
        "format": format,
        "columns": columns,
        "position_scale": position_scale,
        "output_scale": output_scale,
        "sample_number": sample_number,
    }
    given = [k for k, v in opts.items() if v is not None]
    where = "" if capture is None else f"HAL capture {str(capture)!r}: "
    if map_ is None:
        if given:
            flag = {"format": "hal-format", "columns": "hal-columns"}.get(given[0], given[0])
            raise LogFormatError(
                f"{where}--{flag.replace('_', '-')} describes a HAL capture: give --map too "
                "(e.g. --map cmd=pid.0.output,pos=encoder.0.position, or --map capture.toml)"
            )
        return None
    if isinstance(columns, str):
        opts["columns"] = tuple(c.strip() for c in columns.split(","))
    elif columns is not None:
        opts["columns"] = tuple(columns)
    is_file = map_.endswith(".toml") or Path(map_).is_file()
    try:
        if is_file:
            try:
                return read_hal_map(map_).replace(**opts)
            except LogFormatError as exc:
                if repr(map_) in str(exc):
                    raise
                raise LogFormatError(f"HAL map file {map_!r} with the options: {exc}") from None
        mapping = parse_hal_map(map_)
        try:
            given_opts = {k: v for k, v in opts.items() if v is not None}
            return HalSettings(mapping=mapping, **given_opts)
        except LogFormatError as exc:
            raise LogFormatError(f"--map and its options: {exc}") from None
    except LogFormatError as exc:
        raise LogFormatError(f"{where}{exc}") from None
