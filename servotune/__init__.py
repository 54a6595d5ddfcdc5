"""servotune: control design and tuning workbench for synchronised position servos.

Identify axis models from logs, synthesise PI and fuzzy-PID tables, verify them in a bit-true
4 ms closed loop, and export them to the runtime.
"""

from importlib import import_module
from typing import TYPE_CHECKING, Any

from servotune._version import __version__

if TYPE_CHECKING:  # what type checkers and IDEs see; at run time the names load on first use
    from servotune.arch.gantry import GantryConfig, compare_topologies, simulate_gantry
    from servotune.arch.gantry.load import load_gantry
    from servotune.arch.gantry.synthesis import resolve_gains
    from servotune.arch.linkage import (
        LinkageCheckError,
        LinkageConfig,
        LinkageResult,
        load_linkage,
        recommended_resync_interval_s,
        run_linkage,
    )
    from servotune.errors import (
        ConfigError,
        DigestError,
        ExportError,
        IdentificationError,
        LogFormatError,
        RigError,
        SchedulerError,
        ServotuneError,
        SimulationError,
        SpecError,
        TrustError,
        TuningError,
    )
    from servotune.export.json import check_tables, load_tables
    from servotune.fixed import Fixed, quantize
    from servotune.fleet import FleetResult, FleetSpread, fit_fleet, fleet_spread
    from servotune.identify import FitResult, PoorFitWarning, fit, fit_arrays
    from servotune.laws import AxisController, PIGains, lock_holding_band
    from servotune.laws.fuzzy_pid import FuzzyPIDGains
    from servotune.logs import Log, read_log, write_log
    from servotune.metrics import StepInfo, TrackingMetrics, step_info, tracking_metrics
    from servotune.modal import discretize, discretize_lti
    from servotune.plant import Plant
    from servotune.rig import Rig, load_rig, write_plant
    from servotune.scenarios import Inputs, build_scenario, sync_move
    from servotune.sim.engine import (
        Batch,
        BatchResult,
        Loop,
        Trace,
        prepare_batch,
        run_batch,
        simulate,
    )
    from servotune.tune.pi import PITuning, tune_pi, tune_pi_axis
    from servotune.tuning import Tuning, read_tuning, write_tuning

# Each public name -> the module defining it. ``import servotune`` (and so ``servotune --help``)
# imports none of them: a name's module is imported on first access (PEP 562), which keeps
# numba, scipy and matplotlib out of a process that never uses them.
_LAZY: dict[str, str] = {
    "GantryConfig": "servotune.arch.gantry",
    "compare_topologies": "servotune.arch.gantry",
    "load_gantry": "servotune.arch.gantry.load",
    "resolve_gains": "servotune.arch.gantry.synthesis",
    "simulate_gantry": "servotune.arch.gantry",
    "LinkageCheckError": "servotune.arch.linkage",
    "LinkageConfig": "servotune.arch.linkage",
    "LinkageResult": "servotune.arch.linkage",
    "load_linkage": "servotune.arch.linkage",
    "recommended_resync_interval_s": "servotune.arch.linkage",
    "run_linkage": "servotune.arch.linkage",
    "Batch": "servotune.sim.engine",
    "BatchResult": "servotune.sim.engine",
    "Loop": "servotune.sim.engine",
    "Trace": "servotune.sim.engine",
    "prepare_batch": "servotune.sim.engine",
    "run_batch": "servotune.sim.engine",
    "simulate": "servotune.sim.engine",
    "ConfigError": "servotune.errors",
    "DigestError": "servotune.errors",
    "ExportError": "servotune.errors",
    "IdentificationError": "servotune.errors",
    "LogFormatError": "servotune.errors",
    "RigError": "servotune.errors",
    "SchedulerError": "servotune.errors",
    "ServotuneError": "servotune.errors",
    "SimulationError": "servotune.errors",
    "SpecError": "servotune.errors",
    "TrustError": "servotune.errors",
    "TuningError": "servotune.errors",
    "check_tables": "servotune.export.json",
    "load_tables": "servotune.export.json",
    "Fixed": "servotune.fixed",
    "quantize": "servotune.fixed",
    "Frf": "servotune.analysis.frf",
    "frf": "servotune.analysis.frf",
    "FleetResult": "servotune.fleet",
    "FleetSpread": "servotune.fleet",
    "fit_fleet": "servotune.fleet",
    "fleet_spread": "servotune.fleet",
    "FitResult": "servotune.identify",
    "PoorFitWarning": "servotune.identify",
    "fit": "servotune.identify",
    "fit_arrays": "servotune.identify",
    "AxisController": "servotune.laws",
    "PIGains": "servotune.laws",
    "lock_holding_band": "servotune.laws",
    "FuzzyPIDGains": "servotune.laws.fuzzy_pid",
    "Log": "servotune.logs",
    "read_log": "servotune.logs",
    "write_log": "servotune.logs",
    "StepInfo": "servotune.metrics",
    "TrackingMetrics": "servotune.metrics",
    "step_info": "servotune.metrics",
    "tracking_metrics": "servotune.metrics",
    "Plant": "servotune.plant",
    "discretize": "servotune.modal",
    "discretize_lti": "servotune.modal",
    "Rig": "servotune.rig",
    "load_rig": "servotune.rig",
    "write_plant": "servotune.rig",
    "Inputs": "servotune.scenarios",
    "build_scenario": "servotune.scenarios",
    "sync_move": "servotune.scenarios",
    "PITuning": "servotune.tune.pi",
    "tune_pi": "servotune.tune.pi",
    "tune_pi_axis": "servotune.tune.pi",
    "Tuning": "servotune.tuning",
    "read_tuning": "servotune.tuning",
    "write_tuning": "servotune.tuning",
}


def __getattr__(name: str) -> Any:
    """A public name, imported from its module on first access (PEP 562)."""
    try:
        module = _LAZY[name]
    except KeyError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    value = getattr(import_module(module), name)
    globals()[name] = value  # later lookups skip __getattr__
    return value


def __dir__() -> list[str]:
    """The module's attributes and every public name, loaded or not."""
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "AxisController",
    "Batch",
    "BatchResult",
    "ConfigError",
    "DigestError",
    "ExportError",
    "FitResult",
    "Fixed",
    "FleetResult",
    "FleetSpread",
    "Frf",
    "FuzzyPIDGains",
    "GantryConfig",
    "IdentificationError",
    "Inputs",
    "LinkageCheckError",
    "LinkageConfig",
    "LinkageResult",
    "Log",
    "LogFormatError",
    "Loop",
    "PIGains",
    "PITuning",
    "Plant",
    "PoorFitWarning",
    "Rig",
    "RigError",
    "SchedulerError",
    "ServotuneError",
    "SimulationError",
    "SpecError",
    "StepInfo",
    "Trace",
    "TrackingMetrics",
    "TrustError",
    "Tuning",
    "TuningError",
    "__version__",
    "build_scenario",
    "check_tables",
    "compare_topologies",
    "discretize",
    "discretize_lti",
    "fit",
    "fit_arrays",
    "fit_fleet",
    "fleet_spread",
    "frf",
    "load_gantry",
    "load_linkage",
    "load_rig",
    "load_tables",
    "lock_holding_band",
    "prepare_batch",
    "quantize",
    "read_log",
    "read_tuning",
    "recommended_resync_interval_s",
    "resolve_gains",
    "run_batch",
    "run_linkage",
    "simulate",
    "simulate_gantry",
    "step_info",
    "sync_move",
    "tracking_metrics",
    "tune_pi",
    "tune_pi_axis",
    "write_log",
    "write_plant",
    "write_tuning",
]
