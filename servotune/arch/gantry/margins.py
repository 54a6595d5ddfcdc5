"""Margins of the gantry's loops over what is not known.

The loops the gantry runs: each drive's position PI, closed in the drive at the bus cycle
(ZOH, the drive's compute time and the plant's delay, the drive's output filters, the D/A LSB),
and, where the deployed
topology has one (``listening``, ``cross``), the sync loop ``C(z)·z^-L·T_s(z)`` through the
compensator, the bus latency and the slave's closed drive loop. Each is taken on the plant set
of :func:`gantry_cases`: the nominal drives and the corners of gain ± ``gain_spread`` and tau ±
``tau_spread`` of both drives (the sync loop sees only the slave's), each also with
``extra_cycles`` more latency (a bus cycle late: the bus jitter, at most a cycle, is inside
it). Gain, phase and delay margin, Ms, Mt and bandwidth by python-control
(:func:`servotune.analysis.margins.loop_margins`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from servotune.analysis.margins import (
    GainSet,
    LoopMargins,
    MarginLimits,
    loop_margins,
    loop_model,
    margin_grid,
)
from servotune.arch.gantry.config import GantryAxis, GantryConfig, GantryMargins
from servotune.arch.gantry.design import sync_loop_models
from servotune.plant import Plant

__all__ = [
    "LOOP_NAMES",
    "SYNC_TOPOLOGIES",
    "GantryCase",
    "gantry_cases",
    "gantry_margins",
    "margin_failures",
    "worst_corner",
]

SYNC_TOPOLOGIES = ("listening", "cross")
"""Topologies that run the sync compensator (the others have no sync loop)."""

LOOP_NAMES = {"master": "the master's drive loop", "slave": "the slave's drive loop",
              "sync": "the sync loop"}  # fmt: skip
"""The gantry's loops as messages name them."""


@dataclass(frozen=True, slots=True, kw_only=True)
class GantryCase:
    """One plant set of the gantry's robustness check.

    Attributes
    ----------
    label : str
        ``"nominal"`` or ``"gain+,tau-"`` …, with ``"+1cycle"`` where it is late.
    master, slave : Plant
    extra_cycles : int
        Latency added to every loop [bus cycles].
    """

    label: str
    master: Plant
    slave: Plant
    extra_cycles: int = 0


def _scaled(p: Plant, fg: float, ft: float) -> Plant:
    changes = {"gain_cps_per_v": p.gain_cps_per_v * fg, "tau_s": p.tau_s * ft}
    if p.gain_neg_cps_per_v is not None:
        changes["gain_neg_cps_per_v"] = p.gain_neg_cps_per_v * fg
    return replace(p, **changes)


def worst_corner(axis: GantryAxis, m: GantryMargins) -> Plant:
    """The corner a PI on an integrating plant has least margin at: gain and tau both high,
    by the drive's spreads (the robust designs of :mod:`servotune.arch.gantry.synthesis` aim
    there; every corner is checked)."""
    gs, ts = m.spreads(axis)
    return _scaled(axis.plant, 1.0 + gs, 1.0 + ts)


def gantry_cases(cfg: GantryConfig) -> tuple[GantryCase, ...]:
    """The plant set of ``cfg.margins``: nominal and the four gain/tau corners (both drives at
    the same corner, each by its own spreads: each loop sees one drive), each on time and
    ``extra_cycles`` late."""
    m = cfg.margins
    sets = [("nominal", cfg.master.plant, cfg.slave.plant)]
    (mg, mt), (sg_, st_) = m.spreads(cfg.master), m.spreads(cfg.slave)
    if max(mg, mt, sg_, st_) > 0:
        for sg in (-1, 1):
            for st in (-1, 1):
                sets.append(
                    (
                        f"gain{'-+'[sg > 0]},tau{'-+'[st > 0]}",
                        _scaled(cfg.master.plant, 1.0 + sg * mg, 1.0 + st * mt),
                        _scaled(cfg.slave.plant, 1.0 + sg * sg_, 1.0 + st * st_),
                    )
                )
    lates = [0] + ([m.extra_cycles] if m.extra_cycles > 0 else [])
    return tuple(
        GantryCase(label=label + (f"+{x}cycle" if x else ""), master=pm, slave=ps, extra_cycles=x)
        for label, pm, ps in sets
        for x in lates
    )


def gantry_margins(
    cfg: GantryConfig, loops: Sequence[str] = ("master", "slave", "sync")
) -> tuple[LoopMargins, ...]:
    """Every loop of the gantry (of ``loops``) on every case of :func:`gantry_cases`
    (the gains of those loops must be resolved:
    :func:`servotune.arch.gantry.synthesis.resolve_gains`).

    Returns
    -------
    tuple of LoopMargins
        ``axis`` ``"master"``/``"slave"`` with ``loop`` ``"drive"`` (gains in D/A codes per
        count), and ``axis`` ``"sync"``, ``loop`` ``"sync"`` (gains in counts of compensation
        per count of sync error) where the topology runs the compensator.
    """
    dt = cfg.bus.cycle_s
    lsb = cfg.rig.dac.lsb_v
    out = []
    for case in gantry_cases(cfg):
        late = case.extra_cycles * dt
        for name, ax, plant in (
            ("master", cfg.master, case.master),
            ("slave", cfg.slave, case.slave),
        ):
            if name not in loops:
                continue
            g = GainSet(ax.gains.kp, ax.gains.ki * dt)
            model = loop_model(
                plant,
                g,
                period_s=dt,
                lag_s=cfg.bus.compute_s + plant.delay_s + late,
                lsb_volts=lsb,
                filters=cfg.drive_filters(name),
            )
            figures = loop_margins(model, margin_grid(plant, dt))
            out.append(
                LoopMargins(
                    axis=name,
                    loop="drive",
                    cell=None,
                    plant=case.label,
                    gains=g,
                    period_s=dt,
                    **figures.as_fields(),
                )
            )
        if "sync" in loops and cfg.topology in SYNC_TOPOLOGIES:
            # the sync loop: the slave's closed drive loop behind the bus latency, plus the
            # extra cycles
            bus = replace(cfg.bus, latency_cycles=cfg.bus.latency_cycles + case.extra_cycles)
            c = replace(cfg, bus=bus, slave=replace(cfg.slave, plant=case.slave))
            s = cfg.sync.gains
            g = GainSet(s.kp, s.ki * dt, s.kd / dt)
            loop = sync_loop_models(c).loop
            figures = loop_margins(loop, margin_grid(case.slave, dt))
            out.append(
                LoopMargins(
                    axis="sync",
                    loop="sync",
                    cell=None,
                    plant=case.label,
                    gains=g,
                    period_s=dt,
                    **figures.as_fields(),
                )
            )
    return tuple(out)


def margin_failures(margins: Sequence[LoopMargins], limits: MarginLimits) -> list[str]:
    """One line per loop that breaks ``limits`` somewhere in the plant set, naming the loop,
    the plant case where it has least margin and what it breaks (empty: every loop keeps
    them)."""
    out = []
    for loop in LOOP_NAMES:
        bad = [(m, limits.broken(m)) for m in margins if m.axis == loop and limits.broken(m)]
        if bad:
            m, broken = min(bad, key=lambda mb: (mb[0].stable, mb[0].phase_margin_deg))
            out.append(f"margins: {LOOP_NAMES[loop]} on plant {m.plant}: {'; '.join(broken)}")
    return out
