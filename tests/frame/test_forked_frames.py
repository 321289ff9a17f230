"""`dropvision.frame.measure_frame.stream_frames` in forked processes measures exactly what threads measure.

The per-frame work holds the GIL much of its time, so on a long sequence `stream_frames` forks
``workers`` processes through the engine `dvcore.parallel.map_in_order` (its own rules and
failure modes on plain items: tests/dvcore/test_parallel.py). Checked here on the shipped samples:
PNG files (one frame per file), a 16-bit multi-page TIFF stack (one file shared by every frame:
the forked children must not share its open handle and file offset with the parent,
`Sequence.after_fork`); a colour frame in a grey sequence (the children's warnings reach the
caller, the colour note once per sequence, as with threads); that an error raised in a child
reaches the caller with its message; that a dead worker's frames are measured with threads; that
the workers are forked before a progress bar starts its thread; and the issue-29 race (a native
pool's threads, a lock held at the fork) on a real sequence.
"""

from __future__ import annotations

import os
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import dvcore.parallel as P
from dropvision.frame import measure_frame as F
from dropvision.calibrate.calibration_pass import calibrate_sequence
from dropvision.config import MeasureConfig
from dropvision.io.sequence import RGBConvertedWarning, SequenceError, open_sequence
from dropvision.io.sequence_writer import write_image

SAMPLES = Path(__file__).resolve().parents[2] / "sample_frames"
linux_only = pytest.mark.skipif(sys.platform != "linux", reason="the forked path runs on Linux only")


def _calibrated(name: str):
    seq = open_sequence(SAMPLES / name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RGBConvertedWarning)  # the colour sample's note, tested elsewhere
        _, _, ctx = calibrate_sequence(seq, MeasureConfig())
    return seq, ctx


@linux_only
@pytest.mark.parametrize("name", ["u55_u30", "satellite_dust_tiff16", "colour_ink_u70_u25"])
@pytest.mark.slow
def test_forked_processes_measure_what_threads_measure(name, monkeypatch):
    seq, ctx = _calibrated(name)
    n = len(seq)
    monkeypatch.setenv(P.NO_FORK_ENV, "1")
    threads = list(F.stream_frames(seq, range(n), ctx, 2))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing to note: the calibration pass saw the sequence
        forked = list(F.stream_frames(seq, range(n), ctx, 2, processes=True))
    assert len(forked) == len(threads) == n
    assert [r.index for r in forked] == list(range(n))
    assert sum(len(r.bodies) for r in forked) > 0 and np.isfinite([r.attached_volume_nl for r in forked]).any()
    assert [repr(r) for r in forked] == [repr(r) for r in threads]


@linux_only
def test_the_stack_is_still_readable_in_the_parent_after_the_children():
    """The children read the TIFF stack through handles of their own: the parent's reads after
    them (and interleaved with its own cached handle) still give the right pages."""
    seq, ctx = _calibrated("satellite_dust_tiff16")
    before = [seq.read(i).image.copy() for i in (0, len(seq) - 1)]
    assert seq.open_files  # the parent holds the stack open while the children run
    list(F.stream_frames(seq, range(len(seq)), ctx, 2, processes=True))
    after = [seq.read(i).image for i in (0, len(seq) - 1)]
    for a, b in zip(before, after):
        np.testing.assert_array_equal(a, b)


@linux_only
def test_an_error_in_a_child_reaches_the_caller(tmp_path):
    """A frame of another size raises SequenceError in the child that reads it; the caller gets
    it, naming the file."""
    import shutil

    folder = tmp_path / "seq"
    shutil.copytree(SAMPLES / "u55_u30", folder)
    src = open_sequence(folder)
    bad = src.meta.frames[40].file
    (folder / bad).unlink()
    write_image(folder / bad, src.read(39).image[:-8])  # a frame of another size
    seq = open_sequence(folder)
    _, _, ctx = calibrate_sequence(seq, MeasureConfig())
    with pytest.raises(SequenceError, match="image size") as err:
        list(F.stream_frames(seq, range(len(seq)), ctx, 2, processes=True))
    assert bad in str(err.value)


def test_when_processes_are_used(monkeypatch):
    """The engine's rules (tests/dvcore/test_parallel.py), the frames' least count, and no Rerun logger."""
    import dvcore.parallel

    monkeypatch.setattr(dvcore.parallel, "processes_usable", lambda n, w, min_items: n >= min_items and w >= 2)
    n = F.MIN_FRAMES_FOR_PROCESSES
    assert F.processes_usable(n, 2)
    assert not F.processes_usable(n - 1, 2)  # short sequence: threads
    assert not F.processes_usable(n, 1)
    assert not F.processes_usable(n, 2, logger=object())  # the Rerun logger lives in this process


