"""One engine for work measured item by item: ``fn(item)`` for every item, the results in order.

    for result in map_in_order(fn, items, workers):
        ...

runs ``fn`` in ``workers`` **forked processes** where that is safe and pays (`processes_usable`),
else on ``workers`` threads (or in this process, one item after the other, with ``workers=1`` or
``threads=False``). The results are the same either way, in the items' order, with at most
``2 * workers`` items (or chunks of items) submitted and not yet yielded: memory stays bounded
whatever the length.

The forked path (issue 29: a forked worker once hung for ever on a lock inherited from a thread
of OpenCV's pool) keeps these rules, all here:

- **fork only a process that runs one thread** at the operating system's level
  (`dvcore.process.os_thread_count`): no other thread -- a notebook's, a viewer's, a native
  pool's (OpenBLAS, OpenCV) -- can then hold a lock at the instant of the fork. A caller that
  means to fork keeps OpenCV's pool unstarted before it (:func:`serial_native_pools`);
- the workers are forked **all at once, first**: before a progress bar (tqdm starts a monitor
  thread with its first bar) and never again (`ProcessPoolExecutor` forks every worker at its
  first submit with the fork context);
- nothing is pickled on the way in: ``fn`` and ``after_fork`` are inherited at the fork (a
  closure over a sequence and its calibration is fine); only the items and the results travel;
- a worker dies with its parent (``kill -9`` of it leaves none behind) and leaves Ctrl-C to it;
  ``after_fork()`` then runs in it (e.g. a lock and file handles of its own);
- **every wait on a worker is bounded** (`dvcore.process.wait_working`): the workers must use CPU
  at least once every :data:`STALL_S` seconds while a result is awaited; a dead worker
  (:class:`WorkerProcessDied`) or stalled workers (:class:`WorkerProcessStalled`) are killed and
  the items not yet returned are computed the other way (threads, or here), with that warning;
- the warnings ``fn`` raised in a worker are recorded there and given in this process, in the
  items' order (``relay``);
- a caller that stops early (or Ctrl-C) ends the workers at once, without waiting for chunks in
  flight.

Users: `dropvision.frame.measure_frame.stream_frames` (a sequence's frames), `dropvision.analysis.shot_rig.measure_each`
(a folder's shots).
"""

from __future__ import annotations

import os
import sys
import warnings
from collections import deque
from contextlib import contextmanager
from typing import Callable, Iterable, Iterator

from dvcore import process as _process

#: Set to 1 to keep `map_in_order` on threads (no forked processes).
NO_FORK_ENV = "DROPVISION_NO_FORK"
#: Seconds without CPU progress of every worker process, while their result is awaited, after
#: which they are taken for stalled (:class:`WorkerProcessStalled`). A busy worker uses CPU even on
#: a loaded machine; one blocked on a lock uses none. :data:`STALL_ENV` sets another value.
STALL_S = 10.0
STALL_ENV = _process.STALL_ENV


class WorkerProcessDied(RuntimeWarning):
    """A forked worker process of `map_in_order` died (killed, out of memory, a crash in a native
    library); the items it had not returned are computed again the other way (threads, or here)."""


class WorkerProcessStalled(WorkerProcessDied):
    """The forked workers of `map_in_order` used no CPU for :data:`STALL_S` seconds while a result
    was awaited (a worker blocked for ever, e.g. on a lock held at the fork); they are killed and
    the items not yet returned are computed the other way."""


def stall_seconds() -> float:
    """Seconds without CPU progress after which forked workers are taken for stalled (:data:`STALL_S`,
    or the environment variable :data:`STALL_ENV`)."""
    return _process.stall_s(STALL_S)


def processes_usable(n_items: int, workers: int, *, min_items: int = 2) -> bool:
    """Whether `map_in_order` forks: on Linux, with at least two workers and ``min_items`` items
    (below, forking costs more than it saves), only from a top-level process (not inside a pool's
    or a campaign's worker: no nested pools), unless :data:`NO_FORK_ENV` is set, and only while
    this process runs **one thread at the operating system's level**
    (`dvcore.process.os_thread_count`). Any other thread may hold a lock at the instant of the
    fork, and the child that needs it waits for ever (issue 29: a worker blocked in
    ``pthread_mutex_lock`` inside ``cv2.findContours`` after the calibration had used OpenCV's
    pool). With one thread there is no such lock."""
    import multiprocessing
    import threading

    from dvcore.process import os_thread_count

    return (sys.platform == "linux" and workers >= 2 and n_items >= min_items
            and not os.environ.get(NO_FORK_ENV)
            and multiprocessing.parent_process() is None and threading.active_count() == 1
            and os_thread_count() == 1)


