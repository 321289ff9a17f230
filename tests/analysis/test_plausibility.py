"""Hostile and lying input: every lie is flagged on the frames and noted in summary.json.

Each test builds a known lie from one small honest synthetic sequence (its sequence.json edited
or frames replaced) and checks the flag, the note and the summary values that depend on it.
"""

import json
import shutil
import warnings

import cv2
import numpy as np
import pytest

from dropvision.calibrate.calibration import CalibrationWarning
from dropvision.measurement import measure_sequence
from dropvision.synth import SynthConfig, write_synthetic_sequence

SMALL = dict(width_px=192, height_px=640, tip_row=40.4, axis_col=95.6, seed=3)
DELAYS = tuple(float(d) for d in range(0, 1401, 20))


@pytest.fixture(scope="module")
def honest(tmp_path_factory):
    cfg = SynthConfig(delays_us=DELAYS, **SMALL)
    seq = write_synthetic_sequence(cfg, tmp_path_factory.mktemp("h") / "seq", progress=False)
    return seq, measure_sequence(seq)


@pytest.fixture(scope="module")
def other(tmp_path_factory):
    """Another sequence of the same rig (same dust), another waveform."""
    cfg = SynthConfig(u1_um_per_ms=50.0, u2_um=35.0, delays_us=DELAYS, **SMALL)
    return write_synthetic_sequence(cfg, tmp_path_factory.mktemp("o") / "seq", progress=False)


def lie(honest, tmp_path, edit):
    seq = tmp_path / "lie"
    shutil.copytree(honest[0], seq)
    meta = json.loads((seq / "sequence.json").read_text())
    edit(seq, meta)
    (seq / "sequence.json").write_text(json.dumps(meta))
    return seq


def set_delays(fn):
    def edit(seq, meta):
        for f in meta["frames"]:
            f["delay_us"] = fn(f["delay_us"])
    return edit


def test_honest_sequence_has_no_flag_and_no_note(honest):
    s = honest[1].summary
    assert (honest[1].frames.quality == "ok").all()
    assert s["notes"] == []
    assert abs(s["calibration"]["pixel_size_ratio"] - 1) < 4 * s["calibration"]["pixel_size_ratio_uncertainty"]


def test_pixel_size_beyond_tolerance_flags_every_frame(honest, tmp_path):
    def edit(seq, meta):
        meta["pixel_size_um"] *= 1.05
    with pytest.warns(CalibrationWarning):
        res = measure_sequence(lie(honest, tmp_path, edit))
    s = res.summary
    assert s["calibration"]["pixel_size_ratio"] == pytest.approx(1 / 1.05, rel=2e-3)
    assert res.frames.quality.str.contains("pixel_size_mismatch").all()
    assert any("pixel size" in n for n in s["notes"])
    assert np.isnan(s["inflight_volume_nl"]) and np.isnan(s["jetting_velocity_m_s"])
    assert s["pinchoff_us"] == honest[1].summary["pinchoff_us"]  # does not depend on lengths


def test_pixel_size_inside_tolerance_is_noted(honest, tmp_path):
    """1.5 % (inside 2 %) gives +4.6 % volume: reported and noted, beyond the edge fit's uncertainty."""
    def edit(seq, meta):
        meta["pixel_size_um"] *= 1.015
    res = measure_sequence(lie(honest, tmp_path, edit))
    cal = res.summary["calibration"]
    assert cal["pixel_size_ratio"] == pytest.approx(1 / 1.015, rel=2e-3)
    assert abs(cal["pixel_size_ratio"] - 1) > 10 * cal["pixel_size_ratio_uncertainty"]
    assert any("pixel size implied" in n for n in res.summary["notes"])


def test_pixel_size_unchecked_without_outer_diameter(honest, tmp_path):
    def edit(seq, meta):
        del meta["nozzle_outer_diameter_um"]
    res = measure_sequence(lie(honest, tmp_path, edit))
    # the outer diameter is not there to check it, the inner diameter is (issue 29): said so, nothing flagged
    note = next(n for n in res.summary["notes"] if "no nozzle_outer_diameter_um" in n)
    assert "checked against the inner diameter only" in note, note
    assert (res.frames.quality == "ok").all()
    assert np.isnan(res.summary["calibration"]["pixel_size_ratio"])


@pytest.mark.parametrize("name, fn", [("ms", lambda t: 0.001 * t), ("shift", lambda t: t - 1000.0),
                                      ("x10", lambda t: 10.0 * t), ("half", lambda t: 0.5 * t)])
@pytest.mark.slow
def test_delays_in_another_unit_or_shifted(honest, tmp_path, name, fn):
    res = measure_sequence(lie(honest, tmp_path, set_delays(fn)))
    s = res.summary
    assert res.frames.quality.str.contains("delay_inconsistent").all()
    assert np.isnan(s["pinchoff_us"]) and np.isnan(s["jetting_velocity_m_s"])
    assert np.isnan(s["flow_velocity_at_max_stroke_m_s"])
    assert any("delays" in n for n in s["notes"])


