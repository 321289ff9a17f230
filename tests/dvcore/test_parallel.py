"""`dvcore.parallel.map_in_order`: the engine that forks worker processes (issue 29), on plain items.

Every way of running (forked processes, threads, here) gives the same results in order; the
fork-safety rules hold: the decision (`processes_usable`: one thread at the operating system's
level), the workers forked before a progress bar, ``fn`` inherited and never pickled,
``after_fork`` run in each worker, a worker dying with its parent, a dead or stalled worker's items
computed the other way with a warning, every wait bounded, a worker's warnings given here in
order, a caller stopping early ending the workers at once. The frame workers on real sequences:
tests/frame/test_forked_frames.py.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import signal
import subprocess
import sys
import threading
import warnings
from pathlib import Path

import pytest

import dvcore.parallel as P

linux_only = pytest.mark.skipif(sys.platform != "linux", reason="the forked path runs on Linux only")
ROOT = Path(__file__).resolve().parents[2]


def _square_and_pid(x):
    return x * x, os.getpid()


def _no_children_left():
    """Whether every child of this process is gone (polled a little: the pool's own thread may reap
    one first, and its Process object then reads alive for a moment)."""
    for _ in range(150):
        if not multiprocessing.active_children():
            return True
        threading.Event().wait(0.02)
    return False


@pytest.mark.parametrize("how", [dict(processes=False), dict(processes=False, threads=False),
                                 pytest.param(dict(processes=True), marks=linux_only),
                                 pytest.param(dict(processes=True, threads=False), marks=linux_only)])
def test_every_way_gives_the_results_in_order(how):
    out = list(P.map_in_order(_square_and_pid, range(57), 2, max_chunk=4, **how))
    assert [v for v, _ in out] == [x * x for x in range(57)]
    pids = {pid for _, pid in out}
    if how["processes"]:
        assert os.getpid() not in pids and 1 <= len(pids) <= 2  # every item in a worker (one may take all)
    else:
        assert pids == {os.getpid()}
    assert _no_children_left()


def test_one_worker_or_no_items():
    assert list(P.map_in_order(lambda x: -x, [3, 1, 2], 1)) == [-3, -1, -2]
    assert list(P.map_in_order(lambda x: -x, [], 2, processes=True)) == []


@linux_only
def test_fn_is_inherited_not_pickled_and_after_fork_runs_in_each_worker():
    """A closure over an unpicklable object works in the workers; ``after_fork`` ran in each one
    before its first item, and never here."""
    lock = threading.Lock()  # not picklable
    state = {"forked": None}

    def after_fork():
        state["forked"] = os.getpid()

    def fn(x):
        with lock:
            return x + 1, state["forked"] == os.getpid()

    out = list(P.map_in_order(fn, range(20), 2, processes=True, after_fork=after_fork))
    assert [v for v, _ in out] == list(range(1, 21))
    assert all(ok for _, ok in out)
    assert state["forked"] is None


def test_when_processes_are_used(monkeypatch):
    import dvcore.process

    monkeypatch.delenv(P.NO_FORK_ENV, raising=False)
    monkeypatch.setattr(threading, "active_count", lambda: 1)
    monkeypatch.setattr(dvcore.process, "os_thread_count", lambda: 1)
    assert P.processes_usable(8, 2, min_items=8) is (sys.platform == "linux")
    assert not P.processes_usable(7, 2, min_items=8)  # too few items: not worth a fork
    assert not P.processes_usable(8, 1, min_items=8)
    monkeypatch.setattr(threading, "active_count", lambda: 2)
    assert not P.processes_usable(8, 2, min_items=8)  # another thread runs: no fork
    monkeypatch.setattr(threading, "active_count", lambda: 1)
    monkeypatch.setattr(dvcore.process, "os_thread_count", lambda: 3)
    assert not P.processes_usable(8, 2, min_items=8)  # a native pool's threads (OpenBLAS, OpenCV): no fork
    monkeypatch.setattr(dvcore.process, "os_thread_count", lambda: None)
    assert not P.processes_usable(8, 2, min_items=8)  # cannot tell: no fork
    monkeypatch.setattr(dvcore.process, "os_thread_count", lambda: 1)
    monkeypatch.setenv(P.NO_FORK_ENV, "1")
    assert not P.processes_usable(8, 2, min_items=8)


@linux_only
def test_the_rules_decide_before_the_progress_bar(monkeypatch):
    """Decided by the rules (``processes=None``), before the bar exists (its thread would forbid
    the fork); where they allow it the workers are forked, also before the bar."""
    calls = []
    monkeypatch.setattr(P, "processes_usable", lambda n, w, min_items: calls.append("decided") or True)
    before: set = set()

    def bar(n):
        # the children forked by this call (an earlier pool's workers may still be exiting)
        calls.append(("bar", n, len({c.pid for c in multiprocessing.active_children()} - before)))
        return None

    before = {c.pid for c in multiprocessing.active_children()}
    out = list(P.map_in_order(_square_and_pid, range(10), 2, progress=bar))
    assert calls == ["decided", ("bar", 10, 2)]
    assert os.getpid() not in {pid for _, pid in out}
    calls.clear()
    monkeypatch.setattr(P, "processes_usable", lambda n, w, min_items: calls.append("decided") and False)
    before = {c.pid for c in multiprocessing.active_children()}
    out = list(P.map_in_order(_square_and_pid, range(10), 2, progress=bar))
    assert calls == ["decided", ("bar", 10, 0)] and {pid for _, pid in out} == {os.getpid()}


class _Bar:
    def __init__(self, n):
        self.n, self.count, self.closed = n, 0, False

    def update(self):
        self.count += 1

    def close(self):
        self.closed = True


@pytest.mark.parametrize("processes", [False, pytest.param(True, marks=linux_only)])
def test_the_bar_counts_every_result_and_is_closed(processes):
    bars = []
    list(P.map_in_order(abs, range(-9, 9), 2, processes=processes, progress=lambda n: bars.append(_Bar(n)) or bars[-1]))
    assert [(b.n, b.count, b.closed) for b in bars] == [(18, 18, True)]


def _warning_at(x):
    if x % 5 == 0:
        warnings.warn(f"item {x}", UserWarning)
    return x


@linux_only
def test_a_workers_warnings_are_given_here_in_order():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert list(P.map_in_order(_warning_at, range(23), 2, processes=True, max_chunk=3)) == list(range(23))
    assert [str(w.message) for w in caught] == [f"item {x}" for x in range(0, 23, 5)]
    relayed = []
    list(P.map_in_order(_warning_at, range(23), 2, processes=True, max_chunk=3, relay=relayed.extend))
    assert relayed == [(UserWarning, f"item {x}") for x in range(0, 23, 5)]


@linux_only
def test_an_error_in_a_worker_reaches_the_caller():
    def fn(x):
        if x == 13:
            raise ValueError(f"bad item {x}")
        return x

    with pytest.raises(ValueError, match="bad item 13"):
        list(P.map_in_order(fn, range(40), 2, processes=True))
    assert _no_children_left()


@linux_only
@pytest.mark.parametrize("threads", [True, False])
def test_a_dead_worker_falls_back(threads):
    """A worker process that dies at item 10 breaks the pool; the items not yet returned are
    computed here (on threads, or one after the other), with a warning that says how; the results
    are complete and the same."""
    parent = os.getpid()

    def fn(x):
        if x == 10 and os.getpid() != parent:
            os._exit(3)
        return x * 3

    with pytest.warns(P.WorkerProcessDied, match="a worker process died") as rec:
        out = list(P.map_in_order(fn, range(30), 2, processes=True, threads=threads, max_chunk=2,
                                  label="folder", unit="shot"))
    assert out == [x * 3 for x in range(30)]
    message = str(rec[0].message)
    assert message.startswith("folder: ") and "shot(s)" in message
    assert message.endswith("with threads" if threads else "here")
    assert not issubclass(rec[0].category, P.WorkerProcessStalled)
    assert _no_children_left()


def _running(pid):
    """Whether process ``pid`` still runs (a zombie is dead, waiting to be reaped)."""
    try:
        state = Path(f"/proc/{pid}/status").read_text().split("State:")[1].split()[0]
    except (FileNotFoundError, IndexError):
        return False
    return state not in ("Z", "X")


def _gone(pids):
    for _ in range(250):  # polled: a signal's effect is soon, not at once
        if not any(_running(p) for p in pids):
            return True
        threading.Event().wait(0.02)
    return False


@linux_only
def test_stopping_early_ends_the_workers_without_waiting(tmp_path):
    """A caller that stops early: the workers are ended, not waited for. The chunks in flight
    would each take 20 s and then leave a file; when ``close()`` returns, the workers are gone
    and no chunk in flight has finished."""
    parent = os.getpid()

    def fn(x):
        if x >= 4 and os.getpid() != parent:
            threading.Event().wait(20)
            (tmp_path / f"finished-{x}").touch()
        return x

    gen = P.map_in_order(fn, range(40), 2, processes=True, max_chunk=2)
    assert [next(gen) for _ in range(3)] == [0, 1, 2]
    kids = [k.pid for k in multiprocessing.active_children()]
    assert len(kids) == 2
    gen.close()
    assert _gone(kids)
    assert not list(tmp_path.iterdir())


_HELD_AT_FORK = """
import json, os, sys, threading, warnings
sys.path.insert(0, {root!r})
import dvcore.parallel as P
os.environ[P.STALL_ENV] = "0.5"
held = threading.Lock()

