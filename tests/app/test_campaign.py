"""Campaigns: sequences -> dataset, identical serially, on a process pool and on Dask."""

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest

from dropvision.app.campaign import find_sequences, run_campaign, synth_campaign
from dropvision.app.cli import main as dropvision_main
from identify.dataset_checks import load_dataset

#: seconds per test (fitted models, campaigns, subprocesses): left out of `make test-fast`
pytestmark = pytest.mark.slow

SMALL = {"width_px": 128, "height_px": 448, "tip_row": 30.3, "axis_col": 63.6,
         "delays_us": tuple(float(d) for d in range(0, 1501, 10)), "noise": 0.3, "dust": 1}


@pytest.fixture(scope="module")
def campaign_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("campaign")
    synth_campaign(root / "grid", [60.0, 75.0], [22.5, 30.0], workers=1, progress=False, overrides=SMALL)
    return root / "grid"


def _read(ds):
    ts = pd.read_parquet(ds / "timeseries.parquet")
    su = pd.read_parquet(ds / "summary.parquet")
    meta = json.loads((ds / "dataset.json").read_text())
    meta.pop("versions")
    return ts, su, meta


def test_serial_processes_and_dask_give_identical_datasets(campaign_root, tmp_path):
    serial = run_campaign(campaign_root, tmp_path / "serial", workers=1, progress=False)
    assert len(serial.measured) == 4 and not serial.failed
    run_campaign(campaign_root, tmp_path / "pool", workers=2, progress=False)
    pytest.importorskip("dask.distributed")
    run_campaign(campaign_root, tmp_path / "dask", dask_local=2, progress=False)
    ref = _read(tmp_path / "serial")
    for other in ("pool", "dask"):
        got = _read(tmp_path / other)
        pd.testing.assert_frame_equal(ref[0], got[0])
        pd.testing.assert_frame_equal(ref[1], got[1])
        assert ref[2] == got[2]
    ts, su, meta = ref
    assert list(ts.columns) == ["sequence_id", "u1_um_per_ms", "u2_um", "delay_us", "grown_volume_nl",
                                "flow_velocity_m_s", "attached"]
    assert meta["nozzle_inner_diameter_um"] == 200.0 and meta["sample_interval_us"] == 10.0
    assert meta["nozzle"]["length_mm"] == 5.0
    # the dataset is what identify reads, and it matches each sequence's synthetic truth
    ds = load_dataset(tmp_path / "serial")
    assert len(ds.summary) == 4
    for row in su.itertuples():
        truth = json.loads((campaign_root / row.sequence_id / "truth.json").read_text())
        assert row.pinchoff_us == truth["pinchoff_us"]
        assert row.inflight_volume_nl == pytest.approx(truth["inflight_volume_nl"], rel=3e-3)
        assert row.jetting_velocity_m_s == pytest.approx(truth["jetting_velocity_m_s"], rel=5e-3)


def test_resume_skips_unchanged_and_remeasures_changed(campaign_root, tmp_path):
    root = tmp_path / "root"
    shutil.copytree(campaign_root, root)
    ds = tmp_path / "ds"
    first = run_campaign(root, ds, workers=1, progress=False)
    assert len(first.measured) == 4
    again = run_campaign(root, ds, workers=1, progress=False)
    assert again.measured == [] and len(again.skipped) == 4
    seq = sorted(find_sequences(root))[0]
    meta = json.loads((seq / "sequence.json").read_text())
    meta["comment"] = "edited"
    (seq / "sequence.json").write_text(json.dumps(meta))
    third = run_campaign(root, ds, workers=1, progress=False)
    assert third.measured == [seq.name] and len(third.skipped) == 3
    manifest = json.loads((ds / "manifest.json").read_text())
    assert {e["status"] for e in manifest["sequences"].values()} == {"ok"}
    assert not [p for p in ds.rglob("*") if p.name.endswith((".tmp", ".old"))]


def test_failed_sequence_is_recorded_and_does_not_stop_others(campaign_root, tmp_path):
    root = tmp_path / "root"
    shutil.copytree(campaign_root, root)
    bad = root / "broken"
    bad.mkdir()
    (bad / "sequence.json").write_text('{"frames": []}')
    ds = tmp_path / "ds"
    res = run_campaign(root, ds, workers=2, progress=False)
    assert len(res.measured) == 4 and list(res.failed) == ["broken"]
    assert "sequence.json" in res.failed["broken"] and "SequenceError" in res.failed["broken"]
    manifest = json.loads((ds / "manifest.json").read_text())
    assert manifest["sequences"]["broken"]["status"] == "failed"
    assert len(pd.read_parquet(ds / "summary.parquet")) == 4