@linux_only
@pytest.mark.slow
def test_a_dead_worker_process_falls_back_to_threads(monkeypatch):
    """A worker process that dies (here: exits at its third chunk) breaks the pool; the frames
    not yet returned are measured with threads, with a warning, and the records are complete
    and the same."""
    seq, ctx = _calibrated("u55_u30")
    n = len(seq)
    monkeypatch.setenv(P.NO_FORK_ENV, "1")
    threads = list(F.stream_frames(seq, range(n), ctx, 2))
    monkeypatch.setattr(F, "_measure_index", _dying_measure(os.getpid()))
    with pytest.warns(P.WorkerProcessDied, match="remaining .* frame.* with threads"):
        forked = list(F.stream_frames(seq, range(n), ctx, 2, processes=True))
    assert [r.index for r in forked] == list(range(n))
    assert [repr(r) for r in forked] == [repr(r) for r in threads]


_REAL_MEASURE = F._measure_index


def _dying_measure(parent_pid):
    """`dropvision.frame.measure_frame._measure_index`, but a worker process exits at frame 40."""
    def measure(seq, ctx, decoded, i, logger=None):
        if i == 40 and os.getpid() != parent_pid:
            os._exit(3)
        return _REAL_MEASURE(seq, ctx, decoded, i, logger)
    return measure


def test_processes_are_decided_before_the_progress_bar_starts(monkeypatch):
    """tqdm starts a monitor thread with its first bar, and a process running another thread
    does not fork: the decision must come first, or a terminal (bar shown) never gets processes."""
    from tqdm import tqdm

    import dvcore.parallel

    seq, ctx = _calibrated("u55_u30")
    seen = []

    def spy(n_items, workers, min_items):
        seen.append(len(tqdm._instances))
        return False

    monkeypatch.setattr(dvcore.parallel, "processes_usable", spy)
    recs = list(F.stream_frames(seq, range(5), ctx, 2, progress=True))
    assert len(recs) == 5 and seen == [0]


def _with_colour_frame(tmp_path, index=50):
    """A copy of the grey u55_u30 sample whose frame ``index`` is written in colour (RGB)."""
    import shutil

    folder = tmp_path / "seq"
    shutil.copytree(SAMPLES / "u55_u30", folder)
    seq = open_sequence(folder)
    name = seq.meta.frames[index].file
    grey = seq.read(index).image
    (folder / name).unlink()
    write_image(folder / name, np.dstack([grey, grey, grey]))
    return folder, name


@linux_only
@pytest.mark.slow
def test_a_childs_warnings_reach_the_caller_once(tmp_path, monkeypatch):
    folder, name = _with_colour_frame(tmp_path)
    results = {}
    for mode in ("threads", "forked"):
        seq = open_sequence(folder)
        _, _, ctx = calibrate_sequence(seq, MeasureConfig())  # grey calibration frames: no note yet
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            if mode == "threads":
                monkeypatch.setenv(P.NO_FORK_ENV, "1")
                recs = list(F.stream_frames(seq, range(len(seq)), ctx, 2))
            else:
                recs = list(F.stream_frames(seq, range(len(seq)), ctx, 2, processes=True))
        notes = [w for w in caught if issubclass(w.category, RGBConvertedWarning)]
        assert len(notes) == 1 and name in str(notes[0].message), (mode, [str(w.message) for w in caught])
        assert not seq.first_colour_note()  # noted for the sequence, in this process
        results[mode] = [repr(r) for r in recs]
    assert results["forked"] == results["threads"]


@linux_only
def test_workers_are_forked_before_the_progress_bar(monkeypatch):
    import multiprocessing

    seq, ctx = _calibrated("u55_u30")
    seen = []
    monkeypatch.setattr(F, "_progress_bar", lambda n, progress: seen.append(len(multiprocessing.active_children())))
    assert len(list(F.stream_frames(seq, range(len(seq)), ctx, 2, progress=True, processes=True))) == len(seq)
    assert seen == [2]


class _InheritedHandle(UserWarning):
    """Reported by `_measure_checking_handles`: a worker found the parent's open file in its cache."""


def _measure_checking_handles(seq, ctx, decoded, i, logger=None):
    """`dropvision.frame.measure_frame._measure_index`, reporting (as a warning) a handle the parent had open
    (tagged ``_dv_parent``) still in the worker's cache when the frame is read."""
    inherited = [f for f, h in seq._open_files.items() if getattr(h, "_dv_parent", False)]
    if inherited:
        warnings.warn(f"frame {i}: {inherited}", _InheritedHandle)
    return _REAL_MEASURE(seq, ctx, decoded, i, logger)


@linux_only
def test_workers_do_not_read_through_the_parents_open_file(monkeypatch):
    """The parent holds the TIFF stack open at the fork; no worker may use that handle (a shared
    file offset: pages read by one process would move the other's), whatever the timing."""
    seq, ctx = _calibrated("satellite_dust_tiff16")
    seq.read(0)
    assert seq.open_files == ("stack.tif",)
    for handle in seq._open_files.values():
        handle._dv_parent = True
    monkeypatch.setattr(F, "_measure_index", _measure_checking_handles)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        recs = list(F.stream_frames(seq, range(len(seq)), ctx, 2, processes=True))
    assert len(recs) == len(seq)
    assert not [str(w.message) for w in caught if issubclass(w.category, _InheritedHandle)]
    assert seq.open_files == ("stack.tif",)  # the parent's own is still open


