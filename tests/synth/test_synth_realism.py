"""Realism tier of the synthesizer (docs/SYNTH_REALISM.md): every feature changes the image
where it should, its truth is exact, and the default render is bit-identical to before."""

import hashlib
import json
import warnings

import numpy as np
import pandas as pd
import pytest

from dropvision.io.orientation import to_canonical
from dropvision.io.sequence import RGBConvertedWarning, open_sequence
from dropvision.synth import SynthConfig, synthesize, write_synthetic_sequence
from dropvision.synth.render import Renderer
from dropvision.synth.sequence import (BODY_CLASSES, BODY_COLUMNS, RIGS, TRUTH_COLUMNS, colour_gains, plan,
                                       sequence_truth)
from dropvision.synth.shapes import (TabulatedProfile, Profile, ShapeParams, bead_segment, cap_volume_um3,
                                     dumbbell_profile, young_laplace_profile)

#: pinned before the realism tier was added (images only; sha256 of the frames' bytes)
PINNED = {
    "small": ("8772ff9eef04bb2961a635a6b0bbaebbb8cac704f9a607106a14b86ff4ef4568",
              dict(width_px=160, height_px=400, tip_row=20.4, axis_col=79.6,
                   delays_us=(0.0, 800.0, 1040.0, 1050.0, 1200.0, 1400.0), dust=2, seed=5)),
    "sat2": ("e50c3e5ee8786a1426c40b6fc1dc12a8fcbd9e4c52bcafceb2f82dfb74761f05",
             dict(width_px=160, height_px=400, tip_row=20.4, axis_col=79.6, delays_us=(1040.0, 1300.0, 1450.0),
                  satellites=2, seed=1, bit_depth=12, repeats=2, tilt_deg=1.0)),
}

SMALL = dict(width_px=160, height_px=400, tip_row=40.4, axis_col=79.6, seed=2)


def _cfg(**kw):
    return SynthConfig(**{**SMALL, **kw})


def _frames(cfg):
    return list(synthesize(cfg, progress=False))


def _open_quiet(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RGBConvertedWarning)
        seq = open_sequence(path)
        return seq, [f.image for f in seq]


@pytest.mark.parametrize("name", list(PINNED))
def test_default_render_is_bit_identical_to_before(name):
    digest, kw = PINNED[name]
    h = hashlib.sha256()
    for img, _ in synthesize(SynthConfig(**kw), progress=False):
        h.update(img.tobytes())
    assert h.hexdigest() == digest


def test_realism_options_default_off_and_round_trip():
    c = SynthConfig()
    assert (c.orientation, c.holder, c.vignetting, c.exposure, c.clip_fraction, c.colour, c.mist,
            c.path_dust, c.cuvette_wall, c.scene, c.write_nozzle_diameters) == \
        ("down", False, 0.0, 1.0, None, False, 0, 0, None, "jetting", True)
    assert (c.shape.bead_um, c.shape.satellite_mode, c.shape.tail_bulb) == (0.0, "separate", False)
    assert TRUTH_COLUMNS[-2:] == ("n_satellites_visible", "clipped_fraction")
    for name in RIGS:
        cfg = SynthConfig.for_rig(name)
        assert SynthConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    assert SynthConfig.for_rig("clean") == SynthConfig()
    assert SynthConfig.for_rig("watcher-side", bead_um=10.0).shape.bead_um == 10.0
    with pytest.raises(ValueError, match="unknown rig"):
        SynthConfig.for_rig("nope")
    with pytest.raises(ValueError, match="8-bit"):
        SynthConfig(format="jpeg", bit_depth=12)


@pytest.mark.parametrize("orientation", ["up", "left", "right"])
def test_orientation_rotates_the_canonical_render(tmp_path, orientation):
    base = dict(width_px=96, height_px=160, tip_row=12.4, axis_col=47.6, delays_us=(800.0, 1200.0))
    canon = _frames(SynthConfig(**base))
    rot = _frames(SynthConfig(**base, orientation=orientation))
    for (a, ta), (b, tb) in zip(canon, rot):
        assert b.shape == ((96, 160) if orientation in ("left", "right") else (160, 96))
        np.testing.assert_array_equal(to_canonical(b, orientation), a)
        assert ta.to_dict() == tb.to_dict()  # truth stays canonical
    out = write_synthetic_sequence(SynthConfig(**base, orientation=orientation), tmp_path / "s", progress=False)
    seq, images = _open_quiet(out)
    assert seq.meta.shape == (160, 96)
    for img, (a, _) in zip(images, canon):
        np.testing.assert_array_equal(img, a)
    truth = json.loads((out / "truth.json").read_text())
    assert truth["calibration"]["orientation"] == orientation


