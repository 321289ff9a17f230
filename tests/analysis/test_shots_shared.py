"""Shots of one rig share one calibration and are measured in parallel (issue 30 item 4,
`dropvision.analysis.shot_rig`).

Synthetic shots: frames of two synthetic waveforms of one rig (same holder, background and noise model;
truth per frame in truth_frames.csv), renamed as a drop watcher names its exports. The shared answers
are pinned to the solo ones (each image measured alone) and to the synthetic truth.
"""

from __future__ import annotations

import dataclasses
import json
import pickle
import shutil

import cv2
import numpy as np
import pandas as pd
import pytest

import dvcore.parallel as engine
import dropvision.analysis.shot_rig as shot_rig
from dropvision.analysis.shot_rig import disagreement, fingerprint
from dropvision.analysis.shots import measure_shots
from dropvision.synth import SynthConfig, write_synthetic_sequence

SMALL = dict(width_px=128, height_px=448, tip_row=30.3, axis_col=63.6, delays_us=(1250.0, 1400.0), noise=0.3)
WAVES = ((7, 70.0, 30.0), (8, 80.0, -20.0))
PIXEL = {"pixel_size_um": 4.73}
#: Shared against solo: the volumes agree within this fraction of their stated uncertainty (the
#: background of several shots and the sharpest body of all of them as the blur reference, against
#: one shot's own).
TOLERANCE_U = 0.5


@pytest.fixture(scope="module")
def rig_shots(tmp_path_factory):
    """Four synthetic shots of one rig, ``images_V-<u1>_w--<k>.png``, and their truth rows."""
    root = tmp_path_factory.mktemp("rig")
    folder = root / "shots"
    folder.mkdir()
    truth = {}
    for label, u1, drift in WAVES:
        seq = write_synthetic_sequence(SynthConfig(**SMALL, u1_um_per_ms=u1, drift_mrad=drift), root / f"seq{label}",
                                       progress=False)
        rows = pd.read_csv(seq / "truth_frames.csv")
        for k, row in rows.iterrows():
            name = f"images_V-{label}_w--{k + 1}.png"
            shutil.copy(seq / row["file"], folder / name)
            truth[name] = row
    return folder, truth


def test_the_shared_calibration_gives_the_solo_answers(rig_shots):
    folder, truth = rig_shots
    shared = measure_shots(folder, overrides=PIXEL, workers=1)
    alone = measure_shots(folder, overrides=PIXEL, workers=1, shared_calibration=False)
    rig = shared.summary["shared_calibration"]
    assert rig["reference"] == sorted(truth)[0] and rig["left_out"] == []
    # the reference's own calibration: its row is its row alone, to the bit (but the notes)
    assert rig["calibrated_from"] == sorted(truth)[:1]
    assert all(s["shared_calibration"] for s in shared.summary["shots"])
    assert not any(s["shared_calibration"] for s in alone.summary["shots"])
    assert alone.summary["shared_calibration"]["reference"] is None
    a, s = alone.shots.set_index("file"), shared.shots.set_index("file")
    assert list(a.index) == list(s.index) == sorted(truth)
    ref = sorted(truth)[0]
    pd.testing.assert_series_equal(s.loc[ref].drop("notes"), a.loc[ref].drop("notes"))
    for name, t in truth.items():
        u = s.loc[name, "drop_volume_uncertainty_nl"]
        assert u > 0
        assert abs(s.loc[name, "drop_volume_nl"] - a.loc[name, "drop_volume_nl"]) <= TOLERANCE_U * u, name
        assert s.loc[name, "drop_volume_nl"] == pytest.approx(t["drop_volume_nl"], rel=0.02)
        assert s.loc[name, "n_satellites"] == a.loc[name, "n_satellites"] == t["n_satellites"]
        assert s.loc[name, "drop_z_um"] == pytest.approx(a.loc[name, "drop_z_um"], abs=1.0)
        assert s.loc[name, "quality"] == a.loc[name, "quality"] == "ok"
    # the shared calibration is stated once, for the folder
    assert any(n.startswith("calibration shared by the shots of one rig: from 1 shot(s)")
               for n in shared.summary["notes"])


