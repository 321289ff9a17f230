"""Synthetic truth: closed-form volumes, ECM bookkeeping, pinch-off, kinematics, satellites."""

import numpy as np
import pytest

from identify.ecm import simulate
from identify.waveform import Waveform
from dropvision.synth import SynthConfig, SynthPhysics, drop_history, plan, sequence_truth
from dropvision.synth.shapes import (UM3_PER_NL, DropShapeModel, Profile, QuadraticNeck, SphericalSegment,
                                     Spheroid, cap_height_for_volume_um)

PHYS = SynthPhysics()


def test_profile_integrator_matches_closed_forms():
    sphere = Profile((Spheroid(12.0, 150.0, 150.0),))
    assert sphere.volume_um3() == pytest.approx(4 / 3 * np.pi * 150.0**3, rel=1e-12)
    prolate = Profile((Spheroid(-30.0, 210.0, 120.0),))
    assert prolate.volume_um3() == pytest.approx(4 / 3 * np.pi * 210.0 * 120.0**2, rel=1e-12)
    assert prolate.centroid_um() == pytest.approx(-30.0, abs=1e-9)
    for h in (5.0, 15.0, 100.0, 320.0):  # cap, hemisphere, bulb
        seg = SphericalSegment(100.0, h)
        R = (100.0**2 + h**2) / (2 * h)
        # sphere volume minus the cap of height 2R - h cut off above the plane
        cut = 2 * R - h
        expected = 4 / 3 * np.pi * R**3 - np.pi * cut**2 * (3 * R - cut) / 3
        assert Profile((seg,)).volume_um3() == pytest.approx(expected, rel=1e-11)
        assert cap_height_for_volume_um(100.0, expected) == pytest.approx(h, rel=1e-10)
    # frustum-free check of the neck: r = 1 + s^2 on [0, 1] -> pi * (1 + 2/3 + 1/5)
    neck = Profile((QuadraticNeck(0.0, 1.0, 1.0, 2.0),))
    assert neck.volume_um3() == pytest.approx(np.pi * (1 + 2 / 3 + 1 / 5), rel=1e-12)
    # disjoint union = sum
    two = Profile((Spheroid(0.0, 50.0, 50.0), Spheroid(200.0, 30.0, 30.0)))
    assert two.volume_um3() == pytest.approx(4 / 3 * np.pi * (50.0**3 + 30.0**3), rel=1e-12)


def test_history_is_the_ecm_and_laws():
    h = drop_history(PHYS, 70.0, 25.0, t_end_us=1500.0)
    t = np.arange(0.0, 1500.0, 0.25)  # independent grid
    v, f = simulate(PHYS.ecm_parameters().coefficients(), t, Waveform(70.0, 25.0).displacement_um(t - 220.0))
    sel = slice(0, None, 40)
    np.testing.assert_allclose(h.grown_volume_nl_at(t[sel]), v[sel], atol=2e-4)
    assert h.pinchoff_instant_us == pytest.approx(1050.0)
    assert h.inflight_volume_nl == pytest.approx(np.interp(1050.0, t, v) + 0.16 + 0.014 * 70 + 0.0037 * 25, abs=1e-3)
    t_max = 220 + 1000 * 25 / 70
    fv = np.interp(t_max, t, f) * 1e-6 / (np.pi * (100e-6) ** 2)
    assert h.jetting_velocity_m_s == pytest.approx(fv - 0.155 + 0.0025 * 70 + 0.0008 * 25, abs=1e-3)
    p = PHYS.ecm_parameters()
    assert p.natural_frequency_hz() == pytest.approx(800.0)
    assert 0.15 < p.damping_ratio() < 0.25


@pytest.mark.parametrize("u1,u2", [(50.0, 20.0), (70.0, 25.0), (80.0, 35.0), (55.0, 30.0)])
def test_colour_ink_grid_corners_are_reasonable(u1, u2):
    h = drop_history(PHYS, u1, u2, t_end_us=1600.0)
    assert 10.0 < h.inflight_volume_nl < 28.0
    assert 0.9 < h.jetting_velocity_m_s < 1.95


