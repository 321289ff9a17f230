"""Identification of the ECM physical parameters La, Ra, CN, Kc (Wang & Chiu, Section 4.3).

The hydraulic elements LN, RN (nozzle pipe) and LR, RR (reservoir-side channel) are known
from Eq. (2) with the nozzle geometry and the ink (:mod:`identify.hydraulics`); the
remaining four parameters are fitted to measured growing-volume sequences (:class:`EcmData`).

Two estimators, both in :func:`fit_ecm`:

``method="oe"`` (default)
    Output-error / grey-box fit of the continuous-time model: the exact first-order-hold
    simulation of Eq. (6) (:func:`identify.ecm.simulate_sampled`, all sequences at once)
    is fitted to the measured volume of all sequences jointly by
    nonlinear least squares on log-parameters. ``Kc`` enters the volume linearly and is
    eliminated in closed form (variable projection), so the search runs over
    ``(log Ra, log CN)`` after a coarse grid search. Covariance: ``s^2 (J^T J)^-1`` with
    ``J`` the Jacobian of the residuals with respect to ``q = (log Ra, log CN, log|Kc|)``,
    transformed to SI units by the delta method; 95 % intervals are ``exp(q +- 1.96 sd)``.
    Consistent (no discretisation bias), unbiased for white output noise.
``method="delta"`` (paper-faithful)
    Per sequence, least squares on the delta-operator (forward-Euler) form, Eqs. (10)-(11),
    with ``Kc`` eliminated through the final-value constraint, Eqs. (12)-(13), using the
    grown volume at pinch-off ``y_ss`` and the piston displacement there ``K_ss``. Then the
    mean and the 95 % confidence interval of the mean over the sequences (Table 3 style:
    ``mean +- t_{0.975,n-1} s / sqrt(n)``); ``param_cov`` is the covariance of the mean.
    The Euler approximation of the derivatives biases the estimates at ``h = 10 us`` even
    without noise, and the third difference of noisy samples makes them very noise
    sensitive (see the noise study below).

Identifiability
---------------
With LN, RN, LR, RR known the five ratios of Eq. (10) are

    A2/A3 = Rt/Lt + Ra/La,    A1/A3 = (Rt/Lt)(Ra/La) + 1/(CN Lt),   A0/A3 = (Ra/La)/(CN Lt),
    B1/A3 = (Kc/La) LR/Lt,    B0/A3 = (Kc/La) RR/Lt          (Lt = LN+LR, Rt = RN+RR),

i.e. functions of only three combinations: the piston pole ``Ra/La``, the compliance ``CN``
and the gain ``Kc/La``. The volume response is therefore invariant under the joint scaling
``(La, Ra, Kc) -> c (La, Ra, Kc)``: **La is not identifiable from volume data** (the
4-parameter Jacobian has rank 3, null direction (1, 1, 0, 1) in (log La, log Ra, log CN,
log|Kc|)). The paper's objective J (Eq. 13 substituted into Eq. 11) has the same
invariance, so its La is set by the starting point, not by the data. Both estimators here
fix La (argument ``la``, default the paper's Table 3 value 4.01e-13 kg/m^4) and estimate
Ra, CN, Kc given La; the ratios, the poles, the volume and flow predictions do not depend
on that choice. ``param_cov`` has a zero La row/column. The remaining three combinations
are well identified from volume sequences truncated at pinch-off (~80 samples after the
dead time, 91 sequences of the campaign grid): see ``EcmFit.identifiability``.

Accuracy (``noise_study`` of ``tests/ecm_study.py``, run by ``tests/identify/test_ecm_fit.py``;
default physics, 91 waveforms, 10 µs, seed 0, white noise of sd = 1 % / 2 % of each
sequence's peak volume): ``oe`` max ratio error 0.09 % (0 %, the
first-order hold of the 10 µs input samples cuts the waveform corners), 0.39 % (1 %),
0.85 % (2 %), 95 % intervals cover the truth. The standard error of A2/A3 and A0/A3 at 1 %
noise is ~1.1 % / 0.95 % (log Ra and log CN are 0.998 correlated), so "within 1 %" holds
for most but not all noise realisations (7 of 8 seeds). ``delta`` (paper): 49 % (0 %:
Euler bias ~5 %, the rest from Eq. 13, the pinch-off volume not being the steady state of
Eq. 12), > 1000 % with 1-2 % noise (equation-error bias: the third difference of noisy
samples).

Any drive (issue 31): ``u_um`` is whatever drives Eq. (6), the paper's piston stroke or a waveform
template's drive (:mod:`identify.waveform`; a voltage is read as µm of equivalent stroke, Kc then per
volt). A drive whose corners fall between the samples (pulse edges of 2 µs, samples every 10 µs)
is not linear between them: :meth:`EcmData.from_drive` also stores it on a finer grid
(``u_fine_um``, ``substeps``) and the output-error fits simulate on that grid. Noise-free
three-pulse campaign (``tests/identify/test_waveform_template.py``): exact on the 1 µs grid; held linear
between the 10 µs samples, Ra +43 %, CN +22 %, Kc +11 %.

Units: SI for the physical parameters and coefficients; µs, µm and nl for the data.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import optimize, stats

from identify.ecm import NL, UM, EcmCoefficients, EcmParameters, simulate_sampled
from identify.hydraulics import Hydraulics
from identify.waveform import DEAD_TIME_US, Waveform

#: La used when the caller does not fix it (kg/m^4): Table 3 of the paper. La is not
#: identifiable from volume data (see the module docstring).
LA_DEFAULT = 4.01e-13
#: Parameter order of ``EcmFit.param_cov`` and of the identifiability report.
PARAM_NAMES = ("La", "Ra", "CN", "Kc")
#: Ratio order of ``EcmFit.ratio_cov`` (θ of Eq. 10). The coefficient order of
#: ``EcmFit.coeff_cov`` is :data:`identify.ecm.COEFF_NAMES`.
RATIO_NAMES = ("A2/A3", "A1/A3", "A0/A3", "B1/A3", "B0/A3")

_Z95 = stats.norm.ppf(0.975)


def _params_from(la: float, ra: float, cn: float, kc: float, hyd: Hydraulics) -> EcmParameters:
    return EcmParameters(La=la, Ra=ra, CN=cn, Kc=kc, LN=hyd.LN, RN=hyd.RN, LR=hyd.LR, RR=hyd.RR)


# --------------------------------------------------------------------------- data


@dataclass(frozen=True)
class EcmData:
    """One measured growing-volume sequence, truncated at pinch-off.

    Parameters
    ----------
    t_us : array_like
        Uniformly spaced strobe delays from the firing trigger (µs), e.g. 0, 10, ...
    u_um : array_like
        Piston displacement at ``t_us`` already delayed by the dead time, u(t - 220 µs) (µm).
        The first sample must have the piston at rest (0).
    volume_nl : array_like
        Grown volume (nl) at ``t_us``, up to the last attached frame before pinch-off.
    pinchoff_volume_nl : float
        Grown volume at pinch-off, ``y_ss`` of Eq. (13) (nl).
    pinchoff_displacement_um : float
        Piston displacement at pinch-off, ``K_ss`` of Eq. (13) (µm).
    u1_um_per_ms, u2_um : float, optional
        Waveform labels (reported in ``EcmFit.per_sequence``).
    u_fine_um : array_like, optional
        The drive on a grid ``substeps`` times finer than ``t_us`` (``(n - 1) substeps + 1``
        samples from ``t_us[0]``): the output-error fits simulate on it, so that a drive whose
        corners fall between the samples (a waveform template's pulses) is followed exactly
        (:meth:`from_drive`). None: the drive is ``u_um``, linear between samples.
    substeps : int
        Sub-steps per sample of ``u_fine_um`` (1 without it).
    """

    t_us: np.ndarray
    u_um: np.ndarray
    volume_nl: np.ndarray
    pinchoff_volume_nl: float
    pinchoff_displacement_um: float
    u1_um_per_ms: float = float("nan")
    u2_um: float = float("nan")
    u_fine_um: np.ndarray | None = None
    substeps: int = 1

    def __post_init__(self) -> None:
        arrays = {}
        for name in ("t_us", "u_um", "volume_nl"):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.ndim != 1:
                raise ValueError(f"EcmData.{name} must be 1-D, got shape {a.shape}")
            if not np.all(np.isfinite(a)):
                raise ValueError(f"EcmData.{name} contains NaN or inf")
            arrays[name] = a
            object.__setattr__(self, name, a)
        n = arrays["t_us"].size
        if arrays["u_um"].size != n or arrays["volume_nl"].size != n:
            raise ValueError("EcmData: t_us, u_um and volume_nl must have equal lengths")
        if n < 8:
            raise ValueError(f"EcmData: need at least 8 samples up to pinch-off, got {n}")
        dt = np.diff(arrays["t_us"])
        if dt[0] <= 0 or not np.allclose(dt, dt[0], rtol=1e-6, atol=1e-9):
            raise ValueError("EcmData.t_us must be uniformly increasing")
        if abs(arrays["u_um"][0]) > 1e-9:
            raise ValueError("EcmData.u_um[0] must be 0: a sequence starts with the piston at rest")
        for name in ("pinchoff_volume_nl", "pinchoff_displacement_um"):
            v = float(getattr(self, name))
            if not np.isfinite(v):
                raise ValueError(f"EcmData.{name} must be finite")
            object.__setattr__(self, name, v)
        if self.pinchoff_displacement_um == 0:
            raise ValueError("EcmData.pinchoff_displacement_um must be non-zero (K_ss of Eq. 13)")
        if int(self.substeps) != self.substeps or self.substeps < 1:
            raise ValueError(f"EcmData.substeps must be an integer >= 1, got {self.substeps!r}")
        object.__setattr__(self, "substeps", int(self.substeps))
        if self.u_fine_um is not None:
            fine = np.asarray(self.u_fine_um, dtype=float)
            if fine.shape != ((n - 1) * self.substeps + 1,) or not np.all(np.isfinite(fine)):
                raise ValueError(f"EcmData.u_fine_um must hold {(n - 1) * self.substeps + 1} finite samples "
                                 f"((n - 1) substeps + 1), got shape {fine.shape}")
            object.__setattr__(self, "u_fine_um", fine)
        elif self.substeps != 1:
            raise ValueError("EcmData.substeps > 1 needs u_fine_um")

    @property
    def interval_us(self) -> float:
        """Sampling interval (µs)."""
        return float(self.t_us[1] - self.t_us[0])

    @classmethod
    def from_drive(cls, drive, t_us, volume_nl, pinchoff_us: float | None = None, substeps: int = 10) -> "EcmData":
        """A sequence driven by a waveform template (:class:`identify.waveform.Drive`, dead time
        included) with volumes sampled at ``t_us`` (from the trigger): samples after
        ``pinchoff_us`` dropped, the drive also given ``substeps`` times finer (``u_fine_um``).

        ``u_um`` is the drive in the template's unit (µm for the trapezoid; V for a voltage drive,
        which Eq. 6 reads as µm of equivalent stroke). ``K_ss`` of Eq. (13) (the ``delta`` method
        only) is the drive at the last sample, or, where the drive is back at rest there (pulses
        that end before pinch-off: Eq. 13 has no steady state to use), its largest magnitude."""
        t = np.asarray(t_us, dtype=float)
        y = np.asarray(volume_nl, dtype=float)
        if t.shape != y.shape:
            raise ValueError("from_drive: t_us and volume_nl must have equal shapes")
        if pinchoff_us is not None:
            keep = t <= pinchoff_us + 1e-9
            t, y = t[keep], y[keep]
        u = drive.at(t)
        fine_t = t[0] + np.arange((t.size - 1) * substeps + 1) * ((t[-1] - t[0]) / max(t.size - 1, 1) / substeps)
        return cls(t_us=t, u_um=u, volume_nl=y, pinchoff_volume_nl=float(y[-1]),
                   pinchoff_displacement_um=float(u[-1]) if u[-1] != 0 else float(np.max(np.abs(u)) or 1.0),
                   u_fine_um=drive.at(fine_t), substeps=substeps)

    @classmethod
    def from_waveform(
        cls,
        waveform: Waveform,
        t_us,
        volume_nl,
        pinchoff_us: float | None = None,
        dead_time_us: float = DEAD_TIME_US,
    ) -> "EcmData":
        """Build a sequence from a waveform and volumes sampled at ``t_us`` (from the trigger).

        Samples after ``pinchoff_us`` are dropped; ``y_ss``/``K_ss`` are the volume and the
        displacement of the last sample at or before pinch-off.
        """
        t = np.asarray(t_us, dtype=float)
        y = np.asarray(volume_nl, dtype=float)
        if t.shape != y.shape:
            raise ValueError("from_waveform: t_us and volume_nl must have equal shapes")
        if pinchoff_us is not None:
            keep = t <= pinchoff_us + 1e-9
            t, y = t[keep], y[keep]
        u = waveform.displacement_um(t - dead_time_us)
        return cls(
            t_us=t,
            u_um=u,
            volume_nl=y,
            pinchoff_volume_nl=float(y[-1]),
            pinchoff_displacement_um=float(u[-1]),
            u1_um_per_ms=waveform.u1_um_per_ms,
            u2_um=waveform.u2_um,
        )


# --------------------------------------------------------------------------- result


@dataclass
class EcmFit:
    """Result of :func:`fit_ecm`.

    Attributes
    ----------
    method : str
        ``"oe"`` or ``"delta"``.
    parameters : EcmParameters or None
        Estimate (oe) or mean over sequences (delta), SI units; ``La`` is the fixed value.
        None at ``level == "coefficients"`` (no hydraulics: not identifiable).
    coefficients : EcmCoefficients
        Eq. (5) from ``parameters`` (delta: mean of the per-sequence coefficients).
    param_ci95 : dict
        ``{"La"|"Ra"|"CN"|"Kc": (low, high)}`` 95 % interval in SI units (La: fixed).
    param_cov : ndarray (4, 4)
        Covariance of (La, Ra, CN, Kc) in SI units (linearised); La row/column zero.
    coeff_cov : ndarray (6, 6)
        Covariance of (A3, A2, A1, A0, B1, B0) in SI units, delta method, given La.
    ratio_cov : ndarray (5, 5)
        Covariance of θ = (A2/A3, A1/A3, A0/A3, B1/A3, B0/A3), SI; independent of La.
    rmse_nl : float
        Simulation (output-error) RMSE of ``coefficients`` over all sequences (nl).
    n_sequences, n_samples : int
    per_sequence : DataFrame or None
        Method ``delta``: one row per sequence, columns ``u1_um_per_ms, u2_um, La, Ra, CN,
        Kc, A2/A3 .. B0/A3, rmse_1step_nl, rmse_sim_nl, success``.
    identifiability : dict
        Method ``oe``: ``singular_values`` of the column-normalised 4-parameter Jacobian in
        log space (La included), its numerical ``rank`` (3), the ``null_direction`` in
        (log La, log Ra, log CN, log|Kc|) (-> (1, 1, 0, 1)) and the 3x3 ``correlation`` of
        (log Ra, log CN, log|Kc|) given La.
    """

    method: str
    parameters: EcmParameters
    coefficients: EcmCoefficients
    param_ci95: dict
    param_cov: np.ndarray
    coeff_cov: np.ndarray
    ratio_cov: np.ndarray
    rmse_nl: float
    n_sequences: int
    n_samples: int
    per_sequence: pd.DataFrame | None = None
    identifiability: dict = field(default_factory=dict)
    #: ``"physical"`` (Ra, CN, Kc given the hydraulics of Eq. 2) or ``"coefficients"`` (A3..B0
    #: up to scale, A3 = 1, fitted directly: see :func:`fit_ecm_coefficients`).
    level: str = "physical"

    def ratios(self) -> np.ndarray:
        """θ of Eq. (10)."""
        return self.coefficients.ratios()

    def to_dict(self) -> dict:
        """JSON-serialisable dictionary (inverse: :meth:`from_dict`)."""

        def conv(v):
            if isinstance(v, np.ndarray):
                return v.tolist()
            if isinstance(v, dict):
                return {k: conv(x) for k, x in v.items()}
            if isinstance(v, (tuple, list)):
                return [conv(x) for x in v]
            if isinstance(v, (np.floating, np.integer)):
                return v.item()
            return v

        return {
            "schema": "identify.ecm_fit/1",
            "method": self.method,
            "level": self.level,
            "parameters": None if self.parameters is None else self.parameters.to_dict(),
            "coefficients": self.coefficients.to_dict(),
            "param_ci95": {k: [float(a), float(b)] for k, (a, b) in self.param_ci95.items()},
            "param_cov": conv(self.param_cov),
            "coeff_cov": conv(self.coeff_cov),
            "ratio_cov": conv(self.ratio_cov),
            "rmse_nl": float(self.rmse_nl),
            "n_sequences": int(self.n_sequences),
            "n_samples": int(self.n_samples),
            "per_sequence": None
            if self.per_sequence is None
            else {"columns": list(self.per_sequence.columns), "data": conv(self.per_sequence.to_numpy(dtype=object))},
            "identifiability": conv(self.identifiability),
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> "EcmFit":
        """Rebuild from :meth:`to_dict` output."""
        per = d.get("per_sequence")
        df = None
        if per is not None:
            df = pd.DataFrame(per["data"], columns=per["columns"])
            for c in df.columns:
                if c == "success":
                    df[c] = df[c].astype(bool)
                else:
                    df[c] = df[c].astype(float)
        ident = dict(d.get("identifiability", {}))
        for k, v in ident.items():
            if isinstance(v, list) and not any(isinstance(x, str) for x in np.ravel(np.asarray(v, dtype=object))):
                ident[k] = np.asarray(v, dtype=float)
        return cls(
            method=d["method"],
            parameters=None if d.get("parameters") is None else EcmParameters(**d["parameters"]),
            coefficients=EcmCoefficients(**d["coefficients"]),
            param_ci95={k: (float(a), float(b)) for k, (a, b) in d["param_ci95"].items()},
            param_cov=np.asarray(d["param_cov"], dtype=float),
            coeff_cov=np.asarray(d["coeff_cov"], dtype=float),
            ratio_cov=np.asarray(d["ratio_cov"], dtype=float),
            rmse_nl=float(d["rmse_nl"]),
            n_sequences=int(d["n_sequences"]),
            n_samples=int(d["n_samples"]),
            per_sequence=df,
            identifiability=ident,
            level=d.get("level", "physical"),
        )


# --------------------------------------------------------------------------- helpers


def _stack(sequences: Sequence[EcmData]) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Common interval, padded inputs (m, n), volumes (m, n) and the validity mask."""
    if len(sequences) == 0:
        raise ValueError("fit_ecm: no sequences given")
    for i, s in enumerate(sequences):
        if not isinstance(s, EcmData):
            raise TypeError(f"fit_ecm: sequences[{i}] is {type(s).__name__}, expected EcmData")
    h = sequences[0].interval_us
    for i, s in enumerate(sequences):
        if not np.isclose(s.interval_us, h, rtol=1e-6):
            raise ValueError(f"fit_ecm: sequences[{i}] has interval {s.interval_us} µs, expected {h} µs like sequences[0]")
    n = max(s.t_us.size for s in sequences)
    m = len(sequences)
    U = np.zeros((m, n))
    Y = np.zeros((m, n))
    mask = np.zeros((m, n), dtype=bool)
    for i, s in enumerate(sequences):
        k = s.t_us.size
        U[i, :k] = s.u_um
        U[i, k:] = s.u_um[-1]
        Y[i, :k] = s.volume_nl
        mask[i, :k] = True
    return h, U, Y, mask


