"""The PI synthesis: :func:`tune_pi` (largest Ki under robustness targets, on the exact discrete
loop) and :func:`tune_pi_axis` (the same for one axis of a rig)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from servotune._control import scipy_paths
from servotune.analysis.margins import filters_tf, unwrapped_phase
from servotune.errors import InfeasibleError, SpecError
from servotune.hw import dac as hw_dac
from servotune.laws.filters import SectionQ, chain_response
from servotune.plant import Plant, lag_split
from servotune.tune.pi.check import (
    acceptable,
    fast_check,
    new_peaks,
    python_control_check,
    sens,
    violations,
)
from servotune.tune.pi.grid import (
    DECADES_BELOW,
    Ctx,
    check_grid,
    design_grid,
    plant_model,
    q_im,
    ss_response,
    start_point,
)
from servotune.tune.pi.nlp import Nlp
from servotune.tune.pi.spec import (
    MAX_BUILDS,
    PEAK_STENCIL,
    REFINE_ROUNDS,
    PITuning,
    Spec,
    check_spec,
)

if TYPE_CHECKING:  # python-control is imported where used (slow to import)
    import control

    from servotune.rig import Rig

__all__ = ["tune_pi", "tune_pi_axis"]


_Design = tuple[float, float, str, bool]
"""A candidate design: kp, ki, the solver's status, whether it meets the targets strictly."""

_BINDING_TOL = {
    "phase_margin_deg": -0.05,
    "gain_margin_db": -0.05,
    "max_sensitivity": -2e-3,
    "crossover_rad_s": -2e-3,
}
"""Violation (negative: the slack) from which a target counts as binding."""


def _loop_context(
    plant: Plant | control.TransferFunction,
    period_s: float,
    compute_s: float,
    lsb_v: float,
    spec: Spec,
    filters: Sequence[SectionQ] = (),
) -> tuple[Ctx, control.StateSpace]:
    """The plant's discrete model scaled by ``lsb_v`` (behind the output ``filters``) and its
    response on the design grid (:class:`~servotune.tune.pi.grid.Ctx`), and the scaled model
    python-control re-checks on.

    Raises
    ------
    SpecError
        The discrete plant has a pole on the unit circle away from z = 1.
    """
    import control

    discretiser, lag, feature = plant_model(plant, period_s, compute_s)
    p_scaled = lsb_v * discretiser(lag)
    f_tf = filters_tf(filters, period_s)
    if f_tf is not None:
        p_scaled = control.ss(control.series(control.ss(f_tf), p_scaled))
    a = np.asarray(p_scaled.A, dtype=float)
    b = np.asarray(p_scaled.B, dtype=float)
    c = np.asarray(p_scaled.C, dtype=float)
    d = float(np.asarray(p_scaled.D, dtype=float)[0, 0])
    # responses: the whole ticks of lag are a pure shift z^-m, the rest a small model
    m_ticks, lam = lag_split(lag, period_s)
    p_frac = lsb_v * discretiser(lam)
    mats = [np.asarray(x, dtype=float) for x in (p_frac.A, p_frac.B, p_frac.C)]
    d_frac = float(np.asarray(p_frac.D, dtype=float)[0, 0])

    def resp(om: np.ndarray) -> np.ndarray:
        z = np.exp(1j * np.asarray(om, dtype=float) * period_s)
        g = ss_response(*mats, d_frac, z) * z ** (-m_ticks)
        return g * chain_response(filters, om, period_s)

    nyq = math.pi / period_s
    w_lo = min(feature, nyq, spec.wc_max or math.inf) * 10.0**-DECADES_BELOW
    poles = [np.linalg.eigvals(mats[0])] + [np.roots(sec.ba()[1]) for sec in filters]
    w = design_grid(w_lo, nyq, lag + period_s, np.concatenate(poles))
    g = resp(w)
    if not np.all(np.isfinite(g)):
        raise SpecError("the discrete plant has a pole on the unit circle away from z = 1")
    ctx = Ctx(period_s, a, b, c, d, resp, w, g, unwrapped_phase(g), q_im(w, period_s))
    return ctx, p_scaled


