"""The linkage export: a plan's constants for the slave CPUs, as C and as JSON.

The ``c`` export format (:func:`servotune.export.c.to_file` of a plan) writes into a directory:

- ``servotune_link_plan.h``: the plan's constants (:func:`linkage_c_header`): the bus's block
  format and bit budget, the resync interval in ticks, per slave CPU its axes (their columns
  in a block row), queue depth and watermarks with an ``stl_consts_t`` initialiser, and per
  axis its quantised PI constants (``q``, ``f`` pairs: value ``q·2^-f``) as the runtime runs
  them (``servotune_rt.h``, task mode);
- ``servotune_link.c`` / ``servotune_link.h``: the slave CPU's receive queue and clock-sync
  logic (C99, integer only, no I/O, no allocation), copied from the package data. It is the
  simulation's queue model line by line: the simulation's event log replayed through it gives
  the same commands, levels and counts, bit for bit;
- ``servotune_rt.c`` / ``servotune_rt.h``: the axis runtime the position loops run.

Usage on slave CPU ``s1``::

    #include "servotune_link_plan.h"
    static const stl_consts_t consts = STL_CPU_S1_CONSTS_INIT;
    static stl_state_t queue;                 /* stl_init(&queue) at power-up */

The ``json`` format (:func:`servotune.export.json.to_string` of a plan) writes the same plan as
a JSON document (:func:`linkage_plan_document`, ``servotune.linkage-export/1``) with the
provenance (the SHA-256 of the plan, config, rig and spec verified, the verification
summary) and its own digest (:func:`servotune.digest.document_sha256`, field ``sha256``).

An export needs a passing verification record (:func:`~servotune.arch.linkage.
load_plan_for_export` checks it against the files), unless it is marked unverified. The bytes
are deterministic; every file is rendered in memory, then written atomically.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from typing import Any

from servotune._version import __version__
from servotune.arch.linkage.plan import PLAN_SCHEMA, LinkagePlan, plan_to_string
from servotune.digest import DIGEST_FIELD, document_sha256
from servotune.errors import DigestError, ExportError
from servotune.export.c_text import c_identifiers, comment_text, filter_lines
from servotune.export.document import recorded_sha
from servotune.io.files import json_safe, parse_json
from servotune.laws.pi import PIConstants

__all__ = [
    "EXPORT_SCHEMA",
    "LINK_HEADER_NAME",
    "check_linkage_export",
    "linkage_c_header",
    "linkage_plan_document",
]

EXPORT_SCHEMA = "servotune.linkage-export/1"
"""Version tag of :func:`linkage_plan_document`'s document."""
LINK_HEADER_NAME = "servotune_link_plan.h"

_INT32_MAX = 2**31 - 1


def _check_record(record: Mapping[str, Any] | None, unverified: bool) -> None:
    if unverified:
        return
    if record is None:
        raise ExportError(
            "no verification record: verify the plan first, or export it marked unverified "
            "(unverified=True, --unverified)"
        )
    if record.get("passed") is not True:
        raise ExportError(
            "the plan failed its verification: fix it, or export it marked unverified "
            "(unverified=True, --unverified)"
        )


def _file_sha(record: Mapping[str, Any] | None, kind: str) -> str | None:
    """The record's SHA-256 of its ``kind`` file, or None (no record, or none held)."""
    return None if record is None else recorded_sha(record, kind)


def _plan_sha(plan: LinkagePlan, record: Mapping[str, Any] | None) -> str:
    """The record's SHA-256 of the plan file (the bytes verified), else of its serialisation."""
    return (
        _file_sha(record, "plan")
        or hashlib.sha256(plan_to_string(plan).encode("utf-8")).hexdigest()
    )


def _check_fits(plan: LinkagePlan) -> None:
    lo, hi = plan.path.command_min_counts, plan.path.command_max_counts
    if lo < -_INT32_MAX or hi > _INT32_MAX:
        raise ExportError(
            f"the path's commands span {lo}..{hi} counts; the C queue holds int32 setpoints"
        )


