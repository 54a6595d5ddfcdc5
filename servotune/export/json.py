"""The tables export (JSON): a tuning's runtime constants, with CRCs, for the target.

The document (``"schema": "servotune.tables/4"``) holds exactly the constants of the tuning
file, as the runtime runs them: nothing is re-quantised (verified = exported:
docs/runtime.md#fixed-point-constants). It is
JSON with sorted keys, two-space indent (the rows of a table and other lists of numbers on one
line each) and a trailing newline; the same tuning, rig and verification give the same bytes.
There is no timestamp anywhere::

    {
      "data": {
        "axes": [                      rig order; the C runtime's axis index
          {"index", "name", "role",
           "law": "none" | "pi" | "fuzzy_pid",
           "ref_source": -1 (external reference) or the index of the axis followed,
           "lock_gain": {"q", "f"},    [D/A LSB per count]
           "following_error_limit_counts": int (0 = off),
           "task": null
                 | {"kp", "ki_t"}                                    PI
                 | {"kp", "ki_t", "kd_t", "k1_t", "ke", "kec", "n",  fuzzy-PID + feedforward
                    "tables": {"kp"|"ki"|"kd"|"k1": {"n", "f", "q": rows, "crc32"}}},
           "filters": [                0 to 4 output filter sections, in series order
             {"b0", "b1", "b2", "a1", "a2": int32, "frac_bits": 1..30}, …
           ],                          ([] without filters; docs/runtime.md#filters-in-the-law)
           "shaper": [int, …]}         the task reference's input shaper: Q15 amplitudes, tick
                                       0 first, summing to 2^15 ([] without one;
                                       docs/runtime.md#shapers-in-the-tables)
        ],
        "c_layout_sha256": str,        SHA-256 of the bytes the C runtime compiles in
                                       (servotune.export.layout; the C header carries it)
        "constants_crc32": int,
        "counter_bits": int,
        "dac": {"bits", "code_max", "range_v", "zero_code"},
        "f_u": 32,                     fraction bits of the output u_q and the integrator
        "period_s": float,             achieved tick period [s] (folded into the constants)
        "rig_name": str,
        "timer_divisor": int
      },
      "provenance": {"rig": {"name", "path", "sha256"}, "spec_sha256", "tool",
                     "tool_version", "tuning", "tuning_sha256", "verification"},
      "schema": "servotune.tables/4",
      "sha256": str,                   the document's digest (below)
      "verified": true | false
    }

Every fixed-point constant is ``{"q": int, "f": int}``, value ``q · 2**-f``: gains ``Kp``,
``Ki·T``, ``Kd/T``, ``K1/T`` [LSB per count, per count per tick, per count change per tick],
scalings ``Ke`` [levels/count] and ``Kec`` [levels per count/tick]. A table holds int16
entries ``q`` with fraction bits ``f`` (value ``q · 2**-f``, in the units of its base gain),
rows ``E = −n … n``, columns ``EC = −n … n``. A filter section's coefficients are int32
mantissas with its one ``frac_bits`` (value ``q · 2**-frac_bits``), ``a0 = 1``
(:class:`servotune.laws.filters.SectionQ`); each must have a stable quantised denominator, and
its sums must stay within ±2^62 for inputs within the D/A range (checked on export and load).

Integrity (CRC-32 IEEE 802.3, as :func:`zlib.crc32`):

- each table's ``crc32`` covers, little-endian, int16 ``n``, int16 ``f``, then the int16
  entries row-major;
- ``constants_crc32`` covers every other constant as (q int32, f int16) pairs, little-endian;
  an integer is the pair ``(value, 0)``, a constant the law does not use ``(0, 0)``. Order::

      (n_axes, 0), (timer_divisor, 0), then for each axis in order:
      (law, 0), (lock_q, lock_f), (kp_q, kp_f), (kit_q, kit_f), (following_error_limit, 0),
      (counter_bits, 0), (dac_zero, 0), (dac_max, 0), (kdt_q, kdt_f), (k1t_q, k1t_f),
      (ke_q, ke_f), (kec_q, kec_f), (n, 0), (ref_source, 0), (n_filters, 0),
      then for each of the 4 filter section slots: (b0, frac_bits), (b1, frac_bits),
      (b2, frac_bits), (a1, frac_bits), (a2, frac_bits)   (an unused slot: (0, 0) × 5)

  that is, the runtime's constants vector (``servotune.laws.axis`` ``C_LAW`` … ``C_N``), the
  axis's reference source and its filters (``C_NF``, ``C_FILT``): 35 pairs per axis; ``law`` is
  0 none, 1 PI, 2 fuzzy-PID. The C runtime computes
  the same CRCs (``st_consts_crc32``, ``st_table_crc32`` in ``servotune_rt.c``).

The verification summary, hashes and tool version are provenance, kept apart from ``data`` and
outside every CRC. The document's ``sha256`` covers **everything else** (``data``, ``verified``
and ``provenance``): it is the SHA-256 of the document's canonical JSON without that field
(:mod:`servotune.digest`). :func:`load_tables` (and ``servotune check-table``) refuse a document
whose digest, C-layout digest or any CRC does not match, so editing any field, or one table
with its own CRC recomputed, is detected. ``/2`` added the digests, ``/3`` the filters (and
their pairs in the constants CRC and the C layout), ``/4`` the shapers (in the C layout, after
the tables, and under the document's digest; not in the constants CRC); a ``/1``, ``/2`` or
``/3`` file is refused with a request to export again. ``"verified": false`` marks an export
made without a passing verification (``unverified=True``, the CLI's ``--unverified``).
"""

