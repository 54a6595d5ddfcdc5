"""Tuning of the gantry's controllers: each drive's PI and the sync compensator
(docs/systems.md#fieldbus-gantry-with-a-listening-slave).

:func:`tune_sync` synthesises the compensator on the linear sync loop
(:func:`servotune.arch.gantry.design.sync_loop_models`); :func:`resolve_gains` fills in the gains
a gantry config leaves out (the drives, then the compensator).
"""

from __future__ import annotations

import functools
import math
from dataclasses import replace
from typing import Any

import control
import numpy as np

from servotune._control import scipy_paths
from servotune.arch.gantry.config import GantryConfig, SyncSettings
from servotune.arch.gantry.design import compensator_tf, sync_loop_models, sync_open_loop
from servotune.arch.gantry.margins import gantry_margins, worst_corner
from servotune.errors import SpecError
from servotune.laws.sync import SyncGains
from servotune.tune.pi import DEFAULT_TARGETS, tune_pi
from servotune.tune.robust import design_limits

__all__ = ["resolve_gains", "tune_sync"]


@scipy_paths
def tune_sync(cfg: GantryConfig) -> SyncSettings:
    """Synthesise the sync compensator on the linear sync loop (:func:`sync_loop_models`).

    PI: :func:`~servotune.tune.pi.tune_pi` on the slave's closed drive loop ``T_s(z)`` with
    the bus latency as whole cycles of lag (largest Ki under the phase margin, gain margin and
    sensitivity targets). PD: ``kd`` kept (0 if unset) and the largest ``kp`` whose loop meets
    the same targets (bisection on python-control's margins).

    Raises
    ------
    SpecError
        If no compensator meets the targets.
    """
    s = cfg.sync
    dt = cfg.bus.cycle_s
    t_s = sync_loop_models(replace(cfg, sync=replace(s, kp=0.0, ki=0.0, kd=0.0))).t_slave
    if s.law == "pi":
        r = tune_pi(
            t_s,
            period_s=dt,
            compute_s=cfg.bus.latency_cycles * dt,
            phase_margin_deg=s.phase_margin_deg,
            gain_margin_db=s.gain_margin_db,
            max_sensitivity=s.max_sensitivity,
        )
        return replace(s, kp=float(r.kp), ki=float(r.ki), kd=0.0)
    kd = s.kd or 0.0

    def meets(kp: float) -> bool:
        g = SyncGains(law="pd", kp=kp, kd=kd, limit_counts=s.limit_counts)
        loop = sync_open_loop(compensator_tf(g, dt), t_s, cfg)
        cl = control.feedback(loop, 1)
        if np.any(np.abs(cl.poles()) >= 1.0):
            return False
        w = np.geomspace(1e-2, math.pi / dt, 2000)
        resp = loop.frequency_response(w)
        gm, pm = control.stability_margins(resp)[:2]
        gm_db = 20 * math.log10(gm) if np.isfinite(gm) and gm > 0 else math.inf
        ms = float(np.max(1.0 / np.abs(1.0 + np.squeeze(resp.complex))))
        pm_ok = not np.isfinite(pm) or pm >= s.phase_margin_deg
        return pm_ok and gm_db >= s.gain_margin_db and ms <= s.max_sensitivity

    lo, hi = 0.0, 1.0
    if not meets(1e-6):
        raise SpecError(f"no PD sync compensator with kd={kd:g} s meets the sync-loop targets")
    while meets(hi) and hi < 1e6:
        lo, hi = hi, hi * 2
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if meets(mid) else (lo, mid)
    return replace(s, kp=lo, ki=0.0, kd=kd)


def _keeps(cfg: GantryConfig, axis: str) -> bool:
    """Every loop of ``axis`` (``master``, ``slave`` or ``sync``) keeps ``cfg.margins`` over
    the plant set (python-control, :func:`~servotune.arch.gantry.margins.gantry_margins`)."""
    lim = cfg.margins.limits
    return not any(lim.broken(m) for m in gantry_margins(cfg, loops=(axis,)))


