"""Per-frame stages of `dropvision measure` on small exact-coverage drawings (known answers)."""

import numpy as np
import pytest
from scipy import ndimage

from dropvision.frame import segmentation as sg
from dropvision.frame import edges as edg
from dropvision.frame import volume as vo
from dropvision.calibrate.blur import edge_sigma_px
from dropvision.calibrate.calibration import calibrate_frames
from dropvision.calibrate.nozzle import find_nozzle
from test_measure_draw import cap, cylinder, render, sphere, spheroid, volume_px3


def _detached_volumes(img, level, bg, sigma, tilt_rad=0.0):
    thr = edg.edge_threshold(level)
    b_img = np.full(img.shape, bg, np.float32)
    seg = sg.segment(sg.dark_mask(img, sg.threshold_image(b_img, thr, img.dtype)))
    out = []
    for b in seg.bodies:
        if not b.nozzle:
            ed = edg.body_edges(img, 1 / b_img, seg.labels, b.label, (b.x0, b.y0, b.x1, b.y1), thr)
            out.append(vo.integrate(ed, tilt_rad, None, sigma).volume_px3)
    return out


@pytest.mark.parametrize("blur", [0.0, 0.8, 1.5, 2.0])
@pytest.mark.parametrize("body", [sphere(90.37, 25), spheroid(90.37, 25, 35), spheroid(90.37, 25, 18)])
@pytest.mark.slow
def test_detached_volume_with_blur_correction(blur, body):
    img = render(bodies=[body], blur_px=blur, bits=16)
    (v,) = _detached_volumes(img, 0.12, 0.8 * 65535, np.sqrt(blur**2 + 1 / 12))
    assert abs(v / volume_px3(body) - 1) < 0.002


def test_blur_bias_without_correction_matches_theory():
    # the 50 % contour of a blurred sphere of radius R loses 1.5 (sigma/R)^2 of its volume
    blur, r = 2.0, 25.0
    img = render(bodies=[sphere(90.37, r)], blur_px=blur, bits=16)
    (v,) = _detached_volumes(img, 0.12, 0.8 * 65535, 0.0)
    expected = -1.5 * (blur**2 + 1 / 12) / r**2
    assert v / volume_px3(sphere(0, r)) - 1 == pytest.approx(expected, abs=0.001)


def test_tilted_slices_cos_factor_vs_resampling():
    """A tilted cylinder: pi (c/2)^2 cos(tilt) per row is exact; without cos it is 1/cos too big."""
    th = np.radians(1.5)
    img = render(shape=(220, 160), bodies=[cylinder(30, 150, 15)], tilt_deg=1.5, nozzle_r_out=0.001,
                 blur_px=0.8, spot=0, bits=16)
    thr = 0.56
    b_img = np.full(img.shape, 0.8 * 65535, np.float32)
    seg = sg.segment(sg.dark_mask(img, sg.threshold_image(b_img, thr, img.dtype)))
    (b,) = [b for b in seg.bodies if not b.nozzle]
    ed = edg.body_edges(img, 1 / b_img, seg.labels, b.label, (b.x0, b.y0, b.x1, b.y1), thr)
    # middle rows only (away from the flat ends): per unit axial length
    mid = (ed.row > 40 + 60) & (ed.row < 40 + 120)
    area = vo.slice_areas_px2(edg.RowEdges(ed.row[mid], ed.left_px[mid], ed.right_px[mid], False), th)
    per_row = area.mean()
    # one image row is cos(th) of axial length: true volume per row = pi r^2 cos(th)
    assert per_row == pytest.approx(np.pi * 15**2 * np.cos(th), rel=1e-3)
    assert per_row / np.cos(th) == pytest.approx(np.pi * 15**2, rel=1e-3)  # the resampled-along-axis value


