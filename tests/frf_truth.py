"""An independent truth for the measured frequency response (servotune.analysis.frf).

Nothing here comes from servotune's plant model, laws or simulation engine: the plant, the
loop, the converters and the noise are written out below and the plant is integrated with
``scipy.integrate.solve_ivp``. The only servotune code the tests run on these logs is the code
under test (``estimate_frf``) and the excitation it is meant to be used with
(``periodic_multisine``, whose codes are just an integer sequence here).

**Plant.** A two-mass motor-load axis: motor inertia ``J_m``, load inertia ``J_l = R·J_m``, a
shaft of stiffness ``k`` and damping ``c``, viscous damping ``b`` on the motor (bearings and the
drive; it makes the rigid body type 1 with mechanical time constant ``τ_m = (J_m + J_l) / b``,
without which a PI position law could not hold a double integrator), Coulomb friction
``F_c·tanh(ω_m / ω_ε)`` on the motor and a load torque ``d`` on the load. The drive is a torque
source ``K_t·u``, ``u`` [V] the D/A output::

    J_m ω_m' = K_t u − k (θ_m − θ_l) − c (ω_m − ω_l) − b ω_m − F_c tanh(ω_m / ω_ε)
    J_l ω_l' =         k (θ_m − θ_l) + c (ω_m − ω_l) + d

The linear part (``F_c = 0``) has a pole at 0, a real pole near ``−1/τ_m`` (the rigid body)
and a complex pole pair, the *mode*: ``k`` and ``c`` are solved (:meth:`TwoMass.shaft`)
so that the pair has natural frequency ``f_r`` and damping ratio ``ζ`` exactly, the motor's
viscous damping included. The motor-side response also has a zero pair, the antiresonance, at
``√(k / J_l)``, about ``f_r / √(1 + R)`` (the two-mass model of e.g. G. Ellis, "Control System
Design Guide", 4th ed., Butterworth-Heinemann 2012, on mechanical resonance). The measured
output is the motor position in encoder counts.

**Sampling, as on a PC-based rig.** Tick ``k`` starts at ``t_k = k·T``. The counter latches
``y_k = floor(θ_m(t_k)·counts_per_rad + n_k)`` (``n_k`` Gaussian sensor noise in counts, which
also dithers the quantisation). The PI law computes the command from ``y_k``; the excitation code
``r_k`` is added to it in D/A codes and the sum goes through a 12-bit ±10 V converter::

    code_k = clip(round((u_pi,k + 10) / 20 · 4095 + r_k), 0, 4095)
    u_k    = code_k · 20 / 4095 − 10                                  [V]

(numpy's round, half to even: a zero command is code 2048, +2.4 mV). The log records ``u_k``
(the applied voltage), ``y_k`` and ``r_k``.

``u_k`` is written at ``t_k + d`` (``d`` the compute delay, a fraction of the tick: the model is
the fractional delay, not a whole-tick one) and held until the next write (zero-order hold). So
each ``solve_ivp`` call integrates one hold interval ``[t_k + d, t_{k+1} + d]`` from the end
state of the previous one with ``u_k`` and the load torque ``d_k`` constant, and reads
``θ_m(t_{k+1})`` inside it (``t_eval``, the solver's dense output). The axis rests at 0 with
0 V applied until the first write.

**Noise.** The load torque is white Gaussian noise through a first-order low-pass (an AR(1)
sequence of pole ``exp(−2π f_c T)``, held over each hold interval) and the sensor noise is white
Gaussian, both drawn from ``numpy.random.default_rng(seed)``.

**Truth.** The exact discrete-time response of the linear part (``F_c = 0``) from ``u_k`` to
``y_k`` with the zero-order hold and the fractional delay (the sampling of a system with a time
delay shorter than the period: K. J. Åström, B. Wittenmark, "Computer-Controlled Systems", 3rd
ed., Prentice Hall 1997, ch. 2)::

    x_{k+1} = Φ x_k + Γ_1 u_k + Γ_2 u_{k−1},   Φ = e^{AT},
    Γ_1 = ∫_0^{T−d} e^{As} ds B,   Γ_2 = e^{A(T−d)} ∫_0^d e^{As} ds B,
    G(e^{jωT}) = C (e^{jωT} I − Φ)^{-1} (Γ_1 + Γ_2 e^{−jωT}),

computed with ``scipy.linalg.expm`` of the augmented matrix ``[[A, B], [0, 0]]``. The velocity
response (the backward difference of the position over ``T``) is ``G · (1 − e^{−jωT}) / T``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp
from scipy.linalg import expm
from scipy.signal import lfilter

DAC_CODES = 4095
"""Top code of the 12-bit D/A; code 0 is −10 V, 4095 is +10 V."""
DAC_RANGE_V = 20.0
LSB_V = DAC_RANGE_V / DAC_CODES
"""One D/A code [V]."""


@dataclass(frozen=True, slots=True, kw_only=True)
class TwoMass:
    """The two-mass axis (module docstring), from its mode and a few physical scales.

    Attributes
    ----------
    f_r_hz : float
        The mode: natural frequency of the complex pole pair of the linear part [Hz].
    zeta : float
        Its damping ratio [-] (of the pole pair itself, the motor's viscous damping included).
    inertia_ratio : float
        ``R = J_l / J_m`` [-].
    tau_m_s : float
        Mechanical time constant of the rigid body, ``(J_m + J_l) / b`` [s].
    accel_per_v : float
        Acceleration of the rigid body per volt, ``K_t / (J_m + J_l)`` [rad/s² per V].
    motor_inertia : float
        ``J_m`` [kg m²] (only ratios matter for the response; it scales the torques).
    coulomb_v : float
        Coulomb friction on the motor as the D/A voltage that balances it, ``F_c / K_t`` [V]
        (default 2 mV, the example rig's ``coulomb_v``, plants/pc-dual-servo.toml).
    friction_speed : float
        ``ω_ε`` of the ``tanh`` smoothing [rad/s].
    counts_per_rev : int
        Encoder counts per motor revolution.
    """

    f_r_hz: float
    zeta: float
    inertia_ratio: float
    tau_m_s: float = 0.1
    accel_per_v: float = 80.0 * math.pi
    motor_inertia: float = 1e-4
    coulomb_v: float = 0.002
    friction_speed: float = 0.2
    counts_per_rev: int = 2**17

    @property
    def j_m(self) -> float:
        return self.motor_inertia

    @property
    def j_l(self) -> float:
        return self.inertia_ratio * self.motor_inertia

    @property
    def j_total(self) -> float:
        return self.j_m + self.j_l

    @property
    def omega_r(self) -> float:
        return 2.0 * math.pi * self.f_r_hz

    @property
    def b(self) -> float:
        """Viscous damping on the motor [N m s / rad]."""
        return self.j_total / self.tau_m_s

    @property
    def k_t(self) -> float:
        """Drive torque per volt [N m / V]."""
        return self.accel_per_v * self.j_total

    @property
    def f_c(self) -> float:
        """Coulomb friction torque [N m]."""
        return self.coulomb_v * self.k_t

    @property
    def counts_per_rad(self) -> float:
        return self.counts_per_rev / (2.0 * math.pi)

    def shaft(self) -> tuple[float, float, float]:
        """Stiffness ``k`` [N m / rad], damping ``c`` [N m s / rad] of the shaft and the real
        pole ``−a`` [1/s] such that the linear part has its pole pair at ``f_r``, ``ζ``.

        The characteristic polynomial of the linear part is ``s · (J_m J_l s³ + (c J + b J_l) s²
        + (k J + b c) s + b k)``, ``J = J_m + J_l``; equating the cubic to ``J_m J_l (s² +
        2ζω_r s + ω_r²)(s + a)`` gives ``k = a ω_r² J_m J_l / b``, ``c = ((2ζω_r + a) J_m J_l −
        b J_l) / J`` and an equation linear in ``a``.

        Raises
        ------
        ValueError
            If the motor's viscous damping alone damps the mode more than ``ζ`` (``c < 0``).
        """
        w, z, b = self.omega_r, self.zeta, self.b
        jm, jl = self.j_m, self.j_l
        j, p = jm + jl, jm * jl
        coef = 2.0 * z * w * p - j / b * w * w * p - b / j * p
        const = w * w * p - b / j * (2.0 * z * w * p - b * jl)
        a = -const / coef
        k = a * w * w * p / b
        c = ((2.0 * z * w + a) * p - b * jl) / j
        if not (a > 0 and k > 0 and c >= 0):
            raise ValueError(
                f"no shaft gives a mode at {self.f_r_hz:g} Hz with zeta {z:g}: the viscous "
                f"damping (tau_m {self.tau_m_s:g} s) alone damps it more"
            )
        return k, c, a

    @property
    def k(self) -> float:
        return self.shaft()[0]

    @property
    def c(self) -> float:
        return self.shaft()[1]

    @property
    def antiresonance_hz(self) -> float:
        """``√(k / J_l) / 2π``: the zero pair of the motor-side response."""
        return math.sqrt(self.k / self.j_l) / (2.0 * math.pi)

    def matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``A``, ``B`` (from u [V]) and ``B_d`` (from the load torque [N m]) of the linear part,
        state ``[θ_m, ω_m, θ_l, ω_l]`` [rad, rad/s]."""
        k, c, _ = self.shaft()
        jm, jl, b = self.j_m, self.j_l, self.b
        a = np.array(
            [
                [0.0, 1.0, 0.0, 0.0],
                [-k / jm, -(c + b) / jm, k / jm, c / jm],
                [0.0, 0.0, 0.0, 1.0],
                [k / jl, c / jl, -k / jl, -c / jl],
            ]
        )
        bu = np.array([0.0, self.k_t / jm, 0.0, 0.0])
        bd = np.array([0.0, 0.0, 0.0, 1.0 / jl])
        return a, bu, bd


@dataclass(frozen=True, slots=True, kw_only=True)
class Loop:
    """The sampled PI position loop: ``u_pi,k = kp·e_k + ki·T·Σ_{i≤k} e_i``, ``e_k = −y_k``
    (the axis is held at 0) [V]; the command is written ``delay_s`` after the tick starts."""

    period_s: float
    delay_s: float
    kp: float
    ki: float


@dataclass(frozen=True, slots=True, kw_only=True)
class Noise:
    """The disturbances. ``load_v``: RMS load torque as the D/A voltage that balances it
    (``d / K_t``) [V]; ``load_corner_hz``: its low-pass corner; ``sensor_counts``: RMS sensor
    noise before the counter's floor [counts]."""

    load_v: float = 0.01
    load_corner_hz: float = 2.0
    sensor_counts: float = 0.5


@dataclass(frozen=True, slots=True, kw_only=True)
class Case:
    """One log to make: the plant, the loop, the noise, the excitation codes (periodic) and
    the seed of the noise."""

    plant: TwoMass
    loop: Loop
    noise: Noise
    exc_codes: np.ndarray = field(repr=False)
    seed: int = 0


@dataclass(frozen=True, slots=True)
class Log:
    """What the rig records per tick: ``u`` the applied D/A voltage [V], ``y`` the counter
    [counts], ``r`` the excitation [D/A codes]; ``clipped`` the ticks the D/A saturated."""

    u: np.ndarray
    y: np.ndarray
    r: np.ndarray
    clipped: int


def discretise(plant: TwoMass, period_s: float, delay_s: float) -> tuple[np.ndarray, ...]:
    """``Φ``, ``Γ_1``, ``Γ_2`` of the module docstring (zero-order hold, fractional delay)."""
    if not 0.0 <= delay_s < period_s:
        raise ValueError("the compute delay must be within the tick")
    a, bu, _ = plant.matrices()
    n = a.shape[0]
    aug = np.zeros((n + 1, n + 1))
    aug[:n, :n] = a
    aug[:n, n] = bu

    def step(t: float) -> tuple[np.ndarray, np.ndarray]:
        e = expm(aug * t)
        return e[:n, :n], e[:n, n]

    phi, _ = step(period_s)
    phi_1, gam_1 = step(period_s - delay_s)
    _, gam_d = step(delay_s)
    return phi, gam_1, phi_1 @ gam_d


def truth_frf(
    plant: TwoMass,
    period_s: float,
    delay_s: float,
    freq_hz: np.ndarray,
    output: str = "velocity",
) -> np.ndarray:
    """The exact response of the linear part from the applied D/A voltage ``u_k`` to the
    sampled position ``y_k`` [counts per V] or its backward difference over ``T`` [counts/s per
    V], at ``freq_hz`` (module docstring)."""
    phi, gam_1, gam_2 = discretise(plant, period_s, delay_s)
    c = np.zeros(phi.shape[0])
    c[0] = plant.counts_per_rad
    z = np.exp(2j * np.pi * np.asarray(freq_hz, dtype=float).ravel() * period_s)
    eye = np.eye(phi.shape[0])
    out = np.array([c @ np.linalg.solve(zi * eye - phi, gam_1 + gam_2 / zi) for zi in z])
    if output == "velocity":
        out = out * (1.0 - 1.0 / z) / period_s
    elif output != "position":
        raise ValueError(f"unknown output {output!r}")
    return out.reshape(np.shape(freq_hz))


def loop_ss(plant: TwoMass, loop: Loop) -> tuple[Any, Any]:
    """The discrete plant (u → y [counts], one extra state holding ``u_{k−1}``) and the PI
    law (``e → u``) as python-control systems of sampling time ``T``."""
    import control

    phi, gam_1, gam_2 = discretise(plant, loop.period_s, loop.delay_s)
    n = phi.shape[0]
    a = np.zeros((n + 1, n + 1))
    a[:n, :n] = phi
    a[:n, n] = gam_2
    b = np.zeros((n + 1, 1))
    b[:n, 0] = gam_1
    b[n, 0] = 1.0
    c = np.zeros((1, n + 1))
    c[0, 0] = plant.counts_per_rad
    g = control.ss(a, b, c, np.zeros((1, 1)), loop.period_s)
    t = loop.period_s
    pi = control.tf([loop.kp + loop.ki * t, -loop.kp], [1.0, -1.0], t)
    return g, pi


def loop_margins(plant: TwoMass, loop: Loop) -> dict[str, float]:
    """Gain margin [-], phase margin [deg] and the largest closed-loop pole radius of the PI
    loop on the linear part (python-control ``stability_margins`` on the discrete loop)."""
    import control

    g, pi = loop_ss(plant, loop)
    open_loop = pi * g
    gm, pm, sm, *_ = control.stability_margins(open_loop, method="frd")
    closed = control.feedback(open_loop, 1)
    return {
        "gain_margin": float(gm),
        "phase_margin_deg": float(pm),
        "stability_margin": float(sm),
        "pole_radius": float(np.max(np.abs(closed.poles()))),
    }


def design_pi(
    plant: TwoMass, period_s: float, delay_s: float, crossover_hz: float, ratio: float = 4.0
) -> Loop:
    """A PI law with its loop gain 1 at ``crossover_hz`` on the rigid body
    (``K / (s (τ_m s + 1))``, ``K = accel_per_v · τ_m · counts_per_rad``) and its zero a factor
    ``ratio`` below (``ki = kp · ω_c / ratio``)."""
    w = 2.0 * math.pi * crossover_hz
    gain = plant.accel_per_v * plant.tau_m_s * plant.counts_per_rad
    mag = gain / (w * math.hypot(1.0, w * plant.tau_m_s))
    kp = 1.0 / mag
    return Loop(period_s=period_s, delay_s=delay_s, kp=kp, ki=kp * w / ratio)


def simulate(
    cases: Sequence[Case], *, integrator: str = "ivp", rtol: float = 1e-6, atol_rad: float = 1e-8
) -> list[Log]:
    """The closed-loop logs of ``cases`` (module docstring), all of one tick period, delay and
    length, made together: one ``solve_ivp`` call (RK45, ``rtol``; ``atol_rad`` on the angles,
    100 times it on the speeds) per hold interval on the stacked states of every case.

    ``integrator="expm"`` steps the linear part exactly instead (the transition matrix of a
    hold interval from ``scipy.linalg.expm``); it needs ``coulomb_v = 0`` everywhere and serves
    for long friction-free logs and to check the ``solve_ivp`` path.
    """
    if integrator not in ("ivp", "expm"):
        raise ValueError(f"unknown integrator {integrator!r}")
    if not cases:
        return []
    period = cases[0].loop.period_s
    delay = cases[0].loop.delay_s
    n_ticks = int(cases[0].exc_codes.size)
    if any(
        c.loop.period_s != period or c.loop.delay_s != delay or c.exc_codes.size != n_ticks
        for c in cases
    ):
        raise ValueError("cases simulated together need one period, delay and length")
    m = len(cases)
    plants = [c.plant for c in cases]
    if integrator == "expm" and any(p.coulomb_v != 0.0 for p in plants):
        raise ValueError("the exact integrator holds for the linear part only (coulomb_v 0)")
    jm = np.array([p.j_m for p in plants])
    jl = np.array([p.j_l for p in plants])
    kt = np.array([p.k_t for p in plants])
    fric_gain = np.array([p.f_c / p.j_m for p in plants])
    veps = np.array([p.friction_speed for p in plants])
    cpr = np.array([p.counts_per_rad for p in plants])
    kp = np.array([c.loop.kp for c in cases])
    ki_t = np.array([c.loop.ki * period for c in cases])
    r = np.stack([np.asarray(c.exc_codes, dtype=np.int64) for c in cases])

    # the noise, per case from its own generator: the load torque [N m] and the sensor [counts]
    load = np.empty((m, n_ticks))
    sensor = np.empty((m, n_ticks))
    for i, c in enumerate(cases):
        rng = np.random.default_rng(c.seed)
        pole = math.exp(-2.0 * math.pi * c.noise.load_corner_hz * period)
        white = rng.standard_normal(n_ticks) * math.sqrt(1.0 - pole * pole)
        start = rng.standard_normal()  # the AR(1) starts in its stationary distribution
        ar, _ = lfilter([1.0], [1.0, -pole], white, zi=[pole * start])
        load[i] = ar * c.noise.load_v * c.plant.k_t
        sensor[i] = rng.standard_normal(n_ticks) * c.noise.sensor_counts

    # the stacked state is [θ_m; ω_m; θ_l; ω_l], each a block of m rows (one per case)
    rows = [np.arange(4) * m + i for i in range(m)]
    if integrator == "ivp":
        big = np.zeros((4 * m, 4 * m))
        for i, p in enumerate(plants):
            big[np.ix_(rows[i], rows[i])] = p.matrices()[0]
        forcing = np.zeros(4 * m)
        atol = np.repeat([atol_rad, 100.0 * atol_rad, atol_rad, 100.0 * atol_rad], m)

        def rhs(_t: float, x: np.ndarray) -> np.ndarray:
            dx = big @ x + forcing
            dx[m : 2 * m] -= fric_gain * np.tanh(x[m : 2 * m] / veps)
            return dx

    else:
        # [x; u; d] ↦ the state a hold interval later, and θ_m at the sample inside it
        full = np.zeros((4 * m, 6 * m))
        at_sample = np.zeros((m, 6 * m))
        for i, p in enumerate(plants):
            a_c, bu, bd = p.matrices()
            aug = np.zeros((6, 6))
            aug[:4, :4] = a_c
            aug[:4, 4] = bu
            aug[:4, 5] = bd
            cols = np.concatenate((rows[i], [4 * m + i, 5 * m + i]))
            full[np.ix_(rows[i], cols)] = expm(aug * period)[:4]
            at_sample[i, cols] = expm(aug * (period - delay))[0]

    x = np.zeros(4 * m)  # the state at t_k + d; at rest before the first write
    theta = np.zeros(m)  # θ_m(t_k)
    integral = np.zeros(m)
    u_log = np.empty((m, n_ticks))
    y_log = np.empty((m, n_ticks), dtype=np.int64)
    clipped = np.zeros(m, dtype=np.int64)
    t_eval = [period - delay, period]
    for j in range(n_ticks):
        y = np.floor(theta * cpr + sensor[:, j])
        integral -= y
        u_pi = -kp * y + ki_t * integral
        raw = np.round((u_pi + 10.0) / DAC_RANGE_V * DAC_CODES + r[:, j])
        code = np.clip(raw, 0, DAC_CODES)
        clipped += raw != code
        u = code * LSB_V - 10.0
        u_log[:, j] = u
        y_log[:, j] = y
        if integrator == "ivp":
            forcing[m : 2 * m] = kt * u / jm
            forcing[3 * m :] = load[:, j] / jl
            sol = solve_ivp(rhs, (0.0, period), x, t_eval=t_eval, rtol=rtol, atol=atol)
            if not sol.success:
                raise RuntimeError(f"solve_ivp failed at tick {j}: {sol.message}")
            theta = sol.y[:m, 0]
            x = sol.y[:, 1]
        else:
            v = np.concatenate((x, u, load[:, j]))
            theta = at_sample @ v
            x = full @ v
    return [Log(u=u_log[i], y=y_log[i], r=r[i].copy(), clipped=int(clipped[i])) for i in range(m)]
