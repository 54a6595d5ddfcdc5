"""The tiny real workloads that compile each kernel group (:data:`servotune.kernels.GROUPS`):
a few ticks of the example rig, a verification with one plant set, a fit of a short log, a gantry
and a linkage run, each through the public entry points, so each compiles exactly the
specialisations the commands use. :func:`servotune.kernels.warm_up` runs them by name."""

from __future__ import annotations

from pathlib import Path

__all__ = [
    "run_batch",
    "run_gantry",
    "run_identification",
    "run_linkage",
    "run_margins",
    "run_simulation",
    "run_verification",
]


def _example(name: str = "pc-dual-servo.toml") -> Path:
    from servotune.rig import EXAMPLE_RIG_PATH

    return EXAMPLE_RIG_PATH.parent / name


def run_simulation() -> None:
    from servotune.rig import describe_rig, load_rig
    from servotune.scenarios import Inputs
    from servotune.sim.engine import Loop, simulate

    rig = load_rig(_example())
    describe_rig(rig)  # the lock's holding band (servotune rig)
    simulate(Loop.from_rig(rig), Inputs.hold(25, len(rig.axes)))


def run_margins() -> None:
    import numpy as np

    from servotune.analysis.margins import controller_basis, grid_margins, unwrapped_phase
    from servotune.modal import discretize
    from servotune.rig import load_rig

    rig = load_rig(_example())
    plant = rig.axes[0].plant
    discretize(plant, rig.period_s, rig.timer.compute_s + plant.delay_s)
    w = np.logspace(-1.0, 2.0, 16)
    g = rig.dac.lsb_v * plant.gain_cps_per_v / (1j * w * (1j * w * plant.tau_s + 1.0))
    grid_margins(
        w,
        np.array([[0.5, 0.01, 0.0]]),
        controller_basis(w, rig.period_s),
        g[None, :],
        unwrapped_phase(g)[None, :],
    )


def run_batch() -> None:
    from dataclasses import replace

    from servotune.laws import PIGains
    from servotune.rig import load_rig
    from servotune.scenarios import build_scenario
    from servotune.sim.engine import Loop, prepare_batch, run_batch

    rig = load_rig(_example())
    axis = replace(rig.axes[0], role="master")
    one = replace(rig, axes=(axis,))
    loop = Loop.from_rig(one, [PIGains(kp=0.2, ki=0.5)])
    inputs = build_scenario(one, "steps", axis=axis.name, seconds=0.2).inputs
    run_batch(prepare_batch(loop, n_candidates=2), inputs, metrics_only=True)


def run_verification() -> None:
    from dataclasses import replace

    from servotune.pipeline import default_pi_gains
    from servotune.rig import load_rig
    from servotune.sim.engine import Loop
    from servotune.tuning import Tuning
    from servotune.verify import load_spec
    from servotune.verify.run import verify

    rig = load_rig(_example())
    spec = load_spec(_example("pc-dual-servo.spec.toml"))
    spec = replace(spec, montecarlo=replace(spec.montecarlo, count=1), margin_samples=0)
    loop = Loop.from_rig(rig, default_pi_gains(rig))
    verify(Tuning.for_rig(rig, loop.controllers, rig_sha256="0" * 64), rig, spec)


def run_identification() -> None:
    import tempfile

    from servotune.identify import fit_log
    from servotune.io.log import write_log
    from servotune.pipeline import log_metadata, run_scenario, trace_log_columns
    from servotune.rig import load_rig
    from servotune.scenarios import build_scenario

    rig = load_rig(_example())
    name = rig.axes[0].name
    scen = build_scenario(rig, "prbs", axis=name, seconds=4.0, closed_loop=True)
    trace = run_scenario(rig, scen)
    with tempfile.TemporaryDirectory(prefix="servotune-warmup-") as tmp:
        path = Path(tmp) / "log.csv"
        write_log(
            path,
            period_s=rig.period_s,
            columns=trace_log_columns(trace, scen.inputs.dac_add_codes),
            metadata=log_metadata(rig, scenario="prbs", axis=name, closed_loop="true", seed=0),
        )
        fit_log(path, axis=name)


def run_gantry() -> None:
    from dataclasses import replace

    from servotune.arch.gantry import simulate_gantry
    from servotune.arch.gantry.load import load_gantry

    cfg = load_gantry(_example("gantry.toml"))
    # gains given rather than designed (a design takes seconds): the kernel is the same
    cfg = replace(
        cfg,
        master=replace(cfg.master, kp=0.5, ki=1.0),
        slave=replace(cfg.slave, kp=0.5, ki=1.0),
        sync=replace(cfg.sync, kp=0.01, ki=0.01),
    )
    simulate_gantry(cfg)


def run_linkage() -> None:
    from servotune.arch.linkage import load_linkage, resolve_gains, run_linkage

    # the example gives every axis's gains: resolving them tunes nothing
    run_linkage(resolve_gains(load_linkage(_example("linkage-6axis.toml"))), seconds=0.05)
