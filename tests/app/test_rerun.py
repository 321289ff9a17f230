"""Rerun logging (dropvision/rerun_log.py, identify/rerun_log.py): write tiny .rrd files and read
them back with the SDK's independent reader ``rerun.chunk.RrdReader``; check entity paths,
timeline values and logged values against the inputs (known answers).

No warning filters are needed: reading and writing emit no warnings with rerun-sdk 0.41.
"""

from __future__ import annotations

import argparse
import math
import pickle
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from dropvision.app.rerun_log import (
    CLASS_ATTACHED,
    CLASS_BORDER,
    CLASS_DROP,
    CLASS_NOZZLE,
    CLASS_OUT_OF_FOCUS,
    CLASS_SATELLITE,
    CLASS_SPECK,
    CLASS_TAIL,
    CLASS_TOUCHING,
    CLASSES,
    LABELLED_CLASSES,
    RerunLogger,
    body_labels,
    logger_from_args,
)
from identify.app import rerun_log as irl
from dvcore import rerun_options as rst
from dvcore.rerun_options import RerunOptions, add_rerun_args, options_from_args

ROWS, COLS = 48, 64
DELAYS_US = [0.0, 30.5, 1150.25]
PIXEL_UM = 4.0
TIP_ROW, AXIS_COL = 9.0, 31.0


from rrdtools import Rrd  # noqa: E402  (reader shared with other tests)


# --- synthetic frame data ----------------------------------------------------------------------


@dataclass(frozen=True)
class FrameRefLike:  # same fields as dropvision.io.sequence.FrameRef (interfaces.md)
    index: int
    file: str
    page: int | None
    delay_us: float
    repeat: int


@dataclass(frozen=True)
class CalibrationLike:
    tip_row: float
    axis_col: float
    tilt_deg: float
    pixel_size_um: float
    method: str



def _labels(i: int) -> np.ndarray:
    lab = np.zeros((ROWS, COLS), dtype=np.int32)
    lab[: int(TIP_ROW) + 1, 24:40] = CLASS_NOZZLE
    lab[10:16, 28:35] = CLASS_ATTACHED
    lab[20 + 5 * i:26 + 5 * i, 29:34] = CLASS_DROP
    lab[40, 50:52] = CLASS_SATELLITE
    lab[3, 3] = CLASS_SPECK
    return lab


def _frame(i: int):
    rng = np.random.default_rng(i)
    image = rng.integers(0, 256, size=(ROWS, COLS), dtype=np.uint8)
    transmission = np.linspace(-0.2, 1.3, ROWS * COLS).reshape(ROWS, COLS)
    edges = np.array([[28.25 + i, 20.5], [33.75, 21.0 + i], [30.0, 25.5]])
    bodies = [
        {"bbox": (29, 20 + 5 * i, 34, 26 + 5 * i), "class": "main drop", "volume_nl": 2.0 + i},
        {"bbox": (50, 40, 52, 41), "class_id": CLASS_SATELLITE},
    ]
    row = {
        "file": f"f_{i}.png",
        "grown_volume_nl": 1.5 * i + 0.25,
        "drop_volume_nl": math.nan if i == 0 else 10.0 + i,
        "flow_velocity_m_s": 1.3 - 0.1 * i,
        "drop_z_um": math.nan if i == 0 else 60.0 * i,
        "drop_x_um": 0.0 if i == 0 else 4.0 * i,
        "n_satellites": i,
        "quality": "ok" if i else "low contrast",
    }
    ref = FrameRefLike(index=i, file=f"f_{i}.png", page=None, delay_us=DELAYS_US[i], repeat=0)
    # the measurement may pass a row of its frames DataFrame (a pandas Series) or a dict
    return ref, image, transmission, _labels(i), edges, bodies, (pd.Series(row) if i == 2 else row)


@pytest.fixture(scope="module")
def measured_rrd(tmp_path_factory) -> tuple[Path, list]:
    path = tmp_path_factory.mktemp("rrd") / "sub" / "seq.rrd"  # parent folder created on open
    frames = [_frame(i) for i in range(len(DELAYS_US))]
    with RerunLogger(RerunOptions(path=path, application_id="dv_test", recording_name="seq")) as logger:
        logger.log_calibration({"tip_row": TIP_ROW, "axis_col": AXIS_COL, "tilt_deg": 0.0,
                                "pixel_size_um": PIXEL_UM})
        for frame in frames:
            logger.log_frame(*frame)
        logger.log_summary({"inflight_volume_nl": 12.345, "fit": {"pinchoff_us": 1050.0}})
    return path, frames


# --- measurement logger ------------------------------------------------------------------------


def test_entities_and_timelines(measured_rrd):
    path, _ = measured_rrd
    rrd = Rrd(path)
    assert [s.application_id for s in rrd.reader.recordings()] == ["dv_test"]
    expected = {"/frame", "/frame/transmission", "/frame/segmentation", "/frame/axis",
                "/frame/tip_plane", "/frame/edges", "/frame/bodies", "/frame/track", "/frame/drop",
                "/series/volume_nl/grown", "/series/volume_nl/drop", "/series/velocity_m_s/flow",
                "/series/position_um/drop_z", "/series/position_um/drop_x",
                "/series/count/satellites", "/log", "/summary", "/calibration"}
    assert expected <= rrd.entities()
    assert "/frame/raw" not in rrd.entities()  # the raw frame only on request (test_images)
    grown = rrd.series("/series/volume_nl/grown", "Scalars:scalars")
    # delay timeline: integer nanoseconds; frame timeline: processing index
    assert grown["delay_ns"].tolist() == [0, 30_500, 1_150_250]
    assert grown["frame"].tolist() == [0, 1, 2]
    assert [v[0] for v in grown["value"]] == [0.25, 1.75, 3.25]
    # NaN values are not logged (gaps, not zeros)
    drop = rrd.series("/series/volume_nl/drop", "Scalars:scalars")
    assert drop["delay_ns"].tolist() == [30_500, 1_150_250]
    assert [v[0] for v in drop["value"]] == [11.0, 12.0]
    # no wall-clock timeline
    for batches in rrd.temporal.values():
        assert "log_time" not in batches[0].schema.names


def test_annotation_context_and_segmentation(measured_rrd):
    path, frames = measured_rrd
    rrd = Rrd(path)
    context = rrd.static["/frame"]["AnnotationContext:context"][0]
    classes = {c["class_id"]: c["class_description"]["info"]["label"] for c in context}
    assert classes == {cid: label for cid, (label, _colour) in CLASSES.items()}
    assert classes[CLASS_DROP] == "main drop" and classes[CLASS_OUT_OF_FOCUS].startswith("out of focus (mist")
    assert set(classes) == set(range(10))
    # every body class its own hue (the screenshot check tells them apart by hue)
    import colorsys

    hues = [colorsys.rgb_to_hsv(*(c / 255 for c in colour[:3]))[0] * 360
            for cid, (_label, colour) in CLASSES.items() if cid not in (0, CLASS_NOZZLE)]
    gaps = [abs((a - b + 180) % 360 - 180) for i, a in enumerate(hues) for b in hues[i + 1:]]
    assert min(gaps) > 12
    seg = rrd.series("/frame/segmentation", "SegmentationImage:buffer")
    fmt = rrd.series("/frame/segmentation", "SegmentationImage:format")
    for i, (buf, f) in enumerate(zip(seg["value"], fmt["value"])):
        assert (f[0]["width"], f[0]["height"]) == (COLS, ROWS)
        labels = np.asarray(buf[0], dtype=np.uint8).reshape(ROWS, COLS)
        np.testing.assert_array_equal(labels, frames[i][3])
        assert set(np.unique(labels)) == {0, 1, 2, 3, 4, 5}


