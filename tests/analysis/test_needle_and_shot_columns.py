"""Issue 30 items 7 and 3: the needle-only pixel size (one width per frame from one rule, its
uncertainty propagated, no mismatch against a pixel size never given), and the shot table's tail
length, double-exposure velocity and per-shot pixel size, against synthetic truth and real drops."""

from __future__ import annotations

import json
import shutil
import warnings

import cv2
import numpy as np
import pandas as pd
import pytest

from dropvision.app.cli import main

from dropvision.calibrate.calibration import CalibrationWarning, calibrate_frames
from dropvision.calibrate.inspection import nozzle_outer_width_px
from dropvision.analysis.shots import measure_shots
from dropvision.synth import SynthConfig, synthesize
from dropvision.synth.planning import plan
from dropvision.synth.shapes import ShapeParams

NEEDLE_UM = 720.0
#: (pixel size um, blur px, Bond number) of three synthetic pendant drops (pendant-saturated rig, clipped)
PENDANTS = ((10.0, 1.0, 0.2), (8.0, 2.0, 0.25), (12.5, 1.5, 0.15))


@pytest.fixture(scope="module")
def pendant_folder(tmp_path_factory):
    """Three synthetic pendant drops at three pixel sizes in one folder; their truth by file name."""
    folder = tmp_path_factory.mktemp("pendants") / "drops"
    folder.mkdir()
    truth = {}
    for i, (px, blur, bond) in enumerate(PENDANTS):
        cfg = SynthConfig.for_rig("pendant-saturated", pixel_size_um=px, blur_px=blur, pendant_bond=bond, seed=i,
                                  width_px=480, height_px=400, tip_row=30.4, axis_col=239.6, format="png",
                                  colour=False)
        (img, t), = synthesize(cfg, progress=False)
        name = f"drop_{i}.png"
        cv2.imwrite(str(folder / name), img)
        truth[name] = (t.attached_volume_nl, px)
    return folder, truth


def test_pendant_drops_in_one_folder_each_with_its_own_pixel_size(pendant_folder, tmp_path):
    folder, truth = pendant_folder
    r = measure_shots(folder, tmp_path / "out", overrides={"nozzle_outer_diameter_um": NEEDLE_UM})
    t = r.shots.set_index("file")
    assert len(t) == len(truth)
    for name, (volume, px) in truth.items():
        row = t.loc[name]
        # the pixel size is this image's needle width: within its stated uncertainty (and 0.3 %)
        assert 0 < row["pixel_size_uncertainty_um"] < 0.005 * px
        assert abs(row["pixel_size_um"] - px) <= 2 * row["pixel_size_uncertainty_um"]
        assert abs(row["pixel_size_um"] / px - 1) < 0.003
        v, u = row["attached_volume_nl"], row["attached_volume_uncertainty_nl"]
        assert abs(v / volume - 1) < 0.02
        assert abs(v - volume) <= 2 * u
        assert "pixel_size_mismatch" not in row["quality"]
    shots = {s["file"]: s for s in r.summary["shots"]}
    for name in truth:
        cal = shots[name]["calibration"]
        assert cal["pixel_size_from_nozzle"] is True
        # nothing to check a pixel size against that nobody gave: the ratio is 1, its uncertainty the width's
        assert cal["pixel_size_ratio"] == 1.0
        assert cal["pixel_size_ratio_uncertainty"] == pytest.approx(cal["pixel_size_uncertainty_um"]
                                                                    / cal["pixel_size_um"])
        assert set(cal["nozzle_outer_diameter_terms_px"]) == {"rows", "taper", "edges"}
        assert shots[name]["pixel_size_source"].startswith("nozzle outer diameter 720 um / ")
        assert f"{cal['nozzle_outer_diameter_px']:.2f} px" in shots[name]["pixel_size_source"]


def test_the_pixel_size_uncertainty_widens_the_volumes(pendant_folder):
    """Given, the pixel size is exact (no term); from the needle, its uncertainty enters the volume's (by its cube)."""
    folder, truth = pendant_folder
    name = "drop_0.png"
    given = measure_shots([folder / name, folder / "drop_1.png"], None,
                          overrides={"pixel_size_um": PENDANTS[0][0]}).shots.set_index("file").loc[name]
    needle = measure_shots([folder / name, folder / "drop_1.png"], None,
                           overrides={"nozzle_outer_diameter_um": NEEDLE_UM}).shots.set_index("file").loc[name]
    assert given["pixel_size_uncertainty_um"] == 0
    rel3 = 3 * needle["pixel_size_uncertainty_um"] / needle["pixel_size_um"]
    expect = np.hypot(given["attached_volume_uncertainty_nl"] * needle["attached_volume_nl"]
                      / given["attached_volume_nl"], rel3 * needle["attached_volume_nl"])
    assert needle["attached_volume_uncertainty_nl"] == pytest.approx(expect, rel=0.05)
    # the pixel size's part is no small addition: over half the given-scale uncertainty of this clipped drop
    assert rel3 * needle["attached_volume_nl"] > 0.5 * given["attached_volume_uncertainty_nl"]
    assert needle["attached_volume_uncertainty_nl"] > 1.1 * given["attached_volume_uncertainty_nl"]


