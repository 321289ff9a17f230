"""Synthetic printhead rows (issue 32, dropvision.synth.printhead): per-nozzle truth agrees with the frames."""

import numpy as np
import pandas as pd
import pytest

import cv2
from dropvision.synth.printhead import RowConfig, for_rig, write_row

SMALL = dict(n_nozzles=4, pitch_um=200.0, width_px=512, height_px=320, pixel_size_um=2.0, volume_nl=0.05,
             planted={1: "missing", 2: "deviated", 3: "satellites"}, supersample=4)


def test_row_truth_matches_frames(tmp_path):
    cfg = RowConfig(delays_us=(60.0, 80.0), **SMALL)
    out = write_row(cfg, tmp_path / "row")
    nz = pd.read_csv(out / "truth_nozzles.csv")
    assert list(nz.nozzle) == [0, 1, 2, 3]
    assert list(nz.state) == ["ok", "missing", "deviated", "satellites"]
    assert np.isnan(nz.volume_nl[1]) and abs(nz.angle_mrad[2]) > 30
    bodies = pd.read_csv(out / "truth_bodies.csv")
    assert 1 not in set(bodies.nozzle)  # the missing nozzle fires nothing
    assert (bodies[bodies.nozzle == 3]["class"] == "satellite").sum() == 2
    main = bodies[bodies["class"] == "main_drop"]
    for i, g in main.groupby("nozzle"):
        g = g.sort_values("delay_us")
        t = nz.loc[i]
        d = np.hypot(np.diff(g.row), np.diff(g.col)) * cfg.pixel_size_um / np.diff(g.delay_us)
        assert d[0] == pytest.approx(t.velocity_m_s, rel=1e-6)
        ang = np.arctan2(np.diff(g.col), np.diff(g.row))[0] * 1e3
        assert ang == pytest.approx(t.angle_mrad, abs=1e-4)
        # the trajectory meets the plate at the nozzle's column
        r, c = g.row.iloc[0], g.col.iloc[0]
        assert c - (r - cfg.plate_row) * np.tan(ang * 1e-3) == pytest.approx(t.col_px, abs=1e-4)
    img = cv2.imread(str(out / bodies.file[0]), cv2.IMREAD_UNCHANGED).astype(float)
    assert img[:30].mean() < 0.2 * img[100:].mean()  # the plate spans the top
    for _, b in bodies[bodies.file == bodies.file[0]].iterrows():
        assert img[int(round(b.row)), int(round(b.col))] < 0.5 * np.median(img)


def test_scan_one_frame_per_nozzle(tmp_path):
    out = write_row(for_rig("printhead-scan", delays_us=(60.0,), **SMALL), tmp_path / "scan")
    frames = pd.read_csv(out / "truth_frames.csv")
    assert list(frames.file) == [f"nozzle_{i:02d}.png" for i in range(4)]
    assert list(frames.nozzle) == [0, 1, 2, 3]


def test_bad_row_config():
    with pytest.raises(ValueError, match="RowConfig.planted"):
        RowConfig(planted={9: "missing"})
    with pytest.raises(ValueError, match="RowConfig.pitch_um"):
        RowConfig(pitch_um=5000.0)
    with pytest.raises(ValueError, match="RowConfig.crosstalk"):
        RowConfig(crosstalk=(7,))  # no right-hand neighbour
    with pytest.raises(ValueError, match="RowConfig.ligament_um"):
        RowConfig(meniscus_nl=0.01, ligament_um=30.0)


def test_liquid_at_the_plate_and_crosstalk_truth(tmp_path):
    cfg = RowConfig(delays_us=(60.0,), meniscus_nl=0.004, crosstalk=(0,), **{**SMALL, "planted": {1: "missing"}})
    out = write_row(cfg, tmp_path / "row")
    nz = pd.read_csv(out / "truth_nozzles.csv")
    assert nz.state[0] == "deviated" and nz.angle_mrad[0] > 200
    bodies = pd.read_csv(out / "truth_bodies.csv")
    men = bodies[bodies["class"] == "meniscus"]
    assert list(men.nozzle) == [0, 2, 3]  # every live nozzle, at its column, just below the plate
    np.testing.assert_allclose(men.col, nz.col_px[[0, 2, 3]], atol=1e-6)
    assert ((men.row > cfg.plate_row) & (men.row < cfg.plate_row + 5)).all()
    img = cv2.imread(str(out / bodies.file[0]), cv2.IMREAD_UNCHANGED).astype(float)
    for _, b in men.iterrows():
        assert img[int(round(cfg.plate_row + 2)), int(round(b.col))] < 0.5 * np.median(img)
        assert img[int(round(cfg.plate_row + 2)), int(round(b.col)) + 20] > 0.8 * np.median(img)
    lig = write_row(RowConfig(delays_us=(60.0,), ligament_um=30.0, **SMALL), tmp_path / "lig")
    lb = pd.read_csv(lig / "truth_bodies.csv")
    assert (lb["class"] == "ligament").sum() == 3
