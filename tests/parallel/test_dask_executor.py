"""Serial and a 2-worker local Dask cluster give the same results bit for bit; failures are reported by id.

One local cluster for the module (starting one costs seconds). Every comparison is exact: poses, covariances,
verdicts and estimates through their JSON (shortest round-trip reprs of the floats), without the run times.
"""

from __future__ import annotations

import json
import math
import os
import sys
from collections.abc import Iterator, Sequence
from concurrent.futures import CancelledError
from pathlib import Path
from typing import Any

import cloudpickle
import helpers_parallel
import pytest
from helpers_parallel import raising_steps

from factorloc.datasets import load_scenario
from factorloc.datasets.rosbag import read_laser_log
from factorloc.evaluation import evaluate, run_hierarchy
from factorloc.evaluation.relations import read_relations, relations_benchmark
from factorloc.parallel import DaskExecutor, TaskFailure
from factorloc.parallel.dask_executor import _run_chunk

pytest.importorskip("distributed")
pytestmark = pytest.mark.slow  # ~60-90 s on the shared 2 cores: a cluster start, the sample twice, 16 relations twice

# the workers cannot import the test modules: the helpers they run are sent by value
cloudpickle.register_pickle_by_value(sys.modules[__name__])
cloudpickle.register_pickle_by_value(helpers_parallel)


@pytest.fixture(scope="module")
def dask2() -> Iterator[DaskExecutor]:
    # a task whose worker dies is reported at once (no retry), so that the dying-worker test stays short; no
    # kernel warm-up (timings are not compared here)
    with DaskExecutor(workers=2, allowed_failures=0, warm_up=False) as ex:
        yield ex


def _without_times(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _without_times(v) for k, v in value.items() if "seconds" not in k and not k.endswith("_ms")}
    if isinstance(value, list):
        return [_without_times(v) for v in value]
    return value


def _fingerprint(loc: Any) -> str:
    return json.dumps(_without_times(loc.to_dict()), sort_keys=True)


def test_evaluate_on_the_sample_is_identical_on_two_workers(dask2: DaskExecutor, repo_root: Path) -> None:
    scen = load_scenario(repo_root / "data" / "sample")
    serial = evaluate(scen)
    done: list[tuple[int, int]] = []
    parallel = evaluate(scen, executor=dask2, chunk_size=4, progress=lambda d, t: done.append((d, t)))
    assert dask2.workers == 2 and done[-1] == (30, 30) and len(done) == 8  # 8 chunks of at most 4 queries
    assert [r.query_id for r in parallel.results] == [r.query_id for r in serial.results]
    for a, b in zip(serial.results, parallel.results, strict=True):
        assert a.pose.as_array().tobytes() == b.pose.as_array().tobytes()
        assert a.covariance.tobytes() == b.covariance.tobytes()
    for a, b in zip(serial.run.runs, parallel.run.runs, strict=True):
        assert _fingerprint(a.localization) == _fingerprint(b.localization)
    s, p = serial.to_json(), parallel.to_json()
    for key in ("position_rmse_m", "heading_rmse_deg", "nees_mean", "confidently_wrong_count", "determined_rate"):
        assert s[key] == p[key]
    assert p["failed_queries"] == 0 and set(parallel.run.prepare_seconds) == set(serial.run.prepare_seconds)
    # one reference: prepared once in process, once per worker (not once per chunk: 8 chunks)
    assert serial.run.preparations == 1 and 1 <= parallel.run.preparations <= 2


def test_a_query_that_raises_in_a_worker_is_reported_by_id_the_others_kept(dask2: DaskExecutor, make_room_scenario: Any) -> None:
    scen = make_room_scenario(6, 3)
    ids = [q.id for q in scen.queries]
    bad = frozenset({ids[2]})
    serial = run_hierarchy(scen, steps=raising_steps(bad))
    parallel = run_hierarchy(scen, steps=raising_steps(bad), executor=dask2, chunk_size=2)
    assert [(f.index, f.query_id) for f in parallel.failures] == [(2, ids[2])]
    assert "RuntimeError: injected failure on" in parallel.failures[0].error and not parallel.failures[0].worker_died
    assert [_fingerprint(q.localization) for q in parallel.runs] == [_fingerprint(q.localization) for q in serial.runs]
    assert evaluate(parallel).summary().failed_queries == 1


