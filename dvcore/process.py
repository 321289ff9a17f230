"""Worker processes that never outlive the process that started them."""

from __future__ import annotations

import os
import sys


def die_with_parent(parent_pid: int) -> None:
    """In a child process: on Linux have the kernel send it SIGKILL when its parent dies
    (``prctl(PR_SET_PDEATHSIG)``), and exit at once if the parent (``parent_pid``) is already
    gone (the child was re-parented before the call). A ``kill -9`` of the main process then
    leaves no worker behind, still computing and writing. Elsewhere only the second part."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes
            import signal

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PR_SET_PDEATHSIG = 1
        except (OSError, AttributeError):  # pragma: no cover - no usable libc
            pass
    if os.getppid() != parent_pid:  # the parent died before the line above
        os._exit(1)


def os_thread_count() -> int | None:
    """How many threads this process runs at the operating system's level (Python's and native
    ones: OpenBLAS's, OpenCV's pool, a decoder's), read from ``/proc/self/task`` on Linux; None
    where that cannot be read. One means no other thread exists that could hold a lock at the
    moment of a fork: the only state in which forking is provably safe."""
    try:
        return len(os.listdir("/proc/self/task"))
    except OSError:
        return None


def cpu_ticks(pids) -> int | None:
    """User + system CPU time (clock ticks) of the main threads of the processes ``pids``
    together, from ``/proc/PID/task/PID/stat`` (Linux); None where any cannot be read (gone, or
    not Linux). A process whose main thread is blocked for ever on a lock uses none there (a
    helper thread of its own, polling, does not count): a watchdog reads this to tell working
    from stalled."""
    total = 0
    for pid in pids:
        try:
            with open(f"/proc/{pid}/task/{pid}/stat", "rb") as f:
                fields = f.read().rsplit(b")", 1)[1].split()
        except (OSError, IndexError):
            return None
        total += int(fields[11]) + int(fields[12])  # utime, stime: fields 14 and 15 of stat(5)
    return total


class WorkersStalled(RuntimeError):
    """Raised by :func:`wait_working`: the worker processes used no CPU for the stall time while
    their results were awaited (a worker blocked for ever, e.g. on a lock held at a fork)."""


#: Environment variable: seconds without CPU progress of the workers after which a wait on them
#: gives up (`wait_working`); each caller has its own default.
STALL_ENV = "DROPVISION_WORKER_STALL_S"


def stall_s(default: float) -> float:
    """The stall time from :data:`STALL_ENV` (a positive number of seconds), else ``default``."""
    raw = os.environ.get(STALL_ENV)
    try:
        value = float(raw) if raw else default
    except ValueError:
        value = default
    return value if value > 0 else default


def wait_working(futures, pids, stall_after_s: float, *, poll_s: float = 0.2):
    """``concurrent.futures.wait(futures, return_when=FIRST_COMPLETED)`` with a bound: while none
    is done, the processes ``pids()`` (a callable: a pool may replace its workers) must use CPU
    (`cpu_ticks`) at least once every ``stall_after_s`` seconds, or :class:`WorkersStalled` is
    raised. A busy worker uses CPU even on a loaded machine; one blocked on a lock uses none.
    Returns ``(done, not_done)`` as `concurrent.futures.wait` does."""
    import time
    from concurrent.futures import FIRST_COMPLETED, wait

    last, since = cpu_ticks(pids()), time.monotonic()
    while True:
        done, not_done = wait(futures, timeout=poll_s, return_when=FIRST_COMPLETED)
        if done:
            return done, not_done
        ticks, now = cpu_ticks(pids()), time.monotonic()
        if ticks is None or ticks != last:  # working (or a worker gone: its pool breaks the futures)
            last, since = ticks, now
        elif now - since > stall_after_s:
            raise WorkersStalled(f"no CPU used by the worker processes for {now - since:.0f} s")


def pool_pids(pool) -> list[int]:
    """The process ids of a `concurrent.futures.ProcessPoolExecutor`'s workers (none for other
    executors)."""
    return [p.pid for p in (getattr(pool, "_processes", None) or {}).values() if p.pid is not None]


def end_pool(pool, kill: bool = False) -> None:
    """Stop a `concurrent.futures.ProcessPoolExecutor` now: nothing queued runs, and its workers
    (busy, or blocked) are terminated (killed with ``kill``, or when a termination is not enough
    within 2 s). Bounded: it never waits on a worker for longer."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.kill() if kill else p.terminate()
    for p in procs:
        p.join(timeout=2)
        if p.is_alive():
            p.kill()
            p.join(timeout=2)


def close_pool(pool, timeout_s: float = 5.0) -> None:
    """Let a `concurrent.futures.ProcessPoolExecutor`'s idle workers exit (every task returned),
    waiting at most ``timeout_s`` for each; a worker still there then (blocked at its exit) is
    killed (`end_pool`)."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False)
    for p in procs:
        p.join(timeout=timeout_s)
    if any(p.is_alive() for p in procs):
        end_pool(pool, kill=True)
