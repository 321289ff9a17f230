"""Waveform (Eq. 1/9) and ECM (Eqs. 2-6) against independent references."""

import numpy as np
import pytest
from scipy import signal

from identify.ecm import simulate
from identify.hydraulics import pipe_inertance, pipe_resistance
from identify.waveform import Waveform


def test_waveform_corners():
    w = Waveform(70.0, 25.0)
    assert w.rise_us == pytest.approx(1000 * 25 / 70)
    t = np.array([-1.0, 0.0, w.rise_us / 2, w.rise_us, w.rise_us + 10, w.retract_start_us + 500, w.end_us + 1])
    u = w.displacement_um(t)
    np.testing.assert_allclose(u, [0, 0, 12.5, 25, 25, 25 - 2e-3 * 500, 0], atol=1e-12)


def test_sampled_eq9_matches_eq1():
    w = Waveform(50.0, 20.0)
    u = w.sampled_um(80)
    assert u.size == 81
    np.testing.assert_allclose(u, w.displacement_um(np.arange(81) * 10.0))
    with pytest.raises(ValueError):
        Waveform(-1.0, 20.0)


def test_pipe_elements_eq2():
    assert pipe_resistance(1e-3, 1.0, 1.0) == pytest.approx(8e-3 / np.pi)
    assert pipe_inertance(1000.0, 2.0, 1.0) == pytest.approx(2000.0 / np.pi)


def _params():
    """Colour-ink-like physics from nozzle geometry and ink (Eq. 2): the synthesizer's default."""
    from identify.physics import SynthPhysics

    return SynthPhysics().ecm_parameters()


def test_characteristic_polynomial_factorises():
    p = _params()
    c = p.coefficients()
    poles = np.sort_complex(c.poles())
    wn = 2 * np.pi * p.natural_frequency_hz()
    z = p.damping_ratio()
    expected = np.sort_complex(
        np.array([-p.Ra / p.La, -z * wn + 1j * wn * np.sqrt(1 - z**2), -z * wn - 1j * wn * np.sqrt(1 - z**2)])
    )
    np.testing.assert_allclose(poles, expected, rtol=1e-9)


def test_simulate_matches_scipy_lsim():
    c = _params().coefficients()
    w = Waveform(70.0, 25.0)
    t = np.arange(0.0, 1500.0, 1.0)
    u = w.displacement_um(t - 220.0)
    vol, flow = simulate(c, t, u)
    num, den = c.volume_tf()
    sys = signal.lti(num * 1e-6 / 1e-12, den)  # µm in, nl out, time in s
    _, y_ref, _ = signal.lsim(sys, u, t * 1e-6)
    np.testing.assert_allclose(vol, y_ref, atol=1e-6 * np.abs(y_ref).max())
    np.testing.assert_allclose(flow, np.gradient(vol, t), atol=2e-3 * np.abs(flow).max())
    assert 10 < vol.max() < 25


def test_simulate_rows_equal_single_simulations():
    c = _params().coefficients()
    t = np.arange(0.0, 1200.0, 10.0)
    U = np.stack([Waveform(u1, u2).displacement_um(t - 220.0) for u1, u2 in [(50, 20), (70, 25), (80, 35)]])
    vol, flow = simulate(c, t, U)
    assert vol.shape == flow.shape == U.shape
    for k in range(U.shape[0]):
        v1, f1 = simulate(c, t, U[k])
        np.testing.assert_allclose(vol[k], v1, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(flow[k], f1, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError):
        simulate(c, t, U[:, :-1])