# --- issue 29: a fork may not inherit a lock held by another thread; a stalled worker is caught ---

_NATIVE_POOLS = """
import json, os, sys
os.environ["OPENBLAS_NUM_THREADS"] = "1"  # as the command line sets it
sys.path.insert(0, {tests!r})
import cv2, numpy as np
from dvcore.process import os_thread_count
import dvcore.parallel as P
from dropvision.frame import measure_frame as F
n = F.MIN_FRAMES_FOR_PROCESSES
seen = {{"start": [os_thread_count(), F.processes_usable(n, 2)]}}
from test_forked_frames import _calibrated
with P.serial_native_pools():
    seq, ctx = _calibrated("u55_u30")  # the calibration pass, OpenCV's pool held off
    seen["after_calibration_serial"] = [os_thread_count(), F.processes_usable(n, 2)]
cv2.setNumThreads(4)
a = np.random.default_rng(0).random((1500, 1500), dtype=np.float32)
cv2.GaussianBlur(a, (0, 0), 4.0)  # OpenCV's pool runs: its threads stay
seen["after_opencv_pool"] = [os_thread_count(), F.processes_usable(n, 2)]
recs = list(F.stream_frames(seq, range(len(seq)), ctx, 2))
seen["measured"] = [len(recs), len(seq)]
print(json.dumps(seen))
"""


@linux_only
@pytest.mark.slow
def test_no_fork_once_a_native_pool_has_run(tmp_path):
    """A fresh command-line-like process (one BLAS thread) runs one thread, and keeps it so
    through a calibration with OpenCV's pool held off: it may fork. Once OpenCV's pool has run,
    its threads stay (one of them could hold a lock at the fork: the issue-29 hang), and
    `stream_frames` measures with threads instead, the records complete."""
    import json
    import subprocess

    script = tmp_path / "pools.py"
    script.write_text(_NATIVE_POOLS.format(tests=str(Path(__file__).resolve().parent)))
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    seen = json.loads(r.stdout.strip().splitlines()[-1])
    assert seen["start"] == [1, True]
    assert seen["after_calibration_serial"] == [1, True]
    assert seen["after_opencv_pool"][0] > 1 and seen["after_opencv_pool"][1] is False
    assert seen["measured"][0] == seen["measured"][1] > F.MIN_FRAMES_FOR_PROCESSES


_HELD_AT_FORK = """
import json, os, sys, threading, warnings
sys.path.insert(0, {tests!r})
from test_forked_frames import _calibrated, F
import dvcore.parallel as P
os.environ[P.STALL_ENV] = "1"
seq, ctx = _calibrated("u55_u30")
os.environ[P.NO_FORK_ENV] = "1"
threads = [repr(r) for r in F.stream_frames(seq, range(len(seq)), ctx, 2)]
del os.environ[P.NO_FORK_ENV]
held = threading.Lock()
real_measure, real_bar = F.measure_frame, F._progress_bar

def measure_needing_the_lock(*args, **kw):  # like cv2.findContours waiting on its pool's mutex
    with held:
        pass
    return real_measure(*args, **kw)

def bar_after_the_fork(n, progress):  # the holder lets go, in this process only
    if held.locked():
        held.release()
    return real_bar(n, progress)

F.measure_frame, F._progress_bar = measure_needing_the_lock, bar_after_the_fork
held.acquire()  # held at the instant of the fork: every child inherits it locked, with no owner
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    forked = [repr(r) for r in F.stream_frames(seq, range(len(seq)), ctx, 2, processes=True)]
import multiprocessing
print(json.dumps({{"same": forked == threads, "n": len(forked),
                  "warnings": [(w.category.__name__, str(w.message)) for w in caught],
                  "children_left": len(multiprocessing.active_children())}}))
"""


@linux_only
@pytest.mark.slow
def test_a_lock_held_at_the_fork_is_caught_and_the_frames_measured(tmp_path):
    """The race provoked on purpose: a lock is held at the instant the workers are forked, and
    every frame needs it. Each child waits for ever (no CPU used); the watchdog sees it within
    its stall time (1 s here), kills the workers and measures every frame with threads, with a
    `WorkerProcessStalled` warning; the records are those of threads. Run in a process of its own
    with a time limit: without the watchdog it would hang."""
    import json
    import subprocess

    script = tmp_path / "held.py"
    script.write_text(_HELD_AT_FORK.format(tests=str(Path(__file__).resolve().parent)))
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    seen = json.loads(r.stdout.strip().splitlines()[-1])
    assert seen["same"] and seen["n"] > F.MIN_FRAMES_FOR_PROCESSES
    stalls = [m for c, m in seen["warnings"] if c == "WorkerProcessStalled"]
    assert len(stalls) == 1 and "stalled" in stalls[0] and "with threads" in stalls[0], seen["warnings"]
    assert seen["children_left"] == 0
