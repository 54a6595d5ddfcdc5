"""The C layout: the bytes the C runtime compiles in, and their SHA-256
(docs/runtime.md#integrity-crcs-and-the-c-layout).

The C runtime has no loader: ``servotune_tables.h`` compiles a tuning's constants and query
tables into an ``st_consts_t`` (``SERVOTUNE_TABLES_INIT``). The header carries the SHA-256 of
those constants serialised in the *C layout* below (``ST_TABLES_SHA256``); the runtime's
``st_check_digest`` serialises its compiled-in ``st_consts_t`` the same way at start-up and
compares. This module computes the same bytes from a tables document's ``data`` section
(``servotune.tables/4``, :func:`servotune.export.json.tables_document`), so the JSON export,
the header and the runtime agree on one digest. It is an integrity check against accidental
edits, stale files and mix-ups, not against an attacker.

Layout
------
Little-endian two's complement, no padding, no header or length prefix; three parts, the first
two each exactly the byte stream one of the export's CRCs covers:

1. **Constants** — ``2 + 35·n_axes`` pairs of (int32 ``q``, int16 ``f``), 6 bytes each; an
   integer is the pair ``(value, 0)``, a constant the axis's law does not use ``(0, 0)``::

       (n_axes, 0), (timer_divisor, 0), then for each axis a = 0 .. n_axes-1, in order:
       (law, 0), (lock_q, lock_f), (kp_q, kp_f), (kit_q, kit_f), (fe_limit, 0),
       (counter_bits, 0), (dac_zero, 0), (dac_max, 0), (kdt_q, kdt_f), (k1t_q, k1t_f),
       (ke_q, ke_f), (kec_q, kec_f), (n, 0), (ref_source, 0), (n_filters, 0),
       then for each of the 4 filter section slots k = 0 .. 3:
       (b0, frac_bits), (b1, frac_bits), (b2, frac_bits), (a1, frac_bits), (a2, frac_bits)

   ``law`` is 0 none, 1 PI, 2 fuzzy-PID; ``n`` is 0 unless fuzzy-PID; ``n_filters`` is the
   number of output filter sections (0 … 4, docs/runtime.md#filters-in-the-law), and a slot
   ``k >= n_filters`` is five ``(0, 0)``: every axis has 14 + 1 + 20 = 35 pairs. These are the
   bytes of ``data.constants_crc32`` (``st_consts_crc32``).

2. **Tables** — then, for each axis in order whose law is fuzzy-PID, for each of its tables
   in ``TABLE_NAMES`` order (``kp``, ``ki``, ``kd``, ``k1``): int16 ``n``, int16 ``f``, then the
   ``(2n+1)²`` int16 entries row-major (row ``E = −n … n``, column ``EC = −n … n``). Each
   table's block is the bytes of its ``crc32`` (``st_table_crc32``). Other axes contribute
   nothing.

3. **Shapers** — then, for each axis in order, int32 ``shaper_n`` (0 without a shaper, else
   its number of taps, 1 … 1024) followed by its ``shaper_n`` int32 Q15 amplitudes, tick 0
   first (docs/runtime.md#shapers-in-the-tables).

Its length is ``6·(2 + 35·n_axes) + Σ over fuzzy-PID axes of 4·(4 + 2·(2n+1)²) +
4·(n_axes + Σ shaper_n)`` bytes. The layout is unambiguous: part 1 has a fixed size given
``n_axes`` and gives each axis's law and ``n``, which fix the size of part 2; each axis's
``shaper_n`` fixes the size of its part 3.

Where the numbers come from in ``data``: ``n_axes = len(axes)``, ``timer_divisor``;
``counter_bits``; ``dac.zero_code`` and ``dac.code_max`` (which must be ``2**dac.bits − 1``);
per axis ``law``, ``lock_gain``, ``following_error_limit_counts``, ``ref_source``, the
``task`` constants (``kp``, ``ki_t``, ``kd_t``, ``k1_t``, ``ke``, ``kec``, ``n``, ``tables``) and
``filters`` (each section's ``b0``, ``b1``, ``b2``, ``a1``, ``a2``, ``frac_bits``) and
``shaper``.
Nothing else is part of it: not the axis names, roles or indices, the stored CRCs, the period
in seconds, the rig name, the D/A voltage range, ``f_u``, the provenance or ``verified``,
since none of them is compiled into ``st_consts_t``.

The byte-stream helpers here (:func:`constants_pairs`, :func:`pairs_bytes`,
:func:`table_bytes`) are the one home of the serialisation the CRCs of
:mod:`servotune.export.json` cover. This module must not import that one (it imports this).
"""

from __future__ import annotations

import hashlib
import struct
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from servotune.errors import ExportError
from servotune.laws.axis import (
    C_FILT,
    C_NF,
    CONST_HEADER,
    FILTER_WORDS,
    MAX_FILTERS,
    TASK_LAWS,
    AxisController,
    task_law,
)