def _simulator(sequences: Sequence[EcmData], h: float, U: np.ndarray):
    """``sim(coeffs) -> volume (m, n)`` of the stacked sequences: :func:`simulate_sampled` on
    ``U``, or, where the sequences carry a finer drive (``u_fine_um``), on that grid, read back
    every ``substeps`` samples."""
    subs = {s.substeps for s in sequences}
    if subs == {1}:
        return lambda c: simulate_sampled(c, h, U)[0]
    if len(subs) != 1 or any(s.u_fine_um is None for s in sequences):
        raise ValueError("fit_ecm: the sequences must all carry a fine drive with the same substeps, or none")
    sub = subs.pop()
    n = (U.shape[1] - 1) * sub + 1
    F = np.empty((len(sequences), n))
    for i, s in enumerate(sequences):
        F[i, :s.u_fine_um.size] = s.u_fine_um
        F[i, s.u_fine_um.size:] = s.u_fine_um[-1]
    return lambda c: simulate_sampled(c, h / sub, F)[0][:, ::sub]


def _delta_cov(fun, q, cov_q, rel_step: float = 1e-6) -> np.ndarray:
    """Delta-method covariance of fun(q) for a covariance of q."""
    q = np.asarray(q, dtype=float)
    f0 = np.asarray(fun(q))
    Jf = np.empty((f0.size, q.size))
    for j in range(q.size):
        dq = rel_step * max(1.0, abs(q[j]))
        e = np.zeros_like(q)
        e[j] = dq
        Jf[:, j] = (np.asarray(fun(q + e)) - np.asarray(fun(q - e))) / (2 * dq)
    return Jf @ cov_q @ Jf.T