def _shifted(src, dst, dx: float, dy: float) -> None:
    img = cv2.imread(str(src), cv2.IMREAD_UNCHANGED)
    m = np.float32([[1, 0, dx], [0, 1, dy]])
    cv2.imwrite(str(dst), cv2.warpAffine(img, m, img.shape[1::-1], borderMode=cv2.BORDER_REPLICATE))


def test_an_odd_shot_is_measured_alone_with_a_note(rig_shots, tmp_path):
    folder, truth = rig_shots
    odd = tmp_path / "odd"
    shutil.copytree(folder, odd)
    names = sorted(truth)
    # the first shot of the folder taken with the camera 6 px aside: it must not spoil the calibration
    moved = "images_A-moved.png"
    _shifted(folder / names[0], odd / moved, 6.0, 0.0)
    # another under another light (a tilted backlight: the background's shape changes by +-15 %)
    img = cv2.imread(str(folder / names[1]), cv2.IMREAD_UNCHANGED).astype(np.float64)
    ramp = np.linspace(0.85, 1.15, img.shape[0])[:, None]
    lit = "images_Z-lit.png"
    cv2.imwrite(str(odd / lit), np.clip(img * ramp, 0, np.iinfo(np.uint16).max if img.max() > 255 else 255)
                .astype(cv2.imread(str(folder / names[1]), cv2.IMREAD_UNCHANGED).dtype))
    res = measure_shots(odd, overrides=PIXEL, workers=1)
    rig = res.summary["shared_calibration"]
    assert rig["reference"] in names and moved not in rig["calibrated_from"]
    assert {d["file"] for d in rig["left_out"]} <= {moved, lit} and moved in {d["file"] for d in rig["left_out"]}
    by_file = {s["file"]: s for s in res.summary["shots"]}
    table = res.shots.set_index("file")
    assert not by_file[moved]["shared_calibration"] and not by_file[lit]["shared_calibration"]
    assert "calibrated alone: its scene is shifted by" in table.loc[moved, "notes"]
    assert "calibrated alone: its background differs by" in table.loc[lit, "notes"]
    for name in names:  # the others share it, and their answers are the folder's without the odd shots
        assert by_file[name]["shared_calibration"] and "calibrated alone" not in table.loc[name, "notes"]
        assert table.loc[name, "drop_volume_nl"] == pytest.approx(truth[name]["drop_volume_nl"], rel=0.02)
    # measured alone, the odd shots are what their images give alone (their own calibration)
    alone = measure_shots(odd, overrides=PIXEL, workers=1, shared_calibration=False).shots.set_index("file")
    for name in (moved, lit):
        assert table.loc[name, "drop_volume_nl"] == alone.loc[name, "drop_volume_nl"]
        # measured from its frame as decoded for the comparison (not opened again): its whole row, its orientation
        pd.testing.assert_series_equal(table.loc[name].drop("notes"), alone.loc[name].drop("notes"))
        assert by_file[name]["orientation_source"].startswith("the shared calibration's reference's")

def test_fingerprints_tell_a_moved_camera_and_another_light(rig_shots):
    folder, truth = rig_shots
    a, b = (cv2.imread(str(folder / n), cv2.IMREAD_UNCHANGED) for n in sorted(truth)[:2])
    assert disagreement(fingerprint(b), fingerprint(a)) is None  # another drop, the same rig
    m = np.float32([[1, 0, 0], [0, 1, 3]])
    moved = cv2.warpAffine(b, m, b.shape[1::-1], borderMode=cv2.BORDER_REPLICATE)
    shifted, resized = disagreement(fingerprint(moved), fingerprint(a)), disagreement(fingerprint(b[:-2]), fingerprint(a))
    assert shifted.startswith("its scene is shifted by")
    assert resized.startswith("its size 128x446 differs")
    # the decision to measure a shot alone from its frame as decoded reads the flag, never the words
    assert shifted.same_view and not resized.same_view
    assert pickle.loads(pickle.dumps(shifted)).same_view  # it crosses to a forked worker's parent intact