def _refine(
    ctx: Ctx, spec: Spec, start: tuple[float, float], w_check: np.ndarray
) -> tuple[list[_Design], int]:
    """The NLP's acceptable designs, solved again with the targets missed between grid points
    refined (see :func:`tune_pi`), and the solver iterations they took."""
    # the NLP aims a hair inside the targets, so that the re-check finds them met
    pm_t = spec.pm_deg + 1e-6 if spec.pm_deg is not None else 0.0
    gm_t = spec.gm_db + 1e-6 if spec.gm_db is not None else 0.0
    ms_t = spec.ms * (1 - 1e-7) if spec.ms is not None else 2.0
    ms_w, guard_w = np.empty(0), np.empty(0)
    wc_w = np.array([spec.wc_max * (1 - 1e-7)]) if spec.wc_max is not None else np.empty(0)
    iterations, builds = 0, 0
    designs: list[_Design] = []  # acceptable: kp, ki, status, strictly
    nlp = Nlp(ctx, spec, start)
    x0: np.ndarray | None = None
    for _ in range(REFINE_ROUNDS):
        res = nlp.solve(x0, pm_deg=pm_t, gm_db=gm_t, ms=ms_t, ms_w=ms_w, wc_w=wc_w, guard_w=guard_w)
        iterations += res.iterations
        if not (res.success and res.ki > 0):
            break
        chk = fast_check(ctx, res.kp, res.ki, w_check)
        viol = violations(chk, spec)
        strict = acceptable(viol, strict=True)
        if acceptable(viol):
            designs.append((res.kp, res.ki, res.status, strict))
        guards = np.empty(0) if strict else new_peaks(nlp, res, chk)
        if guards.size:
            # the NLP went to a loop with new crossovers above the ones it models, and that
            # loop misses a target: keep |L| <= 1 there, and solve again as before
            guard_w = np.append(guard_w, np.outer(guards, PEAK_STENCIL))
            continue
        structure = Nlp.structure_of(ctx, spec, res.kp, res.ki)
        if res.on_bracket or structure != nlp.structure:
            if builds >= MAX_BUILDS:
                break
            nlp, x0, builds = Nlp(ctx, spec, (res.kp, res.ki)), None, builds + 1
            continue  # a crossing appeared, vanished or left its bracket: model it again
        if strict:
            break
        # exchange: add the frequencies where a target was missed between grid points
        x0 = res.x
        if viol.get("max_sensitivity", 0.0) > 0:
            hot = chk.ms_peaks[np.abs(sens(ctx, res.kp, res.ki, chk.ms_peaks)) > ms_t]
            if ms_w.size:  # peaks were added already, yet the peak moved: tighten as well
                ms_t /= 1.0 + viol["max_sensitivity"] + 1e-7
            ms_w = np.append(ms_w, np.outer(hot, PEAK_STENCIL))
        if viol.get("crossover_rad_s", 0.0) > 0:
            wc_w = np.append(wc_w, chk.wc_top)
        if viol.get("phase_margin_deg", 0.0) > 0:
            pm_t = min(89.99, pm_t + viol["phase_margin_deg"] + 1e-6)
        if viol.get("gain_margin_db", 0.0) > 0:
            gm_t += viol["gain_margin_db"] + 1e-6
    return designs, iterations


def _recheck(
    designs: list[_Design],
    ctx: Ctx,
    p_scaled: control.StateSpace,
    spec: Spec,
    w_check: np.ndarray,
    where: str,
) -> tuple[_Design, Any]:
    """The design python-control finds acceptable, and its check.

    Raises
    ------
    SpecError
        No design is acceptable.
    """
    # the re-check by python-control decides: designs that meet the targets, the largest Ki
    # first, then those within the tolerances, the last refined first
    tried = sorted((d for d in designs if d[3]), key=lambda d: -d[1])
    tried += [d for d in designs[::-1] if not d[3]]
    for design in tried:
        w_design = fast_check(ctx, design[0], design[1], w_check).w
        chk = python_control_check(p_scaled, design[0], design[1], w_design)
        viol = violations(chk, spec)
        if acceptable(viol):
            break
    else:
        worst = max(viol, key=lambda k: viol[k])
        raise SpecError(
            f"cannot meet {spec.describe()} {where} with a PI (kp >= 0, ki > 0): "
            f"the best design found misses {worst}"
        )
    return design, chk


def _binding(viol: dict[str, float]) -> tuple[str, ...]:
    """The targets the design sits on (within :data:`_BINDING_TOL` of them)."""
    return tuple(k for k, v in viol.items() if k in _BINDING_TOL and v >= _BINDING_TOL[k])