def fn(x):  # like cv2.findContours waiting on its pool's mutex
    with held:
        return x * x

def bar_after_the_fork(n):  # the holder lets go, in this process only
    held.release()
    return None

held.acquire()  # held at the instant of the fork: every child inherits it locked, with no owner
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    out = list(P.map_in_order(fn, range(50), 2, processes=True, progress=bar_after_the_fork, label="seq", unit="frame"))
import multiprocessing
print(json.dumps({{"same": out == [x * x for x in range(50)],
                  "warnings": [(w.category.__name__, str(w.message)) for w in caught],
                  "children_left": len(multiprocessing.active_children())}}))
"""


@linux_only
def test_a_lock_held_at_the_fork_is_caught_and_the_items_computed(tmp_path):
    """The issue-29 race provoked on purpose: a lock is held at the instant the workers are
    forked, and every item needs it. Each child waits for ever (no CPU used); the watchdog sees it
    within its stall time (0.5 s here), kills the workers and computes every item with threads,
    with a `WorkerProcessStalled` warning. In a process of its own with a time limit: without the
    watchdog it would hang."""
    script = tmp_path / "held.py"
    script.write_text(_HELD_AT_FORK.format(root=str(ROOT)))
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr[-2000:]
    seen = json.loads(r.stdout.strip().splitlines()[-1])
    assert seen["same"]
    stalls = [m for c, m in seen["warnings"] if c == "WorkerProcessStalled"]
    assert len(stalls) == 1 and stalls[0].startswith("seq: the worker processes stalled"), seen["warnings"]
    assert "remaining 50 frame(s) with threads" in stalls[0]
    assert seen["children_left"] == 0


_KILLED_PARENT = """
import multiprocessing, os, sys, threading
sys.path.insert(0, {root!r})
import dvcore.parallel as P