@pytest.mark.parametrize("edit_frames", ["swap", "repeat"])
def test_mislabelled_delays_drop_goes_back_up(honest, tmp_path, edit_frames):
    def edit(seq, meta):
        fr = meta["frames"]
        if edit_frames == "swap":
            fr[60]["delay_us"], fr[64]["delay_us"] = fr[64]["delay_us"], fr[60]["delay_us"]
        else:  # the frame at 1240 us labelled as a repeat of 1160 us
            fr[62]["delay_us"] = fr[58]["delay_us"]
    res = measure_sequence(lie(honest, tmp_path, edit))
    bad = res.frames[res.frames.quality != "ok"]
    assert (bad.quality == "delay_inconsistent").all()
    assert set(bad.file) == ({"f_0060_01200us.png", "f_0064_01280us.png"} if edit_frames == "swap"
                             else {"f_0062_01240us.png"})
    s, t = res.summary, honest[1].summary
    assert any("mislabelled" in n for n in s["notes"])
    assert s["jetting_velocity_m_s"] == pytest.approx(t["jetting_velocity_m_s"], rel=2e-3)  # liar left out


def test_two_frames_define_no_pinchoff(honest, tmp_path):
    def edit(seq, meta):
        meta["frames"] = [meta["frames"][0], meta["frames"][60]]
    res = measure_sequence(lie(honest, tmp_path, edit))
    assert np.isnan(res.summary["pinchoff_us"])
    assert res.frames.quality.str.contains("pinchoff_undefined").all()
    assert any("pinch-off undefined" in n for n in res.summary["notes"])


def test_pinchoff_needs_consecutive_delays_at_own_step(honest, tmp_path):
    def edit(seq, meta):  # 1000..1100 us missing: attached 980, detached 1120
        meta["frames"] = [f for f in meta["frames"] if not 1000 <= f["delay_us"] <= 1100]
    res = measure_sequence(lie(honest, tmp_path, edit))
    assert np.isnan(res.summary["pinchoff_us"])
    bad = res.frames[res.frames.quality.str.contains("pinchoff_undefined")]
    assert set(bad.delay_us) == {980.0, 1120.0}


def test_frames_from_another_sequence(honest, other, tmp_path):
    def edit(seq, meta):
        for k in (30, 40, 62):  # 600, 800 and 1240 us
            f = meta["frames"][k]["file"]
            shutil.copy(other / f, seq / f)
    res = measure_sequence(lie(honest, tmp_path, edit))
    f = res.frames.set_index("delay_us")
    for d in (600.0, 800.0):
        assert "inconsistent_with_neighbours" in f.loc[d, "quality"] and np.isnan(f.loc[d, "grown_volume_nl"])
    # still attached in the other sequence: no drop after the pinch-off (flagged, left out)
    assert f.loc[1240.0, "quality"] != "ok" and not f.loc[1240.0, "inflight"]
    others = f.drop([600.0, 800.0, 1240.0])
    assert (others.quality == "ok").all()
    s, t = res.summary, honest[1].summary
    assert s["pinchoff_us"] == t["pinchoff_us"]
    assert s["inflight_volume_nl"] == pytest.approx(t["inflight_volume_nl"], rel=1e-3)
    assert s["grown_volume_at_pinchoff_nl"] == pytest.approx(t["grown_volume_at_pinchoff_nl"], rel=1e-2)
    assert any("neighbour" in n for n in s["notes"])


def test_foreign_detached_frame_is_not_the_pinchoff(honest, other, tmp_path):
    """A detached frame among attached ones (another sequence) gave pinch-off there."""
    def edit(seq, meta):
        src = meta["frames"][65]["file"]  # in flight in the other sequence too
        shutil.copy(other / src, seq / meta["frames"][10]["file"])
    res = measure_sequence(lie(honest, tmp_path, edit))
    assert res.summary["pinchoff_us"] == honest[1].summary["pinchoff_us"]
    q = res.frames.set_index("delay_us").quality
    assert "inconsistent_with_neighbours" in q.loc[200.0] and (q.drop(200.0) == "ok").all()