def _decode_jpeg(blob) -> np.ndarray:
    import io

    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(bytes(np.asarray(blob, np.uint8)))))


def test_images(measured_rrd, tmp_path):
    # default: the normalised frame as a JPEG (a few kB), no raw frame
    path, frames = measured_rrd
    rrd = Rrd(path)
    blobs = rrd.series("/frame/transmission", "EncodedImage:blob")["value"]
    media = rrd.series("/frame/transmission", "EncodedImage:media_type")["value"]
    assert len(blobs) == len(frames)
    for i in range(len(frames)):
        assert media[i] == ["image/jpeg"]
        decoded = _decode_jpeg(blobs[i][0])
        expected = np.round(np.clip(frames[i][2], 0, 1) * 255).astype(np.uint8)
        assert decoded.shape == (ROWS, COLS)
        assert np.abs(decoded.astype(int) - expected).max() <= 8  # JPEG quality 90, lossy
    # on request (RerunOptions.raw / --rerun-raw): the raw frame too, unchanged
    raw_path = tmp_path / "raw.rrd"
    with RerunLogger(path=raw_path, raw=True) as logger:
        for frame in frames:
            logger.log_frame(*frame)
    raw = Rrd(raw_path).series("/frame/raw", "Image:buffer")["value"]
    for i in range(len(frames)):
        np.testing.assert_array_equal(np.asarray(raw[i][0], np.uint8).reshape(ROWS, COLS), frames[i][1])
    assert [k[0] for k in _view_kinds(Rrd(raw_path))].count("2D") == 3  # camera | normalised | raw tabs


def test_geometry_overlays(measured_rrd):
    path, frames = measured_rrd
    rrd = Rrd(path)
    # dropvision pixel centres are integers; Rerun's are at +0.5
    edges = rrd.series("/frame/edges", "Points2D:positions")["value"]
    for i in range(len(frames)):
        np.testing.assert_allclose(np.asarray(edges[i]), frames[i][4] + 0.5)
    axis = np.asarray(rrd.static["/frame/axis"]["LineStrips2D:strips"][0])
    np.testing.assert_allclose(axis[:, 0], AXIS_COL + 0.5)
    np.testing.assert_allclose(axis[:, 1], [0.0, ROWS])  # whole image height
    tip = np.asarray(rrd.static["/frame/tip_plane"]["LineStrips2D:strips"][0])
    np.testing.assert_allclose(tip[:, 1], TIP_ROW + 0.5)
    np.testing.assert_allclose(tip[:, 0], [0.0, COLS])
    centers = rrd.series("/frame/bodies", "Boxes2D:centers")["value"]
    half = rrd.series("/frame/bodies", "Boxes2D:half_sizes")["value"]
    ids = rrd.series("/frame/bodies", "Boxes2D:class_ids")["value"]
    for i in range(len(frames)):
        assert ids[i] == [CLASS_DROP, CLASS_SATELLITE]
        x0, y0, x1, y1 = frames[i][5][0]["bbox"]
        np.testing.assert_allclose(centers[i][0], [(x0 + x1) / 2, (y0 + y1) / 2])
        np.testing.assert_allclose(half[i][0], [(x1 - x0) / 2, (y1 - y0) / 2])
    # drop centroid from the table (z along the axis, x across) and the calibration
    drop = rrd.series("/frame/drop", "Points2D:positions")
    expected_from_table = [
        (AXIS_COL + 4.0 * i / PIXEL_UM + 0.5, TIP_ROW + 60.0 * i / PIXEL_UM + 0.5) for i in (1, 2)]
    np.testing.assert_allclose([v[0] for v in drop["value"][1:]], expected_from_table)
    # frame 0 has no z: centre of the main-drop box (slice convention, no shift)
    np.testing.assert_allclose(drop["value"][0][0], [31.5, 23.0])
    track = rrd.series("/frame/track", "LineStrips2D:strips")
    assert track["frame"].tolist() == [1, 2]  # a line needs two points
    np.testing.assert_allclose(track["value"].iloc[-1][0],
                               [[31.5, 23.0], *expected_from_table])


def test_texts_and_blueprint(measured_rrd):
    path, _ = measured_rrd
    rrd = Rrd(path)
    summary = rrd.static["/summary"]["TextDocument:text"][0]
    assert "| inflight_volume_nl | 12.345 |" in summary and "| fit.pinchoff_us | 1050 |" in summary
    assert "| tip_row [px] | 9 |" in rrd.static["/calibration"]["TextDocument:text"][0]
    log = rrd.series("/log", "TextLog:text")["value"].tolist()
    assert log[0] == ["frame 0 delay 0 us f_0.png: low contrast"]
    assert rrd.series("/log", "TextLog:level")["value"].tolist() == [["WARN"], ["INFO"], ["INFO"]]
    # the blueprint travels in the same file
    (blueprint,) = rrd.reader.blueprints()
    kinds, origins = [], []
    for chunk in rrd.reader.stream(store=blueprint):
        batch = chunk.to_record_batch()
        if "ViewBlueprint:class_identifier" in batch.schema.names:
            kinds += batch.column("ViewBlueprint:class_identifier").to_pylist()
            origins += batch.column("ViewBlueprint:space_origin").to_pylist()
    kinds = [k[0] for k in kinds]
    assert kinds.count("2D") == 2 and kinds.count("TimeSeries") == 3  # camera | normalised; no raw tab without raw
    assert ["/series/volume_nl"] in origins and ["/frame"] in origins and ["/"] in origins  # / : the camera's frame
    # the frame gets the room: selection and blueprint panels collapsed, the time panel on the
    # delay timeline collapsed to its scrubber (PanelState 2 = collapsed)
    panels = {}
    for chunk in rrd.reader.stream(store=blueprint):
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if name.endswith(":state"):
                panels[chunk.entity_path] = batch.column(name).to_pylist()[-1]
        if "TimePanelBlueprint:timeline" in batch.schema.names:
            assert batch.column("TimePanelBlueprint:timeline").to_pylist()[-1] == ["delay"]
    assert panels == {"/time_panel": [2], "/selection_panel": [2], "/blueprint_panel": [2]}
    # the axis and tip-plane lines carry no visible label (they covered the drops)
    assert rrd.static["/frame/axis"]["LineStrips2D:show_labels"] == [False]
    assert rrd.static["/frame/tip_plane"]["LineStrips2D:show_labels"] == [False]
    assert all(v == [False] for v in rrd.series("/frame/drop", "Points2D:show_labels")["value"])


