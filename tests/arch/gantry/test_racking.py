"""The gantry beam's racking mode (docs/systems.md): ``[beam] racking_hz``/``racking_damping``
become the beam's stiffness and damping, checked against the poles of the two coupled drives
built here with python-control (not servotune's formula), and the gantry runs with it."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import control
import numpy as np
import pytest

from servotune.arch.gantry.config import Beam
from servotune.arch.gantry.load import load_gantry
from servotune.arch.gantry.run import simulate_gantry
from servotune.arch.gantry.synthesis import resolve_gains
from servotune.errors import ConfigError

ROOT = Path(__file__).resolve().parents[3]


def _coupled_poles(k_g: float, tau: float, k: float, c: float) -> np.ndarray:
    """Poles of both sides' drives (``τ v̇ + v = K (u ∓ f)``) coupled by ``f = k e + c ė``,
    ``e = p_0 − p_1``, state ``(p_0, v_0, p_1, v_1)``."""
    a = np.array(
        [
            [0.0, 1.0, 0.0, 0.0],
            [-k_g * k / tau, -(1.0 + k_g * c) / tau, k_g * k / tau, k_g * c / tau],
            [0.0, 0.0, 0.0, 1.0],
            [k_g * k / tau, k_g * c / tau, -k_g * k / tau, -(1.0 + k_g * c) / tau],
        ]
    )
    return control.poles(control.ss(a, np.zeros((4, 1)), np.eye(4)[:1], 0.0))


@pytest.mark.parametrize(("hz", "zeta"), [(20.0, 0.2), (35.0, 0.3), (8.0, 0.5)])
def test_the_racking_mode_is_the_coupled_drives_pole_pair(hz: float, zeta: float) -> None:
    cfg = load_gantry(ROOT / "plants" / "gantry.toml")
    cfg = dataclasses.replace(cfg, beam=Beam(racking_hz=hz, racking_damping=zeta))
    plant = cfg.master.plant
    b = cfg.beam
    assert b.coupled and b.racking_hz is None  # resolved into stiffness and damping
    poles = _coupled_poles(
        plant.gain_cps_per_v, plant.tau_s, b.stiffness_v_per_count, b.damping_v_s_per_count
    )
    pair = poles[np.abs(poles.imag) > 0]
    wn = np.abs(pair)
    assert np.allclose(wn / (2 * np.pi), hz, rtol=1e-9)
    assert np.allclose(-pair.real / wn, zeta, rtol=1e-9)
    f, z = b.racking(plant)
    assert (f, z) == pytest.approx((hz, zeta), rel=1e-12)


def test_the_gantry_runs_with_a_racking_beam() -> None:
    cfg = resolve_gains(load_gantry(ROOT / "plants" / "gantry.toml"))
    stiff = dataclasses.replace(cfg, beam=Beam(racking_hz=20.0, racking_damping=0.2))
    a = simulate_gantry(cfg, case="mismatch")
    b = simulate_gantry(stiff, case="mismatch")
    err_a = np.abs(a.position[:, 0] - a.position[:, 1]).max()
    err_b = np.abs(b.position[:, 0] - b.position[:, 1]).max()
    assert err_b < err_a  # the beam holds the sides together


def test_bad_racking_settings_are_refused() -> None:
    cfg = load_gantry(ROOT / "plants" / "gantry.toml")
    with pytest.raises(ConfigError, match="go together"):
        Beam(racking_hz=20.0)
    with pytest.raises(ConfigError, match="not both"):
        Beam(racking_hz=20.0, racking_damping=0.2, stiffness_v_per_count=0.1)
    with pytest.raises(ConfigError, match="drives' own damping"):
        dataclasses.replace(cfg, beam=Beam(racking_hz=20.0, racking_damping=0.01))
