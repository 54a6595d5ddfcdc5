"""Deprecated location: the fieldbus gantry (seed 003) lives in :mod:`servotune.arch.gantry`.

Importing this module warns (``DeprecationWarning``) and gives the same objects; it will be
removed in a later release. The names are also in the top-level ``servotune`` API.
"""

from servotune._deprecate import moved_module
from servotune.arch.gantry import *  # noqa: F403 (the same public names)
from servotune.arch.gantry import __all__ as _GANTRY
from servotune.arch.gantry.load import load_gantry
from servotune.tune.sync import resolve_gains, tune_sync

__all__ = [*_GANTRY, "load_gantry", "resolve_gains", "tune_sync"]

moved_module(__name__, "servotune.arch.gantry")