def test_holder_block_reflections_and_wedge():
    kw = dict(noise=0.0, dust=0, delays_us=(1300.0,), falloff=0.0)
    plain = _frames(_cfg(**kw))[0][0].astype(float)
    img, truth = _frames(_cfg(**kw, holder=500.0, nozzle_protrusion_um=47.3))[0]
    img = img.astype(float)
    face = 40.4 - 10.0  # 47.3 µm above the tip = 10 px
    bg = plain[200, 5]
    block = img[2:int(face) - 3, 79 - 45:79 + 45]  # 500 µm = 106 px wide, centred
    assert np.median(block) < 0.1 * bg  # a dark block
    assert block.max() > 0.3 * bg  # bright reflections inside it
    # the wedge beside the block (right side, widening upwards) darkens the corner next to it
    assert img[3, 134:140].mean() < 0.3 * bg and img[3, 2:6].mean() > 0.8 * bg
    np.testing.assert_array_equal(img[int(face) + 8:], plain[int(face) + 8:])  # nozzle tip, drop untouched
    holder = [b for b in truth.bodies if b.body_class == "holder"]
    assert {b.detail for b in holder} == {"block", "reflection", "wedge"}
    assert all(np.isnan(b.volume_nl) and not b.countable for b in holder)


def test_vignetting_darkens_the_corners():
    r = Renderer(_cfg().geometry(), _cfg(vignetting=0.9, falloff=0.0).optics(), 180.0)
    assert r.backlight[0, 0] == pytest.approx(0.88 * 0.1) and r.backlight[-1, -1] == pytest.approx(0.88 * 0.1)
    assert r.backlight[199:201, 79:81].min() > 0.88 * 0.999
    plain = _frames(_cfg(delays_us=(0.0,)))[0][0]
    vig = _frames(_cfg(delays_us=(0.0,), vignetting=0.9))[0][0]
    assert vig[-3:, :3].mean() < 0.15 * plain[-3:, :3].mean()


@pytest.mark.parametrize("colour", [False, True])
def test_clipped_background_fraction(tmp_path, colour):
    cfg = _cfg(delays_us=(0.0, 1300.0), clip_fraction=0.76, colour=colour)
    frames = _frames(cfg)
    p = plan(cfg)
    truth = sequence_truth(p)
    assert truth["realism"]["clipped_fraction_background"] == pytest.approx(0.76, abs=0.005)
    assert truth["realism"]["exposure"] > 1
    img, t0 = frames[0]
    assert t0.clipped_fraction == pytest.approx(0.76, abs=0.02)
    grey = img if img.ndim == 2 else (img.astype(float) @ np.array([0.299, 0.587, 0.114])).round()
    assert t0.clipped_fraction == pytest.approx(np.mean(grey >= 255), abs=1e-3)
    assert frames[1][1].clipped_fraction < t0.clipped_fraction  # the drop hides clipped background


def test_colour_png_gives_the_grey_scene(tmp_path):
    grey = _frames(_cfg(delays_us=(0.0, 1300.0)))
    cfg = _cfg(delays_us=(0.0, 1300.0), colour=True)
    rgb = _frames(cfg)
    g = colour_gains((1.0, 0.95, 0.85))
    assert sum(w * x for w, x in zip((0.299, 0.587, 0.114), g)) == pytest.approx(1.0)
    assert g[0] > g[1] > g[2]
    out = write_synthetic_sequence(cfg, tmp_path / "c", progress=False)
    seq, images = _open_quiet(out)
    for im, (ref, _), (col, _) in zip(images, grey, rgb):
        assert col.shape == ref.shape + (3,) and im.shape == ref.shape
        assert np.abs(im.astype(int) - ref.astype(int)).max() <= 1
        assert col[..., 0].mean() > col[..., 1].mean() > col[..., 2].mean()


