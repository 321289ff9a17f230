"""Shot folders in `dropvision campaign` and `dropvision watch` (issue 30 item 5): the same rows as
`dropvision measure` of the folder gives, resumable, failures reported; a drop watcher's exports
measured as they land.

Synthetic shots: frames of one small synthetic sequence copied under drop-watcher names (no delay in the
names), in two shot folders; one synthetic sequence beside them.
"""

from __future__ import annotations

import json
import shutil
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from dropvision.app.campaign import find_inputs, run_campaign
from dropvision.app.cli import main
from dropvision.analysis.shots import measure_shots
from dropvision.synth import SynthConfig, write_synthetic_sequence
from dvcore import schema

#: seconds per test (fitted models, campaigns, subprocesses): left out of `make test-fast`
pytestmark = pytest.mark.slow

SMALL = dict(width_px=128, height_px=448, tip_row=30.3, axis_col=63.6, noise=0.3)
PIXEL = {"pixel_size_um": 4.73}


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    """(frames of a synthetic sequence, a synthetic sequence with a waveform) rendered once."""
    base = tmp_path_factory.mktemp("sources")
    shots = write_synthetic_sequence(SynthConfig(**SMALL, delays_us=(1150.0, 1250.0, 1400.0), u1_um_per_ms=75.0),
                                     base / "frames", progress=False)
    seq = write_synthetic_sequence(SynthConfig(**SMALL, delays_us=tuple(float(d) for d in range(0, 1501, 100))),
                                   base / "seq", progress=False)
    frames = [shots / f["file"] for f in json.loads((shots / "sequence.json").read_text())["frames"]]
    return frames, seq


def _shot_folder(folder: Path, frames: list[Path], volts: list[int]) -> Path:
    """A drop watcher's exports: one image per shot, its setting in the name, no delay."""
    folder.mkdir(parents=True)
    for frame, v in zip(frames, volts):
        shutil.copy(frame, folder / f"images_V1-{v}_w1-{v // 10}.png")
    (folder / "sequence.json").write_text(json.dumps(PIXEL))  # the rig's settings, no frames list
    return folder


@pytest.fixture
def root(sources, tmp_path):
    frames, seq = sources
    root = tmp_path / "root"
    _shot_folder(root / "rig_a", frames, [80, 85, 90])
    _shot_folder(root / "rig_b" / "day2", frames[:2], [95, 100])
    shutil.copytree(seq, root / "seq1")
    return root


def _rows(table: pd.DataFrame) -> pd.DataFrame:
    return table.drop(columns="shot_folder").reset_index(drop=True)


def test_campaign_of_shot_folders_and_a_sequence(root, tmp_path, capsys):
    assert [(f.relative_to(root).as_posix(), k) for f, k in find_inputs(root)] == [
        ("rig_a", "shots"), ("rig_b/day2", "shots"), ("seq1", "sequence")]
    ds = tmp_path / "ds"
    assert main(["campaign", str(root), "--out", str(ds), "--workers", "1"]) == 0
    assert capsys.readouterr().out.strip() == (f"campaign: 3 measured, 0 unchanged (skipped), 0 failed -> {ds}; "
                                               "shots.parquet: 5 rows from 2 shot folder(s)")
    shots = pd.read_parquet(ds / "shots.parquet")
    schema.check_table(shots, schema.DATASET_SHOTS, ds / "shots.parquet")
    assert list(shots.columns) == schema.DATASET_SHOTS.column_names + ["V1", "w1"]
    assert list(shots["shot_folder"]) == ["rig_a"] * 3 + ["rig_b/day2"] * 2
    assert list(shots["V1"]) == [80.0, 85.0, 90.0, 95.0, 100.0] and list(shots["w1"]) == [8.0, 8.0, 9.0, 9.0, 10.0]
    assert shots["drop_volume_nl"].notna().sum() >= 3  # the in-flight frames give a main drop
    # each folder's rows are what `dropvision measure` of that folder gives
    for sid in ("rig_a", "rig_b/day2"):
        out = tmp_path / "measured" / sid
        assert main(["measure", str(root / sid), "--out", str(out), "-q"]) == 0
        alone = pd.read_parquet(out / "shots.parquet")
        pd.testing.assert_frame_equal(_rows(shots[shots["shot_folder"] == sid]), alone, check_dtype=False)
    # the sequence's dataset is as before, and dataset.json lists the shot folders
    summary = pd.read_parquet(ds / "summary.parquet")
    assert list(summary["sequence_id"]) == ["seq1"] and summary["inflight_volume_nl"].notna().all()
    meta = json.loads((ds / "dataset.json").read_text())
    schema.check_document(meta, schema.DATASET, ds / "dataset.json")
    assert meta["shot_folders"] == ["rig_a", "rig_b/day2"] and meta["n_shots"] == 5 and meta["sequences"] == ["seq1"]
    manifest = json.loads((ds / "manifest.json").read_text())
    assert [e.get("kind") for _, e in sorted(manifest["sequences"].items())] == ["shots", "shots", None]
    assert {e["status"] for e in manifest["sequences"].values()} == {"ok"}


