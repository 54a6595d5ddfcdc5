"""The rig file's plant table edited in place (docs/formats.md#rig-file): what
:func:`servotune.rig.file.write_plant` writes.

:func:`edit_plant_text` rewrites one ``[axis.<name>.plant]`` table of a rig file's text from a
:class:`~servotune.plant.Plant` (and its fit record and modes), every comment and the layout of
the rest kept byte for byte (in that table, a comment that described a replaced value goes with
it); :func:`new_rig_text` makes a new rig file's text from a template's.
:func:`servotune.rig.file.write_plant` checks the result against the model of
:mod:`servotune.rig.model` before it writes it. The package :mod:`servotune.rig` re-exports
:data:`FLOAT_SIGNIFICANT_DIGITS`.
"""

from __future__ import annotations

import errno
import re
from collections.abc import Mapping, MutableMapping
from dataclasses import fields
from pathlib import Path
from typing import Any

import tomlkit
import tomlkit.exceptions
import tomlkit.items

from servotune.errors import RigError
from servotune.plant import Plant
from servotune.rig.model import FIT_PCT_KEYS
from servotune.validate import is_number, show_value

__all__ = ["FLOAT_SIGNIFICANT_DIGITS", "edit_plant_text", "new_rig_text"]


FLOAT_SIGNIFICANT_DIGITS = 7
"""Significant digits :func:`write_plant` keeps of each parameter (relative error <= 5e-7)."""

_FITTED_KEYS = ("gain_cps_per_v", "tau_s", "delay_s", "offset_v", "coulomb_v")
# Settings of the hardware that a fit does not estimate: written only when the plant sets them
# (differs from the Plant default), otherwise the file's values stay.
_KEPT_KEYS = ("max_speed_rpm", "noise_counts")
# The negative direction's gain and Coulomb level (asymmetric model): written when the plant
# sets them, removed when it leaves them None (a symmetric plant), so the file says which.
_DIRECTION_KEYS = ("gain_neg_cps_per_v", "coulomb_neg_v")


def _toml_float(value: float) -> str:
    """TOML text of ``value`` rounded to :data:`FLOAT_SIGNIFICANT_DIGITS` significant digits.

    The rounded number is written with ``repr``, the shortest text that reads back as exactly
    that float: ``12288.049999999999`` → ``12288.05``, ``0.0008`` → ``0.0008``, ``12288`` →
    ``12288.0``, ``1.5e-05`` → ``1.5e-05`` (valid TOML). ``-0.0`` is written as ``0.0``.
    """
    x = float(f"{float(value):.{FLOAT_SIGNIFICANT_DIGITS}g}")
    if x == 0.0:
        x = 0.0
    return repr(x)


# A comment that states a number or cites a source describes the value it was written beside
# (``# 600 r/min at 10 V with 12288 counts/rev``, ``# from the drive's data sheet``): once a
# fit replaces the value it is false. A comment without either names the quantity
# (``# analog zero drift``) and stays true.
_STATES_VALUE_OR_SOURCE = re.compile(
    r"\d|[§≈~=<>±]|://|\.\./|\b(?:spec|decisions?|seed|issue|data ?sheet|manual|catalog(?:ue)?"
    r"|measured|measurement|fit|fitted|estimated|identified|tuned|calibrated|nominal|typical"
    r"|guess(?:ed)?|assumed|approx(?:imately)?|about|around|roughly|from|see|per|according|was"
    r"|old|default|template|example|pc-dual-servo)\b",
    re.IGNORECASE,
)


def _outlives_new_value(comment: str) -> bool:
    """Whether a comment written beside (or directly above) a value stays true when a fit
    replaces the value: it neither states a number nor cites a source.

    >>> _outlives_new_value("# analog zero drift")
    True
    >>> _outlives_new_value("# 600 r/min at 10 V with 12288 counts/rev")
    False
    >>> _outlives_new_value("# from the drive's data sheet")
    False
    """
    return _STATES_VALUE_OR_SOURCE.search(comment.lstrip("#")) is None