def _grid_start(objective, hyd: Hydraulics, la: float, ra_over_la_grid, f_res_hz_grid) -> tuple[float, float]:
    """Best (Ra, CN) of a coarse grid of piston poles Ra/La (rad/s) and resonances (Hz)."""
    lt = hyd.LN + hyd.LR
    best = (np.inf, None)
    for pole in ra_over_la_grid:
        for f in f_res_hz_grid:
            cn = 1.0 / ((2 * np.pi * f) ** 2 * lt)
            val = objective(la * pole, cn)
            if np.isfinite(val) and val < best[0]:
                best = (val, (la * pole, cn))
    if best[1] is None:
        raise RuntimeError("fit_ecm: grid search found no finite objective value")
    return best[1]


_POLE_GRID = np.geomspace(30.0, 3e5, 11)  # Ra/La (rad/s)
_FRES_GRID = np.geomspace(100.0, 2e4, 11)  # meniscus resonance (Hz)


# --------------------------------------------------------------------------- OE


def _fit_oe(sequences, hyd: Hydraulics, la: float, initial: EcmParameters | None) -> EcmFit:
    h, U, Y, mask = _stack(sequences)
    y = Y[mask]
    sim = _simulator(sequences, h, U)

    def shape_response(ra: float, cn: float) -> np.ndarray:
        """Volume for Kc = -1 (the volume is linear in Kc)."""
        c = _params_from(la, ra, cn, -1.0, hyd).coefficients()
        return sim(c)[mask]

    def kc_star(v1: np.ndarray) -> float:
        den = float(v1 @ v1)
        return -float(v1 @ y) / den if den > 0 else -1.0

    def vp_residual(q2) -> np.ndarray:
        ra, cn = np.exp(q2)
        v1 = shape_response(ra, cn)
        return -kc_star(v1) * v1 - y

    def vp_objective(ra, cn) -> float:
        r = vp_residual(np.log([ra, cn]))
        return float(r @ r)

    if initial is None:
        ra0, cn0 = _grid_start(vp_objective, hyd, la, _POLE_GRID, _FRES_GRID)
    else:
        ra0, cn0 = initial.Ra * la / initial.La, initial.CN
    sol = optimize.least_squares(vp_residual, np.log([ra0, cn0]), x_scale=1.0, xtol=1e-12, ftol=1e-12, gtol=1e-12)
    ra, cn = np.exp(sol.x)
    v1 = shape_response(ra, cn)
    kc = kc_star(v1)
    params = _params_from(la, ra, cn, kc, hyd)
    coeffs = params.coefficients()
    resid = -kc * v1 - y
    n_obs, n_par = y.size, 3
    sigma2 = float(resid @ resid) / max(n_obs - n_par, 1)

    # Jacobian of the simulated volume w.r.t. q = (log Ra, log CN, log|Kc|), and the
    # log La direction for the identifiability report.
    def sim_q(qf) -> np.ndarray:
        la_, ra_, cn_, kca = np.exp(qf)
        c = _params_from(la_, ra_, cn_, np.sign(kc) * kca, hyd).coefficients()
        return sim(c)[mask]

    q_full = np.log([la, ra, cn, abs(kc)])
    J = np.empty((n_obs, 4))
    for j in range(4):
        e = np.zeros(4)
        e[j] = 1e-5
        J[:, j] = (sim_q(q_full + e) - sim_q(q_full - e)) / 2e-5
    Jq = J[:, 1:]
    cov_q = sigma2 * np.linalg.inv(Jq.T @ Jq)
    sd_q = np.sqrt(np.diag(cov_q))
    corr = cov_q / np.outer(sd_q, sd_q)
    Js = J / np.linalg.norm(J, axis=0)
    sv = np.linalg.svd(Js, compute_uv=False)
    rank = int(np.sum(sv > 1e-6 * sv[0]))
    _, _, vt = np.linalg.svd(J, full_matrices=False)  # log space, unscaled
    null = vt[-1] / vt[-1][np.argmax(np.abs(vt[-1]))]

    vals = np.array([ra, cn, kc])
    param_cov = np.zeros((4, 4))
    param_cov[1:, 1:] = cov_q * np.outer(vals, vals)  # d(value)/d(log|value|) = value
    ci = {"La": (la, la)}
    for name, qv, sd, v in zip(("Ra", "CN", "Kc"), np.log(np.abs(vals)), sd_q, vals):
        lo, hi = np.sign(v) * np.exp(qv - _Z95 * sd), np.sign(v) * np.exp(qv + _Z95 * sd)
        ci[name] = (float(min(lo, hi)), float(max(lo, hi)))

    def coeff_of(q3):
        return _params_from(la, np.exp(q3[0]), np.exp(q3[1]), np.sign(kc) * np.exp(q3[2]), hyd).coefficients().to_array()

    def ratio_of(q3):
        return _params_from(la, np.exp(q3[0]), np.exp(q3[1]), np.sign(kc) * np.exp(q3[2]), hyd).coefficients().ratios()

    q3 = np.log(np.abs(vals))
    return EcmFit(
        method="oe",
        parameters=params,
        coefficients=coeffs,
        param_ci95=ci,
        param_cov=param_cov,
        coeff_cov=_delta_cov(coeff_of, q3, cov_q),
        ratio_cov=_delta_cov(ratio_of, q3, cov_q),
        rmse_nl=float(np.sqrt(np.mean(resid**2))),
        n_sequences=len(sequences),
        n_samples=int(n_obs),
        per_sequence=None,
        identifiability={
            "parameters": ["log La", "log Ra", "log CN", "log|Kc|"],
            "singular_values": sv,
            "rank": rank,
            "null_direction": null,
            "correlation": corr,
            "optimizer_success": bool(sol.success),
        },
    )