from __future__ import annotations

import hashlib
import json
import zlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol, TypedDict, Unpack

import numpy as np

from servotune._version import __version__
from servotune.arch.gantry.tuning import GantryTuning
from servotune.arch.linkage.plan import LinkagePlan
from servotune.digest import DIGEST_FIELD, document_sha256
from servotune.errors import DigestError, ExportError
from servotune.export.document import document_text, recorded_sha, write_export
from servotune.export.gantry import gantry_document
from servotune.export.layout import (
    INT16,
    INT32,
    c_layout_sha256,
    constants_bytes,
    constants_pairs,
    pairs_bytes,
    table_bytes,
)
from servotune.export.linkage import linkage_plan_document
from servotune.fixed import F_U
from servotune.io.files import json_safe, parse_json, read_json
from servotune.laws.axis import (
    MAX_FILTERS,
    TASK_LAWS,
    AxisController,
    filter_overflow_problem,
    law_names,
    task_law,
)
from servotune.laws.filters import SectionQ
from servotune.laws.fuzzy_pid import int_rows
from servotune.laws.shaping import check_taps
from servotune.rig import Counter, Dac, Rig
from servotune.tuning import Tuning, tuning_to_string
from servotune.validate import check_keys, show_value

__all__ = [
    "SCHEMA",
    "Exportable",
    "Summary",
    "TablesOptions",
    "as_record",
    "check_tables",
    "constants_crc32",
    "controllers_from_tables",
    "export_document",
    "load_tables",
    "table_crc32",
    "tables_document",
    "to_file",
    "to_string",
]

SCHEMA = "servotune.tables/4"
_OLD_SCHEMAS = ("servotune.tables/1", "servotune.tables/2", "servotune.tables/3")


class Summary(Protocol):
    """A verification result that gives its summary as a plain dict
    (:class:`servotune.verify.Verification`)."""

    def to_dict(self) -> dict[str, Any]: ...


# --- CRCs ------------------------------------------------------------------------------------


def table_crc32(q: np.ndarray | Sequence[Sequence[int]], f: int) -> int:
    """CRC-32 of one query table (docs/runtime.md#integrity-crcs-and-the-c-layout): ``zlib.crc32``
    of :func:`~.layout.table_bytes`.

    Parameters
    ----------
    q, f
        The table's entries and fraction bits, as :func:`~.layout.table_bytes` takes them.

    Returns
    -------
    int
        ``zlib.crc32`` of int16 ``n``, int16 ``f`` and the entries row-major, little-endian.

    Examples
    --------
    >>> hex(table_crc32([[0, 1, 2], [3, 4, 5], [6, 7, -8]], 3))
    '0xd3d2eea4'
    """
    return zlib.crc32(table_bytes(q, f))