def test_tilted_calibration_lines(tmp_path):
    tilt_deg = 5.0
    path = tmp_path / "tilt.rrd"
    logger = RerunLogger(RerunOptions(path=path))
    logger.log_calibration(CalibrationLike(10.0, 30.0, tilt_deg, 2.0, "edge fit"), shape=(ROWS, COLS))
    logger.log_frame({"index": 0, "delay_us": 500.0}, None, None, None, None, None,
                     {"drop_z_um": 40.0, "drop_x_um": 0.0})
    logger.close()
    rrd = Rrd(path)
    assert "| method | edge fit |" in rrd.static["/calibration"]["TextDocument:text"][0]
    t = math.radians(tilt_deg)
    pivot = np.array([30.5, 10.5])
    axis = np.asarray(rrd.static["/frame/axis"]["LineStrips2D:strips"][0]) - pivot
    tip = np.asarray(rrd.static["/frame/tip_plane"]["LineStrips2D:strips"][0]) - pivot
    # axis along (sin t, cos t) through the tip point; tip plane perpendicular to it
    np.testing.assert_allclose(axis[:, 0] * math.cos(t) - axis[:, 1] * math.sin(t), 0.0, atol=1e-4)
    np.testing.assert_allclose(tip @ np.array([math.sin(t), math.cos(t)]), 0.0, atol=1e-4)
    drop = np.asarray(rrd.series("/frame/drop", "Points2D:positions")["value"][0][0])
    np.testing.assert_allclose(drop - pivot, 20.0 * np.array([math.sin(t), math.cos(t)]), atol=1e-5)


@dataclass(frozen=True)
class BodyLike:  # like dropvision.frame.segmentation.DarkBody plus a class (half-open box, ROI coordinates)
    label: int
    x0: int
    y0: int
    x1: int
    y1: int
    class_id: int


def test_roi_coordinates_and_keyword_constructor(tmp_path):
    path = tmp_path / "roi.rrd"
    with pytest.raises(ValueError, match="application id 'dropvision.measurement'"):
        RerunLogger(path=path, app_id="dropvision.measurement")  # rerun would rename it "dropvision-measureea52"
    logger = RerunLogger(path=path, app_id="dropvision-measure")
    roi = np.zeros((10, 20), np.uint16)
    roi[2:5, 3:6] = CLASS_DROP
    body = BodyLike(label=7, x0=3, y0=2, x1=6, y1=5, class_id=CLASS_DROP)
    logger.log_frame({"index": 0, "delay_us": 1.0}, np.zeros((ROWS, COLS), np.uint8), None, roi,
                     np.array([[3.0, 2.0]]), [body], None, roi_origin_xy=(30, 5))
    logger.close()
    rrd = Rrd(path)
    assert [s.application_id for s in rrd.reader.recordings()] == ["dropvision-measure"]
    labels = np.asarray(rrd.series("/frame/segmentation", "SegmentationImage:buffer")["value"][0][0])
    expected = np.zeros((ROWS, COLS), np.uint8)
    expected[7:10, 33:36] = CLASS_DROP
    np.testing.assert_array_equal(labels.reshape(ROWS, COLS), expected)
    np.testing.assert_allclose(rrd.series("/frame/edges", "Points2D:positions")["value"][0], [[33.5, 7.5]])
    np.testing.assert_allclose(rrd.series("/frame/bodies", "Boxes2D:centers")["value"][0], [[34.5, 8.5]])
    np.testing.assert_allclose(rrd.series("/frame/drop", "Points2D:positions")["value"][0], [[34.5, 8.5]])
    with pytest.raises(TypeError, match="not both"):
        RerunLogger(RerunOptions(path=path), path=path)


def test_two_loggers_are_independent(tmp_path):
    import rerun as rr

    a = RerunLogger(RerunOptions(path=tmp_path / "a.rrd", application_id="dv_a"))
    b = RerunLogger(RerunOptions(path=tmp_path / "b.rrd", application_id="dv_b"))
    for i in range(2):
        a.log_frame({"index": i, "delay_us": 10.0 * i}, None, None, None, None, None, {"grown_volume_nl": 1.0 + i})
        b.log_frame({"index": i, "delay_us": 20.0 * i}, None, None, None, None, None, {"grown_volume_nl": 5.0 + i})
    a.close()
    b.close()
    a.close()  # idempotent
    assert rr.get_global_data_recording() is None  # never touched the global stream
    ga = Rrd(tmp_path / "a.rrd").series("/series/volume_nl/grown", "Scalars:scalars")
    gb = Rrd(tmp_path / "b.rrd").series("/series/volume_nl/grown", "Scalars:scalars")
    assert ga["delay_ns"].tolist() == [0, 10_000] and [v[0] for v in ga["value"]] == [1.0, 2.0]
    assert gb["delay_ns"].tolist() == [0, 20_000] and [v[0] for v in gb["value"]] == [5.0, 6.0]
    with pytest.raises(RuntimeError, match="closed"):
        a.log_summary({})


def _worker_writes(path: str) -> str:
    logger = RerunLogger(RerunOptions(path=Path(path), application_id="dv_worker"))
    logger.log_frame({"index": 0, "delay_us": 250.0}, None, None, None, None, None, {"grown_volume_nl": 7.5})
    logger.close()
    return path


@pytest.mark.slow
def test_logger_in_worker_process(tmp_path):
    options = RerunOptions(path=tmp_path / "w.rrd")
    assert pickle.loads(pickle.dumps(options)) == options
    with ProcessPoolExecutor(1, mp_context=get_context("spawn")) as pool:
        path = pool.submit(_worker_writes, str(options.path)).result(timeout=60)
    grown = Rrd(Path(path)).series("/series/volume_nl/grown", "Scalars:scalars")
    assert grown["delay_ns"].tolist() == [250_000] and grown["value"].tolist() == [[7.5]]


def test_bad_inputs(tmp_path):
    logger = RerunLogger(RerunOptions(path=tmp_path / "bad.rrd"))
    ref = {"index": 0, "delay_us": 0.0}
    img = np.zeros((ROWS, COLS), np.uint8)
    with pytest.raises(ValueError, match="labels shape"):
        logger.log_frame(ref, img, None, np.zeros((ROWS, COLS + 1), int), None, None, None)
    with pytest.raises(ValueError, match="class ids 0..9"):
        logger.log_frame(ref, img, None, np.full((ROWS, COLS), 10), None, None, None)
    with pytest.raises(ValueError, match=r"edges must be an \(N, 2\)"):
        logger.log_frame(ref, None, None, None, np.zeros((3, 3)), None, None)
    with pytest.raises(ValueError, match="unknown class 'blob'"):
        logger.log_frame(ref, None, None, None, None, [{"bbox": (0, 0, 1, 1), "class": "blob"}], None)
    # a frame without a nozzle (issue 29): no tip plane, the axis still drawn; nothing refused
    logger.log_calibration({"tip_row": math.nan, "axis_col": 3.0}, shape=(ROWS, COLS))
    assert logger._calibration.tip_row is None and logger._calibration.axis_col == 3.0 and logger._lines_logged
    with pytest.raises(TypeError, match="pass RerunOptions"):
        pickle.dumps(logger)
    logger.close()