# --------------------------------------------------------------------------- delta


def delta_theta(ratios, h_s: float) -> np.ndarray:
    """θ of Eq. (11) (delta-operator form) from the ratios of Eq. (10), data in nl and µm.

    ``y(k) = θ1 y(k-1) + θ2 y(k-2) + θ3 y(k-3) + θ4 u(k-2) + θ5 u(k-3)`` with ``h_s`` the
    step in seconds; the B terms carry the nl/µm unit factor 1e6.
    """
    a2, a1, a0, b1, b0 = np.moveaxis(np.asarray(ratios, dtype=float), -1, 0)
    g = UM / NL
    return np.stack(
        [
            3 - h_s * a2,
            -3 + 2 * h_s * a2 - h_s**2 * a1,
            1 - h_s * a2 + h_s**2 * a1 - h_s**3 * a0,
            -(h_s**2) * b1 * g,
            (h_s**2 * b1 - h_s**3 * b0) * g,
        ],
        axis=-1,
    )


def delta_regressors(s: EcmData) -> tuple[np.ndarray, np.ndarray]:
    """Regressors and target of Eq. (11) for one sequence.

    Parameters
    ----------
    s : EcmData

    Returns
    -------
    Phi : ndarray, shape (n-3, 5)
        Rows ``[y(k-1), y(k-2), y(k-3), u(k-2), u(k-3)]`` (nl, nl, nl, µm, µm), k = 3..n-1.
    target : ndarray, shape (n-3,)
        ``y(k)`` (nl).
    """
    y, u = s.volume_nl, s.u_um
    k = np.arange(3, y.size)
    Phi = np.column_stack([y[k - 1], y[k - 2], y[k - 3], u[k - 2], u[k - 3]])
    return Phi, y[k]


