"""Waveform templates (issue 31 items 1-2): the drive in the lab's own named parameters.

Pinned to hand-computed piecewise-linear values (the three-pulse template), to the paper's
trapezoid of `identify.waveform.Waveform` (bit for bit), and to the ECM's own time stepping.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest

from dropvision.io.overrides import validate_waveform
from dropvision.io.sequence_meta import SequenceError
from identify.ecm import pwl_response, simulate, waveform_knots
from identify.ecm_fit import EcmData
from identify.physics import (THREE_PULSE_CENTRE, THREE_PULSE_LAWS, SynthPhysics, drive_history, drop_history,
                              trapezoid_laws)
from identify.template_fit import TemplateModel, fit_template_model
from identify.waveform import (Drive, ThreePulseTemplate, TrapezoidTemplate, Waveform, WaveformTemplate,
                               drive_from_document, template_from_dict)

PULSES = {"V1": 30.0, "V2": -10.0, "V3": 5.0, "w1": 100.0, "w2": 50.0, "w3": 20.0, "d1": 10.0, "d2": 30.0}

# By hand, edge 2 us: pulse 1 rises over [0, 2] to 30 V, holds to 100, falls to 0 at 102; pulse 2
# starts at 100 + 2 + 10 = 112, reaches -10 V at 114, holds to 162, back at 0 at 164; pulse 3 starts
# at 112 + 50 + 2 + 30 = 194, reaches 5 V at 196, holds to 214, back at 0 at 216.
HAND = [(-1.0, 0.0), (0.0, 0.0), (1.0, 15.0), (2.0, 30.0), (50.0, 30.0), (100.0, 30.0), (101.0, 15.0),
        (102.0, 0.0), (105.0, 0.0), (112.0, 0.0), (113.0, -5.0), (130.0, -10.0), (162.0, -10.0), (163.0, -5.0),
        (170.0, 0.0), (194.0, 0.0), (195.0, 2.5), (200.0, 5.0), (214.0, 5.0), (215.0, 2.5), (216.0, 0.0),
        (300.0, 0.0)]


def test_three_pulse_drive_is_the_hand_computed_piecewise_linear_function():
    tpl = ThreePulseTemplate()
    t = np.array([a for a, _ in HAND])
    assert tpl.drive(PULSES, t) == pytest.approx([b for _, b in HAND], abs=1e-12)
    assert tpl.end_us(PULSES) == 216.0
    assert tpl.velocity_instant_us(PULSES) == 100.0  # end of pulse 1's plateau
    d = Drive(tpl, PULSES, dead_time_us=220.0)
    assert d.at(t + 220.0) == pytest.approx([b for _, b in HAND], abs=1e-12)
    assert d.velocity_instant_us == 320.0 and d.end_us == 436.0
    # a wider edge moves every corner: pulse 1 reaches 30 V at 5 us, is back at 0 at 105
    assert ThreePulseTemplate(edge_us=5.0).drive(PULSES, [2.5, 5.0, 102.5, 105.0]) == pytest.approx([15, 30, 15, 0])
    assert tpl.units() == {"V1": "V", "V2": "V", "V3": "V", "w1": "us", "w2": "us", "w3": "us", "d1": "us",
                           "d2": "us"}


def test_knots_rebuild_the_drive():
    """u(t) = sum_i c_i (t - t_i)_+ with the template's knots is the drive itself."""
    t = np.linspace(-20.0, 500.0, 4001)
    for tpl, values in ((ThreePulseTemplate(), PULSES), (ThreePulseTemplate(), THREE_PULSE_CENTRE),
                        (TrapezoidTemplate(), {"u1_um_per_ms": 70.0, "u2_um": 25.0})):
        knots, jumps = tpl.knots(values, dead_time_us=0.0)
        rebuilt = np.sum(jumps[:, None] * np.clip(t[None, :] - knots[:, None], 0.0, None), axis=0)
        assert rebuilt == pytest.approx(tpl.drive(values, t), abs=1e-9)
    # back-to-back pulses (zero delays) and a triangle (w = edge) merge their corners
    tight = {**PULSES, "d1": 0.0, "d2": 0.0, "w2": 2.0}
    knots, jumps = ThreePulseTemplate().knots(tight)
    assert np.all(np.diff(knots) > 0)