def test_a_given_pixel_size_is_still_checked_against_the_needle(pendant_folder):
    folder, _ = pendant_folder
    with pytest.warns(Warning, match="disagrees by"):
        r = measure_shots([folder / "drop_0.png", folder / "drop_1.png"], None,
                          overrides={"pixel_size_um": 10.0 * 1.05, "nozzle_outer_diameter_um": NEEDLE_UM})
    q = r.shots.set_index("file").loc["drop_0.png", "quality"]
    assert "pixel_size_mismatch" in q


# ------------------------------------------------------------------------------------------ shot columns
def _tail_truth(cfg: SynthConfig, delay_us: float) -> float:
    """The main body's length beyond a round head as wide as it (µm), from the synthetic shape."""
    body = plan(cfg).model.state(delay_us).main_body
    lo, hi = body.profile.support
    return max((hi - lo) - 2 * body.profile.max_radius_um, 0.0)


def test_tail_length_of_a_drop_with_a_long_tail_and_a_bulb(tmp_path):
    """A drop with a long tail and a bulb (its tail stretching until it breaks into a satellite): its volume,
    its tail's length against the synthetic shape's, ``tail_joined`` and a note; the compact drop later none."""
    cfg = SynthConfig(width_px=256, height_px=900, delays_us=(1150.0, 1500.0), seed=3, satellites=1,
                      shape=ShapeParams(tail_bulb=True, tail_break_us=300.0))
    frames = list(synthesize(cfg, progress=False))
    folder = tmp_path / "shots"
    folder.mkdir()
    for k, (img, _t) in enumerate(frames):
        cv2.imwrite(str(folder / f"shot_{k}.png"), img)
    r = measure_shots(folder, None, overrides={"pixel_size_um": cfg.pixel_size_um})
    t = r.shots.set_index("file")
    tailed, compact = t.loc["shot_0.png"], t.loc["shot_1.png"]
    truth = _tail_truth(cfg, 1150.0)
    assert truth > 150  # a long tail in the truth
    assert abs(tailed["tail_length_um"] - truth) <= 2 * cfg.pixel_size_um + 0.03 * truth
    assert tailed["drop_volume_nl"] == pytest.approx(frames[0][1].drop_volume_nl, rel=0.01)
    assert not tailed["inflight"] and "tail_joined" in tailed["quality"].split("; ")
    assert "tail is joined" in tailed["notes"] and f"{tailed['tail_length_um']:.0f} um" in tailed["notes"]
    assert abs(compact["tail_length_um"] - _tail_truth(cfg, 1500.0)) <= 2 * cfg.pixel_size_um
    assert compact["inflight"] and compact["quality"] == "ok" and "tail" not in compact["notes"]


def test_velocity_from_a_double_exposure(tmp_path):
    """Two synthetic frames 400 us apart combined into one image (each drop seen twice): the velocity is the
    distance between the main drop's two images over the interval; without the interval none (NaN)."""
    dt = 400.0  # the two images apart (a drop of ~330 um moving ~1.3 m/s)
    cfg = SynthConfig(width_px=256, height_px=1000, delays_us=(1500.0, 1500.0 + dt), seed=5, satellites=0, noise=0.3)
    (a, ta), (b, tb) = synthesize(cfg, progress=False)
    double = np.minimum(a, b)
    folder = tmp_path / "shots"
    folder.mkdir()
    cv2.imwrite(str(folder / "double_1.png"), double)
    cv2.imwrite(str(folder / "single_2.png"), a)
    (folder / "shots.csv").write_text(f"file,strobe_interval_us\ndouble_1.png,{dt}\n")
    r = measure_shots(folder, None, overrides={"pixel_size_um": cfg.pixel_size_um})
    t = r.shots.set_index("file")
    truth = (tb.drop_z_um - ta.drop_z_um) / dt  # um/us = m/s
    v, u = t.loc["double_1.png", "drop_velocity_m_s"], t.loc["double_1.png", "drop_velocity_uncertainty_m_s"]
    assert truth > 1
    assert 0 < u < 0.05 * truth
    assert abs(v - truth) <= 2 * u + 0.01 * truth
    assert np.isnan(t.loc["single_2.png", "drop_velocity_m_s"])
    # the second image is the main drop's, not a satellite (no satellites rendered)
    assert t.loc["double_1.png", "n_satellites"] == t.loc["single_2.png", "n_satellites"] == 0
    assert abs(t.loc["double_1.png", "satellites_volume_nl"]) < 0.01 * t.loc["double_1.png", "drop_volume_nl"]
    assert t.loc["double_1.png", "drop_volume_nl"] == pytest.approx(ta.drop_volume_nl, rel=0.01)
    # the command line's option gives every image the interval (the label, per image, wins)
    (folder / "shots.csv").unlink()
    assert main(["measure", str(folder), "--out", str(tmp_path / "out"), "--pixel-size-um", str(cfg.pixel_size_um),
                 "--strobe-interval-us", str(dt), "-q"]) == 0
    t = pd.read_parquet(tmp_path / "out" / "shots.parquet").set_index("file")
    assert t.loc["double_1.png", "drop_velocity_m_s"] == pytest.approx(v, rel=1e-9)
    with pytest.raises(SystemExit) as exc:  # argparse: one line naming the option, exit 2
        main(["measure", str(folder), "--out", str(tmp_path / "bad"), "--pixel-size-um", "4.73",
              "--strobe-interval-us", "-40", "-q"])
    assert exc.value.code == 2
    assert not (tmp_path / "bad").exists()