def fit_delta_one(s: EcmData, hyd: Hydraulics, la: float, h_s: float, final_value: bool = True):
    """The paper's delta-operator least squares (Eqs. 10-13) on one sequence.

    Parameters
    ----------
    s : EcmData
    hyd : Hydraulics
        Known elements of Eq. (2) (SI).
    la : float
        Fixed La (kg/m^4).
    h_s : float
        Step of the delta operator (s).
    final_value : bool
        Eliminate Kc through Eq. (13) (True) or fit it freely.

    Returns
    -------
    params : EcmParameters
        Estimate (SI units).
    rmse_1step_nl : float
        RMS one-step (equation) error of Eq. (11) (nl).
    success : bool
        Whether the optimiser converged.
    """
    Phi, target = delta_regressors(s)
    y_ss = s.pinchoff_volume_nl * NL
    k_ss = s.pinchoff_displacement_um * UM

    def kc_eq13(ra, cn):
        return -y_ss * ra / (k_ss * cn * hyd.RR)  # Eq. (13)

    def residual(q):
        ra, cn = np.exp(q[:2])
        kc = kc_eq13(ra, cn) if final_value else kc_eq13(ra, cn) * np.exp(q[2])
        theta = delta_theta(_params_from(la, ra, cn, kc, hyd).coefficients().ratios(), h_s)
        return target - Phi @ theta

    def objective(ra, cn):
        q = np.log([ra, cn]) if final_value else np.append(np.log([ra, cn]), 0.0)
        r = residual(q)
        return float(r @ r)

    ra0, cn0 = _grid_start(objective, hyd, la, _POLE_GRID, _FRES_GRID)
    q0 = np.log([ra0, cn0]) if final_value else np.append(np.log([ra0, cn0]), 0.0)
    sol = optimize.least_squares(residual, q0, xtol=1e-12, ftol=1e-12, gtol=1e-12)
    ra, cn = np.exp(sol.x[:2])
    kc = kc_eq13(ra, cn) * (1.0 if final_value else np.exp(sol.x[2]))
    p = _params_from(la, ra, cn, kc, hyd)
    rmse1 = float(np.sqrt(np.mean(residual(sol.x) ** 2)))
    return p, rmse1, bool(sol.success)


