"""Deprecated location: the single-rig engine lives in :mod:`servotune.sim.engine`.

Importing this module warns (``DeprecationWarning``) and gives the same objects; it will be
removed in a later release. The names are also in the top-level ``servotune`` API.
"""

from servotune._deprecate import moved_module
from servotune.sim.engine import *  # noqa: F403 (the same public names)
from servotune.sim.engine import __all__  # noqa: F401

moved_module(__name__, "servotune.sim.engine")
