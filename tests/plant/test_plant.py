"""Axis model: exact integration (with Coulomb sticking and speed limit) and discretisation."""

from __future__ import annotations

import math

import control
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.signal import cont2discrete

from servotune.modal import discretize
from servotune.plant import Plant, advance, step_coefficients


def _ode(gain: float, tau: float, w: float, coulomb: float, vmax: float):
    """Reference right-hand side (docs/formats.md#axis-model), integrated with tight tolerances by
    scipy."""

    def rhs(_t: float, x: np.ndarray) -> list[float]:
        v = x[1]
        s = math.copysign(1.0, v) if v != 0 else math.copysign(1.0, w)
        vinf = min(max(gain * (w - coulomb * s), -vmax), vmax)
        return [v, (vinf - v) / tau]

    return rhs


@pytest.mark.parametrize(
    ("v0", "w", "coulomb", "vmax"),
    [
        (0.0, 0.3, 0.0, math.inf),  # linear, from rest
        (1500.0, -0.2, 0.0, math.inf),  # linear, reversing (no friction: no event)
        (800.0, 0.01, 0.05, math.inf),  # friction brakes the axis to a stop: it sticks
        (2000.0, -0.5, 0.02, math.inf),  # friction, stops then reverses
        (0.0, 2.0, 0.01, 5000.0),  # speed limit binds
    ],
)
def test_advance_matches_ode(v0: float, w: float, coulomb: float, vmax: float) -> None:
    gain, tau, h = 12288.0, 0.025, 0.1
    a, b = step_coefficients(h, tau)
    p, v = advance(10.0, v0, w, h, a, b, gain, tau, coulomb, vmax)
    # reference: integrate up to the stop (event), then hold or continue
    rhs = _ode(gain, tau, w, coulomb, vmax)

    def stop(_t: float, x: np.ndarray) -> float:
        return x[1]

    stop.terminal = coulomb > 0 and v0 != 0  # type: ignore[attr-defined]
    sol = solve_ivp(rhs, (0, h), [10.0, v0], rtol=1e-11, atol=1e-9, events=stop)
    x = sol.y[:, -1]
    if sol.status == 1:  # stopped: sticks or restarts the other way
        t0 = sol.t_events[0][0]
        if abs(w) > coulomb:
            sol2 = solve_ivp(
                _ode(gain, tau, w, coulomb, vmax), (t0, h), [x[0], 0.0], rtol=1e-11, atol=1e-9
            )
            x = sol2.y[:, -1]
        else:
            x = np.array([x[0], 0.0])
    np.testing.assert_allclose([p, v], x, rtol=1e-7, atol=1e-6)


def test_sticks_at_rest_within_coulomb_band() -> None:
    # docs/formats.md#axis-model: at rest the motor stays at rest while |u + offset + load| <=
    # coulomb_v
    a, b = step_coefficients(0.004, 0.03)
    for w in (0.0, 0.002, -0.002, 0.0025):
        assert advance(5.0, 0.0, w, 0.004, a, b, 12000.0, 0.03, 0.0025, math.inf) == (5.0, 0.0)
    p, v = advance(5.0, 0.0, 0.0026, 0.004, a, b, 12000.0, 0.03, 0.0025, math.inf)
    assert v > 0 and p > 5.0


def test_discretize_equals_scipy_zoh_without_lag() -> None:
    pl = Plant(gain_cps_per_v=12288.0, tau_s=0.025)
    d = discretize(pl, 0.004, 0.0)
    ref = cont2discrete(
        (
            np.array([[0, 1], [0, -1 / 0.025]]),
            np.array([[0], [12288 / 0.025]]),
            np.array([[1, 0]]),
            np.array([[0]]),
        ),
        0.004,
        method="zoh",
    )
    np.testing.assert_allclose(d.A, ref[0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(d.B, ref[1], rtol=1e-12, atol=1e-9)


def test_discretize_with_whole_tick_lag_is_a_pure_shift() -> None:
    pl = Plant(gain_cps_per_v=12288.0, tau_s=0.025)
    t = np.arange(50, dtype=np.int64) * 0.004
    u = np.zeros(50)
    u[3:] = 1.0
    y0 = control.forced_response(discretize(pl, 0.004, 0.0), T=t, U=u).outputs
    y2 = control.forced_response(discretize(pl, 0.004, 0.008), T=t, U=u).outputs
    np.testing.assert_allclose(y2[2:], y0[:-2], rtol=1e-12, atol=1e-9)


def test_tf_round_trip_and_validation() -> None:
    pl = Plant(gain_cps_per_v=11700.0, tau_s=0.03, offset_v=0.004)
    back = Plant.from_tf(pl.to_tf(), offset_v=0.004)
    assert back.gain_cps_per_v == pytest.approx(11700.0, rel=1e-12)
    assert back.tau_s == pytest.approx(0.03, rel=1e-12)
    with pytest.raises(ValueError, match=r"tau_s must be > 0 \[s\], got -0.1"):
        Plant(gain_cps_per_v=1.0, tau_s=-0.1)
    with pytest.raises(ValueError, match="coulomb_v"):
        Plant(gain_cps_per_v=1.0, tau_s=0.1, coulomb_v=-1e-3)
    with pytest.raises(ValueError, match="from_tf"):
        Plant.from_tf(control.tf([1], [1, 1]))