@pytest.mark.parametrize("colour", [False, True])
def test_jpeg_frames_open_with_the_expected_grey(tmp_path, colour):
    ref = _frames(_cfg(delays_us=(0.0, 1300.0)))
    cfg = _cfg(delays_us=(0.0, 1300.0), colour=colour, format="jpeg", jpeg_quality=90)
    out = write_synthetic_sequence(cfg, tmp_path / "j", progress=False)
    assert sorted(p.suffix for p in out.iterdir() if p.name.startswith("f_")) == [".jpg", ".jpg"]
    seq, images = _open_quiet(out)
    assert seq.meta.bit_depth == 8 and seq.meta.shape == (400, 160)
    for im, (r, _) in zip(images, ref):
        d = np.abs(im.astype(float) - r.astype(float))
        assert d.mean() < 3.0 and np.percentile(d, 99) < 12


def test_mist_drifts_and_path_dust_is_static():
    kw = dict(noise=0.0, delays_us=(0.0,), repeats=2, position_jitter_um=0.0, dust=0)
    (a, ta), (b, tb) = _frames(_cfg(**kw, mist=5))
    (c, _), (d, _) = _frames(_cfg(**kw))
    np.testing.assert_array_equal(c, d)
    assert not np.array_equal(a, b)  # new mist positions every frame
    mist = [x for x in ta.bodies if x.body_class == "mist"]
    assert len(mist) == 5 and not any(x.in_focus or x.countable for x in mist)
    for m in mist:
        r, cc = int(round(m.row_px)), int(round(m.col_px))
        if 2 < r < 397 and 2 < cc < 157 and not (r < 45 and abs(cc - 79.6) < 45):
            assert a[r, cc] < c[r, cc]  # darker at the droplet
    assert [m.row_px for m in mist] != [m.row_px for m in tb.bodies if m.body_class == "mist"]
    dusty = _frames(_cfg(**kw, path_dust=2))
    specks = [x for x in dusty[0][1].bodies if x.body_class == "dust" and x.detail == "on the path"]
    assert len(specks) == 2
    for s in specks:
        assert abs(s.col_px - 79.6) < 0.4 * plan(_cfg()).model.r_inflight / 4.73 + 1e-9  # on the drop path
        r, cc = int(round(s.row_px)), int(round(s.col_px))
        assert dusty[0][0][r, cc] < 0.8 * c[r, cc] and dusty[1][0][r, cc] == dusty[0][0][r, cc]


def test_bead_volume_is_added_to_the_attached_truth():
    kw = dict(noise=0.0, delays_us=(1000.0, 1100.0, 1300.0), dust=0)
    plain = _frames(_cfg(**kw))
    beaded = _frames(_cfg(**kw, shape=ShapeParams(bead_um=30.0)))
    seg = bead_segment(0.0, 30.0)
    v_cap = cap_volume_um3(seg.base_radius_um, seg.height_um) / 1e6
    assert seg.height_um == pytest.approx(25.5) and seg.sphere_radius_um == pytest.approx(15.0)
    (i0, t0), (j0, u0) = plain[0], beaded[0]
    np.testing.assert_array_equal(i0, j0)  # before pinch-off: no bead
    assert u0.attached_volume_nl == t0.attached_volume_nl
    for (i, t), (j, u) in zip(plain[1:], beaded[1:]):
        assert not u.attached
        assert u.attached_volume_nl - t.attached_volume_nl == pytest.approx(v_cap, rel=1e-9)
        assert u.grown_volume_nl - t.grown_volume_nl == pytest.approx(v_cap, rel=1e-9)
        diff = np.nonzero(i != j)
        assert diff[0].size and diff[0].min() >= 40 and diff[0].max() < 40 + 12  # just below the tip
        att = [b for b in u.bodies if b.body_class == "attached"][0]
        assert att.volume_nl == u.attached_volume_nl and "bead" in att.detail


def test_dumbbell_profile_volume_is_exact():
    prof = dumbbell_profile(2.5e4)
    assert prof.volume_um3() == pytest.approx(2.5e4, rel=1e-12)
    assert prof.volume_um3(0.01) == pytest.approx(2.5e4, rel=1e-12)  # no kink inside a panel


@pytest.mark.parametrize("mode,n,visible", [("touching", 1, 1), ("dumbbell", 1, 1), ("mixed", 2, 2),
                                            ("separate", 2, 2)])
