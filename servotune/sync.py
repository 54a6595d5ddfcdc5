"""Deprecated location: the fieldbus gantry (seed 003) lives in :mod:`servotune.arch.gantry`.

Importing this module warns (``DeprecationWarning``) and gives the same objects; it will be
removed in a later release. The names are also in the top-level ``servotune`` API.
"""

import warnings

from servotune.arch.gantry import *  # noqa: F403 (the same public names)
from servotune.arch.gantry import __all__  # noqa: F401

warnings.warn(
    "servotune.sync moved to servotune.arch.gantry; import it from there",
    DeprecationWarning,
    stacklevel=2,
)