# --- command line / logging off ------------------------------------------------------------------


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser()
    add_rerun_args(parser)
    return parser


def test_cli_flags(tmp_path):
    args = _parser().parse_args(["--rerun", str(tmp_path / "x.rrd")])
    opts = options_from_args(args, "dv_cli", recording_name="seq")
    assert opts == RerunOptions(path=tmp_path / "x.rrd", application_id="dv_cli", recording_name="seq")
    assert opts.for_sequence("d 01/a").path == tmp_path / "x-d_01_a.rrd"
    connect = options_from_args(_parser().parse_args(["--rerun-connect"]))
    assert connect.connect_url == rst.DEFAULT_VIEWER_URL and connect.path is None
    assert options_from_args(_parser().parse_args(["--rerun-spawn"])).spawn
    assert not opts.raw
    assert options_from_args(_parser().parse_args(["--rerun", str(tmp_path / "x.rrd"), "--rerun-raw"])).raw
    from dvcore.errors import UsageError

    with pytest.raises(UsageError, match="is a directory"):
        options_from_args(_parser().parse_args(["--rerun", str(tmp_path)]))


def test_logging_off_creates_no_stream(monkeypatch):
    import rerun as rr

    def forbidden(*args, **kwargs):
        raise AssertionError("a RecordingStream was created with logging off")

    monkeypatch.setattr(rr, "RecordingStream", forbidden)
    args = _parser().parse_args([])
    assert logger_from_args(args, "dv") is None
    assert irl.recording_from_args(args) is None
    assert logger_from_args(argparse.Namespace(), "dv") is None  # parser without the flags


def test_logging_off_does_not_import_rerun():
    code = textwrap.dedent("""
        import argparse, sys
        from dropvision.app.rerun_log import logger_from_args
        from dvcore.rerun_options import add_rerun_args
        from identify.app.rerun_log import recording_from_args
        p = argparse.ArgumentParser(); add_rerun_args(p); a = p.parse_args([])
        assert logger_from_args(a, "dv") is None and recording_from_args(a) is None
        assert not [m for m in sys.modules if m == "rerun" or m.startswith(("rerun.", "rerun_"))], "rerun imported"
    """)
    subprocess.run([sys.executable, "-c", code], check=True, cwd=Path(__file__).parents[2], timeout=60)


# --- identification ----------------------------------------------------------------------------


def test_identify_logging(tmp_path):
    path = tmp_path / "identify.rrd"
    rec = irl.open_identify_recording(RerunOptions(path=path, application_id="dv_identify"))
    t_us = np.array([220.0, 500.0, 1000.0, 1200.5])
    measured = np.array([0.5, 8.0, math.nan, 17.0])
    sim_t = np.arange(0.0, 1300.0, 100.0)
    simulated = 0.01 * sim_t
    irl.log_sequence_fit(rec, "u1=70 u2=25", t_us, measured, simulated, sim_t_us=sim_t,
                         measured_flow_m_s=[1.0, 1.3, 0.2, -0.1], simulated_flow_m_s=np.ones(sim_t.size))
    cv = pd.DataFrame({"rmse_volume_nl": [0.12, 0.34], "n": [5, 6]}, index=pd.Index(["fold 1", "fold 2"], name="fold"))
    irl.log_cv_table(rec, cv, value_column="rmse_volume_nl")
    band_t = np.array([300.0, 600.0, 900.0])
    irl.log_monte_carlo_band(rec, "u1=70 u2=25", band_t, [1.0, 2.0, 3.0], [0.9, 1.8, 2.7], [1.1, 2.2, 3.3])
    with pytest.raises(ValueError, match="low > high"):
        irl.log_monte_carlo_band(rec, "bad", band_t, [1, 2, 3], [1, 2, 3], [0, 0, 0])
    with pytest.raises(ValueError, match="simulated_volume_nl has 4 values, expected 13"):
        irl.log_sequence_fit(rec, "bad", t_us, measured, measured, sim_t_us=sim_t)
    with pytest.raises(ValueError, match="value_column 'cv'"):
        irl.log_cv_table(rec, cv, value_column="cv")
    irl.close_recording(rec)

    rrd = Rrd(path)
    seq = "u1\\=70\\ u2\\=25"  # rr.escape_entity_path_part
    m = rrd.series(f"/identify/volume_nl/{seq}/measured", "Scalars:scalars")
    assert m["delay_ns"].tolist() == [220_000, 500_000, 1_200_500]  # NaN skipped
    assert [v[0] for v in m["value"]] == [0.5, 8.0, 17.0]
    s = rrd.series(f"/identify/volume_nl/{seq}/simulated", "Scalars:scalars")
    assert s["delay_ns"].tolist() == [int(x) * 1000 for x in sim_t]
    np.testing.assert_allclose([v[0] for v in s["value"]], simulated)
    f = rrd.series(f"/identify/flow_m_s/{seq}/measured", "Scalars:scalars")
    assert [v[0] for v in f["value"]] == [1.0, 1.3, 0.2, -0.1]
    for kind, expected in (("mean", [1.0, 2.0, 3.0]), ("low", [0.9, 1.8, 2.7]), ("high", [1.1, 2.2, 3.3])):
        band = rrd.series(f"/identify/monte_carlo/volume_nl/{seq}/{kind}", "Scalars:scalars")
        assert band["delay_ns"].tolist() == [300_000, 600_000, 900_000]
        np.testing.assert_allclose([v[0] for v in band["value"]], expected)
    table = rrd.static["/identify/cv/table"]["TextDocument:text"][0]
    assert "| fold | rmse_volume_nl | n |" in table and "| fold 2 | 0.34 | 6 |" in table
    np.testing.assert_allclose(rrd.static["/identify/cv/bar"]["BarChart:values"][0]["buffer"], [0.12, 0.34])
    # a band was logged: the prediction views (incl. the 2-D (u1, u2) plane) are in the layout
    assert {k[0] for k in _view_kinds(rrd)} == {"TimeSeries", "TextDocument", "BarChart", "2D"}
    fill = rrd.series(f"/identify/monte_carlo/volume_nl/{seq}/fill", "Scalars:scalars")
    assert fill["delay_ns"].min() == 300_000 and fill["delay_ns"].max() == 900_000
    assert min(v[0] for v in fill["value"]) == pytest.approx(0.9)
    assert max(v[0] for v in fill["value"]) == pytest.approx(3.3)


def _colour(rrd: Rrd, entity: str, archetype: str) -> int:
    return rrd.static[entity][f"{archetype}:colors"][0]