__all__ = [
    "c_layout_bytes",
    "c_layout_sha256",
    "constants_bytes",
    "constants_pairs",
    "pairs_bytes",
    "shaper_bytes",
    "table_bytes",
]

INT16 = (-(2**15), 2**15 - 1)
INT32 = (-(2**31 - 1), 2**31 - 1)

# (q index, f index) in the constants vector; f index None: an integer, the pair (value, 0)
_CONST_PAIRS: tuple[tuple[int, int | None], ...] = tuple(
    (slot, slot + 1 if pair else None) for _, slot, pair in CONST_HEADER
)


# --- the byte streams ------------------------------------------------------------------------


def constants_pairs(
    controllers: Sequence[AxisController],
    ref_source: Sequence[int],
    *,
    timer_divisor: int,
    counter_bits: int,
    dac_bits: int,
    dac_zero: int,
) -> list[tuple[int, int]]:
    """The constants as (q, f) pairs, in the order of part 1 of the layout.

    Parameters
    ----------
    controllers : sequence of AxisController
        Per axis, rig order.
    ref_source : sequence of int
        Per axis −1 (external reference) or the index of the axis it follows.
    timer_divisor, counter_bits, dac_bits, dac_zero : int
        The 8253 divisor, the counter width [bits], the D/A width [bits] and its code of 0 V.

    Returns
    -------
    list of (int, int)
        ``2 + 35 · len(controllers)`` pairs.
    """
    pairs = [(len(controllers), 0), (int(timer_divisor), 0)]
    for ctl, src in zip(controllers, ref_source, strict=True):
        c = ctl.consts(counter_bits=counter_bits, dac_bits=dac_bits, dac_zero=dac_zero)
        for iq, jf in _CONST_PAIRS:
            pairs.append((int(c[iq]), 0 if jf is None else int(c[jf])))
        pairs.append((int(src), 0))
        pairs.append((int(c[C_NF]), 0))
        for k in range(MAX_FILTERS):  # b0 b1 b2 a1 a2, each with the section's frac_bits
            p = C_FILT + k * FILTER_WORDS
            *coefs, frac_bits = (int(v) for v in c[p : p + FILTER_WORDS])
            pairs.extend((q, frac_bits) for q in coefs)
    return pairs


def pairs_bytes(pairs: Sequence[tuple[int, int]]) -> bytes:
    """(q, f) pairs as little-endian (int32 q, int16 f), 6 bytes each.

    Parameters
    ----------
    pairs : sequence of (int, int)

    Returns
    -------
    bytes

    Raises
    ------
    ExportError
        If a ``q`` is outside ±(2³¹ − 1) or an ``f`` outside int16.

    Examples
    --------
    >>> pairs_bytes([(1, 0), (-2, 3)]).hex()
    '010000000000feffffff0300'
    """
    out = bytearray()
    for q, f in pairs:
        if not (INT32[0] <= q <= INT32[1]) or not (INT16[0] <= f <= INT16[1]):
            raise ExportError(f"constant ({q}, {f}) does not fit the (int32 q, int16 f) pair")
        out += struct.pack("<ih", q, f)
    return bytes(out)


