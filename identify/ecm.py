"""Third-order equivalent circuit model (ECM) of the nozzle (Wang & Chiu, Eqs. 2-6).

All physical parameters are SI: inertances L in kg/m^4, resistances R in kg/(m^4 s),
compliance C_N in m^4 s^2/kg, compliance ratio K_c in kg/(m^2 s^2) (negative: a positive
piston stroke pushes liquid out of the nozzle). The piston displacement enters in metres
and the volume leaves in m^3 in the transfer function of Eq. (6):

    Y_vol(s) = -(B1 s + B0) / (A3 s^3 + A2 s^2 + A1 s + A0) U(s)

Simulation helpers take the displacement in µm and time in µs and return the growing
volume in nl and the flow in nl/µs (1 nl/µs = 1e-6 m^3/s): :func:`simulate` (time
stepping, first-order hold), :func:`simulate_sampled` (the same for many input sequences
sampled from rest) and :func:`pwl_response` (closed form for piecewise-linear inputs, e.g.
the waveform of Eq. (1) through :func:`waveform_knots`). The batched simulation of many
coefficient sets (Monte Carlo) is :func:`identify.montecarlo.simulate_ensemble`.

The hydraulic elements L_N, R_N, L_R, R_R of Eq. (2) are computed in
:mod:`identify.hydraulics`.

Eq. (5) as printed repeats ``C_N L_a R_N`` in A2; the second term is ``C_N L_a R_R``
(it follows from Eq. 3). With it the characteristic polynomial factors exactly as

    A(s) = L_a (s + R_a/L_a) (C_N L_t s^2 + C_N R_t s + 1),  L_t = L_N + L_R, R_t = R_N + R_R,

a slow piston pole and a meniscus/inertance resonance of natural frequency
1/sqrt(C_N L_t) and damping ratio R_t/2 sqrt(C_N/L_t).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from dvcore.waveform import DEAD_TIME_US, UM, Waveform, flow_velocity_m_s, nozzle_area_m2

__all__ = [  # the flow formulas live in dvcore.waveform (shared with the measurement layer)
    "COEFF_NAMES", "NL", "UM", "EcmCoefficients", "EcmParameters", "companion_form", "flow_velocity_m_s",
    "foh_step", "nozzle_area_m2", "pwl_response", "simulate", "simulate_sampled", "waveform_knots",
]

#: 1 nl in m^3.
NL = 1e-12
#: Order of the coefficients of Eq. (6) wherever they form a vector (covariances, files).
COEFF_NAMES = ("A3", "A2", "A1", "A0", "B1", "B0")


@dataclass(frozen=True)
class EcmCoefficients:
    """Coefficients of Eq. (4)/(6) in SI units (displacement in m, volume in m^3)."""

    A3: float
    A2: float
    A1: float
    A0: float
    B1: float
    B0: float

    def ratios(self) -> np.ndarray:
        """θ of Eq. (10): [A2/A3, A1/A3, A0/A3, B1/A3, B0/A3]."""
        return np.array([self.A2, self.A1, self.A0, self.B1, self.B0]) / self.A3

    def volume_tf(self) -> tuple[np.ndarray, np.ndarray]:
        """(num, den) of Y_vol/U in SI units, highest power first."""
        return np.array([-self.B1, -self.B0]), np.array([self.A3, self.A2, self.A1, self.A0])

    def static_gain_nl_per_um(self) -> float:
        """Final volume per unit of held displacement, Eq. (12): -B0/A0 (nl per µm)."""
        return -self.B0 / self.A0 * UM / NL

    def poles(self) -> np.ndarray:
        """Poles of Eq. (6) in rad/s."""
        return np.roots([self.A3, self.A2, self.A1, self.A0])

    def to_array(self) -> np.ndarray:
        """The coefficients as a vector in :data:`COEFF_NAMES` order (SI units), shape (6,)."""
        return np.array([getattr(self, k) for k in COEFF_NAMES])

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class EcmParameters:
    """Physical parameters of the ECM of Fig. 4 (SI units).

    La, Ra: mechanical inductance and loss of the piston; CN: meniscus compliance;
    Kc: compliance ratio (displacement to pressure); LN, RN and LR, RR: fluid inertance
    and resistance towards the nozzle end and the reservoir (Eq. 2).
    """

    La: float
    Ra: float
    CN: float
    Kc: float
    LN: float
    RN: float
    LR: float
    RR: float

    def coefficients(self) -> EcmCoefficients:
        """Eq. (5), with the misprinted second A2 term read as C_N L_a R_R."""
        p = self
        return EcmCoefficients(
            A3=p.CN * p.LN * p.La + p.CN * p.LR * p.La,
            A2=p.CN * p.La * p.RN + p.CN * p.La * p.RR + p.CN * p.LN * p.Ra + p.CN * p.LR * p.Ra,
            A1=p.CN * p.RR * p.Ra + p.CN * p.RN * p.Ra + p.La,
            A0=p.Ra,
            B1=p.Kc * p.CN * p.LR,
            B0=p.Kc * p.CN * p.RR,
        )

    def natural_frequency_hz(self) -> float:
        """Meniscus/inertance resonance 1/(2π sqrt(C_N (L_N + L_R)))."""
        return 1.0 / (2 * np.pi * np.sqrt(self.CN * (self.LN + self.LR)))

    def damping_ratio(self) -> float:
        """Damping ratio of the resonance, (R_N + R_R)/2 sqrt(C_N/(L_N + L_R))."""
        return 0.5 * (self.RN + self.RR) * np.sqrt(self.CN / (self.LN + self.LR))

    def to_dict(self) -> dict:
        return asdict(self)


def companion_form(coeffs: EcmCoefficients, time_unit_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Controllable canonical state space of Eq. (6), dx/dt = A x + B u, volume = C x.

    Parameters
    ----------
    coeffs : EcmCoefficients
        Coefficients of Eq. (6) in SI units.
    time_unit_s : float
        Time unit of the state space in seconds (1e-6: µs, well conditioned).

    Returns
    -------
    A : ndarray, shape (3, 3)
        State matrix (1/time unit).
    B : ndarray, shape (3,)
        Input vector (displacement in µm).
    C : ndarray, shape (3,)
        Output vector (volume in nl).
    """
    a = np.array([coeffs.A2, coeffs.A1, coeffs.A0]) / coeffs.A3
    b = np.array([coeffs.B1, coeffs.B0]) / coeffs.A3
    tu = time_unit_s
    # s = σ / tu: s^3 + a2 s^2 + a1 s + a0 -> σ^3 + a2 tu σ^2 + a1 tu^2 σ + a0 tu^3
    a_s = a * np.array([tu, tu**2, tu**3])
    b_s = -b * np.array([tu**2, tu**3]) * (UM / NL)
    A = np.array([[-a_s[0], -a_s[1], -a_s[2]], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    B = np.array([1.0, 0.0, 0.0])
    C = np.array([0.0, b_s[0], b_s[1]])
    return A, B, C


def _expm_small(M: np.ndarray) -> np.ndarray:
    """Matrix exponential of a small matrix: scaling and squaring with an 18-term Taylor
    series (error < 1e-16 relative for the scaled norm <= 0.5); agrees with
    scipy.linalg.expm to 1e-12 here and is much cheaper per call for 5x5 matrices."""
    norm = float(np.max(np.sum(np.abs(M), axis=0)))
    s = max(0, int(np.ceil(np.log2(norm))) + 1) if norm > 0 else 0
    X = M / 2.0**s
    n = M.shape[0]
    E = np.eye(n)
    for k in range(18, 0, -1):  # Horner: I + X/1 (I + X/2 (I + ...))
        E = np.eye(n) + (X @ E) / k
    for _ in range(s):
        E = E @ E
    return E


def foh_step(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact step of dx/dt = A x + B u over ``h`` for an input linear over the step,
    u(t) = u0 + s (t - t0): x1 = Phi x0 + G0 u0 + G1 s (first-order hold)."""
    n = A.shape[0]
    M = np.zeros((n + 2, n + 2))
    M[:n, :n] = A
    M[:n, n] = B
    M[n, n + 1] = 1.0
    E = _expm_small(M * h)
    return E[:n, :n], E[:n, n], E[:n, n + 1]


def simulate(coeffs: EcmCoefficients, t_us, u_um) -> tuple[np.ndarray, np.ndarray]:
    """Simulate Eq. (6) from rest for displacements sampled on a uniform time grid.

    The input is taken as piecewise linear between samples (first-order hold), which is
    exact for the trapezoidal waveform of Eq. (1) when its corners fall on the grid.

    Parameters
    ----------
    coeffs : EcmCoefficients
    t_us : array_like, shape (n,)
        Uniformly spaced times (µs).
    u_um : array_like, shape (n,) or (m, n)
        Piston displacement at ``t_us`` (µm), already delayed by any dead time; several
        inputs as the rows of a 2-D array are simulated together.

    Returns
    -------
    volume_nl, flow_nl_per_us : ndarray, same shape as ``u_um``
        Growing volume (nl) and its time derivative (nl/µs; 1 nl/µs = 1e-6 m^3/s).
    """
    t = np.asarray(t_us, dtype=float)
    u = np.asarray(u_um, dtype=float)
    if t.ndim != 1 or u.ndim not in (1, 2) or u.shape[-1] != t.size:
        raise ValueError("t_us must be 1-D and u_um of shape (len(t_us),) or (m, len(t_us))")
    if t.size < 2:
        return np.zeros_like(u), np.zeros_like(u)
    h = t[1] - t[0]
    if h <= 0 or not np.allclose(np.diff(t), h, rtol=1e-6, atol=1e-9):
        raise ValueError("t_us must be uniformly increasing")
    rows = np.atleast_2d(u)
    A, B, C = companion_form(coeffs, 1e-6)
    n = A.shape[0]
    Phi, G0, G1 = foh_step(A, B, h)
    PhiT = Phi.T
    slopes = np.diff(rows, axis=1) / h
    x = np.zeros((rows.shape[0], n))
    states = np.empty((t.size, rows.shape[0], n))
    states[0] = x
    for k in range(t.size - 1):
        x = x @ PhiT + np.outer(rows[:, k], G0) + np.outer(slopes[:, k], G1)
        states[k + 1] = x
    volume = (states @ C).T
    # dV/dt = C (A x + B u); C B = 0 because Eq. (6) has relative degree 2.
    flow = ((states @ A.T) @ C).T + rows * (B @ C)
    return volume.reshape(u.shape), flow.reshape(u.shape)


def simulate_sampled(coeffs: EcmCoefficients, interval_us: float, u_um) -> tuple[np.ndarray, np.ndarray]:
    """:func:`simulate` for several input sequences sampled every ``interval_us`` from rest.

    Parameters
    ----------
    coeffs : EcmCoefficients
        One ECM (SI units).
    interval_us : float
        Sampling interval (µs); sample k is at k * interval_us.
    u_um : array_like, shape (n,) or (m, n)
        Piston displacement (µm), already delayed by any dead time; one sequence per row.

    Returns
    -------
    volume_nl, flow_nl_per_us : ndarray, shape (m, n)
        Growing volume (nl) and flow (nl/µs) of each sequence.
    """
    h = float(interval_us)
    if not h > 0:
        raise ValueError(f"interval_us must be > 0, got {interval_us!r}")
    u = np.atleast_2d(np.asarray(u_um, dtype=float))
    return simulate(coeffs, np.arange(u.shape[1]) * h, u)


def pwl_response(ratios, knots_us, slope_jumps_um_per_us, t_us) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form volume and flow of Eq. (6) for a piecewise-linear displacement.

    The displacement is ``u(t) = sum_i c_i (t - t_i)_+`` (ramps starting at the knots
    ``t_i`` with slope changes ``c_i``); the response is the superposition of the analytic
    unit-ramp response ``r(τ) = G(0) τ + G'(0) + sum_j R_j exp(p_j τ)`` (partial fractions of
    ``G(s)/s^2``). Exact at any instant, no time step; vectorised over parameter sets.

    Parameters
    ----------
    ratios : array_like, shape (..., 5)
        θ of Eq. (10) in SI units (A2/A3, A1/A3, A0/A3, B1/A3, B0/A3).
    knots_us, slope_jumps_um_per_us : array_like, shape (m,) or (..., m)
        Knot instants (µs) and slope changes (µm/µs).
    t_us : array_like, shape (k,) or (..., k)
        Evaluation instants (µs).

    Returns
    -------
    volume_nl, flow_nl_per_us : ndarray, shape (..., k)

    Notes
    -----
    Requires distinct poles (raises ``ValueError`` when two poles nearly coincide).
    """
    th = np.asarray(ratios, dtype=float)
    tu = 1e-6
    a = th[..., :3] * np.array([tu, tu**2, tu**3])  # monic denominator in 1/µs units
    b = th[..., 3:] * np.array([tu**2, tu**3]) * (UM / NL)  # numerator -(b1 σ + b0)
    comp = np.zeros(th.shape[:-1] + (3, 3))
    comp[..., 0, :] = -a
    comp[..., 1, 0] = 1.0
    comp[..., 2, 1] = 1.0
    p = np.linalg.eigvals(comp)  # (..., 3) poles in 1/µs
    scale = np.max(np.abs(p), axis=-1)
    gaps = np.abs(p[..., [0, 0, 1]] - p[..., [1, 2, 2]])
    if np.any(gaps < 1e-7 * scale[..., None]):
        raise ValueError("pwl_response: repeated poles; use simulate instead")
    num = -(b[..., 0, None] * p + b[..., 1, None])  # N(p_j)
    others = np.stack(
        [(p[..., 0] - p[..., 1]) * (p[..., 0] - p[..., 2]),
         (p[..., 1] - p[..., 0]) * (p[..., 1] - p[..., 2]),
         (p[..., 2] - p[..., 0]) * (p[..., 2] - p[..., 1])],
        axis=-1,
    )
    R = num / (p**2 * others)  # residues of G/s^2 at the poles
    a1, a0 = a[..., 1], a[..., 2]
    n0, n1 = -b[..., 1], -b[..., 0]  # N(0), N'(0)
    G0 = n0 / a0
    G1 = (n1 * a0 - n0 * a1) / a0**2
    knots = np.asarray(knots_us, dtype=float)
    jumps = np.asarray(slope_jumps_um_per_us, dtype=float)
    t = np.asarray(t_us, dtype=float)
    tau = t[..., None, :] - knots[..., :, None]  # (..., m, k)
    on = tau > 0
    tau_c = np.where(on, tau, 0.0)
    e = np.exp(p[..., :, None, None] * tau_c[..., None, :, :])  # (..., 3, m, k)
    R_ = R[..., :, None, None]
    p_ = p[..., :, None, None]
    ramp = G0[..., None, None] * tau_c + G1[..., None, None] + np.sum(R_ * e, axis=-3).real
    dramp = G0[..., None, None] + np.sum(R_ * p_ * e, axis=-3).real
    ramp = np.where(on, ramp, 0.0)
    dramp = np.where(on, dramp, 0.0)
    vol = np.sum(jumps[..., :, None] * ramp, axis=-2)
    flow = np.sum(jumps[..., :, None] * dramp, axis=-2)
    return vol, flow


def waveform_knots(waveform: Waveform, dead_time_us: float = DEAD_TIME_US) -> tuple[np.ndarray, np.ndarray]:
    """Knots and slope changes of the waveform of Eq. (1), for :func:`pwl_response`.

    Parameters
    ----------
    waveform : identify.waveform.Waveform
        The trapezoidal waveform (u1 µm/ms, u2 µm, u3 µm/ms, hold µs).
    dead_time_us : float
        Delay from the trigger to the start of the piston motion (µs).

    Returns
    -------
    knots_us : ndarray, shape (4,)
        Corner instants from the trigger (µs).
    slope_jumps_um_per_us : ndarray, shape (4,)
        Slope change of the displacement at each corner (µm/µs).
    """
    w = waveform
    u1, u3 = w.u1_um_per_ms * 1e-3, w.u3_um_per_ms * 1e-3
    knots = dead_time_us + np.array([0.0, w.rise_us, w.retract_start_us, w.end_us])
    return knots, np.array([u1, -u1, -u3, u3])
