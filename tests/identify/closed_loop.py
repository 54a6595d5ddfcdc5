"""An independent closed-loop log simulator for the identification tests.

What makes it independent of the identifier: the plant is the *continuous* axis model
(docs/formats.md#axis-model) integrated here with a fixed-step fourth-order Runge–Kutta scheme
(``SUBSTEPS`` steps per constant-input segment, each Coulomb stick/slip event located by bisection),
not with :func:`servotune.plant.advance_tick` (the closed-form tick step the identifier simulates
its model with). What it shares with the product is only what a real rig shares with it: the
runtime PI law (:func:`servotune.laws.pi.pi_step`, the integer law that runs on the target) and
the hardware conventions of docs/runtime.md#one-tick — the counter latches ``floor(position +
noise)`` at the tick start into a 24-bit register, the law's output goes through the 12-bit D/A
(code = clamp(round(u) + 2048)), the code is written at ``t_k + compute_s`` and reaches the motor
``delay_s`` later.

The log has the columns ``servotune simulate`` writes (``dac_code``, ``counter``, ``ref_counts``,
``mode``) and the excitation the law adds, ``exc_code`` (docs/decisions.md#5-excitation-is-logged).
The load disturbance is AR(1) with pole :data:`LOAD_POLE` per tick, held over each tick, and the
encoder noise is Gaussian; both are drawn from a counter-based generator keyed by ``(seed, index)``
(Philox, docs/decisions.md#11-random-numbers), so log ``index`` of a study is the same whatever runs
it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np

from servotune.fixed import F_U, align, shift_round
from servotune.laws.pi import PIGains, pi_step
from servotune.logs import write_log

SUBSTEPS = 12
"""RK4 steps per constant-input segment (a tick has one or two segments)."""
LOAD_POLE = 0.99
"""Pole of the AR(1) load disturbance, per tick."""
COUNTER_BITS = 24
DAC_BITS = 12
DAC_RANGE_V = (-10.0, 10.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class TruePlant:
    """The true axis (docs/formats.md#axis-model), with optional per-direction gain and Coulomb
    friction.

    ``gain_neg_cps_per_v`` / ``coulomb_neg_v`` act while the motor moves (or starts) in the
    negative direction; None means the same as the positive one.
    """

    gain_cps_per_v: float = 12288.0
    tau_s: float = 0.025
    delay_s: float = 0.0008
    offset_v: float = 0.005
    coulomb_v: float = 0.002
    gain_neg_cps_per_v: float | None = None
    coulomb_neg_v: float | None = None
    noise_counts: float = 0.3


@dataclass(frozen=True, slots=True, kw_only=True)
class Experiment:
    """One closed-loop identification experiment.

    Attributes
    ----------
    n_ticks : int
    period_s, compute_s : float
        Tick and tick-start → D/A-write time [s].
    pi : PIGains
        The runtime PI law in task mode [codes/count, codes/(count·s)].
    exc_amplitude_codes : int
        Level of the multi-level PRBS added to the law's output [D/A codes].
    exc_hold_ticks : int
        Ticks per PRBS bit.
    ref_amplitude_counts : int
        Amplitude of the slow triangular reference [counts] (0: the reference stays).
    ref_period_ticks : int
        Period of the triangular reference [ticks].
    load_std_v : float
        Stationary standard deviation of the AR(1) load [V].
    counter_init : int
        Counter register at power-up (near the top, so the log wraps).
    """

    n_ticks: int = 12_000
    period_s: float = 0.004
    compute_s: float = 0.0002
    pi: PIGains = field(default_factory=lambda: PIGains(kp=0.5, ki=5.0))
    exc_amplitude_codes: int = 200
    exc_hold_ticks: int = 6
    ref_amplitude_counts: int = 20_000
    ref_period_ticks: int = 2_500
    load_std_v: float = 0.25
    counter_init: int = 2**24 - 3000


def _rng(seed: int, index: int) -> np.random.Generator:
    return np.random.Generator(np.random.Philox(key=np.array([seed, index], dtype=np.uint64)))


def excitation_codes(exp: Experiment, rng: np.random.Generator) -> np.ndarray:
    """Multi-level random binary excitation [D/A codes]: ±A at levels 1, 0.4, 0.7, 0.25."""
    n_bits = -(-exp.n_ticks // exp.exc_hold_ticks)
    bits = np.where(rng.random(n_bits) < 0.5, -1.0, 1.0)
    levels = np.array([1.0, 0.4, 0.7, 0.25])
    scale = levels[(np.arange(n_bits) // 31) % levels.size]
    codes = np.floor(
        np.repeat(bits * scale, exp.exc_hold_ticks)[: exp.n_ticks] * exp.exc_amplitude_codes + 0.5
    )
    return codes.astype(np.int64)


def reference_counts(exp: Experiment) -> np.ndarray:
    """Slow triangular reference [counts] (integer tick arithmetic)."""
    k = np.arange(exp.n_ticks, dtype=np.int64)
    if exp.ref_amplitude_counts == 0:
        return np.zeros(exp.n_ticks, dtype=np.int64)
    per = exp.ref_period_ticks
    phase = k % per
    half = per // 2
    tri = np.where(phase < half, phase, per - phase)  # 0 … half … 0
    return (2 * exp.ref_amplitude_counts * tri // half - exp.ref_amplitude_counts).astype(
        np.int64
    ) + exp.ref_amplitude_counts


@numba.njit(cache=False)
def _accel(
    v: float, w: float, gp: float, gn: float, cp: float, cn: float, tau: float, s: float
) -> float:
    """dv/dt for direction ``s`` (+1/−1) [counts/s²]."""
    if s > 0.0:
        return (gp * (w - cp) - v) / tau
    return (gn * (w + cn) - v) / tau


@numba.njit(cache=False)
def _rk4(
    p: float,
    v: float,
    w: float,
    h: float,
    gp: float,
    gn: float,
    cp: float,
    cn: float,
    tau: float,
    s: float,
) -> tuple[float, float]:
    k1v = _accel(v, w, gp, gn, cp, cn, tau, s)
    k1p = v
    k2v = _accel(v + 0.5 * h * k1v, w, gp, gn, cp, cn, tau, s)
    k2p = v + 0.5 * h * k1v
    k3v = _accel(v + 0.5 * h * k2v, w, gp, gn, cp, cn, tau, s)
    k3p = v + 0.5 * h * k2v
    k4v = _accel(v + h * k3v, w, gp, gn, cp, cn, tau, s)
    k4p = v + h * k3v
    return (
        p + h / 6.0 * (k1p + 2 * k2p + 2 * k3p + k4p),
        v + h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v),
    )


@numba.njit(cache=False)
def _segment(
    p: float,
    v: float,
    w: float,
    length: float,
    gp: float,
    gn: float,
    cp: float,
    cn: float,
    tau: float,
    nsub: int,
) -> tuple[float, float]:
    """Integrate over ``length`` seconds of constant net input ``w`` (stick/slip handled)."""
    h = length / nsub
    for _ in range(nsub):
        t_left = h
        while t_left > 0.0:
            if v == 0.0:
                if -cn <= w <= cp:
                    break  # stuck for the rest of this step
                s = 1.0 if w > cp else -1.0
            else:
                s = 1.0 if v > 0.0 else -1.0
            p1, v1 = _rk4(p, v, w, t_left, gp, gn, cp, cn, tau, s)
            if v1 * s > 0.0:
                p, v = p1, v1
                t_left = 0.0
                break
            if v == 0.0:  # cannot start in this direction (rounding): stay
                break
            # the speed reaches zero inside the step: bisect the crossing time
            lo, hi = 0.0, t_left
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                _, vm = _rk4(p, v, w, mid, gp, gn, cp, cn, tau, s)
                if vm * s > 0.0:
                    lo = mid
                else:
                    hi = mid
            p, _ = _rk4(p, v, w, hi, gp, gn, cp, cn, tau, s)
            v = 0.0
            t_left -= hi
    return p, v


@numba.njit(cache=False)
def _run(
    n: int,
    period: float,
    m: int,
    lam: float,
    gp: float,
    gn: float,
    cp: float,
    cn: float,
    tau: float,
    offset: float,
    noise_sd: float,
    noise: np.ndarray,
    load: np.ndarray,
    ref: np.ndarray,
    exc: np.ndarray,
    kp_q: int,
    kp_f: int,
    kit_q: int,
    kit_f: int,
    lsb: float,
    zero: int,
    cmax: int,
    nsub: int,
    codes: np.ndarray,
    pos: np.ndarray,
    true_p: np.ndarray,
) -> None:
    p = 0.0
    v = 0.0
    integ = 0
    y0 = math.floor(noise_sd * noise[0])
    for k in range(n):
        true_p[k] = p
        y = math.floor(p + noise_sd * noise[k]) - y0
        pos[k] = y
        e = ref[k] - y
        u_q, integ = pi_step(kp_q, kp_f, kit_q, kit_f, integ, e, align(exc[k], F_U), zero, cmax)
        code = shift_round(u_q, F_U) + zero
        if code > cmax:
            code = cmax
        elif code < 0:
            code = 0
        codes[k] = code
        # motor input in this tick: write k-m-1 until lam, then write k-m
        j_new = k - m
        j_old = j_new - 1
        u_new = (codes[j_new] - zero) * lsb if j_new >= 0 else 0.0
        u_old = (codes[j_old] - zero) * lsb if j_old >= 0 else 0.0
        if lam > 0.0:
            p, v = _segment(p, v, u_old + offset + load[k], lam, gp, gn, cp, cn, tau, nsub)
        p, v = _segment(p, v, u_new + offset + load[k], period - lam, gp, gn, cp, cn, tau, nsub)


@dataclass(frozen=True, slots=True, kw_only=True)
class ClosedLoopLog:
    """A simulated log's columns and its truth."""

    dac_code: np.ndarray
    counter: np.ndarray
    pos_counts: np.ndarray
    ref_counts: np.ndarray
    exc_code: np.ndarray
    load_v: np.ndarray
    true_pos_counts: np.ndarray
    period_s: float
    compute_s: float
    plant: TruePlant

    @property
    def cmd_v(self) -> np.ndarray:
        """D/A output [V]."""
        lo, hi = DAC_RANGE_V
        return (self.dac_code - 2 ** (DAC_BITS - 1)) * ((hi - lo) / 2**DAC_BITS)

    def write(self, path: Path, *, axis: str = "x", with_exc: bool = True) -> Path:
        """Write the log as ``servotune simulate`` does (counter and codes, task mode)."""
        cols = {
            f"{axis}.dac_code": self.dac_code,
            f"{axis}.counter": self.counter,
            f"{axis}.ref_counts": self.ref_counts,
            f"{axis}.mode": np.ones(self.dac_code.size, dtype=np.int8),
        }
        if with_exc:
            cols[f"{axis}.exc_code"] = self.exc_code
        meta = {
            "period_s": repr(self.period_s),
            "counter_bits": COUNTER_BITS,
            "dac_bits": DAC_BITS,
            "dac_range_v": "-10,10",
            "compute_s": repr(self.compute_s),
        }
        write_log(path, period_s=self.period_s, columns=cols, metadata=meta)
        return path


def simulate_closed_loop(
    plant: TruePlant, exp: Experiment, *, seed: int, index: int
) -> ClosedLoopLog:
    """Run the closed loop; random streams keyed by ``(seed, index)``."""
    rng = _rng(seed, index)
    n = exp.n_ticks
    exc = excitation_codes(exp, rng)
    w = rng.standard_normal(n)
    noise = rng.standard_normal(n)
    load = np.empty(n)
    sd_w = exp.load_std_v * math.sqrt(1.0 - LOAD_POLE**2)
    acc = exp.load_std_v * rng.standard_normal()
    for k in range(n):  # AR(1), started in its stationary distribution
        acc = LOAD_POLE * acc + sd_w * w[k]
        load[k] = acc
    ref = reference_counts(exp)
    lag = exp.compute_s + plant.delay_s
    m = math.floor(lag / exp.period_s + 1e-12)
    lam = lag - m * exp.period_s
    consts = exp.pi.quantize(exp.period_s)
    lo, hi = DAC_RANGE_V
    lsb = (hi - lo) / 2**DAC_BITS
    codes = np.empty(n, dtype=np.int64)
    pos = np.empty(n, dtype=np.int64)
    true_p = np.empty(n)
    gn = plant.gain_neg_cps_per_v if plant.gain_neg_cps_per_v is not None else plant.gain_cps_per_v
    cn = plant.coulomb_neg_v if plant.coulomb_neg_v is not None else plant.coulomb_v
    _run(
        n,
        exp.period_s,
        m,
        lam,
        plant.gain_cps_per_v,
        gn,
        plant.coulomb_v,
        cn,
        plant.tau_s,
        plant.offset_v,
        plant.noise_counts,
        noise,
        load,
        ref,
        exc,
        consts.kp.q,
        consts.kp.f,
        consts.ki_t.q,
        consts.ki_t.f,
        lsb,
        2 ** (DAC_BITS - 1),
        2**DAC_BITS - 1,
        SUBSTEPS,
        codes,
        pos,
        true_p,
    )
    counter = (exp.counter_init + pos) % (1 << COUNTER_BITS)
    return ClosedLoopLog(
        dac_code=codes,
        counter=counter,
        pos_counts=pos,
        ref_counts=ref,
        exc_code=exc,
        load_v=load,
        true_pos_counts=true_p,
        period_s=exp.period_s,
        compute_s=exp.compute_s,
        plant=plant,
    )
