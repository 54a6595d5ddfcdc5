"""The gantry's kernel against the single-rig engine, bit for bit (one tick engine).

Both compose the axis tick of :mod:`servotune.sim.tick`. A gantry the engine can express —
topology ``parallel`` (both drives follow the CNC's command), no sync jitter, the beam
uncoupled, the monitor off (so nothing is routed through the bus) — is a two-axis rig whose
axes each follow the same reference. The reference values here are the engine's
(:func:`servotune.sim.engine.simulate`) on a :class:`~servotune.sim.engine.Loop` built from
the gantry config's fields in this file, not by the gantry's own code: a rig ticking at the
bus cycle with the drive's compute time, the drives' plants, counter registers at power-up,
PI gains and following-error limits, the rig's counts per revolution for the speed limit, and
the same seed (one splitmix64 noise stream per run, master then slave each tick).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from servotune.arch.gantry import Beam, GantryConfig, simulate_gantry
from servotune.arch.gantry.load import load_gantry
from servotune.arch.gantry.synthesis import resolve_gains
from servotune.laws.axis import MODE_TASK
from servotune.laws.pi import PIGains
from servotune.rig import Axis, Rig, Timer
from servotune.scenarios import Inputs, trapezoid_ref
from servotune.sim.engine import Loop, simulate

ROOT = Path(__file__).resolve().parents[3]
CONFIG = ROOT / "plants" / "gantry.toml"
SEED = 7
N_CYCLES = 100_000


@pytest.fixture(scope="module")
def expressible() -> GantryConfig:
    """The example gantry (gains resolved) in a form the single-rig engine can run too.

    Changed from plants/gantry.toml, each for the comparison: topology parallel, jitter 0,
    the beam uncoupled, the monitor off; the drive's compute time is the rig's timer compute
    time; 100 s (100,000 cycles); the master's counter starts near the top of its 24-bit
    register (the move wraps it); the slave's plant has a longer dead time (compute + delay
    = 1.5 cycles: a whole cycle of lag in the tick-slot ring) and no encoder noise (no draw
    for it: the stream is the master's alone, in the ``mismatch`` case).
    """
    g = resolve_gains(load_gantry(CONFIG))
    bits = g.rig.counter.bits
    master = dataclasses.replace(g.master, counter_init=(1 << bits) - 40_000)
    slave = dataclasses.replace(
        g.slave,
        counter_init=0x400,
        plant=dataclasses.replace(g.slave.plant, delay_s=0.0013, noise_counts=0.0),
    )
    return dataclasses.replace(
        g,
        topology="parallel",
        seconds=N_CYCLES * g.bus.cycle_s,
        bus=dataclasses.replace(g.bus, jitter_s=0.0, compute_s=g.rig.timer.compute_s),
        beam=Beam(stiffness_v_per_count=0.0, damping_v_s_per_count=0.0),
        sync=dataclasses.replace(g.sync, warn_counts=0, trip_counts=0),
        master=master,
        slave=slave,
    )


def _engine_rig(cfg: GantryConfig, sides: tuple) -> Rig:
    """The gantry's two drives as a two-axis rig ticking at the bus cycle.

    ``sides``: the (GantryAxis) master and slave as the case runs them. The timer's clock is
    chosen so the achieved period is exactly the bus cycle (1000 counts of 1 MHz); the counter
    is latched (a drive reads its count whole at the sample instant).
    """
    timer = Timer(period_s=cfg.bus.cycle_s, clock_hz=1e6, compute_s=cfg.bus.compute_s)
    axes = tuple(
        Axis(
            name=name,
            role=name,
            plant=side.plant,
            lock_gain_codes_per_count=0.4,
            following_error_limit_counts=side.following_error_limit_counts,
            counter_init=side.counter_init,
            counter_channel=i,
            dac_channel=i,
        )
        for i, (name, side) in enumerate(zip(("master", "slave"), sides, strict=True))
    )
    rig = dataclasses.replace(
        cfg.rig,
        timer=timer,
        counter=dataclasses.replace(cfg.rig.counter, latched=True),
        axes=axes,
    )
    assert rig.period_s == cfg.bus.cycle_s  # the engine's tick is the bus cycle, exactly
    return rig


def _engine_run(cfg: GantryConfig, case: str):
    """The case as the engine runs it, and the CNC's command.

    ``mismatch``: each side its own drive; ``load``: the slave side a copy of the master's
    drive (its own counter register) and the load step of ``cfg.load`` on its side, from the
    cycle nearest ``time_s`` (the cases of :data:`servotune.arch.gantry.CASES`).
    """
    n = cfg.n_cycles
    dt = cfg.bus.cycle_s
    load = np.zeros((n, 2))
    sides = (cfg.master, cfg.slave)
    if case == "load":
        sides = (cfg.master, dataclasses.replace(cfg.master, counter_init=cfg.slave.counter_init))
        load[round(cfg.load.time_s / dt) :, 0 if cfg.load.axis == "master" else 1] = cfg.load.volts
    rig = _engine_rig(cfg, sides)
    base = Loop.from_rig(rig, [PIGains(kp=s.kp, ki=s.ki) for s in sides])
    loop = Loop(rig=rig, controllers=base.controllers, ref_source=(-1, -1))  # both external
    mv = cfg.move
    cmd = trapezoid_ref(
        n, dt, mv.distance_counts, mv.speed_cps, mv.accel_cps2, start_tick=round(mv.start_s / dt)
    )
    z = np.zeros((n, 2), dtype=np.int64)
    inputs = Inputs(
        ref_counts=np.column_stack([cmd, cmd]),
        mode=z + MODE_TASK,
        reset=z.astype(bool),
        dac_add_codes=z,
        load_v=load,
    )
    return simulate(loop, inputs, seed=SEED), cmd


@pytest.mark.parametrize("case", ["mismatch", "load"])
def test_gantry_parallel_run_is_the_engines_bit_for_bit(expressible, case) -> None:
    cfg = expressible
    assert cfg.n_cycles >= 100_000
    tr = simulate_gantry(cfg, "parallel", case=case, seed=SEED)
    ref, cmd = _engine_run(cfg, case)
    # nothing went through the bus: both drives followed the CNC's command, no compensator
    # call, no monitor level
    assert np.array_equal(tr.command, cmd)
    assert np.array_equal(tr.ref, ref.ref_counts)
    assert not np.any(tr.sync_op) and not np.any(tr.sync_level) and tr.trip_cycle == -1
    # the run did something worth comparing: the move (through the master's counter wrap),
    # noise on the master's reads at rest
    assert np.ptp(tr.y[:, 0]) > 100_000 and np.any(np.diff(tr.y[-1000:, 0]) != 0)
    for name, gantry, engine in (
        ("D/A code", tr.code, ref.code),
        ("flags", tr.flags, ref.flags),
        ("unwrapped position", tr.y, ref.pos_counts),
        ("true position", tr.position, ref.true_pos_counts),  # float equality
    ):
        assert gantry.shape == engine.shape, name
        bad = np.argwhere(gantry != engine)
        assert bad.size == 0, f"{case}: {name} differs first at cycle, axis {bad[0].tolist()}"
