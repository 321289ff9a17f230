"""Fixtures shared by the test modules, and the test processes' native thread pools.

Several tests fork workers directly (`dvcore.parallel.map_in_order` with ``processes=True``,
bypassing its rules, `dvcore.parallel.processes_usable`) from a pytest process that runs other
threads. A child forked while one of OpenCV's pool threads held its lock waits for ever on it
(issue 29; the watchdog then ends it with a `WorkerProcessStalled` warning, which the test suite
turns into an error): this happened once in a full run. So the test processes run OpenBLAS on one thread (as
the command line does, set before NumPy loads where conftest comes first) and never start
OpenCV's pool; tests of the pools' own behaviour run in processes of their own.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import pytest  # noqa: E402

from realdata import need_realdata  # noqa: E402

cv2.setNumThreads(0)  # OpenCV runs on the calling thread: no pool thread can hold a lock at a fork


@pytest.fixture
def realdata_dir():
    """``../shared/realdata``: skipped on a fresh clone without it, a failure in CI (tests/realdata.py)."""
    return need_realdata()