def constants_crc32(tuning: Tuning, *, rig: Rig | None = None) -> int:
    """The constants CRC of a tuning's export (order in the module docstring).

    Parameters
    ----------
    tuning : Tuning
    rig : Rig, optional
        The rig the tuning runs on (counter and D/A facts); default the example rig's hardware
        (24-bit counter, 12-bit ±10 V D/A).

    Returns
    -------
    int
    """
    hw = _hardware(tuning, rig)
    dac = hw["dac"]
    pairs = constants_pairs(
        tuning.controllers,
        _ref_sources(tuning.roles),
        timer_divisor=tuning.timer_divisor,
        counter_bits=hw["counter_bits"],
        dac_bits=dac["bits"],
        dac_zero=dac["zero_code"],
    )
    return zlib.crc32(pairs_bytes(pairs))


# --- building the document -------------------------------------------------------------------


def _ref_sources(roles: Sequence[str]) -> list[int]:
    """Per axis −1 (external reference) or the master's index: the engine's default Loop."""
    master = next((i for i, r in enumerate(roles) if r == "master"), -1)
    return [-1 if (r == "master" or master < 0) else master for r in roles]


def _hardware(tuning: Tuning, rig: Rig | None) -> dict[str, Any]:
    if rig is not None:
        try:
            tuning.check_rig(rig)
        except ValueError as exc:
            raise ExportError(str(exc)) from None
        counter, dac = rig.counter, rig.dac
    else:
        counter, dac = Counter(), Dac()
    return {
        "counter_bits": int(counter.bits),
        "dac": {
            "bits": int(dac.bits),
            "code_max": int(dac.code_max),
            "range_v": [float(dac.range_v[0]), float(dac.range_v[1])],
            "zero_code": int(dac.zero_code),
        },
    }


def _plain(x: Any, where: str) -> Any:
    """JSON-safe copy of a summary (:func:`servotune.io.files.json_safe`), as an ExportError."""
    try:
        return json_safe(x)
    except TypeError as exc:
        raise ExportError(f"{where}: {exc} in the export") from None


def _axis_doc(
    i: int, name: str, role: str, ctl: AxisController, src: int, dac: Mapping[str, Any]
) -> dict[str, Any]:
    fe = ctl.following_error_limit_counts
    if fe > INT32[1]:
        raise ExportError(
            f"axis {name!r}: following_error_limit_counts {fe} does not fit int32 [counts]"
        )
    problem = filter_overflow_problem(ctl.filters, dac["zero_code"], dac["code_max"])
    if problem is not None:
        raise ExportError(f"axis {name!r}: {problem}")
    d = ctl.to_dict()
    task = d["task"]
    tables = () if ctl.task is None else task_law(ctl.task).tables
    if tables:
        n = ctl.task.n  # type: ignore[union-attr]
        task["tables"] = {
            t: {"crc32": table_crc32(q, f_t), "f": int(f_t), "n": n, "q": q.astype(int).tolist()}
            for t, (q, f_t) in zip(tables, ctl.task.tables, strict=True)  # type: ignore[union-attr]
        }
    return {
        "filters": [s.to_dict() for s in ctl.filters],
        "following_error_limit_counts": int(fe),
        "index": i,
        "law": d["law"],
        "lock_gain": d["lock_gain"],
        "name": name,
        "ref_source": src,
        "role": role,
        "shaper": list(ctl.shaper),
        "task": task,
    }


class TablesOptions(TypedDict, total=False):
    """The keywords of :func:`tables_document`, which every export passes on to the document
    it renders (:func:`export_document`, :func:`to_string`, :func:`to_file`,
    :func:`servotune.export.c.to_string`, :func:`servotune.export.c.to_file`, …): ``rig``,
    ``verification`` and ``unverified``."""

    rig: Rig | None
    verification: Mapping[str, Any] | Summary | None
    unverified: bool


