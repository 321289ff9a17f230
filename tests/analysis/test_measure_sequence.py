"""`dropvision measure` end to end: CLI, output files, bad input, real pendant drop."""

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from dropvision.app.cli import main
from dropvision.io.sequence import SequenceError
from dropvision.measurement import MeasureResult, measure_sequence
from dropvision.analysis.sequence_summary import FRAME_COLUMNS
from realdata import REALDATA  # ../shared/realdata: skipped on a fresh clone without it, a failure in CI

PENDANT = REALDATA / "menipy-pendant-drop"


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    from dropvision.synth import SynthConfig, write_synthetic_sequence

    out = tmp_path_factory.mktemp("m") / "seq"
    cfg = SynthConfig(width_px=256, height_px=640, delays_us=tuple(float(d) for d in range(0, 1401, 40)),
                      repeats=2, seed=5)
    return write_synthetic_sequence(cfg, out, progress=False)


def test_cli_writes_complete_result(seq, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["measure", str(seq), "--out", str(out), "--csv"]) == 0
    assert sorted(p.name for p in out.iterdir()) == [".dropvision-output.json", "bodies.parquet", "frames.csv",
                                                     "frames.parquet", "per_delay.parquet", "summary.json"]
    frames = pd.read_parquet(out / "frames.parquet")
    assert list(frames.columns) == FRAME_COLUMNS
    truth = pd.read_csv(seq / "truth_frames.csv")
    assert len(frames) == len(truth)  # repeated frames all kept
    summary = json.loads((out / "summary.json").read_text())
    for key in ("schema_version", "pinchoff_us", "grown_volume_at_pinchoff_nl", "inflight_volume_nl",
                "inflight_volume_std_nl", "jetting_velocity_m_s", "jetting_velocity_se_m_s",
                "trajectory_angle_mrad", "satellites", "flow_velocity_at_max_stroke_m_s", "calibration",
                "errors", "software", "config"):
        assert key in summary
    assert summary["pinchoff_us"] == json.loads((seq / "truth.json").read_text())["pinchoff_us"]
    per = pd.read_parquet(out / "per_delay.parquet")
    assert (per["n_frames"] == 2).all()
    assert not frames.loc[frames.attached, "drop_volume_nl"].notna().any()
    assert frames.loc[~frames.attached, "flow_velocity_m_s"].isna().all()


def test_python_api_per_delay(seq):
    res = measure_sequence(seq)
    assert isinstance(res, MeasureResult)
    per = res.per_delay()
    g = res.frames.groupby("delay_us")["grown_volume_nl"]
    assert np.allclose(per["grown_volume_nl_mean"], g.mean().to_numpy(), equal_nan=True)
    assert np.allclose(per["grown_volume_nl_std"], g.std().to_numpy(), equal_nan=True)