def test_second_moving_body(honest, tmp_path):
    """A larger body moving up in some frames was taken for the main drop (velocity went wrong)."""
    def edit(seq, meta):
        for f in meta["frames"]:
            if f["delay_us"] in (1200.0, 1260.0, 1320.0):
                img = cv2.imread(str(seq / f["file"]), cv2.IMREAD_UNCHANGED)
                cv2.circle(img, (40, int(600 - (f["delay_us"] - 1100) * 0.5)), 38, 20, -1)
                cv2.imwrite(str(seq / f["file"]), img)
    res = measure_sequence(lie(honest, tmp_path, edit))
    bad = res.frames[res.frames.quality != "ok"]
    assert set(bad.delay_us) == {1200.0, 1260.0, 1320.0}
    assert (bad.quality == "inconsistent_with_neighbours").all()
    t = honest[1].summary
    assert res.summary["jetting_velocity_m_s"] == pytest.approx(t["jetting_velocity_m_s"], rel=2e-3)
    assert res.summary["notes"]


def test_drop_too_large_for_the_nozzle(honest, tmp_path):
    def edit(seq, meta):
        meta["nozzle_inner_diameter_um"] = 20.0
    res = measure_sequence(lie(honest, tmp_path, edit))
    s = res.summary
    assert res.frames.loc[res.frames.inflight, "quality"].str.contains("implausible_physics").all()
    assert np.isnan(s["flow_velocity_at_max_stroke_m_s"]) and res.frames.flow_velocity_m_s.isna().all()
    assert any("nozzle volumes" in n for n in s["notes"])


def test_inner_diameter_not_smaller_than_outer_is_noted():
    from types import SimpleNamespace

    from dropvision.config import MeasureConfig
    from dropvision.analysis.findings import Withheld
    from dropvision.analysis.plausibility import check_nozzle

    drop = SimpleNamespace(drop_volume_nl=np.array([1.0, np.nan]))
    meta = SimpleNamespace(nozzle_inner_diameter_um=400.0, nozzle_outer_diameter_um=360.0)
    (found,) = check_nozzle(meta, drop, np.array([False, True]), MeasureConfig())
    assert "inner diameter 400 um >= outer 360 um" in found.note
    # the flow is withheld and the attached frame (whose flow it is) flagged, the 1 nl drop's frame not
    assert found.withheld == {Withheld.FLOW} and found.frames == (1,) and found.flag == "implausible_physics"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert MeasureConfig().max_jetting_velocity_m_s == 20.0


# --- the inner diameter cross-checks the pixel size (issue 29, item C) -----------------------------------
def test_honest_resting_meniscus_is_the_inner_diameter(honest):
    """The honest sequence: the resting meniscus's width at the tip plane is the 200 um orifice (42.3 px at
    4.73 um) within 1 %, and nothing is flagged (the notes stay empty: see the first test)."""
    s = honest[1].summary
    assert s["calibration"]["rest_meniscus_width_px"] == pytest.approx(200.0 / 4.73, rel=0.01)
    assert not honest[1].frames.quality.str.contains("pixel_size_mismatch").any()


def _inner_mismatch(res):
    assert res.frames.quality.str.contains("pixel_size_mismatch").all()
    note = next(n for n in res.summary["notes"] if "inner diameter" in n)
    ratio = float(note.split(" is ")[1].split(" x ")[0])
    assert ratio == pytest.approx(0.5, abs=0.01), note  # the implied pixel size is half the given one
    assert np.isnan(res.summary["inflight_volume_nl"]) and np.isnan(res.summary["jetting_velocity_m_s"])


def test_doubled_pixel_size_without_outer_diameter_is_flagged(honest, tmp_path):
    """Lie: pixel size x 2 and no outer diameter to check it against; the inner diameter is given."""
    def edit(seq, meta):
        meta["pixel_size_um"] *= 2
        del meta["nozzle_outer_diameter_um"]
    _inner_mismatch(measure_sequence(lie(honest, tmp_path, edit)))


def test_doubled_pixel_size_and_outer_diameter_are_flagged(honest, tmp_path):
    """Lie: pixel size and outer diameter both x 2 (they agree with each other, not with the inner)."""
    def edit(seq, meta):
        meta["pixel_size_um"] *= 2
        meta["nozzle_outer_diameter_um"] *= 2
    res = measure_sequence(lie(honest, tmp_path, edit))
    assert res.summary["calibration"]["pixel_size_ratio"] == pytest.approx(1.0, abs=0.01)  # the outer check passes
    _inner_mismatch(res)


def test_doubled_pixel_size_in_a_tiff_stack_description_is_flagged(tmp_path):
    """Lie: a multi-page TIFF whose description says pixel_size_um x 2 (sequence.json gives none, nor an
    outer diameter: with one, the nozzle of the expected width is not found and the frame is refused)."""
    import tifffile

    from dropvision.io.sequence_writer import write_multipage_tiff

    cfg = SynthConfig(delays_us=tuple(float(d) for d in range(0, 1401, 40)), format="tiff-stack", **SMALL)
    seq = write_synthetic_sequence(cfg, tmp_path / "stack", progress=False)
    meta = json.loads((seq / "sequence.json").read_text())
    meta.pop("pixel_size_um", None)
    meta.pop("nozzle_outer_diameter_um")
    (seq / "sequence.json").write_text(json.dumps(meta))
    tif = next(seq.glob("*.tif*"))
    with tifffile.TiffFile(tif) as f:
        pages = [p.asarray() for p in f.pages]
        delays = [json.loads(p.description)["delay_us"] for p in f.pages]
    tif.unlink()
    write_multipage_tiff(tif, pages, delays, pixel_size_um=2 * cfg.pixel_size_um)
    res = measure_sequence(seq)
    assert res.summary["calibration"]["pixel_size_um"] == pytest.approx(2 * cfg.pixel_size_um)
    _inner_mismatch(res)


