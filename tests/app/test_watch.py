"""`dropvision watch`: frames measured as a drop watcher writes them, final tables equal to a batch
`measure_sequence` of the same folder, nothing lost on SIGKILL, a restart completes the sequence.

A synthetic sequence is rendered once, then replayed into a watched folder frame by frame
(`dropvision.app.replay.replay_sequence`: sequence.json first, each frame in two writes with a
pause, so the watcher can meet it half-written).
"""

from __future__ import annotations

import json
import os
import signal
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import pandas as pd
import pytest

from dropvision.app.cli import main
from dropvision.app.live_journal import JOURNAL, journal_table, read_journal
from dropvision.app.replay import replay_sequence
from dropvision.app.watch import WATCH_JSON, WatchOptions, watch_sequence
from dropvision.measurement import measure_sequence
from dropvision.io.sequence import open_sequence
from dvcore import schema
from dvcore.atomic import MARKER, to_json

DELAYS_US = tuple(float(d) for d in range(0, 1401, 70))  # 21 frames: meniscus, growth, pinch-off, flight


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    from dropvision.synth import SynthConfig, write_synthetic_sequence

    cfg = SynthConfig(width_px=160, height_px=400, tip_row=40.4, axis_col=79.6, delays_us=DELAYS_US, seed=2)
    return write_synthetic_sequence(cfg, tmp_path_factory.mktemp("w") / "src", progress=False)


def _frame_names(src: Path) -> list[str]:
    return [f["file"] for f in json.loads((src / "sequence.json").read_text())["frames"]]


def _assert_same(out: Path, batch) -> None:
    """The tables on disk equal the batch measurement's."""
    pd.testing.assert_frame_equal(pd.read_parquet(out / "frames.parquet"), batch.frames)
    pd.testing.assert_frame_equal(pd.read_parquet(out / "bodies.parquet"), batch.bodies)
    assert json.loads((out / "summary.json").read_text()) == json.loads(to_json(batch.summary))


def _wait_rows(out: Path, n: int, proc: subprocess.Popen | None = None, timeout_s: float = 20.0) -> None:
    end = time.monotonic() + timeout_s
    while len(read_journal(out)) < n:
        assert proc is None or proc.poll() is None, proc.communicate()
        assert time.monotonic() < end, f"{n} rows not on disk after {timeout_s} s"
        time.sleep(0.01)


def _start_cli(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "dropvision.app.cli", "watch", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.slow
def test_live_rows_and_final_tables_equal_batch(rendered, tmp_path):
    watched, out = tmp_path / "watched", tmp_path / "out"
    watched.mkdir()
    completed: dict[str, float] = {}
    writer = threading.Thread(target=lambda: completed.update(replay_sequence(rendered, watched, rate_hz=20.0)))
    writer.start()
    try:
        res = watch_sequence(watched, out, WatchOptions(idle_s=20.0))
    finally:
        writer.join()
    assert res.ended_by == "frames"  # sequence.json lists 21 frames: the end, without waiting for --idle-s
    names = _frame_names(rendered)
    rows = read_journal(out)
    assert sorted(r["file"] for r in rows) == sorted(names) and res.n_live == len(names)
    assert list(rows[0]) == schema.LIVE_FRAMES.column_names
    schema.check_table(journal_table(out), schema.LIVE_FRAMES, out / JOURNAL)
    schema.check_document(json.loads((out / WATCH_JSON).read_text()), schema.WATCH, out / WATCH_JSON)
    # completion (the writer closed the file) to the row on disk
    latency_ms = [(r["row_unix_s"] - completed[r["file"]]) * 1e3 for r in rows]
    print(f"\nwatch: {len(rows)} frames at 20 frames/s, completion to row on disk: median "
          f"{statistics.median(latency_ms):.1f} ms, max {max(latency_ms):.1f} ms")
    assert statistics.median(latency_ms) < 500.0
    assert rows[0]["row_unix_s"] < completed[names[-1]]  # measured while the sequence was being written
    # nothing written into the watched folder: exactly what the writer put there
    assert sorted(p.name for p in watched.iterdir()) == sorted(["sequence.json", *names])
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()) == [
        MARKER, "bodies.parquet", "frames.parquet", JOURNAL, WATCH_JSON, "per_delay.parquet", "summary.json"]
    batch = measure_sequence(watched)
    pd.testing.assert_frame_equal(res.result.frames, batch.frames)
    _assert_same(out, batch)
    assert json.loads((out / WATCH_JSON).read_text())["ended_by"] == "frames"


def test_sigkill_keeps_rows_and_restart_completes(rendered, tmp_path, capsys):
    watched, out = tmp_path / "watched", tmp_path / "out"
    names = _frame_names(rendered)
    half = len(names) // 2
    proc = _start_cli(str(watched.mkdir() or watched), "--out", str(out))
    try:
        _wait_rows(out, 0, proc)
        while not (out / JOURNAL).exists():
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.01)
        replay_sequence(rendered, watched, rate_hz=40.0, stop_after=half)
        _wait_rows(out, half, proc)
    finally:
        proc.kill()  # SIGKILL
        proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    rows = read_journal(out)
    assert sorted(r["file"] for r in rows) == sorted(names[:half])
    assert not (out / "frames.parquet").exists()
    # a cut last line (what only a power loss could leave) is dropped on resume
    with open(out / JOURNAL, "ab") as fh:
        fh.write(b'{"file": "f_00')
    for name in names[half:]:  # the rest of the sequence, written while nothing watched
        (watched / name).write_bytes((rendered / name).read_bytes())
    (watched / "zz_extra.png").write_bytes((rendered / names[0]).read_bytes())  # not in sequence.json: no frame
    assert main(["watch", str(watched), "--out", str(out), "--idle-s", "20"]) == 0
    assert f"({len(names) - half} live, {half} from the journal; ended by frames)" in capsys.readouterr().out
    rows = read_journal(out)
    assert sorted(r["file"] for r in rows) == sorted(names)  # every frame once: none measured twice
    assert (out / JOURNAL).read_bytes().endswith(b"\n")
    _assert_same(out, measure_sequence(watched))


