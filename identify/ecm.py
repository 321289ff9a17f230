"""Third-order equivalent circuit model (ECM) of the nozzle (Wang & Chiu, Eqs. 2-6).

All physical parameters are SI: inertances L in kg/m^4, resistances R in kg/(m^4 s),
compliance C_N in m^4 s^2/kg, compliance ratio K_c in kg/(m^2 s^2) (negative: a positive
piston stroke pushes liquid out of the nozzle). The piston displacement enters in metres
and the volume leaves in m^3 in the transfer function of Eq. (6):

    Y_vol(s) = -(B1 s + B0) / (A3 s^3 + A2 s^2 + A1 s + A0) U(s)

Simulation helpers take the displacement in µm and time in µs and return the growing
volume in nl and the flow in nl/µs (1 nl/µs = 1e-6 m^3/s).

Eq. (5) as printed repeats ``C_N L_a R_N`` in A2; the second term is ``C_N L_a R_R``
(it follows from Eq. 3). With it the characteristic polynomial factors exactly as

    A(s) = L_a (s + R_a/L_a) (C_N L_t s^2 + C_N R_t s + 1),  L_t = L_N + L_R, R_t = R_N + R_R,

a slow piston pole and a meniscus/inertance resonance of natural frequency
1/sqrt(C_N L_t) and damping ratio R_t/2 sqrt(C_N/L_t).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

#: 1 nl in m^3.
NL = 1e-12
#: 1 µm in m.
UM = 1e-6


def pipe_resistance(viscosity_pa_s: float, length_m: float, radius_m: float) -> float:
    """Hydraulic resistance of a laminar pipe flow, Eq. (2): R = 8 µ l / (π r^4), kg/(m^4 s)."""
    return 8.0 * viscosity_pa_s * length_m / (np.pi * radius_m**4)


def pipe_inertance(density_kg_m3: float, length_m: float, radius_m: float) -> float:
    """Hydraulic inertance of a pipe, Eq. (2): L = ρ l / (π r^2), kg/m^4."""
    return density_kg_m3 * length_m / (np.pi * radius_m**2)


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

    @classmethod
    def from_ratios(cls, theta, A3: float = 1.0) -> "EcmCoefficients":
        """Build coefficients from the ratios θ of Eq. (10) and a scale A3."""
        a2, a1, a0, b1, b0 = np.asarray(theta, dtype=float) * A3
        return cls(A3=A3, A2=a2, A1=a1, A0=a0, B1=b1, B0=b0)

    def volume_tf(self) -> tuple[np.ndarray, np.ndarray]:
        """(num, den) of Y_vol/U in SI units, highest power first."""
        return np.array([-self.B1, -self.B0]), np.array([self.A3, self.A2, self.A1, self.A0])

    def static_gain_nl_per_um(self) -> float:
        """Final volume per unit of held displacement, Eq. (12): -B0/A0 (nl per µm)."""
        return -self.B0 / self.A0 * UM / NL

    def poles(self) -> np.ndarray:
        """Poles of Eq. (6) in rad/s."""
        return np.roots([self.A3, self.A2, self.A1, self.A0])

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


def _companion(coeffs: EcmCoefficients, time_unit_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Controllable canonical state space of Eq. (6) with time in ``time_unit_s`` seconds,
    displacement in µm and volume in nl (well conditioned for µs time units)."""
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
    A, B, C = _companion(coeffs, 1e-6)
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


def flow_velocity_m_s(flow_nl_per_us, nozzle_inner_diameter_um: float) -> np.ndarray:
    """Average flow velocity (m/s) in the nozzle: flow / (π d^2 / 4)."""
    area_m2 = np.pi * (nozzle_inner_diameter_um * UM) ** 2 / 4.0
    return np.asarray(flow_nl_per_us, dtype=float) * 1e-6 / area_m2
