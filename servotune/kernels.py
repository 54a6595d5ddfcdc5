"""The compiled kernels: their groups, whether the cache holds them, compiling them ahead of use,
and saying so while numba compiles.

servotune's loops are numba kernels, compiled at their first call and cached on disk
(:mod:`servotune._numba_cache`: a directory named by a digest of the sources, or
``NUMBA_CACHE_DIR``). A fresh install, or any edit of the sources, compiles them afresh: about
two minutes in all on two cores, the two-axis verification kernel the largest part. This module
makes that a visible step:

- :func:`warm_up` compiles the kernel groups (:data:`GROUPS`) whose kernels are not in the
  cache yet. Each group compiles by running a tiny real workload through the public entry points
  (a few ticks of the example rig, a verification with one plant set, a fit of a short log, a
  gantry and a linkage run), so it compiles exactly the specialisations the commands use, and
  the commands then load them from the cache. Before it starts it reports a line (``compiling
  simulation kernels (first run only, about 25 s)…``), then each group as ``k/n``, and while a
  group compiles a heartbeat every few seconds.
- :func:`cold_groups` tells which groups are not cached, from numba's cache index files alone
  (:func:`servotune._numba_cache.cached_overloads`): nothing is compiled to find out.
- :func:`compile_notices` reports any other compilation while it is active (a specialisation
  no workload covers, a verb that compiles a small kernel): a line when numba starts compiling
  (numba's ``numba:compile`` event: a load from the cache is none), and the heartbeat.

This module imports neither numba nor the kernels' modules until a function needs them, so the
command line can hold :func:`compile_notices` open for every verb; a group's workload
(:mod:`servotune.warmup`, which runs the whole package) is imported by its name when the group
compiles, so the layers below can warm their kernels up (``verify`` does) without importing
what is above them. The library prints nothing: every line goes to the ``progress`` callable
given.
"""

from __future__ import annotations

import threading
import time
import warnings
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from importlib import import_module
from pathlib import Path
from typing import Any

__all__ = ["GROUPS", "KernelGroup", "Warmup", "cold_groups", "compile_notices", "warm_up"]

HEARTBEAT_S = 4.0
"""Seconds between heartbeat lines while numba compiles: the user is never left more than 5 s
without a line (or, on a terminal, a redrawn bar)."""

Progress = Callable[[str], None]


@dataclass(frozen=True, slots=True)
class KernelGroup:
    """Kernels compiled together, by one tiny workload (see the module docstring).

    Parameters
    ----------
    name : str
        What ``servotune warmup NAME`` and the progress lines call it.
    what : str
        Which kernels, for whom (one line, for ``--help``).
    about_s : int
        Its cold compilation on a 2-core machine [s] (measured; the announced estimate).
    kernels : tuple of str
        ``"module:attribute"`` of the compiled functions whose cache entries say the group is
        compiled (``attribute()`` for a function that returns the compiled function); the
        first is the group's main kernel, the one that takes most of ``about_s``.
    modules : tuple of str
        The modules whose compilations :func:`compile_notices` reports as this group's.
    workload : str
        ``"module:function"`` of its tiny workload (:mod:`servotune.warmup`), imported when the
        group compiles: the workloads run the whole package, this module sits below it.
    """

    name: str
    what: str
    about_s: int
    kernels: tuple[str, ...]
    modules: tuple[str, ...]
    workload: str


@dataclass(frozen=True, slots=True)
class Warmup:
    """What :func:`warm_up` did.

    Parameters
    ----------
    compiled : tuple of str
        Groups it compiled (they were not in the cache), in order.
    cached : tuple of str
        Groups asked for that were already in the cache (nothing run).
    seconds : float
        Wall time of the call [s].
    group_seconds : dict of str to float
        Wall time of each compiled group [s].
    still_cold : tuple of str
        Compiled groups the cache still lacks afterwards (the cache is not writable): every
        process compiles them again.
    cache_dir : Path or None
        Where numba caches the kernels (None: not known).
    """

    compiled: tuple[str, ...]
    cached: tuple[str, ...]
    seconds: float
    group_seconds: dict[str, float]
    still_cold: tuple[str, ...]
    cache_dir: Path | None

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (``servotune warmup --json``)."""
        return {
            "cache_dir": None if self.cache_dir is None else str(self.cache_dir),
            "cached": list(self.cached),
            "compiled": list(self.compiled),
            "group_seconds": {k: round(v, 1) for k, v in self.group_seconds.items()},
            "seconds": round(self.seconds, 1),
            "still_cold": list(self.still_cold),
        }


# --- the groups ----------------------------------------------------------------------------

_PLANT = (
    "servotune.plant:fill_plant_rows",
    "servotune.plant:lag_split",
    "servotune.plant:step_coefficients",
    "servotune.plant:tick_coefficients",
)
"""The plant's discretisation, compiled with every simulation (and called by itself)."""