def _fit_delta(sequences, hyd: Hydraulics, la: float, h_us: float | None, final_value: bool = True) -> EcmFit:
    h_data, U, Y, mask = _stack(sequences)
    h_s = (h_data if h_us is None else float(h_us)) * 1e-6
    rows = []
    for s in sequences:
        p, rmse1, ok = fit_delta_one(s, hyd, la, h_s, final_value)
        c = p.coefficients()
        vol, _ = simulate_sampled(c, s.interval_us, s.u_um[None, :])
        rows.append(
            {
                "u1_um_per_ms": s.u1_um_per_ms,
                "u2_um": s.u2_um,
                "La": p.La,
                "Ra": p.Ra,
                "CN": p.CN,
                "Kc": p.Kc,
                **dict(zip(RATIO_NAMES, c.ratios())),
                "rmse_1step_nl": rmse1,
                "rmse_sim_nl": float(np.sqrt(np.mean((vol[0] - s.volume_nl) ** 2))),
                "success": ok,
            }
        )
    df = pd.DataFrame(rows)
    n = len(df)
    P = df[list(PARAM_NAMES)].to_numpy(dtype=float)
    mean = P.mean(axis=0)
    tq = stats.t.ppf(0.975, n - 1) if n > 1 else np.inf
    if n > 1:
        cov_mean = np.cov(P, rowvar=False) / n
        cov_mean[0, :] = cov_mean[:, 0] = 0.0  # La fixed
    else:
        cov_mean = np.full((4, 4), np.nan)
    eb = tq * np.sqrt(np.diag(cov_mean))
    ci = {name: (float(m - e), float(m + e)) for name, m, e in zip(PARAM_NAMES, mean, eb)}
    params = _params_from(*mean, hyd)
    C = np.array([_params_from(*row, hyd).coefficients().to_array() for row in P])
    R = df[list(RATIO_NAMES)].to_numpy(dtype=float)
    coeffs = EcmCoefficients(*C.mean(axis=0))
    vol, _ = simulate_sampled(coeffs, h_data, U)
    resid = (vol - Y)[mask]
    return EcmFit(
        method="delta",
        parameters=params,
        coefficients=coeffs,
        param_ci95=ci,
        param_cov=cov_mean,
        coeff_cov=np.cov(C, rowvar=False) / n if n > 1 else np.full((6, 6), np.nan),
        ratio_cov=np.cov(R, rowvar=False) / n if n > 1 else np.full((5, 5), np.nan),
        rmse_nl=float(np.sqrt(np.mean(resid**2))),
        n_sequences=n,
        n_samples=int(mask.sum()),
        per_sequence=df,
        identifiability={"note": "J is invariant under (La, Ra, Kc) -> c (La, Ra, Kc); La fixed"},
    )