def test_shot_folders_resume_and_report_failures(root, tmp_path):
    ds = tmp_path / "ds"
    first = run_campaign(root, ds, workers=1, progress=False)
    assert sorted(first.measured) == ["rig_a", "rig_b/day2", "seq1"]
    # unchanged: skipped; a sub-folder added below a shot folder does not change the folder's own inputs
    nested = shutil.copytree(root / "rig_b" / "day2", root / "rig_a" / "later")
    again = run_campaign(root, ds, workers=1, progress=False)
    assert again.measured == ["rig_a/later"] and sorted(again.skipped) == ["rig_a", "rig_b/day2", "seq1"]
    assert list(pd.read_parquet(ds / "shots.parquet")["shot_folder"].unique()) == ["rig_a", "rig_a/later",
                                                                                 "rig_b/day2"]
    # a changed image: that folder measured again
    shutil.copy(nested / sorted(p.name for p in nested.glob("*.png"))[0], root / "rig_a" / "images_V1-80_w1-8.png")
    third = run_campaign(root, ds, workers=1, progress=False)
    assert third.measured == ["rig_a"] and len(third.skipped) == 3
    # a shot folder whose labels contradict each other fails alone, named in the manifest
    (nested / "shots.csv").write_text("file,V1\nimages_V1-95_w1-9.png,7\n")
    res = run_campaign(root, ds, workers=2, progress=False)
    assert list(res.failed) == ["rig_a/later"] and "label V1 is 95 by the file name but 7" in res.failed["rig_a/later"]
    assert json.loads((ds / "manifest.json").read_text())["sequences"]["rig_a/later"]["status"] == "failed"
    assert "rig_a/later" not in set(pd.read_parquet(ds / "shots.parquet")["shot_folder"])


def test_a_campaign_whose_shot_folders_all_fail_exits_2(sources, tmp_path, capsys):
    frames, _ = sources
    root = tmp_path / "root"
    for name in ("a", "b"):
        folder = _shot_folder(root / name, frames[:2], [80, 85])
        for image in folder.glob("*.png"):
            image.write_bytes(b"not an image")
    assert main(["campaign", str(root), "--out", str(tmp_path / "ds"), "--workers", "1", "-q"]) == 2
    err = capsys.readouterr().err
    assert "all 2 sequences failed, no dataset written" in err and "no shot could be measured" in err
    manifest = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    assert {e["status"] for e in manifest["sequences"].values()} == {"failed"}
    assert not (tmp_path / "ds" / "shots.parquet").exists()


