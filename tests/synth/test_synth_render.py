"""Synthetic rendering: coverage vs truth, reader round trips, determinism, CLI."""

import json

import numpy as np
import pandas as pd
import pytest

from dropvision.io.sequence import open_sequence
from dropvision.synth import SynthConfig, SynthPhysics, drop_history, synthesize, write_synthetic_sequence
from dropvision.synth.render import CameraGeometry, body_coverage
from dropvision.synth.sequence import TRUTH_COLUMNS
from dropvision.synth.shapes import DropShapeModel

PHYS = SynthPhysics()


def _row_integrated_volume_nl(cov, pixel_um):
    w = cov.sum(axis=1) * pixel_um  # coverage-weighted row width (µm)
    return float(np.sum(np.pi * (w / 2) ** 2) * pixel_um) / 1e6


@pytest.fixture(scope="module")
def model():
    return DropShapeModel(drop_history(PHYS, 70.0, 25.0, t_end_us=1800.0), PHYS)


@pytest.mark.parametrize("t_us,kind", [(1500.0, "drop"), (700.0, "attached"), (1040.0, "attached")])
def test_rendered_coverage_integrates_to_truth(model, t_us, kind):
    """Noise/blur-free coverage at 1 µm pixels, 16x16 supersampling, integrated per row."""
    s = model.state(t_us)
    body = s.main_body if kind == "drop" else s.attached_body
    truth = s.drop_volume_nl if kind == "drop" else s.attached_volume_nl
    geom = CameraGeometry(1.0, (1700, 500), tip_row=9.5, axis_col=249.3)  # tip plane on a pixel edge
    r0, c0, cov = body_coverage(body, geom, supersample=16)
    assert r0 > 0 and c0 > 0 and c0 + cov.shape[1] < 500 and r0 + cov.shape[0] < 1700
    assert _row_integrated_volume_nl(cov, 1.0) == pytest.approx(truth, rel=1e-3)


def test_edge_supersampling_equals_full_supersampling(model):
    geom = CameraGeometry(4.73, (400, 200), tip_row=20.3, axis_col=99.6, tilt_deg=2.0)
    for t in (600.0, 1040.0, 1050.0):
        s = model.state(t)
        for b in s.bodies:
            fast = body_coverage(b, geom, 8)
            full = body_coverage(b, geom, 8, full=True)
            assert fast[:2] == full[:2]
            np.testing.assert_allclose(fast[2], full[2], atol=1e-12)


def _small(**kw):
    base = dict(width_px=96, height_px=160, tip_row=12.4, axis_col=47.6, delays_us=(0.0, 800.0, 1040.0, 1050.0, 1200.0),
                dust=1, seed=3)
    base.update(kw)
    return SynthConfig(**base)


@pytest.mark.parametrize("fmt,bits", [("png", 8), ("png", 16), ("tiff", 8), ("tiff", 12), ("tiff", 16),
                                      ("tiff-stack", 16), ("tiff-stack", 8)])
def test_reader_round_trips_what_synth_writes(tmp_path, fmt, bits):
    cfg = _small(format=fmt, bit_depth=bits, repeats=2 if fmt == "tiff-stack" else 1)
    out = write_synthetic_sequence(cfg, tmp_path / "seq", progress=False)
    expected = list(synthesize(cfg, progress=False))
    seq = open_sequence(out)
    assert seq.meta.pixel_size_um == 4.73 and seq.meta.bit_depth == bits
    assert seq.meta.shape == (160, 96) and len(seq) == len(expected)
    assert seq.meta.nozzle_outer_diameter_um == 360.0
    for frame, (img, truth) in zip(seq, expected):
        assert frame.error is None
        assert frame.ref.delay_us == truth.delay_us and frame.ref.repeat == truth.repeat
        assert frame.image.dtype == img.dtype
        np.testing.assert_array_equal(frame.image, img)
    df = pd.read_csv(out / "truth_frames.csv")
    assert tuple(df.columns) == TRUTH_COLUMNS and len(df) == len(expected)
    listed = json.loads((out / "sequence.json").read_text())["frames"]
    assert [f["file"] for f in listed] == list(df["file"])
    truth = json.loads((out / "truth.json").read_text())
    assert truth["schema"] == "dropvision.truth/1" and truth["pinchoff_us"] == 1050.0
    assert SynthConfig.from_dict(truth["parameters"]["config"]) == cfg  # reproducible from the truth
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary leftovers


def test_determinism_with_seed():
    a = [img for img, _ in synthesize(_small(), progress=False)]
    b = [img for img, _ in synthesize(_small(), progress=False)]
    c = [img for img, _ in synthesize(_small(seed=4), progress=False)]
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not all(np.array_equal(x, y) for x, y in zip(a, c))


def test_noise_free_image_levels():
    cfg = _small(noise=0.0, blur_px=0.0, dust=0, falloff=0.0, delays_us=(1150.0, 1500.0))
    (img, truth), (_, gone) = list(synthesize(cfg, progress=False))
    assert gone.inflight and not gone.drop_in_view  # centre 935 µm below the tip: out of 160 rows
    assert img[-1, 0] == round(0.88 * 255)  # background
    assert img[0, 47] == round(0.88 * 0.07 * 255)  # nozzle
    assert truth.inflight and truth.drop_in_view


def test_repeats_jitter_positions(model):
    cfg = _small(repeats=3, delays_us=(1300.0,), noise=0.0)
    rows = [t for _, t in synthesize(cfg, progress=False)]
    z = [r.drop_z_um for r in rows]
    assert [r.repeat for r in rows] == [0, 1, 2] and len(set(z)) == 3
    assert max(abs(np.array(z) - model.state(1300.0).drop_z_um)) < 10.0


def test_cli_writes_sequence(tmp_path, capsys):
    from dropvision.app.cli import main

    out = tmp_path / "cli"
    rc = main(["synth", str(out), "--u1", "60", "--u2", "30", "--delays", "0:100:50", "--size", "96x128",
               "--format", "tiff", "--bit-depth", "12", "--satellites", "1", "--tilt-deg", "1.0",
               "--no-progress"])
    assert rc == 0 and "wrote 3 frames" in capsys.readouterr().out
    truth = json.loads((out / "truth.json").read_text())
    assert truth["calibration"]["tilt_deg"] == 1.0 and truth["satellites"] == 1
    assert main(["synth", str(out), "--delays", "5:1"]) == 2
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "keep.txt").write_text("x")
    assert main(["synth", str(tmp_path / "other"), "--delays", "0", "--size", "96x128"]) == 2
    assert (tmp_path / "other" / "keep.txt").exists()
