"""Where batches of independent work run: in this process, or on a Dask cluster.

Every batch of independent work (Monte-Carlo chunks of a verification, fits of many logs,
big tuner candidate batches) goes through one small interface, :class:`Executor`: ``map(fn,
items)`` returns ``[fn(item) for item in items]`` in input order, and the caller reduces the
results in that fixed order. Two implementations:

- :class:`InProcessExecutor`: a plain loop in this process (the default for small work; the
  engine's own numba threads still use every core);
- :class:`DaskExecutor`: the tasks of a `Dask distributed <https://distributed.dask.org>`_
  ``Client``: an embedded ``LocalCluster`` on this machine's cores (worker processes, one
  thread each), or an existing cluster reached by its scheduler's address
  (``tcp://HOST:8786``; deployment: ``docs/scale.md``). Dask schedules, moves the data and
  re-runs the tasks of a worker that dies; servotune has no pool or scheduler of its own.

:func:`open_executor` chooses one. Results do not depend on the choice: a task's randomness is
keyed by the work's seed and each item's index (docs/decisions.md#11-random-numbers; e.g. a chunk of
plants ``[start, stop)`` of a Monte-Carlo run draws its plants as
:func:`servotune.verify.variants.chunk_generator` jumps into the seed's stream), never by the
worker, the chunk or the order in which tasks finish; so a run gives the same bytes on one
process, two workers or a hundred. (A seed per chunk, ``SeedSequence`` of the seed and the
chunk's index, would tie the draws to the chunk size: the same seed would give other plants in
chunks of 1,000 than in chunks of 4,096.)

Dask is imported only here, and only when a cluster is used (``servotune --help`` does not
load it).
"""

from __future__ import annotations

import logging
import math
import os
import signal
import threading
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import CancelledError
from contextlib import contextmanager, suppress
from typing import Any, TypeVar

from servotune.budget import check_memory, format_bytes, memory_budget
from servotune.errors import SchedulerError

__all__ = [
    "EMBEDDED_CLUSTER_CONFIG",
    "LOCAL_CLUSTER_MIN_ITEMS",
    "SCHEDULER_ENV",
    "WORKER_BYTES",
    "DaskExecutor",
    "Executor",
    "InProcessExecutor",
    "check_workers",
    "chunk_bounds",
    "guided_chunk_bounds",
    "local_cluster",
    "local_workers",
    "open_executor",
]

T = TypeVar("T")
R = TypeVar("R")

SCHEDULER_ENV = "SERVOTUNE_SCHEDULER"
"""Environment variable naming a Dask scheduler (``tcp://HOST:8786``) when none is given."""

LOCAL_CLUSTER_MIN_ITEMS = 100_000
"""Work items (e.g. plant sets) from which :func:`open_executor` starts an embedded
``LocalCluster`` rather than running in-process. Below it, the cluster's start (about 2 s:
worker processes, imports, the compiled kernels' cache) costs more than it gains: the engine
already runs its candidates on every core's thread in-process, and only the Python around the
kernel (plant draws, discretisation, evaluation of the traces) runs on one core."""


Done = Callable[[int], None] | None
"""The progress callback of :meth:`Executor.map` (None: no progress)."""


class Executor(ABC):
    """Runs ``fn`` over independent items; the results come back in input order.

    An implementation subclasses it and writes ``_map`` (the items as a list, the other
    arguments positional); :meth:`map` is the one public entry.

    Attributes
    ----------
    name : str
        For progress lines (``"in-process"``, ``"dask LocalCluster (2 workers)"``,
        ``"dask tcp://host:8786 (16 workers)"``).
    workers : int
        Workers that run tasks at once [1].
    threads_per_task : int or None
        Threads a task may use for compiled kernels (numba): None (every core) in-process, 1
        on a cluster (Dask runs one task per worker thread).
    """

    name: str
    workers: int
    threads_per_task: int | None

    def map(
        self,
        fn: Callable[..., R],
        items: Sequence[Any],
        *,
        shared: Any = None,
        done: Callable[[int], None] | None = None,
    ) -> list[R]:
        """``[fn(item, shared=shared) for item in items]`` (``fn(item)`` if ``shared`` is
        None), in input order: ``fn``'s second parameter must be named ``shared`` (a cluster
        passes it by keyword).

        Parameters
        ----------
        fn : callable
            A module-level function (a cluster pickles it by reference).
        items : sequence
            Independent work items (picklable).
        shared : object, optional
            Data every call needs (sent to each worker once).
        done : callable, optional
            Called in the calling thread with the number of finished items after each one
            finishes (for progress).
        """
        return self._map(fn, list(items), shared, done)

    @abstractmethod
    def _map(self, fn: Callable[..., R], items: list[Any], shared: Any, done: Done) -> list[R]:
        """:meth:`map` of this implementation."""