def test_trapezoid_template_is_the_papers_waveform_bit_for_bit():
    tpl = TrapezoidTemplate()
    t = np.arange(-50.0, 14000.0, 0.7)
    for u1, u2 in ((70.0, 25.0), (62.5, 21.25), (100.0, 35.0)):
        v = {"u1_um_per_ms": u1, "u2_um": u2}
        assert np.array_equal(tpl.drive(v, t), Waveform(u1, u2).displacement_um(t))
        k1, j1 = tpl.knots(v, 220.0)
        k2, j2 = waveform_knots(Waveform(u1, u2), 220.0)
        assert np.array_equal(k1, k2) and np.array_equal(j1, j2)
        # the generic rule (corners -> slope changes) gives the same to 1e-12
        k3, j3 = WaveformTemplate.knots(tpl, v, 220.0)
        np.testing.assert_allclose(k3, k2, rtol=1e-12)
        np.testing.assert_allclose(j3, j2, rtol=1e-12)
        assert tpl.velocity_instant_us(v) == Waveform(u1, u2).max_stroke_us
    custom = TrapezoidTemplate(u3_um_per_ms=3.0, hold_us=5.0)
    assert np.array_equal(custom.drive({"u1_um_per_ms": 70, "u2_um": 25}, t),
                          Waveform(70.0, 25.0, 3.0, 5.0).displacement_um(t))


def test_ecm_through_a_template_matches_its_time_stepping():
    """The closed form of the ECM (pwl_response on the template's knots) equals the first-order-hold
    simulation of the sampled drive, whose corners lie on the 0.5 us grid."""
    ph = SynthPhysics()
    c = ph.ecm_parameters().coefficients()
    d = Drive(ThreePulseTemplate(), THREE_PULSE_CENTRE, 220.0)
    t = np.arange(0.0, 900.0, 0.5)
    vol, flow = simulate(c, t, d.at(t))
    knots, jumps = d.knots()
    v2, f2 = pwl_response(c.ratios(), knots, jumps, t)
    np.testing.assert_allclose(v2, vol, rtol=0, atol=1e-9 * np.abs(vol).max())
    np.testing.assert_allclose(f2, flow, rtol=0, atol=1e-9 * np.abs(flow).max())


def test_synth_history_of_the_trapezoid_template_is_the_papers():
    ph = SynthPhysics()
    for u1, u2 in ((70.0, 25.0), (65.0, 28.0)):
        h0 = drop_history(ph, u1, u2)
        h1 = drive_history(ph, Drive(TrapezoidTemplate(), {"u1_um_per_ms": u1, "u2_um": u2}, ph.dead_time_us),
                           trapezoid_laws(ph))
        assert h1.summary() == h0.summary()
        assert np.array_equal(h1.volume_nl, h0.volume_nl) and np.array_equal(h1.flow_nl_per_us, h0.flow_nl_per_us)


def test_three_pulse_synth_history_follows_its_drive_and_laws():
    ph = SynthPhysics()
    d = Drive(ThreePulseTemplate(), THREE_PULSE_CENTRE, ph.dead_time_us)
    h = drive_history(ph, d, THREE_PULSE_LAWS)
    assert h.pinchoff_instant_us == 660.0  # the law's constant at its centre
    assert h.max_stroke_instant_us == 420.0  # 220 + w1
    knots, jumps = d.knots()
    v, _ = pwl_response(ph.ecm_parameters().coefficients().ratios(), knots, jumps, [660.0])
    assert h.grown_volume_at_pinchoff_instant_nl == pytest.approx(float(v[0]), rel=1e-9)
    assert h.inflight_volume_nl == pytest.approx(h.grown_volume_at_pinchoff_instant_nl + 0.3, rel=1e-12)
    # a stronger main pulse: later pinch-off (1.5 us per V) and a larger drop
    h2 = drive_history(ph, Drive(ThreePulseTemplate(), {**THREE_PULSE_CENTRE, "V1": 34.0}, ph.dead_time_us),
                       THREE_PULSE_LAWS)
    assert h2.pinchoff_instant_us == 666.0 and h2.inflight_volume_nl > h.inflight_volume_nl


