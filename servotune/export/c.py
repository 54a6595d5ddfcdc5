"""The C export (``export-table --format c``): a generated header and the runtime's sources.

The format's two functions, as every export format's (:mod:`servotune.export.formats`):
:func:`to_string` is the generated header's text, :func:`to_file` writes it with the runtime's
sources into a directory. What goes in depends on what is exported:

- a rig's tuning: ``servotune_tables.h`` and ``servotune_rt.c/.h`` (below);
- a gantry tuning: ``servotune_gantry_consts.h`` (:func:`servotune.export.gantry.gantry_c_header`),
  ``servotune_rt.c/.h`` and ``servotune_gantry.c/.h``;
- a linkage plan: ``servotune_link_plan.h`` (:func:`servotune.export.linkage.linkage_c_header`),
  ``servotune_link.c/.h`` and ``servotune_rt.c/.h``.

A rig's tuning:

- ``servotune_tables.h``: the tuning's constants as the runtime runs them (the same numbers and
  CRCs as the JSON export, :func:`servotune.export.json.tables_document`): include guard,
  ``<stdint.h>`` types, the schema version, per axis every constant as an int32 ``q`` and its
  fraction bits ``f``, the query tables as ``static const int16_t`` arrays (row ``E``, column
  ``EC``), the output filter sections (``ST_<AXIS>_N_FILTERS``, ``ST_<AXIS>_FILT<k>_B0`` …
  ``_FRAC_BITS``; docs/runtime.md#filters-in-the-law), the CRCs as ``uint32_t`` constants,
  ``SERVOTUNE_TABLES_INIT``, an initialiser of the runtime's ``st_consts_t``, and the SHA-256
  of those compiled-in constants in the C layout (:mod:`servotune.export.layout`, the JSON's
  ``data.c_layout_sha256``):
  ``ST_TABLES_SHA256`` (hex string), ``ST_TABLES_SHA256_BYTES`` (a 32-byte initialiser) and
  ``st_tables_sha256``, the array the runtime's ``st_check_digest`` compares with;
- ``servotune_rt.c`` / ``servotune_rt.h`` and ``servotune_filter.h`` (the filter section's
  step, which ``servotune_rt.h`` includes): the reference runtime (C99, integer only, no I/O),
  copied from the package data. It mirrors the Python laws line by line, so it produces the
  simulator's D/A codes bit for bit.

Usage on the target::

    #include "servotune_tables.h"
    static const st_consts_t consts = SERVOTUNE_TABLES_INIT;
    static st_state_t state;            /* zero: power-up */
    ...
    if (st_check_digest(&consts, st_tables_sha256) != 0) halt(); /* the exported bytes? */
    if (st_check_consts(&consts) != 0) halt();                   /* ranges the runtime needs */
    st_tick(&consts, &state, in, out);  /* every tick: bytes, reference, mode -> codes, flags */

The runtime has no loader, so the digest check is what ties the compiled-in constants to the
export: ``st_check_digest`` serialises ``consts`` into the C layout, hashes it and compares
with ``st_tables_sha256`` (an edited constant, a stale header or one mixed up with another
tuning's digest fails it). It guards against accidents, not an attacker.

The bytes are deterministic (no timestamps). Every file is rendered in memory first and then
written atomically (temp file, then rename), so a failure leaves no half-written file.
"""

from __future__ import annotations

from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any, Unpack

from servotune.arch.gantry.tuning import GantryTuning
from servotune.arch.linkage.plan import LinkagePlan
from servotune.errors import ExportError
from servotune.export.c_text import axis_lines, c_identifiers, comment_text, digest_bytes_lines
from servotune.export.gantry import GANTRY_HEADER_NAME, gantry_c_header
from servotune.export.json import (
    SCHEMA,
    Exportable,
    TablesOptions,
    as_record,
    export_document,
    tables_document,
)
from servotune.export.linkage import LINK_HEADER_NAME, linkage_c_header
from servotune.io.files import write_files

__all__ = [
    "FILTER_RUNTIME_FILES",
    "GANTRY_RUNTIME_FILES",
    "HEADER_NAME",
    "LINK_RUNTIME_FILES",
    "PLANT_RUNTIME_FILES",
    "RUNTIME_FILES",
    "SHAPER_RUNTIME_FILES",
    "runtime_source",
    "to_file",
    "to_string",
]

