"""The executor protocol in process: chunking, input order, failures; and Dask stays out of ``import factorloc``."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Sequence
from typing import Any

import pytest
from helpers_parallel import raising_steps

from factorloc.errors import InputError
from factorloc.evaluation import evaluate, run_hierarchy
from factorloc.parallel import DaskExecutor, Executor, SerialExecutor, TaskFailure, chunk_indices


def test_chunks_never_mix_groups_and_keep_input_order_inside_a_group() -> None:
    chunks = chunk_indices(7, 2, group=["a", "b", "a", "a", "b", "a", "c"])
    assert chunks == [[0, 2], [1, 4], [3, 5], [6]]
    assert chunk_indices(5, 2) == [[0, 1], [2, 3], [4]]
    with pytest.raises(InputError, match="chunk_size"):
        chunk_indices(3, 0)
    with pytest.raises(InputError, match="one key per item"):
        chunk_indices(3, 1, group=["a"])


def _square_unless_seven(chunk: Sequence[int], offset: int) -> list[int]:
    if 7 in chunk:
        raise RuntimeError("seven")
    return [x * x + offset for x in chunk]


def test_serial_executor_gives_results_in_input_order_and_a_failure_per_item_of_a_failed_chunk() -> None:
    ex = SerialExecutor()
    assert isinstance(ex, Executor) and ex.workers == 1
    calls: list[tuple[int, int, int]] = []
    items = list(range(10))
    group = [i % 2 for i in items]  # interleaved groups: chunks finish out of input order
    out = list(ex.map_chunks(_square_unless_seven, items, 2, group=group, shared=1, progress=lambda *a: calls.append(a)))
    assert [r for r in out if not isinstance(r, TaskFailure)] == [i * i + 1 for i in items if i not in (5, 7)]
    assert [i for i, r in enumerate(out) if isinstance(r, TaskFailure)] == [5, 7]  # 7's chunk is [5, 7]
    assert out[7].error == "RuntimeError: seven" and not out[7].worker_died
    assert calls[-1] == (10, 10, 2) and [c[0] for c in calls] == [2, 4, 6, 8, 9, 10]


def test_dask_executor_rejects_bad_options_before_starting(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DASK_SCHEDULER_ADDRESS", raising=False)
    with pytest.raises(InputError, match="workers=N or scheduler"):
        DaskExecutor()
    with pytest.raises(InputError, match="not both"):
        DaskExecutor(workers=2, scheduler="tcp://x:1")
    with pytest.raises(InputError, match="workers must be"):
        DaskExecutor(workers=0)
    monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", "tcp://127.0.0.1:1")
    assert DaskExecutor().scheduler == "tcp://127.0.0.1:1"


def test_import_factorloc_and_its_batch_modules_do_not_import_dask() -> None:
    probe = (
        "import factorloc, factorloc.parallel, factorloc.evaluation, factorloc.evaluation.relations, factorloc.cli\n"
        "import json, sys\nprint(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed'))))"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert json.loads(out.splitlines()[-1]) == []


def test_a_query_that_raises_is_reported_by_id_and_counted_the_others_kept(make_room_scenario: Any) -> None:
    scen = make_room_scenario(6, 3)
    ids = [q.id for q in scen.queries]
    bad = frozenset({ids[1], ids[4]})
    seen: list[str] = []
    report = evaluate(scen, steps=raising_steps(bad), on_failure=lambda f: seen.append(f.query_id))
    clean = evaluate(scen)
    assert seen == [ids[1], ids[4]]
    s = report.summary()
    assert s.failed_queries == 2 and s.overall.queries == 4
    assert [f.query_id for f in s.failed] == [ids[1], ids[4]] and "RuntimeError: injected failure" in s.failed[0].error
    js = report.to_json()
    assert js["failed_queries"] == 2 and js["failed"][1]["query_id"] == ids[4]
    kept = {r.query_id: r for r in report.results}
    for r in clean.results:
        if r.query_id not in bad:
            assert kept[r.query_id].pose.as_array().tobytes() == r.pose.as_array().tobytes()
    run = run_hierarchy(scen, steps=raising_steps(bad))
    assert [q.index for q in run.runs] == [0, 2, 3, 5] and [f.index for f in run.failures] == [1, 4]


def test_the_shared_batch_pickles_after_a_process_prepared_its_references() -> None:
    # a Dask worker may fetch the shared batch from another worker that already ran chunks with it: a prepared
    # reference holds objects that cannot be pickled (small_gicp's KdTree), so the batch travels without them —
    # before, the transfer failed and the task waited on it for ever (seen as a hang of the 2-worker test)
    import pickle

    from factorloc.config import Config
    from factorloc.datasets import load_scenario
    from factorloc.evaluation.runner import _Batch

    s = load_scenario("data/sample")
    batch = _Batch({r.id: r.reference for r in s.references}, Config(), None, True)
    loc, fresh = batch.localizer(s.references[0].id)
    loc.localize(s.queries[0].query)
    assert fresh and batch.localizers
    copy = pickle.loads(pickle.dumps(batch))
    assert copy.localizers == {} and copy.seeded and set(copy.references) == set(batch.references)
    # a process that receives the same batch again keeps the one it has (and its preparations)
    again = pickle.loads(pickle.dumps(batch))
    assert again is copy and again.token == batch.token


def test_a_batch_received_again_after_the_process_dropped_its_copy_keeps_its_preparations() -> None:
    # Dask's active memory manager may drop a worker's replica of the shared batch while none of that worker's
    # waiting tasks needs it, then send it again for a later task (a 2-worker run counted 3 preparations, 1 in 6)
    import gc
    import pickle

    from factorloc.config import Config
    from factorloc.datasets import load_scenario
    from factorloc.evaluation.runner import _Batch

    s = load_scenario("data/sample")
    sent = pickle.dumps(_Batch({r.id: r.reference for r in s.references}, Config(), None, True))
    first = pickle.loads(sent)
    _, fresh = first.localizer(s.references[0].id)
    first_id = id(first)
    del first  # the worker released its replica
    gc.collect()
    second = pickle.loads(sent)
    _, fresh_again = second.localizer(s.references[0].id)
    assert fresh and not fresh_again and id(second) == first_id
