"""LinuxCNC's stock ``pid`` closing the loop around a servotune plant, in floating point.

What a HAL servo thread does each period when it runs, in this order::

    plant   moves the plant over one tick by the D/A output written last period (the
            simulator's lag and model: :func:`servotune.plant.advance_tick`), then latches the
            encoder: counts = counter_init + floor(position + noise) (noise: 0, or with a
            ``noise_seed`` the plant's encoder noise, as the HAL plant component's ``seed``)
    encoder feedback = counts · (1 / position_scale)  [machine units]  (conv_s32_float, then a
            ``scale`` of gain 1/position_scale: the product with the reciprocal, as LinuxCNC's
            ``encoder`` computes its ``position`` from ``position-scale``)
    pid     output = the stock pid's law (:func:`servotune.laws.linuxcnc_pid.pid_step`) of the
            command and the feedback  [output units]
    D/A     volts = output · (1 / output_scale)  (a ``scale``); with a ``dac``, the D/A's code
            for it (round half away from zero, clamped to the rails) and that code's voltage

:func:`simulate_pid_loop` is that loop, tick by tick, in the same float arithmetic as HAL; the
plant is moved exactly as servotune's engine moves it (the engine's write history and lag,
``tests/export/test_c_runtime.py``'s ``_closed_loop``, and the plant component of
:func:`servotune.export.hal_component.plant_component`). It is how servotune says
what the exported stock-pid loop does, and what ``tests/hal/test_pid_export.py`` compares with
the real component in HAL.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from servotune.errors import SimulationError
from servotune.hw.dac import code_from_volts
from servotune.laws.linuxcnc_pid import PidParameters, PidState, pid_step, thread_period_ns
from servotune.plant import R_MODES, R_OFFSET, Plant, advance_tick_modal, plant_row
from servotune.resonance import MAX_MODES, modes_output
from servotune.rig import Dac
from servotune.sim.tick import noise_draws
from servotune.validate import check_number, check_seed

__all__ = ["PidLoopResult", "simulate_pid_loop"]


@dataclass(frozen=True, slots=True, kw_only=True)
class PidLoopResult:
    """One run of the stock pid's loop (:func:`simulate_pid_loop`); arrays over ticks.

    Attributes
    ----------
    period_s : float
        The plant's tick [s].
    period_ns : int
        The thread period the pid received [ns].
    command_units : ndarray
        The ``command`` pin [machine units].
    counts : ndarray of int64
        Encoder count latched at the tick start (s32, as the plant component's ``counts``).
    position_counts : ndarray
        Plant position at the tick start, before the floor [counts].
    feedback_units : ndarray
        The ``feedback`` pin [machine units].
    error_units : ndarray
        The pid's ``error`` pin [machine units].
    output : ndarray
        The pid's ``output`` pin [output units].
    volts : ndarray
        The D/A output written this tick [V] (a D/A code's voltage when run with a ``dac``).
    """

    period_s: float
    period_ns: int
    command_units: np.ndarray
    counts: np.ndarray
    position_counts: np.ndarray
    feedback_units: np.ndarray
    error_units: np.ndarray
    output: np.ndarray
    volts: np.ndarray

    @property
    def n_ticks(self) -> int:
        """Number of ticks."""
        return int(self.counts.shape[0])

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of every field (arrays as lists)."""
        return {
            f.name: (v.tolist() if isinstance(v := getattr(self, f.name), np.ndarray) else v)
            for f in fields(self)
        }


def _positive(name: str, value: object, unit: str) -> float:
    check_number(name, value, unit, strict=True, error=SimulationError)
    return float(value)  # type: ignore[arg-type]


def _s32(x: int) -> int:
    """The s32 a HAL pin holds for ``x`` (two's complement wrap, as the plant component)."""
    x &= 0xFFFFFFFF
    return x - (1 << 32) if x >= 1 << 31 else x


def simulate_pid_loop(
    params: PidParameters,
    plant: Plant,
    period_s: float,
    command_units: np.ndarray,
    *,
    position_scale: float,
    output_scale: float = 1.0,
    compute_s: float = 0.0,
    counts_per_rev: float = math.inf,
    dac: Dac | None = None,
    period_ns: int | None = None,
    counter_init: int = 0,
    noise_seed: int | None = None,
) -> PidLoopResult:
    """The stock pid in the loop with ``plant``, one tick per command sample (module docstring).

    Parameters
    ----------
    params : PidParameters
        The pid's pins (``enable`` is on from the first tick).
    plant : Plant
        The axis (its encoder noise only with ``noise_seed``).
    period_s : float
        The tick the plant is discretised with [s] (the rig's achieved period).
    command_units : array_like, shape (ticks,)
        The ``command`` pin per tick [machine units].
    position_scale : float
        Encoder counts per machine unit [counts/unit], > 0.
    output_scale : float
        pid output units per volt at the D/A [units/V], > 0.
    compute_s : float
        Tick start → D/A write [s] (with the plant's ``delay_s``, the lag of the drive input).
    counts_per_rev : float
        For the plant's speed limit [counts/rev]; ``inf`` (default): no limit, as the HAL
        plant component built without it.
    dac : Dac, optional
        Quantise the output to this D/A's codes; None (default): the volts as computed.
    period_ns : int, optional
        The thread period the pid receives [ns]; default :func:`thread_period_ns` of
        ``period_s``.
    counter_init : int
        Encoder count at position 0 [counts].
    noise_seed : int, optional
        None (default): noiseless. An int: the encoder latches ``floor(position + noise)``,
        the plant's ``noise_counts`` times one normal draw per tick of the simulator's stream
        (:func:`servotune.sim.tick.draw_noise`) started from this seed, as the HAL plant
        component with its ``seed`` parameter set to it.

    Returns
    -------
    PidLoopResult

    Raises
    ------
    SimulationError
        A scale or period that is not a finite number > 0, or a command that is not a 1-D
        array of finite numbers.
    """
    ps = _positive("position_scale", position_scale, "counts per machine unit")
    os_ = _positive("output_scale", output_scale, "output units per V")
    _positive("period_s", period_s, "s")
    cmd = np.asarray(command_units, dtype=float)
    if cmd.ndim != 1 or cmd.size == 0 or not np.all(np.isfinite(cmd)):
        raise SimulationError("command_units must be a 1-D array of finite numbers [machine units]")
    if period_ns is None:
        period_ns = thread_period_ns(period_s)
    fb_gain = 1.0 / ps  # the `scale` gains the HAL wiring sets
    out_gain = 1.0 / os_
    row, lag = plant_row(plant, period_s, compute_s, counts_per_rev)
    w_off = float(row[R_OFFSET])
    ring = lag + 2
    hist = [0.0] * ring  # volts written, by slot
    n = cmd.size
    counts = np.zeros(n, dtype=np.int64)
    pos_out = np.zeros(n)
    fb_out = np.zeros(n)
    err_out = np.zeros(n)
    y_out = np.zeros(n)
    v_out = np.zeros(n)
    pos = spd = 0.0
    q = np.zeros(2 * MAX_MODES)  # a resonant plant's modes (docs/frf.md)
    state = PidState()
    slot = ring - 1
    commands = cmd.tolist()
    noise = (
        [0.0] * n
        if noise_seed is None
        else noise_draws(
            np.uint64(check_seed(noise_seed, error=SimulationError)), plant.noise_counts, n
        ).tolist()
    )
    for k in range(n):
        y_pos = modes_output(pos, q, row, R_MODES) if plant.modes else pos
        c = _s32(counter_init + math.floor(y_pos + noise[k]))  # 1. the encoder latches
        fb = float(c) * fb_gain + 0.0  # 2. conv_s32_float, scale (in * gain + offset)
        out, err, state = pid_step(params, state, commands[k], fb, period_ns)  # 3. pid
        volts = out * out_gain + 0.0  # 4. scale to the D/A
        if dac is not None:
            code = int(code_from_volts(volts, dac.bits, dac.range_v))
            volts = dac.range_v[0] + code * dac.lsb_v
        counts[k], pos_out[k], fb_out[k] = c, y_pos, fb
        err_out[k], y_out[k], v_out[k] = err, out, volts
        slot = 0 if slot + 1 == ring else slot + 1  # 5. hold the write, move to the next tick
        hist[slot] = volts
        j_new = slot - lag if slot >= lag else slot - lag + ring
        v_new = hist[j_new] if k >= lag else 0.0
        j_old = j_new - 1 if j_new >= 1 else ring - 1
        v_old = hist[j_old] if k >= lag + 1 else 0.0
        pos, spd = advance_tick_modal(pos, spd, q, v_old + w_off, v_new + w_off, row)
    return PidLoopResult(
        period_s=float(period_s),
        period_ns=int(period_ns),
        command_units=cmd.copy(),
        counts=counts,
        position_counts=pos_out,
        feedback_units=fb_out,
        error_units=err_out,
        output=y_out,
        volts=v_out,
    )
