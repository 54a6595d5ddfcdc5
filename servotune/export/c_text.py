"""The pieces of a generated C header, shared by every C export (:mod:`servotune.export.c`
renders the rig's, gantry's and linkage's headers with them): C identifiers from names, int32
literals, text safe in a comment, one axis's constants, query tables and output filters as macros
with its ``st_axis_consts_t`` initialiser, and a SHA-256 as a byte array.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import Any

from servotune.errors import ExportError
from servotune.laws.axis import TASK_LAWS
from servotune.laws.filters import SECTION_WORDS

__all__ = [
    "axis_lines",
    "c_identifiers",
    "comment_text",
    "digest_bytes_lines",
    "filter_lines",
    "int32_literal",
]


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


def _table_lines(ident: str, name: str, title: str, tab: Mapping[str, Any]) -> list[str]:
    n = tab["n"]
    up = f"ST_{ident.upper()}_TAB_{name.upper()}"
    side = f"(2 * ST_{ident.upper()}_N + 1)"
    lines = [
        f"/* query table {title}: value q * 2^-f, row E = -{n}..{n}, column EC = -{n}..{n} */",
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
        f".law = {'ST_LAW_NONE' if law == 'none' else TASK_LAWS[law].macro}",
        f".lock_q = {up}_LOCK_Q",
        f".lock_f = {up}_LOCK_F",
        f".fe_limit = {up}_FE_LIMIT",
        ".counter_bits = ST_COUNTER_BITS",
        ".dac_zero = ST_DAC_ZERO",
        ".dac_max = ST_DAC_MAX",
        f".ref_source = {ax['ref_source']}",
    ]
    task = ax["task"]
    described = TASK_LAWS.get(law)
    for word in () if described is None else described.words:
        mac = word.stem.upper()
        value = task[word.key]
        lines.append(f"#define {up}_{mac}_Q {int32_literal(value['q'])} /* {word.title} */")
        lines.append(f"#define {up}_{mac}_F {value['f']}")
        init.append(f".{word.stem}_q = {up}_{mac}_Q")
        init.append(f".{word.stem}_f = {up}_{mac}_F")
    tables = () if described is None else described.tables
    if tables:
        lines.append(f"#define {up}_N {task['n']} /* levels -n..n */")
        init.append(f".n = {up}_N")
        for name, title in zip(tables, described.table_titles, strict=True):  # type: ignore[union-attr]
            lines.append("")
            lines.extend(_table_lines(ident, name, title, task["tables"][name]))
        tf = ", ".join(f"{up}_TAB_{t.upper()}_F" for t in tables)
        tab = ", ".join(f"st_{ident}_tab_{t}" for t in tables)
        init.append(f".tf = {{{tf}}}")
        init.append(f".tab = {{{tab}}}")
    if "filters" in ax:  # a tables document's axis, or a gantry drive with filters
        macros, members = filter_lines(ax["filters"], up)
        lines.extend(macros)
        init.extend(members)
    if ax.get("shaper"):  # a tables document's axis with a reference shaper
        lines += _shaper_lines(ax["shaper"], ident, up)
        init += [f".shaper_n = {up}_SHAPER_N", f".shaper_q = st_{ident}_shaper_q"]
    return lines, init


def _shaper_lines(taps: Sequence[int], ident: str, up: str) -> list[str]:
    """An axis's reference shaper (docs/runtime.md#shapers-in-the-tables): ``<UP>_SHAPER_N``
    and the ``static const int32_t st_<ident>_shaper_q[]`` of its Q15 amplitudes, eight to a
    line (an ``st_shaper_t`` for ``servotune_shaper.h`` is filled from them)."""
    lines = [
        "",
        "/* input shaper of the task reference (the firmware shapes the reference it hands",
        " * st_tick: servotune_shaper.h): Q15 amplitudes, tick 0 first, summing to 2^15 */",
        f"#define {up}_SHAPER_N {len(taps)}",
        f"static const int32_t st_{ident}_shaper_q[{up}_SHAPER_N] = {{",
    ]
    for i in range(0, len(taps), 8):
        lines.append("    " + ", ".join(str(int(a)) for a in taps[i : i + 8]) + ",")
    lines.append("};")
    return lines


def filter_lines(filters: Sequence[Mapping[str, int]], up: str) -> tuple[list[str], list[str]]:
    """An axis's output filters (docs/runtime.md#filters-in-the-law): ``<UP>_N_FILTERS`` and,
    per section ``k``, ``<UP>_FILT<k>_B0`` … ``_A2`` and ``_FRAC_BITS``; the initialiser's
    ``.n_filters`` and ``.filter[k]`` (the slots past the last section are left zero)."""
    lines = [f"#define {up}_N_FILTERS {len(filters)} /* output filter sections, 0 = none */"]
    init = [f".n_filters = {up}_N_FILTERS"]
    for k, sec in enumerate(filters):
        mac = f"{up}_FILT{k}"
        lines += [
            "",
            f"/* output filter section {k} (in series before the D/A, on the law's output in D/A",
            " * codes with 16 fraction bits): H(z) = (b0 + b1 z^-1 + b2 z^-2) / (1 + a1 z^-1 +",
            " * a2 z^-2), each coefficient q * 2^-frac_bits */",
        ]
        for word in SECTION_WORDS[:-1]:
            lines.append(f"#define {mac}_{word.upper()} {int32_literal(sec[word])}")
        lines.append(f"#define {mac}_FRAC_BITS {sec['frac_bits']}")
        words = ", ".join(f"{mac}_{w.upper()}" for w in SECTION_WORDS)
        init.append(f".filter[{k}] = {{{words}}}")
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