def test_unreadable_frames_are_skipped_and_reported(seq, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(seq, bad)
    files = sorted(bad.glob("*.png"))
    files[5].write_bytes(files[5].read_bytes()[:200])  # truncated
    files[7].write_bytes(b"")  # zero bytes
    res = measure_sequence(bad, tmp_path / "out")
    assert len(res.frames) == len(files) - 2
    assert {e["file"] for e in res.summary["errors"]} == {files[5].name, files[7].name}
    assert all(e["reason"] for e in res.summary["errors"])


def test_other_frame_size_exit_2_and_no_output(seq, tmp_path, capsys):
    bad = tmp_path / "bad"
    shutil.copytree(seq, bad)
    f = sorted(bad.glob("*.png"))[20]
    cv2.imwrite(str(f), cv2.imread(str(f), cv2.IMREAD_UNCHANGED)[:-4])
    out = tmp_path / "out"
    assert main(["measure", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f.name in err and len(err.strip().splitlines()) == 1
    assert not out.exists() and not list(tmp_path.glob(".out*"))


def test_empty_folder_and_missing_pixel_size(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["measure", str(tmp_path / "empty"), "--out", str(tmp_path / "o")]) == 2
    nopx = tmp_path / "nopx"
    nopx.mkdir()
    cv2.imwrite(str(nopx / "a_0us.png"), np.full((50, 50), 200, np.uint8))
    (nopx / "sequence.json").write_text(json.dumps({"frames": [{"file": "a_0us.png", "delay_us": 0}]}))
    assert main(["measure", str(nopx), "--out", str(tmp_path / "o")]) == 2
    with pytest.raises(SequenceError):
        measure_sequence(nopx)


def test_no_nozzle_is_a_sequence_error(tmp_path):
    d = tmp_path / "blank"
    d.mkdir()
    cv2.imwrite(str(d / "a_0us.png"), np.full((80, 60), 200, np.uint8))
    (d / "sequence.json").write_text(json.dumps({"pixel_size_um": 5.0}))
    with pytest.raises(SequenceError, match="nozzle"):
        measure_sequence(d)


def test_real_pendant_drop_volume(realdata_dir):
    res = measure_sequence(PENDANT)
    truth = json.loads((PENDANT / "truth.json").read_text())
    v = res.frames["attached_volume_nl"].iloc[0]
    assert abs(v / truth["attached_volume_nl"] - 1) * 100 <= truth["tolerance_percent"]
    assert res.frames["quality"].iloc[0] == "ok"
    assert abs(res.summary["calibration"]["pixel_size_disagreement_percent"]) < 2


def test_no_frame_at_rest_gives_no_grown_volume():
    """A sequence starting after the piston moved has no initial meniscus: grown volume and flow
    are NaN with a reason, never numbers relative to a moving meniscus; the drop is still measured."""
    import json
    from pathlib import Path

    seq = Path(__file__).resolve().parents[2] / "sample_frames" / "satellite_dust_tiff16"
    res = measure_sequence(seq)
    truth = json.loads((seq / "truth.json").read_text())
    att = res.frames[res.frames.attached]
    assert att.grown_volume_nl.isna().all() and att.flow_velocity_m_s.isna().all()
    assert att.quality.str.contains("no_rest_meniscus").all()
    s = res.summary
    assert s["grown_volume_at_pinchoff_nl"] != s["grown_volume_at_pinchoff_nl"]  # NaN
    assert s["pinchoff_us"] == truth["pinchoff_us"] and s["satellites"] == truth["satellites"]
    assert abs(s["inflight_volume_nl"] / truth["inflight_volume_nl"] - 1) < 3e-3


@pytest.mark.slow
def test_measure_cli_writes_rerun_recording(tmp_path):
    """`dropvision measure --rerun` logs every stage; the values read back equal frames.parquet."""
    from rrdtools import Rrd

    seq = Path(__file__).resolve().parents[2] / "sample_frames" / "u55_u30"
    rrd = tmp_path / "m.rrd"
    assert main(["measure", str(seq), "--out", str(tmp_path / "out"), "--rerun", str(rrd)]) == 0
    frames = pd.read_parquet(tmp_path / "out" / "frames.parquet")
    r = Rrd(rrd)
    for entity in ("/frame/transmission", "/frame/segmentation", "/frame/edges", "/frame/bodies",
                   "/frame/axis", "/frame/tip_plane", "/series/volume_nl/grown", "/summary", "/calibration"):
        assert entity in r.entities(), entity
    grown = r.series("/series/volume_nl/grown", "Scalars:scalars")
    logged = dict(zip(grown.delay_ns // 1000, [v[0] for v in grown.value]))
    expected = frames.dropna(subset=["grown_volume_nl"]).set_index("delay_us").grown_volume_nl
    assert len(logged) == len(expected)
    for d, v in expected.items():
        assert logged[int(d)] == pytest.approx(v, rel=1e-6)


@pytest.mark.parametrize("u1, u2, seed, every_10_us", [
    (70.0, 25.0, 9000, False),  # pinch-off exactly at a frame: two blurred ends 4 rows apart, no thread
    (60.0, 30.0, 9, False),  # frame 1 us before pinch-off: a thread thinner than the blur still joins the drop
    # the two failures of the 0.02-everywhere rule in a 96-case seed sweep (every 10 us, as there):
    (80.0, 25.0, 3, True),  # tapered ends darken the gap rows next to them beyond a straight edge's tail
    (50.0, 30.0, 4, True),  # a thread whose waist sits in the gap row next to the meniscus
])
@pytest.mark.slow
def test_pinchoff_thread_rule_small_gap(u1, u2, seed, every_10_us, tmp_path):
    """The first detached frame is pinch-off; blurred ends close together are no thread."""
    from dropvision.synth import SynthConfig, write_synthetic_sequence

    tp = 1050.0 - 14.0 * (u1 - 70.0) + 10.2 * (u2 - 25.0)  # pinch-off law of the synthetic physics
    near = np.arange(10.0 * np.floor(tp / 10.0) - 30.0, 10.0 * np.floor(tp / 10.0) + 31.0, 10.0)
    delays = tuple(float(d) for d in np.concatenate([np.arange(0.0, near[0] - 1.0, 200.0), near]))
    if every_10_us:
        delays = tuple(float(d) for d in range(0, int(near[-1]) + 1, 10))
    cfg = SynthConfig(u1_um_per_ms=u1, u2_um=u2, seed=seed, width_px=192, height_px=640, tip_row=40.4,
                      axis_col=95.6, delays_us=delays, noise=0.5)
    seq = write_synthetic_sequence(cfg, tmp_path / "seq", progress=False)
    truth = json.loads((seq / "truth.json").read_text())
    assert truth["pinchoff_us"] in delays and truth["pinchoff_us"] - 10.0 in delays
    assert measure_sequence(seq).summary["pinchoff_us"] == truth["pinchoff_us"]


@pytest.mark.slow
def test_per_frame_blur_and_contrast_flags(tmp_path):
    """A defocused frame and a washed-out frame are flagged (their numbers NaN); the others not."""
    from dropvision.synth import SynthConfig, write_synthetic_sequence

    delays = tuple(float(d) for d in range(0, 1001, 50))
    cfg = SynthConfig(width_px=192, height_px=640, tip_row=40.4, axis_col=95.6, delays_us=delays, seed=3)
    seq = write_synthetic_sequence(cfg, tmp_path / "seq", progress=False)
    files = [f["file"] for f in json.loads((seq / "sequence.json").read_text())["frames"]]
    blurred, washed = files[7], files[12]
    extra_sigma_px = 1.5
    img = cv2.imread(str(seq / blurred), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(seq / blurred), cv2.GaussianBlur(img, (0, 0), extra_sigma_px))
    img = cv2.imread(str(seq / washed), cv2.IMREAD_UNCHANGED).astype(np.float64)
    white = cv2.dilate(img, np.ones((41, 41)))  # local bright level: the backlight
    cv2.imwrite(str(seq / washed), np.round(img + 0.3 * (white - img)).astype(np.uint8))  # 30 % less contrast

    res = measure_sequence(seq)
    f = res.frames.set_index("file")
    sigma = res.summary["calibration"]["edge_blur_sigma_px"]
    others = f.drop([blurred, washed])
    assert (others.quality == "ok").all()
    np.testing.assert_allclose(others.blur_px, sigma, rtol=0.05)
    # Gaussian blurs add in quadrature
    assert f.loc[blurred, "blur_px"] == pytest.approx(np.hypot(sigma, extra_sigma_px), rel=0.15)
    assert "blurred" in f.loc[blurred, "quality"] and np.isnan(f.loc[blurred, "grown_volume_nl"])
    assert f.loc[washed, "wall_contrast"] == pytest.approx(0.7 * others.wall_contrast.median(), rel=0.05)
    assert "low_contrast" in f.loc[washed, "quality"] and np.isnan(f.loc[washed, "grown_volume_nl"])


def test_one_line_of_a_pendant_drop_says_its_volume(realdata_dir, tmp_path, capsys):
    """A single frame's one-line result is what it shows (here the liquid hanging from the needle),
    not the NaNs of a time series (pinch-off, in-flight volume, velocity)."""
    assert main(["measure", str(PENDANT), "--out", str(tmp_path / "o")]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert "attached volume 7" in line and "nl" in line and "nan" not in line and "pinch-off" not in line
