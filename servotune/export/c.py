"""The C export: ``servotune_tables.h`` and the reference runtime ``servotune_rt.c/.h``.

:func:`write_c` writes three files into a directory:

- ``servotune_tables.h``: the tuning's constants as the runtime runs them (the same numbers and
  CRCs as the JSON export, :func:`servotune.export.json.tables_document`): include guard,
  ``<stdint.h>`` types, the schema version, per axis every constant as an int32 ``q`` and its
  fraction bits ``f``, the query tables as ``static const int16_t`` arrays (row ``E``, column
  ``EC``), the CRCs as ``uint32_t`` constants, ``SERVOTUNE_TABLES_INIT``, an initialiser
  of the runtime's ``st_consts_t``, and the SHA-256 of those compiled-in constants in the C
  layout (:mod:`servotune.export.layout`, the JSON's ``data.c_layout_sha256``):
  ``ST_TABLES_SHA256`` (hex string), ``ST_TABLES_SHA256_BYTES`` (a 32-byte initialiser) and
  ``st_tables_sha256``, the array the runtime's ``st_check_digest`` compares with;
- ``servotune_rt.c`` / ``servotune_rt.h``: the reference runtime (C99, integer only, no I/O),
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

import re
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any, Unpack

from servotune.errors import ExportError
from servotune.export.json import SCHEMA, TablesOptions, tables_document
from servotune.io.files import write_files
from servotune.laws.fuzzy_pid import TABLE_NAMES
from servotune.tuning import Tuning

__all__ = [
    "GANTRY_RUNTIME_FILES",
    "HEADER_NAME",
    "LINK_RUNTIME_FILES",
    "PLANT_RUNTIME_FILES",
    "RUNTIME_FILES",
    "SHAPER_RUNTIME_FILES",
    "c_identifiers",
    "int32_literal",
    "runtime_source",
    "to_string",
    "write_c",
    "write_c_files",
]

HEADER_NAME = "servotune_tables.h"
RUNTIME_FILES = ("servotune_rt.c", "servotune_rt.h")
"""The reference runtime's sources (package data of ``servotune.export``)."""
GANTRY_RUNTIME_FILES = ("servotune_gantry.c", "servotune_gantry.h")
"""The gantry runtime's sources, on top of :data:`RUNTIME_FILES`
(:mod:`servotune.export.gantry`)."""
PLANT_RUNTIME_FILES = ("servotune_plant.h",)
"""The simulator's plant model in C (header only; :mod:`servotune.export.hal_component`)."""
LINK_RUNTIME_FILES = ("servotune_link.c", "servotune_link.h")
"""A linkage slave CPU's receive queue and clock sync (:mod:`servotune.export.linkage`)."""
SHAPER_RUNTIME_FILES = ("servotune_shaper.h",)
"""The input shaper's integer step (header only; :mod:`servotune.laws.shaping`)."""

_MAX_AXES = 4  # ST_MAX_AXES default of servotune_rt.h
_LAW_MACROS = {"none": "ST_LAW_NONE", "pi": "ST_LAW_PI", "fuzzy_pid": "ST_LAW_FUZZY_PID"}
_TABLE_TITLES = {
    "kp": "dKp [LSB/count]",
    "ki": "d(Ki*T) [LSB/count/tick]",
    "kd": "d(Kd/T) [LSB per count change per tick]",
    "k1": "d(K1/T) [LSB per count change per tick]",
}


def runtime_source(name: str) -> str:
    """Text of one reference-runtime file (of :data:`RUNTIME_FILES`,
    :data:`GANTRY_RUNTIME_FILES`, :data:`LINK_RUNTIME_FILES`)."""
    known = (
        RUNTIME_FILES
        + GANTRY_RUNTIME_FILES
        + LINK_RUNTIME_FILES
        + PLANT_RUNTIME_FILES
        + SHAPER_RUNTIME_FILES
    )
    if name not in known:
        raise ExportError(f"no runtime file {name!r}; files: {', '.join(known)}")
    return resources.files("servotune.export").joinpath("runtime", name).read_text(encoding="utf-8")