def _aim(cfg: GantryConfig) -> dict[str, float]:
    """The margin limits tightened as robust designs aim (:func:`~servotune.tune.robust.
    design_limits`), as :func:`~servotune.tune.pi.tune_pi` targets."""
    a = design_limits(cfg.margins.limits)
    return {
        "phase_margin_deg": a.min_phase_margin_deg,
        "gain_margin_db": a.min_gain_margin_db,
        "max_sensitivity": a.max_sensitivity,
    }


def _with_drive_pi(
    cfg: GantryConfig, name: str, plant: Any, compute_s: float, targets: Any
) -> GantryConfig:
    """``cfg`` with drive ``name``'s missing PI gains designed on ``plant``."""
    ax = getattr(cfg, name)
    r = tune_pi(
        plant,
        period_s=cfg.bus.cycle_s,
        compute_s=compute_s,
        lsb_v=cfg.rig.dac.lsb_v,
        filters=cfg.drive_filters(name),
        **targets,
    )
    return replace(
        cfg,
        **{
            name: replace(
                ax,
                kp=float(r.kp) if ax.kp is None else ax.kp,
                ki=float(r.ki) if ax.ki is None else ax.ki,
            )
        },
    )


def _with_robust_sync(cfg: GantryConfig, slave_plant: Any, more_pm_deg: float) -> GantryConfig:
    """``cfg`` with the compensator designed on ``slave_plant`` behind the bus latency plus
    the extra cycles, aiming just inside the margin limits (``more_pm_deg`` more phase)."""
    m, s = cfg.margins, cfg.sync
    aim = _aim(cfg)
    aim["phase_margin_deg"] = min(aim["phase_margin_deg"] + more_pm_deg, 85.0)
    bus = replace(cfg.bus, latency_cycles=cfg.bus.latency_cycles + m.extra_cycles)
    at = replace(cfg, bus=bus, slave=replace(cfg.slave, plant=slave_plant), sync=replace(s, **aim))
    return replace(cfg, sync=replace(tune_sync(at), **{k: getattr(s, k) for k in aim}))


@functools.lru_cache(maxsize=32)
def resolve_gains(cfg: GantryConfig) -> GantryConfig:
    """Fill in the gains the config leaves out, each loop robust over ``cfg.margins``' plant
    set (:func:`~servotune.arch.gantry.margins.gantry_cases`).

    Each drive's PI is tuned at the bus cycle (:func:`~servotune.tune.pi.tune_pi`, PM 50°,
    GM 8 dB, Ms 1.6 on the nominal drive), then the compensator (:func:`tune_sync`, the
    config's targets). Where such a design breaks the margin limits somewhere in the plant set,
    it is designed again where the loop has least margin, aiming just inside the limits: a
    drive at gain and tau high, one extra cycle late; the compensator behind the latency plus
    the extra cycles, on the slave at tau high and gain high, else gain low, with a few degrees
    more phase if needed. A design that still breaks them is kept: the gantry's margins check
    names what breaks.

    A pure function of the (frozen) config: results are kept for the 32 latest configs, since
    a robust design takes seconds and a session loads the same gantry again and again.
    """
    m = cfg.margins
    late = cfg.bus.compute_s + m.extra_cycles * cfg.bus.cycle_s
    for name in ("master", "slave"):
        ax = getattr(cfg, name)
        if ax.kp is not None and ax.ki is not None:
            continue
        out = _with_drive_pi(cfg, name, ax.plant, cfg.bus.compute_s, DEFAULT_TARGETS)
        if not _keeps(out, name):
            out = _with_drive_pi(cfg, name, worst_corner(ax, m), late, _aim(cfg))
        cfg = out
    s = cfg.sync
    if s.kp is None or (s.law == "pi" and s.ki is None):
        out = replace(cfg, sync=tune_sync(cfg))
        if not _keeps(out, "sync"):
            high = worst_corner(cfg.slave, m)
            low = replace(
                high,
                gain_cps_per_v=cfg.slave.plant.gain_cps_per_v * (1.0 - m.spreads(cfg.slave)[0]),
            )
            # the sync loop's worst corner moves with its gains: aim at each candidate with a
            # little more phase until every case keeps the limits
            for more in (0.0, 1.0, 2.0, 4.0, 8.0):
                found = False
                for plant in (high, low):
                    out = _with_robust_sync(cfg, plant, more)
                    found = _keeps(out, "sync")
                    if found:
                        break
                if found:
                    break
        cfg = out
    return cfg
