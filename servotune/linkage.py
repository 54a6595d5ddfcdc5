"""Deprecated location: the multi-CPU linkage (seed 002) lives in :mod:`servotune.arch.linkage`.

Importing this module warns (``DeprecationWarning``) and gives the same objects; it will be
removed in a later release. The names are also in the top-level ``servotune`` API.
"""

from servotune._deprecate import moved_module
from servotune.arch.linkage import *  # noqa: F403 (the same public names)
from servotune.arch.linkage import __all__  # noqa: F401

moved_module(__name__, "servotune.arch.linkage")