def test_campaign_cli(campaign_root, tmp_path, capsys):
    assert dropvision_main(["campaign", str(campaign_root), "--out", str(tmp_path / "ds"), "--workers", "1"]) == 0
    assert "4 measured" in capsys.readouterr().out
    assert dropvision_main(["campaign", str(tmp_path / "nothing"), "--out", str(tmp_path / "x")]) == 2
    assert "campaign root is not a folder" in capsys.readouterr().err
    assert dropvision_main(["synth-campaign", str(tmp_path / "s"), "--u1", "80:50:5"]) == 2


def test_killed_run_loses_no_finished_sequence(campaign_root, tmp_path):
    """SIGKILL a campaign after its first finished sequence: no half-written shard, the
    finished sequence is kept and skipped on resume, the result equals an uninterrupted run."""
    import os
    import signal
    import subprocess
    import sys
    import time

    ds = tmp_path / "ds"
    cmd = [sys.executable, "-m", "dropvision.app.cli", "campaign", str(campaign_root), "--out", str(ds),
           "--workers", "1", "--no-progress"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and proc.poll() is None:
            try:
                m = json.loads((ds / "manifest.json").read_text())
            except (OSError, ValueError):
                m = {}
            if any(e.get("status") == "ok" for e in m.get("sequences", {}).values()):
                break
            time.sleep(0.02)
        killed = proc.poll() is None
        if killed:
            os.kill(proc.pid, signal.SIGKILL)
        proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
    manifest = json.loads((ds / "manifest.json").read_text())
    done = {k for k, e in manifest["sequences"].items() if e["status"] == "ok"}
    assert done
    for entry in manifest["sequences"].values():  # every visible shard is complete
        shard = ds / "shards" / entry["shard"]
        if shard.exists():
            assert (shard / "frames.parquet").exists() and (shard / "summary.json").exists()
    resumed = run_campaign(campaign_root, ds, workers=1, progress=False)
    assert set(resumed.skipped) == done and len(resumed.skipped) + len(resumed.measured) == 4
    assert not [p for p in ds.rglob(".*") if p.name.endswith((".tmp", ".old"))]
    fresh = run_campaign(campaign_root, tmp_path / "fresh", workers=1, progress=False)
    assert not fresh.failed
    for name in ("timeseries.parquet", "summary.parquet"):
        pd.testing.assert_frame_equal(pd.read_parquet(ds / name), pd.read_parquet(tmp_path / "fresh" / name))


def test_linked_sequence_folders_are_followed_but_links_out_of_a_sequence_are_not_read(campaign_root, tmp_path):
    from dropvision.app.campaign import input_hash, sequence_id

    real = sorted(p for p in campaign_root.iterdir() if p.is_dir())
    root = tmp_path / "assembled"
    root.mkdir()
    (root / "rig_a").symlink_to(real[0], target_is_directory=True)  # a campaign assembled from links
    (root / "loop").symlink_to(root, target_is_directory=True)      # and a link loop
    found = find_sequences(root)
    assert found == [root / "rig_a"] and sequence_id(root, found[0]) == "rig_a"
    res = run_campaign(root, tmp_path / "ds", workers=1, progress=False)
    assert res.measured == ["rig_a"] and not res.failed
    # a frame linked out of a sequence folder is neither measured nor read for the input hash
    seq = tmp_path / "seq"
    shutil.copytree(real[1], seq)
    outside = tmp_path / "outside.bin"
    outside.write_bytes(b"secret 1")
    (seq / "extra.png").symlink_to(outside)
    h1 = input_hash(seq)
    outside.write_bytes(b"secret 2")
    assert input_hash(seq) == h1


def test_run_stopped_by_an_error_keeps_every_finished_sequence_in_the_manifest(campaign_root, tmp_path,
                                                                               monkeypatch):
    import dropvision.app.campaign as campaign

    root = tmp_path / "root"
    shutil.copytree(campaign_root, root)
    ds = tmp_path / "ds"
    assert len(run_campaign(root, ds, workers=1, progress=False).measured) == 4
    seqs = sorted(find_sequences(root))
    for seq in seqs[:2]:  # the first two change and are measured again; the third cannot be read
        meta = json.loads((seq / "sequence.json").read_text())
        meta["comment"] = "edited"
        (seq / "sequence.json").write_text(json.dumps(meta))
    real_hash = campaign.input_hash

    def failing_hash(folder, config_repr=""):
        if folder.name == seqs[2].name:
            raise PermissionError(13, "Permission denied", str(folder))
        return real_hash(folder, config_repr)

    monkeypatch.setattr(campaign, "input_hash", failing_hash)
    with pytest.raises(PermissionError):
        run_campaign(root, ds, workers=2, progress=False)
    manifest = json.loads((ds / "manifest.json").read_text())["sequences"]
    assert len(manifest) == 4  # the sequences after the failure keep their earlier entries
    assert {e["status"] for e in manifest.values()} == {"ok"}  # the two re-measured ones were recorded


def test_client_overlaps_its_serial_work_with_the_tasks(campaign_root, tmp_path, monkeypatch):
    """Issue 22: the client hashes no new sequence and reads no new shard (the workers do),
    rewrites the manifest once per batch of finished sequences, reads no shard again at the
    end, and the dataset and manifest hashes equal the serial run's."""
    from dropvision.app import campaign

    serial = tmp_path / "serial"
    run_campaign(campaign_root, serial, workers=1, progress=False)
    hashed, parts, writes = [], [], []
    real_hash, real_part, real_write = campaign.input_hash, campaign.shard_part, campaign._write_manifest
    monkeypatch.setattr(campaign, "input_hash", lambda *a, **k: hashed.append(a) or real_hash(*a, **k))
    monkeypatch.setattr(campaign, "shard_part", lambda *a, **k: parts.append(a[1]) or real_part(*a, **k))
    monkeypatch.setattr(campaign, "_write_manifest",
                        lambda w, d: writes.append(w.path.name) or real_write(w, d))
    res = run_campaign(campaign_root, tmp_path / "pool", workers=2, progress=False)
    assert len(res.measured) == 4 and not res.failed
    assert hashed == [] and parts == []  # the pool's workers hashed and read their shards back
                                         # (they do not see this process's patches)
    # start, all submitted, one per batch (1 to 4 batches), the end
    assert 4 <= writes.count("manifest.json") <= 7
    for name in ("timeseries.parquet", "summary.parquet"):
        pd.testing.assert_frame_equal(pd.read_parquet(serial / name), pd.read_parquet(tmp_path / "pool" / name))
    a = json.loads((serial / "manifest.json").read_text())["sequences"]
    b = json.loads((tmp_path / "pool" / "manifest.json").read_text())["sequences"]
    assert {k: e["input_hash"] for k, e in a.items()} == {k: e["input_hash"] for k, e in b.items()}
    assert all(len(e["input_hash"]) == 64 for e in b.values())
    # a resumed run hashes each sequence once in the client (to know whether to skip it) and
    # reads each skipped shard once
    hashed.clear(), parts.clear()
    again = run_campaign(campaign_root, tmp_path / "pool", workers=2, progress=False)
    assert len(again.skipped) == 4 and len(hashed) == 4 and sorted(parts) == sorted(again.skipped)


def test_manifest_writer_gives_the_text_of_write_json(tmp_path):
    """The manifest, rewritten from cached per-entry pieces, is byte for byte what write_json
    writes, after entries change, are added, hold NaN, nested values or odd keys."""
    from dropvision.app.campaign import ManifestWriter
    from dvcore.atomic import to_json

    entries = {}
    manifest = {"schema": "x/1", "root": "/r", "versions": {"a": "1", "b": [1, 2]}, "sequences": entries}
    writer = ManifestWriter(tmp_path / "manifest.json")
    steps = [lambda: None,
             lambda: entries.update({"a": {"status": "pending", "input_hash": None, "meta": None}}),
             lambda: entries["a"].update(status="ok", meta={"waveform": {"u1": 1.5, "n": [1, {"x": None}]},
                                                            "v": float("nan")}),
             lambda: entries.update({'b"\\n\u00e9': {"status": "failed", "error": "line\nbreak", "e": {}}}),
             lambda: entries["b\"\\n\u00e9"].update(status="ok"),
             lambda: entries.pop("a")]
    for step in steps:
        step()
        writer.write(manifest)
        assert (tmp_path / "manifest.json").read_text() == to_json(manifest)
    assert json.loads((tmp_path / "manifest.json").read_text())["sequences"]
