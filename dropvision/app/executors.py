"""One code path for local and cluster runs: everything is a `concurrent.futures.Executor`.

- ``workers=1``: an in-process serial executor (no pickling, easiest to debug);
- ``workers=N``: a local process pool (the default uses every core); its workers die with the
  main process (:func:`_exit_with_parent`), a ``kill -9`` of a campaign leaves none behind;
- ``dask_local=N``: a Dask ``LocalCluster`` with N single-threaded worker processes (their
  nannies end them when the main process dies);
- ``scheduler="tcp://host:8786"``: an existing Dask cluster, through ``Client.get_executor()``.

Dask is an optional extra (``pip install dropvision[dask]``); asking for it without it
installed raises a clear error.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import threading
import time
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from typing import Iterator

from dvcore.process import die_with_parent


class SerialExecutor(Executor):
    """Runs each task immediately in the calling process."""

    def submit(self, fn, /, *args, **kwargs) -> Future:
        future: Future = Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - delivered through the future
            future.set_exception(exc)
        return future


def _exit_with_parent(parent_pid: int, via_server: bool = False, poll_s: float = 0.25) -> None:
    """Initializer of every pool worker: it dies with the process that started it.

    A worker must never outlive a killed campaign (``kill -9`` of the main process leaves the
    pool's workers orphaned, still measuring and writing shards). On Linux the kernel sends
    SIGKILL to the worker when its parent dies (``prctl(PR_SET_PDEATHSIG)``); everywhere a
    daemon watchdog thread also exits the worker as soon as ``os.getppid()`` changes (the
    worker was re-parented). A worker forked by a fork server (``via_server``) has the server
    as its parent, and the server lives as long as any of its workers holds the campaign's
    "alive" pipe: its thread watches the campaign's process ``parent_pid`` itself (gone, or a
    zombie) and ends the worker, after which the server ends too. Dask ``LocalCluster``
    workers need neither: their nannies already end them with the client process.
    """
    direct = os.getppid() if via_server else parent_pid
    die_with_parent(direct)

    def watch() -> None:
        while True:
            time.sleep(poll_s)
            if os.getppid() != direct or (via_server and not _alive(parent_pid)):
                os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs (exists and is no zombie: a killed process not yet reaped)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # pragma: no cover - another user's process of that number
        return True
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0] not in (b"Z", b"X")
    except (OSError, IndexError):
        return True  # no /proc: existence is all we can tell


def check_executor_args(workers: int | None = None, *, dask_local: int | None = None,
                        scheduler: str | None = None) -> None:
    """Raise ValueError for executor arguments :func:`make_executor` would refuse, before
    anything (an output folder, a manifest) is touched."""
    if dask_local is not None and scheduler is not None:
        raise ValueError("choose either a local Dask cluster (--dask-local) or a scheduler address, not both")
    if dask_local is not None and int(dask_local) < 1:
        raise ValueError(f"--dask-local needs at least one worker, got {dask_local}")
    if scheduler is None and dask_local is None and workers is not None and int(workers) < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")


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
            try:
                client = dd.Client(scheduler)
            except (OSError, TimeoutError) as exc:  # name the scheduler, not the campaign's input
                raise OSError(0, f"cannot reach the Dask scheduler ({exc})", str(scheduler)) from exc
            with client:
                warming = _warm(client)  # noqa: F841 - kept alive while the executor is in use
                yield client.get_executor()
        else:
            if dask_local < 1:
                raise ValueError(f"--dask-local needs at least one worker, got {dask_local}")
            with dd.LocalCluster(
                n_workers=dask_local, threads_per_worker=1, processes=True, dashboard_address=":0",  # any free port
            ) as cluster, dd.Client(cluster) as client:
                warming = _warm(client)  # noqa: F841 - kept alive while the executor is in use
                yield client.get_executor()
        return
    n = default_workers() if workers is None else int(workers)
    if n < 1:
        raise ValueError(f"--workers must be >= 1, got {n}")
    if n == 1:
        yield SerialExecutor()
        return
    context = _pool_context()
    via_server = context is not None and context.get_start_method() == "forkserver"
    with ProcessPoolExecutor(max_workers=n, initializer=_exit_with_parent, initargs=(os.getpid(), via_server),
                             mp_context=context) as pool:
        yield pool


def _pool_context():
    """How the local pool starts its workers: forked from this process only while it runs one
    thread at the operating system's level (no other thread, a native pool's included, can then
    hold a lock at the fork: `dvcore.process.os_thread_count`); otherwise forked by a fork server
    (a fresh process running one thread, started once). Elsewhere than Linux, the default."""
    import multiprocessing
    import sys

    from dvcore.process import os_thread_count

    if not sys.platform.startswith("linux"):
        return None
    return multiprocessing.get_context("fork" if os_thread_count() == 1 else "forkserver")


def _import_measurement() -> None:
    importlib.import_module("dropvision.measurement")  # the bulk; naming the campaign would be a cycle


def _warm(client) -> list:
    """Have every worker import the measurement code now, while the main process hashes the
    sequences, instead of on its first task (~1 s of imports per fresh worker). Returns the
    futures, to be kept until the client closes (a released future may be cancelled)."""
    workers = list(client.scheduler_info().get("workers", {}))
    return [client.submit(_import_measurement, workers=[w], allow_other_workers=False, pure=False) for w in workers]