def test_sequence_json_template_form():
    w = validate_waveform({"template": "three_pulse", "parameters": dict(PULSES)}, "s/sequence.json")
    assert w == {"template": "three_pulse", "edge_us": 2.0, "parameters": PULSES, "dead_time_us": 220.0}
    assert drive_from_document(w).values == PULSES
    # the trapezoid's template form is read into the paper's flat form
    assert validate_waveform({"template": "trapezoid", "parameters": {"u1_um_per_ms": 70, "u2_um": 25},
                              "hold_us": 10}, "s") == {"u1_um_per_ms": 70.0, "u2_um": 25.0, "u3_um_per_ms": 2.0,
                                                       "hold_us": 10.0, "dead_time_us": 220.0}
    bad = [
        ({"template": "three_pulse", "parameters": {"V1": 30}}, "missing three_pulse parameter(s) V2"),
        ({"template": "three_pulse", "parameters": {**PULSES, "V4": 1}}, "unknown three_pulse parameter(s) V4"),
        ({"template": "three_pulse", "parameters": {**PULSES, "w1": 1.0}}, "shorter than the pulse edge"),
        ({"template": "three_pulse", "parameters": {**PULSES, "d1": -1.0}}, "d1 = -1.0 us is outside"),
        ({"template": "three_pulse", "parameters": {**PULSES, "V1": "30"}}, "V1 must be a number (V)"),
        ({"template": "three_pulse", "parameters": PULSES, "hold_us": 3}, "unknown constant(s) hold_us"),
        ({"template": "three_pulse", "parameters": PULSES, "u1_um_per_ms": 70}, "beside template"),
        ({"template": "sine", "parameters": {}}, "unknown waveform template 'sine'"),
        ({"template": "sine"}, "unknown waveform template 'sine'"),
        ({"template": "three_pulse", "w1": 3}, "unknown constant(s) w1"),
    ]
    for doc, why in bad:
        with pytest.raises(SequenceError, match="^s/sequence.json: ") as e:
            validate_waveform(doc, "s/sequence.json")
        assert why in str(e.value) and "\n" not in str(e.value)
    assert template_from_dict({"template": "three_pulse", "edge_us": 3}).edge_us == 3.0
    # without parameters: the template alone, its parameters each shot's labels (tests/io/test_shot_waveform_labels.py;
    # a strobe sequence of it is left out of a campaign's dataset: tests/synth/test_template_campaign.py)
    assert validate_waveform({"template": "three_pulse"}, "s") == {"template": "three_pulse", "edge_us": 2.0,
                                                                   "dead_time_us": 220.0}


def test_synth_writes_the_template_waveform(tmp_path):
    from dropvision.io.sequence import open_sequence
    from dropvision.synth.config import SynthConfig
    from dropvision.synth.writer import write_synthetic_sequence

    cfg = SynthConfig(width_px=96, height_px=256, tip_row=20.4, axis_col=47.6, delays_us=(0.0, 400.0, 700.0),
                      supersample=2, waveform={"template": "three_pulse", "parameters": dict(THREE_PULSE_CENTRE)})
    seq = write_synthetic_sequence(cfg, tmp_path / "seq", progress=False)
    meta = open_sequence(seq).meta
    assert meta.waveform == {"template": "three_pulse", "edge_us": 2.0, "parameters": THREE_PULSE_CENTRE,
                             "dead_time_us": 220.0}
    truth = json.loads((seq / "truth.json").read_text())
    assert truth["pinchoff_instant_us"] == 660.0
    assert truth["parameters"]["laws"]["template"]["parameters"] == THREE_PULSE_CENTRE
    from dropvision.io.describe import describe_folder  # dropvision init's report of a waveform given to it
    desc = describe_folder(seq, overrides={"waveform": {"template": "three_pulse", "parameters": THREE_PULSE_CENTRE}})
    assert "  waveform   three_pulse: V1 30, V2 10, V3 10, w1 200, w2 80, w3 80, d1 20, d2 20" in desc.lines
    assert desc.doc["waveform"]["parameters"] == THREE_PULSE_CENTRE
    assert SynthConfig.from_dict(truth["parameters"]["config"]).drive().values == THREE_PULSE_CENTRE
    with pytest.raises(ValueError, match="dead_time_us"):
        SynthConfig(waveform={"template": "three_pulse", "parameters": THREE_PULSE_CENTRE, "dead_time_us": 0})
    with pytest.raises(ValueError, match="missing three_pulse parameter"):
        SynthConfig(waveform={"template": "three_pulse", "parameters": {"V1": 3}})