@pytest.mark.slow
def test_pendant_drops_of_realdata_in_one_folder_with_only_the_needle_diameter(realdata_dir, tmp_path):
    """The five real pendant drops in one folder, no pixel size: each within 3 % of its reference, its
    pixel size from its own needle (shots.csv gives each its needle's diameter: two needles)."""
    folder = tmp_path / "drops"
    folder.mkdir()
    refs, needles = {}, {}
    for sub in sorted((realdata_dir / "droppytension-saturated").iterdir()):
        if sub.is_dir():
            image = next(sub.glob("*.jpg"))
            shutil.copy(image, folder / image.name)
            refs[image.name] = json.loads((sub / "truth.json").read_text())["attached_volume_nl"]
            needles[image.name] = json.loads((sub / "sequence.json").read_text())["nozzle_outer_diameter_um"]
    menipy = realdata_dir / "menipy-pendant-drop"
    shutil.copy(menipy / "gota_pendiente_1.png", folder / "gota_pendiente_1.png")
    refs["gota_pendiente_1.png"] = json.loads((menipy / "truth.json").read_text())["attached_volume_nl"]
    needles["gota_pendiente_1.png"] = json.loads((menipy / "sequence.json").read_text())["nozzle_outer_diameter_um"]
    (folder / "shots.csv").write_text("file,nozzle_outer_diameter_um\n"
                                      + "".join(f"{k},{v}\n" for k, v in needles.items()))
    with pytest.warns(Warning):  # colour JPEGs converted to grey
        r = measure_shots(folder, None)
    t = r.shots.set_index("file")
    assert len(refs) == 5 and set(t.index) == set(refs)
    for name, ref in refs.items():
        row = t.loc[name]
        assert abs(row["attached_volume_nl"] / ref - 1) < 0.03, name
        assert row["pixel_size_uncertainty_um"] > 0
        assert "pixel_size_mismatch" not in row["quality"]
    # the four drops of one rig: one needle, one camera: their pixel sizes agree within their uncertainties
    dpt = t.loc[[n for n in refs if n.startswith("water")]]
    assert np.ptp(dpt["pixel_size_um"]) <= 2 * dpt["pixel_size_uncertainty_um"].max()



@pytest.mark.parametrize("blur_px", [1.0, 3.0])
def test_one_needle_width_robust_to_blur(blur_px):
    """The needle's width by the one rule (its straight outer walls, the meniscus below them), the opening's
    provisional width and the calibration's the same number, whatever the blur: within 0.1 px of the truth."""
    px = 6.9
    cfg = SynthConfig.for_rig("pendant-saturated", pixel_size_um=px, blur_px=blur_px, seed=1, width_px=480,
                              height_px=480, tip_row=60.4, axis_col=239.6, format="png", colour=False,
                              needle_diameter_um=717.6, pendant_apex_radius_um=1000.0)
    (img, _t), = synthesize(cfg, progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)  # the clipped backlight's note
        provisional, _ = nozzle_outer_width_px([img], max_value=255)
        cal = calibrate_frames(img, [img], 1.0, max_value=255, nozzle_outer_diameter_um=717.6,
                               pixel_size_from_nozzle=True)
    assert abs(cal.nozzle_outer_diameter_px - 717.6 / px) < 0.1
    assert provisional == pytest.approx(cal.nozzle_outer_diameter_px, abs=1e-9)  # one rule, one width
    assert cal.pixel_size_um == pytest.approx(717.6 / cal.nozzle_outer_diameter_px)
    assert np.isnan(cal.pixel_size_ratio) and "disagrees" not in " ".join(cal.notes)