@scipy_paths
def tune_pi(
    plant: Plant | control.TransferFunction,
    *,
    period_s: float,
    phase_margin_deg: float | None = None,
    gain_margin_db: float | None = None,
    max_sensitivity: float | None = None,
    crossover_rad_s: float | None = None,
    compute_s: float = 0.0,
    lsb_v: float | None = None,
    filters: Sequence[SectionQ] = (),
) -> PITuning:
    """PI gains with the largest integral gain Ki that meet the robustness targets.

    The controller is the runtime's (:mod:`servotune.laws.pi`), ``C(z) = Kp + Ki·T·z/(z−1)``,
    and the loop ``L(z) = C(z) · lsb_v · P(z)`` is exact in discrete time: ``P`` is the plant
    discretised with a zero-order hold at ``period_s`` and its input lagged by ``compute_s``
    (plus ``delay_s`` for a :class:`~servotune.plant.Plant`): :func:`~servotune.modal.discretize`
    or :func:`~servotune.plant.discretize_lti`.

    Formulation (a constrained NLP solved by casadi/ipopt): maximise Ki over ``Kp >= 0``,
    ``Ki > 0`` and, as extra variables, the frequency ``ωc`` of every gain crossover (if a
    phase margin is asked) and ``ωp`` of every phase crossover (if a gain margin is asked),
    subject to

    - phase margin, at each ``ωc``: ``|L(ωc)| = 1`` and ``arg L(ωc) + 180° >= phase_margin_deg``
      (the phase taken on its branch, as python-control's margin);
    - gain margin, at each ``ωp``: ``arg L(ωp) = −180°`` (or −540°, ...) and
      ``−20·log10|L(ωp)| >= gain_margin_db``;
    - sensitivity: ``|1 + L(ω)| >= 1/max_sensitivity`` at every design-grid frequency;
    - crossover bound: ``|L(ω)| <= 1`` at ``crossover_rad_s`` and every grid frequency above it
      (and ``ωc <= crossover_rad_s``).

    ``L`` is linear in (Kp, Ki): the plant's response is computed once with numpy on the
    design grid and enters as constants; at the crossover variables it enters through cubic
    splines of its log-magnitude and unwrapped phase on that grid. The design grid is
    log-spaced, :data:`POINTS_PER_DECADE` per decade, from :data:`DECADES_BELOW` decades below
    the slowest plant pole/zero (``1/tau_s`` for a Plant) to the Nyquist frequency ``π/T``
    included, plus a linear grid fine enough that the lag turns the phase by at most 0.2 rad
    per step, plus 129 points around each lightly damped pole (ζ < 0.2). Each crossover
    variable is kept between its neighbours'; the start point is the best design on the
    phase-margin loci (for each grid ω, the (Kp, Ki) that put ``L`` at the margin there),
    checked against all targets on the grid and for stability.

    Re-check and refinement: every NLP solution is checked on a verification grid (the design
    grid's midpoints, plus the refined extrema of ``|L|`` near 1 and of its phase near −180°,
    so that no pair of crossings hides between points) with crossings solved on the exact
    loop. A target missed between grid points is refined by an exchange step (the missed
    sensitivity peak's frequencies added as constraints, or the target tightened by the miss)
    and the NLP solved again; if the solution has a gain crossover above those modelled and
    misses a target, ``|L| <= 0.95`` is imposed at that peak of ``|L|`` (a design with a new
    crossover there is not searched); if crossovers otherwise appear or vanish, the NLP is
    rebuilt around the new loop. The start point stays a candidate. The final design is
    re-checked
    with python-control, and every reported number is python-control's: margins from
    ``control.stability_margins`` on the loop's ``control.frequency_response`` (its FRD
    method; its polynomial method is ill-conditioned for short periods), the sensitivity peak
    over that response (refined between neighbours), stability from the poles of
    ``control.feedback(L, 1)``. Targets are then met exactly up to the NLP's tolerances
    (about 1e-6° and 1e-7 relative) or, after eight solves, within 0.5° / 0.1 dB / 1 % / 1 %
    (reported as found); a larger miss, or an unstable loop, raises
    :class:`~servotune.errors.SpecError`.

    A phase margin below 90° is always reachable with small enough gains on a stable plant,
    a plant with an integrator included (Ki then becomes small: ``phase_margin_deg=89`` on the
    example rig gives Ki ≈ 2e-5 codes/(count·s)); a spec is impossible when no PI with
    ``Kp, Ki >= 0`` stabilises the plant while meeting it.

    Parameters
    ----------
    plant : Plant or control.TransferFunction
        Axis model (volts → counts, lag ``delay_s`` included), any continuous SISO system, or
        a SISO system already discrete at ``period_s`` (e.g. a closed inner loop; then
        ``compute_s`` must be whole periods and acts as ``z^-m``).
    period_s : float
        Sample period [s]: for a rig, the achieved timer period.
    phase_margin_deg : float, optional
        Lower bound on the phase margin [deg], in (0, 90).
    gain_margin_db : float, optional
        Lower bound on the gain margin [dB], > 0.
    max_sensitivity : float, optional
        Upper bound on ``max |1/(1 + L)|`` [-], > 1.
    crossover_rad_s : float, optional
        Upper bound on the gain crossover frequency [rad/s], below ``π/period_s``.
    compute_s : float
        Sample instant → output write [s], >= 0 (the loop's computation lag).
    lsb_v : float, optional
        Output units per controller unit. Default: the 12-bit ±10 V D/A step 20/4096 V for a
        :class:`~servotune.plant.Plant` (gains in D/A codes), 1.0 for a transfer function.
    filters : sequence of SectionQ
        Quantised output filters between the controller and the plant
        (``AxisController.filters``): the loop is ``C(z)·F(z)·lsb_v·P(z)``.

    Returns
    -------
    PITuning
        Gains [codes/count], [codes/(count·s)] and the loop's margins.

    Raises
    ------
    SpecError
        If no target (phase, gain margin or sensitivity) is given, a target is out of range,
        or no stabilising PI with ``Kp >= 0, Ki > 0`` meets the targets.
    ValueError
        If ``period_s``, ``compute_s``, ``lsb_v`` or ``plant`` are invalid.

    Examples
    --------
    >>> import control
    >>> r = tune_pi(control.tf([1], [1, 3, 3, 1]), period_s=0.001, phase_margin_deg=60)
    >>> round(r.phase_margin_deg, 1), round(r.ki, 2)
    (60.0, 0.45)
    """
    if lsb_v is None:
        lsb_v = hw_dac.lsb_v() if isinstance(plant, Plant) else 1.0
    spec = check_spec(
        period_s,
        compute_s,
        lsb_v,
        phase_margin_deg,
        gain_margin_db,
        max_sensitivity,
        crossover_rad_s,
    )
    ctx, p_scaled = _loop_context(plant, period_s, compute_s, lsb_v, spec, filters)
    w_check = check_grid(ctx.w)
    where = f"on this plant at period_s={period_s:g} s, compute_s={compute_s:g} s"

    start = start_point(ctx, spec)
    if start is None:
        raise InfeasibleError(
            f"no stabilising PI with kp >= 0, ki > 0 meets {spec.describe()} {where}"
        )
    designs, iterations = _refine(ctx, spec, start, w_check)
    viol = violations(fast_check(ctx, *start, w_check), spec)
    designs.append((*start, "start point", acceptable(viol, strict=True)))
    (kp, ki, status, _), chk = _recheck(designs, ctx, p_scaled, spec, w_check, where)
    binding = _binding(violations(chk, spec))
    return PITuning(
        kp=kp,
        ki=ki,
        period_s=float(period_s),
        compute_s=float(compute_s),
        lsb_v=float(lsb_v),
        crossover_rad_s=chk.wgc,
        phase_margin_deg=chk.pm_deg,
        gain_margin_db=chk.gm_db,
        phase_crossover_rad_s=chk.wpc,
        max_sensitivity=chk.ms,
        sensitivity_peak_rad_s=chk.w_ms,
        spectral_radius=chk.rho,
        target_phase_margin_deg=spec.pm_deg,
        target_gain_margin_db=spec.gm_db,
        target_max_sensitivity=spec.ms,
        target_crossover_rad_s=spec.wc_max,
        binding=binding,
        solver_status=status,
        solver_iterations=iterations,
    )