GROUPS: tuple[KernelGroup, ...] = (
    KernelGroup(
        "simulation",
        "the single-rig engine: simulate, tune, compare, demo",
        25,
        ("servotune.sim.kernel:batch_kernel", "servotune.laws.lock:_lock_codes", *_PLANT),
        (
            "servotune.sim.kernel",
            "servotune.sim.tick",
            "servotune.plant",
            "servotune.fixed",
            "servotune.laws",
        ),
        "servotune.warmup:run_simulation",
    ),
    KernelGroup(
        "margins",
        "the loops' margin screen on a frequency grid: tune, margins, verify, sync",
        2,
        (
            "servotune.analysis.margins:_grid_kernel",
            "servotune.plant:lag_split",
            "servotune.plant:tick_coefficients",
        ),
        ("servotune.verify",),
        "servotune.warmup:run_margins",
    ),
    KernelGroup(
        "batch",
        "the lean one-axis batch kernel: run_batch of one-axis candidates, metrics only",
        20,
        ("servotune.sim.lean:kernel_lean", *_PLANT),
        ("servotune.sim.lean",),
        "servotune.warmup:run_batch",
    ),
    KernelGroup(
        "verification",
        "the lean two-axis kernel of the Monte Carlo: verify, compare, demo",
        50,
        ("servotune.sim.lean_sync:_kernel_sync", *_PLANT),
        ("servotune.sim.lean_sync",),
        "servotune.warmup:run_verification",
    ),
    KernelGroup(
        "identification",
        "reading logs and fitting models: fit, demo",
        8,
        (
            "servotune.identify.noise:_short_rows",
            "servotune.identify.noise:_lfilter_rows",
            "servotune.identify.model:_increments",
            "servotune.hw.counter:_unwrap_kernel",
            "servotune.io.log_rows:_plain_kernel()",
            *_PLANT,
        ),
        ("servotune.io", "servotune.hw", "servotune.identify"),
        "servotune.warmup:run_identification",
    ),
    KernelGroup(
        "gantry",
        "the gantry's kernel: sync, tune and verify of a gantry, demo",
        15,
        ("servotune.arch.gantry.run:_gantry_kernel", *_PLANT),
        ("servotune.arch.gantry",),
        "servotune.warmup:run_gantry",
    ),
    KernelGroup(
        "linkage",
        "the multi-CPU linkage's kernels: linkage, verify of a plan, demo",
        25,
        (
            "servotune.arch.linkage.kernel:linkage_kernel",
            "servotune.arch.linkage.path:contour_distances",
            *_PLANT,
        ),
        ("servotune.arch.linkage",),
        "servotune.warmup:run_linkage",
    ),
)
"""Every kernel group, in the order :func:`warm_up` compiles them."""

_BY_NAME = {g.name: g for g in GROUPS}
_MAIN_KERNELS = {g.kernels[0]: g for g in GROUPS}  # "module:name" -> its group


def _names(groups: Iterable[str] | None) -> tuple[str, ...]:
    """The groups asked for (all by default), in :data:`GROUPS` order; ValueError if unknown."""
    if groups is None:
        return tuple(_BY_NAME)
    asked = set(groups)
    unknown = sorted(asked - set(_BY_NAME))
    if unknown:
        raise ValueError(f"unknown kernel group {unknown[0]!r}; the groups: {', '.join(_BY_NAME)}")
    return tuple(n for n in _BY_NAME if n in asked)


def _kernel(ref: str) -> Any:
    """The compiled function ``"module:attribute"`` names (imports its module)."""
    module, _, attr = ref.partition(":")
    if attr.endswith("()"):
        return getattr(import_module(module), attr[:-2])()
    return getattr(import_module(module), attr)


def _is_cold(group: KernelGroup) -> bool:
    from servotune._numba_cache import cached_overloads

    for ref in group.kernels:
        kernel = _kernel(ref)
        if getattr(kernel, "overloads", None):  # compiled or loaded in this process already
            continue
        if cached_overloads(kernel) == 0:  # None: numba's cache cannot be read; not cold
            return True
    return False


