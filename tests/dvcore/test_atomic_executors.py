"""Atomic writes and the executor factory."""

import json
import os

import pytest

from dvcore.atomic import atomic_dir, write_json, write_text
from dropvision.app.campaign import parse_range, shard_name
from dropvision.app.executors import SerialExecutor, make_executor


def _square(x):
    return x * x


def test_write_json_nan_is_null(tmp_path):
    p = write_json(tmp_path / "a" / "x.json", {"v": float("nan"), "w": 1.5})
    assert json.loads(p.read_text()) == {"v": None, "w": 1.5}
    assert [f.name for f in p.parent.iterdir()] == ["x.json"]


def test_atomic_dir_failure_leaves_old_result(tmp_path):
    final = tmp_path / "out"
    with atomic_dir(final) as tmp:
        write_text(tmp / "a.txt", "first")
    with pytest.raises(RuntimeError):
        with atomic_dir(final) as tmp:
            write_text(tmp / "a.txt", "second")
            raise RuntimeError("boom")
    assert (final / "a.txt").read_text() == "first"
    assert sorted(os.listdir(tmp_path)) == ["out"]
    with atomic_dir(final) as tmp:
        write_text(tmp / "b.txt", "third")
    assert sorted(os.listdir(final)) == [".dropvision-output.json", "b.txt"]  # ours, replaced as a whole
    assert sorted(os.listdir(tmp_path)) == ["out"]


def test_serial_executor_delivers_exceptions():
    ex = SerialExecutor()
    assert ex.submit(_square, 3).result() == 9
    fut = ex.submit(lambda: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        fut.result()


@pytest.mark.slow
def test_process_pool_and_bad_arguments():
    with make_executor(2) as ex:
        assert list(ex.map(_square, range(4))) == [0, 1, 4, 9]
    with pytest.raises(ValueError):
        with make_executor(0):
            pass
    with pytest.raises(ValueError):
        with make_executor(dask_local=1, scheduler="tcp://x:1"):
            pass


def test_parse_range_and_shard_names():
    assert parse_range("50:80:5", "--u1") == [50, 55, 60, 65, 70, 75, 80]
    assert parse_range("20:35:2.5", "--u2")[-1] == 35
    assert parse_range("1,2", "--u1") == [1, 2]
    with pytest.raises(ValueError, match="--u1"):
        parse_range("80:50:5", "--u1")
    assert shard_name("a/b") != shard_name("a_b")


def test_the_local_pool_forks_only_a_single_threaded_process(monkeypatch):
    """A process running other threads (a native pool's, a progress bar's) has its campaign workers
    forked by a fork server instead of forking itself (issue 29: a lock held at the fork)."""
    import sys

    import dvcore.process
    from dropvision.app.executors import _pool_context

    if not sys.platform.startswith("linux"):
        assert _pool_context() is None
        return
    monkeypatch.setattr(dvcore.process, "os_thread_count", lambda: 1)
    assert _pool_context().get_start_method() == "fork"
    monkeypatch.setattr(dvcore.process, "os_thread_count", lambda: 4)
    assert _pool_context().get_start_method() == "forkserver"
    with make_executor(2) as pool:  # and its workers run (their parent is the fork server)
        assert pool.submit(pow, 3, 4).result(timeout=120) == 81


@pytest.mark.slow
def test_a_stalled_campaign_worker_stops_the_campaign_with_a_bound(monkeypatch):
    """A local worker that uses no CPU (here asleep: as blocked on a lock) while its sequence is
    awaited: after the stall time the workers are killed and `CampaignStalled` names the sequence;
    never an endless wait."""
    import multiprocessing
    import time
    from concurrent.futures import ProcessPoolExecutor

    from dropvision.app.campaign import CampaignStalled, _wait_bounded
    from dvcore.process import STALL_ENV

    monkeypatch.setenv(STALL_ENV, "1")
    pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("forkserver"))
    try:
        assert pool.submit(pow, 2, 2).result(timeout=120) == 4  # started
        pending = {pool.submit(time.sleep, 60): "seq_07"}
        with pytest.raises(CampaignStalled, match="seq_07.*rerun"):
            _wait_bounded(pool, pending)
        procs = list(pool._processes.values()) if pool._processes else []
        assert all(not p.is_alive() for p in procs)
    finally:
        pool.shutdown(wait=False, cancel_futures=True)