def c_identifiers(
    names: tuple[str, ...], what: str = "axis", prefix: str = "axis_", upper: bool = False
) -> list[str]:
    """C identifiers of ``names`` (non-alphanumerics as ``_``, lower or upper case, ``prefix``
    before a leading digit); two that clash are refused, naming the ``what`` names."""
    out = []
    for name in names:
        ident = re.sub(r"[^0-9A-Za-z_]", "_", name)
        ident = ident.upper() if upper else ident.lower()
        if not ident or ident[0].isdigit():
            ident = prefix + ident
        out.append(ident)
    if len(set(out)) != len(out):
        raise ExportError(
            f"{what} names {list(names)} give clashing C identifiers {out}; rename them"
        )
    return out


def comment_text(s: str) -> str:
    """Text safe inside a C block comment, on one line."""
    return s.replace("*/", "*\\/").replace("\n", " ")


def int32_literal(v: int) -> str:
    """A quantised gain as a C ``int32_t`` constant: ``INT32_C(v)``."""
    return f"INT32_C({v})"


def _table_lines(ident: str, name: str, tab: Mapping[str, Any]) -> list[str]:
    n = tab["n"]
    up = f"ST_{ident.upper()}_TAB_{name.upper()}"
    side = f"(2 * ST_{ident.upper()}_N + 1)"
    lines = [
        f"/* query table {_TABLE_TITLES[name]}: value q * 2^-f, row E = -{n}..{n}, "
        f"column EC = -{n}..{n} */",
        f"#define {up}_F {tab['f']}",
        f"#define {up}_CRC32 UINT32_C(0x{tab['crc32']:08x})",
        # sized by the axis's N: the runtime reads (2n+1)^2 entries, so an edited N changes
        # the digest but cannot make st_check_digest (or st_tick) read past the table
        f"static const int16_t st_{ident}_tab_{name}[{side} * {side}] = {{",
    ]
    for r, row in enumerate(tab["q"]):
        lines.append(f"    /* E = {r - n:3d} */ " + ", ".join(str(v) for v in row) + ",")
    lines.append("};")
    return lines


def axis_lines(ax: Mapping[str, Any], ident: str) -> tuple[list[str], list[str]]:
    """The axis's macros and tables, and its designated initialiser lines."""
    up = f"ST_{ident.upper()}"
    law = ax["law"]
    src = "external reference" if ax["ref_source"] < 0 else f"follows axis {ax['ref_source']}"
    lines = [
        "",
        f"/* axis {ax['index']}: {comment_text(ax['name'])} (role {ax['role']}, law {law}, "
        f"{src}) */",
        f"#define ST_AXIS_{ident.upper()} {ax['index']}",
        f"#define {up}_LOCK_Q {int32_literal(ax['lock_gain']['q'])} /* lock gain [LSB/count] */",
        f"#define {up}_LOCK_F {ax['lock_gain']['f']}",
        f"#define {up}_FE_LIMIT {ax['following_error_limit_counts']} /* [counts], 0 = off */",
    ]
    init = [
        f".law = {_LAW_MACROS[law]}",
        f".lock_q = {up}_LOCK_Q",
        f".lock_f = {up}_LOCK_F",
        f".fe_limit = {up}_FE_LIMIT",
        ".counter_bits = ST_COUNTER_BITS",
        ".dac_zero = ST_DAC_ZERO",
        ".dac_max = ST_DAC_MAX",
        f".ref_source = {ax['ref_source']}",
    ]
    task = ax["task"]
    consts: list[tuple[str, str, str]] = []
    if law == "pi":
        consts = [("kp", "KP", "Kp [LSB/count]"), ("ki_t", "KIT", "Ki*T [LSB/count/tick]")]
    elif law == "fuzzy_pid":
        consts = [
            ("kp", "KP", "Kp0 [LSB/count]"),
            ("ki_t", "KIT", "Ki0*T [LSB/count/tick]"),
            ("kd_t", "KDT", "Kd0/T [LSB per count change per tick]"),
            ("k1_t", "K1T", "K10/T, feedforward [LSB per count change per tick]"),
            ("ke", "KE", "Ke [levels/count]"),
            ("kec", "KEC", "Kec [levels per count/tick]"),
        ]
    for key, mac, title in consts:
        lines.append(f"#define {up}_{mac}_Q {int32_literal(task[key]['q'])} /* {title} */")
        lines.append(f"#define {up}_{mac}_F {task[key]['f']}")
        init.append(f".{mac.lower()}_q = {up}_{mac}_Q")
        init.append(f".{mac.lower()}_f = {up}_{mac}_F")
    if law == "fuzzy_pid":
        lines.append(f"#define {up}_N {task['n']} /* levels -n..n */")
        init.append(f".n = {up}_N")
        for name in TABLE_NAMES:
            lines.append("")
            lines.extend(_table_lines(ident, name, task["tables"][name]))
        tf = ", ".join(f"{up}_TAB_{t.upper()}_F" for t in TABLE_NAMES)
        tab = ", ".join(f"st_{ident}_tab_{t}" for t in TABLE_NAMES)
        init.append(f".tf = {{{tf}}}")
        init.append(f".tab = {{{tab}}}")
    return lines, init