@contextmanager
def serial_native_pools(active: bool = True):
    """While ``active``: OpenCV runs its functions on the calling thread, so that its thread pool
    is never started and the process stays single-threaded up to the fork of the workers
    (:func:`processes_usable`). Its thread count is given back afterwards (setting it starts no
    thread). Wrap in it the work done before a `map_in_order` that will fork (a calibration)."""
    if not active:
        yield
        return
    import cv2

    before = cv2.getNumThreads()
    cv2.setNumThreads(0)
    try:
        yield
    finally:
        cv2.setNumThreads(before)


def in_order(pool, fn, items, depth: int, result=None):
    """``fn(item)`` for every item, run on ``pool`` (an executor), yielded in the items' order, with
    at most ``depth`` submitted and not yet yielded; ``result(future)`` waits for each (default
    ``future.result()``; the forked workers' `Watchdog` bounds the wait)."""
    result = result or (lambda f: f.result())
    pending: deque = deque()
    it = iter(items)
    for item in it:
        pending.append(pool.submit(fn, item))
        if len(pending) >= depth:
            break
    while pending:
        value = result(pending.popleft())
        for item in it:  # one more, if any
            pending.append(pool.submit(fn, item))
            break
        yield value


class Watchdog:
    """A future's result, waited for with a bound (`dvcore.process.wait_working`): while it is
    awaited, the worker processes ``pids`` must use CPU at least once every ``stall_s`` seconds,
    or `dvcore.process.WorkersStalled` is raised: never an endless wait."""

    def __init__(self, pids, stall_s: float, poll_s: float = 0.2):
        self.pids, self.stall_s, self.poll_s = list(pids), stall_s, poll_s

    def result(self, future):
        from dvcore.process import wait_working

        wait_working([future], lambda: self.pids, self.stall_s, poll_s=self.poll_s)
        return future.result()


def relay_warnings(caught, stacklevel: int = 2) -> None:
    """Give in this process the warnings (category, message) a worker recorded, in order."""
    for category, message in caught:
        warnings.warn(message, category, stacklevel=stacklevel + 1)


def map_in_order(fn: Callable, items: Iterable, workers: int, *, processes: bool | None = None,
                 threads: bool = True, min_items: int = 2, min_chunk: int = 1, max_chunk: int = 32,
                 after_fork: Callable[[], None] | None = None,
                 relay: Callable[[list], None] | None = None,
                 progress: Callable[[int], object] | None = None,
                 label: str = "", unit: str = "item") -> Iterator:
    """``fn(item)`` for every item, yielded in the items' order.

    Parameters
    ----------
    fn : callable
        One item -> its result. In forked workers it is inherited, not pickled (a closure is
        fine); the items and results are pickled.
    items : iterable
    workers : int
        Processes or threads (1: here, one item after the other).
    processes : bool, optional
        None (default): fork where :func:`processes_usable` says so, decided here, at the fork.
        False: never fork. True: fork whatever the rules say (tests and benchmarks only: the caller
        vouches that no other thread can hold a lock).
    threads : bool
        Whether ``fn`` may run on threads (False: computed here one after the other, where not in
        forked workers; also after a dead or stalled worker).
    min_items : int
        Fewest items for which the rules allow forking (an item's cost against a fork's, some
        10-20 ms for two workers).
    min_chunk, max_chunk : int
        Items sent to a forked worker in one message: about a quarter of a worker's share, within
        these bounds (few messages, little work in flight when the caller stops).
    after_fork : callable, optional
        Run in each forked worker once it starts (e.g. a lock and file handles of its own: an
        inherited file's offset is shared with the parent).
    relay : callable, optional
        Gives this process the warnings ``fn`` raised in a forked worker, a list of (category,
        message) per chunk, in order (default :func:`relay_warnings`). On threads or here, ``fn``'s
        warnings are raised directly.
    progress : callable, optional
        ``progress(n_items)`` -> a bar with ``update()`` and ``close()``, made after the workers are
        forked (a bar's monitor thread would forbid the fork); updated once per result.
    label, unit : str
        Name the work in the warning of a dead or stalled worker (``label`` a file or folder).

    Yields
    ------
    ``fn(item)`` for each item, in order. An exception raised by ``fn`` reaches the caller (the
    workers ended).
    """
    items = list(items)
    workers = max(1, int(workers))
    if processes is None:
        processes = processes_usable(len(items), workers, min_items=min_items)  # before any bar's thread
    if processes and items:
        yield from _map_forked(fn, items, workers, threads=threads, min_chunk=min_chunk, max_chunk=max_chunk,
                               after_fork=after_fork, relay=relay or relay_warnings, progress=progress,
                               label=label, unit=unit)
        return
    bar = progress(len(items)) if progress is not None else None
    try:
        yield from _updating(_map_here(fn, items, workers, threads), bar)
    finally:
        if bar is not None:
            bar.close()