def _cal(**kw):
    from types import SimpleNamespace
    base = dict(pixel_size_ratio=1.0, pixel_size_ratio_uncertainty=0.001, nozzle_outer_diameter_px=76.0,
                nozzle_out_of_focus=False, nozzle_sigma_px=0.0, rest_meniscus_width_px=float("nan"),
                rest_meniscus_delay_us=0.0, rest_meniscus_at_outer_edge=False, pixel_size_um=4.73)
    return SimpleNamespace(**{**base, **kw})


@pytest.mark.parametrize("ratio, flagged", [(0.921, False), (1.08, False), (0.5, True), (1.3, True)])
def test_out_of_focus_walls_judge_the_pixel_size_to_their_blur(ratio, flagged):
    """Walls 8 px out of focus give their outer width to about 2 x 8 px of 76 (21 %): 0.921 (the
    synthetic blurred holder at one tip phase, a correct pixel size) is a note, a factor of 2 or
    1.3 still a flag; in focus, 0.921 is a flag."""
    from types import SimpleNamespace

    from dropvision.analysis.plausibility import blurred_width_fraction, check_pixel_size
    from dropvision.config import MeasureConfig

    meta = SimpleNamespace(nozzle_outer_diameter_um=360.0, nozzle_inner_diameter_um=None)
    blurred = _cal(pixel_size_ratio=ratio, nozzle_out_of_focus=True, nozzle_sigma_px=8.0)
    assert blurred_width_fraction(blurred) == pytest.approx(16.0 / 76.0)
    found = check_pixel_size(blurred, meta, MeasureConfig(), 3)
    assert any(f.flag == "pixel_size_mismatch" for f in found) == flagged
    if not flagged:
        assert any("out-of-focus walls allow" in (f.note or "") for f in found)
    in_focus = check_pixel_size(_cal(pixel_size_ratio=ratio), meta, MeasureConfig(), 3)
    assert any(f.flag == "pixel_size_mismatch" for f in in_focus)


def test_a_meniscus_pinned_at_the_outer_edge_says_nothing_of_the_inner_diameter():
    """A resting liquid as wide as the walls at the plane (a pendant drop on a needle: 71.7 px for a
    72 px needle) is not the orifice: the inner-diameter check does not apply (it read 0.60 x)."""
    from types import SimpleNamespace

    from dropvision.analysis.plausibility import inner_diameter_ratio

    meta = SimpleNamespace(nozzle_inner_diameter_um=432.0)
    pendant = _cal(rest_meniscus_width_px=71.7, pixel_size_um=10.0, rest_meniscus_at_outer_edge=True)
    assert np.isnan(inner_diameter_ratio(pendant, meta, dead_time_us=220.0))
    inside = _cal(rest_meniscus_width_px=71.7, pixel_size_um=10.0)
    assert inner_diameter_ratio(inside, meta, dead_time_us=220.0) == pytest.approx(432.0 / 717.0)


@pytest.mark.parametrize("tip_row", [59.018, 59.254])
def test_tilted_resting_meniscus_is_the_inner_diameter(tip_row, tmp_path):
    """A nozzle tilted by 1.5 deg, its tip plane at two sub-pixel phases: the resting meniscus's width
    is read along the axis (each edge at its own depth) and is the 200 um orifice (42.3 px) within 1 %;
    the rows' horizontal chords read 61.2 and 50.8 px there and called the pixel size wrong."""
    from dropvision.config import MeasureConfig
    from dropvision.synth import SynthConfig, write_synthetic_sequence

    cfg = SynthConfig(u1_um_per_ms=80, u2_um=22, tilt_deg=1.5, tip_row=tip_row, axis_col=159.98, seed=13,
                      width_px=320, height_px=800, delays_us=tuple(float(d) for d in range(0, 601, 20)))
    write_synthetic_sequence(cfg, tmp_path / "seq", progress=False)
    res = measure_sequence(tmp_path / "seq", config=MeasureConfig(workers=1))
    assert res.summary["calibration"]["rest_meniscus_width_px"] == pytest.approx(200.0 / 4.73, rel=0.01)
    assert not res.frames.quality.str.contains("pixel_size_mismatch").any()