def tune_pi_axis(rig: Rig, axis_name: str, **targets: float | None) -> PITuning:
    """:func:`tune_pi` for one axis of a rig, at the rig's achieved period and compute lag.

    ``period_s`` is ``rig.period_s`` (the achieved timer period), ``compute_s`` is
    ``rig.timer.compute_s`` and ``lsb_v`` is ``rig.dac.lsb_v``, so the gains are in D/A codes
    per count as the runtime uses them.

    Parameters
    ----------
    rig : Rig
    axis_name : str
        Name of the axis (``rig.axis_names``).
    **targets : float
        ``phase_margin_deg``, ``gain_margin_db``, ``max_sensitivity``, ``crossover_rad_s``.

    Returns
    -------
    PITuning

    Raises
    ------
    RigError
        If the rig has no such axis.
    SpecError
        As :func:`tune_pi`, or if a target is not one of the four names.
    """
    allowed = {"phase_margin_deg", "gain_margin_db", "max_sensitivity", "crossover_rad_s"}
    unknown = sorted(set(targets) - allowed)
    if unknown:
        raise SpecError(
            f"tune_pi_axis takes only the targets {', '.join(sorted(allowed))}; got "
            f"{', '.join(unknown)} (period_s, compute_s and lsb_v come from the rig)"
        )
    axis = rig.axis(axis_name)
    return tune_pi(
        axis.plant,
        period_s=rig.period_s,
        compute_s=rig.timer.compute_s,
        lsb_v=rig.dac.lsb_v,
        **targets,  # type: ignore[arg-type]
    )