def _close(a: Any, b: Any) -> bool:
    """Equal, floats within 1e-9 relative (nested dicts and lists)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b)) or math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12)
    return a == b


def test_the_relations_benchmark_on_a_real_log_subset_is_identical_on_two_workers(dask2: DaskExecutor, shared_data: Path) -> None:
    laser = shared_data / "laser"
    log = read_laser_log(laser / "mit-csail.sort.bag")
    rel = read_relations(laser / "mit-csail.relations").subset(73)  # 17 relations, loops among them
    serial = relations_benchmark(log, rel)
    parallel = relations_benchmark(log, rel, executor=dask2, chunk_size=5)
    assert len(serial) == len(parallel) > 0

    def fields(r: Any) -> dict:
        return _without_times({k: v for k, v in vars(r).items() if k != "seconds"})

    ours = [(json.dumps(fields(a), sort_keys=True, default=str), json.dumps(fields(b), sort_keys=True, default=str))
            for a, b in zip(serial, parallel, strict=True) if not a.method.startswith("open3d")]  # fmt: skip
    assert len(ours) == 3 * len(rel) and all(a == b for a, b in ours)  # ours, ours_icp, odometry: bit for bit
    # Open3D's ICP reduces over OpenMP threads: its rows depend on its thread count (the workers run one thread,
    # this process as many as cores), in the last digits only
    peers = [(fields(a), fields(b)) for a, b in zip(serial, parallel, strict=True) if a.method.startswith("open3d")]
    assert len(peers) == 2 * len(rel) and all(_close(a, b) for a, b in peers)
    assert {r.kind for r in serial} == {"local", "loop"}


def _die_on_three(chunk: Sequence[int], shared: Any) -> list[int]:
    if 3 in chunk:
        os._exit(1)  # the worker process dies mid-task
    return [x + 1 for x in chunk]


def test_a_dying_worker_is_reported_and_the_batch_finishes(dask2: DaskExecutor) -> None:
    out = list(dask2.map_chunks(_die_on_three, list(range(6)), 2))
    assert [r for r in out if not isinstance(r, TaskFailure)] == [1, 2, 5, 6]
    failed = [r for r in out if isinstance(r, TaskFailure)]
    assert len(failed) == 2 and all(f.worker_died for f in failed) and "KilledWorker" in failed[0].error


def _die_on_one_and_four(chunk: Sequence[int], shared: Any) -> list[int]:
    if 1 in chunk or 4 in chunk:
        os._exit(1)
    return [x + shared["step"] for x in chunk]


def test_two_dying_workers_lose_only_the_chunks_they_ran(dask2: DaskExecutor) -> None:
    # one chunk runs per worker thread at a time: a worker's death fails only its own chunk, never one that was
    # waiting (with allowed_failures=0 Dask fails every task it had sent to the dead worker); shared is a dict
    dask2.client.wait_for_workers(2, timeout=120)
    out = list(dask2.map_chunks(_die_on_one_and_four, list(range(8)), 1, shared={"step": 10}))
    assert [r if not isinstance(r, TaskFailure) else None for r in out] == [10, None, 12, 13, None, 15, 16, 17]
    assert all(r.worker_died for r in out if isinstance(r, TaskFailure))


def _opencv_threads() -> int:
    import cv2

    return int(cv2.getNumThreads())


def test_every_worker_runs_opencv_on_one_thread_also_one_that_replaced_a_dead_one(dask2: DaskExecutor) -> None:
    # after the dying-worker test above the nanny has started a new worker process: the plugin set it up too
    dask2.client.wait_for_workers(2, timeout=120)
    threads = dask2.client.run(_opencv_threads)
    assert len(threads) == 2 and set(threads.values()) == {1}


def _trim_threshold() -> str | None:
    return os.environ.get("MALLOC_TRIM_THRESHOLD_")


def test_local_workers_keep_glibcs_allocator_tuning(dask2: DaskExecutor) -> None:
    # Dask's nanny would set MALLOC_TRIM_THRESHOLD_=65536, which made every query 51 % slower (docs/scale.md);
    # the local cluster's workers inherit whatever this process has instead (normally nothing)
    values = set(dask2.client.run(_trim_threshold).values())
    assert values == {os.environ.get("MALLOC_TRIM_THRESHOLD_")}


def test_a_chunk_cancelled_by_the_scheduler_is_sent_again_then_failed(dask2: DaskExecutor) -> None:
    # what a chunk whose scattered input died with a worker gets: a cancelled future (here cancelled by hand)
    import distributed

    # restricted to a worker that does not exist: it never runs before it is cancelled
    fut = dask2.client.submit(_run_chunk, _die_on_three, [1], None, pure=False, workers=["tcp://127.0.0.1:9"])
    dask2.client.cancel([fut])
    with pytest.raises(CancelledError) as cancelled:
        fut.result()
    assert DaskExecutor._results_of(fut, cancelled.value, [0], distributed, resend=True) is None
    (failure,) = DaskExecutor._results_of(fut, cancelled.value, [0], distributed, resend=False)
    assert isinstance(failure, TaskFailure) and failure.worker_died and "CancelledError" in failure.error