def test_parallel_and_serial_give_identical_rows(rig_shots, tmp_path, monkeypatch):
    folder, _ = rig_shots
    forked = []
    map_forked = engine._map_forked

    def spy(*args, **kwargs):
        forked.append(True)
        yield from map_forked(*args, **kwargs)

    monkeypatch.setattr(engine, "_map_forked", spy)
    serial = measure_shots(folder, overrides=PIXEL, workers=1)
    assert not forked
    # the pytest process runs other threads (processes_usable says no): forked here as the tests of
    # the frame workers do (conftest: OpenBLAS on one thread, OpenCV's pool never started)
    monkeypatch.setattr(engine, "processes_usable", lambda *args, **kwargs: True)
    parallel = measure_shots(folder, overrides=PIXEL, workers=2)
    assert forked  # the shots were measured in forked worker processes
    pd.testing.assert_frame_equal(parallel.shots, serial.shots)
    pd.testing.assert_frame_equal(parallel.frames, serial.frames)
    pd.testing.assert_frame_equal(parallel.bodies, serial.bodies)
    # NaN != NaN: compared as JSON text
    assert json.dumps(parallel.summary["shots"], default=str) == json.dumps(serial.summary["shots"], default=str)


def test_the_command_line_forks_the_shot_workers(rig_shots, tmp_path):
    """`dropvision measure` over a shot folder measures in forked workers: nothing it runs before the fork
    starts a native thread (pandas loads pyarrow, whose allocator starts one: after the fork)."""
    import subprocess
    import sys

    folder, _ = rig_shots
    code = (
        "import os, sys\n"
        "from dropvision.app.cli import main\n"
        "import dvcore.parallel as engine\n"
        "each = engine._map_forked\n"
        "def spy(*a, **k):\n"
        "    print('forked from', len(os.listdir('/proc/self/task')), 'thread(s)')\n"
        "    yield from each(*a, **k)\n"
        "engine._map_forked = spy\n"
        f"sys.exit(main(['measure', {str(folder)!r}, '--out', {str(tmp_path / 'out')!r}, '--pixel-size-um', '4.73']))\n"
    )
    env = {k: v for k, v in __import__("os").environ.items() if k != "OPENBLAS_NUM_THREADS"}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode == 0, done.stderr
    assert "forked from 1 thread(s)" in done.stdout
    assert "measured 4 shots" in done.stdout


def test_a_rotated_rig_shares_its_calibration(rig_shots, tmp_path):
    """Shots stored with the drops flying right (PNG: its header tells the size): the calibration
    shots are read as stored, compared, then turned as the reference shot's orientation says."""
    folder, truth = rig_shots
    turned = tmp_path / "turned"
    turned.mkdir()
    for name in truth:
        cv2.imwrite(str(turned / name), np.ascontiguousarray(np.rot90(cv2.imread(str(folder / name),
                                                                                 cv2.IMREAD_UNCHANGED))))
    res = measure_shots(turned, overrides=PIXEL, workers=1)
    assert res.summary["shared_calibration"]["calibrated_from"] == sorted(truth)[:1]
    assert all(s["shared_calibration"] and s["orientation"] == "right" for s in res.summary["shots"])
    table = res.shots.set_index("file")
    for name, t in truth.items():
        assert table.loc[name, "drop_volume_nl"] == pytest.approx(t["drop_volume_nl"], rel=0.02)


