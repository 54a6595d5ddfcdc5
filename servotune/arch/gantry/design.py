"""The gantry's linear sync-loop models and the design of its gains; the config reader.

:func:`sync_loop_models` (drive closed loops, compensator, latency, sensitivity),
:func:`tune_sync` (the compensator), :func:`resolve_gains` (the drives, then the compensator),
:func:`load_gantry` (read a file, resolve the gains it leaves out) and
:func:`predicted_load_reduction` (what the loop gains predict for the ``load`` case).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import control
import numpy as np

from servotune.arch.gantry.config import (
    GantryConfig,
    SyncSettings,
    _case_config,
    gantry_from_dict,
)
from servotune.errors import ConfigError, SpecError
from servotune.io.files import read_toml
from servotune.laws.sync import SyncGains
from servotune.plant import discretize
from servotune.tune.pi import DEFAULT_TARGETS, tune_pi

__all__ = [
    "LoadPrediction",
    "SyncLoopModels",
    "load_gantry",
    "predicted_load_reduction",
    "resolve_gains",
    "sync_loop_models",
    "tune_sync",
]


@dataclass(frozen=True, slots=True, kw_only=True)
class SyncLoopModels:
    """Linear discrete models of the gantry's sync loop (:func:`sync_loop_models`), each with
    ``dt`` = the bus cycle.

    Attributes
    ----------
    t_master, t_slave : control.StateSpace
        The drives' closed position loops, command → position [counts/count].
    load_master, load_slave : control.StateSpace
        Load volts on that side → its position, the drive's loop closed [counts/V].
    compensator : control.TransferFunction
        The sync law ``C(z)`` [counts of compensation per count of sync error].
    loop : control.StateSpace
        The sync loop ``C(z)·z^-L·T_s(z)`` [-].
    sensitivity : control.StateSpace
        ``1/(1 + loop)`` [-]: the factor by which the listening compensator scales the
        parallel topology's sync error.
    """

    t_master: control.StateSpace
    t_slave: control.StateSpace
    load_master: control.StateSpace
    load_slave: control.StateSpace
    compensator: control.TransferFunction
    loop: control.StateSpace
    sensitivity: control.StateSpace

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of the models keyed by field name (python-control objects, not JSON)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True, slots=True, kw_only=True)
class LoadPrediction:
    """What the linear loop gains predict for the ``load`` case
    (:func:`predicted_load_reduction`), noise-free.

    Attributes
    ----------
    parallel_max_counts : float
        Max |sync error| of the parallel topology: the slave's closed-loop load response
        [counts].
    listening_max_counts : float
        Max |sync error| of the listening topology: that error shaped by the sync loop's
        sensitivity [counts].
    ratio : float
        ``listening_max_counts / parallel_max_counts`` [-].
    """

    parallel_max_counts: float
    listening_max_counts: float
    ratio: float

    def to_dict(self) -> dict[str, float]:
        """Plain dict keyed by field name (``sync.json``'s ``predicted_load``)."""
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}


def _pi_tf(kp: float, ki_t: float, dt: float) -> control.TransferFunction:
    """``Kp + Ki·T·z/(z−1)``: the runtime PI (:func:`~servotune.laws.pi.pi_step`)."""
    return control.tf([kp + ki_t, -kp], [1.0, -1.0], dt)


def _compensator_tf(g: SyncGains, dt: float) -> control.TransferFunction:
    """The sync law as a discrete transfer function: the runtime PI, or ``Kp + Kd/T·(1 − z⁻¹)``."""
    if g.law == "pi":
        return _pi_tf(g.kp, g.ki * dt, dt)
    return control.tf([g.kp + g.kd / dt, -g.kd / dt], [1.0, 0.0], dt)