HEADER_NAME = "servotune_tables.h"
RUNTIME_FILES = ("servotune_rt.c", "servotune_rt.h", "servotune_filter.h")
"""The reference runtime's sources (package data of ``servotune.export``); its header includes
the filter section's (:data:`FILTER_RUNTIME_FILES`)."""
GANTRY_RUNTIME_FILES = ("servotune_gantry.c", "servotune_gantry.h")
"""The gantry runtime's sources, on top of :data:`RUNTIME_FILES`
(:mod:`servotune.export.gantry`)."""
PLANT_RUNTIME_FILES = ("servotune_plant.h",)
"""The simulator's plant model in C (header only; :mod:`servotune.export.hal_component`)."""
LINK_RUNTIME_FILES = ("servotune_link.c", "servotune_link.h")
"""A linkage slave CPU's receive queue and clock sync (:mod:`servotune.export.linkage`)."""
SHAPER_RUNTIME_FILES = ("servotune_shaper.h",)
"""The input shaper's integer step (header only; :mod:`servotune.laws.shaping`)."""
FILTER_RUNTIME_FILES = ("servotune_filter.h",)
"""A filter section's integer step (header only; :mod:`servotune.laws.filters`)."""


def runtime_source(name: str) -> str:
    """Text of one reference-runtime file (of :data:`RUNTIME_FILES`,
    :data:`GANTRY_RUNTIME_FILES`, :data:`LINK_RUNTIME_FILES`)."""
    known = (
        RUNTIME_FILES
        + GANTRY_RUNTIME_FILES
        + LINK_RUNTIME_FILES
        + PLANT_RUNTIME_FILES
        + SHAPER_RUNTIME_FILES
        + FILTER_RUNTIME_FILES
    )
    if name not in known:
        raise ExportError(f"no runtime file {name!r}; files: {', '.join(known)}")
    return resources.files("servotune.export").joinpath("runtime", name).read_text(encoding="utf-8")


def _digest_lines(digest: str) -> list[str]:
    """The C-layout digest as a hex string macro, a byte initialiser and the array."""
    return [
        "",
        "/* SHA-256 of the compiled-in constants and tables in the C layout (servotune_rt.h):",
        " * st_check_digest(&consts, st_tables_sha256) recomputes it; 0 = they are these. */",
        f'#define ST_TABLES_SHA256 "{digest}"',
        *digest_bytes_lines("st_tables_sha256", digest),
    ]


def _header(doc: Mapping[str, Any]) -> str:
    data, prov = doc["data"], doc["provenance"]
    axes = data["axes"]
    digest = data["c_layout_sha256"]  # tables_document computed it (layout.c_layout_sha256)
    idents = c_identifiers(tuple(a["name"] for a in axes))
    verification = prov["verification"]
    if verification is None:
        summary = "none"
    else:
        passed = verification.get("passed")
        summary = {True: "passed", False: "failed"}.get(passed, "summary without a result")
        if prov["spec_sha256"]:
            summary += f" (spec sha256 {prov['spec_sha256']}); the summary is in the JSON export"
    verified = (
        "yes" if doc["verified"] else "NO -- exported unverified; verify before running a machine"
    )
    out = [
        f"/* {HEADER_NAME} -- generated by servotune {prov['tool_version']} ({SCHEMA}).",
        " * Do not edit: export the tuning again. The runtime is servotune_rt.c / servotune_rt.h.",
        f" * rig: {comment_text(prov['rig']['name'])} (sha256 {prov['rig']['sha256']})",
        f" * tuning sha256: {prov['tuning_sha256']}",
        f" * verified: {verified}",
        f" * verification: {comment_text(summary)}",
        " *",
        " * Every constant is (q, f): value q * 2^-f. Constants CRC order (st_consts_crc32):",
        " * (n_axes, 0), (timer_divisor, 0), then per axis (law, 0), (lock_q, lock_f),",
        " * (kp_q, kp_f), (kit_q, kit_f), (fe_limit, 0), (counter_bits, 0), (dac_zero, 0),",
        " * (dac_max, 0), (kdt_q, kdt_f), (k1t_q, k1t_f), (ke_q, ke_f), (kec_q, kec_f), (n, 0),",
        " * (ref_source, 0), (n_filters, 0), then for each of the ST_MAX_FILTERS filter slots",
        " * (b0, frac_bits), (b1, frac_bits), (b2, frac_bits), (a1, frac_bits), (a2, frac_bits)",
        " * (an unused slot (0, 0) x 5), as little-endian int32 q, int16 f. Table CRCs",
        " * (st_table_crc32): int16 n, int16 f, then the int16 entries row-major, little-endian.",
        " * ST_TABLES_SHA256 is the SHA-256 of the C layout: the constants CRC's bytes, then for",
        " * each fuzzy-PID axis in order its kp, ki, kd, k1 tables' CRC bytes, then for each axis",
        " * its shaper: int32 shaper_n and the int32 amplitudes. At start-up:",
        " *     if (st_check_digest(&consts, st_tables_sha256) != 0) halt();",
        " */",
        "#ifndef SERVOTUNE_TABLES_H",
        "#define SERVOTUNE_TABLES_H",
        "",
        "#include <stdint.h>",
        "",
        '#include "servotune_rt.h"',
        "",
        f'#define ST_TABLES_SCHEMA "{SCHEMA}"',
        f"#define ST_TABLES_SCHEMA_VERSION {SCHEMA.rsplit('/', 1)[1]}",
        f"#define ST_TABLES_VERIFIED {1 if doc['verified'] else 0}",
        f"#define ST_N_AXES {len(axes)}",
        f"#define ST_PERIOD_S {data['period_s']!r} /* achieved tick period [s] */",
        f"#define ST_TIMER_DIVISOR {data['timer_divisor']} /* 8253 divisor */",
        f"#define ST_COUNTER_BITS {data['counter_bits']}",
        f"#define ST_DAC_BITS {data['dac']['bits']}",
        f"#define ST_DAC_ZERO {data['dac']['zero_code']} /* code of 0 V */",
        f"#define ST_DAC_MAX {data['dac']['code_max']}",
        f"#define ST_CONSTS_CRC32 UINT32_C(0x{data['constants_crc32']:08x})",
        *_digest_lines(digest),
        "",
        f"#if ST_MAX_AXES < {len(axes)}",
        f'#error "compile servotune_rt.c and this file with -DST_MAX_AXES={len(axes)}"',
        "#endif",
    ]
    inits = []
    for ax, ident in zip(axes, idents, strict=True):
        lines, init = axis_lines(ax, ident)
        out.extend(lines)
        inits.append(init)
    out += [
        "",
        "/* static const st_consts_t consts = SERVOTUNE_TABLES_INIT;",
        " * at start-up: if (st_check_digest(&consts, st_tables_sha256) != 0) halt(); */",
        "#define SERVOTUNE_TABLES_INIT \\",
        "    { \\",
        "        .n_axes = ST_N_AXES, \\",
        "        .timer_divisor = ST_TIMER_DIVISOR, \\",
        "        .axis = { \\",
    ]
    for ident, init in zip(idents, inits, strict=True):
        out.append(f"            {{ /* {ident} */ \\")
        out.extend(f"                {item}, \\" for item in init)
        out.append("            }, \\")
    out += [
        "        } \\",
        "    }",
        "",
        "#endif /* SERVOTUNE_TABLES_H */",
        "",
    ]
    return "\n".join(out)