def test_lens_spot_is_filled_like_scipy():
    img = render(bodies=[sphere(90, 25)], spot=0.8, blur_px=1.0)
    mask = sg.dark_mask(img, sg.threshold_image(np.full(img.shape, 0.8 * 255, np.float32), 0.56, img.dtype))
    seg = sg.segment(mask)
    filled = ndimage.binary_fill_holes(mask > 0)
    assert ((seg.labels > 0) == filled).all()
    assert (filled & ~(mask > 0)).sum() > 50  # there was a spot to fill


def test_row_weights_at_the_tip_plane():
    rows = np.arange(8, 14)
    w = vo.row_weights(rows, 10.2)  # row 10 centre above the plane: its 0.3 goes to row 11
    assert w.tolist() == pytest.approx([0, 0, 0, 1.3, 1, 1])
    w = vo.row_weights(rows, 9.8)  # row 10 centre below: it keeps its 0.7
    assert w.tolist() == pytest.approx([0, 0, 0.7, 1, 1, 1])


@pytest.mark.parametrize("tilt", [0.0, 1.5, -1.0])
@pytest.mark.slow
def test_calibration_recovers_tip_axis_tilt(tilt):
    kw = dict(tilt_deg=tilt, noise=0.01, falloff=0.3, nozzle_r_in=12)
    rest = render(bodies=[cap(12, 3)], **kw)
    drop = render(bodies=[cap(12, 3), sphere(100, 22)], seed=1, **kw)
    att = render(bodies=[cap(12, 3), cylinder(0, 50, 10), sphere(65, 18)], seed=2, **kw)
    cal = calibrate_frames(rest, [rest, drop, att], 4.73, nozzle_outer_diameter_um=40 * 4.73,
                    nozzle_inner_diameter_um=24 * 4.73)
    assert cal.tip_row == pytest.approx(40.3, abs=0.1)
    assert cal.axis_col == pytest.approx(80.2, abs=0.1)
    assert cal.tilt_deg == pytest.approx(tilt, abs=0.2)  # 35 wall rows only; the synthetic sweep checks 0.01 deg
    assert cal.liquid_level == pytest.approx(0.12, abs=0.03)
    assert abs(cal.pixel_size_disagreement_percent) < 0.5
    assert cal.tip_source.startswith("wall annulus")
    # the wall annulus between the bore (12 px) + 1.5 and the outer wall (20 px) - 2.5: 5 columns a side
    assert cal.tip_crossings == 10


def test_pendant_tip_from_silhouette():
    # liquid hanging from the outer edge: the tip is where the silhouette leaves the walls
    img = render(bodies=[cap(20, 45)], noise=0.005)
    cal = calibrate_frames(img, [img], 4.73)
    assert cal.tip_source.startswith("silhouette")
    assert cal.tip_row == pytest.approx(40.3, abs=1.0)


@pytest.mark.parametrize("blur", [0.5, 1.0, 2.0])
def test_edge_sigma_from_nozzle_walls(blur):
    img = render(bodies=[], blur_px=blur, noise=0.01, tilt_deg=1.5)
    t = img / (0.8 * 255)
    nz = find_nozzle(t, 0.5)
    assert edge_sigma_px(t, nz) == pytest.approx(np.hypot(blur, np.sqrt(1 / 12)), abs=0.08)


def test_opaque_dust_is_never_liquid():
    dust = [(150, 30, 3, 0.1)]  # opaque speck off the axis
    frames = [render(bodies=[cap(12, 3)] + ([sphere(z, 15)] if z else []), dust=dust, seed=i, noise=0.01)
              for i, z in enumerate([0, 40, 70, 100, 130])]
    cal = calibrate_frames(frames[0], frames, 4.73)
    assert cal.background.opaque is not None and cal.background.opaque[150, 30]
    allowed = np.where(cal.background.opaque, 0, 255).astype(np.uint8)
    thr = sg.threshold_image(cal.background.background, cal.threshold, np.uint8)
    seg = sg.segment(sg.dark_mask(frames[0], thr, allowed))
    assert [b.nozzle for b in seg.bodies] == [True]
