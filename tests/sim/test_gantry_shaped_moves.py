"""The gantry's shaped move (servotune.arch.gantry.shaping;
docs/systems.md#shaping-the-gantrys-move): the vibration both sides are left with after the
CNC's move, unshaped and shaped, in the gantry's own engine (the numba kernel both drives and
the sync loop run in).

The gantry: plants/gantry.toml with a lightly damped mode on each side (the master 13 Hz, the
slave 13 Hz or 21 Hz; damping 0.02, gain 0.3; the drive loops tuned with 13 Hz on both), a
move of 6,000 counts with 15 ms ramps (its spectrum's zeros lie at multiples of 10 Hz and of
67 Hz: it excites 13 Hz well and 21 Hz less), and
offset, friction and encoder noise off so that after the move the loops are linear. The
vibration is measured by a matrix-pencil fit of each side's true position after the command
has stopped (tests/sim/vibration.py), not by the design code's residual formula.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from vibration import vibration_near

from servotune.arch.gantry import (
    compare_topologies,
    gantry_command,
    gantry_shaper,
    move_profile,
    simulate_gantry,
)
from servotune.arch.gantry.load import load_gantry
from servotune.arch.gantry.shaping import drive_modes
from servotune.arch.gantry.synthesis import resolve_gains
from servotune.errors import ConfigError
from servotune.report.text import format_comparison
from servotune.resonance import Mode

ROOT = Path(__file__).resolve().parents[2]
WINDOW = 700  # cycles after the command stops (0.7 s: a 13 Hz mode of damping 0.04 decays e^-4.6)


def _gantry(master_hz: float = 13.0, slave_hz: float = 13.0, shaper: str = "none"):
    cfg = load_gantry(ROOT / "plants" / "gantry.toml")

    def side(drive, hz: float):
        plant = dataclasses.replace(
            drive.plant,
            noise_counts=0.0,
            coulomb_v=0.0,
            offset_v=0.0,
            modes=(Mode(freq_hz=hz, damping=0.02, gain=0.3),),
        )
        return dataclasses.replace(drive, plant=plant)

    move = dataclasses.replace(
        cfg.move, distance_counts=6_000, speed_cps=60_000.0, accel_cps2=4.0e6, shaper=shaper
    )
    cfg = dataclasses.replace(
        cfg,
        seconds=1.6,
        master=side(cfg.master, master_hz),
        slave=side(cfg.slave, slave_hz),
        move=move,
    )
    return resolve_gains(cfg)


def _scaled(cfg, scale: float):
    """The same drives (gains kept) on plants whose modes lie at ``scale`` times theirs."""

    def side(drive):
        modes = tuple(dataclasses.replace(m, freq_hz=m.freq_hz * scale) for m in drive.plant.modes)
        return dataclasses.replace(drive, plant=dataclasses.replace(drive.plant, modes=modes))

    return dataclasses.replace(cfg, master=side(cfg.master), slave=side(cfg.slave))


def _vibration(cfg, cmd: np.ndarray, side: int, near_hz: float) -> float:
    tr = simulate_gantry(cfg, "listening", case="mismatch", command=cmd)
    end = int(np.flatnonzero(np.diff(cmd))[-1]) + 1
    assert end + WINDOW <= cmd.size
    x = tr.position[end : end + WINDOW, side] - cmd[-1]
    return vibration_near(x, cfg.bus.cycle_s, near_hz)


@pytest.fixture(scope="module")
def one_mode():
    base = _gantry()
    shaped = {
        k: dataclasses.replace(base, move=dataclasses.replace(base.move, shaper=k))
        for k in ("zv", "zvd", "ei")
    }
    cmds = {k: gantry_command(c, base.n_cycles) for k, c in shaped.items()}
    cmds["none"] = gantry_command(base, base.n_cycles)
    near = drive_modes(base)[0][1].freq_hz
    return base, cmds, near


@pytest.mark.parametrize("scale", [0.85, 1.0, 1.15])
def test_a_shaped_gantry_move_leaves_at_most_5_percent_of_the_vibration(one_mode, scale) -> None:
    """Shapers designed for the nominal closed-loop mode, both sides' plants at 85 %, 100 % and
    115 % of it, in the deployed (listening) topology.

    - At nominal every kind leaves ≤ 5 % of the unshaped vibration on either side.
    - Over ±15 % zvd and ei do on the master, which follows the command; zv does not (so the
      measurement tells them apart).
    - The slave follows the command plus the sync compensator's reaction to the two sides'
      difference, a path the shaper does not see: over ±15 % ei keeps ≤ 5 % there too, zvd
      ≤ 10 %.

    Measured (2026-11-30), unshaped master / slave [counts] and zv, zvd, ei [% of it]:
    85 %: 28.2 / 11.2, master 21.6, 4.7, 2.1, slave 31.8, 9.3, 4.8;
    100 %: 35.1 / 25.9, master 0.1, 0.1, 2.8, slave 1.9, 0.3, 2.1;
    115 %: 26.3 / 14.7, master 22.0, 4.6, 2.1, slave 21.8, 4.0, 1.3."""
    base, cmds, near = one_mode
    cfg = _scaled(base, scale)
    for side in (0, 1):
        unshaped = _vibration(cfg, cmds["none"], side, near * scale)
        assert unshaped > 10.0  # the move does excite the mode [counts]
        ratios = {
            k: _vibration(cfg, cmds[k], side, near * scale) / unshaped for k in ("zv", "zvd", "ei")
        }
        if scale == 1.0:
            limits = {"zv": 0.05, "zvd": 0.05, "ei": 0.05}
        else:
            limits = {"zvd": 0.05 if side == 0 else 0.10, "ei": 0.05}
            assert ratios["zv"] > 0.15, (side, ratios)
        for k, lim in limits.items():
            assert ratios[k] <= lim, (side, k, ratios)


def test_two_modes_get_the_product_and_both_sides_are_quiet(one_mode) -> None:
    """The master's mode at 13 Hz, the slave's at 21 Hz (the drives keep the gains tuned with
    13 Hz on both): ``auto`` designs for both (a product of two shapers), and each side keeps
    ≤ 5 % of its unshaped vibration at its own mode."""
    base, _, _ = one_mode
    slave_plant = dataclasses.replace(
        base.slave.plant, modes=(Mode(freq_hz=21.0, damping=0.02, gain=0.3),)
    )
    cfg = dataclasses.replace(
        base,
        slave=dataclasses.replace(base.slave, plant=slave_plant),
        move=dataclasses.replace(base.move, shaper="auto"),
    )
    modes = drive_modes(cfg)
    assert [side for side, _ in modes] == ["master", "slave"]
    sh, _ = gantry_shaper(cfg)
    assert sh is not None and "×" in sh.kind and len(sh.modes) == 2
    plain = dataclasses.replace(cfg, move=dataclasses.replace(cfg.move, shaper="none"))
    n = cfg.n_cycles
    for side, (_, m) in enumerate(modes):
        unshaped = _vibration(cfg, gantry_command(plain, n), side, m.freq_hz)
        shaped = _vibration(cfg, gantry_command(cfg, n), side, m.freq_hz)
        # the slave's 21 Hz is excited less by this move (1.9 counts, measured), but with the
        # noise off a count is still measured to far better than 5 %
        assert unshaped > 1.0 and shaped / unshaped <= 0.05, (side, unshaped, shaped)


def test_the_added_move_time_is_stated_and_is_what_the_command_shows(one_mode) -> None:
    """The command's last change comes ``n_taps − 1`` cycles after the unshaped move's (up to 2
    cycles earlier: the last impulse's share of the ramp's last, smallest steps rounds to no
    count), and the comparison's text says so in milliseconds and cycles; the shaped command
    still ends at the move's distance."""
    base, cmds, _ = one_mode
    cfg = dataclasses.replace(base, move=dataclasses.replace(base.move, shaper="zvd"))
    sh, _ = gantry_shaper(cfg)
    last = {k: int(np.flatnonzero(np.diff(cmds[k]))[-1]) for k in ("none", "zvd")}
    assert sh.n_taps - 3 <= last["zvd"] - last["none"] <= sh.n_taps - 1
    assert cmds["zvd"][-1] == cmds["none"][-1] == base.move.distance_counts
    text = format_comparison(compare_topologies(cfg))
    want = f"{1000 * sh.added_time_s:.1f} ms ({sh.n_taps - 1} cycles) later"
    assert want in text and "move shaping:" in text
    assert gantry_shaper(base) == (None, [])  # no shaper: no line (what the comparison prints)
    unshaped = move_profile(base.move, base.bus.cycle_s, base.n_cycles)
    assert np.array_equal(cmds["none"], unshaped)  # no shaper: the move as it was


def test_a_shaper_without_modes_or_of_an_unknown_kind_is_refused() -> None:
    cfg = load_gantry(ROOT / "plants" / "gantry.toml")  # rigid plants (no gains needed)
    cfg = dataclasses.replace(cfg, move=dataclasses.replace(cfg.move, shaper="zvd"))
    with pytest.raises(ConfigError, match="neither drive's plant has modes"):
        gantry_shaper(cfg)
    with pytest.raises(ConfigError, match=r"move\.shaper must be one of none, auto, zv, zvd, ei"):
        dataclasses.replace(cfg.move, shaper="zvdd")