def _set_float(table: MutableMapping[str, Any], key: str, value: float) -> float:
    """Set ``table[key]`` to ``value`` (rounded, see :func:`_toml_float`); return what is written.

    An existing entry that already holds that value keeps its text (``0.030`` stays ``0.030``)
    and its comment. A replaced entry keeps a trailing comment that names the quantity, at the
    same column where the new value allows; one that states a number or a source described the
    old value and is dropped (:func:`_outlives_new_value`).
    """
    text = _toml_float(value)
    number = float(text)
    old = table.get(key)
    if is_number(old) and float(old) == number:
        return float(old)
    item = tomlkit.value(text)
    comment = old.trivia.comment if isinstance(old, tomlkit.items.Item) else ""
    if comment and _outlives_new_value(comment):
        ws = old.trivia.comment_ws
        column = len(old.as_string()) + len(ws)
        item.trivia.comment_ws = " " * max(column - len(text), min(len(ws), 2), 1)
        item.trivia.comment = comment
    table[key] = item
    if comment and not _outlives_new_value(comment):  # tomlkit copies the old comment over
        new = table[key]
        new.trivia.comment_ws = new.trivia.comment = ""
    return number


def _one_line(provenance: str) -> str:
    line = provenance.strip()
    bad = [c for c in line if (ord(c) < 0x20 and c != "\t") or ord(c) == 0x7F]
    if bad:
        raise RigError(
            f"provenance must be one line of text without control characters, got "
            f"{show_value(provenance)}"
        )
    return line


def _fit_table(fit: Mapping[str, Any]) -> tuple[Any, dict[str, Any]]:
    """The ``[axis.<name>.plant.fit]`` table of a fit record, and the record as it reads back.

    Keys in a fixed order; the fit figures and the interval ends rounded like the plant's values
    (:func:`_toml_float`).
    """
    table = tomlkit.table()
    back: dict[str, Any] = {}
    for key in ("method", "structure", "friction", "adequate", "reason", "interval"):
        value = fit[key]
        table[key] = list(value) if isinstance(value, tuple) else value
        back[key] = list(value) if isinstance(value, tuple | list) else value
    for key in FIT_PCT_KEYS:  # the fit figures, those recorded (a None is left out)
        if fit.get(key) is not None:
            table[key] = tomlkit.value(_toml_float(fit[key]))
            back[key] = float(_toml_float(fit[key]))
    ci = tomlkit.table()
    back["ci95"] = {}
    for name, (lo, hi) in fit["ci95"].items():
        pair = [float(_toml_float(lo)), float(_toml_float(hi))]
        ci[name] = tomlkit.array(f"[{_toml_float(lo)}, {_toml_float(hi)}]")
        back["ci95"][name] = pair
    ci.add(tomlkit.nl())  # a blank line before whatever table follows, as the file had
    table["ci95"] = ci
    return table, back


_MODE_KEYS = ("freq_hz", "damping", "gain")
# A mode's entries in the order written; each value's 95 % interval, where the mode has one,
# follows as ``<key>_95 = [low, high]``.


def _modes_item(modes: Any, inline: bool) -> tuple[Any, list[dict[str, Any]]]:
    """The ``modes`` of a plant table: an array of tables (``[[axis.<name>.plant.modes]]``, or an
    array of inline tables in an inline plant table), each value rounded like the plant's
    (:func:`_toml_float`); and the modes as they read back (a dict per mode: the values and the
    intervals written, an interval as a ``(low, high)`` tuple)."""
    back: list[dict[str, Any]] = []
    tables = []
    for mode in modes:
        table = tomlkit.inline_table() if inline else tomlkit.table()
        entry: dict[str, Any] = {}
        for key in _MODE_KEYS:
            table[key] = tomlkit.value(_toml_float(getattr(mode, key)))
            entry[key] = float(table[key])
        for key in _MODE_KEYS:
            pair = getattr(mode, f"{key}_95", None)
            if pair is not None:
                lo, hi = (_toml_float(x) for x in pair)
                table[f"{key}_95"] = tomlkit.array(f"[{lo}, {hi}]")
                entry[f"{key}_95"] = (float(lo), float(hi))
        tables.append(table)
        back.append(entry)
    if inline:
        array = tomlkit.array()
        array.extend(tables)
        return array, back
    aot = tomlkit.aot()
    for table in tables:
        aot.append(table)
    tables[-1].add(tomlkit.nl())  # a blank line before whatever table follows, as the file had
    return aot, back


