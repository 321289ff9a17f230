"""One code path for local and cluster runs: everything is a `concurrent.futures.Executor`.

- ``workers=1``: an in-process serial executor (no pickling, easiest to debug);
- ``workers=N``: a local process pool (the default uses every core);
- ``dask_local=N``: a Dask ``LocalCluster`` with N single-threaded worker processes;
- ``scheduler="tcp://host:8786"``: an existing Dask cluster, through ``Client.get_executor()``.

Dask is an optional extra (``pip install dropvision[dask]``); asking for it without it
installed raises a clear error.
"""

from __future__ import annotations

import contextlib
import os
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from typing import Iterator


class SerialExecutor(Executor):
    """Runs each task immediately in the calling process."""

    def submit(self, fn, /, *args, **kwargs) -> Future:
        future: Future = Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - delivered through the future
            future.set_exception(exc)
        return future


def default_workers() -> int:
    """Number of cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


def _import_dask_distributed():
    try:
        import dask.distributed as dd
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise RuntimeError(
            "Dask is not installed: install the optional extra with "
            "`pip install 'dropvision[dask]'` to use --dask-local or --scheduler"
        ) from exc
    return dd


@contextlib.contextmanager
def make_executor(
    workers: int | None = None, *, dask_local: int | None = None, scheduler: str | None = None
) -> Iterator[Executor]:
    """Context manager yielding the executor described by the arguments (see module doc)."""
    if dask_local is not None and scheduler is not None:
        raise ValueError("choose either a local Dask cluster (--dask-local) or a scheduler address, not both")
    if scheduler is not None or dask_local is not None:
        dd = _import_dask_distributed()
        if scheduler is not None:
            with dd.Client(scheduler) as client:
                yield client.get_executor()
        else:
            if dask_local < 1:
                raise ValueError(f"--dask-local needs at least one worker, got {dask_local}")
            with dd.LocalCluster(
                n_workers=dask_local, threads_per_worker=1, processes=True, dashboard_address=None
            ) as cluster, dd.Client(cluster) as client:
                yield client.get_executor()
        return
    n = default_workers() if workers is None else int(workers)
    if n < 1:
        raise ValueError(f"--workers must be >= 1, got {n}")
    if n == 1:
        yield SerialExecutor()
        return
    with ProcessPoolExecutor(max_workers=n) as pool:
        yield pool
