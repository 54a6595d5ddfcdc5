"""Margins and robustness of the gantry's loops, checked independently.

The oracle rebuilds each loop from the config's numbers with python-control's own primitives:
the drive plant ``K/(s(τs+1))`` with its input lag (drive compute time + plant delay, plus the
extra cycles) as a 6th-order Padé approximant, discretised by ``c2d`` (ZOH) at the bus cycle
(servotune uses the exact modified z-transform), the runtime PI ``Kp + Ki·T·z/(z−1)``, the
slave's drive loop closed by ``feedback``, the sync loop ``C(z)·z^-L·T_s(z)``; margins by
python-control's default ``stability_margins`` on the transfer function, Ms on a linear grid.
"""

from __future__ import annotations

import dataclasses
import math
import re
import warnings
from pathlib import Path

import control
import numpy as np
import pytest

from servotune.arch.gantry.load import load_gantry
from servotune.arch.gantry.margins import gantry_cases, gantry_margins
from servotune.arch.gantry.synthesis import resolve_gains
from servotune.cli import main
from servotune.errors import ConfigError

ROOT = Path(__file__).resolve().parents[3]
GANTRY = ROOT / "plants" / "gantry.toml"


@pytest.fixture(scope="module")
def cfg():
    return resolve_gains(load_gantry(GANTRY))


def _figures(loop: control.TransferFunction, dt: float) -> dict[str, float]:
    with warnings.catch_warnings():  # python-control may fall back to its FRD method
        warnings.simplefilter("ignore", UserWarning)
        gm, pm, _, _, _, _ = control.stability_margins(loop)
    w = np.linspace(1e-3, math.pi / dt * (1 - 1e-9), 20001)
    lw = loop(np.exp(1j * w * dt))
    return {
        "pm": pm,
        "gm_db": 20 * math.log10(gm) if np.isfinite(gm) else math.inf,
        "ms": float(np.max(np.abs(1 / (1 + lw)))),
    }


def _drive_loop(cfg, ax, plant, extra_cycles: int) -> control.TransferFunction:
    dt = cfg.bus.cycle_s
    lag = cfg.bus.compute_s + plant.delay_s + extra_cycles * dt
    g = control.tf([plant.gain_cps_per_v], [plant.tau_s, 1.0, 0.0])
    num, den = control.pade(lag, 6)
    p = control.c2d(g * control.tf(num, den), dt, method="zoh") * cfg.rig.dac.lsb_v
    z = control.tf([1.0, 0.0], [1.0], dt)
    c = ax.gains.kp + ax.gains.ki * dt * z / (z - 1)
    return control.minreal(c * p, verbose=False)


def _sync_loop(cfg, plant, extra_cycles: int) -> control.TransferFunction:
    dt = cfg.bus.cycle_s
    t_s = control.feedback(_drive_loop(cfg, cfg.slave, plant, 0), 1)  # the drive's own loop
    z = control.tf([1.0, 0.0], [1.0], dt)
    s = cfg.sync.gains
    comp = s.kp + s.ki * dt * z / (z - 1)
    latency = control.tf([1.0], [1.0] + [0.0] * (cfg.bus.latency_cycles + extra_cycles), dt)
    return control.minreal(comp * latency * t_s, verbose=False)


def test_the_plant_set_is_the_corners_on_time_and_late(cfg) -> None:
    cases = gantry_cases(cfg)
    assert len(cases) == 10  # (nominal + 4 corners) × (on time, one cycle late)
    assert cases[0].label == "nominal" and cases[1].label == "nominal+1cycle"
    gains = sorted({c.slave.gain_cps_per_v for c in cases})
    assert gains == pytest.approx([11100 * 0.8, 11100.0, 11100 * 1.2])  # plants/gantry.toml


def test_every_loop_agrees_with_an_independent_python_control_loop(cfg) -> None:
    margins = {(m.axis, m.plant): m for m in gantry_margins(cfg)}
    assert {a for a, _ in margins} == {"master", "slave", "sync"}  # listening: a sync loop
    dt = cfg.bus.cycle_s
    checked = 0
    for case in gantry_cases(cfg):
        if case.label not in ("nominal", "gain+,tau++1cycle", "gain-,tau+"):
            continue
        for axis, loop in (
            ("master", _drive_loop(cfg, cfg.master, case.master, case.extra_cycles)),
            ("slave", _drive_loop(cfg, cfg.slave, case.slave, case.extra_cycles)),
            ("sync", _sync_loop(cfg, case.slave, case.extra_cycles)),
        ):
            got, want = margins[(axis, case.label)], _figures(loop, dt)
            assert got.phase_margin_deg == pytest.approx(want["pm"], abs=0.5), (axis, case)
            assert got.gain_margin_db == pytest.approx(want["gm_db"], abs=0.2), (axis, case)
            assert got.max_sensitivity == pytest.approx(want["ms"], rel=0.01), (axis, case)
            checked += 1
    assert checked == 9


