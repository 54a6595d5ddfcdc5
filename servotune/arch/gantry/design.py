"""The gantry's linear sync-loop models.

:func:`sync_loop_models` (drive closed loops, compensator, latency, sensitivity) and
:func:`predicted_load_reduction` (what the loop gains predict for the ``load`` case). The
tuning of the drives and of the compensator is in :mod:`servotune.arch.gantry.synthesis`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import control
import numpy as np

from servotune._control import scipy_paths
from servotune.analysis.margins import filters_tf
from servotune.arch.gantry.config import (
    GantryConfig,
    case_config,
)
from servotune.laws.sync import SyncGains
from servotune.modal import discretize

__all__ = [
    "LoadPrediction",
    "SyncLoopModels",
    "compensator_tf",
    "predicted_load_reduction",
    "sync_loop_models",
    "sync_open_loop",
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


def compensator_tf(g: SyncGains, dt: float) -> control.TransferFunction:
    """The sync law as a discrete transfer function: the runtime PI, or ``Kp + Kd/T·(1 − z⁻¹)``."""
    if g.law == "pi":
        return _pi_tf(g.kp, g.ki * dt, dt)
    return control.tf([g.kp + g.kd / dt, -g.kd / dt], [1.0, 0.0], dt)


@scipy_paths
def sync_open_loop(
    comp: control.TransferFunction, t_slave: control.StateSpace, cfg: GantryConfig
) -> control.StateSpace:
    """``C(z)·z^-L·T_s(z)``: the compensator, the bus latency, the slave's closed drive loop."""
    dt = cfg.bus.cycle_s
    delay = control.tf([1.0], [1.0] + [0.0] * cfg.bus.latency_cycles, dt)
    return control.ss(comp) * control.ss(delay) * t_slave


@scipy_paths
def sync_loop_models(cfg: GantryConfig) -> SyncLoopModels:
    """Linear discrete models of the sync loop (friction, quantisation and beam left out; each
    drive's output filters in its loop).

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
        f = filters_tf(cfg.drive_filters(key), dt)  # the drive's output filters, if any
        if f is not None:
            c = c * control.ss(f)
        out[f"t_{key}"] = control.feedback(c * lsb * p_u, 1)
        # a load d adds to the drive input without the compute/delay lag:
        # y = P_d·d + P_u·lsb·u with u = −C·y, so y = P_d·d / (1 + C·lsb·P_u)
        p_d = control.ss(discretize(ax.plant, dt, 0.0))
        one = control.ss(control.tf([1.0], [1.0], dt))
        out[f"load_{key}"] = p_d * control.feedback(one, c * lsb * p_u)
    comp = compensator_tf(cfg.sync.gains, dt)
    loop = sync_open_loop(comp, out["t_slave"], cfg)
    sensitivity = control.feedback(control.ss(control.tf([1.0], [1.0], dt)), loop)
    return SyncLoopModels(compensator=comp, loop=loop, sensitivity=sensitivity, **out)


@scipy_paths
def predicted_load_reduction(cfg: GantryConfig) -> LoadPrediction:
    """What the loop gains predict for the ``load`` case: max |sync error| of the parallel
    topology (the slave's closed-loop load response) and of the listening one (that error
    shaped by the sync loop's sensitivity ``1/(1 + C·z^-L·T_s)``), linear and noise-free.

    Returns
    -------
    LoadPrediction
    """
    cfg, load = case_config(cfg, "load")
    models = sync_loop_models(cfg)
    n = cfg.n_cycles
    side = 0 if cfg.load.axis == "master" else 1
    d = load[:, side]
    resp = control.forced_response(models.load_slave, U=d)
    e_par = np.squeeze(resp.outputs) * (1.0 if side == 0 else -1.0)
    e_lis = np.squeeze(control.forced_response(models.sensitivity, U=e_par).outputs)
    p, li = float(np.max(np.abs(e_par[:n]))), float(np.max(np.abs(e_lis[:n])))
    ratio = li / p if p > 0.0 else math.nan  # no error to reduce: no ratio
    return LoadPrediction(parallel_max_counts=p, listening_max_counts=li, ratio=ratio)