def table_bytes(q: np.ndarray | Sequence[Sequence[int]], f: int) -> bytes:
    """One query table as the C layout (and its CRC) holds it.

    Parameters
    ----------
    q : array_like of int, shape (2n+1, 2n+1)
        Entries, row ``E = −n…n``, column ``EC = −n…n``; each must fit int16.
    f : int
        The table's fraction bits (int16).

    Returns
    -------
    bytes
        int16 ``n``, int16 ``f``, then the entries row-major, little-endian.

    Raises
    ------
    ValueError
        If the table is not square with an odd side, or an entry or ``f`` does not fit int16.

    Examples
    --------
    >>> table_bytes([[0, 1, 2], [3, 4, 5], [6, 7, -8]], 3).hex(" ", 2)
    '0100 0300 0000 0100 0200 0300 0400 0500 0600 0700 f8ff'
    """
    a = np.asarray(q, dtype=np.int64)
    size = a.shape[0] if a.ndim == 2 else -1
    if a.ndim != 2 or a.shape[1] != size or size % 2 != 1:
        raise ValueError(f"a table must be square with an odd side (2n+1), got shape {a.shape}")
    if a.size and (a.min() < INT16[0] or a.max() > INT16[1]):
        raise ValueError("table entries must fit int16")
    if not INT16[0] <= int(f) <= INT16[1]:
        raise ValueError(f"table fraction bits must fit int16, got {f}")
    return struct.pack("<hh", (size - 1) // 2, int(f)) + a.astype("<i2").tobytes()


# --- from a tables document ------------------------------------------------------------------


def _int(x: Any, where: str) -> int:
    if isinstance(x, bool) or not isinstance(x, int | np.integer):
        raise ExportError(f"{where} must be an integer, got {x!r}")
    return int(x)


def _controllers(axes: Sequence[Any]) -> list[AxisController]:
    """The axes' controllers (checked by :meth:`AxisController.from_dict`); a document's
    tables also carry ``n`` and ``crc32``, which the controller does not take, and every axis
    carries ``filters`` (``[]`` without any), which an unfiltered controller's dict omits."""
    ctls = []
    for i, ax in enumerate(axes):
        where = f"data.axes[{i}]"
        try:
            task = ax["task"]
            law = ax["law"]
            described = TASK_LAWS.get(law) if isinstance(law, str) else None
            if described is not None and described.tables and isinstance(task, Mapping):
                tabs = task["tables"]
                task = dict(task)
                task["tables"] = {t: {"f": tabs[t]["f"], "q": tabs[t]["q"]} for t in tabs}
            d = {
                "following_error_limit_counts": ax["following_error_limit_counts"],
                "law": ax["law"],
                "lock_gain": ax["lock_gain"],
                "task": task,
            }
            if ax["filters"] != []:  # always present in a tables document, [] without any
                d["filters"] = ax["filters"]
            if ax["shaper"] != []:  # the same
                d["shaper"] = ax["shaper"]
            ctls.append(AxisController.from_dict(d))
        except KeyError as exc:
            raise ExportError(f"{where} is missing the field {exc.args[0]!r}") from None
        except (ValueError, TypeError) as exc:
            raise ExportError(f"{where}: {exc}") from None
    return ctls


def c_layout_bytes(data: Mapping[str, Any]) -> bytes:
    """The C layout (module docstring) of a tables document's ``data`` section.

    Parameters
    ----------
    data : mapping
        ``tables_document(...)["data"]`` (or the ``data`` of a loaded export).

    Returns
    -------
    bytes
        Part 1 (the constants), part 2 (the fuzzy-PID axes' tables), part 3 (the shapers).

    Raises
    ------
    ExportError
        A missing or malformed field, ``dac.code_max`` other than ``2**dac.bits − 1``, or a
        constant that does not fit its C type.
    """
    constants, ctls = _constants_part(data)
    parts = [constants]
    for ctl in ctls:
        if ctl.task is not None and task_law(ctl.task).tables:
            parts.extend(table_bytes(q, f_t) for q, f_t in ctl.task.tables)  # type: ignore[union-attr]
    parts.extend(shaper_bytes(ctl.shaper) for ctl in ctls)
    return b"".join(parts)


def shaper_bytes(taps: Sequence[int]) -> bytes:
    """One axis's part 3 (module docstring): int32 ``len(taps)``, then the int32 taps."""
    return struct.pack(f"<i{len(taps)}i", len(taps), *taps)


def constants_bytes(data: Mapping[str, Any]) -> bytes:
    """Part 1 of :func:`c_layout_bytes` (the constants; ``data.constants_crc32`` is its
    CRC-32). Raises as :func:`c_layout_bytes`."""
    return _constants_part(data)[0]


def _constants_part(data: Mapping[str, Any]) -> tuple[bytes, list[AxisController]]:
    """Part 1 of the layout, and the axes' controllers it was built from."""
    try:
        axes = data["axes"]
        dac = data["dac"]
        divisor = _int(data["timer_divisor"], "data.timer_divisor")
        bits = _int(data["counter_bits"], "data.counter_bits")
        dac_bits = _int(dac["bits"], "data.dac.bits")
        dac_zero = _int(dac["zero_code"], "data.dac.zero_code")
        code_max = _int(dac["code_max"], "data.dac.code_max")
        refs = [_int(ax["ref_source"], f"data.axes[{i}].ref_source") for i, ax in enumerate(axes)]
    except KeyError as exc:
        raise ExportError(f"data is missing the field {exc.args[0]!r}") from None
    except TypeError as exc:
        raise ExportError(f"data is malformed: {exc}") from None
    if not 1 <= dac_bits <= 16 or code_max != 2**dac_bits - 1:
        raise ExportError(f"data.dac.code_max must be 2**bits - 1, got {code_max} for {dac_bits}")
    ctls = _controllers(axes)
    pairs = constants_pairs(
        ctls, refs, timer_divisor=divisor, counter_bits=bits, dac_bits=dac_bits, dac_zero=dac_zero
    )
    return pairs_bytes(pairs), ctls


def c_layout_sha256(data: Mapping[str, Any]) -> str:
    """SHA-256 of :func:`c_layout_bytes`, lower-case hex (``ST_TABLES_SHA256``).

    Parameters
    ----------
    data : mapping
        ``tables_document(...)["data"]``.

    Returns
    -------
    str
        64 hex digits.

    Raises
    ------
    ExportError
        As :func:`c_layout_bytes`.
    """
    return hashlib.sha256(c_layout_bytes(data)).hexdigest()