def _plant_section(
    text: str,
    source: Path,
    axis: str,
    plant: Plant,
    provenance: str | None,
    fit: Mapping[str, Any] | None = None,
) -> tuple[str, dict[str, Any]]:
    """``text`` with the plant table of ``axis`` rewritten, and the values written."""
    try:
        doc = tomlkit.parse(text)
    except tomlkit.exceptions.TOMLKitError as exc:
        raise RigError(f"rig file {str(source)!r} is not valid TOML: {exc}") from None
    axes = doc.get("axis")
    names = list(axes) if isinstance(axes, Mapping) else []
    if not isinstance(axes, MutableMapping) or axis not in axes:
        raise RigError(
            f"no axis {show_value(axis)} in rig file {str(source)!r}; axes: {names}. "
            f"Choose one of these or add an [axis.{axis}] table first."
        )
    axis_table = axes[axis]
    if not isinstance(axis_table, MutableMapping):
        raise RigError(f"[axis.{axis}] in {str(source)!r} must be a table")
    if "plant" not in axis_table:
        axis_table["plant"] = tomlkit.table()
    table = axis_table["plant"]
    if not isinstance(table, MutableMapping):
        raise RigError(f"[axis.{axis}.plant] in {str(source)!r} must be a table")

    before = {k: _entry_text(table, k) for k in (*_FITTED_KEYS, *_DIRECTION_KEYS, *_KEPT_KEYS)}
    above = _comments_above(table)
    written = {key: _set_float(table, key, getattr(plant, key)) for key in _FITTED_KEYS}
    for key in _DIRECTION_KEYS:
        if getattr(plant, key) is not None:
            written[key] = _set_float(table, key, getattr(plant, key))
        elif key in table:
            del table[key]
    defaults = {f.name: f.default for f in fields(Plant)}
    for key in _KEPT_KEYS:
        value = getattr(plant, key)
        if value != defaults[key]:
            written[key] = _set_float(table, key, value)

    # a full-line comment directly above an entry that changed described the old value too
    for key, old_text in before.items():
        if _entry_text(table, key) != old_text:
            for comment in above.get(key, ()):
                if not _outlives_new_value(comment.trivia.comment):
                    _blank(comment)

    # the fit record (docs/decisions.md#6-the-fit-record) describes these values: written with them,
    # or removed (a record left from an earlier fit would describe other numbers); so do the
    # modes (docs/formats.md#modes): the plant's, or none
    if "fit" in table:
        del table["fit"]
    old_modes = table.get("modes")
    if old_modes is not None:
        del table["modes"]
    if plant.modes:
        inline = isinstance(table, tomlkit.items.InlineTable)
        table["modes"], written["modes"] = _modes_item(plant.modes, inline)
    elif isinstance(old_modes, tomlkit.items.AoT) and not table.as_string().endswith("\n\n"):
        table.add(tomlkit.nl())  # the blank line before the next table, which the modes held
    if fit is not None:
        table["fit"], written["fit"] = _fit_table(fit)
    if provenance is not None:
        line = _one_line(provenance)
        trivia = getattr(table, "trivia", None)
        if trivia is None:
            raise RigError(
                f"[axis.{axis}.plant] in {str(source)!r} is written with dotted keys "
                f"(plant.tau_s = ...), which leaves no header for the provenance comment; "
                f"write it as an [axis.{axis}.plant] table or pass provenance=None"
            )
        _set_comment(table, line)
    return doc.as_string(), written


def _entry_text(table: Any, key: str) -> str | None:
    """The TOML text of one entry of a table (None: no such entry)."""
    item = table.get(key)
    return item.as_string() if isinstance(item, tomlkit.items.Item) else None


def _comments_above(table: Any) -> dict[str, list[tomlkit.items.Comment]]:
    """Per key of a table, the full-line comments directly above it (no blank line between)."""
    body = getattr(getattr(table, "value", None), "body", None) or []
    out: dict[str, list[tomlkit.items.Comment]] = {}
    run: list[tomlkit.items.Comment] = []
    for key, item in body:
        if isinstance(item, tomlkit.items.Comment):
            run.append(item)
            continue
        if key is not None:
            out[key.key] = run
        run = []
    return out


def _blank(comment: tomlkit.items.Comment) -> None:
    """Remove a full-line comment from the text (the item stays, rendering as nothing)."""
    trivia = comment.trivia
    trivia.indent = trivia.comment_ws = trivia.comment = trivia.trail = ""


_STALE_COMMENT = re.compile(
    r"[ \t]+#[^\n\"']*\b(?:SPEC|seed \d{3}|docs/systems\.md)\b[^\n\"']*(?=\n|$)"
)


def _set_comment(table: Any, line: str) -> None:
    """Set (or, with ``""``, clear) the trailing comment of a table's header line."""
    trivia = table.trivia
    trivia.comment_ws = (trivia.comment_ws or "  ") if line else ""
    trivia.comment = f"# {line}" if line else ""


