"""Deprecated location: the single-rig engine lives in :mod:`servotune.sim.engine`.

Importing this module warns (``DeprecationWarning``) and gives the same objects; it will be
removed in a later release. The names are also in the top-level ``servotune`` API.
"""

import warnings

from servotune.sim.engine import *  # noqa: F403 (the same public names)
from servotune.sim.engine import __all__  # noqa: F401

warnings.warn(
    "servotune.engine moved to servotune.sim.engine; import it from there",
    DeprecationWarning,
    stacklevel=2,
)