@pytest.fixture(scope="module")
def identification_rrd(tmp_path_factory):
    from identify.dataset_checks import load_dataset
    from identify.synthetic_dataset import make_synthetic_dataset
    from identify.hybrid_fit import fit_hybrid

    base = tmp_path_factory.mktemp("ident")
    grid = [(a, b) for a in (55.0, 70.0, 85.0) for b in (20.0, 35.0)]
    make_synthetic_dataset(base / "ds", grid=grid, noise_percent=1.0, seed=3, repeats=1)
    ds = load_dataset(base / "ds")
    model = fit_hybrid(ds, arx=False).model
    mc = model.monte_carlo(70.0, 25.0, samples=300, seed=0, band=True)
    path = base / "identify.rrd"
    rec = irl.open_identify_recording(RerunOptions(path=path, application_id="dv_identify"))
    irl.log_model_fit(rec, ds, model)
    irl.log_prediction(rec, mc)  # the model of log_model_fit gives the intervals
    irl.close_recording(rec)
    return Rrd(path), grid, model.interval_prediction(70.0, 25.0, mc=mc), model, ds


def test_identification_view_colours_and_names(identification_rrd):
    rrd, grid, *_ = identification_rrd
    parts = [f"u1\\={a:g}\\ u2\\={b:g}" for a, b in grid]  # rr.escape_entity_path_part
    colours = []
    for name, part in zip((irl.control_name(a, b) for a, b in grid), parts):
        base = f"/identify/volume_nl/{part}"
        measured = _colour(rrd, f"{base}/measured", "SeriesPoints")
        # measured points and simulated line of one sequence share its colour; so do the
        # pinch-off markers (cross: measured, diamond: simulated) and the flow series
        assert measured == _colour(rrd, f"{base}/simulated", "SeriesLines")
        assert measured == _colour(rrd, f"{base}/pinchoff", "SeriesPoints")
        assert measured == _colour(rrd, f"/identify/flow_m_s/{part}/simulated", "SeriesLines")
        assert rrd.static[f"{base}/pinchoff"]["SeriesPoints:markers"][0] != \
            rrd.static[f"{base}/pinchoff_simulated"]["SeriesPoints:markers"][0]
        # legends name series by (u1, u2), never 16 identical "simulated", with the fit's RMSE
        assert rrd.static[f"{base}/simulated"]["SeriesLines:names"][0].startswith(f"{name} simulated (RMSE ")
        assert len(rrd.series(f"{base}/pinchoff", "Scalars:scalars")) == 1
        colours.append(measured)
    assert len(set(colours)) == len(grid)  # one colour per sequence
    # the training points in the (u1, u2) plane carry the same colours
    pts = rrd.static["/identify/controls/training"]
    assert sorted(map(tuple, pts["Points2D:positions"])) == sorted(grid)
    assert sorted(pts["Points2D:colors"]) == sorted(colours)
    # fit table worst first, and one small multiple per sequence
    table = rrd.static["/identify/fit/table"]["TextDocument:text"][0]
    rmse = [float(line.split("|")[4]) for line in table.splitlines() if line.startswith("| u1=")]
    assert len(rmse) == len(grid) and rmse == sorted(rmse, reverse=True)
    kinds = [k[0] for k in _view_kinds(rrd)]
    assert kinds.count("TimeSeries") == len(grid) + 4 and kinds.count("2D") == 1
    assert kinds.count("3D") == 3 and kinds.count("BarChart") == 2  # surfaces; RMSE and CV bars


def test_identification_view_prediction(identification_rrd):
    rrd, grid, iv, *_ = identification_rrd
    seq = "u1\\=70\\ u2\\=25"
    base = f"/identify/monte_carlo/volume_nl/{seq}"
    for kind in ("mean", "low", "high", "fill"):
        assert f"{base}/{kind}" in rrd.entities()
    lo = np.concatenate(rrd.series(f"{base}/low", "Scalars:scalars")["value"])
    hi = np.concatenate(rrd.series(f"{base}/high", "Scalars:scalars")["value"])
    assert np.all(hi >= lo - 1e-12)
    # the intervals at the pinch-off: confidence inside prediction, equal to interval_prediction
    for output, quantity in (("inflight_volume_nl", "volume_nl"), ("jetting_velocity_m_s", "flow_m_s"),
                             ("pinchoff_us", "volume_nl")):
        b = f"/identify/monte_carlo/{quantity}/{seq}/{output}"
        e = iv[output]
        for kind in ("confidence", "prediction"):
            df = rrd.series(f"{b}/{kind}", "Scalars:scalars")
            ends = (df["delay_ns"].to_numpy() / 1000.0 if output == "pinchoff_us"
                    else np.concatenate(df["value"].to_numpy()))
            key = {"confidence": "mean_drop", "prediction": "one_drop"}[kind]
            np.testing.assert_allclose(sorted(ends), [e[f"{key}_low"], e[f"{key}_high"]], atol=1e-3)
        assert e["one_drop_low"] <= e["mean_drop_low"] <= e["mean"] <= e["mean_drop_high"] <= e["one_drop_high"]
    pred = rrd.static["/identify/controls/prediction"]
    assert [tuple(p) for p in pred["Points2D:positions"]] == [(70.0, 25.0)]
    assert "prediction u1=70 u2=25" in pred["Points2D:labels"][0]
    table = rrd.static["/identify/prediction/table"]["TextDocument:text"][0]
    assert "| inflight_volume_nl |" in table and "one drop (prediction) high" in table and "parameters only low" in table


def _view_kinds(rrd: Rrd) -> list:
    (blueprint,) = rrd.reader.blueprints()
    out = []
    for chunk in rrd.reader.stream(store=blueprint):
        batch = chunk.to_record_batch()
        if "ViewBlueprint:class_identifier" in batch.schema.names:
            out += batch.column("ViewBlueprint:class_identifier").to_pylist()
    return out


def test_identification_view_worst_fit(identification_rrd):
    """Which sequence fits worst: RMSE bars worst first (= the fit table), RMSE labels on the
    training points, a frame around the worst one."""
    rrd, grid, *_ = identification_rrd
    table = rrd.static["/identify/fit/table"]["TextDocument:text"][0]
    rows = [line.split("|") for line in table.splitlines() if line.startswith("| u1=")]
    rmse = [float(r[4]) for r in rows]
    bars = rrd.static["/identify/fit/rmse_nl"]["BarChart:values"][0]["buffer"]
    np.testing.assert_allclose(bars, rmse, rtol=1e-3)
    assert np.all(np.diff(bars) <= 0)
    pts = rrd.static["/identify/controls/training"]
    labels = dict(zip(map(tuple, pts["Points2D:positions"]), pts["Points2D:labels"]))
    worst_name = rows[0][1].strip()
    worst = next(p for p in grid if irl.control_name(*p) == worst_name)
    assert labels[worst].startswith("worst: ") and sum(lb.startswith("worst") for lb in labels.values()) == 1
    for row in rows:  # every label is the RMSE of its sequence
        u1, u2 = float(row[2]), float(row[3])
        assert float(labels[(u1, u2)].removeprefix("worst: ").removesuffix(" nl")) == pytest.approx(float(row[4]), rel=0.05)
    assert pts["Points2D:show_labels"] == [True]
    box = rrd.static["/identify/controls/worst"]
    assert [tuple(c) for c in box["Boxes2D:centers"]] == [worst]
    # the prediction among the training grid: box and crosshair through (70, 25)
    pbox = rrd.static["/identify/controls/prediction_box"]
    assert [tuple(c) for c in pbox["Boxes2D:centers"]] == [(70.0, 25.0)]
    assert pbox["Boxes2D:labels"][0].startswith("prediction ")
    cross = rrd.static["/identify/controls/prediction_crosshair"]["LineStrips2D:strips"]
    horizontal, vertical = (np.asarray(c) for c in cross)
    assert np.all(horizontal[:, 1] == 25.0) and horizontal[:, 0].min() < 55 and horizontal[:, 0].max() > 85
    assert np.all(vertical[:, 0] == 70.0) and vertical[:, 1].min() < 20 and vertical[:, 1].max() > 35