def digest_bytes_lines(array: str, digest: str) -> list[str]:
    """A SHA-256 (hex) as the macro ``<ARRAY>_BYTES`` (a 32-byte initialiser) and the
    ``static const uint8_t`` array ``array``."""
    octets = [f"0x{digest[i : i + 2]}" for i in range(0, 64, 2)]
    rows = [", ".join(octets[i : i + 8]) for i in range(0, 32, 8)]
    return [
        f"#define {array.upper()}_BYTES \\",
        "    { \\",
        *(f"        {row}, \\" for row in rows),
        "    }",
        f"static const uint8_t {array}[32] = {array.upper()}_BYTES;",
    ]


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
        " * (ref_source, 0), as little-endian int32 q, int16 f. Table CRCs (st_table_crc32):",
        " * int16 n, int16 f, then the int16 entries row-major, little-endian.",
        " * ST_TABLES_SHA256 is the SHA-256 of the C layout: the constants CRC's bytes, then for",
        " * each fuzzy-PID axis in order its kp, ki, kd, k1 tables' CRC bytes. At start-up:",
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


def to_string(tuning: Tuning, **options: Unpack[TablesOptions]) -> str:
    """The text of ``servotune_tables.h`` (arguments as
    :func:`servotune.export.json.tables_document`)."""
    return _header(tables_document(tuning, **options))


def write_c(
    tuning: Tuning, out_dir: str | Path, **options: Unpack[TablesOptions]
) -> tuple[Path, ...]:
    """Write ``servotune_tables.h``, ``servotune_rt.c`` and ``servotune_rt.h`` into ``out_dir``.

    Parameters
    ----------
    tuning : Tuning
    out_dir : str or Path
        The directory (created if missing; written as a whole, :func:`write_c_files`).
    rig, verification, unverified
        As :func:`servotune.export.json.tables_document`.

    Returns
    -------
    tuple of Path
        The files written: the tables header, then the runtime's two sources.

    Raises
    ------
    ExportError
        As :func:`~servotune.export.json.tables_document`, or if ``out_dir`` is not a
        directory. Nothing is written then.
    """
    return write_c_files(out_dir, {HEADER_NAME: to_string(tuning, **options)}, RUNTIME_FILES)


def write_c_files(
    out_dir: str | Path, rendered: Mapping[str, str], runtime: tuple[str, ...]
) -> tuple[Path, ...]:
    """Write the ``rendered`` files (name → text, rendered in memory first) and the
    ``runtime`` sources (:func:`runtime_source`) into the directory ``out_dir`` (created if
    missing) as a whole (:func:`servotune.io.files.write_files`): all of them or none.

    Raises
    ------
    ExportError
        ``out_dir`` is a file, or the files cannot be written (a full disk, no permission):
        nothing new is left in ``out_dir`` then, and the files it held are unchanged.
    """
    d = Path(out_dir)
    if d.exists() and not d.is_dir():
        raise ExportError(f"{d}: not a directory")
    texts = {**rendered, **{name: runtime_source(name) for name in runtime}}
    try:
        return write_files(d, texts)
    except OSError as exc:
        raise ExportError(f"{d}: cannot write the C files: {exc}") from None