def _updating(results, bar):
    for value in results:
        yield value
        if bar is not None:
            bar.update()


def _map_here(fn, items, workers: int, threads: bool):
    """``fn`` over ``items`` in this process: on ``workers`` threads, or one after the other."""
    if workers <= 1 or not threads:
        for item in items:
            yield fn(item)
        return
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=workers) as pool:
        yield from in_order(pool, fn, items, 2 * workers)


# in a forked worker only: (fn, parent pid), set by `_worker_init` (inherited at the fork, never pickled)
_WORKER: tuple | None = None


def _worker_init(fn, after_fork, parent_pid: int) -> None:
    """In a forked worker: die with the parent (``kill -9`` of it leaves no worker behind), leave
    Ctrl-C to the parent (it ends the workers), then the caller's ``after_fork``."""
    import signal

    from dvcore.process import die_with_parent

    global _WORKER
    die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _WORKER = (fn, parent_pid)
    if after_fork is not None:
        after_fork()


def _run_chunk(chunk) -> tuple[list, list]:
    """In a forked worker: the results of ``chunk`` and the warnings they raised (category,
    message), for the parent to give in order (a child's own would be lost or printed)."""
    fn = _WORKER[0]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        results = [fn(item) for item in chunk]
    return results, [(w.category, str(w.message)) for w in caught]


def _map_forked(fn, items: list, workers: int, *, threads: bool, min_chunk: int, max_chunk: int,
                after_fork, relay, progress, label: str, unit: str):
    """`map_in_order` in ``workers`` forked processes: contiguous chunks, at most ``2 * workers``
    in flight, results in order; the rules of the module's docstring."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    from dvcore.process import WorkersStalled, close_pool, end_pool, pool_pids

    size = min(max_chunk, max(min_chunk, -(-len(items) // (4 * workers))))
    chunks = [items[a:a + size] for a in range(0, len(items), size)]
    done, bar, finished, bar_made = 0, None, False, False
    pool = ProcessPoolExecutor(max_workers=min(workers, len(chunks)), initializer=_worker_init,
                               initargs=(fn, after_fork, os.getpid()), mp_context=multiprocessing.get_context("fork"))
    try:
        with warnings.catch_warnings():  # Python >= 3.12 warns of every fork once native threads exist
            warnings.simplefilter("ignore", DeprecationWarning)
            first = pool.submit(int)  # the first submit forks every worker: now, before the bar's thread
        watchdog = Watchdog(pool_pids(pool), stall_seconds())
        watchdog.result(first)
        bar, bar_made = progress(len(items)) if progress is not None else None, True
        for results, caught in in_order(pool, _run_chunk, chunks, 2 * workers, watchdog.result):
            relay(caught)
            for value in results:
                yield value
                done += 1
                if bar is not None:
                    bar.update()
        finished = True
    except (BrokenProcessPool, WorkersStalled) as exc:
        stalled = isinstance(exc, WorkersStalled)
        end_pool(pool, kill=True)  # before computing on: a stalled worker holds no CPU, but memory
        rest = items[done:]
        what = "the worker processes stalled" if stalled else "a worker process died"
        how = "with threads" if threads and workers > 1 else "here"
        warnings.warn(f"{label}: {what} ({exc}); measuring the remaining {len(rest)} {unit}(s) {how}",
                      WorkerProcessStalled if stalled else WorkerProcessDied, stacklevel=3)
        if not bar_made and progress is not None:
            bar = progress(len(items))
        yield from _updating(_map_here(fn, rest, workers, threads), bar)
    finally:
        if finished:
            close_pool(pool)
        else:  # stopped early, interrupted, an error, a dead or stalled worker: no waiting for chunks in flight
            end_pool(pool)
        if bar is not None:
            bar.close()