def linkage_plan_document(
    plan: LinkagePlan, record: Mapping[str, Any] | None, *, unverified: bool = False
) -> dict[str, Any]:
    """The JSON export as a plain dict (what :func:`servotune.export.json.to_string` of a plan
    serialises).

    ``data`` is the plan exactly as its file holds it; ``provenance`` the SHA-256 of the plan
    (the record's, i.e. the bytes verified, else of the plan's own serialisation), config, rig
    and spec, the tool and the verification summary; ``verified`` is true with a passing
    record; ``sha256`` the document's digest over everything else.

    Raises
    ------
    ExportError
        No record (and not ``unverified``), or a failed one.
    """
    _check_record(record, unverified)
    summary = None if record is None else json_safe(record.get("summary"))
    doc: dict[str, Any] = {
        "data": plan.to_dict(),
        "provenance": {
            "config_sha256": plan.config_sha256,
            "plan_sha256": _plan_sha(plan, record),
            "rig_sha256": plan.rig_sha256,
            "spec_sha256": _file_sha(record, "spec"),
            "tool": "servotune",
            "tool_version": __version__,
            "verification": summary,
        },
        "schema": EXPORT_SCHEMA,
        "verified": record is not None and record.get("passed") is True and not unverified,
    }
    doc[DIGEST_FIELD] = document_sha256(doc)
    return doc


def check_linkage_export(text: str, src: str = "<text>") -> dict[str, Any]:
    """Parse a linkage JSON export (:func:`linkage_plan_document`) and check its digest, computed
    as the writer does (:func:`servotune.digest.document_sha256`): any edit is refused.

    Returns
    -------
    dict
        The document.

    Raises
    ------
    DigestError
        The digest does not match (the document was edited).
    ExportError
        Not a linkage export.
    """
    doc = parse_json(text, src, ExportError)
    if not isinstance(doc, dict) or doc.get("schema") != EXPORT_SCHEMA:
        raise ExportError(f"{src}: not a linkage export ({EXPORT_SCHEMA})")
    try:
        computed = document_sha256(doc)
    except (TypeError, ValueError):
        computed = None
    if doc.get(DIGEST_FIELD) != computed:
        raise DigestError(
            f"{src}: the document's sha256 does not match its content: a field "
            "was edited after export (export the plan again)"
        )
    if not isinstance(doc.get("data"), dict) or not isinstance(doc.get("verified"), bool):
        raise ExportError(f"{src}: a linkage export holds an object 'data' and a bool 'verified'")
    return doc


def linkage_c_header(
    plan: LinkagePlan, record: Mapping[str, Any] | None, *, unverified: bool = False
) -> str:
    """The text of ``servotune_link_plan.h``: the plan's constants for the slave CPUs.

    Raises
    ------
    ExportError
        No record (and not ``unverified``), a failed one, names that give clashing C
        identifiers, or commands that do not fit int32.
    """
    _check_record(record, unverified)
    _check_fits(plan)
    verified = record is not None and record.get("passed") is True and not unverified
    cpu_ids = c_identifiers(tuple(c.name for c in plan.cpus), "cpu", "N_", upper=True)
    axis_ids = c_identifiers(plan.axis_names, "axis", "N_", upper=True)
    out = [
        *_header_top(plan, record, verified),
        *_bus_and_clock_lines(plan),
        *_axis_lines(plan, axis_ids, cpu_ids),
        *_cpu_lines(plan, cpu_ids, axis_ids),
    ]
    macros = [line.split()[1] for line in out if line.startswith("#define ")]
    clash = sorted({m for m in macros if macros.count(m) > 1})
    if clash:
        raise ExportError(f"axis and cpu names give clashing C macros {clash}; rename them")
    out += ["", "#endif /* SERVOTUNE_LINK_PLAN_H */", ""]
    return "\n".join(out)