def test_ecm_data_fine_drive_checks():
    t = np.arange(10) * 10.0
    with pytest.raises(ValueError, match="substeps > 1 needs u_fine_um"):
        EcmData(t, np.r_[0.0, np.ones(9)], np.ones(10), 1.0, 1.0, substeps=4)
    with pytest.raises(ValueError, match="must hold 37 finite samples"):
        EcmData(t, np.r_[0.0, np.ones(9)], np.ones(10), 1.0, 1.0, substeps=4, u_fine_um=np.zeros(36))


def _noise_free_campaign(settings, ph):
    """Training table and time series of the synthetic three-pulse head without images."""
    rows, series = [], []
    t = np.arange(0.0, 1000.0, 10.0)
    for i, v in enumerate(settings):
        h = drive_history(ph, Drive(ThreePulseTemplate(), v, ph.dead_time_us), THREE_PULSE_LAWS)
        tp = np.ceil(h.pinchoff_instant_us / 10.0) * 10.0  # first strobe delay with the drop detached
        att = t < tp
        series.append(pd.DataFrame({"sequence_id": f"s{i}", "delay_us": t, "attached": att,
                                    "grown_volume_nl": np.where(att, h.grown_volume_nl_at(t), np.nan)}))
        rows.append({"sequence_id": f"s{i}", **v, "pinchoff_us": h.pinchoff_instant_us,
                     "inflight_volume_nl": h.inflight_volume_nl, "jetting_velocity_m_s": h.jetting_velocity_m_s})
    return pd.DataFrame(rows), pd.concat(series, ignore_index=True)


@pytest.mark.slow
def test_template_model_recovers_a_noise_free_head_and_round_trips(tmp_path):
    ph = SynthPhysics()
    c = THREE_PULSE_CENTRE
    train = [{**c, "V1": a, "w1": b} for a in (26.0, 34.0) for b in (180.0, 220.0)] + [dict(c)]
    table, series = _noise_free_campaign(train, ph)
    true = ph.ecm_parameters()
    hyd = (true.LN, true.RN, true.LR, true.RR)
    m = fit_template_model({"template": "three_pulse", "edge_us": 2.0}, table, series, dead_time_us=220.0,
                           nozzle_inner_diameter_um=ph.nozzle_inner_diameter_um, hydraulics=hyd, la=true.La)
    assert m.inputs == ("V1", "w1") and m.fixed["V2"] == 10.0
    # the pulse edges lie between the 10 us samples: the fit follows the drive on a 1 us grid (exact here;
    # the drive sampled at 10 us and held linear between samples gives Ra +43 %, CN +22 %, Kc +11 %)
    for k in ("Ra", "CN", "Kc"):
        assert m.ecm["parameters"][k]["value"] == pytest.approx(getattr(true, k), rel=1e-6)
    test = {**c, "V1": 31.0, "w1": 205.0}
    truth = drive_history(ph, Drive(ThreePulseTemplate(), test, 220.0), THREE_PULSE_LAWS)
    p = m.predict(test)
    assert p["outside_training_region"] == []
    assert p["pinchoff_us"] == pytest.approx(truth.pinchoff_instant_us, abs=1e-6)  # the law is linear
    assert p["inflight_volume_nl"] == pytest.approx(truth.inflight_volume_nl, rel=2e-3)
    assert p["jetting_velocity_m_s"] == pytest.approx(truth.jetting_velocity_m_s, rel=2e-3)
    back = TemplateModel.from_dict(json.loads(json.dumps(m.to_dict())))
    assert back.predict(test) == p
    m.save(tmp_path / "model.json")
    assert TemplateModel.from_json(tmp_path / "model.json").predict(test) == p
    doc = m.to_dict()
    doc["volume_adjuster"]["coefficients"] = doc["volume_adjuster"]["coefficients"][:2]
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"bad.json: invalid template model .*volume_adjuster.coefficients must be a "
                                         r"list of 3"):
        TemplateModel.from_json(tmp_path / "bad.json")
    del doc["ecm"]
    with pytest.raises(ValueError, match="missing key ecm"):
        TemplateModel.from_dict(doc, "x.json")
    assert m.predict({**test, "V1": 40.0})["outside_training_region"] == ["V1"]
    with pytest.raises(ValueError, match="V2 = 12 differs from the value 10"):
        m.predict({**test, "V2": 12.0})
    with pytest.raises(ValueError, match="need at least 4"):
        fit_template_model(ThreePulseTemplate(), table.iloc[:3], series, dead_time_us=220.0,
                           nozzle_inner_diameter_um=200.0, hydraulics=hyd)


