"""Monte Carlo uncertainty of the hybrid model (Section 5.1), vectorised over samples.

Instead of the paper's grid of values drawn from each parameter's interval, every model
parameter vector is drawn from its estimated covariance: the six ECM coefficients
(A3, A2, A1, A0, B1, B0) from a multivariate normal (in relative units, a singular
covariance is fine), and each polynomial (pinch-off, volume and velocity adjusters) from
the multivariate normal of its coefficients. Each draw is one hybrid model; the spread of
the predicted pinch-off instant, grown volume at pinch-off, in-flight volume and jetting
velocity is reported as mean, std and a 95 % band (2.5 / 97.5 percentiles).

Batched exact simulation
------------------------
The third-order ECM of Eq. (6) is put in modal form per sample (poles λ_i from a closed-form
cubic solve polished by Newton steps, residues r_i): Y = Σ r_i /(s - λ_i) U. With a
piecewise-linear input (first-order hold, exact for the trapezoidal waveform) each mode
advances over a step δ exactly as

    z <- exp(λδ) z + δ φ1(λδ) u0 + δ² φ2(λδ) slope,  φ1(x) = (e^x-1)/x, φ2(x) = (e^x-1-x)/x²,

volume = Re Σ r_i z_i and flow = Re Σ r_i (λ_i z_i + u). Scalar outputs at arbitrary
instants (pinch-off, maximum stroke) are obtained by stepping exactly through the corners of
the waveform (:func:`ecm_response_at`, no time loop); the per-time band for plotting uses a
time loop over (N, 3) complex arrays, compiled with numba when available
(:func:`simulate_ensemble`). Samples with (nearly) repeated poles fall back to the companion
form of :mod:`identify.ecm` with a matrix exponential.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field


def _default_numba_cache_dir() -> str:
    """``$XDG_CACHE_HOME/dropvision/numba`` (``~/.cache/...``), or a per-user temporary folder
    when the home cache cannot be created: never next to the installed sources."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    for folder in (os.path.join(base, "dropvision", "numba"),
                   os.path.join(tempfile.gettempdir(), f"dropvision-numba-{os.getuid() if hasattr(os, 'getuid') else 0}")):
        try:
            os.makedirs(folder, exist_ok=True)
        except OSError:
            continue
        if os.access(folder, os.W_OK):
            return folder
    return ""


# numba's cache (``@njit(cache=True)`` below) goes to a user cache folder, not next to the
# installed source: set before numba is imported, unless the user chose NUMBA_CACHE_DIR.
if not os.environ.get("NUMBA_CACHE_DIR"):
    _cache_dir = _default_numba_cache_dir()
    if _cache_dir:
        os.environ["NUMBA_CACHE_DIR"] = _cache_dir

from typing import TYPE_CHECKING

import numpy as np  # noqa: E402

if TYPE_CHECKING:
    import pandas as pd

from identify.ecm import COEFF_NAMES, NL, UM, EcmCoefficients, companion_form, flow_velocity_m_s, foh_step, simulate
from identify.polynomial import design_matrix  # noqa: E402
from identify.polynomial import sample_mvn  # noqa: E402
from identify.waveform import Waveform  # noqa: E402

_UM_PER_NL = UM / NL  # m^3 per m of displacement -> nl per µm
_TU = 1e-6  # time unit: µs

try:  # numba is optional: the numpy path gives identical results, only slower
    import numba as _numba
except ImportError:  # pragma: no cover - depends on the installation
    _numba = None
else:
    if os.environ.get("NUMBA_CACHE_DIR") and not getattr(_numba.config, "CACHE_DIR", ""):
        # numba was imported (and read its configuration) before this module
        _numba.config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]

#: Peak memory of one Monte Carlo sample (bytes), measured with tracemalloc on
#: :func:`run_monte_carlo` and `identify.design.design` (~650 B: the (N, 6) coefficient draws,
#: the three polynomial draws, the modal form with its (N, 3) complex poles and residues, the
#: corner stepping) rounded up to 1 KiB for a margin.
BYTES_PER_SAMPLE = 1024
#: Most memory a Monte Carlo may use: min(available RAM / 4, this).
MEMORY_CAP_BYTES = 4 << 30


