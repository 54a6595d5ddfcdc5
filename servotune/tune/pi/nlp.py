"""The casadi/ipopt NLP of :func:`~servotune.tune.pi.design.tune_pi` for one crossing structure
of the loop: the crossings it models (``_crossings``, ``_modelled``) and the NLP (``Nlp``)."""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from servotune.tune.pi.grid import Ctx, q_im
from servotune.tune.pi.spec import GUARD_GAIN, Spec

__all__: list[str] = []


class _Crossing(NamedTuple):
    """A crossing of the start loop: ln ω, its bracket [lo, hi] and its phase branch/level."""

    x: float
    lo: float
    hi: float
    level: float  # gain crossover: the branch offset b (PM = ph − b − π); phase: the level


_MAX_CROSSINGS = 6


def _crossings(ctx: Ctx, kp: float, ki: float) -> tuple[list[_Crossing], list[_Crossing]]:
    """Gain crossovers and phase crossings (odd multiples of π) of the loop on the grid.

    Each is located by linear interpolation in ln ω and bracketed by the midpoints to its
    neighbours of the same kind (the grid ends outside).
    """
    t = ctx.period_s
    cr, ci = kp + 0.5 * ki * t, ki * ctx.q_im
    lnl = np.log(np.abs((cr + 1j * ci) * ctx.g) + 1e-300)
    phl = ctx.ph + np.arctan2(ci, cr)
    lw = np.log(ctx.w)

    def bracket(xs: list[float], levels: list[float]) -> list[_Crossing]:
        out = []
        for i, (x, lvl) in enumerate(zip(xs, levels, strict=True)):
            lo = lw[0] if i == 0 else 0.5 * (xs[i - 1] + x)
            hi = lw[-1] if i == len(xs) - 1 else 0.5 * (x + xs[i + 1])
            out.append(_Crossing(float(x), float(lo), float(hi), float(lvl)))
        return out[:_MAX_CROSSINGS]

    i = np.flatnonzero((lnl[:-1] >= 0) != (lnl[1:] >= 0))
    f = lnl[i] / (lnl[i] - lnl[i + 1])
    xs = list(lw[i] + f * (lw[i + 1] - lw[i]))
    ph_c = phl[i] + f * (phl[i + 1] - phl[i])
    gains = bracket(xs, list(2 * math.pi * np.floor(ph_c / (2 * math.pi))))
    k = np.floor((phl + math.pi) / (2 * math.pi))
    i = np.flatnonzero(k[:-1] != k[1:])
    lvl = np.maximum(k[i], k[i + 1]) * 2 * math.pi - math.pi
    f = (lvl - phl[i]) / (phl[i + 1] - phl[i])
    phases = bracket(list(lw[i] + f * (lw[i + 1] - lw[i])), list(lvl))
    return gains, phases


def _modelled(
    ctx: Ctx, spec: Spec, kp: float, ki: float
) -> tuple[list[_Crossing], list[_Crossing]]:
    """The crossings the NLP models: every gain crossover if a phase margin is asked; the
    phase crossings if a gain margin is asked, except those with a margin 20 dB beyond the
    target (the re-check watches them) and a touch at the Nyquist frequency (where ``L`` is
    real; a constraint of its own)."""
    xcs, x180s = _crossings(ctx, kp, ki)
    if spec.pm_deg is None:
        xcs = []
    if spec.gm_db is None:
        return xcs, []
    t = ctx.period_s
    x_last = math.log(ctx.w[-2])
    keep = []
    for c in x180s:
        om = np.array([math.exp(c.x)])
        loop = (kp + ki * (0.5 * t + 1j * q_im(om, t)[0])) * ctx.resp(om)[0]
        gm_db = -20 * math.log10(abs(loop))
        if c.x < x_last and gm_db < spec.gm_db + 20.0:
            keep.append(c)
    return xcs, keep


class NlpResult(NamedTuple):
    kp: float
    ki: float
    x: np.ndarray  # the solution vector (scaled gains, crossing frequencies)
    status: str
    iterations: int
    success: bool
    on_bracket: bool  # a crossing ended on an inner bracket bound: rebuild from here


_N_EXTRA_MS, _N_EXTRA_WC = 24, 16  # parameter slots for frequencies added by the refinement