def fn(x):
    threading.Event().wait(0.01)
    return x

for k, x in enumerate(P.map_in_order(fn, range(100000), 2, processes=True, max_chunk=2)):
    if k == 0:
        print(" ".join(str(p.pid) for p in multiprocessing.active_children()), flush=True)
"""


@linux_only
def test_workers_die_with_a_killed_parent(tmp_path):
    """kill -9 of the calling process: its forked workers do not go on (the kernel kills them,
    PR_SET_PDEATHSIG, `dvcore.process.die_with_parent`)."""
    script = tmp_path / "parent.py"
    script.write_text(_KILLED_PARENT.format(root=str(ROOT)))
    p = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        kids = [int(k) for k in p.stdout.readline().split()]
    finally:
        p.send_signal(signal.SIGKILL)
        p.wait()
        p.stdout.close()
    assert len(kids) == 2
    assert _gone(kids)


@linux_only
def test_the_watchdog_bounds_a_wait_on_a_blocked_process():
    """A result awaited from a process that uses no CPU (here: `sleep`) raises after the stall
    time instead of waiting; a done result is returned."""
    from concurrent.futures import Future

    from dvcore.process import WorkersStalled

    sleeper = subprocess.Popen(["sleep", "30"])
    try:
        with pytest.raises(WorkersStalled, match="no CPU"):
            P.Watchdog([sleeper.pid], stall_s=0.5, poll_s=0.05).result(Future())
    finally:
        sleeper.kill()
        sleeper.wait()
    done = Future()
    done.set_result(7)
    assert P.Watchdog([sleeper.pid], stall_s=0.5).result(done) == 7


def test_stall_time_from_the_environment(monkeypatch):
    monkeypatch.setenv(P.STALL_ENV, "2.5")
    assert P.stall_seconds() == 2.5
    for bad in ("x", "-1", "0"):
        monkeypatch.setenv(P.STALL_ENV, bad)
        assert P.stall_seconds() == P.STALL_S


def test_serial_native_pools_holds_opencv_on_the_calling_thread():
    """Inside, OpenCV runs on the calling thread (its pool never starts); its count is given back
    after (setting a count starts no thread)."""
    import cv2

    before = cv2.getNumThreads()
    try:
        cv2.setNumThreads(3)
        with P.serial_native_pools():
            assert cv2.getNumThreads() == 1  # 0 asked: OpenCV reports one, the calling thread
        assert cv2.getNumThreads() == 3
        with P.serial_native_pools(False):
            assert cv2.getNumThreads() == 3
    finally:
        cv2.setNumThreads(before)
