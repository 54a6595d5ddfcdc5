"""The gantry export: a verified gantry tuning's runtime constants as JSON, and as C for the
gantry runtime (``servotune_gantry.c``).

The JSON document (``"schema": "servotune.gantry-tables/2"``) holds exactly the tuning's
integers (nothing re-quantised)::

    {
      "data": {
        "c_layout_sha256": str,       SHA-256 of the 672-byte C layout
                                      (servotune.export.gantry_layout; the C header carries it)
        "counter_bits": int,
        "cycle_s": float,             bus cycle [s] (folded into the constants)
        "dac": {"bits", "code_max", "range_v", "zero_code"},
        "drives": [{"name": "master"|"slave", "controller": {law, lock_gain, task: {kp, ki_t},
                    following_error_limit_counts, filters?}}],   filters: the drive's output
                                      filters (each section's integers), only where it has any
        "gantry_name": str,
        "latency_cycles": int,        the master's feedback reaches the slave this late
        "sync": {"law", "constants": {kp, ki_t, kd_t, dead_zone_counts, limit_counts},
                 "trip_counts", "warn_counts"},
        "topology": str
      },
      "provenance": {"gantry": {"name", "sha256"}, "rig": {"name", "sha256"}, "spec_sha256",
                     "tool", "tool_version", "tuning_sha256", "verification"},
      "schema": "servotune.gantry-tables/2",
      "sha256": str,                  the document's digest (servotune.digest)
      "verified": true | false
    }

The export formats render it (:mod:`servotune.export.formats`): ``json`` the document's text
(:func:`servotune.export.json.to_string` of a :class:`~servotune.arch.gantry.tuning.
GantryTuning`), ``c`` :func:`gantry_c_header`'s ``servotune_gantry_consts.h`` (the same
constants as an initialiser of ``st_gantry_consts_t``, ``SERVOTUNE_GANTRY_INIT``, and the
C-layout digest ``st_gantry_consts_sha256`` that ``st_gantry_check_digest`` compares with at
start-up) with the runtime's sources (``servotune_rt.c/.h``, ``servotune_gantry.c/.h``:
:func:`servotune.export.c.to_file`). Every file is rendered in memory, then written atomically.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from servotune._version import __version__
from servotune.arch.gantry.tuning import DRIVES, GantryTuning
from servotune.digest import DIGEST_FIELD, document_sha256
from servotune.errors import DigestError, ExportError
from servotune.export.c_text import axis_lines, comment_text, digest_bytes_lines, int32_literal
from servotune.export.gantry_layout import gantry_layout_sha256
from servotune.io.files import json_safe, parse_json
from servotune.laws.axis import filter_overflow_problem
from servotune.rig import Rig

__all__ = [
    "GANTRY_HEADER_NAME",
    "GANTRY_TABLES_SCHEMA",
    "OLD_GANTRY_TABLES_SCHEMAS",
    "check_gantry_tables",
    "gantry_c_header",
    "gantry_document",
]

GANTRY_TABLES_SCHEMA = "servotune.gantry-tables/2"
OLD_GANTRY_TABLES_SCHEMAS = ("servotune.gantry-tables/1",)
"""Gantry exports of an older servotune (/1: no output filters in the C layout)."""
GANTRY_HEADER_NAME = "servotune_gantry_consts.h"


def gantry_document(
    tuning: GantryTuning,
    rig: Rig,
    *,
    record: Mapping[str, Any] | None = None,
    unverified: bool = False,
) -> dict[str, Any]:
    """The export as a plain dict (see the module docstring).

    Parameters
    ----------
    tuning : GantryTuning
    rig : Rig
        The gantry's rig (counter width, D/A coding).
    record : mapping, optional
        The tuning's checked verification record (:func:`~servotune.arch.gantry.verify.
        load_gantry_for_export`); its summary goes into the provenance.
    unverified : bool
        Export without a record; marked ``"verified": false``.

    Raises
    ------
    ExportError
        No record (and not ``unverified``) or a failed one, or a drive's filter section whose
        sums could leave ±2^62 for inputs within the D/A's range.
    """
    if not unverified:
        if record is None:
            raise ExportError(
                "no verification record: verify the gantry tuning first, or "
                "export it marked unverified (--unverified)"
            )
        if record.get("passed") is not True:
            raise ExportError("the verification failed: fix the tuning and verify it again")
    files = record.get("files", {}) if record is not None else {}
    dac = rig.dac
    for name, drive in zip(DRIVES, tuning.drives, strict=True):
        problem = filter_overflow_problem(drive.filters, dac.zero_code, dac.code_max)
        if problem is not None:
            raise ExportError(f"the {name} drive's {problem}")
    data: dict[str, Any] = {
        "counter_bits": rig.counter.bits,
        "cycle_s": float(tuning.cycle_s),
        "dac": {
            "bits": dac.bits,
            "code_max": 2**dac.bits - 1,
            "range_v": list(dac.range_v),
            "zero_code": dac.zero_code,
        },
        "drives": [
            {"controller": c.to_dict(), "name": n}
            for n, c in zip(DRIVES, tuning.drives, strict=True)
        ],
        "gantry_name": tuning.gantry_name,
        "latency_cycles": tuning.latency_cycles,
        "sync": {
            "constants": tuning.sync.to_dict(),
            "law": tuning.sync_law,
            "trip_counts": tuning.trip_counts,
            "warn_counts": tuning.warn_counts,
        },
        "topology": tuning.topology,
    }
    data["c_layout_sha256"] = gantry_layout_sha256(data)
    summary = None
    if record is not None:
        summary = json_safe(
            {
                "passed": record.get("passed"),
                "record_sha256": record.get(DIGEST_FIELD),
                "summary": record.get("summary"),
            }
        )
    doc: dict[str, Any] = {
        "data": data,
        "provenance": {
            "gantry": {"name": tuning.gantry_name, "sha256": tuning.gantry_sha256},
            "rig": {"name": tuning.rig_name, "sha256": tuning.rig_sha256},
            "spec_sha256": files.get("spec", {}).get("sha256"),
            "tool": "servotune",
            "tool_version": __version__,
            "tuning_sha256": files.get("tuning", {}).get("sha256"),
            "verification": summary,
        },
        "schema": GANTRY_TABLES_SCHEMA,
        "verified": not unverified,
    }
    doc[DIGEST_FIELD] = document_sha256(doc)
    return doc


def check_gantry_tables(text: str, src: str = "<text>") -> dict[str, Any]:
    """Parse a gantry tables export and check its digests (the document's and the C layout's).

    Raises
    ------
    DigestError
        A digest does not match (the document was edited).
    ExportError
        Not a gantry tables export.
    """
    doc = parse_json(text, src, ExportError)
    if isinstance(doc, dict) and doc.get("schema") in OLD_GANTRY_TABLES_SCHEMAS:
        raise ExportError(
            f"{src}: {doc['schema']} was written by an older servotune; export the gantry "
            "tuning again"
        )
    if not isinstance(doc, dict) or doc.get("schema") != GANTRY_TABLES_SCHEMA:
        raise ExportError(f"{src}: not a gantry tables export ({GANTRY_TABLES_SCHEMA})")
    if doc.get(DIGEST_FIELD) != document_sha256(doc):
        raise DigestError(f"{src}: the document's sha256 does not match its content (edited)")
    data = doc.get("data")
    if not isinstance(data, dict) or data.get("c_layout_sha256") != gantry_layout_sha256(data):
        raise DigestError(f"{src}: data.c_layout_sha256 does not match the constants (edited)")
    return doc


def _sync_lines(sync: Mapping[str, Any]) -> tuple[list[str], list[str]]:
    k = sync["constants"]
    lines = [
        "",
        f"/* sync compensator: law {sync['law']}; gains in counts of compensation per count of",
        " * sync error, value q * 2^-f */",
        f"#define ST_GANTRY_SYNC_KP_Q {int32_literal(k['kp']['q'])} /* Kp [-] */",
        f"#define ST_GANTRY_SYNC_KP_F {k['kp']['f']}",
        f"#define ST_GANTRY_SYNC_KIT_Q {int32_literal(k['ki_t']['q'])} /* Ki*T [-/cycle] */",
        f"#define ST_GANTRY_SYNC_KIT_F {k['ki_t']['f']}",
        f"#define ST_GANTRY_SYNC_KDT_Q {int32_literal(k['kd_t']['q'])} /* Kd/T [-*cycle] */",
        f"#define ST_GANTRY_SYNC_KDT_F {k['kd_t']['f']}",
        f"#define ST_GANTRY_SYNC_DEAD_ZONE {k['dead_zone_counts']} /* [counts] */",
        f"#define ST_GANTRY_SYNC_LIMIT {k['limit_counts']} /* largest compensation [counts] */",
        f"#define ST_GANTRY_SYNC_WARN {sync['warn_counts']} /* warning [counts], 0 = off */",
        f"#define ST_GANTRY_SYNC_TRIP {sync['trip_counts']} /* trip [counts], 0 = off */",
    ]
    fields = (
        "kp_q",
        "kp_f",
        "kit_q",
        "kit_f",
        "kdt_q",
        "kdt_f",
        "dead_zone",
        "limit",
        "warn",
        "trip",
    )
    init = [f".{f} = ST_GANTRY_SYNC_{f.upper()}" for f in fields]
    return lines, init


def gantry_c_header(doc: Mapping[str, Any]) -> str:
    """The text of ``servotune_gantry_consts.h`` from a document of :func:`gantry_document`."""
    data, prov = doc["data"], doc["provenance"]
    verified = "yes" if doc["verified"] else "NO -- exported unverified; verify before use"
    out = [
        f"/* {GANTRY_HEADER_NAME} -- generated by servotune {prov['tool_version']} "
        f"({GANTRY_TABLES_SCHEMA}).",
        " * Do not edit: export the tuning again. The runtime is servotune_gantry.c/.h on",
        " * servotune_rt.c/.h.",
        f" * gantry: {comment_text(data['gantry_name'])} (config sha256 "
        f"{prov['gantry']['sha256']})",
        f" * rig: {comment_text(prov['rig']['name'])} (sha256 {prov['rig']['sha256']})",
        f" * tuning sha256: {prov['tuning_sha256']}",
        f" * verified: {verified}",
        " * At start-up:",
        " *     static const st_gantry_consts_t consts = SERVOTUNE_GANTRY_INIT;",
        " *     if (st_gantry_check_digest(&consts, st_gantry_consts_sha256) != 0) halt();",
        " *     if (st_gantry_check(&consts) != 0) halt();",
        " */",
        "#ifndef SERVOTUNE_GANTRY_CONSTS_H",
        "#define SERVOTUNE_GANTRY_CONSTS_H",
        "",
        "#include <stdint.h>",
        "",
        '#include "servotune_gantry.h"',
        "",
        f'#define ST_GANTRY_SCHEMA "{GANTRY_TABLES_SCHEMA}"',
        f"#define ST_GANTRY_VERIFIED {1 if doc['verified'] else 0}",
        f"#define ST_GANTRY_CYCLE_S {data['cycle_s']!r} /* bus cycle [s] */",
        f"#define ST_GANTRY_TOPOLOGY ST_TOPO_{data['topology'].upper()}",
        f"#define ST_GANTRY_LATENCY {data['latency_cycles']} /* [cycles] */",
        f"#define ST_COUNTER_BITS {data['counter_bits']}",
        f"#define ST_DAC_ZERO {data['dac']['zero_code']} /* code of 0 V */",
        f"#define ST_DAC_MAX {data['dac']['code_max']}",
        "",
        "/* SHA-256 of the constants in the C layout; st_gantry_check_digest recomputes it. */",
        f'#define ST_GANTRY_SHA256 "{data["c_layout_sha256"]}"',
        *digest_bytes_lines("st_gantry_consts_sha256", data["c_layout_sha256"]),
    ]
    inits = []
    for i, d in enumerate(data["drives"]):
        ax = {**d["controller"], "index": i, "name": d["name"], "role": d["name"], "ref_source": -1}
        lines, init = axis_lines(ax, d["name"])
        out.extend(lines)
        inits.append(init)
    lines, sync_init = _sync_lines(data["sync"])
    out.extend(lines)
    out += [
        "",
        "#define SERVOTUNE_GANTRY_INIT \\",
        "    { \\",
        "        .topology = ST_GANTRY_TOPOLOGY, \\",
        "        .latency = ST_GANTRY_LATENCY, \\",
        "        .drive = { \\",
    ]
    for d, init in zip(data["drives"], inits, strict=True):
        out.append(f"            {{ /* {d['name']} */ \\")
        out.extend(f"                {item}, \\" for item in init)
        out.append("            }, \\")
    out += ["        }, \\", "        .sync = { \\"]
    out.extend(f"            {item}, \\" for item in sync_init)
    out += ["        } \\", "    }", "", "#endif /* SERVOTUNE_GANTRY_CONSTS_H */", ""]
    return "\n".join(out)