def test_the_example_gantry_is_robust_over_its_plant_set(cfg) -> None:
    # judged by the independent loops at every case: PM >= 45°, GM >= 6 dB, Ms <= 2
    dt = cfg.bus.cycle_s
    for case in gantry_cases(cfg):
        for loop in (
            _drive_loop(cfg, cfg.master, case.master, case.extra_cycles),
            _drive_loop(cfg, cfg.slave, case.slave, case.extra_cycles),
            _sync_loop(cfg, case.slave, case.extra_cycles),
        ):
            f = _figures(loop, dt)
            assert f["pm"] >= 45.0 - 0.5 and f["gm_db"] >= 6.0 and f["ms"] <= 2.0 * 1.01, case


def _anywhere(text: str) -> str:
    """The gantry config with its rig reference absolute (the copy lives elsewhere)."""
    rig = (ROOT / "plants" / "pc-dual-servo.toml").as_posix()
    return text.replace('rig = "pc-dual-servo.toml"', f'rig = "{rig}"')


def _with_gains(cfg, tmp_path: Path, latency_cycles: int) -> Path:
    """plants/gantry.toml with ``cfg``'s designed gains written in (nothing left to tune) and
    another bus latency; a short run."""
    text = _anywhere(GANTRY.read_text())
    text = re.sub(r"(?m)^latency_cycles = \d+", f"latency_cycles = {latency_cycles}", text)
    text = re.sub(r"(?m)^seconds = [0-9.]+", "seconds = 1.0", text)
    for name in ("master", "slave"):
        g = getattr(cfg, name).gains
        text = text.replace(f"[axis.{name}]\n", f"[axis.{name}]\nkp = {g.kp!r}\nki = {g.ki!r}\n")
    s = cfg.sync.gains
    text = text.replace('law = "pi"', f'law = "pi"\nkp = {s.kp!r}\nki = {s.ki!r}')
    path = tmp_path / "gantry.toml"
    path.write_text(text)
    return path


def test_one_cycle_more_latency_than_verified_fails_naming_the_loop(cfg, tmp_path, capsys):
    # the gains designed for a latency of 1 cycle keep the limits up to 1 + 1 extra cycle;
    # at 2 cycles (so 3 with the extra one) the sync loop loses phase margin
    assert main(["sync", str(_with_gains(cfg, tmp_path, 1))]) == 0
    out = capsys.readouterr().out
    assert "PASS" in out and "  sync   PM" in out
    assert main(["sync", str(_with_gains(cfg, tmp_path, 2))]) == 1
    out = capsys.readouterr().out
    assert "FAIL: margins: the sync loop on plant gain+,tau++1cycle: PM 44." in out
    assert "° < 45°" in out


def test_margins_table_is_read_and_checked(tmp_path) -> None:
    text = _anywhere(GANTRY.read_text())
    path = tmp_path / "g.toml"
    path.write_text(
        text.replace("extra_cycles = 1", "extra_cycles = 0").replace(
            "gain_spread = 0.2", "gain_spread = 0.1"
        )
    )
    c = load_gantry(path)
    assert (c.margins.extra_cycles, c.margins.gain_spread, c.margins.tau_spread) == (0, 0.1, 0.3)
    assert len(gantry_cases(c)) == 5  # nothing late
    path.write_text(text.replace("max_sensitivity = 2.0", "max_sensitivity = 0.5"))
    with pytest.raises(ConfigError, match="max_sensitivity"):
        load_gantry(path)
    path.write_text(text.replace("extra_cycles = 1", "extra_cycle = 1"))
    with pytest.raises(ConfigError, match="extra_cycle"):
        load_gantry(path)


def test_to_dict_carries_the_worst_loops(cfg) -> None:
    from servotune.arch.gantry.result import SyncComparison

    cmp = SyncComparison(
        config=cfg, rows=(), traces=(), predicted=None, failed=(), margins=gantry_margins(cfg)
    )
    d = cmp.to_dict()
    assert d["schema"] == "servotune.sync/2"
    assert set(d["margins"]["worst"]) == {"master", "slave", "sync"}
    assert d["margins"]["limits"]["extra_cycles"] == 1
    assert dataclasses.asdict(cfg.margins)["gain_spread"] == 0.2


def test_each_drive_may_have_its_own_spread(tmp_path) -> None:
    # the slave's own identification is poorer: ±40 % gain; the master keeps [margins]' ±20 %
    text = _anywhere(GANTRY.read_text()).replace(
        "[axis.slave]\n", "[axis.slave]\ngain_spread = 0.4\n"
    )
    path = tmp_path / "g.toml"
    path.write_text(text)
    c = load_gantry(path)
    cases = gantry_cases(c)
    m0, s0 = c.master.plant.gain_cps_per_v, c.slave.plant.gain_cps_per_v
    assert sorted({x.master.gain_cps_per_v / m0 for x in cases}) == pytest.approx([0.8, 1, 1.2])
    assert sorted({x.slave.gain_cps_per_v / s0 for x in cases}) == pytest.approx([0.6, 1, 1.4])
    path.write_text(text.replace("gain_spread = 0.4", "gain_spread = 1.5"))
    with pytest.raises(ConfigError, match="gain_spread"):
        load_gantry(path)