def test_satellite_modes_count_what_is_visible(mode, n, visible):
    cfg = _cfg(satellites=n, delays_us=(1300.0,), noise=0.0, dust=0, shape=ShapeParams(satellite_mode=mode))
    (img, t), = _frames(cfg)
    p = plan(cfg)
    assert t.n_satellites == n and t.n_satellites_visible == visible and t.inflight
    assert t.detached_volume_nl == pytest.approx((p.model.v_inflight_um3 + p.model.v_sat_um3) / 1e6, rel=1e-7)
    sats = [b for b in t.bodies if b.body_class == "satellite"]
    assert len(sats) == n and sum(b.volume_nl for b in sats) == pytest.approx(p.model.v_sat_um3 / 1e6, rel=1e-7)
    assert sum(b.countable for b in sats) == visible
    if mode in ("touching", "mixed"):  # a drop of its own, a lobe of the main drop's silhouette
        assert sats[0].detail == "touching" and sats[0].countable
        assert t.drop_volume_nl == pytest.approx((p.model.v_inflight_um3 + sats[0].volume_nl * 1e6) / 1e6, rel=1e-7)
    if mode in ("dumbbell", "mixed"):
        db = sats[-1 if mode == "mixed" else 0]
        assert db.detail == "dumbbell" and db.countable


def test_tail_bulb_is_part_of_the_main_body():
    cfg = _cfg(satellites=1, delays_us=(1100.0,), noise=0.0, shape=ShapeParams(tail_bulb=True))
    (img, t), = _frames(cfg)
    p = plan(cfg)
    assert t.tail_attached and t.n_satellites == 0
    st = p.model.state(1100.0)
    parts = st.main_body.profile.parts
    assert parts[-1].a_um > 3 * p.model.r_thread  # a bulb, not the thin thread's rounded tip
    assert t.drop_volume_nl == pytest.approx((p.model.v_inflight_um3 + p.model.v_sat_um3) / 1e6, rel=1e-9)
    rows = {b.body_class: b for b in t.bodies}
    assert rows["main_drop"].volume_nl + rows["tail"].volume_nl == pytest.approx(t.drop_volume_nl, rel=1e-12)
    assert not rows["tail"].countable and rows["tail"].row_px < rows["main_drop"].row_px


def test_pendant_profile_volume():
    b, rn = 1000.0, 180.0
    d = young_laplace_profile(b, 0.0, rn)  # Bond 0: a sphere cut by the needle plane
    h = b - np.sqrt(b * b - rn * rn)
    analytic = 4.0 / 3.0 * np.pi * b**3 - np.pi * h * h * (3 * b - h) / 3.0
    assert d["volume_um3"] == pytest.approx(analytic, rel=1e-9)
    assert d["height_um"] == pytest.approx(b + np.sqrt(b * b - rn * rn), rel=1e-9)
    d2 = young_laplace_profile(b, 0.2, 360.0)
    rendered = Profile((TabulatedProfile(d2["s_um"], d2["r2_um2"]),)).volume_um3()
    assert rendered == pytest.approx(d2["volume_um3"], rel=1e-6)
    sphere_height = b + np.sqrt(b * b - 360.0**2)
    assert d2["max_radius_um"] > b and d2["height_um"] > 1.2 * sphere_height  # stretched by gravity
    with pytest.raises(ValueError, match="never narrows"):
        young_laplace_profile(b, 0.3, 180.0)


def test_pendant_preset(tmp_path):
    cfg = SynthConfig.for_rig("pendant-saturated", width_px=200, height_px=180, tip_row=10.4, axis_col=99.6,
                              pixel_size_um=20.0)
    out = write_synthetic_sequence(cfg, tmp_path / "p", progress=False)
    seq, (img,) = _open_quiet(out)
    assert seq.meta.nozzle_outer_diameter_um == 720.0 and len(seq) == 1
    t = pd.read_csv(out / "truth_frames.csv").iloc[0]
    truth = json.loads((out / "truth.json").read_text())
    d = young_laplace_profile(1000.0, 0.2, 360.0)
    assert t["attached"] and t["attached_volume_nl"] == pytest.approx(d["volume_um3"] / 1e6, rel=1e-9)
    assert truth["pendant"]["volume_nl"] == pytest.approx(t["attached_volume_nl"], rel=1e-9)
    assert 0.3 < t["clipped_fraction"] < 0.76
    eq_row = 10.4 + d["equator_s_um"] / 20.0
    r = int(round(eq_row))
    assert img[r, 99] > 200 and img[r, 99 - int(0.7 * d["max_radius_um"] / 20)] < 60  # lens spot in a dark drop
    assert img[100:, 180].mean() < 0.6 * img[100:, 170].mean()  # the cuvette wall at 0.9 x width