def test_drops_at_one_place_in_every_shot_are_not_dust(tmp_path):
    """Shots of several waveforms at one strobe delay put their drops at nearly one place: dark in
    every calibration shot, they are the liquid, not static dust (the shared calibration looks for no
    dust, as one shot alone does not). Three delays 100-150 us apart: the 70 px drops overlap."""
    src = write_synthetic_sequence(SynthConfig(**{**SMALL, "delays_us": (1150.0, 1250.0, 1400.0)}, u1_um_per_ms=75.0),
                                   tmp_path / "seq", progress=False)
    folder = tmp_path / "shots"
    folder.mkdir()
    rows = pd.read_csv(src / "truth_frames.csv")
    for k, row in rows.iterrows():
        shutil.copy(src / row["file"], folder / f"images_V1-{80 + 5 * k}_w1-8.png")
    shared = measure_shots(folder, overrides=PIXEL, workers=1)
    alone = measure_shots(folder, overrides=PIXEL, workers=1, shared_calibration=False)
    assert all(s["shared_calibration"] for s in shared.summary["shots"])
    assert list(shared.shots["quality"]) == list(alone.shots["quality"]) == ["ok"] * 3
    diff = np.abs(shared.shots["drop_volume_nl"] - alone.shots["drop_volume_nl"])
    assert np.isfinite(diff).all() and (diff <= TOLERANCE_U * alone.shots["drop_volume_uncertainty_nl"]).all()


def test_each_group_of_agreeing_shots_shares_its_own_calibration(rig_shots, tmp_path, monkeypatch):
    """The holder at two places in one folder (three shots 6 px aside), two groups allowed: two shared
    calibrations, one per place, each shot measured with its own place's; every answer is the solo one
    within TOLERANCE_U of its uncertainty. One group (the default): the second place's shots alone."""
    folder, truth = rig_shots
    two = tmp_path / "two"
    shutil.copytree(folder, two)
    names = sorted(truth)
    moved = {f"images_B-moved{k}.png": names[k] for k in range(3)}
    for name, src in moved.items():
        _shifted(folder / src, two / name, 6.0, 0.0)
    default = measure_shots(two, overrides=PIXEL, workers=1)
    assert default.summary["shared_calibration"]["others"] == []
    assert {s["file"] for s in default.summary["shots"] if not s["shared_calibration"]} == set(moved)
    monkeypatch.setattr(shot_rig, "MAX_GROUPS", 2)
    res = measure_shots(two, overrides=PIXEL, workers=1)
    rig = res.summary["shared_calibration"]
    assert rig["calibrated_from"] == names[:1] and rig["left_out"] == []
    assert [o["calibrated_from"] for o in rig["others"]] == [sorted(moved)[:1]]
    assert all(s["shared_calibration"] for s in res.summary["shots"])
    table = res.shots.set_index("file")
    alone = measure_shots(two, overrides=PIXEL, workers=1, shared_calibration=False).shots.set_index("file")
    for name in moved:
        assert "calibration shared by the shots of one rig: from 1 shot(s) (images_B-moved0" in table.loc[name, "notes"]
    for name in list(truth) + list(moved):
        u = table.loc[name, "drop_volume_uncertainty_nl"]
        assert u > 0
        assert abs(table.loc[name, "drop_volume_nl"] - alone.loc[name, "drop_volume_nl"]) <= TOLERANCE_U * u, name
        ref = truth[moved.get(name, name)]["drop_volume_nl"]
        assert table.loc[name, "drop_volume_nl"] == pytest.approx(ref, rel=0.02)


def test_a_reference_without_a_nozzle_shares_nothing(rig_shots, monkeypatch):
    """Whether the nozzle is found differs between real shots of one holder place: a reference whose
    calibration finds none gives no shared calibration (each shot its own, as alone)."""
    import dropvision.calibrate.calibration_pass as calibration_pass

    folder, truth = rig_shots
    plain = calibration_pass.calibrate_sequence

    def no_nozzle(seq, config, **kwargs):
        cal, sigma, ctx = plain(seq, config, **kwargs)
        if seq.meta.frames[0].file.startswith("/"):  # the shared calibration's in-memory frames only
            cal = dataclasses.replace(cal, nozzle_found=False)  # a frozen calibration: a new one
        return cal, sigma, ctx

    monkeypatch.setattr(calibration_pass, "calibrate_sequence", no_nozzle)
    res = measure_shots(folder, overrides=PIXEL, workers=1)
    rig = res.summary["shared_calibration"]
    assert rig["reference"] is None and "finds no nozzle" in rig["reason"]
    assert not any(s["shared_calibration"] for s in res.summary["shots"])
    assert list(res.shots["quality"]) == ["ok"] * len(truth)
