"""The gantry tuning file: what ``servotune tune plants/gantry.toml`` writes and ``verify`` and
``export-table`` read.

It holds what the gantry's runtime runs, every constant as its quantised ``(q, f)`` pair
(nothing is re-quantised later): both drives' controllers (position PI at the bus cycle, lock
gain, following-error limit), the sync compensator's constants (law, Kp, Ki·T, Kd/T, dead zone,
limit) and the monitor's warning and trip thresholds; the topology, the bus cycle and the
latency it was tuned for; the design values (floats, for people); the gantry config file and
its rig file it was made from (name, path, SHA-256), and the tool version.

JSON with sorted keys, two-space indent and a trailing newline (the same tuning gives the same
bytes); ``"schema": "servotune.gantry-tuning/1"``. Reading is strict: every key known, every
integer an integer, a PI compensator without a derivative constant and a PD one without an
integral constant, a PI law on each drive.

:func:`apply_tuning` gives the gantry config that runs exactly these integers (the drives'
``controller``, the compensator's ``constants``), with the float gains the margins are taken
of set to their values: what is checked is what runs.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from servotune._version import __version__
from servotune.arch.gantry.config import TOPOLOGIES, GantryConfig
from servotune.arch.gantry.load import load_gantry
from servotune.arch.gantry.margins import gantry_margins
from servotune.arch.gantry.run import simulate_gantry
from servotune.arch.gantry.synthesis import resolve_gains
from servotune.digest import bytes_sha256
from servotune.errors import ConfigError, TuningError
from servotune.io.files import (
    atomic_write_text,
    json_safe,
    json_text,
    parse_json_as,
    parse_toml,
    read_bytes,
)
from servotune.laws.axis import LAW_PI, AxisController
from servotune.laws.sync import SYNC_LAWS, SyncConstants
from servotune.validate import check_keys, show_value

__all__ = [
    "GANTRY_TUNING_SCHEMA",
    "GantryTuning",
    "apply_tuning",
    "gantry_rig_path",
    "gantry_tuning_to_string",
    "is_gantry_config",
    "read_gantry_tuning",
    "read_gantry_tuning_bytes",
    "tune_gantry",
    "write_gantry_tuning",
]

GANTRY_TUNING_SCHEMA = "servotune.gantry-tuning/1"
DRIVES = ("master", "slave")
_SHA256 = re.compile(r"[0-9a-f]{64}")
_MAX_NAME = 256


@dataclass(frozen=True, slots=True, kw_only=True)
class GantryTuning:
    """A complete tuning of a gantry, as its runtime runs it.

    Parameters
    ----------
    gantry_name, gantry_path, gantry_sha256 : str
        The gantry config file it was made from (path as given to ``tune``).
    rig_name, rig_sha256 : str
        The rig file that config names (hardware facts).
    topology : str
        The deployed topology (:data:`~servotune.arch.gantry.config.TOPOLOGIES`).
    cycle_s : float
        Bus cycle [s] (the constants fold it in).
    latency_cycles : int
        Bus latency of the master's feedback to the slave it was tuned for [cycles].
    master, slave : AxisController
        The drives' controllers (PI law).
    sync_law : str
        ``"pi"`` or ``"pd"``.
    sync : SyncConstants
        The compensator's constants.
    warn_counts, trip_counts : int
        The monitor's thresholds on |sync error| [counts], 0 off.
    design, provenance : mapping
        Design values (floats) and the tuner's figures; the tool version.
    """

    gantry_name: str
    gantry_path: str
    gantry_sha256: str
    rig_name: str
    rig_sha256: str
    topology: str
    cycle_s: float
    latency_cycles: int
    master: AxisController
    slave: AxisController
    sync_law: str
    sync: SyncConstants
    warn_counts: int
    trip_counts: int
    design: Mapping[str, Any] = field(default_factory=dict, compare=False)
    provenance: Mapping[str, Any] = field(default_factory=dict, compare=False)

    @property
    def drives(self) -> tuple[AxisController, AxisController]:
        """(master, slave)."""
        return (self.master, self.slave)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (the file's content)."""
        return {
            "bus": {"cycle_s": float(self.cycle_s), "latency_cycles": self.latency_cycles},
            "design": json_safe(self.design),
            "drives": {n: c.to_dict() for n, c in zip(DRIVES, self.drives, strict=True)},
            "gantry": {
                "name": self.gantry_name,
                "path": self.gantry_path,
                "sha256": self.gantry_sha256,
            },
            "provenance": json_safe(self.provenance),
            "rig": {"name": self.rig_name, "sha256": self.rig_sha256},
            "schema": GANTRY_TUNING_SCHEMA,
            "sync": {
                "constants": self.sync.to_dict(),
                "law": self.sync_law,
                "trip_counts": self.trip_counts,
                "warn_counts": self.warn_counts,
            },
            "topology": self.topology,
        }

    @classmethod
    def from_dict(cls, d: Any) -> GantryTuning:
        """Inverse of :meth:`to_dict`; every field checked (see the module docstring).

        Raises
        ------
        TuningError
            Wrong schema, a missing, unknown or malformed field (the message names it).
        """
        if not isinstance(d, dict):
            raise TuningError("a gantry tuning file must hold a JSON object")
        if d.get("schema") != GANTRY_TUNING_SCHEMA:
            raise TuningError(
                f"schema must be {GANTRY_TUNING_SCHEMA!r}, got {show_value(d.get('schema'))}"
            )
        try:
            check_keys(
                d,
                "",
                ("bus", "drives", "gantry", "rig", "schema", "sync", "topology"),
                ("design", "provenance"),
            )
            bus = check_keys(d["bus"], "bus", ("cycle_s", "latency_cycles"))
            gantry = check_keys(d["gantry"], "gantry", ("name", "path", "sha256"))
            rig = check_keys(d["rig"], "rig", ("name", "sha256"))
            drives = check_keys(d["drives"], "drives", DRIVES)
            sync = check_keys(d["sync"], "sync", ("constants", "law", "trip_counts", "warn_counts"))
            ctl = {}
            for name in DRIVES:
                try:
                    ctl[name] = AxisController.from_dict(drives[name])
                except ValueError as exc:
                    raise ValueError(f"drives.{name}: {exc}") from None
                if ctl[name].law != LAW_PI:
                    raise ValueError(f"drives.{name}.law must be 'pi' (a drive's position loop)")
            law, sc = sync["law"], _sync_constants(sync["constants"])
            if law not in SYNC_LAWS:
                raise ValueError(
                    f"sync.law must be one of {', '.join(SYNC_LAWS)}, got {show_value(law)}"
                )
            if law == "pi" and sc.kd_t.q != 0:
                raise ValueError("sync.constants.kd_t must be 0 for a PI compensator")
            if law == "pd" and sc.ki_t.q != 0:
                raise ValueError("sync.constants.ki_t must be 0 for a PD compensator")
            warn, trip = _count(sync, "warn_counts"), _count(sync, "trip_counts")
            if warn and trip and warn >= trip:
                raise ValueError(
                    f"sync.warn_counts must be < sync.trip_counts, got {warn} >= {trip}"
                )
            cycle, lat = bus["cycle_s"], bus["latency_cycles"]
            if type(cycle) is not float or not 1e-6 <= cycle <= 0.01:
                raise ValueError(
                    f"bus.cycle_s must be a number in 1e-6..0.01 [s], got {show_value(cycle)}"
                )
            if type(lat) is not int or not 0 <= lat <= 1000:
                raise ValueError(
                    f"bus.latency_cycles must be an integer in 0..1000, got {show_value(lat)}"
                )
            if d["topology"] not in TOPOLOGIES:
                raise ValueError(
                    f"topology must be one of {', '.join(TOPOLOGIES)}, got "
                    f"{show_value(d['topology'])}"
                )
            for where, sha in (("gantry.sha256", gantry["sha256"]), ("rig.sha256", rig["sha256"])):
                if not isinstance(sha, str) or not _SHA256.fullmatch(sha):
                    raise ValueError(
                        f"{where} must be 64 lower-case hex digits, got {show_value(sha)}"
                    )
            for key in ("design", "provenance"):
                if not isinstance(d.get(key, {}), dict):
                    raise ValueError(f"{key} must be an object")
            return cls(
                gantry_name=_text(gantry["name"], "gantry.name"),
                gantry_path=_text(gantry["path"], "gantry.path", 4096),
                gantry_sha256=gantry["sha256"],
                rig_name=_text(rig["name"], "rig.name"),
                rig_sha256=rig["sha256"],
                topology=d["topology"],
                cycle_s=cycle,
                latency_cycles=lat,
                master=ctl["master"],
                slave=ctl["slave"],
                sync_law=law,
                sync=sc,
                warn_counts=warn,
                trip_counts=trip,
                design=d.get("design", {}),
                provenance=d.get("provenance", {}),
            )
        except ValueError as exc:
            raise TuningError(str(exc)) from None