class Nlp:
    """The NLP for the crossing structure of one loop (built again when that changes).

    Variables: ``kp/kp0``, ``ki/ki0`` (scaled by the gains it is built from) and the ln ω of
    every gain crossover (if a phase margin is asked) and phase crossing (if a gain margin is
    asked) of that loop, each kept inside its bracket. Objective: ``−ki/ki0``. The targets and
    the frequencies added by the refinement are parameters, so one build serves every round.
    """

    def __init__(self, ctx: Ctx, spec: Spec, gains: tuple[float, float]) -> None:
        import casadi as ca

        t = ctx.period_s
        self.ctx, self.kp0, self.ki0 = ctx, gains[0], gains[1]
        xcs, x180s = _modelled(ctx, spec, *gains)
        self.structure = (len(xcs), tuple(c.level for c in x180s))
        lw = np.log(ctx.w)
        nv = 2 + len(xcs) + len(x180s)
        v = ca.SX.sym("v", nv)
        # parameters: PM target [rad], ln GM target, Ms², then (Re G, Im G, Im q) per slot
        p_t = ca.SX.sym("p_t", 3)
        p_ms = ca.SX.sym("p_ms", 3, _N_EXTRA_MS)
        p_wc = ca.SX.sym("p_wc", 3, _N_EXTRA_WC)
        p_gd = ca.SX.sym("p_gd", 3, _N_EXTRA_WC)
        kp, ki = self.kp0 * v[0], self.ki0 * v[1]
        cr = kp + 0.5 * t * ki
        g: list[Any] = []
        lbg: list[float] = []
        ubg: list[float] = []

        def loop(gr: Any, gi: Any, qim: Any) -> tuple[Any, Any]:
            ci = ki * qim
            return cr * gr - ci * gi, cr * gi + ci * gr

        def add(expr: Any, lo: float, hi: float) -> None:
            g.append(expr)
            lbg.extend([lo] * expr.numel())
            ubg.extend([hi] * expr.numel())

        if spec.ms is not None:
            # in log form: |1 + L| spans decades over the grid
            lr, li = loop(ca.DM(ctx.g.real), ca.DM(ctx.g.imag), ca.DM(ctx.q_im))
            add(ca.log(p_t[2]) + ca.log((1 + lr) ** 2 + li**2), 0.0, math.inf)
            lr, li = loop(p_ms[0, :].T, p_ms[1, :].T, p_ms[2, :].T)
            add(p_t[2] * ((1 + lr) ** 2 + li**2) - 1, 0.0, math.inf)
        top = lw[-1]
        if spec.wc_max is not None:
            top = min(top, math.log(spec.wc_max))
            above = ctx.w > spec.wc_max
            if above.any():
                gw, qw = ctx.g[above], ctx.q_im[above]
                lr, li = loop(ca.DM(gw.real), ca.DM(gw.imag), ca.DM(qw))
                add(1 - (lr**2 + li**2), 0.0, math.inf)
        if spec.gm_db is not None and ctx.g[-1].real < 0:
            # at the Nyquist frequency L is real: a gain margin there, L(π/T) >= −1/GM
            add(1 + (cr * ctx.g[-1].real) * ca.exp(p_t[1]), 0.0, math.inf)
        # |L| <= 1 at added frequencies (the crossover bound), |L| <= 0.95 at guards against
        # new crossovers
        lr, li = loop(p_wc[0, :].T, p_wc[1, :].T, p_wc[2, :].T)
        add(1 - (lr**2 + li**2), 0.0, math.inf)
        lr, li = loop(p_gd[0, :].T, p_gd[1, :].T, p_gd[2, :].T)
        add(GUARD_GAIN**2 - (lr**2 + li**2), 0.0, math.inf)
        if xcs or x180s:
            f_ln = ca.interpolant("ln_g", "bspline", [lw], np.log(np.abs(ctx.g) + 1e-300))
            f_ph = ca.interpolant("ph_g", "bspline", [lw], ctx.ph)

            def at(x: Any) -> tuple[Any, Any]:
                ci = -ki * 0.5 * t / ca.tan(0.5 * t * ca.exp(x))
                return f_ln(x) + 0.5 * ca.log(cr**2 + ci**2), f_ph(x) + ca.atan2(ci, cr)

        self.lbx, self.ubx = [0.0, 1e-9], [math.inf, math.inf]
        self.x0 = [1.0, 1.0]
        self.inner: list[tuple[int, float, float]] = []  # variable, inner bracket bounds
        k = 2
        for c in xcs:  # PM = (phase − branch) − π, python-control's convention
            ln_c, ph_c = at(v[k])
            add(ln_c, 0.0, 0.0)
            add(ph_c - c.level - math.pi - p_t[0], 0.0, math.inf)
            add(ph_c - c.level - 2 * math.pi, -math.inf, 0.0)  # PM < 180°: no wrap
            self._bound(k, c, hi_cap=top)
            k += 1
        for c in x180s:
            ln_p, ph_p = at(v[k])
            add(ph_p - c.level, 0.0, 0.0)
            add(-ln_p - p_t[1], 0.0, math.inf)
            self._bound(k, c)
            k += 1
        self.lbg, self.ubg = lbg, ubg
        params = ca.vertcat(p_t, ca.vec(p_ms), ca.vec(p_wc), ca.vec(p_gd))
        nlp = {"x": v, "p": params, "f": -v[1], "g": ca.vertcat(*g) if g else ca.SX(0, 1)}
        opts = {
            "print_time": False,
            "ipopt.print_level": 0,
            "ipopt.sb": "yes",
            "ipopt.tol": 1e-10,
            "ipopt.constr_viol_tol": 1e-10,
            "ipopt.max_iter": 100,
        }
        self.solver = ca.nlpsol("tune_pi", "ipopt", nlp, opts)

    @staticmethod
    def structure_of(ctx: Ctx, spec: Spec, kp: float, ki: float) -> tuple[int, tuple]:
        """What the NLP models of a loop: the number of gain crossovers, the phase levels."""
        xcs, x180s = _modelled(ctx, spec, kp, ki)
        return len(xcs), tuple(c.level for c in x180s)

    def _bound(self, k: int, c: _Crossing, hi_cap: float = math.inf) -> None:
        lw = np.log(self.ctx.w)
        hi = min(c.hi, hi_cap)
        lo = min(c.lo, hi - 1e-9)
        self.lbx.append(lo)
        self.ubx.append(hi)
        self.x0.append(min(max(c.x, lo), hi))
        self.inner.append((k, lo if lo > lw[0] else -math.inf, hi if c.hi < lw[-1] else math.inf))

    def _slots(self, w: np.ndarray, n: int) -> np.ndarray:
        """Parameter values for ``n`` slots: the last ``n`` frequencies of ``w``."""
        out = np.zeros((3, n))  # an empty slot has G = 0: a constraint that always holds
        w = np.asarray(w, dtype=float)[-n:]
        if w.size:
            ctx = self.ctx
            gw = ctx.resp(w)
            out[:, : w.size] = [gw.real, gw.imag, q_im(w, ctx.period_s)]
        return out

    def solve(
        self,
        x0: np.ndarray | None,
        *,
        pm_deg: float,
        gm_db: float,
        ms: float,
        ms_w: np.ndarray,
        wc_w: np.ndarray,
        guard_w: np.ndarray,
    ) -> NlpResult:
        """Solve from ``x0`` (a previous solution; None: the build point)."""
        p = np.concatenate(
            [
                [math.radians(pm_deg), gm_db / 20 * math.log(10), ms**2],
                self._slots(ms_w, _N_EXTRA_MS).ravel(order="F"),
                self._slots(wc_w, _N_EXTRA_WC).ravel(order="F"),
                self._slots(guard_w, _N_EXTRA_WC).ravel(order="F"),
            ]
        )
        x_start = self.x0 if x0 is None else x0
        sol = self.solver(x0=x_start, p=p, lbx=self.lbx, ubx=self.ubx, lbg=self.lbg, ubg=self.ubg)
        stats = self.solver.stats()
        xs = np.asarray(sol["x"]).ravel()
        status = str(stats.get("return_status", "unknown"))
        ok = bool(stats.get("success", False)) or status == "Solved_To_Acceptable_Level"
        on_bracket = any(
            abs(xs[k] - lo) < 1e-6 or abs(xs[k] - hi) < 1e-6 for k, lo, hi in self.inner
        )
        return NlpResult(
            kp=max(0.0, float(xs[0] * self.kp0)),
            ki=max(0.0, float(xs[1] * self.ki0)),
            x=xs,
            status=status,
            iterations=int(stats.get("iter_count", 0)),
            success=ok,
            on_bracket=on_bracket,
        )
