"""The published colour-ink hybrid model of Wang & Chiu (Eqs. 14-17, Table 3), built in.

:data:`PAPER_COLOUR_INK` holds the ECM coefficients of Eq. (14) with their 95 % error
bounds, the Table 3 parameters with their error bounds, the pinch-off polynomial of Eq. (15)
and the volume/velocity adjusters of Eqs. (16)-(17) with their error bounds, for the
200 µm nozzle. :func:`paper_prediction` runs the Monte Carlo of Section 5.1 (vectorised,
closed-form ECM responses, no time stepping).

Conventions
-----------
* Instants ``k`` of Eq. (15) count strobe samples of ``ts = 10 µs`` **from the firing
  trigger** (the images are timed from the trigger and the ARX of Table 2 carries the
  220 µs dead time as n_k = 22 samples, so the data index is the trigger index). Following
  the note of Table 4, ``k_p`` is rounded up: at (70, 25) ``k_p = 90.6 -> 91``, i.e. 910 µs
  after the trigger, 690 µs after the start of the piston motion. (Counting from the
  waveform start instead puts pinch-off at 1130 µs and gives in-flight volumes ~0.3 nl
  smaller, further from the paper; see the table below.)
* The piston waveform (Eq. 1, u3 = 2 µm/ms, tH = 20 µs) starts 220 µs after the trigger.
* Monte Carlo (Section 5.1): each of La, Ra, CN, Kc takes 10 values drawn uniformly from
  its Table 3 interval (mean +- EB), all 10^4 combinations are simulated with the
  hydraulics implied by Eq. (14) (below). Pinch-off and adjusters: 100 constants x 10 x 10
  coefficients drawn uniformly from their intervals. The ECM is truncated at the nominal
  pinch-off instant. In-flight volume = every grown volume + every volume adjustment
  (10^8 pairs, statistics computed exactly: means add, variances add, extremes add);
  the same for the jetting velocity.

What the published numbers give (u1 = 70 µm/ms, u2 = 25 µm)
------------------------------------------------------------
Hydraulics implied by Eq. (14) with Table 3 (A3 = CN Lt La, B1 = Kc CN LR, B0 = Kc CN RR,
A2 = CN La Rt + CN Lt Ra): Lt = 2.249e8, LR = 3.593e7, LN = 1.890e8 kg/m^4;
RR = 1.263e9, RN = 3.373e11 kg/(m^4 s). By Eq. (2) LN and RN both correspond to a
200 µm nozzle 5.98 / 5.99 mm long (colour ink) -- the published numbers are mutually
consistent, and the reservoir side is a wide, ~0.7 mm radius channel.

The model is, however, dynamically extreme: poles at -35.0 rad/s (piston, 5.6 Hz, time
constant 28.6 ms) and -752.7 +- 632 929 j rad/s, a **100.73 kHz meniscus mode with damping
ratio 0.00119** (CN = 1.11e-20 m^4 s^2/kg is tiny). Below 100 kHz the volume simply
follows the piston, V ~ -(B1/La) u + small integral term: gain 0.673 nl/µm (static gain
-B0/A0 = 0.677 nl/µm). Each corner of the waveform rings the 100 kHz mode with a flow
amplitude equal to the flow step (~1.5 m/s) that decays only over ~1.3 ms.

================================================  ============  ===========================
quantity at (70, 25)                                exact (CT)    sampled at 10 µs (paper)
================================================  ============  ===========================
grown volume at k_p = 91 (910 µs), nominal ECM      16.404 nl     16.474 nl
grown volume, MC mean (40 seeds: mean +- sd)        16.42+-0.03   16.49+-0.03 nl
flow velocity at max stroke, nominal ECM            0.367 m/s     1.077 m/s (backward diff.)
flow velocity at max stroke, MC mean                0.40+-0.02    1.078+-0.002 m/s
in-flight volume, MC mean (paper 17.74 nl)          17.71+-0.41   17.78+-0.41 nl
jetting velocity, MC mean (paper 1.12 m/s)          0.45+-0.06    1.13+-0.05 m/s
================================================  ============  ===========================

The MC means scatter from seed to seed because the paper's scheme draws only 10 values of
each adjuster coefficient: 0.021 x u1 = +-1.5 nl for the u1 term of Eq. (16) gives the
mean adjustment a sampling sd of ~0.36 nl (velocity ~0.05 m/s); seed 0 gives 18.14 /
18.20 nl. The expected adjustments are the nominal ones, 1.2325 nl and 0.040 m/s.
:func:`paper_expectation` gives the converged expectation (adjusters exact, ECM averaged
over 2e4 independent draws): 17.64 nl exact, 17.71 nl sampled (the default), stable to ~0.002 nl between
seeds; ``identify paper`` prints it by default and one draw of the paper's scheme with
``--scheme-draw``.

("exact (CT)": the continuous-time model of Eq. (6) evaluated in closed form at the
instants for the true trapezoid, checked against scipy.signal.lsim at a 1/70 µs step.
"sampled": the Eq. (9) samples, held first-order between the 10 µs strobe instants
(MATLAB-lsim style), volume read at the sample k_p and the velocity as the backward
difference ``(V(36) - V(35)) / 10 µs`` of the sampled volume at the first sample at or
after the maximum stroke (357.1 µs after the waveform start), checked against
scipy.signal.cont2discrete(..., "foh") + dlsim.) Counting k_p from the waveform start
would give 16.10 / 16.18 nl grown volume (1130 µs after the trigger).

Why the figures differ:

1. The paper's 1.12 m/s is reproduced only by reading the velocity off the volume sampled
   at 10 µs. The 100.73 kHz mode is aliased by 10 µs sampling to 0.73 kHz (its period,
   9.93 µs, is almost the sampling interval), where it looks like a plausible, well damped
   (apparent damping ratio ~0.16) meniscus oscillation; the backward difference over
   [350, 360] µs also averages the 1.5 m/s ramp flow with the stopped piston. The exact
   flow at the maximum-stroke instant is 0.37 m/s: the ringing from the ramp start
   (-1.5 m/s x cos(ω_d 357 µs)) nearly cancels the mean ramp flow. At the sample
   instants 350 and 360 µs the exact flow is 1.55 and -0.25 m/s. So "flow velocity at
   maximum stroke" of this model is ill-defined to about +-1.5 m/s within +-2.5 µs.
2. The grown volume is robust (ringing amplitude in volume ~0.07 nl): 16.40 (exact) vs
   16.47 nl (sampled: the first-order hold cuts the corner at 357.1 µs, which is not on
   the 10 µs grid). With the 1.23 nl adjuster the in-flight volume is 17.62-17.71 nl vs
   the paper's 17.74 nl; the remaining 0.03-0.1 nl is far inside the Monte Carlo
   sampling scatter (+-0.4 nl) and within the rounding of Eq. (14) (A1 has 3
   significant digits: +-0.12 % in ω shifts the ringing phase at 910 µs by ~0.6 rad).
   Both figures are consistent with the paper; only the velocity discriminates.
3. The Monte Carlo mean differs from the nominal response because the CN interval
   (±0.36 %) spreads the 100 kHz phase by ±0.8 rad at 690 µs, averaging the ringing.
4. The error bounds printed for A3, A2, B1 and B0 in Eq. (14) are 1.6e-5 to 5e-5
   relative, while Table 3 implies ~0.5-1.2 % (A1 and A0 do match La and Ra at 0.4 %):
   probably exponent misprints. :data:`PAPER_COLOUR_INK` keeps them as printed and also
   gives ``coefficient_eb_from_table3`` (linear propagation).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from identify.ecm import COEFF_NAMES, EcmCoefficients, EcmParameters, flow_velocity_m_s, pwl_response, waveform_knots
from identify.hydraulics import Hydraulics
from identify.waveform import DEAD_TIME_US, SAMPLE_INTERVAL_US, Waveform


@dataclass(frozen=True)
class PaperModel:
    """A published hybrid model: ECM (Eq. 14 / Table 3), pinch-off (Eq. 15), adjusters (16, 17).

    Polynomials are ``(p00, p10, p01)`` of ``p00 + p10 u1 + p01 u2`` (u1 in µm/ms, u2 in µm)
    with 95 % error bounds ``*_eb``. ``table3``/``table3_eb`` are in SI units.
    """

    name: str
    coefficients: EcmCoefficients
    coefficient_eb: dict
    table3: dict
    table3_eb: dict
    pinchoff_poly: tuple
    pinchoff_poly_eb: tuple
    volume_adjuster_poly: tuple
    volume_adjuster_poly_eb: tuple
    velocity_adjuster_poly: tuple
    velocity_adjuster_poly_eb: tuple
    nozzle_inner_diameter_um: float = 200.0
    sample_interval_us: float = SAMPLE_INTERVAL_US
    dead_time_us: float = DEAD_TIME_US
    ink: dict = field(default_factory=dict)

    def hydraulics(self) -> Hydraulics:
        """LN, RN, LR, RR implied by Eq. (14) with the Table 3 means (see module docstring)."""
        c, t = self.coefficients, self.table3
        la, ra, cn, kc = t["La"], t["Ra"], t["CN"], t["Kc"]
        lt = c.A3 / (cn * la)
        lr = c.B1 / (kc * cn)
        rr = c.B0 / (kc * cn)
        rt = (c.A2 - cn * lt * ra) / (cn * la)
        return Hydraulics(LN=lt - lr, RN=rt - rr, LR=lr, RR=rr)

    def parameters(self) -> EcmParameters:
        """Table 3 means with the implied hydraulics (reproduces Eq. 14)."""
        t = self.table3
        return EcmParameters(La=t["La"], Ra=t["Ra"], CN=t["CN"], Kc=t["Kc"], **self.hydraulics()._asdict())

    def coefficient_eb_from_table3(self) -> dict:
        """95 % bounds of A3..B0 propagated linearly from independent Table 3 bounds."""
        p0 = self.parameters()
        base = p0.coefficients().to_array()
        var = np.zeros(6)
        for name in ("La", "Ra", "CN", "Kc"):
            step = 1e-6 * getattr(p0, name)
            hi = EcmParameters(**{**p0.to_dict(), name: getattr(p0, name) + step})
            d = (hi.coefficients().to_array() - base) / step
            var += (d * self.table3_eb[name]) ** 2
        return dict(zip(COEFF_NAMES, np.sqrt(var)))

    def pinchoff_instant(self, u1_um_per_ms, u2_um):
        """Unrounded k_p of Eq. (15) (samples from the trigger)."""
        p = self.pinchoff_poly
        return p[0] + p[1] * np.asarray(u1_um_per_ms, float) + p[2] * np.asarray(u2_um, float)

    def pinchoff_us(self, u1_um_per_ms, u2_um):
        """Pinch-off time from the trigger (µs): ceil(k_p) x 10 µs (Table 4 rounding)."""
        return np.ceil(self.pinchoff_instant(u1_um_per_ms, u2_um) - 1e-9) * self.sample_interval_us

    def volume_adjuster_nl(self, u1_um_per_ms, u2_um):
        """Eq. (16) (nl)."""
        p = self.volume_adjuster_poly
        return p[0] + p[1] * np.asarray(u1_um_per_ms, float) + p[2] * np.asarray(u2_um, float)

    def velocity_adjuster_m_s(self, u1_um_per_ms, u2_um):
        """Eq. (17) (m/s)."""
        p = self.velocity_adjuster_poly
        return p[0] + p[1] * np.asarray(u1_um_per_ms, float) + p[2] * np.asarray(u2_um, float)


#: The colour ink of the paper (Table 1 ink, Eq. 14, Table 3, Eqs. 15-17), 200 µm nozzle.
PAPER_COLOUR_INK = PaperModel(
    name="Wang & Chiu colour ink",
    coefficients=EcmCoefficients(A3=10.01e-25, A2=15.42e-22, A1=4.01e-13, A0=14.02e-12, B1=-2.70e-19, B0=-9.49e-18),
    coefficient_eb={"A3": 0.16e-28, "A2": 0.24e-25, "A1": 1.59e-15, "A0": 0.56e-13, "B1": 1.31e-23, "B0": 4.59e-22},
    table3={"Kc": -6.77e-7, "Ra": 14.02e-12, "La": 4.01e-13, "CN": 1.11e-20},
    table3_eb={"Kc": 0.082e-7, "Ra": 0.056e-12, "La": 0.016e-13, "CN": 0.004e-20},
    pinchoff_poly=(163.1, -1.40, 1.02),
    pinchoff_poly_eb=(15.4, 0.17, 0.33),
    volume_adjuster_poly=(0.16, 0.014, 0.0037),
    volume_adjuster_poly_eb=(1.87, 0.021, 0.0454),
    velocity_adjuster_poly=(-0.155, 0.0025, 0.0008),
    velocity_adjuster_poly_eb=(0.300, 0.0034, 0.0072),
    ink={"name": "colour ink", "density_kg_m3": 993.0, "viscosity_mPa_s": 2.21, "surface_tension_mN_m": 28.72},
)


# --------------------------------------------------------------------------- responses


def _sampled_knots(w: Waveform, n_samples: int, ts_us: float, dead_time_us: float):
    """Knots/slope jumps of the Eq. (9) samples held first-order between strobe instants."""
    up = w.sampled_um(n_samples - 1, ts_us)
    slopes = np.diff(np.concatenate([[0.0], up, [up[-1]]])) / ts_us  # slope on [k-1, k] ... [n-1, inf)
    jumps = np.diff(slopes)
    knots = dead_time_us + ts_us * np.arange(n_samples)
    return knots, jumps


def ecm_at_pinchoff(
    ratios,
    w: Waveform,
    pinchoff_us: float,
    *,
    simulation: str = "exact",
    model: PaperModel = PAPER_COLOUR_INK,
) -> tuple[np.ndarray, np.ndarray]:
    """Grown volume at pinch-off (nl) and flow velocity at maximum stroke (m/s).

    Parameters
    ----------
    ratios : array_like, shape (..., 5)
        θ of Eq. (10), one row per ECM.
    w : Waveform
    pinchoff_us : float
        Pinch-off instant from the trigger (µs).
    simulation : {"exact", "sampled"}
        ``"exact"``: continuous-time response to the true trapezoid, volume at
        ``pinchoff_us`` and flow at the maximum-stroke instant (220 µs + u2/u1).
        ``"sampled"``: the paper's 10 µs view: Eq. (9) samples held first-order, volume at
        the strobe instant ``pinchoff_us``, velocity as the backward difference of the
        sampled volume at the first strobe instant at or after the maximum stroke.
    """
    ts, dead = model.sample_interval_us, model.dead_time_us
    d_um = model.nozzle_inner_diameter_um
    if simulation == "exact":
        knots, jumps = waveform_knots(w, dead)
        vol, flow = pwl_response(ratios, knots, jumps, np.array([pinchoff_us, dead + w.rise_us]))
        return vol[..., 0], flow_velocity_m_s(flow[..., 1], d_um)
    if simulation == "sampled":
        k_ms = int(np.ceil(w.rise_us / ts - 1e-9))
        n = int(max(np.ceil((pinchoff_us - dead) / ts), k_ms)) + 2
        knots, jumps = _sampled_knots(w, n, ts, dead)
        t_ms = dead + ts * k_ms
        vol, _ = pwl_response(ratios, knots, jumps, np.array([pinchoff_us, t_ms, t_ms - ts]))
        flow = (vol[..., 1] - vol[..., 2]) / ts
        return vol[..., 0], flow_velocity_m_s(flow, d_um)
    raise ValueError(f"simulation must be 'exact' or 'sampled', got {simulation!r}")


def _uniform(rng, mean, eb, n):
    return mean + eb * rng.uniform(-1.0, 1.0, n)


def _poly_samples(rng, poly, eb, u1, u2, n_const, n_coef):
    """100 x 10 x 10 style combinations of the linear polynomial of Eq. (7)."""
    c0 = _uniform(rng, poly[0], eb[0], n_const)
    c1 = _uniform(rng, poly[1], eb[1], n_coef)
    c2 = _uniform(rng, poly[2], eb[2], n_coef)
    return (c0[:, None, None] + c1[None, :, None] * u1 + c2[None, None, :] * u2).ravel()


def _stats(x) -> dict:
    x = np.asarray(x, dtype=float)
    return {"mean": float(x.mean()), "std": float(x.std()), "parameters_only_low": float(x.min()), "parameters_only_high": float(x.max())}


def pair_stats(a, b) -> dict:
    """Statistics of a_i + b_j over all pairs (exact, without forming them).

    Parameters
    ----------
    a, b : array_like
        Samples of two independent quantities in the same unit (e.g. nl).

    Returns
    -------
    dict
        ``{"mean", "std", "parameters_only_low", "parameters_only_high"}`` of all sums a_i + b_j (unit of the inputs); std
        is the population standard deviation.
    """
    a, b = np.asarray(a, float), np.asarray(b, float)
    return {
        "mean": float(a.mean() + b.mean()),
        "std": float(np.sqrt(a.var() + b.var())),
        "parameters_only_low": float(a.min() + b.min()),
        "parameters_only_high": float(a.max() + b.max()),
    }


def _theta(model: PaperModel, la, ra, cn, kc) -> np.ndarray:
    """θ of Eq. (10) for Table 3 parameter draws with the hydraulics implied by Eq. (14)."""
    hyd = model.hydraulics()
    lt, rt = hyd.LN + hyd.LR, hyd.RN + hyd.RR
    a3 = cn * lt * la
    return np.column_stack([(cn * la * rt + cn * lt * ra) / a3, (cn * rt * ra + la) / a3, ra / a3,
                            kc * cn * hyd.LR / a3, kc * cn * hyd.RR / a3])


#: Default number of independent draws of :func:`paper_expectation` (seed-to-seed scatter of
#: the in-flight volume expectation ~0.002 nl at (70, 25), far below 0.05 nl).
EXPECTATION_SAMPLES = 20_000


def paper_expectation(
    u1: float,
    u2: float,
    samples: int = EXPECTATION_SAMPLES,
    seed: int = 0,
    *,
    simulation: str = "exact",
    model: PaperModel = PAPER_COLOUR_INK,
) -> dict:
    """Expectation of the published model's Monte Carlo (Section 5.1), converged.

    The same distributions as :func:`paper_prediction` (every parameter and polynomial
    coefficient uniform on its published interval), but the expectation is computed instead of
    one draw of the paper's 10-values-per-coefficient scheme: the adjusters are linear in their
    coefficients, so their expectation is exactly the nominal adjuster (Eqs. 16-17); the ECM
    part (nonlinear in La, Ra, CN, Kc) is averaged over ``samples`` independent draws (standard
    error ~0.0005 nl at the default). ``std``/``low``/``high`` describe the spread of one
    Monte Carlo model (standard deviation, 2.5 / 97.5 percentiles of the independent draws).

    Returns the keys of :func:`paper_prediction`, with ``estimate`` = ``"expectation"``.
    """
    if not (np.isfinite(u1) and np.isfinite(u2) and u1 > 0 and u2 > 0):
        raise ValueError(f"paper_expectation: u1 and u2 must be positive, got ({u1!r}, {u2!r})")
    if int(samples) < 16:
        raise ValueError(f"paper_expectation: samples must be >= 16, got {samples!r}")
    n = int(samples)
    rng = np.random.default_rng(seed)
    w = Waveform(float(u1), float(u2))
    tp = float(model.pinchoff_us(u1, u2))
    kp = (_uniform(rng, model.pinchoff_poly[0], model.pinchoff_poly_eb[0], n)
          + _uniform(rng, model.pinchoff_poly[1], model.pinchoff_poly_eb[1], n) * u1
          + _uniform(rng, model.pinchoff_poly[2], model.pinchoff_poly_eb[2], n) * u2)
    tp_mc = np.ceil(kp - 1e-9) * model.sample_interval_us
    la, ra, cn, kc = (_uniform(rng, model.table3[k], model.table3_eb[k], n) for k in ("La", "Ra", "CN", "Kc"))
    vol_mc, vel_mc = ecm_at_pinchoff(_theta(model, la, ra, cn, kc), w, tp, simulation=simulation, model=model)
    vol0, vel0 = ecm_at_pinchoff(model.coefficients.ratios(), w, tp, simulation=simulation, model=model)

    def adjuster(poly, eb):
        draws = sum(_uniform(rng, poly[i], eb[i], n) * x for i, x in enumerate((1.0, u1, u2)))
        return float(poly[0] + poly[1] * u1 + poly[2] * u2), draws

    def total(ecm, poly, eb):
        mean_adj, adj = adjuster(poly, eb)
        x = ecm + adj
        lo, hi = np.percentile(x, [2.5, 97.5])
        return {"mean": float(np.mean(ecm) + mean_adj), "std": float(np.std(x)), "parameters_only_low": float(lo), "parameters_only_high": float(hi)}

    def stats_(x):
        lo, hi = np.percentile(x, [2.5, 97.5])
        return {"mean": float(np.mean(x)), "std": float(np.std(x)), "parameters_only_low": float(lo), "parameters_only_high": float(hi)}

    return {
        "u1_um_per_ms": float(u1),
        "u2_um": float(u2),
        "pinchoff_us": tp,
        "pinchoff_us_mc": stats_(tp_mc),
        "grown_volume_at_pinchoff_nl": float(vol0),
        "grown_volume_at_pinchoff_mc_nl": stats_(vol_mc),
        "flow_velocity_at_max_stroke_m_s": float(vel0),
        "flow_velocity_at_max_stroke_mc_m_s": stats_(vel_mc),
        "inflight_volume_nl": total(vol_mc, model.volume_adjuster_poly, model.volume_adjuster_poly_eb),
        "jetting_velocity_m_s": total(vel_mc, model.velocity_adjuster_poly, model.velocity_adjuster_poly_eb),
        "simulation": simulation,
        "instant_origin": "trigger",
        "samples": n,
        "seed": int(seed),
        "estimate": "expectation",
    }


def paper_prediction(
    u1: float,
    u2: float,
    samples: int = 10000,
    seed: int = 0,
    *,
    simulation: str = "exact",
    model: PaperModel = PAPER_COLOUR_INK,
) -> dict:
    """Monte Carlo prediction of the published hybrid model (Section 5.1).

    Parameters
    ----------
    u1, u2 : float
        Stroke velocity (µm/ms) and stroke (µm).
    samples : int
        Size of each Monte Carlo set (10^4 in the paper): ECM parameters take
        ``n = round(samples ** 0.25)`` values each; polynomials ``samples // n^2`` constants
        x n x n coefficients.
    seed : int
    simulation : {"exact", "sampled"}
        See :func:`ecm_at_pinchoff`; ``"sampled"`` mimics the paper's 10 µs simulation and
        reproduces its 1.12 m/s, ``"exact"`` is the continuous-time model.

    Returns
    -------
    dict
        ``pinchoff_us`` (nominal, from the trigger), ``pinchoff_us_mc`` {mean, std, low,
        high}, ``grown_volume_at_pinchoff_nl`` (nominal ECM), ``grown_volume_at_pinchoff_mc_nl``,
        ``flow_velocity_at_max_stroke_m_s`` (nominal), ``flow_velocity_at_max_stroke_mc_m_s``,
        ``inflight_volume_nl`` and ``jetting_velocity_m_s`` {mean, std, low, high} over all
        ECM x adjuster pairs, and the settings.
    """
    if not (np.isfinite(u1) and np.isfinite(u2) and u1 > 0 and u2 > 0):
        raise ValueError(f"paper_prediction: u1 and u2 must be positive, got ({u1!r}, {u2!r})")
    if int(samples) < 16:
        raise ValueError(f"paper_prediction: samples must be >= 16, got {samples!r}")
    rng = np.random.default_rng(seed)
    n = max(2, int(round(samples**0.25)))
    n_const = max(1, int(samples) // n**2)
    w = Waveform(float(u1), float(u2))

    tp = float(model.pinchoff_us(u1, u2))
    kp_mc = _poly_samples(rng, model.pinchoff_poly, model.pinchoff_poly_eb, u1, u2, n_const, n)
    tp_mc = np.ceil(kp_mc - 1e-9) * model.sample_interval_us

    hyd = model.hydraulics()
    draws = [_uniform(rng, model.table3[k], model.table3_eb[k], n) for k in ("La", "Ra", "CN", "Kc")]
    la, ra, cn, kc = (g.ravel() for g in np.meshgrid(*draws, indexing="ij"))
    lt, rt = hyd.LN + hyd.LR, hyd.RN + hyd.RR
    a3 = cn * lt * la
    theta = np.column_stack(
        [
            (cn * la * rt + cn * lt * ra) / a3,
            (cn * rt * ra + la) / a3,
            ra / a3,
            kc * cn * hyd.LR / a3,
            kc * cn * hyd.RR / a3,
        ]
    )
    vol_mc, vel_mc = ecm_at_pinchoff(theta, w, tp, simulation=simulation, model=model)
    vol0, vel0 = ecm_at_pinchoff(model.coefficients.ratios(), w, tp, simulation=simulation, model=model)

    vadj = _poly_samples(rng, model.volume_adjuster_poly, model.volume_adjuster_poly_eb, u1, u2, n_const, n)
    jadj = _poly_samples(rng, model.velocity_adjuster_poly, model.velocity_adjuster_poly_eb, u1, u2, n_const, n)
    return {
        "u1_um_per_ms": float(u1),
        "u2_um": float(u2),
        "pinchoff_us": tp,
        "pinchoff_us_mc": _stats(tp_mc),
        "grown_volume_at_pinchoff_nl": float(vol0),
        "grown_volume_at_pinchoff_mc_nl": _stats(vol_mc),
        "flow_velocity_at_max_stroke_m_s": float(vel0),
        "flow_velocity_at_max_stroke_mc_m_s": _stats(vel_mc),
        "inflight_volume_nl": pair_stats(vol_mc, vadj),
        "jetting_velocity_m_s": pair_stats(vel_mc, jadj),
        "simulation": simulation,
        "instant_origin": "trigger",
        "samples": int(n**4),
        "seed": int(seed),
        "estimate": "scheme_draw",
    }
