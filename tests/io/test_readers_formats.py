"""Every image a user has (issue 11 item 1): JPEG (grey and colour), colour PNG, PNM, video
(AVI) and frame-rate stacks, each measured with ``dropvision.measure`` and compared with the
synthesizer's exact truth (truth.json) and with the measurement of the original PNG frames.

Tolerances:
- lossless conversions (grey PNM, colour PNG with R=G=B, FFV1 AVI, numbered PNG stack and
  multi-page TIFF with ``frame_rate_hz``) decode to the very same pixels, so every per-frame
  and summary number must be IDENTICAL to the PNG measurement;
- the tinted colour PNG (R, G, 0.8 B) is a different grey image (BT.601 luminance is 0.977 of
  the grey level, rounded): the same physics within 0.1 % of the PNG measurement;
- JPEG quality 95 (8x8 DCT blocking, ringing at edges): measured errors against truth on this
  sequence: in-flight volume -0.002 % (grey) / +0.026 % (tinted colour), jetting velocity
  -0.107 % for both (the PNG itself: -0.002 % / -0.108 %; quality 90: -0.010 % / -0.110 %;
  MJPG AVI: -0.015 % / -0.110 %). The tests allow the accuracy goals of the clean tier, 0.3 %
  volume and 0.5 % velocity, and the exact pinch-off delay: JPEG error is a small part of them.
"""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

import dropvision
from dropvision.io.readers import IMAGE_SUFFIXES, reader_for
from dropvision.io.readers import base as readers_base
from dropvision.io.readers.base import UnreadableImage
from dropvision.io.readers.jpeg import jpeg_size
from dropvision.io.sequence import RGBConvertedWarning, SequenceError, open_sequence

STEP_US = 20.0
DELAYS = tuple(float(d) for d in np.arange(0.0, 1401.0, STEP_US))
#: per-frame columns that must match exactly for lossless formats
FRAME_COLS = ["delay_us", "grown_volume_nl", "drop_volume_nl", "flow_velocity_m_s", "quality",
              "n_satellites"]
SUMMARY_KEYS = ["inflight_volume_nl", "jetting_velocity_m_s", "pinchoff_us",
                "grown_volume_at_pinchoff_nl"]


@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    """A small synthetic sequence (PNG, 8-bit), its truth and its PNG measurement."""
    from dropvision.synth import SynthConfig, write_synthetic_sequence

    out = tmp_path_factory.mktemp("fmt") / "png"
    cfg = SynthConfig(width_px=192, height_px=640, delays_us=DELAYS, seed=5)
    write_synthetic_sequence(cfg, out, progress=False)
    truth = json.loads((out / "truth.json").read_text())
    doc = json.loads((out / "sequence.json").read_text())
    frames = [(out / f["file"], float(f["delay_us"])) for f in doc["frames"]]
    return {"dir": out, "truth": truth, "doc": doc, "frames": frames,
            "result": dropvision.measure(out)}


