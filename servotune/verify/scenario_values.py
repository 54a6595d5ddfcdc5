"""A verification scenario's inputs and the limited figures of its runs (docs/formats.md#spec-file):
the move's windows, a hold's holding window, overshoot and settling, sync errors, saturation
and faults, per plant set, from the engine's traces."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from servotune.analysis.plant_cases import mode_factors
from servotune.errors import SpecError
from servotune.laws.axis import FAULT_MASK, FLAG_SATURATED, MODE_TASK
from servotune.metrics import step_info
from servotune.rig import Rig
from servotune.scenarios import Inputs, build_scenario, sync_move_for
from servotune.validate import show_value
from servotune.verify.spec import ScenarioSpec

__all__ = [
    "MoveWindows",
    "evaluate",
    "hold_from",
    "master_axis",
    "move_windows",
    "scenario_inputs",
    "step_values",
]


@dataclass(frozen=True, slots=True, kw_only=True)
class MoveWindows:
    """Where a move's figures are measured."""

    start: int  # last tick before the master's reference moves
    target: float  # the reference's final value [counts]
    steady: tuple[int, int]  # [lo, hi) ticks of the steady-lag window
    stop: int = 0  # first tick the master's reference no longer moves


def scenario_inputs(rig: Rig, sc: ScenarioSpec) -> Inputs:
    assert sc.seconds is not None  # resolved by ScenarioSpec
    if sc.kind == "sync":
        return sync_move_for(rig, sc).inputs
    if sc.kind == "track":
        return build_scenario(rig, "track", axis=master_axis(rig)[1], seconds=sc.seconds).inputs
    n = math.floor(sc.seconds / rig.period_s + 0.5)
    if n < 3:
        raise SpecError(f"scenario.{sc.name}.seconds gives only {n} ticks")
    return Inputs.hold(n, len(rig.axes))


def master_axis(rig: Rig) -> tuple[int, str]:
    for i, a in enumerate(rig.axes):
        if a.role == "master":
            return i, a.name
    raise SpecError(f"rig {show_value(rig.name)} has no master axis")


def move_windows(rig: Rig, sc: ScenarioSpec, inputs: Inputs) -> MoveWindows:
    i_m, _ = master_axis(rig)
    ref = inputs.ref_counts[:, i_m]
    moving = np.flatnonzero(ref != ref[0])
    if moving.size == 0:
        raise SpecError(f"scenario {show_value(sc.name)}: the master's reference does not move")
    start = max(int(moving[0]) - 1, 0)
    direction = 1 if ref[-1] >= ref[0] else -1
    dr = direction * np.diff(ref)
    cruise = np.flatnonzero(dr >= dr.max() - 2)  # within 2 counts/tick of the top speed
    c0, c1 = int(cruise[0]) + 1, int(cruise[-1]) + 1
    hi = c1
    for j, a in enumerate(rig.axes):
        if a.role == "slave":
            changed = np.flatnonzero(inputs.load_v[:, j] != inputs.load_v[0, j])
            if changed.size:
                hi = min(hi, int(changed[0]))
    lo = (c0 + hi) // 2
    if hi - lo < 3:
        raise SpecError(
            f"scenario {show_value(sc.name)} has no constant-speed part before the load step "
            f"to measure "
            "the steady lag; lengthen seconds or shorten accel_s"
        )
    stop = int(np.flatnonzero(np.diff(ref))[-1]) + 1  # the reference is constant from here
    return MoveWindows(start=start, target=float(ref[-1]), steady=(lo, hi), stop=stop)


def hold_from(rig: Rig, sc: ScenarioSpec, inputs: Inputs) -> int:
    """First tick of a hold's holding window (``settle_s`` in); SpecError if none is left."""
    k0 = math.ceil(sc.settle_s / rig.period_s)
    if k0 >= inputs.n_ticks:
        raise SpecError(
            f"scenario {show_value(sc.name)}: settle_s ({sc.settle_s:g} s) leaves no tick of "
            f"its {inputs.n_ticks} to measure the holding band; shorten settle_s"
        )
    return k0


RESIDUAL_BAND = (0.6, 1.6)
"""The residual vibration's band, relative to the lowest and the highest mode's frequency
range (:func:`residual_vibration`)."""
RESIDUAL_ORDER = 4
"""Butterworth order of that band-pass (80 dB a decade outside it: a slow settling of 1000
counts a decade below the band leaks under 1 count)."""
RESIDUAL_SETTLE_PERIODS = 2
"""Periods of the band's low edge after the reference stops before the residual is measured
(the band-pass's own response to the stop has died out by then: measured on a 3 Hz closed loop
stopping from 12500 counts/s, under 1 count)."""