def _rendered(obj: Exportable, options: TablesOptions) -> tuple[dict[str, str], tuple[str, ...]]:
    """The header ``obj`` gets (name → text) and the runtime sources it runs on."""
    if isinstance(obj, GantryTuning):
        doc = export_document(obj, **options)  # servotune.export.gantry.gantry_document
        return {GANTRY_HEADER_NAME: gantry_c_header(doc)}, RUNTIME_FILES + GANTRY_RUNTIME_FILES
    if isinstance(obj, LinkagePlan):
        record = as_record(options.get("verification"))
        header = linkage_c_header(obj, record, unverified=options.get("unverified", False))
        return {LINK_HEADER_NAME: header}, LINK_RUNTIME_FILES + RUNTIME_FILES
    return {HEADER_NAME: _header(tables_document(obj, **options))}, RUNTIME_FILES


def to_string(obj: Exportable, **options: Unpack[TablesOptions]) -> str:
    """The text of the header :func:`to_file` writes for ``obj`` (module docstring):
    ``servotune_tables.h`` of a rig's tuning, ``servotune_gantry_consts.h`` of a gantry tuning
    (:func:`servotune.export.gantry.gantry_c_header`), ``servotune_link_plan.h`` of a linkage
    plan (:func:`servotune.export.linkage.linkage_c_header`). Arguments as
    :func:`servotune.export.json.export_document`."""
    (text,) = _rendered(obj, options)[0].values()
    return text


def to_file(
    obj: Exportable, out_dir: str | Path, **options: Unpack[TablesOptions]
) -> tuple[Path, ...]:
    """Write the header of ``obj`` (:func:`to_string`) and the runtime sources it runs on into
    the directory ``out_dir``: the C export is several files, so its "file" is a directory.

    Parameters
    ----------
    obj : Tuning, GantryTuning or LinkagePlan
    out_dir : str or Path
        The directory (created if missing), written as a whole
        (:func:`servotune.io.files.write_files`): all of the files or none.
    rig, verification, unverified
        As :func:`servotune.export.json.export_document`.

    Returns
    -------
    tuple of Path
        The files written: the header first, then the runtime's sources.

    Raises
    ------
    ExportError
        As :func:`to_string`, ``out_dir`` is a file, or the files cannot be written (a full
        disk, no permission): nothing new is left in ``out_dir`` then, and the files it held
        are unchanged.
    """
    rendered, runtime = _rendered(obj, options)
    d = Path(out_dir)
    if d.exists() and not d.is_dir():
        raise ExportError(f"{d}: not a directory")
    texts = {**rendered, **{name: runtime_source(name) for name in runtime}}
    try:
        return write_files(d, texts)
    except OSError as exc:
        raise ExportError(f"{d}: cannot write the C files: {exc}") from None