def cold_groups(groups: Iterable[str] | None = None) -> tuple[str, ...]:
    """The groups (all by default) whose kernels are not all in numba's on-disk cache.

    Imports the groups' kernel modules and reads their cache index files; compiles nothing.
    A group is cold when one of its kernels has no cached version for these sources, this numba
    and this CPU (and has not been compiled in this process). ``NUMBA_CACHE_DIR``, when set, is
    where numba looks, so it is where this looks.

    Raises
    ------
    ValueError
        If a group is unknown.
    """
    return tuple(n for n in _names(groups) if _is_cold(_BY_NAME[n]))


# --- reporting -----------------------------------------------------------------------------

_SAY = threading.Lock()  # progress lines come from the compiling thread and the heartbeat's


def _say(progress: Progress | None, line: str) -> None:
    if progress is not None:
        with _SAY:
            progress(line)


class _Heartbeat:
    """``line(seconds so far)`` to ``progress`` every ``every_s`` from another thread while
    started (the compiling thread is busy in numba). A sink that raises (the CLI's, once a
    SIGTERM came) ends the heartbeat, not the process; the main thread sees that signal too."""

    def __init__(
        self, progress: Progress | None, line: Callable[[float], str], every_s: float
    ) -> None:
        self.progress, self.line, self.every_s = progress, line, every_s
        self.beats = 0
        self.t0 = time.monotonic()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _beat(self) -> None:
        while not self._stop.wait(self.every_s):
            try:
                _say(self.progress, self.line(time.monotonic() - self.t0))
            except BaseException:  # the sink's own exit: stop beating
                return
            self.beats += 1

    def start(self) -> _Heartbeat:
        if self.progress is not None:
            self._thread = threading.Thread(
                target=self._beat, daemon=True, name="servotune-compile-heartbeat"
            )
            self._thread.start()
        return self

    def stop(self) -> float:
        """Stop; the seconds since :meth:`start`."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        return time.monotonic() - self.t0


def _labels(names: Iterable[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    n = list(names)
    return n[0] if len(n) == 1 else ", ".join(n[:-1]) + " and " + n[-1]


def _cache_dir() -> Path | None:
    from servotune._numba_cache import kernel_cache_dir

    return kernel_cache_dir()


def warm_up(
    groups: Iterable[str] | None = None,
    *,
    progress: Progress | None = None,
    heartbeat_s: float = HEARTBEAT_S,
) -> Warmup:
    """Compile the kernel groups (all by default) that numba's on-disk cache lacks.

    Each cold group (:func:`cold_groups`) runs its tiny workload (module docstring); a group
    already cached costs only the look at its index files. ``progress`` gets, before the first
    compilation, ``compiling simulation and margins kernels (first run only, about 29 s)…``;
    then per group ``compiling simulation kernels: k/n groups done, …`` as it starts and ends
    (``k`` done of ``n``: on a terminal, a bar per group), and every ``heartbeat_s`` while it
    compiles the same with the seconds so far. Nothing at all when every group is cached.

    Parameters
    ----------
    groups : iterable of str, optional
        Names from :data:`GROUPS`.
    progress : callable, optional
        Receives the lines (the CLI prints them on stderr).
    heartbeat_s : float
        Seconds between heartbeat lines.

    Returns
    -------
    Warmup

    Raises
    ------
    ValueError
        If a group is unknown.

    Notes
    -----
    Called within a warm-up's own workload (the verification group's runs
    :func:`servotune.verify.verify`, which warms its kernels up first), it does nothing.
    """
    t0 = time.monotonic()
    names = _names(groups)
    if _MUTE[0]:  # inside a warm-up's workload (one runs verify): that warm-up does the work
        return Warmup(
            compiled=(), cached=(), seconds=0.0, group_seconds={}, still_cold=(), cache_dir=None
        )
    cold = cold_groups(names)
    cached = tuple(n for n in names if n not in cold)
    took: dict[str, float] = {}
    if cold:
        n = len(cold)
        about = sum(_BY_NAME[name].about_s for name in cold)
        which = f"all {n} groups of kernels" if n == len(GROUPS) else f"{_labels(cold)} kernels"
        _say(progress, f"compiling {which} (first run only, about {about} s)…")
        with _muted():
            for k, name in enumerate(cold):
                what = f"compiling {name} kernels: {k}/{n} groups done"
                _say(progress, f"{what}, this one about {_BY_NAME[name].about_s} s")
                beat = _Heartbeat(
                    progress, lambda s, what=what: f"{what}, {s:.0f} s on this one…", heartbeat_s
                ).start()
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")  # a workload's findings are not the user's
                        _kernel(_BY_NAME[name].workload)()
                finally:
                    took[name] = beat.stop()
                _say(
                    progress,
                    f"compiling {name} kernels: {k + 1}/{n} groups done, in {took[name]:.0f} s",
                )
    still = cold_groups(cold) if cold else ()
    return Warmup(
        compiled=cold,
        cached=cached,
        seconds=time.monotonic() - t0,
        group_seconds=took,
        still_cold=still,
        cache_dir=_cache_dir(),
    )


# --- compile notices: numba's compile event, reported -------------------------------------


class _Notices:
    """One :func:`compile_notices` block: announces each group once, beats while compiling."""

    def __init__(self, progress: Progress, heartbeat_s: float) -> None:
        self.progress = progress
        self.heartbeat_s = heartbeat_s
        self.announced: set[str] = set()
        self.label = ""
        self.beating: _Heartbeat | None = None

    def started(self, label: str, about_s: int | None) -> None:
        if label not in self.announced:
            self.announced.add(label)
            about = "" if about_s is None else f", about {about_s} s"
            _say(self.progress, f"compiling {label} kernels (first run only{about})…")
        self.label = label
        self.beating = _Heartbeat(
            self.progress,
            lambda s: f"compiling {label} kernels: 0/1, {s:.0f} s so far…",
            self.heartbeat_s,
        ).start()

    def ended(self) -> None:
        beat, self.beating = self.beating, None
        if beat is not None:
            took = beat.stop()
            if beat.beats:  # it said "0/1": the step ends (on a terminal, its bar closes)
                _say(self.progress, f"compiling {self.label} kernels: 1/1, in {took:.0f} s")


_NOTICES: list[_Notices] = []  # the open compile_notices blocks, innermost last
_MUTE = [0]  # warm_up reports its own compilations
_DEPTH = threading.local()  # per thread: compilations in progress (a kernel compiles its callees)


@contextmanager
def _muted() -> Iterator[None]:
    _MUTE[0] += 1
    try:
        yield
    finally:
        _MUTE[0] -= 1


@contextmanager
def compile_notices(progress: Progress, *, heartbeat_s: float = HEARTBEAT_S) -> Iterator[None]:
    """Within the block, every compilation of a servotune function is reported to ``progress``.

    When numba starts compiling (not loading from the cache) a servotune function, the first
    time for its group in the block: ``compiling simulation kernels (first run only)…`` (with
    the group's estimate, ``…, about 25 s)…``, when it is the group's main kernel); while it
    compiles, a heartbeat line every ``heartbeat_s``. A function that compiles others (its
    callees) is one compilation. Compilations inside :func:`warm_up`, which reports its own, are
    not reported again. Nothing is imported here: numba's event reaches this module from
    :mod:`servotune._numba_cache` once numba is in use.
    """
    notices = _Notices(progress, heartbeat_s)
    _NOTICES.append(notices)
    try:
        yield
    finally:
        notices.ended()
        _NOTICES.remove(notices)


def _group_label(module: str) -> str | None:
    """The group whose modules hold ``module`` (the longest match); ``"servotune"`` for another
    servotune module, None outside servotune."""
    best, label = "", None
    for g in GROUPS:
        for m in g.modules:
            if (module == m or module.startswith(m + ".")) and len(m) > len(best):
                best, label = m, g.name
    if label is None and (module == "servotune" or module.startswith("servotune.")):
        return "servotune"
    return label


def compile_started(dispatcher: Any) -> None:
    """numba starts compiling ``dispatcher`` (called by :mod:`servotune._numba_cache`)."""
    depth = getattr(_DEPTH, "n", 0)
    _DEPTH.n = depth + 1
    if depth or not _NOTICES or _MUTE[0]:
        return
    func = getattr(dispatcher, "py_func", None)
    module = getattr(func, "__module__", None) or ""
    label = _group_label(module)
    if label is not None:
        main = _MAIN_KERNELS.get(f"{module}:{getattr(func, '__qualname__', '')}")
        _NOTICES[-1].started(label, None if main is None else main.about_s)


def compile_ended(dispatcher: Any) -> None:
    """numba has ended compiling ``dispatcher`` (called by :mod:`servotune._numba_cache`)."""
    _DEPTH.n = max(0, getattr(_DEPTH, "n", 1) - 1)
    if _DEPTH.n == 0 and _NOTICES:
        _NOTICES[-1].ended()