def test_identification_view_surfaces(identification_rrd):
    """Pinch-off and adjuster polynomials over (u1, u2): mesh values, training targets, residual
    lines and the prediction, against the model and identify.app.report.training_targets."""
    from identify.app.report import training_targets

    rrd, grid, _, model, ds = identification_rrd
    targets = training_targets(model, ds)
    for attr, column, _title, unit in irl.SURFACES:
        poly = getattr(model, attr)
        base = f"/identify/surfaces/{attr}"
        assert rrd.static[base]["ViewCoordinates:xyz"] is not None  # z up
        verts = np.asarray(rrd.static[f"{base}/mesh"]["Mesh3D:vertex_positions"], dtype=float)
        assert verts.shape == (25 * 25, 3)
        assert verts[:, 0].min() == 55.0 and verts[:, 0].max() == 85.0
        assert verts[:, 1].min() == 20.0 and verts[:, 1].max() == 35.0
        np.testing.assert_allclose(verts[:, 2], poly.predict(verts[:, 0], verts[:, 1]), rtol=1e-5,
                                   atol=1e-6 * np.abs(verts[:, 2]).max())
        tri = np.asarray(rrd.static[f"{base}/mesh"]["Mesh3D:triangle_indices"])
        assert tri.shape == (2 * 24 * 24, 3) and tri.max() == 25 * 25 - 1
        assert len(rrd.static[f"{base}/mesh"]["Mesh3D:vertex_colors"]) == 25 * 25
        # training targets at their true values (hover shows them), residual line to the surface
        pts = np.asarray(rrd.static[f"{base}/training"]["Points3D:positions"], dtype=float)
        expect = targets[["u1_um_per_ms", "u2_um", column]].to_numpy(float)
        np.testing.assert_allclose(pts[np.lexsort(pts[:, :2].T)], expect[np.lexsort(expect[:, :2].T)],
                                   rtol=1e-5, atol=1e-9)
        for strip in rrd.static[f"{base}/residuals"]["LineStrips3D:strips"]:
            (a1, a2, target), (b1, b2, surface) = np.asarray(strip, dtype=float)
            assert (a1, a2) == (b1, b2)
            assert surface == pytest.approx(float(poly.predict(np.array([a1]), np.array([a2]))[0]), rel=1e-5, abs=1e-9)
        assert all(unit in lb and "residual" in lb for lb in rrd.static[f"{base}/training"]["Points3D:labels"])
        # the value axis is scaled for display (Transform3D), the values themselves are not
        scale = np.asarray(rrd.static[f"{base}/mesh"]["Transform3D:scale"][0], dtype=float)
        assert scale[0] == scale[1] == 1.0 and scale[2] > 0
        # the prediction at (70, 25) on the surface
        (p,) = np.asarray(rrd.static[f"{base}/prediction"]["Points3D:positions"], dtype=float)
        assert tuple(p[:2]) == (70.0, 25.0)
        assert p[2] == pytest.approx(float(poly.predict(np.array([70.0]), np.array([25.0]))[0]), rel=1e-5, abs=1e-9)


# --- body classes in the measurement view ------------------------------------------------------


def _detached(bbox, top, bottom, *, volume_nl=0.01, length_um=16.0, touching=False, leaves=False):
    from dropvision.frame.bodies import DetachedBody

    return DetachedBody(volume_nl=volume_nl, z_um=0.0, x_um=0.0, length_um=length_um, diameter_um=10.0,
                        top_row=float(top), bottom_row=float(bottom), leaves=leaves, out_of_band=False,
                        on_dust=False, bbox=bbox, touching=touching)


def test_class_image_rejected_and_touching_bodies():
    """dropvision.app.rerun_log.class_image, a pure function: segmentation + the frame's bodies in,
    class image and one box per body (per part of a split silhouette) out."""
    from dropvision.app.rerun_log import class_image
    from dropvision.frame.segmentation import find_nozzle_body, segment

    mask = np.zeros((64, 40), np.uint8)
    mask[0:10, 15:25] = 255  # nozzle with attached liquid (touches the top)
    mask[20:26, 16:24] = 255  # main drop, rows 20-25 ...
    mask[26:30, 18:22] = 255  # ... and a satellite touching it below its waist (one silhouette)
    mask[34:38, 18:22] = 255  # satellite
    mask[40:52, 19:21] = 255  # tail: 12 rows, thin
    mask[42:47, 2:7] = 255  # out of focus (mist)
    mask[58:64, 30:35] = 255  # cut by the bottom of the frame
    mask[12:14, 30:33] = 255  # joined to the attached liquid by a thread (in neither list)
    opaque = np.zeros(mask.shape, bool)
    opaque[60:62, 2:4] = True  # a static speck
    seg = segment(mask, 4)
    nozzle = find_nozzle_body(seg.bodies, 20.0)
    main = _detached((16, 20, 24, 30), 20, 25, volume_nl=0.2)
    touching = _detached((16, 20, 24, 30), 25, 29, volume_nl=0.02, touching=True)
    bodies = [main, _detached((30, 58, 35, 64), 58, 63, volume_nl=0.05, leaves=True),
              _detached((19, 40, 21, 52), 40, 51, volume_nl=0.001, length_um=48.0),  # d_eq 12.4 um
              touching, _detached((18, 34, 22, 38), 34, 37, volume_nl=0.01, length_um=16.0)]  # d_eq 26.7 um
    rejected = [_detached((2, 42, 7, 47), 42, 46, volume_nl=0.03)]
    labels, boxes = class_image(seg, nozzle, bodies, rejected, opaque, compact_ratio=2.0)

    expected = np.zeros(mask.shape, np.uint8)
    expected[0:10, 15:25] = CLASS_ATTACHED
    expected[20:26, 16:24] = CLASS_DROP
    expected[26:30, 18:22] = CLASS_TOUCHING
    expected[34:38, 18:22] = CLASS_SATELLITE
    expected[40:52, 19:21] = CLASS_TAIL
    expected[42:47, 2:7] = CLASS_OUT_OF_FOCUS
    expected[58:64, 30:35] = CLASS_BORDER
    expected[12:14, 30:33] = CLASS_ATTACHED
    expected[60:62, 2:4] = CLASS_SPECK
    np.testing.assert_array_equal(labels, expected)
    assert labels.dtype == np.uint8 and mask.max() == 255  # inputs untouched
    got = sorted((b["bbox"], b["class_id"], b.get("volume_nl")) for b in boxes)
    assert got == sorted([
        ((15, 0, 25, 10), CLASS_ATTACHED, None), ((30, 12, 33, 14), CLASS_ATTACHED, None),
        ((16, 20, 24, 26), CLASS_DROP, 0.2), ((18, 26, 22, 30), CLASS_TOUCHING, 0.02),  # a box per part
        ((18, 34, 22, 38), CLASS_SATELLITE, 0.01), ((19, 40, 21, 52), CLASS_TAIL, 0.001),
        ((2, 42, 7, 47), CLASS_OUT_OF_FOCUS, 0.03), ((30, 58, 35, 64), CLASS_BORDER, 0.05)])
    # a touching satellite above the main drop takes the rows above it
    up = _detached((16, 20, 24, 30), 20, 25, volume_nl=0.01, touching=True)
    low = _detached((16, 20, 24, 30), 25, 29, volume_nl=0.3)
    labels2, _ = class_image(seg, nozzle, [low, up], (), None)
    assert (labels2[20:25, 16:24] == CLASS_TOUCHING).all() and (labels2[25:30, 18:22] == CLASS_DROP).all()
    # no bodies: every detached silhouette is attached liquid (joined), nothing else
    labels3, boxes3 = class_image(seg, nozzle)
    assert set(np.unique(labels3)) == {0, CLASS_ATTACHED} and len(boxes3) == len(seg.bodies)