def tables_document(
    tuning: Tuning,
    *,
    rig: Rig | None = None,
    verification: Mapping[str, Any] | Summary | None = None,
    unverified: bool = False,
) -> dict[str, Any]:
    """The export as a plain dict (what :func:`to_string` serialises).

    Parameters
    ----------
    tuning : Tuning
        The tuning to export; its constants are copied, never re-quantised.
    rig : Rig, optional
        The rig (checked against the tuning) giving the counter width and the D/A coding;
        default the example rig's hardware (24-bit counter, 12-bit ±10 V D/A).
    verification : mapping or Verification, optional
        The verification summary (a :class:`servotune.verify.Verification` or its
        ``to_dict()``); it goes into the provenance whole. A key ``"passed"`` that is false
        fails the export unless ``unverified``. The provenance's ``spec_sha256`` is the
        summary's ``"spec_sha256"`` if it has one, else the SHA-256 of its ``"spec"`` as
        canonical JSON (sorted keys, no spaces), else null. The provenance's ``tuning_sha256``
        is the record's (``files.tuning.sha256``: the bytes verified) if it has one, else the
        SHA-256 of the tuning's own serialisation (:func:`tuning_to_string`).
    unverified : bool
        Export without a (passing) verification; the document is marked ``"verified": false``.

    Returns
    -------
    dict
        With its digests (``data.c_layout_sha256`` and the document's ``sha256``) filled in.

    Raises
    ------
    ExportError
        No verification (and not ``unverified``), a failed verification, a rig that does not
        match the tuning, or a constant that does not fit the runtime's types.
    """
    verification = as_record(verification)
    if not unverified:
        if verification is None:
            raise ExportError(
                "no verification summary: verify the tuning first, or export it marked "
                "unverified (unverified=True, --unverified)"
            )
        passed = verification.get("passed", True)
        if passed is not None and not bool(passed):
            raise ExportError(
                "the verification failed: fix the tuning, or export it marked unverified "
                "(unverified=True, --unverified)"
            )
    hw = _hardware(tuning, rig)
    refs = _ref_sources(tuning.roles)
    axes = [
        _axis_doc(i, name, role, ctl, src, hw["dac"])
        for i, (name, role, ctl, src) in enumerate(
            zip(tuning.axis_names, tuning.roles, tuning.controllers, refs, strict=True)
        )
    ]
    crc = constants_crc32(tuning, rig=rig)
    summary = None if verification is None else _plain(verification, "verification")
    spec_sha = tuning_sha = None
    if summary is not None:
        spec_sha = summary.get("spec_sha256") or recorded_sha(summary, "spec")
        if spec_sha is None and summary.get("spec") is not None:
            canon = json.dumps(summary["spec"], sort_keys=True, separators=(",", ":"))
            spec_sha = hashlib.sha256(canon.encode()).hexdigest()
        tuning_sha = recorded_sha(summary, "tuning")
    if tuning_sha is None:
        tuning_sha = hashlib.sha256(tuning_to_string(tuning).encode()).hexdigest()
    doc: dict[str, Any] = {
        "data": {
            "axes": axes,
            "constants_crc32": crc,
            "counter_bits": hw["counter_bits"],
            "dac": hw["dac"],
            "f_u": F_U,
            "period_s": float(tuning.period_s),
            "rig_name": tuning.rig_name,
            "timer_divisor": int(tuning.timer_divisor),
        },
        "provenance": {
            "rig": {"name": tuning.rig_name, "path": tuning.rig_path, "sha256": tuning.rig_sha256},
            "spec_sha256": spec_sha,
            "tool": "servotune",
            "tool_version": __version__,
            "tuning": _plain(tuning.provenance, "tuning provenance"),
            "tuning_sha256": tuning_sha,
            "verification": summary,
        },
        "schema": SCHEMA,
        "verified": not unverified,
    }
    doc["data"]["c_layout_sha256"] = c_layout_sha256(doc["data"])
    doc[DIGEST_FIELD] = document_sha256(doc)
    return doc


Exportable = Tuning | GantryTuning | LinkagePlan
"""What an export format renders: a rig's tuning, a gantry tuning or a linkage plan (the
document kinds ``rig``, ``gantry`` and ``linkage`` of :data:`servotune.export.formats.KINDS`)."""