class SampleCountError(ValueError):
    """A Monte Carlo sample count below 1 or above what fits in memory (:func:`max_samples`)."""


def available_memory_bytes() -> int | None:
    """Memory available to a new allocation (``MemAvailable`` of /proc/meminfo), or None."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):  # pragma: no cover - not on POSIX
        return None


def memory_budget_bytes() -> int:
    """min(available RAM / 4, :data:`MEMORY_CAP_BYTES`)."""
    avail = available_memory_bytes()
    return MEMORY_CAP_BYTES if avail is None else max(0, min(avail // 4, MEMORY_CAP_BYTES))


def max_samples() -> int:
    """Largest Monte Carlo sample count that fits in :func:`memory_budget_bytes`."""
    return max(1, memory_budget_bytes() // BYTES_PER_SAMPLE)


def check_samples(samples, what: str = "samples") -> int:
    """``samples`` as an int in [1, :func:`max_samples`], or :class:`SampleCountError` stating
    the maximum (``what`` names the option in the message, e.g. ``"--samples"``)."""
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)):
        raise SampleCountError(f"{what} must be an integer, got {samples!r}")
    n = int(samples)
    if n < 1:
        raise SampleCountError(f"{what} must be >= 1, got {n}")
    top = max_samples()
    if n > top:
        need = n * BYTES_PER_SAMPLE / 2**30
        raise SampleCountError(
            f"{what} {n}: the Monte Carlo would need about {need:.3g} GiB; at most {top} samples fit in "
            f"the memory budget of {memory_budget_bytes() / 2**30:.3g} GiB (min(available RAM / 4, "
            f"{MEMORY_CAP_BYTES >> 30} GiB) at ~{BYTES_PER_SAMPLE} bytes per sample)")
    return n

#: Whether numba is installed (:func:`simulate_ensemble` then compiles its time loop).
HAVE_NUMBA = _numba is not None


def coeff_array(coeffs) -> np.ndarray:
    """ECM coefficient rows as an array.

    Parameters
    ----------
    coeffs : EcmCoefficients, dict or array_like of shape (6,) or (N, 6)
        Coefficients of Eq. (6) in SI units, order :data:`identify.ecm.COEFF_NAMES`.

    Returns
    -------
    ndarray, shape (N, 6)
        (A3, A2, A1, A0, B1, B0) per row (SI units).
    """
    if isinstance(coeffs, EcmCoefficients):
        return coeffs.to_array()[None, :]
    if isinstance(coeffs, dict):
        return np.array([[float(coeffs[k]) for k in COEFF_NAMES]])
    c = np.atleast_2d(np.asarray(coeffs, dtype=float))
    if c.shape[-1] != 6:
        raise ValueError(f"ECM coefficients must have 6 columns (A3..B0), got shape {c.shape}")
    return c


# ---------------------------------------------------------------------------------------
# modal form
# ---------------------------------------------------------------------------------------


def cubic_roots(a2, a1, a0) -> np.ndarray:
    """Roots of the monic cubics s^3 + a2 s^2 + a1 s + a0, closed form polished by Newton steps.

    Parameters
    ----------
    a2, a1, a0 : ndarray, shape (N,)
        Real coefficients (units of 1/time, 1/time^2, 1/time^3; 1/µs here).

    Returns
    -------
    ndarray, shape (N, 3), complex
        The roots (1/time unit), the real root first.
    """
    scale = np.maximum(np.abs(a0) ** (1 / 3), np.maximum(np.abs(a1) ** 0.5, np.abs(a2)))
    scale = np.where(scale > 0, scale, 1.0)
    b2, b1, b0 = a2 / scale, a1 / scale**2, a0 / scale**3
    p = b1 - b2**2 / 3
    q = 2 * b2**3 / 27 - b2 * b1 / 3 + b0
    disc = (q / 2) ** 2 + (p / 3) ** 3
    t = np.empty_like(p)
    one = disc > 0
    if one.any():
        qq, pp, dd = q[one], p[one], disc[one]
        A = -np.sign(qq) * np.cbrt(np.abs(qq) / 2 + np.sqrt(dd))
        A = np.where(A == 0, np.cbrt(-qq), A)
        with np.errstate(divide="ignore", invalid="ignore"):
            B = np.where(A != 0, -pp / (3 * A), 0.0)
        t[one] = A + B
    three = ~one
    if three.any():
        pp, qq = p[three], q[three]
        m = 2 * np.sqrt(np.maximum(-pp / 3, 0))
        with np.errstate(divide="ignore", invalid="ignore"):
            arg = np.clip(np.where(m > 0, -4 * qq / m**3, 0.0), -1, 1)
        t[three] = m * np.cos(np.arccos(arg) / 3)
    r = t - b2 / 3
    for _ in range(3):  # Newton polish of the real root
        f = ((r + b2) * r + b1) * r + b0
        df = (3 * r + 2 * b2) * r + b1
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(df != 0, f / df, 0.0)
        r = r - step
    # deflate: s^2 + c1 s + c0
    c1 = b2 + r
    c0 = b1 + r * c1
    d = np.sqrt((c1**2 / 4 - c0).astype(complex))
    # stable quadratic: root with larger magnitude first
    sgn = np.where(c1 >= 0, 1.0, -1.0)
    big = -c1 / 2 - sgn * d
    with np.errstate(divide="ignore", invalid="ignore"):
        small = np.where(big != 0, c0 / big, 0.0)
    roots = np.column_stack([r.astype(complex), big, small])
    for _ in range(2):  # Newton polish of all three (complex)
        f = ((roots + b2[:, None]) * roots + b1[:, None]) * roots + b0[:, None]
        df = (3 * roots + 2 * b2[:, None]) * roots + b1[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(df != 0, f / df, 0.0)
        roots = roots - step
    return roots * scale[:, None]


@dataclass
class ModalEcm:
    """Batched modal form of Eq. (6) in µs / µm / nl units.

    lam : (N, 3) complex poles (1/µs); res : (N, 3) complex residues; fallback : (N,) bool
    samples with nearly repeated poles (handled by the companion form); coeffs : (N, 6).
    """

    lam: np.ndarray
    res: np.ndarray
    fallback: np.ndarray
    coeffs: np.ndarray

    @property
    def n(self) -> int:
        return self.lam.shape[0]


def modal_form(coeffs) -> ModalEcm:
    """Poles and residues of Eq. (6) for each coefficient row."""
    c = coeff_array(coeffs)
    A3 = c[:, 0]
    if np.any(A3 == 0) or not np.all(np.isfinite(c)):
        raise ValueError("ECM coefficients must be finite with A3 != 0")
    a2, a1, a0 = c[:, 1] / A3 * _TU, c[:, 2] / A3 * _TU**2, c[:, 3] / A3 * _TU**3
    n1, n0 = -c[:, 4] / A3 * _TU**2 * _UM_PER_NL, -c[:, 5] / A3 * _TU**3 * _UM_PER_NL
    lam = cubic_roots(a2, a1, a0)
    # real cubic: roots are one real root and a conjugate pair, or three real roots; make
    # that exact (the time loop uses it to halve the work)
    lam[:, 0] = lam[:, 0].real
    cpx = np.abs(lam[:, 1].imag) > 1e-12 * np.abs(lam[:, 1])
    lam[cpx, 2] = np.conj(lam[cpx, 1])
    lam[~cpx, 1:] = lam[~cpx, 1:].real
    d01, d02, d12 = lam[:, 0] - lam[:, 1], lam[:, 0] - lam[:, 2], lam[:, 1] - lam[:, 2]
    mag = np.max(np.abs(lam), axis=1)
    sep = np.min(np.abs(np.column_stack([d01, d02, d12])), axis=1)
    fallback = ~(sep > 1e-5 * mag)
    den = np.column_stack([d01 * d02, -d01 * d12, d02 * d12])
    num = n1[:, None] * lam + n0[:, None]
    res = np.zeros_like(lam)
    ok = ~fallback
    res[ok] = num[ok] / den[ok]
    res[:, 0] = res[:, 0].real
    res[cpx, 2] = np.conj(res[cpx, 1])
    res[~cpx, 1:] = res[~cpx, 1:].real
    return ModalEcm(lam=lam, res=res, fallback=fallback, coeffs=c)


def _phi12(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """φ1(x) = (e^x - 1)/x and φ2(x) = (e^x - 1 - x)/x² for complex x, accurate near 0."""
    x = np.asarray(x, dtype=complex)
    phi1 = 1 + x / 2 + x**2 / 6 + x**3 / 24 + x**4 / 120
    phi2 = 0.5 + x / 6 + x**2 / 24 + x**3 / 120 + x**4 / 720 + x**5 / 5040
    big1 = np.abs(x) > 1e-3
    big2 = np.abs(x) > 2e-2
    if big1.any():
        xb = x[big1]
        phi1[big1] = np.expm1(xb) / xb
    if big2.any():
        xb = x[big2]
        phi2[big2] = (np.expm1(xb) - xb) / xb**2
    return phi1, phi2


def _segments(w: Waveform):
    """(start µs, end µs, u at start µm, slope µm/µs) of the piecewise-linear waveform."""
    r, th, e = w.rise_us, w.retract_start_us, w.end_us
    return [
        (0.0, r, 0.0, w.u1_um_per_ms * 1e-3),
        (r, th, w.u2_um, 0.0),
        (th, e, w.u2_um, -w.u3_um_per_ms * 1e-3),
        (e, np.inf, 0.0, 0.0),
    ]


def _companion_response_at(c_row: np.ndarray, w: Waveform, tau: float) -> tuple[float, float]:
    """Reference path (one sample): exact stepping of the companion form through the corners."""
    coeffs = EcmCoefficients(*c_row)
    A, B, C = companion_form(coeffs, _TU)
    n = 3
    x = np.zeros(n)
    for a, b, u0, s in _segments(w):
        d = float(np.clip(tau - a, 0.0, b - a))
        if d <= 0:
            continue
        Phi, G0, G1 = foh_step(A, B, d)
        x = Phi @ x + G0 * u0 + G1 * s
    u = float(w.displacement_um(tau))
    return float(C @ x), float(C @ (A @ x + B * u))


def ecm_response_at(coeffs, w: Waveform, tau_us) -> tuple[np.ndarray, np.ndarray]:
    """Exact ECM volume (nl) and flow (nl/µs) at times ``tau_us`` after the waveform start.

    Parameters
    ----------
    coeffs : (N, 6) array or EcmCoefficients
        One coefficient row per sample.
    w : Waveform
        The (undelayed) waveform, common to all samples.
    tau_us : array_like, shape (N,) or scalar
        Time since the start of the piston motion (trigger time minus dead time), per sample.
    """
    modal = coeffs if isinstance(coeffs, ModalEcm) else modal_form(coeffs)
    tau_in = np.atleast_1d(np.asarray(tau_us, dtype=float))
    N = max(modal.n, tau_in.size)
    if modal.n not in (1, N) or tau_in.size not in (1, N):
        raise ValueError(f"{modal.n} coefficient rows and {tau_in.size} instants do not broadcast")
    tau = np.broadcast_to(tau_in, (N,)).copy()
    return _respond(modal, _segments(w), tau, w.displacement_um(tau), lambda i: w)


def ecm_response_at_controls(coeffs, u1, u2, tau_us, u3_um_per_ms: float, hold_us: float):
    """Like :func:`ecm_response_at` for one waveform per row: (u1, u2, tau) arrays of shape (N,)."""
    modal = coeffs if isinstance(coeffs, ModalEcm) else modal_form(coeffs)
    u1, u2, tau = np.broadcast_arrays(*(np.atleast_1d(np.asarray(a, float)) for a in (u1, u2, tau_us)))
    rise = 1000.0 * u2 / u1
    th = rise + hold_us
    end = th + 1000.0 * u2 / u3_um_per_ms
    segs = [(0.0, rise, 0.0, u1 * 1e-3), (rise, th, u2, 0.0), (th, end, u2, -u3_um_per_ms * 1e-3), (end, np.inf, 0.0, 0.0)]
    u = np.where(tau <= rise, u1 * 1e-3 * tau, np.where(tau <= th, u2, u2 - u3_um_per_ms * 1e-3 * (tau - th)))
    u = np.where((tau < 0) | (tau > end), 0.0, u)
    return _respond(modal, segs, tau.copy(), u, lambda i: Waveform(u1[i], u2[i], u3_um_per_ms, hold_us))


def _respond(modal: ModalEcm, segs, tau: np.ndarray, u: np.ndarray, waveform_of):
    N = tau.size
    if modal.n not in (1, N):
        raise ValueError(f"{modal.n} coefficient rows and {N} instants do not broadcast")
    lam = np.broadcast_to(modal.lam, (N, 3))
    res = np.broadcast_to(modal.res, (N, 3))
    z = np.zeros((N, 3), dtype=complex)
    for a, b, u0, s in segs:
        d = np.clip(tau - a, 0.0, b - a)
        if not np.any(d > 0):
            continue
        x = lam * d[:, None]
        p1, p2 = _phi12(x)
        u0 = np.broadcast_to(u0, (N,))[:, None]
        s = np.broadcast_to(s, (N,))[:, None]
        z = np.exp(x) * z + d[:, None] * p1 * u0 + (d**2)[:, None] * p2 * s
    vol = np.real(np.sum(res * z, axis=1))
    flow = np.real(np.sum(res * (lam * z + u[:, None]), axis=1))
    fb = np.broadcast_to(modal.fallback, (N,))
    for i in np.flatnonzero(fb):
        vol[i], flow[i] = _companion_response_at(modal.coeffs[i if modal.n > 1 else 0], waveform_of(i), tau[i])
    return vol, flow


if _numba is not None:

    @_numba.njit(cache=True)
    def _loop_numba(a, g0, g1, res, rl, u, s, vol, flow):  # pragma: no cover - compiled
        N = a.shape[0]
        n = u.shape[0]
        for i in range(N):
            sr = (res[i, 0] + res[i, 1] + res[i, 2]).real
            vol[i, 0] = 0.0
            flow[i, 0] = sr * u[0]
            pair = a[i, 1].imag != 0.0 and a[i, 2] == a[i, 1].conjugate() and res[i, 2] == res[i, 1].conjugate()
            if pair:  # one real mode + one complex mode standing for the conjugate pair
                a0 = a[i, 0].real
                b00 = g0[i, 0].real
                b10 = g1[i, 0].real
                r0 = res[i, 0].real
                q0 = rl[i, 0].real
                a1 = a[i, 1]
                b01 = g0[i, 1]
                b11 = g1[i, 1]
                r1 = 2.0 * res[i, 1]
                q1 = 2.0 * rl[i, 1]
                x0 = 0.0
                x1 = 0j
                for k in range(n - 1):
                    x0 = a0 * x0 + b00 * u[k] + b10 * s[k]
                    x1 = a1 * x1 + b01 * u[k] + b11 * s[k]
                    vol[i, k + 1] = r0 * x0 + (r1 * x1).real
                    flow[i, k + 1] = q0 * x0 + (q1 * x1).real + sr * u[k + 1]
            else:
                z0 = 0j
                z1 = 0j
                z2 = 0j
                for k in range(n - 1):
                    z0 = a[i, 0] * z0 + g0[i, 0] * u[k] + g1[i, 0] * s[k]
                    z1 = a[i, 1] * z1 + g0[i, 1] * u[k] + g1[i, 1] * s[k]
                    z2 = a[i, 2] * z2 + g0[i, 2] * u[k] + g1[i, 2] * s[k]
                    vol[i, k + 1] = (res[i, 0] * z0 + res[i, 1] * z1 + res[i, 2] * z2).real
                    flow[i, k + 1] = (rl[i, 0] * z0 + rl[i, 1] * z1 + rl[i, 2] * z2).real + sr * u[k + 1]


def _loop_numpy(a, g0, g1, res, rl, u, s, vol, flow):
    z = np.zeros_like(a)
    sr = res.sum(axis=1)
    vol[:, 0] = 0.0
    flow[:, 0] = np.real(sr * u[0])
    for k in range(u.size - 1):
        z = a * z + g0 * u[k] + g1 * s[k]
        vol[:, k + 1] = np.real(np.sum(res * z, axis=1))
        flow[:, k + 1] = np.real(np.sum(rl * z, axis=1) + sr * u[k + 1])


def simulate_ensemble(coeffs, t_us, u_um, *, use_numba: bool | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Simulate Eq. (6) from rest for N coefficient rows (an ensemble of ECMs) and one input.

    Same semantics as :func:`identify.ecm.simulate` (first-order hold, exact for the
    trapezoidal waveform), batched over the models; for one model and many inputs see
    :func:`identify.ecm.simulate_sampled`.

    Parameters
    ----------
    coeffs : ModalEcm, EcmCoefficients or array_like of shape (N, 6)
        ECM coefficient rows (SI units) or their modal form.
    t_us : array_like, shape (n,)
        Uniformly spaced times (µs).
    u_um : array_like, shape (n,)
        Piston displacement at ``t_us`` (µm), already delayed by any dead time.
    use_numba : bool, optional
        Compile the time loop with numba (default: when installed, :data:`HAVE_NUMBA`).

    Returns
    -------
    volume_nl, flow_nl_per_us : ndarray, shape (N, n)
        Growing volume (nl) and flow (nl/µs) of each model.
    """
    modal = coeffs if isinstance(coeffs, ModalEcm) else modal_form(coeffs)
    t = np.asarray(t_us, dtype=float)
    u = np.ascontiguousarray(u_um, dtype=float)
    if t.ndim != 1 or t.shape != u.shape:
        raise ValueError("t_us and u_um must be 1-D arrays of equal length")
    N, n = modal.n, t.size
    if n < 2:
        return np.zeros((N, n)), np.zeros((N, n))
    vol = np.empty((N, n))
    flow = np.empty((N, n))
    h = t[1] - t[0]
    if h <= 0 or not np.allclose(np.diff(t), h, rtol=1e-6, atol=1e-9):
        raise ValueError("t_us must be uniformly increasing")
    x = modal.lam * h
    p1, p2 = _phi12(x)
    a = np.exp(x)
    g0 = h * p1
    g1 = h * h * p2
    s = np.diff(u) / h
    rl = modal.res * modal.lam
    if use_numba is None:
        use_numba = HAVE_NUMBA
    if use_numba and HAVE_NUMBA:
        _loop_numba(a, g0, g1, modal.res, rl, u, s, vol, flow)
    else:
        _loop_numpy(a, g0, g1, modal.res, rl, u, s, vol, flow)
    for i in np.flatnonzero(modal.fallback):
        vol[i], flow[i] = simulate(EcmCoefficients(*modal.coeffs[i]), t, u)
    return vol, flow