@dataclass(frozen=True)
class _Box:  # what body_labels reads of a box (full-frame, half-open)
    x0: float
    y0: float
    x1: float
    y1: float
    class_id: int
    volume_nl: float | None
    centroid_xy: tuple[float, float] | None


def test_body_labels_do_not_overlap():
    boxes = [_Box(10, 100, 40, 130, CLASS_DROP, 18.9, None),
             _Box(20, 130, 30, 136, CLASS_TOUCHING, 0.4, None),  # right under the drop
             _Box(22, 140, 28, 144, CLASS_SATELLITE, 0.2, None),
             _Box(0, 120, 8, 128, CLASS_OUT_OF_FOCUS, 0.1, None),  # hover only
             _Box(10, 0, 50, 20, CLASS_ATTACHED, None, None)]
    placed = body_labels(boxes, 13.0)
    assert [c for _, c, _ in placed] == [CLASS_DROP, CLASS_TOUCHING, CLASS_SATELLITE]
    assert [t for _, _, t in placed] == ["main drop 18.9 nl", "touching satellite 0.4 nl", "satellite 0.2 nl"]
    ys = [p[1] for p, _, _ in placed]
    assert ys[0] == 115.0 and all(b - a >= 13.0 for a, b in zip(ys, ys[1:]))
    for (x, _y), _c, text in placed:  # the label (centred on its point) starts right of every box
        assert x - 0.5 * 0.42 * 13.0 * len(text) > 40
    assert set(LABELLED_CLASSES) == {CLASS_DROP, CLASS_SATELLITE, CLASS_TOUCHING, CLASS_TAIL}
    assert body_labels([boxes[-1]], 13.0) == []


@pytest.fixture(scope="module")
def misty_rrd(tmp_path_factory):
    """A small synthetic sequence measured with a Rerun logger; its last frame holds an
    out-of-focus droplet beside the jet (mist)."""
    import cv2

    from dropvision.measurement import measure_sequence
    from dropvision.io.sequence import sequence_from_arrays
    from dropvision.synth import SynthConfig, synthesize

    cfg = SynthConfig(u1_um_per_ms=62, u2_um=30, satellites=2, width_px=320, height_px=700, seed=5, dust=0,
                      delays_us=(0.0, 300.0, 600.0, 900.0, 1200.0, 1350.0))
    frames, delays = [], []
    for img, truth in synthesize(cfg, progress=False):
        if len(frames) == 5:
            disc = np.zeros(img.shape, np.float32)
            cv2.circle(disc, (120, 400), 6, 1.0, -1)
            disc = cv2.GaussianBlur(disc, (0, 0), 4.0)
            img = np.clip(img * (1.0 - 0.8 * disc / disc.max()), 0, 255).astype(np.uint8)
        frames.append(img)
        delays.append(truth.delay_us)
    seq = sequence_from_arrays(frames, delays_us=delays, pixel_size_um=cfg.pixel_size_um,
                               nozzle_inner_diameter_um=cfg.physics.nozzle_inner_radius_um * 2,
                               nozzle_outer_diameter_um=cfg.physics.nozzle_outer_radius_um * 2)
    path = tmp_path_factory.mktemp("mist") / "mist.rrd"
    with RerunLogger(path=path) as logger:
        result = measure_sequence(seq, logger=logger)
    return Rrd(path), result


def test_out_of_focus_body_logs_its_class(misty_rrd):
    rrd, result = misty_rrd
    b = result.bodies
    mist = b[b["body_class"] == "mist"]
    assert len(mist) == 1 and mist["delay_us"].iloc[0] == 1350.0
    seg = rrd.series("/frame/segmentation", "SegmentationImage:buffer")
    fmt = rrd.series("/frame/segmentation", "SegmentationImage:format")
    ids = rrd.series("/frame/bodies", "Boxes2D:class_ids")
    for k, delay_us in enumerate(result.frames["delay_us"]):
        w, h = fmt["value"][k][0]["width"], fmt["value"][k][0]["height"]
        labels = np.asarray(seg["value"][k][0], np.uint8).reshape(h, w)
        has = (labels == CLASS_OUT_OF_FOCUS).any()
        assert has == (delay_us == 1350.0)
        if has:  # the droplet drawn at row 400, column 120, all of it, and nothing else
            rows, cols = np.nonzero(labels == CLASS_OUT_OF_FOCUS)
            assert abs(rows.mean() - 400) < 1 and abs(cols.mean() - 120) < 1 and rows.size > 50
            assert np.hypot(rows - 400, cols - 120).max() < 10
            assert CLASS_OUT_OF_FOCUS in ids["value"][ids["delay_ns"] == 1_350_000].iloc[0]
    # the frame's main drop and satellites keep their classes; only they are labelled
    last = ids["value"][ids["delay_ns"] == 1_350_000].iloc[0]
    assert sorted(last) == sorted([CLASS_ATTACHED, CLASS_DROP, CLASS_SATELLITE, CLASS_SATELLITE, CLASS_OUT_OF_FOCUS])
    texts = rrd.series("/frame/labels", "Points2D:labels")
    shown = texts["value"][texts["delay_ns"] == 1_350_000].iloc[0]
    assert [t.split(" ")[0] for t in shown] == ["satellite", "satellite", "main"]  # top to bottom