def as_record(verification: Mapping[str, Any] | Summary | None) -> Mapping[str, Any] | None:
    """A verification as the plain mapping a document reads (a summary's ``to_dict()``)."""
    if verification is None or isinstance(verification, Mapping):
        return verification
    return verification.to_dict()


def export_document(obj: Exportable, **options: Unpack[TablesOptions]) -> dict[str, Any]:
    """The JSON document of ``obj``, by what it is.

    - a :class:`~servotune.tuning.Tuning`: the tables (:func:`tables_document`, this module's
      docstring);
    - a :class:`~servotune.arch.gantry.tuning.GantryTuning`: the gantry tables
      (:func:`servotune.export.gantry.gantry_document`); ``rig`` is the gantry's rig (needed);
    - a :class:`~servotune.arch.linkage.plan.LinkagePlan`: the linkage export
      (:func:`servotune.export.linkage.linkage_plan_document`); ``rig`` is not used (the plan
      binds its rig by its hash).

    ``verification`` is the checked verification record (or summary) and ``unverified``
    exports without one, marked ``"verified": false``.

    Raises
    ------
    ExportError
        As the document's function: no verification (and not ``unverified``), a failed one, …
    """
    unverified = options.get("unverified", False)
    if isinstance(obj, GantryTuning):
        rig = options.get("rig")
        if rig is None:
            raise ExportError("a gantry tuning's export needs its rig (rig=, the gantry config's)")
        record = as_record(options.get("verification"))
        return gantry_document(obj, rig, record=record, unverified=unverified)
    if isinstance(obj, LinkagePlan):
        record = as_record(options.get("verification"))
        return linkage_plan_document(obj, record, unverified=unverified)
    return tables_document(obj, **options)


def to_string(obj: Exportable, **options: Unpack[TablesOptions]) -> str:
    """The JSON export of ``obj`` (:func:`export_document`) as text: sorted keys, two-space
    indent, lists of numbers on one line, a final newline; deterministic bytes.

    Examples
    --------
    >>> text = to_string(tuning, verification=summary)  # doctest: +SKIP
    >>> load_tables(text)["schema"]  # doctest: +SKIP
    'servotune.tables/3'
    """
    return document_text(export_document(obj, **options))


def to_file(obj: Exportable, path: str | Path, **options: Unpack[TablesOptions]) -> None:
    """Write :func:`to_string` to ``path`` atomically (temp file, then rename).

    Raises
    ------
    ExportError
        As :func:`export_document`, or if the file cannot be written (nothing is written then).
    """
    write_export(path, to_string(obj, **options))


# --- reading it back -------------------------------------------------------------------------


def _is_int(x: Any) -> bool:
    return type(x) is int


def _need(d: Any, key: str, where: str) -> Any:
    if not isinstance(d, dict):
        raise ExportError(f"{where} must be a JSON object")
    if key not in d:
        raise ExportError(f"{where} is missing the field {key!r}")
    return d[key]


def _need_int(d: Any, key: str, where: str) -> int:
    v = _need(d, key, where)
    if not _is_int(v):
        raise ExportError(f"{where}.{key} must be an integer, got {show_value(v)}")
    return v


def _check_table(tab: Any, name: str, n: int, where: str) -> None:
    w = f"{where} table {name}"
    if _need_int(tab, "n", w) != n:
        raise ExportError(f"{w}: n must be {n} (the axis's levels), got {tab['n']}")
    f = _need_int(tab, "f", w)
    stored = _need_int(tab, "crc32", w)
    check_keys(tab, w, ("crc32", "f", "n", "q"), error=ExportError)
    try:
        rows = int_rows(tab["q"], 2 * n + 1, f"{w}: q")
    except ValueError as exc:
        raise ExportError(str(exc)) from None
    if not INT16[0] <= f <= INT16[1]:
        raise ExportError(f"{w}: f = {f} is outside int16")
    computed = table_crc32(rows, f)
    if computed != stored:
        raise DigestError(
            f"{w}: CRC mismatch (stored 0x{stored:08x}, computed 0x{computed:08x}); "
            "the table was changed or damaged"
        )