def sample_ecm_coefficients(nominal, cov, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 6) ECM coefficient draws from N(nominal, cov), sampled in relative units.

    ``cov`` is the 6x6 covariance of (A3, A2, A1, A0, B1, B0); it may be singular (the six
    coefficients depend on four identified physical parameters).
    """
    c0 = coeff_array(nominal)[0]
    cov = np.asarray(cov, dtype=float)
    if cov.shape != (6, 6) or not np.all(np.isfinite(cov)):
        raise ValueError(f"ECM coefficient covariance must be a finite 6x6 matrix, got shape {cov.shape}")
    rel = cov / np.outer(c0, c0)
    return c0 * (1.0 + sample_mvn(np.zeros(6), rel, n, rng))


def pinchoff_volume_cross_covariance(model) -> np.ndarray | None:
    """Covariance between the pinch-off and volume-adjuster coefficients (scaled bases), or None.

    With ``adjuster_reference="ecm"`` the volume adjuster is trained on the measured in-flight
    volume minus the ECM volume at the *measured* pinch-off instant, so pinch-off jitter enters
    both polynomials with opposite signs and cancels in the in-flight volume. Sampling the two
    independently would count it twice; `identify.hybrid_fit.fit_hybrid` stores their
    cross-covariance in ``model.intervals["pinchoff_volume_cross_covariance"]``.
    """
    iv = getattr(model, "intervals", None)
    if not isinstance(iv, dict) or iv.get("pinchoff_volume_cross_covariance") is None:
        return None
    c = np.asarray(iv["pinchoff_volume_cross_covariance"], dtype=float)
    if c.shape != (len(model.pinchoff.terms), len(model.volume_adjuster.terms)):
        return None
    return c


def sample_pinchoff_volume(pinchoff, volume_adjuster, cross, n: int, u1: float, u2: float, rng):
    """Pinch-off instants and volume adjustments at (u1, u2) for ``n`` joint coefficient draws.

    The pinch-off coefficients are drawn exactly as :meth:`PolynomialFit.sample` does; the
    volume-adjuster coefficients from their normal distribution conditional on those
    (regression on the pinch-off draw plus an independent residual draw). With a zero
    ``cross`` the draws equal the independent ones, random number for random number.
    """
    mp, Cp = pinchoff.scaled_coefficients, pinchoff.scaled_covariance
    mv, Cv = volume_adjuster.scaled_coefficients, volume_adjuster.scaled_covariance
    qp = sample_mvn(mp, Cp, n, rng)
    K = np.linalg.lstsq(0.5 * (Cp + Cp.T), cross, rcond=1e-12)[0].T  # Cvp Cp^+ , shape (pv, pp)
    cond = Cv - K @ cross
    qv = sample_mvn(np.zeros(mv.size), cond, n, rng) + mv
    if np.any(K != 0):
        qv = qv + (qp - mp) @ K.T
    x1p, x2p = pinchoff.normalised(u1, u2)
    x1v, x2v = volume_adjuster.normalised(u1, u2)
    return qp @ design_matrix(x1p, x2p, pinchoff.terms), qv @ design_matrix(x1v, x2v, volume_adjuster.terms)


# ---------------------------------------------------------------------------------------
# Monte Carlo of the hybrid model
# ---------------------------------------------------------------------------------------

#: Output quantities of a prediction, in the order printed.
OUTPUTS = ("pinchoff_us", "grown_volume_at_pinchoff_nl", "inflight_volume_nl", "jetting_velocity_m_s")


def summarise(x: np.ndarray, band=(2.5, 97.5)) -> dict:
    """{"mean", "std", "parameters_only_low", "parameters_only_high"} of Monte Carlo samples.

    The low/high pair are the percentiles ``band`` of the samples: an interval of the
    *parameter* uncertainty only (no model discrepancy, measurement error or drop scatter), hence
    the name; the interval of the mean drop and of one drop are in
    `identify.hybrid.HybridModel.interval_prediction` (``mean_drop_*``, ``one_drop_*``).
    """
    x = np.asarray(x, dtype=float)
    if x.size == 1:
        v = float(x[0])
        return {"mean": v, "std": 0.0, "parameters_only_low": v, "parameters_only_high": v}
    lo, hi = np.percentile(x, band)
    return {"mean": float(np.mean(x)), "std": float(np.std(x, ddof=1)), "parameters_only_low": float(lo),
            "parameters_only_high": float(hi)}


@dataclass
class MonteCarloResult:
    """Samples of the hybrid-model outputs at one (u1, u2) and the per-time band.

    ``samples``: dict of (N,) arrays for :data:`OUTPUTS`; ``nominal``: dict of floats from
    the nominal model; ``band``: DataFrame with delay_us, volume_{nominal,mean,low,high}_nl,
    flow_velocity_{nominal,mean,low,high}_m_s (None if not requested).
    """

    u1_um_per_ms: float
    u2_um: float
    samples: dict
    nominal: dict
    band: pd.DataFrame | None = None
    percentiles: tuple = (2.5, 97.5)
    extra: dict = field(default_factory=dict)

    def summary(self) -> dict:
        """One {"mean", "std", "parameters_only_low", "parameters_only_high"} dict per output (:func:`summarise`)."""
        return {k: summarise(self.samples[k], self.percentiles) for k in OUTPUTS}

    def to_dict(self) -> dict:
        return self.summary()

    def to_pandas(self) -> pd.DataFrame:
        import pandas as pd

        return pd.DataFrame(self.samples)


def run_monte_carlo(
    model, u1: float, u2: float, samples: int = 10_000, seed: int | None = 0, *,
    band: bool = False, band_samples: int = 2000, progress=None,
) -> MonteCarloResult:
    """Monte Carlo of Section 5.1 with parameters drawn from their covariances.

    Parameters
    ----------
    model : identify.hybrid.HybridModel
        Anything with ``ecm_coefficients`` (EcmCoefficients), ``ecm_coeff_cov`` (6x6),
        ``pinchoff``, ``volume_adjuster``, ``velocity_adjuster`` (PolynomialFit),
        ``dead_time_us``, ``sample_interval_us``, ``nozzle_inner_diameter_um``, ``waveform(u1, u2)``.
    samples : int
        Number of hybrid models drawn (1 = nominal only).
    band : bool
        Also compute the per-time band of grown volume and flow velocity (from the first
        ``band_samples`` draws, on the sampling grid up to the latest pinch-off).
    """
    samples = check_samples(samples)
    rng = np.random.default_rng(seed)
    w = model.waveform(u1, u2)
    dead = model.dead_time_us
    d_um = model.nozzle_inner_diameter_um
    c_nom = coeff_array(model.ecm_coefficients)
    nominal = model.nominal(u1, u2)  # raw: the checks are the caller's (HybridModel.predict)
    if samples == 1:
        s = {k: np.array([nominal[k]]) for k in OUTPUTS}
        coeffs = c_nom
    else:
        cov = model.ecm_coeff_cov
        coeffs = sample_ecm_coefficients(c_nom, cov, samples, rng) if cov is not None else np.repeat(c_nom, samples, 0)
        cross = pinchoff_volume_cross_covariance(model)
        if cross is None:
            t_p = model.pinchoff.sample(samples, u1, u2, rng)
            adj_v = model.volume_adjuster.sample(samples, u1, u2, rng)
        else:  # pinch-off and volume adjuster coefficients drawn jointly (see the function)
            t_p, adj_v = sample_pinchoff_volume(model.pinchoff, model.volume_adjuster, cross, samples, u1, u2, rng)
        adj_q = model.velocity_adjuster.sample(samples, u1, u2, rng)
        modal = modal_form(coeffs)
        vol_p, _ = ecm_response_at(modal, w, t_p - dead)
        _, q_max = ecm_response_at(modal, w, np.full(samples, w.max_stroke_us))
        s = {
            "pinchoff_us": t_p,
            "grown_volume_at_pinchoff_nl": vol_p,
            "inflight_volume_nl": vol_p + adj_v,
            "jetting_velocity_m_s": flow_velocity_m_s(q_max, d_um) + adj_q,
        }
    band_df = None
    if band:
        h = model.sample_interval_us
        t_end = max(float(np.max(s["pinchoff_us"])), nominal["pinchoff_us"]) + h
        t = np.arange(0.0, t_end + h, h)
        u = w.displacement_um(t - dead)
        nb = min(band_samples, coeffs.shape[0])
        vol, flow = simulate_ensemble(coeffs[:nb], t, u)
        vnom, fnom = simulate_ensemble(c_nom, t, u)
        vel = flow_velocity_m_s(flow, d_um)
        lo, hi = (np.percentile(vol, [2.5, 97.5], axis=0)) if nb > 1 else (vol[0], vol[0])
        vlo, vhi = (np.percentile(vel, [2.5, 97.5], axis=0)) if nb > 1 else (vel[0], vel[0])
        import pandas as pd  # only here: predicting needs no pandas

        band_df = pd.DataFrame({
            "delay_us": t,
            "volume_nominal_nl": vnom[0], "volume_mean_nl": vol.mean(axis=0), "volume_low_nl": lo, "volume_high_nl": hi,
            "flow_velocity_nominal_m_s": flow_velocity_m_s(fnom[0], d_um), "flow_velocity_mean_m_s": vel.mean(axis=0),
            "flow_velocity_low_m_s": vlo, "flow_velocity_high_m_s": vhi,
        })
    return MonteCarloResult(u1_um_per_ms=float(u1), u2_um=float(u2), samples=s, nominal=nominal, band=band_df)