# --------------------------------------------------------------------------- coefficients


def _coeffs_of(p: float, a1: float, a0: float, b1: float, b0: float) -> EcmCoefficients:
    """Eq. (6) with A(s) = (s + p)(s^2 + a1 s + a0), A3 = 1 (the scale is not identifiable)."""
    return EcmCoefficients(A3=1.0, A2=p + a1, A1=p * a1 + a0, A0=p * a0, B1=b1, B0=b0)


_DAMPING_GRID = (0.05, 0.15, 0.4, 1.0)


def fit_ecm_coefficients(sequences: Sequence[EcmData], initial: EcmCoefficients | None = None) -> EcmFit:
    """Output-error fit of the ECM coefficients A3..B0 of Eq. (6) directly, without hydraulics.

    For a nozzle whose ink or reservoir channel is unknown (Eq. 2 cannot be evaluated): the
    same consistent estimator as ``fit_ecm(method="oe")`` (exact first-order-hold simulation of
    all sequences, joint nonlinear least squares) over the five ratios of Eq. (10), with the
    denominator written as ``(s + p)(s^2 + a1 s + a0)`` (``p, a1, a0 > 0``: stable, searched in
    log space after a coarse grid of piston poles, resonances and damping ratios) and the
    numerator ``B1, B0`` eliminated in closed form (the volume is linear in them, variable
    projection). The scale is fixed by ``A3 = 1`` (Eq. 6 is invariant under a common factor).
    Physical parameters are not identifiable at this level: ``parameters`` is None,
    ``level == "coefficients"``. Covariance ``s^2 (J^T J)^-1`` over
    ``(log p, log a1, log a0, B1, B0)``, carried to the coefficients and ratios by the delta
    method (A3 row/column zero).
    """
    h, U, Y, mask = _stack(list(sequences))
    y = Y[mask]
    sim = _simulator(list(sequences), h, U)

    def basis(q3) -> np.ndarray:
        p, a1, a0 = np.exp(q3)
        v1 = sim(_coeffs_of(p, a1, a0, 1.0, 0.0))[mask]
        v0 = sim(_coeffs_of(p, a1, a0, 0.0, 1.0))[mask]
        return np.column_stack([v1, v0])

    def solve_b(X) -> np.ndarray:
        b, *_ = np.linalg.lstsq(X, y, rcond=None)
        return b

    def vp_residual(q3) -> np.ndarray:
        X = basis(q3)
        if not np.all(np.isfinite(X)):
            return np.full(y.size, 1e6 * (np.abs(y).max() + 1.0))
        return X @ solve_b(X) - y

    if initial is None:
        best = (np.inf, None)
        for pole in _POLE_GRID:
            for f in _FRES_GRID:
                w = 2 * np.pi * f
                for zeta in _DAMPING_GRID:
                    q = np.log([pole, 2 * zeta * w, w * w])
                    r = vp_residual(q)
                    val = float(r @ r)
                    if np.isfinite(val) and val < best[0]:
                        best = (val, q)
        if best[1] is None:
            raise RuntimeError("fit_ecm_coefficients: grid search found no finite objective value")
        q0 = best[1]
    else:
        roots = np.roots([initial.A3, initial.A2, initial.A1, initial.A0])
        real = roots[np.argmin(np.abs(roots.imag))].real
        rest = np.poly(np.delete(roots, np.argmin(np.abs(roots.imag)))).real
        q0 = np.log([-real, rest[1], rest[2]])
    sol = optimize.least_squares(vp_residual, q0, x_scale=1.0, xtol=1e-12, ftol=1e-12, gtol=1e-12)
    q3 = sol.x
    b = solve_b(basis(q3))
    p, a1, a0 = np.exp(q3)
    coeffs = _coeffs_of(p, a1, a0, *b)
    resid = vp_residual(q3)
    n_obs, n_par = y.size, 5
    sigma2 = float(resid @ resid) / max(n_obs - n_par, 1)
    theta = np.concatenate([q3, b])

    def sim_full(th) -> np.ndarray:
        return basis(th[:3]) @ th[3:]

    J = np.empty((n_obs, 5))
    for j in range(5):
        e = np.zeros(5)
        e[j] = 1e-5 if j < 3 else 1e-5 * max(abs(theta[j]), 1e-300)
        J[:, j] = (sim_full(theta + e) - sim_full(theta - e)) / (2 * e[j])
    col = np.linalg.norm(J, axis=0)
    col[col == 0] = 1.0
    Jn = J / col
    cov_t = sigma2 * np.linalg.pinv(Jn.T @ Jn) / np.outer(col, col)
    sd = np.sqrt(np.clip(np.diag(cov_t), 0, None))
    corr = cov_t / np.outer(np.where(sd > 0, sd, 1.0), np.where(sd > 0, sd, 1.0))
    Js = J / np.linalg.norm(J, axis=0)
    sv = np.linalg.svd(Js, compute_uv=False)

    def coeff_of(th):
        return _coeffs_of(*np.exp(th[:3]), *th[3:]).to_array()

    def ratio_of(th):
        return _coeffs_of(*np.exp(th[:3]), *th[3:]).ratios()

    return EcmFit(
        method="oe",
        parameters=None,
        coefficients=coeffs,
        param_ci95={},
        param_cov=np.full((4, 4), np.nan),
        coeff_cov=_delta_cov(coeff_of, theta, cov_t),
        ratio_cov=_delta_cov(ratio_of, theta, cov_t),
        rmse_nl=float(np.sqrt(np.mean(resid**2))),
        n_sequences=len(sequences),
        n_samples=int(n_obs),
        per_sequence=None,
        identifiability={
            "parameters": ["log p", "log a1", "log a0", "B1", "B0"],
            "singular_values": sv,
            "rank": int(np.sum(sv > 1e-6 * sv[0])),
            "correlation": corr,
            "optimizer_success": bool(sol.success),
            "note": "coefficients fitted directly (A3 = 1): La, Ra, CN, Kc not identifiable without the "
                    "hydraulics of Eq. (2)",
        },
        level="coefficients",
    )


