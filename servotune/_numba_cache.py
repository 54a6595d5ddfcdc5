"""numba's on-disk cache for servotune, keyed by the package's sources.

numba checks a cached function against its own source file only: a kernel in ``engine.py`` that
inlines a law from ``laws/pi.py`` keeps running the old law after ``laws/pi.py`` is edited,
until ``engine.py`` changes too. Bit-true results cannot rest on that, so while servotune's
modules are imported (and their functions decorated), numba's cache directory is one named by
a digest of every servotune source file: any edit compiles afresh, and an unchanged tree reuses
its cache. ``NUMBA_CACHE_DIR``, when set, is left to rule.

numba has no public per-function cache location: it reads ``numba.config.CACHE_DIR`` when a
function is decorated with ``cache=True``. :func:`jit` therefore sets it for the length of its
own decoration call and restores it (the environment is never touched): other packages'
functions, decorated before or after, keep numba's defaults. The one exception the public API
leaves open is a function decorated by another thread during those microseconds.

Two more services for a visible first run (:mod:`servotune.kernels`): :func:`cached_overloads`
reads a function's cache index without compiling anything, and numba's ``numba:compile`` event
(sent when numba really compiles, not when it loads from the cache) is passed on to
:func:`servotune.kernels.compile_started` and :func:`~servotune.kernels.compile_ended`.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import cache
from pathlib import Path
from typing import Any

import numba
import numba.core.errors
import numba.core.event

from servotune.errors import CompileError

__all__ = [
    "cache_dir",
    "cached_overloads",
    "call_compiled",
    "jit",
    "kernel_cache_dir",
    "keyed_by_sources",
    "source_digest",
]

_PACKAGE = Path(__file__).resolve().parent
_PREFIX = "numba-"
_STALE_S = 3600.0
"""An older cache directory is removed once nothing has been written into it for this long [s]."""


def source_digest(root: Path = _PACKAGE) -> str:
    """SHA-1 (16 hex digits) of the ``*.py`` files under ``root``: their paths and bytes."""
    h = hashlib.sha1()
    for path in sorted(root.rglob("*.py")):
        h.update(path.relative_to(root).as_posix().encode())
        h.update(b"\0")
        h.update(path.read_bytes())
        h.update(b"\0")
    return h.hexdigest()[:16]


def _usable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    return os.access(path, os.W_OK | os.X_OK)


def cache_dir(root: Path = _PACKAGE) -> Path | None:
    """The cache directory for the sources under ``root``; None if none is writable.

    ``root/__pycache__/numba-<digest>`` (older ``numba-*`` siblings there are removed when it
    is created, once idle for an hour), else ``$XDG_CACHE_HOME/servotune/numba-<digest>``
    (default ``~/.cache``).
    """
    name = _PREFIX + source_digest(root)
    in_tree = root / "__pycache__" / name
    if in_tree.is_dir() and os.access(in_tree, os.W_OK | os.X_OK):
        return in_tree
    if _usable(in_tree):
        now = time.time()
        for old in in_tree.parent.glob(_PREFIX + "*"):
            # another process may still be writing into a sibling of a moment ago (the sources
            # changed under a running suite): only siblings left alone for a while go
            try:
                idle = now - old.stat().st_mtime
            except OSError:
                continue
            if old != in_tree and idle > _STALE_S:
                shutil.rmtree(old, ignore_errors=True)
        return in_tree
    user = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "servotune" / name
    return user if _usable(user) else None


@cache
def _package_cache_dir() -> Path | None:
    """:func:`cache_dir` of the installed package, computed once per process."""
    return cache_dir()


def kernel_cache_dir() -> Path | None:
    """Where numba caches servotune's functions: ``NUMBA_CACHE_DIR`` if set, else
    :func:`cache_dir` of the installed package (None: no writable directory)."""
    user = os.environ.get("NUMBA_CACHE_DIR")
    return Path(user) if user else _package_cache_dir()


@contextmanager
def keyed_by_sources() -> Iterator[None]:
    """Within the block, numba caches functions decorated there in :func:`cache_dir`.

    numba picks a function's cache location when it is decorated, so wrapping the imports of
    servotune's modules is enough; other packages' functions are left to numba's defaults.
    """
    if os.environ.get("NUMBA_CACHE_DIR"):
        yield
        return
    path = _package_cache_dir()
    previous = numba.config.CACHE_DIR
    if path is not None:
        numba.config.CACHE_DIR = str(path)
    try:
        yield
    finally:
        numba.config.CACHE_DIR = previous


def jit(fn: Callable[..., Any] | None = None, /, **options: Any) -> Any:
    """``numba.njit(cache=True, **options)``, cached in :func:`cache_dir`: servotune's one jit.

    Every compiled function of servotune is decorated with this, so each one caches under the
    digest of the sources wherever it is imported from (a lazily imported module included), and
    numba's cache setting is touched only while the function is decorated, then restored.

    Examples
    --------
    >>> @jit(inline="always")
    ... def twice(x):
    ...     return 2 * x
    >>> twice(21)
    42
    """

    def decorate(f: Callable[..., Any]) -> Any:
        with keyed_by_sources():
            return numba.njit(cache=True, **options)(f)

    return decorate if fn is None else decorate(fn)


def call_compiled(kernel: Any, *args: Any) -> Any:
    """``kernel(*args)``; a failure to compile becomes a :class:`CompileError` with its cause.

    A kernel compiles at its first call with new argument types (or loads from the cache); a
    numba outside the tested range may refuse it. That is an error to see, with numba's own
    first line, not something to work around silently.

    Raises
    ------
    CompileError
        If numba cannot compile ``kernel`` for these arguments.
    """
    try:
        return kernel(*args)
    except numba.core.errors.NumbaError as exc:
        cause = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        name = getattr(kernel, "__name__", repr(kernel))
        raise CompileError(
            f"the compiled kernel {name} does not compile with numba {numba.__version__} "
            f"({type(exc).__name__}: {cause}); servotune is tested with the numba range in "
            "its pyproject.toml"
        ) from exc


def cached_overloads(kernel: Any) -> int | None:
    """How many compiled versions of ``kernel`` numba's on-disk cache holds that this process
    can load: the index file of the function in its cache directory (wherever numba looks:
    ``NUMBA_CACHE_DIR`` or :func:`cache_dir`), the entries written by this numba for this
    function's source file as it is now (numba's stamp: its time and size), this CPU and this
    bytecode. Nothing is compiled or loaded.

    numba has no public API for this: it is read through the dispatcher's cache object (its
    index and its key, numba 0.6x), and anything unexpected there gives None (not known).
    """
    try:
        cache = kernel._cache
        index = cache._cache_file._load_index()
        _, machine, code = cache._index_key((), kernel.targetctx.codegen())
        return sum(1 for key in index if tuple(key[1:]) == (machine, code))
    except Exception:  # numba internals moved (or caching is off): not known
        return None


class _CompileEvents(numba.core.event.Listener):
    """numba's ``numba:compile`` event, passed on to :mod:`servotune.kernels` (which reports
    it only where the caller asked, :func:`servotune.kernels.compile_notices`) when that
    module is loaded: not imported from here (it sits beside this one and reads this one's
    cache), and where it is not loaded no notices block can be open."""

    def on_start(self, event: numba.core.event.Event) -> None:
        kernels = sys.modules.get("servotune.kernels")
        if kernels is not None:
            kernels.compile_started(event.data["dispatcher"])

    def on_end(self, event: numba.core.event.Event) -> None:
        kernels = sys.modules.get("servotune.kernels")
        if kernels is not None:
            kernels.compile_ended(event.data["dispatcher"])


numba.core.event.register("numba:compile", _CompileEvents())
