"""python-control on its numpy/scipy paths, whether or not slycot is installed.

python-control switches several computations to the Fortran library SLICOT (the optional
package ``slycot``) when it can import it: the frequency response of a state-space system
(Laub's method, ``tb05ad``), the conversion of a transfer function to state space (``td04ad``)
and back (``tb04ad``), a state-space system's zeros (``ab08nd``). Both paths give the same
numbers up to the last bits, but the last bits differ, and servotune writes them: the margins in
a tuning file, hence its SHA-256, which a verification record and an export bind. Measured
with python-control 0.10.2 and slycot 0.7.1: with slycot installed the example rig's
``make demo`` wrote a ``tuning.json`` whose margins differed in the 14th-16th digit (a phase
margin 45.50000108055275 against 45.500001080552494), so the same input and seed gave other bytes
and the pinned demo digests failed.

:func:`scipy_paths` makes servotune's own calls into python-control take the paths it takes
without slycot (the ones the test suite and CI run), so a tuning, a record and an export are
the same bytes on either machine. While a decorated function runs, ``import slycot`` fails at
once (``sys.modules['slycot'] = None``, the documented way to make an import fail) and
python-control's cached ``slycot_check()`` answers False; both are restored when the outermost
decorated call returns, so a user's own use of slycot outside servotune's calls is untouched
(another thread importing slycot while servotune's call runs would find it missing).
"""

from __future__ import annotations

import functools
import sys
import threading
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["scipy_paths"]

F = TypeVar("F", bound=Callable[..., Any])

_ABSENT = object()
_lock = threading.Lock()
_depth = 0
_saved: tuple[Any, Any] = (_ABSENT, None)


def _enter() -> None:
    global _depth, _saved
    import control.exception as cex

    with _lock:
        if _depth == 0:
            _saved = (sys.modules.get("slycot", _ABSENT), cex.slycot_installed)
            sys.modules["slycot"] = None  # type: ignore[assignment]  # import slycot: ImportError
            cex.slycot_installed = False
        _depth += 1


def _leave() -> None:
    global _depth
    import control.exception as cex

    with _lock:
        _depth -= 1
        if _depth == 0:
            module, flag = _saved
            if module is _ABSENT:
                sys.modules.pop("slycot", None)
            else:
                sys.modules["slycot"] = module
            cex.slycot_installed = flag


def scipy_paths(fn: F) -> F:
    """Run ``fn`` with python-control on its numpy/scipy paths (module docstring).

    Nested and concurrent calls share one guard: it is set by the first call to enter and
    lifted when the last one leaves.

    Examples
    --------
    >>> @scipy_paths
    ... def slycot_importable():
    ...     try:
    ...         import slycot  # noqa: F401
    ...     except ImportError:
    ...         return False
    ...     return True
    >>> slycot_importable()
    False
    """

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        _enter()
        try:
            return fn(*args, **kwargs)
        finally:
            _leave()

    return wrapper  # type: ignore[return-value]
