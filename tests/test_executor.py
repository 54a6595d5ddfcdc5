"""The executor seam (servotune.executor) on a real Dask cluster: a ``LocalCluster`` of 2 worker
processes (one thread each) started here, as `servotune verify --workers 2` starts one.

What must hold (docs/decisions.md#11-random-numbers): a Monte-Carlo verification (the single rig's,
and the gantry's plant pairs) gives the same result, to the byte of its record, in-process and on
the cluster, for any chunk size; a worker killed while its
task runs changes nothing (Dask re-runs the task elsewhere); a scheduler that refuses gives one
line and exit 3. Sizes are small (40 plant sets, the sync scenario only): the file runs in
about half a minute, most of it the cluster's start and the workers' first imports.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import threading
import time
from pathlib import Path

import pytest

import servotune as st
from servotune import cli
from servotune.errors import SchedulerError
from servotune.executor import (
    EMBEDDED_CLUSTER_CONFIG,
    SCHEDULER_ENV,
    DaskExecutor,
    InProcessExecutor,
    chunk_bounds,
    guided_chunk_bounds,
    local_cluster,
    open_executor,
)
from servotune.tuning import read_tuning
from servotune.verify import load_spec, verify

distributed = pytest.importorskip("dask.distributed")

ROOT = Path(__file__).resolve().parents[1]
RIG = ROOT / "plants" / "pc-dual-servo.toml"
SPEC = ROOT / "plants" / "pc-dual-servo.spec.toml"
TUNING = ROOT / "tests" / "corpus" / "base" / "tuning.json"  # a tuning of the example rig
COUNT = 40


@pytest.fixture(scope="module")
def client():
    """The embedded LocalCluster of 2 worker processes, one thread each (the one
    ``open_executor`` starts), and its client."""
    with local_cluster(2) as ex:
        ex.client.wait_for_workers(2)
        yield ex.client


@pytest.fixture(scope="module")
def setup():
    """The example rig, a tuning of it and its spec reduced to the sync scenario (the one the
    bench scales) with COUNT Monte-Carlo plant sets."""
    rig = st.load_rig(RIG)
    spec = load_spec(SPEC)
    sync = next(sc for sc in spec.scenarios if sc.name == "sync")
    mc = dataclasses.replace(spec.montecarlo, count=COUNT)
    spec = dataclasses.replace(spec, scenarios=(sync,), montecarlo=mc)
    return read_tuning(TUNING), rig, spec


@pytest.fixture(scope="module")
def in_process(setup):
    """The reference: the whole run in this process, one chunk."""
    tuning, rig, spec = setup
    return verify(tuning, rig, spec, executor=InProcessExecutor())


def _same(a: st.Verification, b: st.Verification) -> None:
    # the record's bytes: canonical JSON of the whole result
    assert json.dumps(a.to_dict(), sort_keys=True) == json.dumps(b.to_dict(), sort_keys=True)
    assert a.variant_passed == b.variant_passed


def square(x: int, shared: int | None = None) -> int:
    """A task for the map tests (module level: a cluster pickles it by reference); slower for
    the earlier items, so they finish last."""
    time.sleep(0.02 * (5 - x) if x < 5 else 0)
    return x * x + (shared or 0)


def fail_on_three(x: int, shared: None = None) -> int:
    """A task that raises for one item (module level, for the cluster)."""
    if x == 3:
        raise ValueError(f"item {x} is bad")
    return x


def exit_soon() -> None:
    """Run on a worker: end its process abruptly (no cleanup) a moment after this returns,
    while its task thread is still computing."""
    threading.Timer(0.05, os._exit, args=(1,)).start()


# --- the interface ---------------------------------------------------------------------------


@pytest.mark.parametrize("n, workers", [(0, 2), (1, 1), (999, 2), (100_001, 2), (5_000, 7)])
def test_guided_chunks_cover_every_item_once_large_first(n, workers) -> None:
    bounds = guided_chunk_bounds(n, workers, smallest=16, largest=1000)
    assert [i for a, b in bounds for i in range(a, b)] == list(range(n))  # in order, once
    sizes = [b - a for a, b in bounds]
    assert all(16 <= s <= 1000 for s in sizes[:-1]) and all(s >= 1 for s in sizes)
    assert sizes == sorted(sizes, reverse=True)  # shrinking towards the end
    if n >= 100_000:  # the largest first, the smallest last: far fewer tasks than fixed 16
        assert sizes[0] == 1000 and sizes[-2] == 16 and len(bounds) < n // 500


def test_guided_chunks_refuse_impossible_sizes() -> None:
    with pytest.raises(ValueError, match="workers"):
        guided_chunk_bounds(10, 0, smallest=1, largest=4)
    with pytest.raises(ValueError, match="smallest"):
        guided_chunk_bounds(10, 2, smallest=5, largest=4)
    with pytest.raises(ValueError, match="smallest"):
        guided_chunk_bounds(10, 2, smallest=0, largest=4)


def test_chunk_bounds_cover_every_item_once() -> None:
    assert chunk_bounds(0, 3) == []
    assert chunk_bounds(7, 3) == [(0, 3), (3, 6), (6, 7)]
    with pytest.raises(ValueError, match="chunk_size"):
        chunk_bounds(7, 0)


def test_in_process_map_keeps_order_and_reports_progress() -> None:
    done: list[int] = []
    ex = InProcessExecutor()
    assert ex.map(square, [3, 1, 2], shared=10, done=done.append) == [19, 11, 14]
    assert done == [1, 2, 3] and ex.threads_per_task is None


def test_small_work_runs_in_process(monkeypatch) -> None:
    monkeypatch.delenv(SCHEDULER_ENV, raising=False)
    with open_executor(1000) as ex:
        assert isinstance(ex, InProcessExecutor)
    with open_executor(10**9, workers=1) as ex:  # one worker: in-process whatever the size
        assert isinstance(ex, InProcessExecutor)
    with pytest.raises(SchedulerError, match="workers must be >= 1"):
        with open_executor(10, workers=0):
            pass


def test_dask_map_returns_results_in_input_order(client) -> None:
    ex = DaskExecutor(client)
    done: list[int] = []
    assert ex.map(square, list(range(8)), shared=1, done=done.append) == [
        x * x + 1 for x in range(8)
    ]
    assert done == list(range(1, 9)) and ex.workers == 2 and ex.threads_per_task == 1


def get_config(key: str) -> object:
    """Run on a worker: its Dask setting ``key``."""
    import dask

    return dask.config.get(key)


def test_embedded_cluster_runs_with_its_quiet_settings(client) -> None:
    """Its processes got EMBEDDED_CLUSTER_CONFIG (the workers their copy from the nanny, the
    scheduler its timers); the caller's configuration is left as it was (Dask's defaults)."""
    import dask

    for key, value in EMBEDDED_CLUSTER_CONFIG.items():
        got = client.run(get_config, key)
        assert len(got) == 2 and set(got.values()) == {value}, key
        assert dask.config.get(key) != value, key  # not leaked into this process's settings
    assert client.run_on_scheduler(lambda dask_scheduler: dask_scheduler._tick_interval) == 1.0
    with pytest.raises(SchedulerError, match="workers"):
        with local_cluster(0):
            pass


def test_dask_map_raises_a_failed_task_s_error(client) -> None:
    """Results come back as their tasks end; a task that raised raises its own error here (as
    in-process), not a result list with a hole in it."""
    with pytest.raises(ValueError, match="item 3 is bad"):
        DaskExecutor(client).map(fail_on_three, list(range(6)))
    with pytest.raises(ValueError, match="item 3 is bad"):
        InProcessExecutor().map(fail_on_three, list(range(6)))


def test_scheduler_from_argument_and_environment(client, monkeypatch) -> None:
    address = client.scheduler.address
    with open_executor(1, scheduler=address) as ex:
        assert isinstance(ex, DaskExecutor) and ex.map(square, [6]) == [36]
    monkeypatch.setenv(SCHEDULER_ENV, address)
    with open_executor(1) as ex:
        assert isinstance(ex, DaskExecutor) and address in ex.name
    with pytest.raises(SchedulerError, match="not both"):
        with open_executor(1, workers=2):
            pass


# --- Monte Carlo on the cluster ------------------------------------------------------------


@pytest.mark.parametrize("chunk_size", [7, 16])
def test_cluster_result_is_the_in_process_result(client, setup, in_process, chunk_size) -> None:
    tuning, rig, spec = setup
    got = verify(tuning, rig, spec, executor=DaskExecutor(client), chunk_size=chunk_size)
    _same(got, in_process)
    assert got.montecarlo is not None and got.montecarlo.count == COUNT


def test_a_worker_killed_mid_run_changes_nothing(client, setup, in_process) -> None:
    """One worker process ends (os._exit) while it runs a chunk: Dask re-runs its task on the
    other worker (and the nanny starts a new one).

    A thread watches the scheduler and kills the first worker it sees holding a task, so the
    test waits on that condition, not on the driver's pace (on a loaded machine the driver
    may take the first result only once every chunk has run)."""
    tuning, rig, spec = setup
    killed: list[str] = []
    done = threading.Event()

    def watch() -> None:
        while not done.is_set() and not killed:
            busy = [w for w, keys in client.processing().items() if keys]
            if busy:
                killed.append(busy[0])
                client.run(exit_soon, workers=[busy[0]])
                return
            time.sleep(0.005)

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    try:
        got = verify(tuning, rig, spec, executor=DaskExecutor(client), chunk_size=4)
    finally:
        done.set()
        watcher.join(timeout=60)
    _same(got, in_process)
    assert killed, "the watcher saw no worker holding a task"
    client.wait_for_workers(2, timeout=60)
    assert killed[0] not in client.scheduler_info()["workers"]  # it really died


def test_gantry_montecarlo_on_the_cluster_is_the_in_process_one(client) -> None:
    """The gantry's own Monte Carlo goes through the same seam: plant pairs in chunks of 3 and
    of 5 on the 2 workers give the in-process result, pair by pair."""
    from servotune.arch.gantry.load import load_gantry
    from servotune.arch.gantry.run import gantry_montecarlo
    from servotune.arch.gantry.synthesis import resolve_gains

    cfg = resolve_gains(load_gantry(ROOT / "plants" / "gantry.toml"))
    ref = gantry_montecarlo(cfg, 8, seed=5)
    assert len({v.max_sync_error_counts for v in ref.variants}) == 8  # 8 different pairs
    for chunk_size in (3, 5):
        got = gantry_montecarlo(
            cfg, 8, seed=5, executor=DaskExecutor(client), chunk_size=chunk_size
        )
        assert got == ref


# --- the command line ------------------------------------------------------------------------


def test_refusing_scheduler_is_one_line_and_exit_3(tmp_path, capsys) -> None:
    import dask

    tuning = tmp_path / "tuning.json"
    shutil.copyfile(TUNING, tuning)
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        code = cli.main(
            [
                "verify",
                str(tuning),
                "--spec",
                str(SPEC),
                "--montecarlo",
                "8",
                "--scheduler",
                "tcp://127.0.0.1:1",
            ]
        )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 3
    assert len(err) == 1 and err[0].startswith("servotune verify: error: ")
    assert "tcp://127.0.0.1:1" in err[0]
    assert not (tmp_path / "tuning.json.verify.json").exists()