def test_the_papers_hybrid_model_is_the_trapezoid_case(tmp_path):
    """The (u1, u2) hybrid model at orders (1, 1) (`identify.hybrid_fit.fit_hybrid`) and the hybrid model on
    the trapezoid template (`identify.template_fit`, the drive at the strobe delays as fit_hybrid takes it)
    are one model: the same ECM and the same predictions, to rounding (the table's columns u1_um_per_ms,
    u2_um are the template's parameters)."""
    from identify.hybrid_fit import fit_hybrid
    from identify.synthetic_dataset import make_synthetic_dataset

    grid = [(a, b) for a in (60.0, 70.0, 80.0) for b in (21.25, 25.0, 28.75)]
    ds = make_synthetic_dataset(tmp_path / "ds", grid=grid, noise_percent=1.0, seed=3)
    h = fit_hybrid(ds, orders=((1, 1),), arx=False, folds=3).model
    m = fit_template_model(TrapezoidTemplate(), ds.summary, ds.timeseries, dead_time_us=ds.dead_time_us,
                           nozzle_inner_diameter_um=ds.nozzle_inner_diameter_um, hydraulics=ds.hydraulics(),
                           substeps=1)
    np.testing.assert_allclose(m.ecm_coefficients.to_array(), h.ecm_coefficients.to_array(), rtol=1e-12)
    for u1, u2 in ((65.0, 23.0), (75.0, 27.0), (60.0, 28.75)):
        a, b = h.nominal(u1, u2), m.predict({"u1_um_per_ms": u1, "u2_um": u2})
        for k in ("pinchoff_us", "grown_volume_at_pinchoff_nl", "inflight_volume_nl", "jetting_velocity_m_s"):
            assert b[k] == pytest.approx(a[k], rel=1e-12), k


