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