def _grey(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img.ndim == 2 and img.dtype == np.uint8
    return img


def _convert(synth, dest: Path, suffix: str, encode) -> Path:
    """Copy the sequence with every frame re-encoded as ``suffix`` by ``encode(grey, path)``."""
    dest.mkdir()
    doc = dict(synth["doc"])
    frames = []
    for path, delay in synth["frames"]:
        name = path.with_suffix(suffix).name
        encode(_grey(path), dest / name)
        frames.append({"file": name, "delay_us": delay})
    doc["frames"] = frames
    (dest / "sequence.json").write_text(json.dumps(doc))
    return dest


def _rate_doc(synth, **keys) -> dict:
    doc = {k: v for k, v in synth["doc"].items() if k != "frames"}
    doc.update(keys)
    return doc


def _measure(folder, colour: bool = False):
    if not colour:
        return dropvision.measure(folder)
    with pytest.warns(RGBConvertedWarning) as rec:
        res = dropvision.measure(folder)
    return res, rec


def _assert_identical(res, ref) -> None:
    a = res.frames[FRAME_COLS].reset_index(drop=True)
    b = ref.frames[FRAME_COLS].reset_index(drop=True)
    assert a.equals(b)
    for key in SUMMARY_KEYS:
        assert res.summary[key] == ref.summary[key], key


def _truth_errors(res, truth) -> dict:
    s = res.summary
    return {"inflight_pct": 100 * (s["inflight_volume_nl"] / truth["inflight_volume_nl"] - 1),
            "velocity_pct": 100 * (s["jetting_velocity_m_s"] / truth["jetting_velocity_m_s"] - 1),
            "pinchoff_ok": s["pinchoff_us"] == truth["pinchoff_us"]}


def _assert_near_truth(res, truth, volume_pct=0.3, velocity_pct=0.5) -> None:
    err = _truth_errors(res, truth)
    assert abs(err["inflight_pct"]) <= volume_pct, err
    assert abs(err["velocity_pct"]) <= velocity_pct, err
    assert err["pinchoff_ok"], err


# --- the reference ------------------------------------------------------------------------

def test_png_reference_meets_truth(synth):
    _assert_near_truth(synth["result"], synth["truth"])


# --- JPEG ---------------------------------------------------------------------------------

def test_grey_jpeg_q95_known_answer(synth, tmp_path):
    folder = _convert(synth, tmp_path / "jpg", ".jpg", lambda g, p: cv2.imwrite(
        str(p), g, [cv2.IMWRITE_JPEG_QUALITY, 95]))
    seq = open_sequence(folder)
    assert seq.meta.bit_depth == 8 and len(seq) == len(DELAYS)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a grey JPEG is not "converted"
        res = dropvision.measure(folder)
    _assert_near_truth(res, synth["truth"])


def test_colour_jpeg_q95_known_answer_and_one_note(synth, tmp_path):
    def encode(g, p):  # tinted: R = G = grey, B = 0.8 grey
        bgr = cv2.merge([(g * 0.8).round().astype(np.uint8), g, g])
        cv2.imwrite(str(p), bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
    folder = _convert(synth, tmp_path / "jpgc", ".jpeg", encode)
    assert jpeg_size((folder / Path(synth["frames"][0][0]).with_suffix(".jpeg").name)
                     .read_bytes())[2] == 3  # really a 3-component JPEG
    res, rec = _measure(folder, colour=True)
    assert len(rec) == 1  # one note per sequence, not one per frame
    assert "BT.601" in str(rec[0].message)
    _assert_near_truth(res, synth["truth"])


def test_jpeg_truncated_frame_is_skipped_and_reported(synth, tmp_path):
    folder = _convert(synth, tmp_path / "cut", ".jpg", lambda g, p: cv2.imwrite(str(p), g))
    victim = folder / Path(synth["frames"][3][0]).with_suffix(".jpg").name
    data = victim.read_bytes()
    victim.write_bytes(data[: len(data) // 2])
    seq = open_sequence(folder)
    fr = seq.read(3)
    assert fr.image is None and "truncated" in fr.error
    assert seq.read(4).image is not None


def test_jpeg_pixel_limit_from_header(tmp_path, monkeypatch):
    path = tmp_path / "a.jpg"
    cv2.imwrite(str(path), np.full((40, 50), 200, np.uint8))
    assert jpeg_size(path.read_bytes()) == (50, 40, 1)
    monkeypatch.setattr(readers_base, "MAX_PIXELS", 1000)
    with pytest.raises(UnreadableImage, match="50x40 pixels"):
        reader_for(path).decode(path, None)


def test_jpeg_decode_identical_to_opencv(tmp_path, realdata_dir):
    """The JPEG reader (imagecodecs' libjpeg-turbo) gives the same arrays, bit for bit, as the
    OpenCV path it replaced (``IMREAD_GRAYSCALE`` for colour, ``IMREAD_UNCHANGED`` for grey):
    the real colour frames of ../shared/realdata (2048x1536 watcher, 752x480 pendant drops) and
    synthetic grey/colour files with odd sizes and 4:4:4 / 4:2:0 subsampling."""
    from dropvision.io.readers.base import ColourLuma
    from dropvision.io.readers.jpeg import JpegReader

    real = sorted(realdata_dir.glob("*/*/*.jpg"))
    assert len(real) >= 12  # the eight watcher frames and four pendant drops
    rng = np.random.default_rng(3)
    made = []
    for k, (h, w) in enumerate([(37, 53), (64, 64), (333, 200)]):
        grey = np.clip(rng.normal(128, 40, (h, w)), 0, 255).astype(np.uint8)
        colour = np.dstack([grey, np.roll(grey, 3, 1), 255 - grey])
        for name, img in ((f"g{k}.jpg", grey), (f"c{k}.jpg", colour)):
            path = tmp_path / name
            cv2.imwrite(str(path), img, [cv2.IMWRITE_JPEG_QUALITY, 90,
                                         cv2.IMWRITE_JPEG_SAMPLING_FACTOR, [0x111111, 0x221111][k % 2]])
            made.append(path)
    reader = JpegReader()
    for path in real + made:
        data = np.fromfile(path, np.uint8)
        colour = jpeg_size(path.read_bytes())[2] == 3
        expected = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION if colour
                                else cv2.IMREAD_UNCHANGED)
        got = reader.decode(path, None)
        assert isinstance(got, ColourLuma) == colour, path
        assert got.dtype == np.uint8 and got.shape == expected.shape, path
        np.testing.assert_array_equal(np.asarray(got), expected, err_msg=str(path))


def test_corrupt_jpeg_scan_is_unreadable(tmp_path):
    """A JPEG whose scan data is garbage (markers intact) is refused with a clear error."""
    path = tmp_path / "bad.jpg"
    cv2.imwrite(str(path), np.full((40, 50, 3), 120, np.uint8))
    data = bytearray(path.read_bytes())
    sos = data.find(b"\xff\xda")
    data[sos + 2:sos + 4] = b"\x00\x02"  # a scan header of impossible length
    path.write_bytes(bytes(data))
    with pytest.raises(UnreadableImage, match="cannot decode JPEG"):
        reader_for(path).decode(path, None)


# --- colour PNG ---------------------------------------------------------------------------

def test_colour_png_equal_channels_identical_to_grey(synth, tmp_path):
    folder = _convert(synth, tmp_path / "rgb", ".png",
                      lambda g, p: cv2.imwrite(str(p), cv2.merge([g, g, g])))
    res, rec = _measure(folder, colour=True)
    assert len(rec) == 1
    _assert_identical(res, synth["result"])


def test_tinted_colour_png_by_luminance(synth, tmp_path):
    def encode(g, p):  # R = G = grey, B = 0.8 grey: luminance 0.977 grey
        cv2.imwrite(str(p), cv2.merge([(g * 0.8).round().astype(np.uint8), g, g]))
    folder = _convert(synth, tmp_path / "tint", ".png", encode)
    first = folder / Path(synth["frames"][0][0]).name
    bgr = cv2.imread(str(first), cv2.IMREAD_UNCHANGED)
    seq = open_sequence(folder)
    with pytest.warns(RGBConvertedWarning):
        grey = seq.read(0).image
    expected = 0.299 * bgr[..., 2] + 0.587 * bgr[..., 1] + 0.114 * bgr[..., 0]
    assert np.abs(grey - expected).max() <= 0.5 + 1e-9  # BT.601, rounded
    res, _ = _measure(folder, colour=True)
    ref = synth["result"].summary
    for key in ("inflight_volume_nl", "jetting_velocity_m_s"):
        assert res.summary[key] == pytest.approx(ref[key], rel=1e-3), key
    assert res.summary["pinchoff_us"] == ref["pinchoff_us"]


# --- PNM ----------------------------------------------------------------------------------

def test_pgm_identical_to_png(synth, tmp_path):
    folder = _convert(synth, tmp_path / "pgm", ".pgm", lambda g, p: cv2.imwrite(str(p), g))
    _assert_identical(dropvision.measure(folder), synth["result"])


def test_pgm_16bit_and_pixel_limit(tmp_path, monkeypatch):
    img = (np.arange(12 * 9, dtype=np.uint16).reshape(12, 9) * 500)
    path = tmp_path / "a_0us.pgm"
    cv2.imwrite(str(path), img)
    assert np.array_equal(reader_for(path).decode(path, None), img)
    monkeypatch.setattr(readers_base, "MAX_PIXELS", 100)
    with pytest.raises(UnreadableImage, match="9x12 pixels"):
        reader_for(path).decode(path, None)


# --- video and frame-rate stacks ----------------------------------------------------------

def _write_video(synth, path: Path, fourcc: str) -> None:
    h, w = _grey(synth["frames"][0][0]).shape
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 50.0, (w, h), False)
    assert vw.isOpened()
    for frame, _ in synth["frames"]:
        vw.write(_grey(frame))
    vw.release()


@pytest.mark.slow
def test_ffv1_avi_with_frame_rate_identical_to_png(synth, tmp_path):
    folder = tmp_path / "avi"
    folder.mkdir()
    _write_video(synth, folder / "recording.avi", "FFV1")
    # delays = first_frame_delay_us + (i - trigger_frame) * 1e6 / frame_rate_hz = 20 i
    (folder / "sequence.json").write_text(json.dumps(_rate_doc(
        synth, frame_rate_hz=1e6 / STEP_US, first_frame_delay_us=2 * STEP_US, trigger_frame=2)))
    seq = open_sequence(folder)
    assert len(seq) == len(DELAYS)
    assert [f.page for f in seq.meta.frames] == list(range(len(DELAYS)))
    assert np.array_equal(seq.meta.delays_us, DELAYS)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # grey video: no colour note
        res = dropvision.measure(folder)
    _assert_identical(res, synth["result"])
    _assert_near_truth(res, synth["truth"])


def test_mjpg_avi_named_by_video_key(synth, tmp_path):
    folder = tmp_path / "mjpg"
    folder.mkdir()
    _write_video(synth, folder / "cam.avi", "MJPG")
    (folder / "notes.txt").write_text("not an image")
    (folder / "sequence.json").write_text(json.dumps(_rate_doc(
        synth, video="cam.avi", frame_rate_hz=1e6 / STEP_US)))
    res = dropvision.measure(folder)
    # MJPG is JPEG at OpenCV's default quality 95: the JPEG tolerances
    _assert_near_truth(res, synth["truth"])


def test_video_cut_short_frames_reported(synth, tmp_path):
    folder = tmp_path / "cutavi"
    folder.mkdir()
    _write_video(synth, folder / "rec.avi", "MJPG")
    data = (folder / "rec.avi").read_bytes()
    (folder / "rec.avi").write_bytes(data[: int(len(data) * 0.6)])
    (folder / "sequence.json").write_text(json.dumps(_rate_doc(synth, frame_rate_hz=5e4)))
    seq = open_sequence(folder)
    frames = list(seq)
    bad = [f for f in frames if f.image is None]
    good = [f for f in frames if f.image is not None]
    assert bad and len(good) >= len(frames) // 2
    assert all("cannot decode video frame" in f.error for f in bad)


def test_numbered_png_stack_with_frame_rate_identical(synth, tmp_path):
    folder = tmp_path / "stack"
    folder.mkdir()
    for i, (path, _) in enumerate(synth["frames"]):
        shutil.copy(path, folder / f"img{i + 1}.png")  # natural order: img2 before img10
    (folder / "sequence.json").write_text(json.dumps(_rate_doc(
        synth, frame_rate_hz=1e6 / STEP_US, trigger_frame=0)))
    seq = open_sequence(folder)
    assert seq.meta.frames[10].file == "img11.png" and seq.meta.frames[10].delay_us == 200.0
    _assert_identical(dropvision.measure(folder), synth["result"])


def test_multipage_tiff_with_frame_rate_identical(synth, tmp_path):
    folder = tmp_path / "tifstack"
    folder.mkdir()
    tifffile.imwrite(folder / "stack.tif", np.stack([_grey(p) for p, _ in synth["frames"]]))
    (folder / "sequence.json").write_text(json.dumps(_rate_doc(
        synth, frame_rate_hz=1e6 / STEP_US)))
    _assert_identical(dropvision.measure(folder), synth["result"])


@pytest.mark.parametrize("keys, match", [
    ({"frame_rate_hz": 0.5}, "frame_rate_hz 0.5 is outside the accepted range 1..1e\\+07 Hz"),
    ({"frame_rate_hz": 2e7}, "outside the accepted range 1..1e\\+07 Hz"),
    ({"frame_rate_hz": "fast"}, "frame_rate_hz must be a number"),
    ({"video": "x.avi"}, "video given without frame_rate_hz"),
    ({"trigger_frame": 3}, "trigger_frame given without frame_rate_hz"),
    ({"frame_rate_hz": 1e4, "trigger_frame": 1.5}, "trigger_frame must be an integer"),
    ({"frame_rate_hz": 1e4, "video": "missing.avi"}, "missing"),
    ({"frame_rate_hz": 1e4, "video": "../x.avi"}, "outside the sequence folder"),
    ({"frame_rate_hz": 1.0, "first_frame_delay_us": 9.5e6}, "gets delay"),
    ({"frame_rate_hz": 1e4, "frames": [{"file": "a.png", "delay_us": 0}]}, "not both"),
])
def test_frame_rate_validation(tmp_path, keys, match):
    cv2.imwrite(str(tmp_path / "a.png"), np.full((20, 20), 200, np.uint8))
    cv2.imwrite(str(tmp_path / "b.png"), np.full((20, 20), 200, np.uint8))
    (tmp_path / "sequence.json").write_text(json.dumps({"pixel_size_um": 2.0, **keys}))
    with pytest.raises(SequenceError, match=match):
        open_sequence(tmp_path)


def test_video_beside_other_images_needs_video_key(synth, tmp_path):
    _write_video(synth, tmp_path / "rec.avi", "FFV1")
    cv2.imwrite(str(tmp_path / "extra.png"), np.full((20, 20), 200, np.uint8))
    (tmp_path / "sequence.json").write_text(json.dumps({"pixel_size_um": 2.0,
                                                        "frame_rate_hz": 1e4}))
    with pytest.raises(SequenceError, match='name the recording with "video"'):
        open_sequence(tmp_path)


def test_video_without_frame_rate_says_how(synth, tmp_path):
    _write_video(synth, tmp_path / "rec.avi", "FFV1")
    (tmp_path / "sequence.json").write_text(json.dumps({"pixel_size_um": 2.0}))
    with pytest.raises(SequenceError, match="frame_rate_hz"):
        open_sequence(tmp_path)


def test_video_pixel_limit_from_header(synth, tmp_path, monkeypatch):
    _write_video(synth, tmp_path / "rec.avi", "FFV1")
    (tmp_path / "sequence.json").write_text(json.dumps({"pixel_size_um": 2.0,
                                                        "frame_rate_hz": 1e4}))
    seq = open_sequence(tmp_path)
    monkeypatch.setattr(readers_base, "MAX_PIXELS", 1000)
    fr = seq.read(1)
    assert fr.image is None and "over the limit" in fr.error


def test_no_readable_suffix_refused():
    for suffix in (".jpg", ".jpeg", ".jpe", ".png", ".tif", ".tiff", ".bmp", ".avi", ".mp4",
                   ".mov", ".pgm", ".ppm"):
        assert suffix in IMAGE_SUFFIXES and reader_for("x" + suffix.upper()) is not None


def test_colour_jpeg_exif_orientation_is_ignored(tmp_path):
    """A colour JPEG is decoded to its luma; its EXIF orientation tag must not turn it (the
    sequence's `orientation` says how frames are turned)."""
    from PIL import Image

    from dropvision.io.readers.jpeg import JpegReader

    rgb = np.zeros((40, 60, 3), np.uint8)
    rgb[:, :30] = (200, 180, 160)
    exif = Image.Exif()
    exif[274] = 6  # rotate 90 degrees when displayed
    path = tmp_path / "tagged.jpg"
    Image.fromarray(rgb).save(path, quality=95, exif=exif)
    grey = JpegReader().decode(path, None)
    assert grey.shape == (40, 60)
    assert grey[:, :25].mean() > 150 and grey[:, 35:].mean() < 20
