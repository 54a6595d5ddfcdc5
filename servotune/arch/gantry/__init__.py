"""Fieldbus gantry with a listening slave (docs/systems.md#fieldbus-gantry-with-a-listening-slave):
topologies, bus, beam, monitor.

Two drives move the two sides of a gantry beam from one command. Each drive is a servotune
axis (docs/formats.md#axis-model, the runtime's PI law in its integer arithmetic,
docs/runtime.md) that takes a position
command from the fieldbus and closes its own position loop at the **bus cycle**. The beam may
couple the sides (a spring and a damper between them: the sync error loads both motors).

Submodules, each importing only those above it:

- :mod:`~servotune.arch.gantry.config`: the configuration (frozen dataclasses validated on
  construction, :func:`gantry_from_dict`), the topologies and the comparison cases;
- :mod:`~servotune.arch.gantry.design`: the linear sync-loop models
  (:func:`sync_loop_models` → :class:`SyncLoopModels`, :func:`predicted_load_reduction` →
  :class:`LoadPrediction`); the tuning of the drives and of the compensator is in
  :mod:`servotune.arch.gantry.synthesis` (``tune_sync``, ``resolve_gains``);
- :mod:`~servotune.arch.gantry.result`: the result (:class:`GantryTrace` and its
  :class:`GantryMetrics`, :class:`SyncComparison`; its text table is
  :func:`servotune.report.text.format_comparison`);
- :mod:`~servotune.arch.gantry.shaping`: the move's input shaper (``gantry_shaper``);
- :mod:`~servotune.arch.gantry.run`: the CNC's move (:func:`move_profile`, shaped by
  :func:`gantry_command`), the numba kernel
  of one run (:func:`simulate_gantry`) and the comparison (:func:`compare_topologies`);
- :mod:`~servotune.arch.gantry.load`: the config reader (``load_gantry``: it only loads; the
  gains a file leaves out are resolved by the caller, ``resolve_gains(load_gantry(path))``);
- :mod:`~servotune.arch.gantry.synthesis`: the tuners (``tune_sync``, ``resolve_gains``).

This package re-exports the public names of all of them but ``load`` and ``synthesis`` (which
import it).

Topologies (``TOPOLOGIES``):

- ``parallel``: both drives get the CNC's command; nothing corrects the sync error.
- ``following``: the slave is commanded with the master's feedback (as it sees it on the bus).
- ``listening``: the patent's. The slave listens to the bus: it reads the command sent to the
  master and the master's feedback; a SISO **sync compensator** (:mod:`servotune.laws.sync`)
  acts on the sync error and its output is added to the slave's position command.
- ``cross``: cross-coupled: the CNC runs the same compensator and splits its output between
  the two commands (the master's with the opposite sign).

Bus (``GantryBus``): a sync frame every ``cycle_s``; every drive samples its encoder at the
sync interrupt plus a random jitter (uniform within ±``jitter_s``; the sample is moved by
speed × jitter, the write timing is not jittered) and writes its output ``compute_s`` later.
The master's feedback of cycle k reaches the slave (and the CNC) ``latency_cycles`` later,
tagged with its cycle, so the sync error the law sees at cycle k is the measured one of cycle
``k − latency_cycles``: ``y_m(k−L) − y_s(k−L)``.

Monitor: the station that forms the sync error (the listening slave, else the CNC) compares it
with a warning and a trip threshold (:func:`~servotune.laws.sync.sync_monitor`). On a trip the
detecting slave stops at once and every other drive with the next frame: both axes are
latched at 0 V (:data:`~servotune.laws.axis.FLAG_SYNC_TRIP`) at most ``latency_cycles + 1``
cycles after the measured sync error first crossed the trip threshold (``stop_bound_cycles``).

The drives' tick is the shared one of :mod:`servotune.sim.tick` (sample, read, law, D/A, hold,
advance), with the single-rig engine's noise stream: with no jitter, no beam and the parallel
topology, each drive runs exactly as an axis of :func:`servotune.sim.engine.simulate` would
(``tests/arch/gantry/test_cross_kernel.py``). Plant motion: exact per axis over the cycle
(:func:`~servotune.plant.advance_tick`, friction and speed limit included); with a coupled beam
each cycle is split into sub-steps over which the beam force is held (chosen so the beam's
mode is resolved, :func:`~servotune.plant.advance` on each).
"""

from servotune.arch.gantry.config import (
    CASES,
    TOPOLOGIES,
    Beam,
    GantryAxis,
    GantryBus,
    GantryConfig,
    GantryLoad,
    GantryMargins,
    GantryMove,
    SyncSettings,
    gantry_from_dict,
)
from servotune.arch.gantry.design import (
    LoadPrediction,
    SyncLoopModels,
    predicted_load_reduction,
    sync_loop_models,
)
from servotune.arch.gantry.margins import GantryCase, gantry_cases, gantry_margins
from servotune.arch.gantry.result import (
    GantryMetrics,
    GantryMonteCarlo,
    GantryTrace,
    GantryVariant,
    SyncComparison,
)
from servotune.arch.gantry.run import (
    compare_topologies,
    gantry_command,
    gantry_montecarlo,
    move_profile,
    simulate_gantry,
)
from servotune.arch.gantry.shaping import gantry_shaper

__all__ = [
    "CASES",
    "TOPOLOGIES",
    "Beam",
    "GantryAxis",
    "GantryBus",
    "GantryCase",
    "GantryConfig",
    "GantryLoad",
    "GantryMargins",
    "GantryMetrics",
    "GantryMonteCarlo",
    "GantryMove",
    "GantryTrace",
    "GantryVariant",
    "LoadPrediction",
    "SyncComparison",
    "SyncLoopModels",
    "SyncSettings",
    "compare_topologies",
    "gantry_cases",
    "gantry_command",
    "gantry_from_dict",
    "gantry_margins",
    "gantry_montecarlo",
    "gantry_shaper",
    "move_profile",
    "predicted_load_reduction",
    "simulate_gantry",
    "sync_loop_models",
]
