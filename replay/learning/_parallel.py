"""Run independent tasks in parallel: local processes through joblib, or a Dask cluster.

Every task carries everything it needs (inputs and its own seed), and results come back in
task order, so the outcome does not depend on how many workers ran it or where. BLAS threads
are pinned to one per task: a different thread count may change the order of floating-point
reductions and with it the last bits of a result.
"""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING, Any, TypeVar

import joblib
from threadpoolctl import threadpool_limits

from replay.errors import ReplayError
from schemas import cli

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator, Sequence

T = TypeVar("T")
R = TypeVar("R")


def _pinned(function: Callable[[T], R], task: T) -> R:
    """Run one task with one BLAS thread."""
    with threadpool_limits(limits=1):
        return function(task)


#: Hosts a plain ``tcp://`` scheduler address may name without a warning (this machine).
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "[::1]", "::1")


def scheduler_warning(scheduler: str) -> str | None:
    """Return a one-line warning for a scheduler reached without TLS off this machine, or None.

    A Dask scheduler and its workers send results back pickled: whoever runs them can run
    code in this process. ``tls://`` (with Dask's TLS settings) authenticates the cluster and
    encrypts the traffic; ``tcp://`` does neither.
    """
    scheme, _, rest = scheduler.rpartition("://")
    host = rest.rsplit(":", 1)[0] if ":" in rest.lstrip("[").split("]")[-1] else rest
    if scheme == "tls" or host in LOOPBACK_HOSTS:
        return None
    return (
        f"--scheduler {scheduler}: unencrypted and unauthenticated; results come back pickled, "
        "so whoever runs this scheduler can run code here. Use a cluster you control, "
        "preferably over tls:// with Dask's TLS settings (distributed.comm.tls.*)"
    )


@contextlib.contextmanager
def _dask_backend(scheduler: str, timeout_s: float) -> Iterator[None]:
    """Route joblib to the Dask cluster at ``scheduler`` for the duration of the block."""
    try:
        from dask.distributed import Client  # noqa: PLC0415 (optional dependency)
    except ImportError as err:
        msg = (
            f"--scheduler {scheduler}: Dask is not installed; install it with "
            "'pip install -e \".[dask]\"' or run without --scheduler"
        )
        raise ReplayError(msg) from err
    try:
        client = Client(scheduler, timeout=f"{timeout_s}s")  # type: ignore[no-untyped-call]
    except OSError as err:
        msg = f"--scheduler {scheduler}: cannot reach the Dask scheduler ({err}); check the address"
        raise ReplayError(msg) from err
    except ValueError as err:  # Dask's parse of the address ("missing port number ...")
        msg = f"--scheduler {scheduler}: {err}; give tls://HOST:PORT or tcp://HOST:PORT"
        raise ReplayError(msg) from err
    try:
        with joblib.parallel_config(backend="dask"):
            yield
    finally:
        client.close()  # type: ignore[no-untyped-call]


def run_tasks(
    function: Callable[[T], R],
    tasks: Sequence[T],
    *,
    workers: int = 1,
    scheduler: str | None = None,
    on_done: Callable[[int], Any] | None = None,
    connect_timeout_s: float = 10.0,
) -> list[R]:
    """Apply ``function`` to every task, in parallel, and return the results in task order.

    Args:
        function: A module-level function (it is pickled to other processes).
        tasks: The tasks; each must be picklable.
        workers: Local worker processes; 1 (or a single task) runs in this process.
        scheduler: Address of a Dask scheduler (``tcp://host:8786``); overrides ``workers``.
        on_done: Called with the number of finished tasks after each one (for progress bars).
        connect_timeout_s: How long to wait for the Dask scheduler.

    Returns:
        ``[function(task) for task in tasks]``, computed in parallel.
    """
    if workers < 1:
        msg = f"--workers {workers}: need at least one worker"
        raise ReplayError(msg)
    if scheduler is None and min(workers, len(tasks)) <= 1:  # no pool for one task (~1.3 s)
        results = []
        for done, task in enumerate(tasks, start=1):
            results.append(_pinned(function, task))
            if on_done is not None:
                on_done(done)
        return results
    backend = _dask_backend(scheduler, connect_timeout_s) if scheduler else contextlib.nullcontext()
    n_jobs = -1 if scheduler else workers
    with backend:
        parallel = joblib.Parallel(n_jobs=n_jobs, return_as="generator")
        with cli.workers_ignore_interrupts():  # the call starts the workers
            outputs = parallel(joblib.delayed(_pinned)(function, task) for task in tasks)
        results = []
        for done, result in enumerate(outputs, start=1):
            results.append(result)
            if on_done is not None:
                on_done(done)
    return results
