"""The gantry runtime's constants in their C layout, and its SHA-256 (the C side's
``st_gantry_check_digest`` in ``servotune_gantry.c`` hashes the same bytes).

The layout is the constants of ``st_gantry_consts_t`` as little-endian int64, in this order
(:data:`GANTRY_LAYOUT_FIELDS`): the topology code and the bus latency [cycles]; per drive
(master, then slave) its law, lock gain, Kp, Ki·T (each ``q``, ``f``), following-error limit,
counter bits, D/A zero code and largest code, then its output filters: their number and
:data:`~servotune.laws.axis.MAX_FILTERS` slots of ``b0 b1 b2 a1 a2 frac_bits`` (the slots past
the last section zero: :func:`servotune.laws.axis.filter_block`); then the sync compensator's
Kp, Ki·T, Kd/T (each ``q``, ``f``), dead zone, limit, and the monitor's warning and trip
thresholds. 84 numbers, 672 bytes. The input is the ``data`` section of a gantry tables export
(:func:`servotune.export.gantry.gantry_document`).
"""

from __future__ import annotations

import hashlib
import struct
from collections.abc import Mapping
from typing import Any

from servotune.arch.gantry.config import TOPOLOGIES
from servotune.errors import ExportError
from servotune.laws.axis import MAX_FILTERS, TASK_LAWS
from servotune.laws.filters import SECTION_WORDS

__all__ = [
    "DRIVE_FIELDS",
    "FILTER_FIELDS",
    "GANTRY_LAYOUT_FIELDS",
    "SYNC_FIELDS",
    "gantry_layout_bytes",
    "gantry_layout_sha256",
    "gantry_layout_values",
]

DRIVE_FIELDS = ("law", "lock_q", "lock_f", "kp_q", "kp_f", "kit_q", "kit_f", "fe_limit",
                "counter_bits", "dac_zero", "dac_max")  # fmt: skip
"""One drive's fields in ``st_axis_consts_t`` that a gantry drive (PI law) uses, in order."""
FILTER_FIELDS = (
    "n_filters",
    *(f"filter{k}.{w}" for k in range(MAX_FILTERS) for w in SECTION_WORDS),
)
"""One drive's output filters in the layout: their number, then every slot."""
SYNC_FIELDS = ("kp_q", "kp_f", "kit_q", "kit_f", "kdt_q", "kdt_f", "dead_zone", "limit", "warn",
               "trip")  # fmt: skip
"""``st_sync_consts_t``'s fields, in order."""
GANTRY_LAYOUT_FIELDS = (
    "topology",
    "latency",
    *(f"master.{f}" for f in (*DRIVE_FIELDS, *FILTER_FIELDS)),
    *(f"slave.{f}" for f in (*DRIVE_FIELDS, *FILTER_FIELDS)),
    *(f"sync.{f}" for f in SYNC_FIELDS),
)
"""Every number of the layout, in order."""


def _get(d: Any, key: str, where: str) -> Any:
    if not isinstance(d, Mapping) or key not in d:
        raise ExportError(f"gantry export: {where}.{key} is missing")
    return d[key]


def _filter_words(filters: Any, where: str) -> list[Any]:
    """A drive's :data:`FILTER_FIELDS` from its controller's ``filters`` (each section's
    integers, in the order they run)."""
    if not isinstance(filters, list) or len(filters) > MAX_FILTERS:
        raise ExportError(
            f"gantry export: {where} must be a list of at most {MAX_FILTERS} sections"
        )
    out: list[Any] = [len(filters)]
    for k, sec in enumerate(filters):
        out += [_get(sec, w, f"{where}[{k}]") for w in SECTION_WORDS]
    return out + [0] * (len(SECTION_WORDS) * (MAX_FILTERS - len(filters)))


def gantry_layout_values(data: Mapping[str, Any]) -> tuple[int, ...]:
    """The layout's numbers (:data:`GANTRY_LAYOUT_FIELDS` order) from an export's ``data``.

    Raises
    ------
    ExportError
        A field is missing or not an integer where one is needed.
    """
    topo = _get(data, "topology", "data")
    if topo not in TOPOLOGIES:
        raise ExportError(f"gantry export: data.topology must be one of {', '.join(TOPOLOGIES)}")
    out = [TOPOLOGIES.index(topo), _get(data, "latency_cycles", "data")]
    dac = _get(data, "dac", "data")
    for i, name in enumerate(("master", "slave")):
        drive = _get(data, "drives", "data")[i]
        c = _get(drive, "controller", f"data.drives[{i}]")
        task = _get(c, "task", f"data.drives[{i}].controller")
        law = _get(c, "law", f"data.drives[{i}].controller")
        if law != "pi" or task is None:
            raise ExportError(f"gantry export: the {name} drive must run a PI law, got {law!r}")
        lock, kp, kit = c["lock_gain"], task["kp"], task["ki_t"]
        out += [
            TASK_LAWS["pi"].code,
            lock["q"],
            lock["f"],
            kp["q"],
            kp["f"],
            kit["q"],
            kit["f"],
            c["following_error_limit_counts"],
            _get(data, "counter_bits", "data"),
            dac["zero_code"],
            dac["code_max"],
            *_filter_words(c.get("filters", []), f"data.drives[{i}].controller.filters"),
        ]
    s = _get(data, "sync", "data")
    k = _get(s, "constants", "data.sync")
    out += [
        k["kp"]["q"],
        k["kp"]["f"],
        k["ki_t"]["q"],
        k["ki_t"]["f"],
        k["kd_t"]["q"],
        k["kd_t"]["f"],
        k["dead_zone_counts"],
        k["limit_counts"],
        s["warn_counts"],
        s["trip_counts"],
    ]
    for name, v in zip(GANTRY_LAYOUT_FIELDS, out, strict=True):
        if type(v) is not int or not -(2**63) <= v < 2**63:
            raise ExportError(f"gantry export: {name} must be an int64, got {v!r}")
    return tuple(out)


def gantry_layout_bytes(data: Mapping[str, Any]) -> bytes:
    """The 672 bytes the C runtime hashes (see the module docstring)."""
    values = gantry_layout_values(data)
    return struct.pack(f"<{len(values)}q", *values)


def gantry_layout_sha256(data: Mapping[str, Any]) -> str:
    """SHA-256 (hex) of :func:`gantry_layout_bytes`."""
    return hashlib.sha256(gantry_layout_bytes(data)).hexdigest()