def _filters(ax: Any, where: str) -> list[dict[str, int]]:
    """An axis's ``filters``, checked: a list of at most 4 sections, each with exactly its six
    integers in range and a stable denominator (:meth:`~servotune.laws.filters.SectionQ.
    from_dict`)."""
    filters = _need(ax, "filters", where)
    if not isinstance(filters, list) or len(filters) > MAX_FILTERS:
        raise ExportError(
            f"{where}.filters must be a list of at most {MAX_FILTERS} sections, "
            f"got {show_value(filters)}"
        )
    for k, sec in enumerate(filters):
        try:
            SectionQ.from_dict(sec, f"{where}.filters[{k}]")
        except ValueError as exc:
            raise ExportError(str(exc)) from None
    return filters


def _controller(ax: Any, where: str) -> AxisController:
    check_keys(
        ax,
        where,
        (
            "filters",
            "following_error_limit_counts",
            "index",
            "law",
            "lock_gain",
            "name",
            "ref_source",
            "role",
            "shaper",
            "task",
        ),
        error=ExportError,
    )
    task = _need(ax, "task", where)
    law = _need(ax, "law", where)
    if law not in law_names():
        raise ExportError(
            f"{where}.law must be one of {', '.join(law_names())}, got {show_value(law)}"
        )
    tables = TASK_LAWS[law].tables if law in TASK_LAWS else ()
    if tables:
        n = _need_int(task, "n", f"{where}.task")
        tabs = _need(task, "tables", f"{where}.task")
        for t in tables:
            _check_table(_need(tabs, t, f"{where}.task.tables"), t, n, where)
        task = dict(task)
        task["tables"] = {t: {"f": tabs[t]["f"], "q": tabs[t]["q"]} for t in tables}
    d = {
        "following_error_limit_counts": _need(ax, "following_error_limit_counts", where),
        "law": law,
        "lock_gain": _need(ax, "lock_gain", where),
        "task": task,
    }
    if filters := _filters(ax, where):
        d["filters"] = filters
    shaper = _need(ax, "shaper", where)
    if shaper != []:
        try:
            d["shaper"] = list(check_taps(shaper, f"{where}.shaper"))
        except ValueError as exc:
            raise ExportError(str(exc)) from None
    try:
        return AxisController.from_dict(d)
    except (ValueError, KeyError, TypeError) as exc:
        raise ExportError(f"{where}: {exc}") from None


def _check_digests(doc: dict[str, Any]) -> None:
    stored = doc.get(DIGEST_FIELD)
    try:
        computed = document_sha256(doc)
    except (TypeError, ValueError):
        computed = None
    if stored != computed:
        raise DigestError(
            "the document's sha256 does not match its content: a field was edited after export "
            "(export the tuning again)"
        )
    data = doc.get("data")
    if not isinstance(data, dict) or not isinstance(data.get("c_layout_sha256"), str):
        raise ExportError("data.c_layout_sha256 must be the C layout's SHA-256 (hex)")
    try:
        c_sha = c_layout_sha256(data)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise ExportError(f"data: cannot lay out the constants for C: {exc}") from None
    if c_sha != data["c_layout_sha256"]:
        raise DigestError("data.c_layout_sha256 does not match the constants and tables")