# --- issue 33: the frame as the camera took it is the main view; one frame gets a table ------------


@pytest.mark.parametrize("orientation", ["left", "up", "right"])
def test_camera_frame_is_the_stored_one_and_overlays_are_placed_on_it(tmp_path, orientation):
    """/camera holds the frame as stored (the canonical one turned back); the static transform of /frame
    maps every canonical pixel onto the same pixel of the stored frame (checked on the pixel corners)."""
    from dropvision.io.orientation import canonical_to_original, from_canonical

    path = tmp_path / "cam.rrd"
    frames = [_frame(i) for i in range(2)]
    with RerunLogger(path=path) as logger:
        logger.log_calibration({"tip_row": TIP_ROW, "axis_col": AXIS_COL, "tilt_deg": 0.0,
                                "pixel_size_um": PIXEL_UM}, shape=(ROWS, COLS), orientation=orientation)
        for frame in frames:
            logger.log_frame(*frame)
    rrd = Rrd(path)
    blobs = rrd.series("/camera", "EncodedImage:blob")["value"]
    assert len(blobs) == len(frames)
    for blob, frame in zip(blobs, frames):
        decoded = _decode_jpeg(blob[0])
        stored = from_canonical(frame[1], orientation)
        assert decoded.shape == stored.shape == ((ROWS, COLS) if orientation == "up" else (COLS, ROWS))
        assert np.abs(decoded.astype(int) - stored.astype(int)).mean() < 12  # JPEG of noise: lossy, same image
    tf = rrd.static["/frame"]
    angle = tf["Transform3D:rotation_axis_angle"][0]
    t = np.asarray(tf["Transform3D:translation"][0], float)
    a = float(angle["angle"]) * np.sign(angle["axis"][2])  # stored in radians
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    for r, c in [(0, 0), (ROWS - 1, 0), (5, COLS - 1), (ROWS - 1, COLS - 1)]:
        x, y = rot @ np.array([c + 0.5, r + 0.5]) + t[:2]  # Rerun: pixel (r, c) centred at (c + .5, r + .5)
        rs, cs = canonical_to_original(r, c, orientation, (ROWS, COLS))
        assert (x, y) == pytest.approx((cs + 0.5, rs + 0.5), abs=1e-4)
    # the main view is the camera's (origin /), with the overlays
    assert [k[0] for k in _view_kinds(rrd)].count("2D") == 2


def test_a_single_frame_gets_a_table_not_time_series_of_one_point(tmp_path):
    path = tmp_path / "one.rrd"
    ref, image, transmission, labels, edges, bodies, row = _frame(1)
    with RerunLogger(path=path) as logger:
        logger.log_calibration({"tip_row": TIP_ROW, "axis_col": AXIS_COL, "tilt_deg": 0.0,
                                "pixel_size_um": PIXEL_UM}, shape=(ROWS, COLS), n_frames=1)
        logger.log_frame(ref, image, transmission, labels, edges, bodies, row)
        logger.log_table(pd.DataFrame([{**row, "delay_us": ref.delay_us}]))
    rrd = Rrd(path)
    assert not any(e.startswith("/series/") and e in rrd.temporal for e in rrd.entities())
    table = rrd.static["/table"]["TextDocument:text"][0]
    assert "| grown_volume_nl | 1.75 |" in table and "| drop_volume_nl | 11 |" in table
    # the layout sent once the logger knows the sequence is one frame (made active): the table, no time series
    layouts = []
    for store in rrd.reader.blueprints():
        views = []
        for chunk in rrd.reader.stream(store=store):
            batch = chunk.to_record_batch()
            if "ViewBlueprint:class_identifier" in batch.schema.names:
                views += zip([k[0] for k in batch.column("ViewBlueprint:class_identifier").to_pylist()],
                             [o[0] for o in batch.column("ViewBlueprint:space_origin").to_pylist()])
        layouts.append(views)
    single = [v for v in layouts if ("TextDocument", "/table") in v]
    assert len(single) == 1
    kinds = [k for k, _ in single[0]]
    assert "TimeSeries" not in kinds and kinds.count("2D") == 2 and ("2D", "/") in single[0]


def test_a_folder_of_shots_gets_its_frames_bars_and_table(tmp_path):
    """issue 33: a shot table gets a table and per-shot plots (bars), each shot as the camera stored it
    with its bodies' outlines; no time series (shots have no time between them)."""
    import cv2

    from dropvision.app.cli import main
    from dropvision.io.orientation import from_canonical
    from dropvision.synth import SynthConfig, synthesize

    cfg = SynthConfig(u1_um_per_ms=62, u2_um=30, satellites=1, width_px=240, height_px=700,
                      delays_us=(1300.0, 1400.0), seed=3, dust=0)
    folder = tmp_path / "shots"
    folder.mkdir()
    for name, (img, _) in zip(("a.png", "b.png"), synthesize(cfg, progress=False)):
        cv2.imwrite(str(folder / name), from_canonical(img, "left"))
    path = tmp_path / "shots.rrd"
    assert main(["measure", str(folder), "--out", str(tmp_path / "r"), "--pixel-size-um", str(cfg.pixel_size_um),
                 "--orientation", "left", "--rerun", str(path), "-q"]) == 0
    shots = pd.read_parquet(tmp_path / "r" / "shots.parquet")
    bodies = pd.read_parquet(tmp_path / "r" / "bodies.parquet")
    rrd = Rrd(path)
    batches = rrd.temporal["/camera/image"]
    shot_index = [v for b in batches for v in b.column("shot").to_pylist()]
    assert sorted(shot_index) == [0, 1]
    stored = cv2.imread(str(folder / "a.png"), cv2.IMREAD_GRAYSCALE)
    blob = [v for b in batches for v in b.column("EncodedImage:blob").to_pylist()][shot_index.index(0)]
    assert _decode_jpeg(blob[0]).shape == stored.shape  # the shot as stored (drops travel left)
    strips = [v for b in rrd.temporal["/camera/bodies"] for v in b.column("LineStrips2D:strips").to_pylist()]
    assert sorted(len(s) for s in strips) == sorted(bodies.groupby("file").size().tolist())
    bars = rrd.static["/shots/drop_volume_nl"]["BarChart:values"][0]["buffer"]
    np.testing.assert_allclose(bars, shots["drop_volume_nl"].fillna(0.0), rtol=1e-6)
    table = rrd.static["/shots/table"]["TextDocument:text"][0]
    assert "| 0 | a.png |" in table and "| 1 | b.png |" in table
    layouts = []
    for store in rrd.reader.blueprints():
        kinds = []
        for chunk in rrd.reader.stream(store=store):
            batch = chunk.to_record_batch()
            if "ViewBlueprint:class_identifier" in batch.schema.names:
                kinds += [k[0] for k in batch.column("ViewBlueprint:class_identifier").to_pylist()]
        layouts.append(kinds)
    assert any(k.count("BarChart") == 3 and "TimeSeries" not in k and "2D" in k for k in layouts)