def residual_vibration(pos: np.ndarray, rig: Rig, axis: int, stop: int) -> np.ndarray:
    """Largest |band-passed position| [counts] after the reference stops, per run (rows of
    ``pos``, shape (runs, ticks)): the vibration left at the axis's modes
    (docs/formats.md#spec-file).

    The position goes through a causal Butterworth band-pass (:data:`RESIDUAL_ORDER`) from
    :data:`RESIDUAL_BAND` ``[0]`` times the lowest mode's low end to ``[1]`` times the highest
    mode's high end (:func:`servotune.analysis.plant_cases.mode_factors`), run from the first
    tick so it has settled through the move; the peak is taken from
    :data:`RESIDUAL_SETTLE_PERIODS` periods of the band's low edge after ``stop`` to the end.
    """
    from scipy.signal import butter, sosfilt

    modes = rig.axes[axis].plant.modes
    lo = min(m.freq_hz * mode_factors(m)[0] for m in modes) * RESIDUAL_BAND[0]
    nyq = 0.5 / rig.period_s
    hi = min(max(m.freq_hz * mode_factors(m)[1] for m in modes) * RESIDUAL_BAND[1], 0.95 * nyq)
    sos = butter(RESIDUAL_ORDER, [lo, hi], btype="bandpass", fs=1.0 / rig.period_s, output="sos")
    x = np.ascontiguousarray(pos, dtype=float)
    v = sosfilt(sos, x - x[:, :1], axis=1)
    k0 = stop + math.ceil(RESIDUAL_SETTLE_PERIODS / (lo * rig.period_s))
    if k0 >= x.shape[1]:
        return np.full(x.shape[0], np.nan)
    return np.abs(v[:, k0:]).max(axis=1)


def step_values(
    t: np.ndarray, y: np.ndarray, y_init: float, target: float, band_pct: float
) -> tuple[float, float]:
    info = step_info(t, y, y_init=y_init, y_final=target, settling_threshold=band_pct / 100.0)
    settle = info.settling_time_s
    return info.overshoot_pct, (math.inf if math.isnan(settle) else settle)


def evaluate(
    rig: Rig, sc: ScenarioSpec, inputs: Inputs, tr: dict[str, np.ndarray]
) -> tuple[dict[tuple[str, str], np.ndarray], dict[str, np.ndarray]]:
    """Every limited quantity per variant of a chunk (``(quantity, axis)`` → values), and per
    axis whether each variant latched a fault."""
    names = rig.axis_names
    n_v, n_t = tr["flags"].shape[:2]
    values: dict[tuple[str, str], np.ndarray] = {}
    pos = tr["true_pos_counts"]
    flags = tr["flags"]
    if sc.kind in ("sync", "track"):
        win = move_windows(rig, sc, inputs)
        i_m, _ = master_axis(rig)
        t = (np.arange(n_t - win.start, dtype=np.int64)) * rig.period_s
        for a, name in enumerate(names):
            task = inputs.mode[:, a] == MODE_TASK
            if not task.any():
                continue
            over = np.empty(n_v)
            settle = np.empty(n_v)
            for b in range(n_v):
                y = pos[b, win.start :, a]
                over[b], settle[b] = step_values(
                    t, y, float(y[0]), win.target, sc.settling_band_pct
                )
            values[("overshoot_pct", name)] = over
            values[("settling_time_s", name)] = settle
            if rig.axes[a].plant.modes:
                values[("residual_vibration_counts", name)] = residual_vibration(
                    pos[:, :, a], rig, a, win.stop
                )
            sat = (flags[:, :, a] & FLAG_SATURATED) != 0
            values[("saturation_pct", name)] = 100.0 * sat[:, task].mean(axis=1)
            if rig.axes[a].role == "slave":
                # sums over C-ordered rows: numpy then adds each plant set's row alone (pairwise),
                # the same bits however many plant sets the batch holds (a column-ordered
                # array is summed across the rows, and the order depends on their number)
                e = pos[:, :, i_m] - pos[:, :, a]
                et = np.ascontiguousarray(e[:, task])
                values[("max_sync_error_counts", name)] = np.abs(et).max(axis=1)
                values[("rms_sync_error_counts", name)] = np.sqrt(np.mean(et * et, axis=1))
                lo, hi = win.steady
                steady = np.ascontiguousarray(np.abs(e[:, lo:hi]))
                values[("steady_lag_counts", name)] = steady.mean(axis=1)
    else:
        k0 = hold_from(rig, sc, inputs)
        bits = rig.counter.bits
        for a, name in enumerate(names):
            # the plant's whole count in the runtime's frame (relative to its first read)
            first = (tr["counter"][:, 0, a] - rig.axes[a].counter_init) % (1 << bits)
            first = np.where(first >= 1 << (bits - 1), first - (1 << bits), first)
            y = np.floor(pos[:, :, a]).astype(np.int64) - first[:, None]
            target = tr["pos_counts"][:, :, a] + tr["err_counts"][:, :, a]
            values[("holding_band_counts", name)] = (
                np.abs(target[:, k0:] - y[:, k0:]).max(axis=1).astype(float)
            )
            sat = (flags[:, :, a] & FLAG_SATURATED) != 0
            values[("saturation_pct", name)] = 100.0 * sat.mean(axis=1)
    faults = {
        name: ((flags[:, :, a] & FAULT_MASK) != 0).any(axis=1) for a, name in enumerate(names)
    }
    return values, faults