def test_synth_command_line_takes_a_template(tmp_path, capsys):
    from dropvision.app.cli import main

    doc = {"template": "three_pulse", "parameters": THREE_PULSE_CENTRE}
    assert main(["synth", str(tmp_path / "s"), "--size", "96x256", "--tip-row", "20.4", "--delays", "0:700:350",
                 "--no-progress", "--waveform", json.dumps(doc)]) == 0
    assert json.loads((tmp_path / "s" / "sequence.json").read_text())["waveform"]["parameters"] == THREE_PULSE_CENTRE
    assert json.loads((tmp_path / "s" / "truth.json").read_text())["pinchoff_instant_us"] == 660.0
    bad = {**doc, "laws": {"pinchoff_us": {"constant": 600, "slopes": {"u1_um_per_ms": 1}},
                           "volume_adjuster_nl": {"constant": 0}, "velocity_adjuster_m_s": {"constant": 0}}}
    capsys.readouterr()
    assert main(["synth", str(tmp_path / "t"), "--waveform", json.dumps(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert "slope for 'u1_um_per_ms', which is not a parameter of the drive (V1, V2" in err and "\n" not in err


def test_segments_template_declared_by_the_lab():
    """A drive the lab declares itself (Dimatix-style segments), pinned to hand-computed corners; written as
    segments, the paper's trapezoid is Eq. (1) to rounding."""
    from identify.waveform import SegmentsTemplate

    dim = SegmentsTemplate({"Vp": "V", "Vn": "V", "t1": "us", "t2": "us"},
                           [[3, "-Vn"], ["t1", "-Vn"], [2, "Vp"], ["t2", "Vp"], [2, 0], [10, 0]])
    v = {"Vp": 20.0, "Vn": 5.0, "t1": 4.0, "t2": 6.0}
    # by hand: 0 -> -5 V over [0, 3], held to 7, -5 -> 20 V over [7, 9], held to 15, back to 0 at 17
    t = [0.0, 1.5, 3.0, 7.0, 8.0, 9.0, 15.0, 16.0, 17.0, 27.0, 30.0]
    assert dim.drive(v, t) == pytest.approx([0, -2.5, -5, -5, 7.5, 20, 20, 10, 0, 0, 0], abs=1e-12)
    assert dim.velocity_instant_us(v) == 9.0  # the end of the first segment reaching |20 V|
    assert dim.parameter_names == ("Vp", "Vn", "t1", "t2") and dim.units()["t1"] == "us"
    doc = Drive(dim, v, 100.0).to_dict()
    back = drive_from_document(json.loads(json.dumps(doc)))
    assert back.template == dim and back.values == v
    assert validate_waveform(doc, "s")["segments"] == doc["segments"]

    trap = SegmentsTemplate({"A": "um", "rise": "us", "hold": "us", "fall": "us"},
                            [["rise", "A"], ["hold", "A"], ["fall", 0]], unit="um")
    tt = np.arange(-5.0, 13500.0, 0.37)
    tv = {"A": 25.0, "rise": 1000 * 25 / 70, "hold": 20.0, "fall": 1000 * 25 / 2}
    np.testing.assert_allclose(trap.drive(tv, tt), Waveform(70.0, 25.0).displacement_um(tt), rtol=0, atol=1e-12)
    assert trap.velocity_instant_us(tv) == pytest.approx(Waveform(70.0, 25.0).max_stroke_us, rel=1e-15)

    bad = [
        ({"declare": {"V": "V"}, "segments": [["t", "V"], [1, 0]]}, "names 't', which is not declared"),
        ({"declare": {"V": "V", "t": "ms"}, "segments": [["t", "V"], [1, 0]]}, "a duration is in us"),
        ({"declare": {"V": "V", "t": "us"}, "segments": [["V", "t"], [1, 0]]}, "is in us, but V is declared in V"),
        ({"declare": {"V": "V", "t": "us"}, "segments": [["t", "V"]]}, "must end at level 0"),
        ({"declare": {"V": "V", "t": "us"}, "segments": [["t", "V"], [1, 0]], "colour": 1}, "unknown constant(s) colour"),
    ]
    for consts, why in bad:
        with pytest.raises(ValueError, match=re.escape(why)):
            template_from_dict({"template": "segments", **consts})
    with pytest.raises(ValueError, match="a step needs a ramp"):
        SegmentsTemplate({"V": "V"}, [[0, "V"], [5, 0]]).drive({"V": 1.0}, [1.0])


def test_segments_template_head_identified_noise_free():
    """The hybrid model fits a head whose drive the lab declared (one trapezoidal pulse, amplitude and
    plateau varied), exactly without noise."""
    from identify.physics import LinearLaw, TemplateLaws
    from identify.waveform import SegmentsTemplate

    ph = SynthPhysics()
    tpl = SegmentsTemplate({"A": "V", "top": "us"}, [[50, "A"], ["top", "A"], [100, 0]])
    centre = {"A": 25.0, "top": 150.0}
    laws = TemplateLaws(LinearLaw(620.0, {"A": 2.0, "top": 0.5}, centre), LinearLaw(0.2, {"A": 0.01}, centre),
                        LinearLaw(0.3, {"top": 0.001}, centre))
    rows, series = [], []
    t = np.arange(0.0, 900.0, 10.0)
    settings = [{"A": a, "top": b} for a in (20.0, 30.0) for b in (120.0, 180.0)] + [dict(centre)]
    for i, v in enumerate(settings):
        h = drive_history(ph, Drive(tpl, v, 220.0), laws)
        att = t < np.ceil(h.pinchoff_instant_us / 10.0) * 10.0
        series.append(pd.DataFrame({"sequence_id": i, "delay_us": t, "attached": att,
                                    "grown_volume_nl": np.where(att, h.grown_volume_nl_at(t), np.nan)}))
        rows.append({"sequence_id": i, **v, "pinchoff_us": h.pinchoff_instant_us,
                     "inflight_volume_nl": h.inflight_volume_nl, "jetting_velocity_m_s": h.jetting_velocity_m_s})
    true = ph.ecm_parameters()
    m = fit_template_model(tpl.to_dict(), pd.DataFrame(rows), pd.concat(series), dead_time_us=220.0,
                           nozzle_inner_diameter_um=200.0, hydraulics=(true.LN, true.RN, true.LR, true.RR), la=true.La)
    for k in ("Ra", "CN", "Kc"):
        assert m.ecm["parameters"][k]["value"] == pytest.approx(getattr(true, k), rel=1e-6)
    test = {"A": 27.0, "top": 140.0}
    truth = drive_history(ph, Drive(tpl, test, 220.0), laws)
    p = TemplateModel.from_dict(json.loads(json.dumps(m.to_dict()))).predict(test)
    assert p["inflight_volume_nl"] == pytest.approx(truth.inflight_volume_nl, rel=1e-6)
    assert p["jetting_velocity_m_s"] == pytest.approx(truth.jetting_velocity_m_s, rel=1e-6)