def test_no_nozzle_diameters(tmp_path):
    out = write_synthetic_sequence(SynthConfig.for_rig("single-frame", **SMALL), tmp_path / "s", progress=False)
    meta = json.loads((out / "sequence.json").read_text())
    assert "nozzle_outer_diameter_um" not in meta and "nozzle_inner_diameter_um" not in meta
    seq, images = _open_quiet(out)
    assert len(images) == 1 and seq.meta.nozzle_outer_diameter_um is None and seq.meta.pixel_size_um == 4.73


_SMALL_RIG = {
    "pendant-saturated": dict(width_px=200, height_px=180, tip_row=10.4, axis_col=99.6, pixel_size_um=20.0),
    "single-frame": dict(SMALL),
}


@pytest.mark.parametrize("name", list(RIGS))
def test_every_preset_writes_a_sequence(tmp_path, name):
    ov = _SMALL_RIG.get(name, dict(SMALL, delays_us=(0.0, 1100.0, 1300.0)))
    cfg = SynthConfig.for_rig(name, **ov)
    out = write_synthetic_sequence(cfg, tmp_path / name, progress=False)
    seq, images = _open_quiet(out)
    assert len(images) == len(cfg.delays_us) and all(i is not None for i in images)
    assert seq.meta.shape == (cfg.height_px, cfg.width_px)
    bodies = pd.read_csv(out / "truth_bodies.csv")
    assert tuple(bodies.columns) == BODY_COLUMNS
    assert set(bodies["body_class"]) <= set(BODY_CLASSES)
    assert {"nozzle", "attached"} <= set(bodies["body_class"])
    frames = pd.read_csv(out / "truth_frames.csv")
    assert tuple(frames.columns) == TRUTH_COLUMNS
    att = bodies[bodies["body_class"] == "attached"]
    np.testing.assert_allclose(att["volume_nl"].to_numpy(), frames["attached_volume_nl"].to_numpy(), rtol=1e-8)
    truth = json.loads((out / "truth.json").read_text())
    assert SynthConfig.from_dict(truth["parameters"]["config"]) == cfg


def test_watcher_preset_features():
    cfg = SynthConfig.for_rig("watcher-side", **SMALL, delays_us=(1100.0, 1300.0))
    (a, ta), (b, tb) = _frames(cfg)
    assert a.shape == (160, 400, 3)  # drops travel right
    classes = {x.body_class for x in ta.bodies}
    assert {"holder", "mist", "tail", "main_drop"} <= classes
    assert tb.n_satellites == 2 and tb.n_satellites_visible == 2  # touching + dumbbell
    assert any("bead" in x.detail for x in tb.bodies if x.body_class == "attached")


def test_cli_rig_and_realism_options(tmp_path, capsys):
    from dropvision.app import synth_cli
    from dropvision.app.cli import main

    assert synth_cli._rig_names() == list(RIGS)
    out = tmp_path / "cli"
    rc = main(["synth", str(out), "--rig", "low-contrast", "--size", "160x400", "--tip-row", "40.4",
               "--delays", "0,1300", "--orientation", "left", "--jpeg-quality", "85", "--colour",
               "--exposure", "1.1", "--vignetting", "0.3", "--mist", "2", "--holder", "yes", "--no-progress"])
    assert rc == 0 and "wrote 2 frames" in capsys.readouterr().out
    cfg = SynthConfig.from_dict(json.loads((out / "truth.json").read_text())["parameters"]["config"])
    assert (cfg.liquid_transmission, cfg.blur_px, cfg.path_dust) == (0.5, 1.8, 2)  # the rig's
    assert (cfg.orientation, cfg.format, cfg.jpeg_quality, cfg.colour, cfg.exposure, cfg.vignetting, cfg.mist,
            cfg.holder, cfg.width_px, cfg.tip_row) == ("left", "jpeg", 85, True, 1.1, 0.3, 2, True, 160, 40.4)
    seq, images = _open_quiet(out)
    assert seq.meta.shape == (400, 160)
    assert main(["synth", str(tmp_path / "bad"), "--rig", "nope", "--delays", "0"]) == 2
