"""Deprecated location: the fieldbus gantry (seed 003) lives in :mod:`servotune.arch.gantry`.

Importing this module warns (``DeprecationWarning``) and gives the same objects; it will be
removed in a later release. The names are also in the top-level ``servotune`` API.
"""

import warnings

from servotune.arch.gantry import *  # noqa: F403 (the same public names)
from servotune.arch.gantry import __all__ as _GANTRY
from servotune.arch.gantry.load import load_gantry
from servotune.tune.sync import resolve_gains, tune_sync

__all__ = [*_GANTRY, "load_gantry", "resolve_gains", "tune_sync"]

warnings.warn(
    "servotune.sync moved to servotune.arch.gantry; import it from there",
    DeprecationWarning,
    stacklevel=2,
)