def _header_top(plan: LinkagePlan, record: Mapping[str, Any] | None, verified: bool) -> list[str]:
    """The header's opening comment (provenance, block layout, PI units), include guard,
    includes and the plan's identity and size."""
    spec_sha = _file_sha(record, "spec")
    return [
        f"/* {LINK_HEADER_NAME} -- generated by servotune {__version__} ({PLAN_SCHEMA}).",
        " * Do not edit: plan, verify and export again. The queue and clock-sync code is",
        " * servotune_link.c / servotune_link.h; the position loops are servotune_rt.c.",
        f" * config: {comment_text(plan.config_name)} (sha256 {plan.config_sha256})",
        f" * rig: {comment_text(plan.rig_name)} (sha256 {plan.rig_sha256})",
        f" * plan sha256: {_plan_sha(plan, record)}",
        " * verified: "
        + ("yes" if verified else "NO -- exported unverified; verify before running a machine"),
        *([f" * spec sha256: {spec_sha}"] if spec_sha else []),
        " *",
        " * A block frame carries block_size ticks of commands for every axis: row r is tick",
        " * block_index * STL_BLOCK_SIZE + r, column c axis c (STL_AXIS_<AXIS>). A slave CPU",
        " * queues its own columns (STL_CPU_<CPU>_COLUMNS, in its axis order) with stl_push.",
        " * PI constants are (q, f) pairs, value q * 2^-f: Kp [D/A LSB per count], Ki*T [LSB per",
        " * count per tick], the lock gain [LSB per count]: the st_axis_consts_t fields of the",
        " * same names (servotune_rt.h, task mode). An axis's output filters: <AXIS>_N_FILTERS",
        " * and per section k <AXIS>_FILT<k>_B0 .. _A2, _FRAC_BITS (st_axis_consts_t's n_filters",
        " * and filter[k]; the slots past the last section zero).",
        " */",
        "#ifndef SERVOTUNE_LINK_PLAN_H",
        "#define SERVOTUNE_LINK_PLAN_H",
        "",
        "#include <stdint.h>",
        "",
        '#include "servotune_link.h"',
        "",
        f'#define STL_PLAN_SCHEMA "{PLAN_SCHEMA}"',
        f"#define STL_PLAN_VERIFIED {1 if verified else 0}",
        f'#define STL_PLAN_SHA256 "{_plan_sha(plan, record)}"',
        f"#define STL_PERIOD_S {plan.period_s!r} /* nominal tick of every CPU [s] */",
        f"#define STL_N_AXES {plan.n_axes} /* columns of a block row */",
        f"#define STL_N_CPUS {len(plan.cpus)}",
    ]


def _bus_and_clock_lines(plan: LinkagePlan) -> list[str]:
    """The bus's block format and bit budget, the resync interval and the queue depth the C
    queue must be compiled for."""
    bus = plan.bus
    return [
        "",
        "/* the bus: block format and bit budget (8N1: 10 bits per byte) */",
        f"#define STL_BLOCK_SIZE {bus.block_size} /* ticks (setpoints per axis) per block */",
        f"#define STL_PREFILL_BLOCKS {bus.prefill_blocks} /* blocks sent before motion */",
        f"#define STL_BYTES_PER_SETPOINT {bus.bytes_per_setpoint} /* [bytes] */",
        f"#define STL_FRAME_OVERHEAD_BYTES {bus.frame_overhead_bytes} /* header, index, CRC */",
        f"#define STL_FRAME_BYTES {plan.frame_bytes} /* [bytes] */",
        f"#define STL_BITS_PER_BYTE {bus.bits_per_byte}",
        f"#define STL_BITS_PER_BLOCK {plan.bits_per_block} /* [bits] */",
        f"#define STL_BAUD {float(bus.baud)!r} /* [bits/s] */",
        f"#define STL_UTILISATION_PCT {plan.utilisation * 100:.3f} /* frame / broadcast period */",
        "",
        "/* clock sync: master ticks between sync broadcasts (0: only the one at motion start) */",
        f"#define STL_RESYNC_TICKS {plan.resync_ticks}",
        f"#define STL_MAX_DRIFT_TICKS {plan.max_drift_ticks:.6f} /* between syncs, worst CPU */",
        "",
        f"#if STL_MAX_DEPTH < {max(c.queue_depth for c in plan.cpus)}",
        f'#error "compile servotune_link.c and this file with -DSTL_MAX_DEPTH='
        f'{max(c.queue_depth for c in plan.cpus)}"',
        "#endif",
    ]