# ----------------------------------------------------------------------------- watch
def _export(folder: Path, frames: list[Path], volts: list[int], out: Path, tables: list) -> None:
    """A drop watcher exporting one image per shot (each in two writes), the rig's settings first; after
    each image, the live shots table once its row is on disk."""
    from dropvision.app.live_journal import read_journal

    (folder / "sequence.json").write_text(json.dumps(PIXEL))
    for k, (frame, v) in enumerate(zip(frames, volts), start=1):
        data = frame.read_bytes()
        with open(folder / f"images_V1-{v}_w1-{v // 10}.png", "wb") as fh:
            fh.write(data[: len(data) // 2])
            fh.flush()
            time.sleep(0.02)
            fh.write(data[len(data) // 2:])
        end = time.monotonic() + 30
        while len(read_journal(out)) < k and time.monotonic() < end:
            time.sleep(0.01)
        tables.append(pd.read_parquet(out / "shots.parquet"))


def test_watch_measures_each_shot_as_it_lands(sources, tmp_path, capsys):
    from dropvision.app.live_journal import JOURNAL, journal_table
    from dropvision.app.watch import WATCH_JSON, WatchOptions, watch_sequence

    frames, _ = sources
    watched, out = tmp_path / "watched", tmp_path / "out"
    watched.mkdir()
    tables: list = []
    writer = threading.Thread(target=_export, args=(watched, frames, [80, 85, 90], out, tables))
    writer.start()
    try:
        res = watch_sequence(watched, out, WatchOptions(frames=3, idle_s=30.0))
    finally:
        writer.join()
    assert res.kind == "shots" and res.ended_by == "frames" and res.n_live == 3 and not res.left_out
    # the live table grew by one row per image, with the columns `dropvision measure` gives
    assert [len(t) for t in tables] == [1, 2, 3]
    assert all(list(t.columns) == schema.SHOTS.column_names + ["V1", "w1"] for t in tables)
    assert list(tables[-1]["V1"]) == [80.0, 85.0, 90.0]
    schema.check_table(journal_table(out), schema.LIVE_FRAMES, out / JOURNAL)
    watch_doc = json.loads((out / WATCH_JSON).read_text())
    schema.check_document(watch_doc, schema.WATCH, out / WATCH_JSON)
    assert watch_doc["kind"] == "shots" and watch_doc["state"] == "finished"
    # the final tables are `dropvision measure` of the same folder; the live rows the same values
    assert main(["measure", str(watched), "--out", str(tmp_path / "batch"), "-q"]) == 0
    batch = pd.read_parquet(tmp_path / "batch" / "shots.parquet")
    pd.testing.assert_frame_equal(pd.read_parquet(out / "shots.parquet"), batch)
    pd.testing.assert_frame_equal(pd.read_parquet(out / "frames.parquet"), pd.read_parquet(tmp_path / "batch" /
                                                                                           "frames.parquet"))
    assert json.loads((out / "summary.json").read_text()) == json.loads((tmp_path / "batch" / "summary.json").read_text())
    # the live rows are each image alone; the batch shares one calibration between the shots (its
    # answers within half their uncertainty of the solo ones, tests/analysis/test_shots_shared.py)
    live, final = tables[-1].set_index("file"), batch.set_index("file")
    pd.testing.assert_series_equal(live["quality"], final["quality"])
    for col in ("drop_volume_nl", "attached_volume_nl"):
        u = final[col.replace("_nl", "_uncertainty_nl")]
        assert np.isfinite(live[col]).all() and (np.abs(live[col] - final[col]) <= 0.5 * u).all(), (live[col], final[col])
    assert np.allclose(live["trajectory_angle_mrad"], final["trajectory_angle_mrad"], atol=0.5)
    assert sorted(p.name for p in watched.iterdir()) == sorted(["sequence.json", *batch["file"]])  # nothing written there
    # a second watch of the same folder resumes from the journal: nothing measured again, the same tables
    assert main(["watch", str(watched), "--out", str(out), "--idle-s", "0.3"]) == 0
    line = capsys.readouterr().out
    assert line.startswith("watched 3 shots (0 live, 3 from the journal; ended by idle)") and "measured 3 shots" in line
    pd.testing.assert_frame_equal(pd.read_parquet(out / "shots.parquet"), batch)


def test_watch_of_an_unreadable_shot_and_of_nothing(sources, tmp_path, capsys):
    from dropvision.app.watch import WatchOptions, watch_sequence

    frames, _ = sources
    watched = _shot_folder(tmp_path / "watched", frames[:2], [80, 85])
    (watched / "images_V1-99_w1-9.png").write_bytes(b"not an image")
    res = watch_sequence(watched, tmp_path / "out", WatchOptions(idle_s=0.5, unreadable_after_s=0.2))
    table = pd.read_parquet(tmp_path / "out" / "shots.parquet")
    assert res.kind == "shots" and list(table["V1"]) == [80.0, 85.0, 99.0]
    bad = table.set_index("file").loc["images_V1-99_w1-9.png"]
    assert bad["quality"] == schema.Quality.NOT_MEASURED and bad["notes"]
    # an empty folder: the watch ends by --idle-s with nothing measured, exit 2, no tables
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["watch", str(empty), "--out", str(tmp_path / "o2"), "--shots", "--idle-s", "0.2"]) == 2
    assert "no complete image arrived (the watch ended by idle)" in capsys.readouterr().err
    assert not (tmp_path / "o2" / "shots.parquet").exists() or len(pd.read_parquet(tmp_path / "o2" / "shots.parquet")) == 0


def test_what_a_watch_takes_a_folder_for(sources, tmp_path):
    """Decided by the first image, as `dropvision measure` decides: a delay in its name, a stack or a frame rate
    make a sequence; an image that tells no delay, shots."""
    from dropvision.app.watch import WatchOptions, _watch_kind

    frames, _ = sources
    opts = WatchOptions(idle_s=5.0)
    root = Path(__file__).resolve().parents[2]
    cases = {"images_V1-80.png": "shots", "f_0003_1250us.png": "sequence"}
    for name, kind in cases.items():
        folder = tmp_path / name
        folder.mkdir()
        shutil.copy(frames[0], folder / name)
        assert _watch_kind(folder, opts, None, None) == kind, name
        assert _watch_kind(folder, WatchOptions(overrides={"frame_rate_hz": 1e4}), None, None) == "sequence"
        assert _watch_kind(folder, WatchOptions(shots=True), None, None) == "shots"
    stack = tmp_path / "stack"
    stack.mkdir()
    shutil.copy(root / "sample_frames" / "satellite_dust_tiff16" / "stack.tif", stack / "stack.tif")
    assert _watch_kind(stack, opts, None, None) == "sequence"


def test_bench_watch_of_shots_runs(sources, tmp_path):
    """tools/bench_watch.py --shots DIR: a user can rerun the figure of the live watch of shots."""
    import os
    import subprocess
    import sys

    frames, _ = sources
    folder = _shot_folder(tmp_path / "shots", frames, [80, 85, 90])
    root = Path(__file__).resolve().parents[2]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")])))
    r = subprocess.run([sys.executable, str(root / "tools" / "bench_watch.py"), "--shots", str(folder), "--rate-hz",
                        "20"], capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "rows on disk: 3; completion to row on disk: median" in r.stdout
    assert "equal to dropvision measure: yes" in r.stdout