def _text(v: object, where: str, max_len: int = _MAX_NAME) -> str:
    if not isinstance(v, str) or not 0 < len(v) <= max_len:
        raise ValueError(
            f"{where} must be a string of 1 to {max_len} characters, got {show_value(v)}"
        )
    return v


def _count(d: Mapping[str, Any], key: str) -> int:
    v = d[key]
    if type(v) is not int or not 0 <= v <= 2**31 - 1:
        raise ValueError(
            f"sync.{key} must be an integer in 0..2147483647 [counts], got {show_value(v)}"
        )
    return v


def _sync_constants(d: Any) -> SyncConstants:
    d = check_keys(d, "sync.constants", ("dead_zone_counts", "kd_t", "ki_t", "kp", "limit_counts"))
    for key, lo in (("dead_zone_counts", 0), ("limit_counts", 1)):
        v = d[key]
        if type(v) is not int or not lo <= v <= 2**31 - 1:
            raise ValueError(
                f"sync.constants.{key} must be an integer in {lo}..2147483647 "
                f"[counts], got {show_value(v)}"
            )
    try:
        return SyncConstants.from_dict(d)
    except ValueError as exc:
        raise ValueError(f"sync.constants: {exc}") from None


def gantry_tuning_to_string(tuning: GantryTuning) -> str:
    """The file's text: sorted keys, two-space indent, trailing newline."""
    return json_text(tuning.to_dict())