@pytest.mark.parametrize("u1,u2", [(70.0, 25.0), (50.0, 35.0), (80.0, 20.0)])
def test_attached_volume_is_meniscus_plus_grown(u1, u2):
    h = drop_history(PHYS, u1, u2, t_end_us=1800.0)
    m = DropShapeModel(h, PHYS)
    men = SphericalSegment(100.0, 15.0).volume_um3() / UM3_PER_NL
    assert m.initial_meniscus_volume_nl() == pytest.approx(men, rel=1e-12)
    ts = np.concatenate([np.arange(0.0, h.pinchoff_instant_us, 37.0),
                         h.pinchoff_instant_us - np.array([60.0, 10.0, 1.0, 0.01])])
    for t in ts:
        s = m.state(t)
        assert s.attached and s.main_body is None
        expected = men + float(h.grown_volume_nl_at(t))
        assert s.attached_volume_nl == pytest.approx(expected, rel=1e-7, abs=1e-9)
        assert s.grown_volume_nl == pytest.approx(float(h.grown_volume_nl_at(t)), abs=1e-12)
    s = m.state(h.pinchoff_instant_us)
    assert not s.attached and s.drop_volume_nl == pytest.approx(h.inflight_volume_nl, rel=1e-7)


def test_pinchoff_truth_is_first_frame_at_or_after_instant():
    cfg = SynthConfig(u1_um_per_ms=55.0, u2_um=31.0, width_px=96, height_px=128)
    p = plan(cfg)
    tp = p.history.pinchoff_instant_us
    assert tp % 10 != 0
    truth = sequence_truth(p)
    delays = np.array(cfg.delays_us)
    assert truth["pinchoff_us"] == delays[delays >= tp].min()
    assert truth["pinchoff_instant_us"] == pytest.approx(1050 - 14 * (55 - 70) + 10.2 * (31 - 25))
    last = delays[delays < tp].max()
    assert truth["grown_volume_at_pinchoff_nl"] == pytest.approx(float(p.history.grown_volume_nl_at(last)))
    for d in (last, truth["pinchoff_us"]):
        assert p.model.state(d).attached == (d < tp)


@pytest.mark.parametrize("drift_mrad", [0.0, 25.0])
def test_inflight_centroid_is_linear_at_jetting_velocity(drift_mrad):
    h = drop_history(PHYS, 70.0, 25.0, t_end_us=1800.0)
    m = DropShapeModel(h, PHYS, drift_mrad=drift_mrad)
    ts = np.arange(1050.0, 1801.0, 10.0)
    states = [m.state(t) for t in ts]
    fl = np.array([s.inflight for s in states])
    assert fl.sum() > 50 and not fl[0] and states[0].tail_attached
    z = np.array([s.drop_z_um for s in states])[fl]
    x = np.array([s.drop_x_um for s in states])[fl]
    t = ts[fl]
    v = h.jetting_velocity_m_s  # µm/µs
    th = drift_mrad * 1e-3
    np.testing.assert_allclose(np.diff(z) / np.diff(t), v * np.cos(th), rtol=1e-9)
    np.testing.assert_allclose(np.diff(x) / np.diff(t), v * np.sin(th), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose([s.drop_volume_nl for s in states], h.inflight_volume_nl, rtol=1e-7)


@pytest.mark.parametrize("n", [1, 2])
def test_satellite_config_gives_satellites(n):
    h = drop_history(PHYS, 70.0, 25.0, t_end_us=1800.0)
    m = DropShapeModel(h, PHYS, satellites=n)
    early, late = m.state(1060.0), m.state(1500.0)
    assert early.n_satellites == 0 and early.tail_attached
    assert late.n_satellites == n and late.inflight
    v_sat = 0.02 * h.inflight_volume_nl
    assert late.drop_volume_nl == pytest.approx(h.inflight_volume_nl, rel=1e-7)
    assert late.detached_volume_nl == pytest.approx(h.inflight_volume_nl + v_sat, rel=1e-7)
    assert early.detached_volume_nl == pytest.approx(h.inflight_volume_nl + v_sat, rel=1e-7)
    # satellites are separate, behind the drop, and clear of the residual meniscus
    drop = late.main_body
    top = drop.origin_z_um - drop.profile.support[1]
    zs = sorted(b.origin_z_um for b in late.satellites)
    r_s = late.satellites[0].profile.max_radius_um
    assert zs[-1] + r_s < top
    assert zs[0] - r_s > 100.0
    assert all(b - a > 2 * r_s for a, b in zip(zs[:-1], zs[1:]))