def _sync_open_loop(
    comp: control.TransferFunction, t_slave: control.StateSpace, cfg: GantryConfig
) -> control.StateSpace:
    """``C(z)·z^-L·T_s(z)``: the compensator, the bus latency, the slave's closed drive loop."""
    dt = cfg.bus.cycle_s
    delay = control.tf([1.0], [1.0] + [0.0] * cfg.bus.latency_cycles, dt)
    return control.ss(comp) * control.ss(delay) * t_slave


def sync_loop_models(cfg: GantryConfig) -> SyncLoopModels:
    """Linear discrete models of the sync loop (friction, quantisation and beam left out).

    Returns
    -------
    SyncLoopModels
        The drives' closed loops and load responses, the compensator ``C(z)``, the sync loop
        ``C(z)·z^-L·T_s(z)`` and its sensitivity.
    """
    dt = cfg.bus.cycle_s
    lsb = cfg.rig.dac.lsb_v
    out: dict[str, Any] = {}
    for key, ax in (("master", cfg.master), ("slave", cfg.slave)):
        p_u = control.ss(discretize(ax.plant, dt, cfg.bus.compute_s + ax.plant.delay_s))
        c = control.ss(_pi_tf(ax.gains.kp, ax.gains.ki * dt, dt))
        out[f"t_{key}"] = control.feedback(c * lsb * p_u, 1)
        # a load d adds to the drive input without the compute/delay lag:
        # y = P_d·d + P_u·lsb·u with u = −C·y, so y = P_d·d / (1 + C·lsb·P_u)
        p_d = control.ss(discretize(ax.plant, dt, 0.0))
        one = control.ss(control.tf([1.0], [1.0], dt))
        out[f"load_{key}"] = p_d * control.feedback(one, c * lsb * p_u)
    comp = _compensator_tf(cfg.sync.gains, dt)
    loop = _sync_open_loop(comp, out["t_slave"], cfg)
    sensitivity = control.feedback(control.ss(control.tf([1.0], [1.0], dt)), loop)
    return SyncLoopModels(compensator=comp, loop=loop, sensitivity=sensitivity, **out)


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


def load_gantry(path: str | Path, *, resolve: bool = True) -> GantryConfig:
    """Read a gantry config (TOML, e.g. ``plants/gantry.toml``).

    Parameters
    ----------
    path : str or Path
    resolve : bool
        Tune the gains the file leaves out (:func:`resolve_gains`).

    Raises
    ------
    ConfigError
        If the file is missing, not TOML, or invalid (the message names the field).
    """
    p = Path(path)
    data = read_toml(p, ConfigError, "gantry config")
    try:
        cfg = gantry_from_dict(data, base_dir=p.parent)
    except ConfigError as exc:
        raise ConfigError(f"gantry config {str(p)!r}: {exc}") from None
    cfg = replace(cfg, name=cfg.name if cfg.name != "gantry" else p.stem.removesuffix(".sync"))
    return resolve_gains(cfg) if resolve else cfg


def predicted_load_reduction(cfg: GantryConfig) -> LoadPrediction:
    """What the loop gains predict for the ``load`` case: max |sync error| of the parallel
    topology (the slave's closed-loop load response) and of the listening one (that error
    shaped by the sync loop's sensitivity ``1/(1 + C·z^-L·T_s)``), linear and noise-free.

    Returns
    -------
    LoadPrediction
    """
    cfg, load = _case_config(cfg, "load")
    models = sync_loop_models(cfg)
    n = cfg.n_cycles
    side = 0 if cfg.load.axis == "master" else 1
    d = load[:, side]
    resp = control.forced_response(models.load_slave, U=d)
    e_par = np.squeeze(resp.outputs) * (1.0 if side == 0 else -1.0)
    e_lis = np.squeeze(control.forced_response(models.sensitivity, U=e_par).outputs)
    p, li = float(np.max(np.abs(e_par[:n]))), float(np.max(np.abs(e_lis[:n])))
    return LoadPrediction(parallel_max_counts=p, listening_max_counts=li, ratio=li / p)
