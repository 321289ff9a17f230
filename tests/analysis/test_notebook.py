"""The notebook workflow (issue 33 item 2): `result.annotate`, per-body outlines in the camera's and the
canonical frame, camera centroids in bodies, `open_sequence` keyword arguments, errors in the caller's
words, a short repr."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.colors as mcolors  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import dropvision  # noqa: E402
from dropvision.output.annotate import CLASS_COLOURS  # noqa: E402
from dropvision.measurement import measure_sequence  # noqa: E402
from dropvision.io.orientation import from_canonical  # noqa: E402
from dropvision.frame.outline import from_camera, to_camera  # noqa: E402
from dropvision.io.sequence import SequenceError, sequence_from_arrays  # noqa: E402
from dropvision.synth import SynthConfig, synthesize  # noqa: E402

DELAYS = [600.0, 1300.0, 1400.0]


@pytest.fixture(scope="module")
def synthetic():
    cfg = SynthConfig(u1_um_per_ms=62, u2_um=30, satellites=1, width_px=240, height_px=700, delays_us=DELAYS,
                      seed=3, dust=0)
    frames = [img for img, _ in synthesize(cfg, progress=False)]
    return cfg, frames


def _measure(cfg, frames, orientation):
    stored = [from_canonical(f, orientation) for f in frames]
    seq = sequence_from_arrays(stored, delays_us=DELAYS, pixel_size_um=cfg.pixel_size_um, orientation=orientation,
                               nozzle_inner_diameter_um=cfg.physics.nozzle_inner_radius_um * 2,
                               nozzle_outer_diameter_um=cfg.physics.nozzle_outer_radius_um * 2)
    return measure_sequence(seq), stored


@pytest.fixture(scope="module")
def down(synthetic):
    return _measure(*synthetic, "down")


@pytest.fixture(scope="module")
def left(synthetic):
    return _measure(*synthetic, "left")


def test_annotate_draws_one_outline_per_body_in_its_class_colour(down):
    res, stored = down
    k = len(DELAYS) - 1  # detached: attached liquid, a main drop, a satellite
    ax = res.annotate(k, image=stored[k])
    row = res.frames.iloc[k]
    mine = res.bodies[(res.bodies["delay_us"] == row["delay_us"]) & (res.bodies["repeat"] == row["repeat"])]
    assert len(mine) >= 2 and {"attached", "main_drop"} <= set(mine["body_class"])
    outlines = [ln for ln in ax.lines if ln.get_label().startswith("body ")]
    assert len(outlines) == len(mine)
    for ln, (_, b) in zip(outlines, mine.iterrows()):
        assert ln.get_label() == f"body {b['body_id']}: {b['body_class']}"
        assert mcolors.to_hex(ln.get_color()) == CLASS_COLOURS[b["body_class"]]
        x, y = ln.get_data()
        # the outline surrounds the body's centroid in the camera's frame
        assert x.min() <= b["col_camera_px"] <= x.max() and y.min() <= b["row_camera_px"] <= y.max()
    assert [ln for ln in ax.lines if ln.get_label() == "axis"]
    texts = " ".join(t.get_text() for t in ax.texts)
    assert "main drop" in texts and "nl" in texts
    assert ax.images[0].get_array().shape == stored[k].shape


def test_outlines_in_camera_frame_match_a_rotated_frame(down, left):
    """The same frames stored turned a quarter (drops travel left): the camera outlines are the canonical
    ones mapped into the stored frame, and they round-trip back within 0.5 px."""
    res_d, _ = down
    res_l, stored_l = left
    canon_shape = res_d.summary["calibration"].get("shape") or (700, 240)
    assert len(res_l.outlines) == len(res_l.bodies) == len(res_l.outlines_camera)
    main_d = int(np.flatnonzero(res_d.bodies["body_class"] == "main_drop")[-1])
    main_l = int(np.flatnonzero(res_l.bodies["body_class"] == "main_drop")[-1])
    np.testing.assert_allclose(res_l.outlines[main_l], res_d.outlines[main_d], atol=0.5)
    cam = res_l.outlines_camera[main_l]
    expected = to_camera(res_d.outlines[main_d], "left", canon_shape)
    np.testing.assert_allclose(cam, expected, atol=0.5)
    back = from_camera(cam, "left", stored_l[-1].shape)
    np.testing.assert_allclose(back, res_l.outlines[main_l], atol=0.5)
    # a drop travelling left: the camera's outline lies where the stored image is dark
    r, c = np.round(cam).astype(int).T
    assert np.median(stored_l[-1][r, c]) < 0.8 * np.median(stored_l[-1])


def test_bodies_have_camera_centroids_and_the_attached_body_a_position(left):
    res, stored = left
    b = res.bodies
    assert b[["row_px", "col_px", "row_camera_px", "col_camera_px"]].notna().all().all()
    att = b[b["body_class"] == "attached"].iloc[0]
    h = stored[0].shape[0]
    # left: camera (r, c) = (canonical col, Hc-1 - canonical row), Hc = stored width
    assert att["row_camera_px"] == pytest.approx(att["col_px"])
    assert att["col_camera_px"] == pytest.approx(stored[0].shape[1] - 1 - att["row_px"])
    assert 0 <= att["row_camera_px"] < h


def test_short_repr(down):
    res, _ = down
    text = repr(res)
    assert 2 <= len(text.splitlines()) <= 6 and len(text) < 600
    assert "pinch-off" in text and "in-flight volume" in text


def test_annotate_in_memory_needs_the_image(down):
    with pytest.raises(ValueError, match="give the image"):
        down[0].annotate(0)


def test_open_sequence_takes_measure_keywords(tmp_path, down):
    import cv2
    folder = tmp_path / "seq"
    folder.mkdir()
    cv2.imwrite(str(folder / "f_100us.png"), down[1][0])
    seq = dropvision.open_sequence(folder, pixel_size_um=3, orientation="down")
    assert seq.meta.pixel_size_um == 3 and seq.meta.sources["pixel_size"] == "argument pixel_size_um"
    seq.close()
    with pytest.raises(TypeError, match="pixel_size_um given both"):
        dropvision.open_sequence(folder, pixel_size_um=3, overrides={"pixel_size_um": 4})
    with pytest.raises(TypeError, match="unknown keyword argument pixel_size"):
        dropvision.open_sequence(folder, pixel_size=3)
    # a Python caller is told the keyword, the command line its option
    with pytest.raises(SequenceError, match="pixel_size_um=") as info:
        dropvision.open_sequence(folder)
    assert "--pixel-size-um" not in str(info.value)
    with pytest.raises(SequenceError, match="--pixel-size-um"):
        dropvision.open_sequence(folder, labels={"_caller": "command line"})


def test_annotate_a_shot_reads_the_image_as_stored(tmp_path, synthetic):
    """A folder of shots (no delays: one image per firing), stored turned (drops travel right): the shot
    is read back from the folder as the camera stored it and drawn with its bodies."""
    import cv2
    cfg, frames = synthetic
    folder = tmp_path / "shots"
    folder.mkdir()
    for name, img in (("a.png", frames[-1]), ("b.png", frames[-2])):
        cv2.imwrite(str(folder / name), from_canonical(img, "right"))
    res = dropvision.measure_shots(folder, overrides={"pixel_size_um": cfg.pixel_size_um, "orientation": "right"})
    assert "2 of 2 shot(s)" in repr(res)
    ax = res.annotate("b.png")
    assert ax.images[0].get_array().shape == from_canonical(frames[-2], "right").shape
    mine = res.bodies[res.bodies["file"] == "b.png"]
    outlines = [ln for ln in ax.lines if ln.get_label().startswith("body ")]
    assert len(outlines) == len(mine) >= 2
    assert [ln.get_label().split(": ")[1] for ln in outlines] == list(mine["body_class"])


def test_clip_rows_gives_one_run_of_a_lobe():
    """A silhouette split at a waist: each lobe's outline is the silhouette's between its rows, one run
    of points whatever point the contour started at."""
    from dropvision.frame.outline import clip_rows
    t = np.linspace(0, 2 * np.pi, 80, endpoint=False)
    circle = np.column_stack([50 + 20 * np.sin(t), 30 + 20 * np.cos(t)]).astype(np.float32)
    for shift in (0, 17, 45):
        ring = np.roll(circle, shift, axis=0)
        top = clip_rows(ring, 0, 50)
        assert (top[:, 0] <= 50).all() and len(top) == int((circle[:, 0] <= 50).sum())
        steps = np.hypot(*np.diff(top, axis=0).T)
        assert steps.max() < 2.0  # contiguous: no jump across the cut


def test_init_refusal_in_the_callers_words(tmp_path):
    (tmp_path / "sequence.json").write_text('{"pixel_size_um": 2.5}')
    with pytest.raises(SequenceError, match=r"overwrite=True replaces it") as info:
        dropvision.init_sequence(tmp_path)
    assert "--overwrite" not in str(info.value)
    with pytest.raises(SequenceError, match=r"--overwrite replaces it"):
        dropvision.init_sequence(tmp_path, labels={"_caller": "command line"})


def test_annotate_labels_the_main_drop_with_the_frames_volume(realdata_dir):
    """A satellite split off the main drop at its waist keeps its volume in the main drop's (frames,
    summary): the main drop's label gives that volume, and its own part beside it."""
    import warnings

    from dropvision.io.sequence import RGBConvertedWarning
    import matplotlib.pyplot

    from dropvision.output.annotate import _fmt

    seq = realdata_dir / "watcher-dod" / "V1--98_V2-12_V3--10_w1-26_w2-10_w3-1_d1-7_d2-5"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RGBConvertedWarning)  # its JPEG is stored as colour
        res = dropvision.measure(seq)
    ax = res.annotate(0)
    whole = float(res.frames["drop_volume_nl"].iloc[0])
    part = float(res.bodies.loc[res.bodies["body_class"] == "main_drop", "volume_nl"].iloc[0])
    assert whole > 1.02 * part  # this frame's 1.6 nl satellite touches the main drop
    texts = [t.get_text() for t in ax.texts if t.get_text().startswith("main drop")]
    assert texts == [f"main drop {_fmt(whole, 'nl')} (this part {_fmt(part, 'nl')})"]
    matplotlib.pyplot.close(ax.figure)