# --------------------------------------------------------------------------- public


def fit_ecm(
    sequences: Sequence[EcmData],
    hydraulics: Hydraulics | Sequence[float] | None,
    method: str = "oe",
    *,
    la: float = LA_DEFAULT,
    initial: EcmParameters | None = None,
    h_us: float | None = None,
    final_value: bool = True,
) -> EcmFit:
    """Identify Ra, CN and Kc (La fixed, not identifiable) from growing-volume sequences.

    Parameters
    ----------
    sequences : sequence of EcmData
        Measured sequences on a common sampling interval (e.g. 10 µs), each truncated at
        pinch-off.
    hydraulics : Hydraulics or (LN, RN, LR, RR) or None
        Known elements of Eq. (2), e.g. from :func:`identify.hydraulics.hydraulics_from_geometry`.
        None: the coefficients A3..B0 are fitted directly (:func:`fit_ecm_coefficients`,
        ``method="oe"`` only; physical parameters not identifiable).
    method : {"oe", "delta"}
        ``"oe"``: joint output-error fit of the exact continuous-time model (default,
        consistent). ``"delta"``: the paper's per-sequence delta-operator least squares with
        the final-value constraint (Eqs. 10-13), then mean and 95 % interval.
    la : float
        Value at which La is fixed (kg/m^4). Only Ra/La, CN and Kc/La are identifiable.
    initial : EcmParameters, optional
        Starting point of the ``oe`` search (default: coarse grid search).
    h_us : float, optional
        Step of the delta operator (``delta`` only); default the sampling interval.
    final_value : bool
        ``delta`` only: eliminate Kc through Eq. (13) with the pinch-off volume and
        displacement (the paper, default). ``False`` fits Kc freely, which isolates the
        Euler-discretisation bias from the bias of Eq. (13): the grown volume at pinch-off
        is not the steady state of Eq. (12).

    Returns
    -------
    EcmFit
    """
    if hydraulics is None:
        if method != "oe":
            raise ValueError(f"fit_ecm: method {method!r} needs the hydraulics of Eq. (2); without them use 'oe'")
        return fit_ecm_coefficients(list(sequences))
    try:
        hyd = Hydraulics(*(float(v) for v in hydraulics))
    except TypeError as exc:
        raise ValueError("fit_ecm: hydraulics must be (LN, RN, LR, RR)") from exc
    if not all(np.isfinite(v) and v > 0 for v in hyd):
        raise ValueError(f"fit_ecm: hydraulics must be positive numbers, got {tuple(hyd)}")
    if not (np.isfinite(la) and la > 0):
        raise ValueError(f"fit_ecm: la must be a positive number, got {la!r}")
    if method == "oe":
        return _fit_oe(list(sequences), hyd, float(la), initial)
    if method == "delta":
        return _fit_delta(list(sequences), hyd, float(la), h_us, final_value)
    raise ValueError(f"fit_ecm: unknown method {method!r} (use 'oe' or 'delta')")
