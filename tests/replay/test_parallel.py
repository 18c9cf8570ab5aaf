import statistics

import pytest

from replay.errors import ReplayError
from replay.learning._parallel import run_tasks

TASKS = [tuple(float(i * j % 7) / 3 for j in range(1, 50)) for i in range(12)]
EXPECTED = [statistics.fmean(task) for task in TASKS]


def test_one_worker_runs_in_order_and_reports_progress() -> None:
    seen: list[int] = []
    assert run_tasks(statistics.fmean, TASKS, workers=1, on_done=seen.append) == EXPECTED
    assert seen == list(range(1, len(TASKS) + 1))


def test_two_workers_give_the_same_results_in_task_order() -> None:
    assert run_tasks(statistics.fmean, TASKS, workers=2) == EXPECTED


def test_a_single_task_runs_in_this_process_whatever_the_workers(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import joblib  # noqa: PLC0415 (the pool the call must not start)

    started: list[object] = []
    monkeypatch.setattr(joblib, "Parallel", lambda *a, **k: started.append((a, k)))
    assert run_tasks(statistics.fmean, TASKS[:1], workers=2) == EXPECTED[:1]
    assert run_tasks(statistics.fmean, [], workers=2) == []
    assert not started


def test_zero_workers_is_refused() -> None:
    with pytest.raises(ReplayError, match="--workers 0"):
        run_tasks(statistics.fmean, TASKS, workers=0)


def test_unreachable_scheduler_is_a_clear_error() -> None:
    pytest.importorskip("dask.distributed")
    with pytest.raises(ReplayError, match="cannot reach the Dask scheduler"):
        run_tasks(statistics.fmean, TASKS, scheduler="tcp://127.0.0.1:1", connect_timeout_s=1.0)


@pytest.mark.slow
def test_local_dask_cluster_gives_the_same_results() -> None:
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        assert run_tasks(statistics.fmean, TASKS, scheduler=cluster.scheduler_address) == EXPECTED