def test_interrupt_writes_final_tables_of_the_frames_so_far(rendered, tmp_path):
    watched, out = tmp_path / "watched", tmp_path / "out"
    watched.mkdir()
    names = _frame_names(rendered)
    proc = _start_cli(str(watched), "--out", str(out), "--idle-s", "30")
    try:
        replay_sequence(rendered, watched, rate_hz=50.0, stop_after=8)
        _wait_rows(out, 8, proc)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, stderr
    assert "ended by interrupt" in stdout and "watched 8 of 8 frames" in stdout
    _assert_same(out, measure_sequence(open_sequence(watched, only_files=names[:8])))


def test_frames_renamed_into_place(rendered, tmp_path):
    """A writer that writes each frame under a temporary name and renames it into place."""
    watched, out = tmp_path / "watched", tmp_path / "out"
    watched.mkdir()
    names = _frame_names(rendered)[:6]

    def write():
        (watched / "sequence.json").write_bytes((rendered / "sequence.json").read_bytes())
        for name in names:
            (watched / f".{name}.part").write_bytes((rendered / name).read_bytes())
            os.replace(watched / f".{name}.part", watched / name)
            time.sleep(0.02)

    writer = threading.Thread(target=write)
    writer.start()
    try:
        res = watch_sequence(watched, out, WatchOptions(frames=6, idle_s=20.0))
    finally:
        writer.join()
    assert res.ended_by == "frames" and sorted(r["file"] for r in read_journal(out)) == sorted(names)
    _assert_same(out, measure_sequence(open_sequence(watched, only_files=names)))


def test_idle_end_and_frames_already_there(rendered, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["watch", str(rendered), "--out", str(out), "--frames", "100", "--idle-s", "0.3", "-q"]) == 0
    assert json.loads((out / WATCH_JSON).read_text())["ended_by"] == "idle"
    _assert_same(out, measure_sequence(rendered))


def test_refuses_outputs_it_does_not_own(rendered, tmp_path, capsys):
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "notes.txt").write_text("mine")
    assert main(["watch", str(rendered), "--out", str(theirs), "--idle-s", "0.1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("dropvision watch: error:") and "notes.txt" in err and len(err.splitlines()) == 1
    assert sorted(p.name for p in theirs.iterdir()) == ["notes.txt"]
    assert main(["watch", str(rendered), "--out", str(rendered / "out"), "--idle-s", "0.1"]) == 2
    assert "inside the input" in capsys.readouterr().err
    assert not (rendered / "out").exists()
    assert main(["watch", str(tmp_path / "none"), "--out", str(tmp_path / "o")]) == 2
    assert "no such folder" in capsys.readouterr().err


@pytest.mark.slow
def test_sequences_one_after_the_other(rendered, tmp_path, capsys):
    """--sequences: a sub-folder per sequence; each ends when the next one appears (or idle)."""
    root, out = tmp_path / "root", tmp_path / "out"
    root.mkdir()
    meta = json.loads((rendered / "sequence.json").read_text())
    del meta["frames"]  # delays from the file names: a batch measure of the folder as it is then
    names = _frame_names(rendered)

    def write():
        for seq, picked in (("seq_a", names[:5]), ("seq_b", names[5:10])):
            (root / seq).mkdir()
            (root / seq / "sequence.json").write_text(json.dumps(meta))
            for name in picked:
                (root / seq / name).write_bytes((rendered / name).read_bytes())
                time.sleep(0.03)
            time.sleep(0.3)

    writer = threading.Thread(target=write)
    writer.start()
    try:
        assert main(["watch", str(root), "--out", str(out), "--sequences", "--idle-s", "1.5"]) == 0
    finally:
        writer.join()
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0] for line in lines] == ["seq_a", "seq_b"]
    assert "watched 5 of 5 frames (5 live, 0 from the journal; ended by next sequence)" in lines[0]
    assert "watched 5 of 5 frames (5 live, 0 from the journal; ended by idle)" in lines[1]
    for seq in ("seq_a", "seq_b"):
        _assert_same(out / seq, measure_sequence(root / seq))
    assert sorted(p.name for p in root.iterdir()) == ["seq_a", "seq_b"]  # nothing written there


def test_live_row_of_an_undecodable_frame_says_so_in_its_quality():
    from dropvision.app.live_journal import live_row
    from dropvision.frame.measure_frame import FrameRecord

    bad = live_row(FrameRecord(3, "f_00150us.png", None, 150.0, 0, error="f_00150us.png: cannot decode PNG"), 4)
    assert bad["quality"] == schema.Quality.UNREADABLE and bad["error"]
    assert schema.Quality.UNREADABLE in schema.QUALITY_CODES
    good = live_row(FrameRecord(3, "f_00150us.png", None, 150.0, 0), 4)
    assert good["quality"] == "ok" and good["error"] is None


def test_a_fifo_named_like_a_frame_is_never_opened(rendered, tmp_path, capsys):
    import shutil

    src = Path(shutil.copytree(rendered, tmp_path / "src"))
    os.mkfifo(src / "f_99999us.png")  # not in the frames list; opening it would wait for a writer forever
    out = tmp_path / "out"
    assert main(["watch", str(src), "--out", str(out), "--frames", "100", "--idle-s", "0.3", "-q"]) == 0
    assert json.loads((out / WATCH_JSON).read_text())["left_out"] == []
    assert len(read_journal(out)) == len(_frame_names(src))
