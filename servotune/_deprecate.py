"""Deprecated names kept where users found them: each warns once used, then gives the object
from its new home (PEP 562 module ``__getattr__``).

The new home may be a higher layer (text formatting moved up to :mod:`servotune.report`), so it
is imported when the old name is used, not when the old package is: the alias never makes a
lower layer import a higher one.
"""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["moved_module", "moved_names"]


def moved_names(package: str, moved: Mapping[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for names of ``package`` that moved to other modules.

    Parameters
    ----------
    package : str
        The old home (``__name__`` of the module that keeps the aliases).
    moved : mapping of str to str
        Name → the module it now lives in.

    Returns
    -------
    callable
        ``__getattr__(name)``: warns (``DeprecationWarning``) and returns the object for a moved
        name, else raises ``AttributeError`` as Python does.
    """

    def __getattr__(name: str) -> Any:
        if name not in moved:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        warnings.warn(
            f"{package}.{name} moved to {moved[name]}; import it from there",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(importlib.import_module(moved[name]), name)

    return __getattr__


def moved_module(old: str, new: str) -> None:
    """Warn (``DeprecationWarning``, at the importer's line) that module ``old`` moved to ``new``.

    Called once at the top level of an old module that re-exports the new one's names.
    """
    warnings.warn(f"{old} moved to {new}; import it from there", DeprecationWarning, stacklevel=3)
