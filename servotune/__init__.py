"""servotune: control design and tuning workbench for synchronised position servos.

Identify axis models from logs, synthesise PI and fuzzy-PID tables, verify them in a bit-true
4 ms closed loop, and export them to the runtime.
"""

from servotune._numba_cache import keyed_by_sources
from servotune._version import __version__

with keyed_by_sources():  # numba's cache follows every source edit (see _numba_cache)
    from servotune.arch.gantry import GantryConfig, compare_topologies, load_gantry, simulate_gantry
    from servotune.arch.linkage import (
        LinkageCheckError,
        LinkageConfig,
        LinkageResult,
        load_linkage,
        recommended_resync_interval_s,
        run_linkage,
    )
    from servotune.engine import Batch, BatchResult, Loop, Trace, prepare_batch, run_batch, simulate
    from servotune.errors import (
        ConfigError,
        DigestError,
        ExportError,
        IdentificationError,
        LogFormatError,
        RigError,
        ServotuneError,
        SimulationError,
        SpecError,
        TrustError,
        TuningError,
    )
    from servotune.export.json import check_tables, load_tables
    from servotune.fixed import Fixed, quantize
    from servotune.identify import FitResult, PoorFitWarning, fit, fit_arrays
    from servotune.laws import AxisController, PIGains, lock_holding_band
    from servotune.laws.fuzzy_pid import FuzzyPIDGains
    from servotune.logs import Log, read_log, write_log
    from servotune.metrics import StepInfo, TrackingMetrics, step_info, tracking_metrics
    from servotune.plant import Plant, discretize, discretize_lti
    from servotune.rig import Rig, load_rig, write_plant
    from servotune.scenarios import Inputs, build_scenario, sync_move
    from servotune.tune.pi import PITuning, tune_pi, tune_pi_axis
    from servotune.tuning import Tuning, read_tuning, write_tuning


__all__ = [
    "AxisController",
    "Batch",
    "BatchResult",
    "ConfigError",
    "DigestError",
    "ExportError",
    "FitResult",
    "Fixed",
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