def write_gantry_tuning(tuning: GantryTuning, path: str | Path) -> None:
    """Write the tuning file atomically (:func:`~servotune.io.files.atomic_write_bytes`).

    Raises
    ------
    OSError
        The folder is missing or not writable; nothing is left half-written.
    """
    atomic_write_text(path, gantry_tuning_to_string(tuning))


def read_gantry_tuning_bytes(raw: bytes, src: str) -> GantryTuning:
    """Parse a gantry tuning from the bytes a caller already holds (``src`` names them)."""
    return parse_json_as(raw, src, TuningError, GantryTuning.from_dict)


def read_gantry_tuning(path: str | Path) -> GantryTuning:
    """Read a gantry tuning file (see the module docstring)."""
    return read_gantry_tuning_bytes(read_bytes(path, TuningError, "tuning file"), str(path))


def is_gantry_config(data: Mapping[str, Any]) -> bool:
    """Whether parsed TOML is a gantry config (it has a ``[gantry]`` table)."""
    return isinstance(data.get("gantry"), Mapping)


def apply_tuning(cfg: GantryConfig, tuning: GantryTuning) -> GantryConfig:
    """``cfg`` running exactly the tuning's integers (drives, compensator, monitor), with its
    float gains set to their values (the margins are taken of what runs).

    Raises
    ------
    TuningError
        The tuning's topology or bus cycle is not the config's.
    """
    if tuning.topology != cfg.topology:
        raise TuningError(
            f"the tuning is for the {tuning.topology} topology, the gantry "
            f"{cfg.name!r} deploys {cfg.topology}"
        )
    dt = cfg.bus.cycle_s
    if not math.isclose(tuning.cycle_s, dt, rel_tol=1e-12):
        raise TuningError(
            f"the tuning is for a bus cycle of {tuning.cycle_s!r} s, the gantry "
            f"{cfg.name!r} runs at {dt!r} s"
        )
    drives = {}
    for name, ctl in zip(DRIVES, tuning.drives, strict=True):
        task = ctl.task
        fe = ctl.following_error_limit_counts
        drives[name] = replace(
            getattr(cfg, name),
            controller=ctl,
            kp=task.kp.value,
            ki=task.ki_t.value / dt,
            following_error_limit_counts=fe,
        )
    k = tuning.sync
    sync = replace(
        cfg.sync,
        law=tuning.sync_law,
        constants=k,
        kp=k.kp.value,
        ki=k.ki_t.value / dt if tuning.sync_law == "pi" else None,
        kd=k.kd_t.value * dt if tuning.sync_law == "pd" else None,
        dead_zone_counts=k.dead_zone_counts,
        limit_counts=k.limit_counts,
        warn_counts=tuning.warn_counts,
        trip_counts=tuning.trip_counts,
    )
    return replace(cfg, sync=sync, **drives)


