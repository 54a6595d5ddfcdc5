"""Deprecated location: the multi-CPU linkage (seed 002) lives in :mod:`servotune.arch.linkage`.

Importing this module warns (``DeprecationWarning``) and gives the same objects; it will be
removed in a later release. The names are also in the top-level ``servotune`` API.
"""

import warnings

from servotune.arch.linkage import *  # noqa: F403 (the same public names)
from servotune.arch.linkage import __all__  # noqa: F401

warnings.warn(
    "servotune.linkage moved to servotune.arch.linkage; import it from there",
    DeprecationWarning,
    stacklevel=2,
)
