"""Shots as labs record them (issue 30 items 1-3): a folder of images with no delay to tell measures,
one row per image, each row what that image gives when measured alone; labels from the names.

Synthetic shots: frames of two synthetic waveforms (truth per frame in truth_frames.csv), renamed as a
drop watcher names its exports. Real shots: the eight ../shared/realdata/watcher-dod frames under their
published names (skipped on a fresh clone, tests/realdata.py).
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from dropvision.app.cli import main
from dropvision.measurement import measure_sequence
from dropvision.io.sequence import SequenceError, open_sequence
from dropvision.io.sequence_meta import RGBConvertedWarning
from dropvision.analysis.shots import find_shots, measure_shots
from dropvision.synth import SynthConfig, write_synthetic_sequence
from dvcore import schema
from realdata import REALDATA

SMALL = dict(width_px=128, height_px=448, tip_row=30.3, axis_col=63.6, delays_us=(1250.0, 1400.0), noise=0.3)
#: (u1 label, u1 um/ms, drift mrad) of the two synthetic waveforms
WAVES = ((7, 70.0, 30.0), (8, 80.0, -20.0))


@pytest.fixture(scope="module")
def synthetic_shots(tmp_path_factory):
    """Four synthetic shots (two waveforms x two delays) named ``images_V-<u1>_w--<k>_n_<i>.png``, no delay in
    the names; their truth rows (truth_frames.csv) by file name."""
    root = tmp_path_factory.mktemp("shots")
    folder = root / "shots"
    folder.mkdir()
    truth = {}
    for label, u1, drift in WAVES:
        seq = write_synthetic_sequence(SynthConfig(**SMALL, u1_um_per_ms=u1, drift_mrad=drift), root / f"seq{label}",
                                       progress=False)
        rows = pd.read_csv(seq / "truth_frames.csv")
        for k, row in rows.iterrows():
            i = len(truth)
            name = f"images_V-{label}_w--{k + 1}_n_{i}.png"
            shutil.copy(seq / row["file"], folder / name)
            truth[name] = row.copy()
            truth[name]["labels"] = (float(label), -float(k + 1), float(i))
    return folder, truth


def _alone(image: Path, folder: Path) -> Path:
    folder.mkdir(parents=True)
    shutil.copy(image, folder / image.name)
    return folder


def test_a_folder_of_shots_measures_one_row_per_image(synthetic_shots, tmp_path, capsys):
    folder, truth = synthetic_shots
    out = tmp_path / "out"
    assert main(["measure", str(folder), "--out", str(out), "--pixel-size-um", "4.73"]) == 0
    line = capsys.readouterr().out.strip()
    assert line.startswith(f"measured 4 shots -> {out}; main drop volume median ")
    assert line.endswith("4 labelled from file names (V, w, n)")
    table = pd.read_parquet(out / "shots.parquet")
    assert list(table.columns) == schema.SHOTS.column_names + ["V", "w", "n"]
    schema.check_table(table, schema.SHOTS, out / "shots.parquet")
    summary = schema.check_document(json.loads((out / "summary.json").read_text()), schema.SHOTS_SUMMARY, "summary")
    assert summary["kind"] == "shots" and summary["n_shots"] == summary["n_measured"] == 4
    assert summary["label_sources"] == {"V": "file names", "w": "file names", "n": "file names"}
    assert sorted(table["file"]) == sorted(truth) and (table["quality"] == "ok").all()
    for _, row in table.iterrows():
        t = truth[row["file"]]
        assert (row["V"], row["w"], row["n"]) == t["labels"]
        assert row["drop_volume_nl"] == pytest.approx(t["drop_volume_nl"], rel=0.02)
        assert row["drop_volume_uncertainty_nl"] > 0 and row["n_satellites"] == t["n_satellites"] == 0
        # the sphere of the volume, and the trajectory angle nozzle -> drop against the truth's
        assert row["drop_sphere_diameter_um"] == pytest.approx((6e6 * row["drop_volume_nl"] / math.pi) ** (1 / 3))
        truth_angle = 1000 * math.atan2(t["drop_x_um"], t["drop_z_um"])
        assert abs(truth_angle) > 5 and row["trajectory_angle_mrad"] == pytest.approx(truth_angle, abs=1.5)
        assert row["satellites_volume_nl"] == 0.0 and row["attached_volume_nl"] < 0.5
    assert summary["drop_volume_median_nl"] == pytest.approx(float(np.median(table["drop_volume_nl"])))
    frames = pd.read_parquet(out / "frames.parquet")
    assert list(frames["file"]) == list(table["file"])  # the per-frame table the rows were built from


def test_each_row_is_what_the_image_gives_alone(synthetic_shots, tmp_path):
    """Without the shared calibration (tests/analysis/test_shots_shared.py: within half their uncertainty with it)."""
    folder, _ = synthetic_shots
    res = measure_shots(folder, overrides={"pixel_size_um": 4.73}, shared_calibration=False)
    for image in sorted(folder.glob("*.png"))[::3]:
        one = measure_sequence(_alone(image, tmp_path / image.stem), overrides={"pixel_size_um": 4.73}).frames
        row = res.frames.set_index("file").loc[image.name]
        pd.testing.assert_series_equal(one.iloc[0].drop("file"), row, check_names=False)
        assert res.shots.set_index("file").loc[image.name, "drop_volume_nl"] == one["drop_volume_nl"].iloc[0]


def test_image_files_and_the_label_table(synthetic_shots, tmp_path, capsys):
    folder, _ = synthetic_shots
    images = sorted(folder.glob("*.png"))
    # one file: a folder of one (the single-frame path); several: shots
    assert main(["measure", str(images[0]), "--out", str(tmp_path / "one"), "--pixel-size-um", "4.73"]) == 0
    assert capsys.readouterr().out.startswith("measured 1 of 1 frames")
    assert main(["measure", str(images[0]), str(images[2]), "--out", str(tmp_path / "two"), "--pixel-size-um",
                 "4.73", "--label-pattern", r"V-(?P<volts>\d+)"]) == 0
    assert capsys.readouterr().out.strip().endswith("2 labelled from --label-pattern (volts)")
    table = pd.read_parquet(tmp_path / "two" / "shots.parquet")
    assert list(table["file"]) == [images[0].name, images[2].name] and list(table["volts"]) == [7.0, 8.0]
    # shots.csv beside the images: its labels join the names'; a contradiction names the file
    copy = tmp_path / "copy"
    shutil.copytree(folder, copy)
    (copy / "shots.csv").write_text("file,nozzle,V\n" + "".join(f"{p.name},{i},\n" for i, p in enumerate(images)))
    res = measure_shots(copy, overrides={"pixel_size_um": 4.73})
    assert list(res.shots["nozzle"]) == [0.0, 1.0, 2.0, 3.0]
    assert res.summary["label_sources"]["nozzle"] == "shots.csv" and res.summary["label_sources"]["V"] == "file names"
    # sequence.json: the settings of every shot (no frames list) and a shots list of labels
    (copy / "sequence.json").write_text(json.dumps({"pixel_size_um": 4.73, "shots": [
        {"file": images[0].name, "V": 7, "piezo": 1.5}]}))
    res = measure_shots(copy)
    assert res.summary["label_sources"] == {"V": "file names and sequence.json", "w": "file names",
                                            "n": "file names", "piezo": "sequence.json", "nozzle": "shots.csv"}
    assert res.shots["piezo"].iloc[0] == 1.5 and np.isnan(res.shots["piezo"].iloc[1])
    assert res.summary["shots"][0]["pixel_size_source"] == "sequence.json"
    (copy / "sequence.json").unlink()
    (copy / "shots.csv").write_text(f"file,V\n{images[1].name},9\n")
    assert main(["measure", str(copy), "--out", str(tmp_path / "bad"), "--pixel-size-um", "4.73"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"dropvision measure: error: {copy / images[1].name}: label V is 7 by the file name but 9 by "
                   "the shots.csv")
    assert not (tmp_path / "bad").exists()
    # the output may not lie in the shot folder
    assert main(["measure", str(folder), "--out", str(folder / "out"), "--pixel-size-um", "4.73"]) == 2
    assert not (folder / "out").exists()
    capsys.readouterr()


def test_other_waveforms_are_never_blended_into_one_sequence(synthetic_shots, tmp_path, capsys):
    folder, _ = synthetic_shots
    assert main(["measure", str(folder), "--out", str(tmp_path / "r"), "--pixel-size-um", "4.73",
                 "--frame-rate-hz", "10000"]) == 2
    err = capsys.readouterr().err
    assert "the file names carry different labels (V, w, n differ" in err and "never blended" in err
    with pytest.raises(SequenceError, match="never blended"):
        open_sequence(folder, overrides={"pixel_size_um": 4.73, "frame_rate_hz": 1e4})
    # a folder that is a sequence is not shots: delays in the names, a frames list, a frame rate, one image
    assert find_shots(folder, overrides={"frame_rate_hz": 1e4}) is None
    seq = tmp_path / "seq"
    seq.mkdir()
    for i, image in enumerate(sorted(folder.glob("*.png"))[:2]):
        shutil.copy(image, seq / f"f_{i}_{100 * (i + 1)}us.png")
    assert find_shots(seq) is None
    assert find_shots(_alone(next(folder.glob("*.png")), tmp_path / "alone")) is None
    with pytest.raises(SequenceError, match="not a folder of shots"):
        measure_shots(seq)


# ----------------------------------------------------------------------------- real drop-watcher shots
WATCHER = sorted((REALDATA / "watcher-dod").glob("V*/frame.jpg"))


@pytest.mark.slow
def test_the_real_watcher_frames_as_published(realdata_dir, tmp_path, capsys):
    folder = tmp_path / "small_samples"
    folder.mkdir()
    for frame in WATCHER:
        shutil.copy(frame, folder / f"images_{frame.parent.name}.jpg")
    assert len(WATCHER) == 8
    out = tmp_path / "out"
    assert main(["measure", str(folder), "--out", str(out), "--pixel-size-um", "3", "-v"]) == 0
    captured = capsys.readouterr()
    assert "of 8 shots" in captured.out or "measured 8 shots" in captured.out
    assert "8 labelled from file names (V1, V2, V3, w1, ...)" in captured.out
    # one colour warning for the folder, not one per image (and only with --verbose: issue 33)
    assert len(captured.err.strip().splitlines()) == 1 and "and 7 other image(s)" in captured.err
    table = pd.read_parquet(out / "shots.parquet")
    assert len(table) == 8
    for frame in WATCHER:  # the labels: the folder names are the source's file names
        row = table.set_index("file").loc[f"images_{frame.parent.name}.jpg"]
        for token in frame.parent.name.split("_"):
            key, value = token.split("-", 1)
            assert row[key] == float(value), (frame.parent.name, key)
    # the rows measured alone (these frames are of several camera positions: each that shares no other's
    # calibration, dropvision.analysis.shot_rig) are what the frame gives alone
    measured = table[table["quality"] != schema.Quality.NOT_MEASURED]
    frames = pd.read_parquet(out / "frames.parquet").set_index("file")
    assert len(measured) >= 7
    alone = [e["file"] for e in json.loads((out / "summary.json").read_text())["shots"]
             if e.get("shared_calibration") is False]
    assert alone and set(alone) <= set(measured["file"])
    assert "calibrated alone: " in table.set_index("file").loc[alone[0], "notes"]
    name = alone[0]
    with pytest.warns(RGBConvertedWarning):
        one = measure_sequence(_alone(folder / name, tmp_path / "alone"), overrides={"pixel_size_um": 3.0}).frames
    pd.testing.assert_series_equal(one.iloc[0].drop("file"), frames.loc[name], check_names=False)
    for _, row in table[table["quality"] == schema.Quality.NOT_MEASURED].iterrows():
        assert row["notes"] and math.isnan(row["drop_volume_nl"])  # one row per image, the reason in its notes


# ----------------------------------------------------------------------------- 6. not a drop image
@pytest.mark.slow
def test_photographs_are_never_measured_as_ok(tmp_path, capsys):
    """Photographs (scikit-image's bundled test images: a man with a camera, an astronaut, a cat, coins, a
    rocket, grass) in a shot folder: each refused (a row not_measured, its reason) or flagged, none 'ok'."""
    data = pytest.importorskip("skimage.data")
    import cv2

    folder = tmp_path / "photos"
    folder.mkdir()
    for name in ("camera", "astronaut", "chelsea", "coins", "rocket", "grass"):
        image = getattr(data, name)()
        if image.ndim == 3:
            image = cv2.cvtColor(image[..., :3], cv2.COLOR_RGB2GRAY)
        cv2.imwrite(str(folder / f"{name}.png"), image)
    with np.errstate(all="ignore"):
        assert main(["measure", str(folder), "--out", str(tmp_path / "out"), "--pixel-size-um", "3", "-q"]) == 0
    capsys.readouterr()
    table = pd.read_parquet(tmp_path / "out" / "shots.parquet")
    assert len(table) == 6 and not (table["quality"] == schema.Quality.OK).any(), table[["file", "quality"]]
    assert table.loc[table["quality"] == schema.Quality.NOT_MEASURED, "notes"].str.len().gt(0).all()
    assert not table["inflight"].any() and table["drop_volume_nl"].isna().all()