def _axis_lines(plan: LinkagePlan, axis_ids: Sequence[str], cpu_ids: Sequence[str]) -> list[str]:
    """Per axis: its column in a block row, its CPU and the PI and lock constants it runs."""
    out = ["", "/* axes: their column in a block row, their CPU, the constants their loop runs */"]
    for i, (name, ident, ctl) in enumerate(
        zip(plan.axis_names, axis_ids, plan.controllers, strict=True)
    ):
        task = ctl.task
        if not isinstance(task, PIConstants):  # LinkagePlan holds PI controllers only
            raise ExportError(f"axis {name!r}: a linkage axis runs PI")
        cpu = plan.cpu_of(name)
        up = f"STL_AXIS_{ident}"
        out += [
            f"/* axis {comment_text(name)}, on cpu {comment_text(cpu.name)} */",
            f"#define {up} {i}",
            f"#define {up}_CPU STL_CPU_{cpu_ids[plan.cpus.index(cpu)]}",
            f"#define {up}_LOCK_Q INT32_C({ctl.lock_gain.q})",
            f"#define {up}_LOCK_F {ctl.lock_gain.f}",
            f"#define {up}_KP_Q INT32_C({task.kp.q})",
            f"#define {up}_KP_F {task.kp.f}",
            f"#define {up}_KIT_Q INT32_C({task.ki_t.q})",
            f"#define {up}_KIT_F {task.ki_t.f}",
            f"#define {up}_FE_LIMIT {ctl.following_error_limit_counts} /* [counts], 0 = off */",
            *filter_lines([s.to_dict() for s in ctl.filters], up)[0],
        ]
    return out


def _cpu_lines(plan: LinkagePlan, cpu_ids: Sequence[str], axis_ids: Sequence[str]) -> list[str]:
    """Per slave CPU: its axes' columns, queue depth and watermarks, and the ``stl_consts_t``
    initialiser its queue is set up with."""
    out: list[str] = []
    for s, (c, ident) in enumerate(zip(plan.cpus, cpu_ids, strict=True)):
        up = f"STL_CPU_{ident}"
        cols = ", ".join(f"STL_AXIS_{axis_ids[plan.axis_names.index(a)]}" for a in c.axes)
        out += [
            "",
            f"/* cpu {s}: {comment_text(c.name)} (clock {c.clock_ppm:+g} ppm as configured; "
            f"{plan.drift_ticks(c):.4f} ticks of drift between syncs),",
            f" * axes {comment_text(', '.join(c.axes))}; COLUMNS: the block-row column of each */",
            f"#define {up} {s}",
            f"#define {up}_N_AXES {len(c.axes)}",
            f"#define {up}_COLUMNS {{{cols}}}",
            f"#define {up}_QUEUE_DEPTH {c.queue_depth} /* [setpoints per axis] */",
            f"#define {up}_LOW_WATERMARK {c.low_watermark} /* STL_LOW below it before a pop */",
            f"#define {up}_HIGH_WATERMARK {c.high_watermark} /* STL_HIGH above it after a block */",
            f"/* static const stl_consts_t consts = {up}_CONSTS_INIT; */",
            f"#define {up}_CONSTS_INIT \\",
            "    { \\",
            f"        .n_axes = {up}_N_AXES, \\",
            f"        .depth = {up}_QUEUE_DEPTH, \\",
            "        .block_size = STL_BLOCK_SIZE, \\",
            f"        .low_watermark = {up}_LOW_WATERMARK, \\",
            f"        .high_watermark = {up}_HIGH_WATERMARK, \\",
            "    }",
        ]
    return out
