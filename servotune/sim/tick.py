"""The axis tick, written once: every closed-loop kernel composes these compiled steps.

One tick of one axis (docs/runtime.md#one-tick) is

1. **sample**: the counter latches ``floor(position + noise)`` (:func:`latch`), the encoder noise
   drawn from the axis's stream (:func:`draw_noise`);
2. **read**: the runtime reads and unwraps the register (:func:`read_axis`, which calls
   :func:`servotune.laws.axis.axis_read`);
3. **law and D/A**: the runtime's integer law gives the code, the D/A its volts
   (:func:`write_axis`: :func:`servotune.laws.axis.axis_control` and :func:`dac_volts`);
4. **hold**: the write is kept in a tick-slot ring and reaches the motor ``m·T + λ`` later
   (:func:`hold`, :func:`held`);
5. **advance**: the motor moves exactly over the tick, the older write for ``λ``, the newer
   after (:func:`advance_axis`, which calls :func:`servotune.plant.advance_tick_modal` on the
   plant's row, :func:`servotune.plant.plant_row`), a resonant plant's modes with it; the
   counter sees the measured position (:func:`sensed`: the rigid position plus the modes').

The single-rig engine (:mod:`servotune.sim.engine`), the gantry (:mod:`servotune.arch.gantry`) and
the linkage (:mod:`servotune.arch.linkage`) call these in this order; each adds only its own
scheduling (which axis ticks when) and routing (where a reference comes from). A plant-model or
law variant is added in :mod:`servotune.plant` / :mod:`servotune.laws` and reaches every kernel
through these functions (and the C runtime through the laws it mirrors).

Noise is one splitmix64 stream per run (per candidate in a batch): a draw is keyed by the seed
and its index in the stream, the same whatever the threads or the batch around it.

Metrics accumulate per tick (:func:`accumulate`, :func:`finish`, :data:`METRIC_NAMES`).
"""

from __future__ import annotations

import math

import numpy as np

from servotune._numba_cache import jit
from servotune.laws.axis import FLAG_SATURATED, MODE_TASK, axis_control, axis_read
from servotune.plant import R_MODES, advance_tick_modal
from servotune.resonance import modes_output, modes_speed

__all__ = [
    "METRIC_NAMES",
    "accumulate",
    "advance_axis",
    "dac_volts",
    "draw_noise",
    "draw_uniforms",
    "finish",
    "held",
    "hold",
    "latch",
    "mix64",
    "noise_draws",
    "normal",
    "read_axis",
    "sensed",
    "splitmix",
    "write_axis",
]

# --- noise: splitmix64 (Steele, Lea & Flood, "Fast splittable pseudorandom number generators",
# OOPSLA 2014), Box-Muller for the normal draws ----------------------------------------------

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)


