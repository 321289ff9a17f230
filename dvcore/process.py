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
    """User + system CPU time (clock ticks) of the processes ``pids`` together, from
    ``/proc/PID/stat`` (Linux); None where any cannot be read (gone, or not Linux). A process
    blocked for ever on a lock uses none: a watchdog reads this to tell working from stalled."""
    total = 0
    for pid in pids:
        try:
            with open(f"/proc/{pid}/stat", "rb") as f:
                fields = f.read().rsplit(b")", 1)[1].split()
        except (OSError, IndexError):
            return None
        total += int(fields[11]) + int(fields[12])  # utime, stime: fields 14 and 15 of stat(5)
    return total