def new_rig_text(
    template_text: str, source: Path, *, name: str, header: str, fitted_axis: str
) -> str:
    """A new rig file's text from a template's: named ``name``, with ``header`` (lines) as its
    leading comment instead of the template's, the template's description replaced by one
    saying where it came from, and every plant but ``fitted_axis``'s marked as the template's
    model, not fitted (nothing in it reads as being about another machine).

    Raises
    ------
    RigError
        The template is not TOML or has no ``[rig]`` table.
    """
    lines = template_text.splitlines(keepends=True)
    k = 0
    while k < len(lines) and (lines[k].startswith("#") or not lines[k].strip()):
        k += 1
    head = "".join(f"# {ln}\n" if ln else "#\n" for ln in header.splitlines())
    # a trailing comment that cites the template machine's own description (the example rig's
    # docs/systems.md, or an older template's sources) does not describe this machine: dropped
    # (the key and its value stay)
    body = [_STALE_COMMENT.sub("", ln) for ln in lines[k:]]
    try:
        doc = tomlkit.parse(head + "\n" + "".join(body))
    except tomlkit.exceptions.TOMLKitError as exc:
        raise RigError(f"template rig file {str(source)!r} is not valid TOML: {exc}") from None
    rig = doc.get("rig")
    if not isinstance(rig, MutableMapping):
        raise RigError(f"template rig file {str(source)!r} has no [rig] table")
    rig["name"] = name
    rig["description"] = (
        f"made by servotune fit from the template {source.name}: check the hardware facts "
        "(timer, counter, D/A, encoder, limits) against this machine"
    )
    axes = doc.get("axis")
    for other, table in axes.items() if isinstance(axes, Mapping) else ():
        plant = table.get("plant") if isinstance(table, Mapping) else None
        if other != fitted_axis and getattr(plant, "trivia", None) is not None:
            _set_comment(
                plant,
                f"NOT FITTED: the template's model ({source.name}); fit this "
                f"axis's log with --axis {other} -o into this file",
            )
    return doc.as_string()


def edit_plant_text(
    path: str | Path,
    axis: str,
    plant: Plant,
    *,
    template: str | Path,
    provenance: str | None,
    fit: Mapping[str, Any] | None = None,
    new: Mapping[str, str] | None = None,
) -> tuple[str, dict[str, Any]]:
    """The text of the rig file ``path`` with its ``[axis.<axis>.plant]`` table rewritten.

    What :func:`servotune.rig.write_plant` writes, once it has checked that the text loads as a
    rig with the values written. ``path`` is read if it exists, else ``template``; only the
    entries of that one table change (see :func:`servotune.rig.write_plant` for what is written
    and how numbers are rounded).

    ``new``: for a file that does not exist yet, ``{"name": ..., "header": ...}`` make it a rig
    of its own (:func:`new_rig_text`); without it the template is copied as it is.

    Returns
    -------
    text : str
        The new text of the file.
    written : dict of str to float
        Each entry written, as the number it reads back as; ``"fit"``: the fit record as it
        reads back (:meth:`servotune.rig.PlantFit.to_dict`), when one was written; ``"modes"``:
        the modes as they read back (per mode a dict of its values and the intervals it has),
        when the plant has modes.

    Raises
    ------
    FileNotFoundError
        If the directory of ``path`` does not exist.
    RigError
        If the file or the template cannot be read or is not TOML, if ``axis`` is not in it, or
        if ``provenance`` is not one line.
    """
    target = Path(path)
    directory = target.parent
    if not directory.is_dir():
        raise FileNotFoundError(
            errno.ENOENT,
            f"cannot write rig file {str(target)!r}: its directory does not exist "
            f"(create it first)",
            str(directory),
        )
    source = target
    try:
        raw = target.read_bytes()
    except FileNotFoundError:
        source = Path(template)
        try:
            raw = source.read_bytes()
        except OSError as exc:
            raise RigError(
                f"cannot read template rig file {str(source)!r}: {exc.strerror or exc}"
            ) from None
    except OSError as exc:
        raise RigError(f"cannot read rig file {str(target)!r}: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise RigError(f"rig file {str(source)!r} is not valid TOML: {exc}") from None
    if source != target and new is not None:
        text = new_rig_text(text, source, name=new["name"], header=new["header"], fitted_axis=axis)
    return _plant_section(text, source, axis, plant, provenance, fit)