def _check_document(doc: Any) -> tuple[AxisController, ...]:
    if not isinstance(doc, dict):
        raise ExportError("a tables export must hold a JSON object")
    schema = doc.get("schema")
    if schema in _OLD_SCHEMAS:
        raise ExportError(f"{schema} was written by an older servotune; export the tuning again")
    if schema != SCHEMA:
        raise ExportError(f"schema must be {SCHEMA!r}, got {str(schema)[:60]!r}")
    check_keys(
        doc,
        "document",
        ("data", DIGEST_FIELD, "provenance", "schema", "verified"),
        error=ExportError,
    )
    if not isinstance(doc["verified"], bool):
        raise ExportError("verified must be true or false")
    data = check_keys(
        doc["data"],
        "data",
        (
            "axes",
            "c_layout_sha256",
            "constants_crc32",
            "counter_bits",
            "dac",
            "f_u",
            "period_s",
            "rig_name",
            "timer_divisor",
        ),
        error=ExportError,
    )
    axes = _need(data, "axes", "data")
    if not isinstance(axes, list) or not axes:
        raise ExportError("data.axes must be a non-empty list")
    bits = _need_int(data, "counter_bits", "data")
    if bits not in (16, 24, 32):
        raise ExportError(f"data.counter_bits must be 16, 24 or 32, got {show_value(bits)}")
    dac = check_keys(
        _need(data, "dac", "data"),
        "data.dac",
        ("bits", "code_max", "range_v", "zero_code"),
        error=ExportError,
    )
    dac_bits = _need_int(dac, "bits", "data.dac")
    if not 1 <= dac_bits <= 16:
        raise ExportError(f"data.dac.bits must be an integer in 1..16 [bits], got {dac_bits}")
    _need_int(dac, "zero_code", "data.dac")
    if _need_int(dac, "code_max", "data.dac") != 2**dac_bits - 1:
        raise ExportError(f"data.dac.code_max must be 2**bits - 1 = {2**dac_bits - 1}")
    if _need_int(data, "f_u", "data") != F_U:
        raise ExportError(f"data.f_u must be {F_U}, got {data['f_u']}")
    _need_int(data, "timer_divisor", "data")
    period = _need(data, "period_s", "data")
    if not isinstance(period, float) or not period > 0:
        raise ExportError(f"data.period_s must be a number > 0 [s], got {show_value(period)}")
    stored = _need_int(data, "constants_crc32", "data")
    ctls = []
    refs = []
    for i, ax in enumerate(axes):
        where = f"axes[{i}]"
        if isinstance(ax, dict) and isinstance(ax.get("name"), str):
            where = f"axes[{i}] ({ax['name']})"
        src = _need_int(ax, "ref_source", where)
        if src != -1 and not (0 <= src < len(axes) and src != i):
            raise ExportError(f"{where}.ref_source must be -1 or another axis's index, got {src}")
        refs.append(src)
        ctls.append(_controller(ax, where))
        problem = filter_overflow_problem(ctls[-1].filters, dac["zero_code"], dac["code_max"])
        if problem is not None:
            raise ExportError(f"{where}.{problem}")
    computed = zlib.crc32(constants_bytes(data))  # from the fields checked above
    if computed != stored:
        raise DigestError(
            f"data.constants_crc32: CRC mismatch (stored 0x{stored:08x}, computed "
            f"0x{computed:08x}); a constant was changed or damaged"
        )
    _check_digests(doc)
    return tuple(ctls)


def check_tables(doc: Any) -> tuple[AxisController, ...]:
    """Check a parsed tables export: schema, exact keys and types, ranges, every table CRC,
    the constants CRC, the C-layout digest and the document's digest.

    Returns
    -------
    tuple of AxisController
        The runtime constants per axis.

    Raises
    ------
    ExportError
        One line naming the field or table that is wrong; a :class:`~servotune.errors.DigestError`
        (also a :class:`~servotune.errors.TrustError`) when the document is well-formed but a
        CRC or digest does not match its content.
    """
    return _check_document(doc)


def load_tables(path_or_text: str | Path) -> dict[str, Any]:
    """Read a tables export and check it (:func:`check_tables`): any edit is refused.

    Parameters
    ----------
    path_or_text : str or Path
        A file path, or the JSON text itself (a string starting with ``{``).

    Returns
    -------
    dict
        The document as loaded.

    Raises
    ------
    ExportError
        One line naming the file, table or field: unreadable or not JSON, wrong schema, a
        missing, unknown or malformed field, an entry outside int16, a CRC or digest mismatch.
    """
    if isinstance(path_or_text, str) and path_or_text.lstrip().startswith("{"):
        src = "tables export"
        doc = parse_json(path_or_text, src, ExportError)
    else:
        src = str(path_or_text)
        doc = read_json(path_or_text, ExportError)
    try:
        _check_document(doc)
    except ExportError as exc:
        raise type(exc)(f"{src}: {exc}") from None
    return doc


def controllers_from_tables(doc: Mapping[str, Any]) -> tuple[AxisController, ...]:
    """The runtime constants of a tables export, per axis (checked as by :func:`load_tables`).

    With the tuning's controllers these compare equal: the export holds them exactly.
    """
    return _check_document(doc)
