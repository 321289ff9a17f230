"""A frame whose nozzle walls show no edge (black, uniform: the hostile corpus's jpeg_named_png)
has an unmeasurable blur: NaN in frames.parquet, flagged ``blurred``, never infinite.

The frames table holds no infinities (`dvcore.schema.check_table`, which the campaign applies when
it reads a shard back): the measurement writes what its readers accept, so a campaign over a
folder holding such a frame measures it instead of failing on its own shard.
"""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pandas as pd
import pytest

from dropvision.app.campaign import run_campaign
from dropvision.calibrate.calibration_pass import calibrate_sequence
from dropvision.frame.measure_frame import measure_photometry
from dropvision.measurement import measure_sequence
from dropvision.io.sequence import open_sequence
from dropvision.analysis.sequence_summary import FRAME_COLUMNS, check_frames_table
from dropvision.synth.sequence import SynthConfig
from dropvision.synth.writer import write_synthetic_sequence
from dvcore import schema

SMALL = dict(width_px=128, height_px=448, tip_row=30.3, axis_col=63.6, noise=0.3, dust=1,
             delays_us=tuple(float(d) for d in range(0, 1501, 20)))
BLACK = 40  # index of the frame replaced by a black JPEG (named .png), as in the hostile corpus


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """A campaign root holding one sequence whose frame BLACK is a black JPEG behind a .png name."""
    root = tmp_path_factory.mktemp("blackframe") / "root"
    seq = write_synthetic_sequence(SynthConfig(u1_um_per_ms=70, u2_um=25, seed=3, **SMALL), root / "seq",
                                   progress=False)
    names = sorted(p.name for p in seq.glob("*.png"))
    ok, jpeg = cv2.imencode(".jpg", np.zeros((448, 128), np.uint8))
    assert ok
    (seq / names[BLACK]).write_bytes(jpeg.tobytes())
    return root


def _float_values(frames: pd.DataFrame) -> np.ndarray:
    cols = [c.name for c in schema.FRAMES.columns if c.dtype == "float"]
    return frames[cols].to_numpy(dtype=float, na_value=np.nan)


def test_photometry_of_a_frame_without_edges(root):
    """The stage itself: a black or uniform frame has no measurable blur (NaN), flagged blurred;
    a good frame of the sequence has the calibration's blur and no flag."""
    with open_sequence(root / "seq") as seq:
        _, _, ctx = calibrate_sequence(seq)
        good = seq.read(0).image
    walls = ctx.photometry.walls
    assert walls is not None  # the walls judge the frames' blur
    ok = measure_photometry(good, ctx)
    assert ok.flags == () and ok.gain == pytest.approx(1.0, abs=0.02)
    assert ok.blur_px == pytest.approx(walls.blur_sigma_px, rel=0.05) and ok.wall_contrast > walls.min_wall_contrast
    black = measure_photometry(np.zeros_like(good), ctx)
    assert np.isnan(black.blur_px) and "blurred" in black.flags
    # a flat grey frame keeps a trace of the background's shading at the walls: a blur far over
    # the limit, finite, flagged
    flat = measure_photometry(np.full_like(good, int(np.median(good))), ctx)
    assert walls.max_frame_blur_px < flat.blur_px < np.inf and "blurred" in flat.flags


def test_black_frame_blur_is_nan_and_flagged(root, tmp_path):
    res = measure_sequence(root / "seq", tmp_path / "out")
    frames = res.frames
    black = frames.iloc[BLACK]
    assert np.isnan(black["blur_px"])
    assert "blurred" in black["quality"].split("; ")
    # every other frame's blur is measured (finite, positive): only the black one is unmeasurable
    others = frames.drop(index=frames.index[BLACK])["blur_px"].to_numpy(float)
    assert others.size == len(frames) - 1 and np.all(np.isfinite(others)) and np.all(others > 0)
    assert not np.isinf(_float_values(frames)).any()
    # what was written is what a reader accepts
    back = pd.read_parquet(tmp_path / "out" / "frames.parquet")
    schema.check_table(back, schema.FRAMES, "frames.parquet read back")
    assert np.isnan(back["blur_px"].iloc[BLACK])


def test_campaign_over_a_black_frame_measures_it(root, tmp_path):
    res = run_campaign(root, tmp_path / "ds", workers=1, progress=False)
    assert res.measured == ["seq"] and not res.failed
    shard = next((tmp_path / "ds" / "shards").iterdir())
    frames = pd.read_parquet(shard / "frames.parquet")
    assert np.isnan(frames["blur_px"].iloc[BLACK])
    assert "blurred" in frames["quality"].iloc[BLACK].split("; ")
    assert len(pd.read_parquet(tmp_path / "ds" / "summary.parquet")) == 1


def test_writer_refuses_an_infinite_value():
    """The writer's check is the reader's: an infinite value is an error naming the column."""
    frames = pd.DataFrame({c.name: (["ok"] if c.dtype == "str" else [False] if c.dtype == "bool" else [1.0])
                           for c in schema.FRAMES.columns}, columns=FRAME_COLUMNS)
    for c in schema.FRAMES.columns:
        if c.dtype == "int":
            frames[c.name] = pd.array([1], dtype="Int64")
    check_frames_table(frames, "finite")
    frames.loc[0, "blur_px"] = np.inf
    with pytest.raises(schema.SchemaError, match=r"inf blur: column 'blur_px' holds infinite values"):
        check_frames_table(frames, "inf blur")