class InProcessExecutor(Executor):
    """:class:`Executor` running every item in this process, one after the other."""

    name = "in-process"
    workers = 1
    threads_per_task: int | None = None

    def _map(self, fn: Callable[..., R], items: list[Any], shared: Any, done: Done) -> list[R]:
        out = []
        for i, item in enumerate(items):
            out.append(fn(item) if shared is None else fn(item, shared=shared))
            if done is not None:
                done(i + 1)
        return out


class DaskExecutor(Executor):
    """:class:`Executor` on a ``dask.distributed.Client`` (one task per item; ``shared`` is
    scattered to every worker once).

    Parameters
    ----------
    client : dask.distributed.Client
        A connected client; the caller owns it (closes it).
    name : str, optional
        For progress lines (default: the scheduler's address).
    retries : int
        Times a task that *raised* is re-run (a task whose worker died is re-run by the
        scheduler anyway, up to ``distributed.scheduler.allowed-failures`` times).
    """

    threads_per_task: int | None = 1

    def __init__(
        self, client: Any, *, name: str | None = None, retries: int = 0, embedded: bool = False
    ) -> None:
        self.client = client
        self.retries = int(retries)
        self.name = name or f"dask {client.scheduler.address}"
        self.embedded = embedded  # a cluster of this run's own (:func:`local_cluster`)
        self.quieted = False  # :meth:`quiet` has run

    def quiet(self) -> None:
        """Silence Dask's loggers in this process (an embedded cluster's scheduler and nannies
        run here) and in the cluster's worker processes, once, before a run stopped by a signal
        closes the cluster: tasks cancelled mid-run, connections closed under a task,
        coroutines never awaited are what a shutdown is, not news (dozens of lines of them
        otherwise, ahead of the run's one line). :func:`local_cluster` turns this process's
        logging back on once the cluster is closed; the worker processes end with it."""
        if self.quieted:
            return
        self.quieted = True
        logging.disable(logging.CRITICAL)
        with suppress(Exception):
            self.client.run(logging.disable, logging.CRITICAL, on_error="ignore")

    @property
    def workers(self) -> int:
        """Worker threads the scheduler knows now [1] (at least 1)."""
        info = self.client.scheduler_info()
        return max(1, sum(int(w.get("nthreads", 1)) for w in info.get("workers", {}).values()))

    def _map(self, fn: Callable[..., R], items: list[Any], shared: Any, done: Done) -> list[R]:
        from dask.distributed import as_completed

        if not items:
            return []
        kwargs: dict[str, Any] = {}
        if shared is not None:
            # broadcast: every worker holds a copy, so a dead worker loses none of it
            (kwargs["shared"],) = self.client.scatter([shared], broadcast=True, hash=False)
        futures = self.client.map(fn, items, pure=False, retries=self.retries, **kwargs)
        index = {f.key: i for i, f in enumerate(futures)}
        results: list[Any] = [None] * len(futures)
        lost = [0] * len(futures)
        try:
            # each result fetched as its task ends, while the others run (gathered at the end,
            # a million plant sets' 88 MB of results came over after the workers had finished)
            done_tasks = as_completed(futures, with_results=True)
            n = 0
            for future, result in done_tasks:
                i = index.pop(future.key)
                if isinstance(result, CancelledError):
                    # a result lost with a worker that died before it was fetched comes back
                    # cancelled: the item runs again (a task's own error raises instead)
                    lost[i] += 1
                    if lost[i] > self.retries + 1:
                        raise result
                    again = self.client.submit(
                        fn, items[i], pure=False, retries=self.retries, **kwargs
                    )
                    index[again.key] = i
                    futures.append(again)
                    done_tasks.add(again)
                    continue
                results[i] = result
                n += 1
                if done is not None:
                    done(n)
            return results
        except BaseException as exc:
            if self.embedded and not isinstance(exc, Exception):  # Ctrl-C, SIGTERM, an exit
                self.quiet()  # before the cancel below makes the workers talk
            raise
        finally:
            self.client.cancel(futures)


