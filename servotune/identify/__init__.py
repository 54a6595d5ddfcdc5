"""Identify the axis model from a logged experiment (``servotune fit``;
docs/formats.md#axis-model).

The package, by concept:

- :mod:`~servotune.identify.model` — the model simulated from a command with the engine's exact
  tick step, its parameters and bounds, parallel sensitivities, the least-squares start and the
  direction check;
- :mod:`~servotune.identify.iv` — ``--method iv``: refined instrumental variables with
  instruments built from the external signals (the excitation the law adds, the reference where
  it moves): consistent in closed loop with a coloured disturbance;
- :mod:`~servotune.identify.oe` — ``--method oe``: output-error least squares, consistent in
  open loop (biased in closed loop when a disturbance the controller reacts to acts);
- :mod:`~servotune.identify.noise` — the residual's ARMA noise model and its whitening filter;
- :mod:`~servotune.identify.quality` — fit %, whiteness and cross-correlation tests, the
  moving-block bootstrap of the intervals;
- :mod:`~servotune.identify.selection` — the structure and friction form chosen by BIC on the
  first samples;
- :mod:`~servotune.identify.fitting` — what ``servotune fit`` runs: method choice, structure and
  friction-form selection, the estimate on the whole log, split-half cross-validation,
  intervals, diagnostics;
- :mod:`~servotune.identify.result` — :class:`FitResult` and the warnings;
- :mod:`~servotune.identify.logfit` — a log file read and one axis fitted (``servotune fit``);
- :mod:`~servotune.identify.emps` — the EMPS benchmark, a real drive's logged experiments: its
  MATLAB files read into a log, its physics in the axis model's terms (not imported here).
"""

from servotune.identify.fitting import (
    MIN_SAMPLES,
    fit,
    fit_arrays,
    simulate_fit,
    validation_split,
)
from servotune.identify.logfit import fit_log
from servotune.identify.model import ASYM_PARAMS, OPTIONAL_PARAMS, PARAMS, UNITS
from servotune.identify.result import (
    ClosedLoopBiasWarning,
    FitResult,
    InadequateModelWarning,
    PoorFitWarning,
)
from servotune.identify.selection import SELECTION_SAMPLES

__all__ = [
    "ASYM_PARAMS",
    "MIN_SAMPLES",
    "OPTIONAL_PARAMS",
    "PARAMS",
    "SELECTION_SAMPLES",
    "UNITS",
    "ClosedLoopBiasWarning",
    "FitResult",
    "InadequateModelWarning",
    "PoorFitWarning",
    "fit",
    "fit_arrays",
    "fit_log",
    "simulate_fit",
    "validation_split",
]
