"""Tuning of the gantry's controllers (seed 003): each drive's PI and the sync compensator.

:func:`tune_sync` synthesises the compensator on the linear sync loop
(:func:`servotune.arch.gantry.design.sync_loop_models`); :func:`resolve_gains` fills in the gains
a gantry config leaves out (the drives, then the compensator).
"""

from __future__ import annotations

import math
from dataclasses import replace

import control
import numpy as np

from servotune.arch.gantry.config import GantryConfig, SyncSettings
from servotune.arch.gantry.design import _compensator_tf, _sync_open_loop, sync_loop_models
from servotune.errors import SpecError
from servotune.laws.sync import SyncGains
from servotune.tune.pi import DEFAULT_TARGETS, tune_pi

__all__ = ["resolve_gains", "tune_sync"]


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
        r = tune_pi(t_s, period_s=dt, compute_s=cfg.bus.latency_cycles * dt,
                    phase_margin_deg=s.phase_margin_deg, gain_margin_db=s.gain_margin_db,
                    max_sensitivity=s.max_sensitivity)  # fmt: skip
        return replace(s, kp=float(r.kp), ki=float(r.ki), kd=0.0)
    kd = s.kd or 0.0

    def meets(kp: float) -> bool:
        g = SyncGains(law="pd", kp=kp, kd=kd, limit_counts=s.limit_counts)
        loop = _sync_open_loop(_compensator_tf(g, dt), t_s, cfg)
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


def resolve_gains(cfg: GantryConfig) -> GantryConfig:
    """Fill in the gains the config leaves out: each drive's PI tuned at the bus cycle
    (:func:`~servotune.tune.pi.tune_pi`, PM 50°, GM 8 dB, Ms 1.6), then the compensator
    (:func:`tune_sync`)."""
    lsb = cfg.rig.dac.lsb_v
    drives = []
    for ax in (cfg.master, cfg.slave):
        if ax.kp is None or ax.ki is None:
            r = tune_pi(ax.plant, period_s=cfg.bus.cycle_s, compute_s=cfg.bus.compute_s,
                        lsb_v=lsb, **DEFAULT_TARGETS)  # fmt: skip
            ax = replace(ax, kp=float(r.kp) if ax.kp is None else ax.kp,
                         ki=float(r.ki) if ax.ki is None else ax.ki)  # fmt: skip
        drives.append(ax)
    cfg = replace(cfg, master=drives[0], slave=drives[1])
    s = cfg.sync
    if s.kp is None or (s.law == "pi" and s.ki is None):
        cfg = replace(cfg, sync=tune_sync(cfg))
    return cfg