def local_workers() -> int:
    """Worker processes of an embedded cluster: this process's usable cores [1]."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


def check_workers(workers: int | None, scheduler: str | None = None) -> None:
    """Refuse a number of worker processes no run should start, before anything starts.

    ``workers`` counts the processes of a cluster started on this machine (one thread each),
    so it is at least 1 and at most :func:`local_workers`, this process's usable cores (more
    would only share the same cores, each process holding its own copy of the compiled
    kernels and of the work's shared data; ``--workers 10000`` would start processes until
    the machine runs out of memory). A cluster reached by its scheduler's address
    (``scheduler``, or the ``SERVOTUNE_SCHEDULER`` environment variable) has the workers it
    was deployed with: ``workers`` is refused with it.

    Parameters
    ----------
    workers : int, optional
        Worker processes asked for (``None``: not given, always accepted).
    scheduler : str, optional
        Address of a Dask scheduler.

    Raises
    ------
    SchedulerError
        ``workers`` is below 1, above :func:`local_workers`, or given with a scheduler.
    BudgetError
        ``workers`` worker processes (:data:`WORKER_BYTES` each) exceed the memory budget.
    """
    if workers is None:
        return
    if workers < 1:
        raise SchedulerError(f"workers must be >= 1, got {workers}")
    address = scheduler or os.environ.get(SCHEDULER_ENV) or None
    if address is not None:
        raise SchedulerError(
            f"give either a scheduler ({address}) or a number of local workers, not both"
        )
    cap = local_workers()
    if workers > cap:
        raise SchedulerError(
            f"workers must be at most {cap} (the usable cores of this machine: one worker "
            f"process per core), got {workers}"
        )
    if workers > 1:
        check_memory(
            workers * WORKER_BYTES,
            f"an embedded Dask cluster of {workers} workers",
            f"{workers} × {format_bytes(WORKER_BYTES)} a worker process",
        )


WORKER_BYTES = 256 * 1024**2
"""Memory a worker process of an embedded cluster is counted at against the memory budget
(:mod:`servotune.budget`): the interpreter, numpy and scipy, the compiled kernels and a task's
arrays (about 235 MB resident each, measured on a Monte-Carlo verification of the example
rig). ``--workers N`` beyond the budget is refused; without ``--workers``, the cluster gets
as many workers as the budget holds (at most the usable cores)."""


@contextmanager
def open_executor(
    n_items: int,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    min_items: int = LOCAL_CLUSTER_MIN_ITEMS,
) -> Iterator[Executor]:
    """The executor for ``n_items`` items of work, closed (cluster and client) on exit.

    The choice, in order:

    1. ``scheduler`` (or the ``SERVOTUNE_SCHEDULER`` environment variable): a client of that
       Dask scheduler (``tcp://HOST:8786``), which must answer within Dask's connect timeout
       (``distributed.comm.timeouts.connect``, 30 s unless configured, e.g.
       ``DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT=5s``);
    2. ``workers`` > 1, or ``n_items >= min_items`` with ``workers`` unset and more than one
       core: an embedded ``LocalCluster`` of ``workers`` (default: the usable cores) worker
       processes with one thread each (:func:`local_cluster`);
    3. else in-process.

    Parameters
    ----------
    n_items : int
        Items of work to come (e.g. plant sets) [1].
    scheduler : str, optional
        Address of a running Dask scheduler.
    workers : int, optional
        Worker processes of an embedded cluster; 1 forces in-process; at most the usable
        cores (:func:`check_workers`). Not with ``scheduler``.
    min_items : int
        From how many items an embedded cluster is started (:data:`LOCAL_CLUSTER_MIN_ITEMS`).

    Yields
    ------
    Executor

    Raises
    ------
    SchedulerError
        The scheduler does not answer (refused, unreachable, timed out), or ``workers`` is
        given with a scheduler, is below 1 or is above the usable cores.

    Examples
    --------
    >>> with open_executor(10) as ex:
    ...     ex.name, ex.map(abs, [-2, 3])
    ('in-process', [2, 3])
    """
    check_workers(workers, scheduler)  # before anything starts
    address = scheduler or os.environ.get(SCHEDULER_ENV) or None
    if address is not None:
        client = _connect(address)
        try:
            yield DaskExecutor(client, name=f"dask {address}")
        finally:
            client.close()
        return
    n_local = workers if workers is not None else min(local_workers(), _workers_in_budget())
    large = workers is not None or n_items >= min_items
    if n_local <= 1 or not large:
        yield InProcessExecutor()
        return
    with local_cluster(n_local) as ex:
        yield ex


def _workers_in_budget() -> int:
    """Worker processes the memory budget holds (:data:`WORKER_BYTES` each), at least 1."""
    return max(1, memory_budget() // WORKER_BYTES)


EMBEDDED_CLUSTER_CONFIG = {
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.profile.enabled": False,
}
"""Dask settings of an embedded ``LocalCluster`` (:func:`local_cluster`), over Dask's defaults:
the event loops' health check every second instead of every 20 ms, the resource monitor every
5 s instead of every 0.5 s, no statistical profiler in the workers (it samples their stacks
every 10 ms for a dashboard nobody opens here). Idle, Dask's defaults cost a 2-worker cluster
on a 2-core machine about 2.2 s of CPU per 20 s (the client's process 0.8 s, the workers 1.4 s);
these, 0.7 s: on a 25 s Monte-Carlo run, about a second of CPU the workers get back (measured:
``docs/scale.md``). A cluster reached by its address keeps its own settings."""


@contextmanager
def local_cluster(workers: int) -> Iterator[DaskExecutor]:
    """A :class:`DaskExecutor` on a ``LocalCluster`` started on this machine, closed on exit.

    ``workers`` worker processes with one thread each (the compiled kernels run one thread per
    task), its HTTP server (dashboard, where bokeh is installed) on a free port, Dask's settings
    :data:`EMBEDDED_CLUSTER_CONFIG` (set while the cluster starts: its processes keep them, the
    caller's configuration is left as it was).

    Parameters
    ----------
    workers : int
        Worker processes [1], >= 1.
    """
    import dask
    from dask.distributed import Client, LocalCluster

    if workers < 1:
        raise SchedulerError(f"workers must be >= 1, got {workers}")
    with dask.config.set(EMBEDDED_CLUSTER_CONFIG), _without_ctrl_c():
        cluster = LocalCluster(
            n_workers=workers, processes=True, threads_per_worker=1, dashboard_address=":0"
        )
    ex: DaskExecutor | None = None
    try:
        with cluster, Client(cluster) as client:
            ex = DaskExecutor(client, name=f"dask LocalCluster ({workers} workers)", embedded=True)
            try:
                yield ex
            except BaseException as exc:
                if not isinstance(exc, Exception):  # a signal or an exit ends the run
                    ex.quiet()
                raise
    finally:
        if ex is not None and ex.quieted:
            logging.disable(logging.NOTSET)  # the cluster is closed: this process logs again


@contextmanager
def _without_ctrl_c() -> Iterator[None]:
    """SIGINT ignored in this process while the block starts the cluster's worker processes:
    a process started with a signal ignored keeps it ignored, so a Ctrl-C at the terminal,
    which reaches every process of the group, ends the run through this process alone (its
    workers are closed with it), not also as a traceback from each worker. A Ctrl-C during
    the start itself (about 2 s) is lost; the next one ends the run. (Blocking SIGINT here
    instead would not reach the workers: Dask's event-loop thread, which starts them, runs
    with an empty signal mask.)"""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before)


def _connect(address: str) -> Any:
    """A client of the scheduler at ``address``; :class:`SchedulerError` if it does not
    answer."""
    from dask.distributed import Client

    try:
        return Client(address)
    except (OSError, TimeoutError, ValueError) as exc:
        why = " ".join(str(exc).split()) or type(exc).__name__
        raise SchedulerError(
            f"no Dask scheduler answers at {address} ({why}); start one (dask scheduler) or "
            f"fix --scheduler / {SCHEDULER_ENV}"
        ) from None


def chunk_bounds(n_items: int, chunk_size: int) -> list[tuple[int, int]]:
    """``[start, stop)`` of consecutive chunks of at most ``chunk_size`` items covering
    ``range(n_items)``.

    >>> chunk_bounds(5, 2)
    [(0, 2), (2, 4), (4, 5)]
    """
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be >= 1, got {chunk_size}")
    n_chunks = math.ceil(n_items / chunk_size)
    return [(i * chunk_size, min(n_items, (i + 1) * chunk_size)) for i in range(n_chunks)]


def guided_chunk_bounds(
    n_items: int, workers: int, *, smallest: int, largest: int
) -> list[tuple[int, int]]:
    """``[start, stop)`` of consecutive chunks covering ``range(n_items)``, large first and
    shrinking towards the end (guided self-scheduling).

    Each chunk takes a quarter of an even share of what is left, ``ceil(left / (4 ·
    workers))`` items, within ``smallest … largest`` (the last may be smaller). Few large
    tasks cost the caller little per item (on a cluster, every task's result passes through
    the client), and the small ones at the end keep every worker busy until the last: a run
    ends at most one small chunk after the first worker falls idle, not one large one.

    >>> guided_chunk_bounds(100, 2, smallest=4, largest=10)[:4]
    [(0, 10), (10, 20), (20, 30), (30, 39)]
    >>> guided_chunk_bounds(100, 2, smallest=4, largest=10)[-3:]
    [(88, 92), (92, 96), (96, 100)]
    """
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if not 1 <= smallest <= largest:
        raise ValueError(f"need 1 <= smallest <= largest, got {smallest}, {largest}")
    out = []
    start = 0
    while start < n_items:
        size = min(largest, max(smallest, math.ceil((n_items - start) / (4 * workers))))
        out.append((start, min(n_items, start + size)))
        start += size
    return out