@jit(inline="always")
def mix64(z: np.uint64) -> np.uint64:
    """splitmix64's output function of a state (the stream's ``i``-th output is
    ``mix64(seed + i·0x9E3779B97F4A7C15)``, so any draw is reached without the ones before)."""
    z = (z ^ (z >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    return z ^ (z >> np.uint64(31))


@jit
def splitmix(state: np.uint64) -> tuple[np.uint64, np.uint64]:
    """The next state and 64-bit output of a splitmix64 stream."""
    state = state + _GOLDEN
    return state, mix64(state)


@jit(inline="always")
def _unit_uniforms(z1: np.uint64, z2: np.uint64) -> tuple[float, float]:
    """Box-Muller's uniforms from two 64-bit outputs: ``u1`` in (0, 1), ``u2`` in [0, 1)."""
    u1 = (float(np.int64(z1 >> np.uint64(11))) + 0.5) * (1.0 / 9007199254740992.0)
    u2 = float(np.int64(z2 >> np.uint64(11))) * (1.0 / 9007199254740992.0)
    return u1, u2


@jit
def normal(state: np.uint64) -> tuple[np.uint64, float]:
    """A standard normal draw (Box-Muller on two splitmix64 outputs) and the next state."""
    state, z1 = splitmix(state)
    state, z2 = splitmix(state)
    u1, u2 = _unit_uniforms(z1, z2)
    return state, math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@jit(inline="always")
def draw_uniforms(seed: np.uint64, d: int) -> tuple[float, float]:
    """The uniforms of the ``d``-th :func:`normal` draw of the stream seeded ``seed``, reached
    directly (its outputs ``2d + 1`` and ``2d + 2``): draws computed independently, e.g. several
    at a time in vector registers."""
    s1 = seed + np.uint64(2 * d + 1) * _GOLDEN
    return _unit_uniforms(mix64(s1), mix64(s1 + _GOLDEN))


@jit(inline="always")
def draw_noise(state: np.uint64, sigma: float) -> tuple[np.uint64, float]:
    """Encoder noise of one sample [counts]: ``sigma`` times a normal draw; no draw if 0."""
    if sigma > 0.0:
        state, g = normal(state)
        return state, g * sigma
    return state, 0.0


@jit
def noise_draws(seed: np.uint64, sigma: float, n: int) -> np.ndarray:
    """``n`` successive :func:`draw_noise` of the stream started from ``seed`` [counts]: one
    axis's encoder noise, tick by tick (the HAL plant component's ``seed``)."""
    out = np.zeros(n)
    state = seed
    for k in range(n):
        state, out[k] = draw_noise(state, sigma)
    return out


# --- 1-3. sample, read, law and D/A -----------------------------------------------------------


@jit(inline="always")
def latch(p, v, nz, init, mask, latched, nbytes, skew):
    """The counter register read at the tick start: position ``p`` [counts] plus noise ``nz``.

    ``(init + floor(p + nz)) & mask``. Latched: one read of the whole register. Not latched:
    byte ``j`` is read ``j · skew`` [s] later, while the count moves at the speed ``v``
    [counts/s] (a torn read, :func:`servotune.hw.counter.torn_read`).
    """
    if latched:
        return (init + np.int64(math.floor(p + nz))) & mask
    raw = np.int64(0)
    for j in range(nbytes):
        cj = np.int64(math.floor(p + v * (j * skew) + nz))
        rj = (init + cj) & mask
        raw |= rj & (np.int64(0xFF) << (8 * j))
    return raw


@jit(inline="always")
def dac_volts(code: int, dac_lo: float, lsb: float) -> float:
    """The D/A output of ``code`` [V]: ``dac_lo + code · lsb``."""
    return dac_lo + code * lsb


@jit(inline="always")
def read_axis(st, c, a, p, v, nz, init, mask, latched, nbytes, skew, reset):
    """Steps 1-2 for axis ``a``: latch the register and let the runtime read it.

    Returns the register ``raw`` and the unwrapped position ``y`` [counts].
    """
    raw = latch(p, v, nz, init, mask, latched, nbytes, skew)
    return raw, axis_read(st, c, a, raw, reset)


@jit(inline="always")
def write_axis(st, c, a, r, mode, reset, u_add, dac_lo, lsb):
    """Steps 3-4 for axis ``a``: the runtime's law, then the D/A.

    Returns ``code``, ``flags``, the error ``e`` [counts] and the volts written.
    """
    code, flags, e = axis_control(st, c, a, r, mode, reset, u_add)
    return code, flags, e, dac_lo + code * lsb


# --- 4-5. hold and advance --------------------------------------------------------------------


@jit(inline="always")
def hold(ring: np.ndarray, slot: int, volts: float) -> None:
    """Keep the write of the tick in ``slot`` (``k mod len(ring)``) of the axis's ring."""
    ring[slot] = volts


@jit(inline="always")
def held(ring: np.ndarray, slot: int, m: int, k: int) -> tuple[float, float]:
    """The writes acting on the motor during tick ``k`` (in ``slot``): ``k−m−1``, then ``k−m``.

    0 V before tick 0. The ring holds at least ``m + 2`` ticks.
    """
    n = ring.shape[0]
    j_new = slot - m
    if j_new < 0:
        j_new += n
    v_new = ring[j_new] if k >= m else 0.0
    j_old = j_new - 1
    if j_old < 0:
        j_old += n
    v_old = ring[j_old] if k >= m + 1 else 0.0
    return v_old, v_new


@jit(inline="always")
def advance_axis(p, v, q, ring, slot, m, k, w_off, row):
    """Step 5: move the motor over tick ``k`` through the held writes plus ``w_off`` [V]
    (offset and load), exactly, and its modes' state ``q`` with it
    (:func:`servotune.plant.advance_tick_modal`)."""
    v_old, v_new = held(ring, slot, m, k)
    return advance_tick_modal(p, v, q, v_old + w_off, v_new + w_off, row)


@jit(inline="always")
def sensed(p, v, q, row):
    """The position [counts] and speed [counts/s] the encoder sees: the rigid ``p``, ``v`` plus
    the modes' (:func:`servotune.resonance.modes_output`); ``p``, ``v`` of a rigid plant."""
    return modes_output(p, q, row, R_MODES), modes_speed(v, q, row, R_MODES)


# --- metrics ----------------------------------------------------------------------------------

METRIC_NAMES = (
    "max_abs_err_counts",
    "rms_err_counts",
    "itae_counts_s2",
    "saturated_ticks",
    "first_fault_tick",
    "final_err_counts",
    "task_ticks",
    "max_err_counts",
    "min_err_counts",
)
"""Per-candidate, per-axis metrics (over task ticks from ``metric_from_tick``; the signed
extremes ``max_err_counts``/``min_err_counts`` of ``e = r − y`` show overshoot)."""
N_METRICS = len(METRIC_NAMES)


@jit(inline="always")
def accumulate(mt, ln, k, e, flags, cur_mode, m_from, period):
    """Add tick ``k`` to the metrics row ``mt[ln]`` (``METRIC_NAMES`` order; rms as a sum)."""
    if flags & 3 and mt[ln, 4] < 0.0:
        mt[ln, 4] = k
    if flags & FLAG_SATURATED:
        mt[ln, 3] += 1.0
    if k >= m_from and cur_mode == MODE_TASK:
        ae = abs(float(e))
        if ae > mt[ln, 0]:
            mt[ln, 0] = ae
        mt[ln, 1] += ae * ae
        mt[ln, 2] += (k - m_from) * period * ae * period
        mt[ln, 6] += 1.0
        if e > mt[ln, 7]:
            mt[ln, 7] = e
        if e < mt[ln, 8]:
            mt[ln, 8] = e
    mt[ln, 5] = e


@jit(inline="always")
def finish(mt, ln, metrics, b, a):
    """Turn the sums of ``mt[ln]`` into the metrics of candidate ``b``, axis ``a``."""
    cnt = mt[ln, 6]
    mt[ln, 1] = math.sqrt(mt[ln, 1] / cnt) if cnt > 0 else 0.0
    for j in range(N_METRICS):
        metrics[b, a, j] = mt[ln, j]