def tune_gantry(path: str | Path, *, raw: bytes | None = None) -> GantryTuning:
    """What ``servotune tune GANTRY.toml`` computes: the gains the config leaves out
    (:func:`~servotune.arch.gantry.synthesis.resolve_gains`: each drive's PI, then the
    compensator, each robust over the config's ``[margins]`` plant set), quantised as the
    runtime runs them.

    The design record holds the float gains, the worst margins of each loop over the plant set
    and the sync error of each case on the nominal drives.

    Parameters
    ----------
    path : str or Path
        The gantry config (TOML).
    raw : bytes, optional
        Its bytes if already read (they are what is hashed).

    Raises
    ------
    ConfigError
        The config (or its rig) cannot be read or is invalid.
    """
    raw = read_bytes(path, ConfigError, "gantry config") if raw is None else raw
    cfg = resolve_gains(load_gantry(path, raw=raw))
    rig_sha = bytes_sha256(read_bytes(gantry_rig_path(raw, path), ConfigError, "rig file"))
    c_m, c_s = cfg.controllers()
    s = cfg.sync
    tuning = GantryTuning(
        gantry_name=cfg.name,
        gantry_path=Path(path).as_posix(),
        gantry_sha256=bytes_sha256(raw),
        rig_name=cfg.rig.name,
        rig_sha256=rig_sha,
        topology=cfg.topology,
        cycle_s=float(cfg.bus.cycle_s),
        latency_cycles=cfg.bus.latency_cycles,
        master=c_m,
        slave=c_s,
        sync_law=s.law,
        sync=cfg.sync_constants,
        warn_counts=s.warn_counts,
        trip_counts=s.trip_counts,
        provenance={"tool": "servotune", "tool_version": __version__},
    )
    return replace(tuning, design=_design(apply_tuning(cfg, tuning), cfg))


def gantry_rig_path(raw: bytes, path: str | Path) -> Path:
    """The rig file a gantry config (its bytes ``raw``, read from ``path``) names, relative to
    the config's directory (validated by :func:`load_gantry` already)."""
    data = parse_toml(raw, str(path), ConfigError, "gantry config")
    return Path(path).parent / data["gantry"]["rig"]


def _design(run: GantryConfig, designed: GantryConfig) -> dict[str, Any]:
    """The design record: float gains as designed, the tuned loops' worst margins over the plant
    set, and each case's sync error on the nominal drives (what runs: ``run``)."""
    loops = {}
    for m in gantry_margins(run):
        w = loops.get(m.axis)
        if w is None or (m.stable, m.phase_margin_deg) < (w.stable, w.phase_margin_deg):
            loops[m.axis] = m
    cases = {}
    for case in ("load", "mismatch"):
        r = simulate_gantry(run, case=case).metrics()
        cases[case] = {
            "max_sync_error_counts": r.max_sync_error_counts,
            "rms_sync_error_counts": r.rms_sync_error_counts,
            "tripped": r.tripped,
        }
    d = designed
    return {
        "cases": cases,
        "gains": {
            "master": {"kp": d.master.kp, "ki": d.master.ki},
            "slave": {"kp": d.slave.kp, "ki": d.slave.ki},
            "sync": {"kp": d.sync.kp, "ki": d.sync.ki or 0.0, "kd": d.sync.kd or 0.0},
        },
        "worst_margins": {
            axis: {
                "plant": m.plant,
                "phase_margin_deg": m.phase_margin_deg,
                "gain_margin_db": m.gain_margin_db,
                "max_sensitivity": m.max_sensitivity,
                "stable": m.stable,
            }
            for axis, m in loops.items()
        },
    }
