"""Hybrid model of drop formation, Eq. (8): ECM + pinch-off instant + adjusters.

Prediction at control parameters (u1, u2):

- pinch-off instant t_p (µs from the trigger) from the pinch-off polynomial (Eq. 7);
- grown volume at pinch-off = ECM volume (Eq. 6) at t_p for the waveform delayed by the
  dead time (exact, :func:`identify.montecarlo.ecm_response_at`);
- in-flight volume = that + volume adjuster polynomial (nl);
- jetting velocity = ECM flow at maximum stroke (t = dead + 1000 u2/u1 µs) / nozzle
  cross-section + velocity adjuster polynomial (m/s).

Adjuster training targets (``adjuster_reference``)
--------------------------------------------------
``"ecm"`` (default): volume adjustment = measured in-flight volume - ECM-simulated grown
volume at the *measured* pinch-off instant of that sequence; velocity adjustment = measured
jetting velocity - ECM flow velocity at maximum stroke. The adjuster then also absorbs any
bias of the identified ECM, so prediction (which uses the ECM) and training are consistent,
while the pinch-off uncertainty stays in the pinch-off polynomial.
``"measured"``: the paper's Section 4.1.2: in-flight volume - grown volume measured right
before pinch-off; jetting velocity - measured flow velocity at maximum stroke (summary
columns ``grown_volume_at_pinchoff_nl`` and ``flow_velocity_at_max_stroke_m_s``).

This module holds the model (prediction, intervals, model.json round trip); the validation of
model.json is in :mod:`identify.model_file`, the fit in :mod:`identify.hybrid_fit`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dvcore import schema
from dvcore.atomic import write_json
from dvcore.jsonio import load_json_hardened
from identify.ecm import COEFF_NAMES, EcmCoefficients, flow_velocity_m_s, nozzle_area_m2
from identify.ecm import simulate as ecm_simulate
from identify.model_file import ModelFileError, check_model_dict
from identify.montecarlo import OUTPUTS, ecm_response_at, ecm_response_at_controls, modal_form, run_monte_carlo
from identify.polynomial import PolynomialFit
from identify.waveform import Waveform

if TYPE_CHECKING:  # imported where used, so that loading a model and predicting stay light
    import pandas as pd

    from identify.design import DesignResult

SCHEMA = schema.MODEL.schema

#: Outputs with a confidence and a prediction interval (measured per drop in the training data).
INTERVAL_OUTPUTS = ("pinchoff_us", "inflight_volume_nl", "jetting_velocity_m_s")


@dataclass
class HybridModel:
    """Identified hybrid model (Eq. 8). See the module docstring."""

    dead_time_us: float
    sample_interval_us: float
    nozzle_inner_diameter_um: float
    u3_um_per_ms: float
    hold_us: float
    ecm_coefficients: EcmCoefficients
    ecm_coeff_cov: np.ndarray | None
    pinchoff: PolynomialFit
    volume_adjuster: PolynomialFit
    velocity_adjuster: PolynomialFit
    arx_structure: dict | None = None
    ecm_parameters: dict | None = None  # SI, {"La": {"value", "ci95"}, ...}
    controls: np.ndarray | None = None  # distinct training (u1, u2), shape (m, 2)
    adjuster_reference: str = "ecm"
    versions: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    intervals: dict | None = None  # scatter of drops about the model, see `interval_prediction`
    #: "physical" (La..Kc given Eq. 2) or "coefficients" (A3..B0 fitted directly, no physical
    #: parameters); None in models written before the level was recorded (physical).
    ecm_level: str | None = None
    #: what the fit dropped or changed and why (`FitReport.notes`); None in older models.
    notes: list | None = None

    # ---- prediction ----------------------------------------------------------------
    def waveform(self, u1: float, u2: float) -> Waveform:
        return Waveform(float(u1), float(u2), self.u3_um_per_ms, self.hold_us)

    def predict(self, u1: float, u2: float) -> dict:
        """Nominal prediction: dict of :data:`identify.montecarlo.OUTPUTS` (+ ECM flow velocity at max stroke).

        Outside the training region of (u1, u2) it warns (:class:`ExtrapolationWarning`); an
        output that is physically impossible there (:func:`impossible_outputs`: a negative
        volume, a pinch-off not after the dead time, a jetting velocity <= 0) is NaN, with the
        value the polynomials gave in the warning: it is not a measurement of anything.
        :meth:`nominal` gives the raw values without checks.
        """
        out = self.nominal(u1, u2)
        check = self.check_prediction(u1, u2, out)
        for k in check["impossible"]:
            out[k] = float("nan")
        if check["notes"]:
            warnings.warn(ExtrapolationWarning(" ".join(check["notes"])), stacklevel=2)
        return out

    def inside_training_region(self, u1: float, u2: float) -> bool | None:
        """Whether (u1, u2) lies in the training region (convex hull of the training controls,
        :class:`identify.design.Region`); None when the model records no usable controls."""
        if self.controls is None:
            return None
        from identify.design import Region

        try:
            return bool(Region(self.controls).inside(u1, u2)[0])
        except ValueError:  # controls spanning no area
            return None

    def check_prediction(self, u1: float, u2: float, values: dict) -> dict:
        """What to say about a prediction at (u1, u2): ``extrapolation`` (True outside the
        training region, None when unknown), ``training_region`` (its bounds, or None),
        ``impossible`` (output -> why its value cannot be physical, :func:`impossible_outputs`)
        and ``notes`` (sentences)."""
        inside = self.inside_training_region(u1, u2)
        region = None
        if inside is not None:
            from identify.design import Region

            region = Region(self.controls).to_dict()
        impossible = impossible_outputs(values, self.dead_time_us)
        notes = []
        if inside is False:
            notes.append(f"(u1, u2) = ({u1:g} um/ms, {u2:g} um) lies outside the training region (u1 "
                         f"{region['u1_um_per_ms'][0]:g}-{region['u1_um_per_ms'][1]:g} um/ms, u2 "
                         f"{region['u2_um'][0]:g}-{region['u2_um'][1]:g} um, {region['shape']}): extrapolation, "
                         "the polynomials are unchecked there.")
        notes += [f"{k}: {why}; not a value (null/NaN)." for k, why in impossible.items()]
        return {"extrapolation": None if inside is None else not inside, "training_region": region,
                "impossible": impossible, "notes": notes}

    def nominal(self, u1: float, u2: float) -> dict:
        """The raw nominal prediction of :meth:`predict`, without the region and physics checks."""
        w = self.waveform(u1, u2)
        t_p = float(self.pinchoff.predict(u1, u2))
        modal = modal_form(self.ecm_coefficients)
        v_p, _ = ecm_response_at(modal, w, np.array([t_p - self.dead_time_us]))
        _, q = ecm_response_at(modal, w, np.array([w.max_stroke_us]))
        v_max = float(flow_velocity_m_s(q[0], self.nozzle_inner_diameter_um))
        return {
            "pinchoff_us": t_p,
            "grown_volume_at_pinchoff_nl": float(v_p[0]),
            "inflight_volume_nl": float(v_p[0] + self.volume_adjuster.predict(u1, u2)),
            "jetting_velocity_m_s": float(v_max + self.velocity_adjuster.predict(u1, u2)),
            "flow_velocity_at_max_stroke_m_s": v_max,
        }

    def simulate(self, u1: float, u2: float, t_us) -> tuple[np.ndarray, np.ndarray]:
        """Nominal ECM growth (Eqs. 4 and 6) on a uniform time grid from the trigger.

        Returns the grown volume (nl) and the average flow velocity (m/s) at ``t_us``; the
        waveform is delayed by the dead time. Valid up to the pinch-off instant.
        """
        t = np.asarray(t_us, dtype=float)
        w = self.waveform(u1, u2)
        vol, flow = ecm_simulate(self.ecm_coefficients, t, w.displacement_um(t - self.dead_time_us))
        return vol, flow_velocity_m_s(flow, self.nozzle_inner_diameter_um)

    def predict_grid(self, u1, u2) -> pd.DataFrame:
        """Nominal predictions for arrays of (u1, u2), vectorised; one row per pair.

        Columns: u1_um_per_ms, u2_um and the keys of :meth:`predict`.
        """
        import pandas as pd

        u1, u2 = np.broadcast_arrays(np.atleast_1d(np.asarray(u1, float)), np.atleast_1d(np.asarray(u2, float)))
        if np.any(~np.isfinite(u1) | ~np.isfinite(u2) | (u1 <= 0) | (u2 <= 0)):
            raise ValueError("u1 and u2 must be positive numbers")
        modal = modal_form(self.ecm_coefficients)
        t_p = self.pinchoff.predict(u1, u2)
        args = (self.u3_um_per_ms, self.hold_us)
        v_p, _ = ecm_response_at_controls(modal, u1, u2, t_p - self.dead_time_us, *args)
        _, q = ecm_response_at_controls(modal, u1, u2, 1000.0 * u2 / u1, *args)
        v_max = flow_velocity_m_s(q, self.nozzle_inner_diameter_um)
        return pd.DataFrame({
            "u1_um_per_ms": u1, "u2_um": u2, "pinchoff_us": t_p, "grown_volume_at_pinchoff_nl": v_p,
            "inflight_volume_nl": v_p + self.volume_adjuster.predict(u1, u2),
            "jetting_velocity_m_s": v_max + self.velocity_adjuster.predict(u1, u2),
            "flow_velocity_at_max_stroke_m_s": v_max,
        })

    def monte_carlo(self, u1: float, u2: float, samples: int = 10_000, seed: int | None = 0, **kw):
        """Monte Carlo of Section 5.1 (see :func:`identify.montecarlo.run_monte_carlo`)."""
        return run_monte_carlo(self, u1, u2, samples=samples, seed=seed, **kw)

    def interval_prediction(self, u1: float, u2: float, samples: int = 10_000, seed: int | None = 0,
                            level: float = 0.95, mc=None) -> dict:
        """The three intervals of each output at (u1, u2), named for what they cover.

        Per output of :data:`INTERVAL_OUTPUTS` a dict with ``mean`` (Monte Carlo mean: the point
        prediction), ``nominal``, ``level`` and

        * ``parameters_only_low/high``: the (1 - level)/2 and (1 + level)/2 percentiles of the
          parameter Monte Carlo alone (ECM coefficient covariance, pinch-off and both adjuster
          polynomials, pinch-off and volume adjuster drawn jointly); ``parameter_std`` its
          standard deviation. Narrowest: it ignores model discrepancy and measurement error,
          so it is *not* an interval of the mean drop;
        * ``mean_drop_low/high`` (the confidence interval): where the *mean* of many drops at
          (u1, u2) lies: the parameter variance plus the model discrepancy ``model_std`` (the
          misfit cross-validation sees beyond noise and parameter uncertainty, locally in
          (u1, u2) where the training data say so, see :func:`local_model_std`) plus the
          systematic measurement uncertainty ``measurement_std`` (below); ``mean_drop_std``;
        * ``one_drop_low/high`` (the prediction interval): where *one individual drop* lies:
          the mean-drop variance plus the drop-to-drop scatter ``drop_std`` estimated from the
          training data (repeats where present, else the sequences' own standard errors, else
          the residuals of the fit or of its flexible reference polynomials); ``one_drop_std``.

        Both intervals are ``mean +- q std`` with q Student's t of the scatter's degrees of
        freedom (``intervals.scatter[output].dof``): the parameter variance and the model
        discrepancy are measured in units of a drop scatter estimated from that many residuals,
        as the textbook interval of a regression mean is; with a stated measurement term the
        dof are the Welch-Satterthwaite ones (that term counted as known), so q tends to the
        normal quantile where it dominates; the normal quantile where no dof are stored.

        ``mean_drop_dominant_term`` and ``one_drop_dominant_term`` name the largest variance
        term of each interval ("parameters", "model_discrepancy", "measurement", "drop_scatter");
        ``variance_shares`` gives every term's share of the one-drop variance, and
        ``model_std_source`` whether the discrepancy is the global or the local estimate, or
        "polynomial_bias": where the chosen polynomials' estimated bias at (u1, u2)
        (:meth:`polynomial_bias_sq`, against the more flexible polynomials the fit stored) exceeds
        them, it is the model discrepancy there.

        Measurement term (``intervals["measurement"]`` of the model, from
        :func:`identify.measurement_uncertainty.measurement_uncertainty`): what every sequence of the training
        campaign shares and residual scatter therefore cannot show (pixel size: volume ∝ px³,
        velocity ∝ px; edge-position bias; the strobe grid of the pinch-off).
        ``measurement_std`` = ``volume_rel`` x |mean| (in-flight volume), ``velocity_rel`` x
        |mean| (jetting velocity), ``pinchoff_std_us`` (pinch-off); ``measurement_source`` says
        where the figures come from. Models without it (older files) add nothing
        (``measurement_std`` 0, source None).

        A model without ``intervals`` (fitted before they existed) gives the one-drop interval
        equal to the mean-drop interval and ``one_drop_available`` False.
        ``mc``: an already computed :class:`identify.montecarlo.MonteCarloResult`.
        """
        from scipy import special  # stdtrit/ndtri: the values of stats.t/norm.ppf, without importing scipy.stats

        if not 0 < level < 1:
            raise ValueError(f"level must be in (0, 1), got {level!r}")
        res = mc if mc is not None else self.monte_carlo(u1, u2, samples=samples, seed=seed)
        nominal = res.nominal
        scatter = (self.intervals or {}).get("scatter") or {}
        meas = (self.intervals or {}).get("measurement") or {}
        z = float(special.ndtri(0.5 + level / 2))
        bias_sq = self.polynomial_bias_sq(u1, u2)
        out = {}
        for k in INTERVAL_OUTPUTS:
            x = np.asarray(res.samples[k], float)
            mean = float(np.mean(x))
            s_mc = float(np.std(x, ddof=1)) if x.size > 1 else 0.0
            lo, hi = (np.percentile(x, [50 * (1 - level), 50 * (1 + level)]) if x.size > 1 else (mean, mean))
            sc = scatter.get(k) or {}
            s_model, model_source = local_model_std(sc, u1, u2)
            if bias_sq.get(k, 0.0) > s_model**2:  # the chosen polynomial's bias here exceeds it
                s_model, model_source = float(np.sqrt(bias_sq[k])), "polynomial_bias"
            s_drop = sc.get("drop_std")
            s_meas = _measurement_std(meas, k, mean)
            s_conf = float(np.sqrt(s_mc**2 + s_model**2 + s_meas**2))
            dof = sc.get("dof")
            q = _quantile(level, dof, s_mc**2 + s_model**2, s_meas**2) if dof else z
            terms = {"parameters": s_mc**2, "model_discrepancy": s_model**2, "measurement": s_meas**2}
            entry = {"mean": mean, "nominal": float(nominal[k]), "level": float(level),
                     "parameters_only_low": float(lo), "parameters_only_high": float(hi),
                     "parameter_std": s_mc, "model_std": s_model, "model_std_source": model_source,
                     "measurement_std": s_meas, "measurement_source": meas.get("source") if meas else None,
                     "mean_drop_std": s_conf, "mean_drop_low": mean - q * s_conf, "mean_drop_high": mean + q * s_conf,
                     "mean_drop_dominant_term": _dominant(terms)}
            if s_drop is not None:
                s_pred = float(np.sqrt(s_conf**2 + float(s_drop) ** 2))
                q = _quantile(level, dof, s_mc**2 + s_model**2 + float(s_drop) ** 2, s_meas**2) if dof else z
                terms["drop_scatter"] = float(s_drop) ** 2
                entry.update({"drop_std": float(s_drop), "one_drop_std": s_pred,
                              "one_drop_low": mean - q * s_pred, "one_drop_high": mean + q * s_pred,
                              "one_drop_available": True})
            else:
                entry.update({"drop_std": None, "one_drop_std": s_conf, "one_drop_low": entry["mean_drop_low"],
                              "one_drop_high": entry["mean_drop_high"], "one_drop_available": False})
            total = sum(terms.values())
            entry["one_drop_dominant_term"] = _dominant(terms)
            entry["variance_shares"] = {t: (v / total if total > 0 else 0.0) for t, v in terms.items()}
            out[k] = entry
        return out

    def polynomial_bias_sq(self, u1: float, u2: float) -> dict:
        """Squared bias of the chosen polynomials at (u1, u2) per output, where the fit stored the
        flexible reference polynomials (``intervals["flexible"]``, order (2, 3), and
        ``intervals["flexible_u1"]``, order (4, 1); :func:`identify.discrepancy.polynomial_bias`).
        Per reference, b² with b the change of the output when the reference polynomials replace
        the chosen ones (for the in-flight volume: the pinch-off's change through the ECM growth
        plus the volume adjuster's). b² of the (2, 3) reference is not reduced by the variance of
        b: E[b²] = bias² + var(b), so on laws the chosen polynomial holds the mean-drop interval
        becomes about as wide as the flexible polynomial's own, while a debiased max(0, b² -
        var(b)) left the misfit families' velocity at 82 %. The (4, 1) reference counts only
        where its departure is significant (:data:`U1_REFERENCE_CHI2`), and then per output the
        larger of the two b² is used. Empty for models without them."""
        out = {k: b * b for k, (b, _) in self._reference_bias("flexible", u1, u2).items()}
        for k, (b, var) in self._reference_bias("flexible_u1", u1, u2).items():
            if b * b > U1_REFERENCE_CHI2 * var:  # the u1 reference departs significantly here
                out[k] = max(out.get(k, 0.0), b * b)
        return out

    def _reference_bias(self, key: str, u1: float, u2: float) -> dict:
        """Per output, (b, var b): the change of the output when the reference polynomials
        ``intervals[key]`` replace the chosen ones, and its variance without bias (see
        :meth:`polynomial_bias_sq`; the pinch-off's variance carried to the volume linearly)."""
        from identify.discrepancy import polynomial_bias

        flex = (self.intervals or {}).get(key) or {}
        bv = {}
        for name, d in flex.items():
            b, var = polynomial_bias(getattr(self, name), PolynomialFit.from_dict(d), u1, u2)
            bv[name] = (float(np.ravel(b)[0]), float(np.ravel(var)[0]))
        out = {}
        if "pinchoff" in bv:
            out["pinchoff_us"] = bv["pinchoff"]
        if "velocity_adjuster" in bv:
            out["jetting_velocity_m_s"] = bv["velocity_adjuster"]
        if "pinchoff" in bv or "volume_adjuster" in bv:
            bp, vp = bv.get("pinchoff", (0.0, 0.0))
            bq, vq = bv.get("volume_adjuster", (0.0, 0.0))
            t_p = float(self.pinchoff.predict(u1, u2))
            t = np.array([t_p, t_p + bp]) - self.dead_time_us
            v_p, _ = ecm_response_at_controls(modal_form(self.ecm_coefficients), np.full(2, float(u1)),
                                              np.full(2, float(u2)), t, self.u3_um_per_ms, self.hold_us)
            dv = float(v_p[1] - v_p[0])
            gain = dv / bp if bp != 0 else 0.0  # volume per microsecond of pinch-off change
            out["inflight_volume_nl"] = (dv + bq, gain * gain * vp + vq)
        return out

    @property
    def nozzle_area_m2(self) -> float:
        """Inner cross-section of the nozzle (m^2), :func:`identify.ecm.nozzle_area_m2`."""
        return nozzle_area_m2(self.nozzle_inner_diameter_um)

    # ---- serialisation --------------------------------------------------------------
    def to_dict(self) -> dict:
        c = self.ecm_coefficients
        cov = None if self.ecm_coeff_cov is None else np.asarray(self.ecm_coeff_cov)
        ci = None if cov is None else (1.959963984540054 * np.sqrt(np.clip(np.diag(cov), 0, None))).tolist()
        return {
            "schema": SCHEMA,
            "dead_time_us": self.dead_time_us,
            "sample_interval_us": self.sample_interval_us,
            "nozzle_inner_diameter_um": self.nozzle_inner_diameter_um,
            "nozzle_area_m2": self.nozzle_area_m2,
            "waveform": {"u3_um_per_ms": self.u3_um_per_ms, "hold_us": self.hold_us},
            "arx_structure": self.arx_structure,
            "ecm": {
                "units": "SI: displacement m, volume m^3, time s",
                "coefficients": {k: getattr(c, k) for k in COEFF_NAMES},
                "coefficients_ci95": None if ci is None else dict(zip(COEFF_NAMES, ci)),
                "coefficient_order": list(COEFF_NAMES),
                "coefficient_covariance": None if cov is None else cov.tolist(),
                "parameters": self.ecm_parameters,
                **({} if self.ecm_level is None else {"level": self.ecm_level}),
                **({"parameters_note": "not identifiable: the ink or the reservoir channel geometry of Eq. (2) "
                    "is unknown; A3..B0 fitted directly, scale A3 = 1"} if self.ecm_level == "coefficients" else {}),
            },
            "pinchoff": self.pinchoff.to_dict(),
            "volume_adjuster": self.volume_adjuster.to_dict(),
            "velocity_adjuster": self.velocity_adjuster.to_dict(),
            "adjuster_reference": self.adjuster_reference,
            "training_controls": None if self.controls is None else np.asarray(self.controls).tolist(),
            "versions": self.versions,
            "extra": self.extra,
            **({} if self.intervals is None else {"intervals": self.intervals}),
            **({} if self.notes is None else {"notes": list(self.notes)}),
        }

    @classmethod
    def from_dict(cls, d: dict, *, source: str = "model.json") -> "HybridModel":
        """A model from its :meth:`to_dict` form; every value is checked (type, shape, finiteness)
        first, so that a malformed or hand-edited model.json raises :class:`ModelFileError`
        naming ``source`` and the key, never a traceback later during prediction."""
        if not isinstance(d, dict) or d.get("schema") != SCHEMA:
            raise ModelFileError(f"{source}: not a hybrid model file (schema {SCHEMA!r} expected)")
        check_model_dict(d, source)
        try:
            e = d["ecm"]
            cov = e.get("coefficient_covariance")
            return cls(
                dead_time_us=float(d["dead_time_us"]),
                sample_interval_us=float(d["sample_interval_us"]),
                nozzle_inner_diameter_um=float(d["nozzle_inner_diameter_um"]),
                u3_um_per_ms=float(d["waveform"]["u3_um_per_ms"]),
                hold_us=float(d["waveform"]["hold_us"]),
                ecm_coefficients=EcmCoefficients(**{k: float(e["coefficients"][k]) for k in COEFF_NAMES}),
                ecm_coeff_cov=None if cov is None else np.asarray(cov, float),
                pinchoff=PolynomialFit.from_dict(d["pinchoff"]),
                volume_adjuster=PolynomialFit.from_dict(d["volume_adjuster"]),
                velocity_adjuster=PolynomialFit.from_dict(d["velocity_adjuster"]),
                arx_structure=d.get("arx_structure"),
                ecm_parameters=e.get("parameters"),
                controls=None if d.get("training_controls") is None else np.asarray(d["training_controls"], float),
                adjuster_reference=d.get("adjuster_reference", "ecm"),
                versions=d.get("versions", {}),
                extra=d.get("extra", {}),
                intervals=d.get("intervals"),
                ecm_level=e.get("level"),
                notes=None if d.get("notes") is None else list(d["notes"]),
            )
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise ModelFileError(f"{source}: invalid model file ({type(exc).__name__}: {exc})") from None

    def save(self, path) -> Path:
        """Write model.json atomically (read it back with `identify.load_model`)."""
        return write_json(path, self.to_dict())

    def design(self, volume_nl: float, velocity_m_s: float | None = None, **options) -> DesignResult:
        """(u1, u2) inside the training region for a target in-flight volume (nl) and, optionally,
        jetting velocity (m/s); see `identify.design.design` for ``options``."""
        from identify.design import design
        return design(self, volume_nl, velocity_m_s, **options)

    @classmethod
    def from_json(cls, path) -> "HybridModel":
        path = Path(path)
        if not path.is_file():
            raise ModelFileError(f"{path}: model file not found")
        d = load_json_hardened(path, ModelFileError)  # size, encoding, NaN, depth: one line naming the file
        return cls.from_dict(d, source=str(path))


#: The reference flexible in u1 counts at a control only where its departure b from the chosen
#: polynomial is significant there: b² > var(b) times the 95 % quantile of χ²(1) (a pointwise
#: Wald test at 5 %; with no bias it fires at about 5 % of controls).
U1_REFERENCE_CHI2 = 3.841


class ExtrapolationWarning(UserWarning):
    """A prediction outside the model's training region of (u1, u2), or a physically impossible
    output there (:meth:`HybridModel.predict`)."""


def impossible_outputs(values: dict, dead_time_us: float) -> dict[str, str]:
    """Outputs whose value cannot be physical, output -> why: a negative volume (grown at
    pinch-off, in flight), a pinch-off not after the dead time (the drop cannot separate before
    the piston moves; the volumes, taken at that instant, then too), a jetting velocity <= 0 (a
    drop that does not leave). Such values come
    from polynomials extrapolated where they mean nothing; they are reported as missing with
    this reason, never as a number (a clipped 0 nl would read as "no drop", which the model
    cannot say either). Keys absent from ``values`` or NaN are skipped."""
    out = {}

    def value(k):
        v = values.get(k)
        v = v.get("mean") if isinstance(v, dict) else v
        return None if v is None or not np.isfinite(v) else float(v)

    for k in ("grown_volume_at_pinchoff_nl", "inflight_volume_nl"):
        v = value(k)
        if v is not None and v < 0:
            out[k] = f"{v:.4g} nl predicted, a negative volume"
    v = value("pinchoff_us")
    if v is not None and v <= dead_time_us:
        out["pinchoff_us"] = (f"{v:.4g} us predicted, not after the dead time {dead_time_us:g} us (the drop cannot "
                              "separate before the piston moves)")
    if "pinchoff_us" in out:  # both volumes are read off the growth at the pinch-off instant
        for k in ("grown_volume_at_pinchoff_nl", "inflight_volume_nl"):
            if k in values and k not in out:
                out[k] = "taken at an impossible pinch-off instant"
    v = value("jetting_velocity_m_s")
    if v is not None and v <= 0:
        out["jetting_velocity_m_s"] = f"{v:.4g} m/s predicted, a drop that does not leave the nozzle"
    return out


def _dominant(terms: dict) -> str:
    """Name of the largest variance term (the first on ties)."""
    return max(terms, key=lambda t: terms[t])


def _quantile(level: float, dof: float, estimated_var: float, known_var: float) -> float:
    """Two-sided Student-t quantile of an interval whose variance is ``estimated_var`` (scaled by
    the drop scatter, estimated with ``dof`` degrees of freedom: the parameter Monte Carlo, the
    model discrepancy measured beyond that scatter, the scatter itself) plus ``known_var`` (the
    stated systematic measurement term, no dof of its own): Welch-Satterthwaite effective dof
    dof (estimated + known)² / estimated², so the quantile is t(dof) without a stated term and
    tends to the normal one where that term dominates."""
    from scipy import special

    total = estimated_var + known_var
    nu = float(dof) * (total / estimated_var) ** 2 if estimated_var > 0 else np.inf
    p = 0.5 + level / 2
    return float(special.ndtri(p)) if not np.isfinite(nu) or nu > 1e7 else float(special.stdtrit(nu, p))


def local_model_std(scatter: dict, u1: float, u2: float) -> tuple[float, str]:
    """Model-discrepancy standard deviation of one output at (u1, u2) and where it comes from.

    ``scatter`` is ``model.intervals["scatter"][output]`` (`fit_hybrid`). The global
    ``model_std`` holds everywhere. Where the fit stored the Gaussian process of the
    cross-validation errors (``local``, :func:`identify.discrepancy.fit_discrepancy`), the
    expected squared misfit at (u1, u2), μ(u)² + v(u)
    (:func:`identify.discrepancy.discrepancy_variance`), replaces the global value where
    larger: near the controls where cross-validation saw the misfit concentrate, and, far from
    every training control, the discrepancy's prior variance.

    Returns
    -------
    model_std : float
        In the unit of the output.
    source : str
        "none" (no discrepancy), "global" or "local".
    """
    from identify.discrepancy import discrepancy_variance

    glob = float(scatter.get("model_std") or 0.0)
    loc = scatter.get("local")
    if loc:
        v = float(discrepancy_variance(loc, u1, u2)[0])
        if v > glob**2:
            return float(np.sqrt(v)), "local"
    return glob, ("global" if glob > 0 else "none")


def widening_reason(output: str, e: dict) -> str | None:
    """A sentence saying why the mean-drop interval of ``output`` is wider than the parameters-only
    band, when the model discrepancy or the measurement term dominates it (else None)."""
    term = e.get("mean_drop_dominant_term")
    share = (e.get("variance_shares") or {}).get(term, 0.0)
    if term == "model_discrepancy":
        where = {"local": "near these controls cross-validation saw the polynomials miss the data (local estimate)",
                 "polynomial_bias": "here a more flexible polynomial departs from the chosen one by more than its "
                                    "own uncertainty (the chosen order's bias)"}.get(
            e.get("model_std_source"), "cross-validation saw the polynomials miss the data")
        return (f"{output}: the mean-drop interval is widened mostly by model discrepancy (std {e['model_std']:.3g}, "
                f"{100 * share:.0f} % of the one-drop variance): {where}")
    if term == "measurement":
        return (f"{output}: the mean-drop interval is widened mostly by the systematic measurement uncertainty "
                f"(std {e['measurement_std']:.3g}, {100 * share:.0f} % of the one-drop variance)")
    return None


#: Key of ``intervals["measurement"]`` per output and whether it is relative to the mean.
MEASUREMENT_TERMS = {"pinchoff_us": ("pinchoff_std_us", False), "inflight_volume_nl": ("volume_rel", True),
                     "jetting_velocity_m_s": ("velocity_rel", True)}


def _measurement_std(meas: dict, output: str, mean: float) -> float:
    """Standard deviation of the systematic measurement error of ``output`` at ``mean``."""
    key, relative = MEASUREMENT_TERMS[output]
    v = float(meas.get(key) or 0.0) if meas else 0.0
    return abs(mean) * v if relative else v


def describe_measurement(model: HybridModel) -> str:
    """One sentence on the systematic measurement term of ``model``'s intervals and its source
    (for `identify predict` and the report)."""
    m = (model.intervals or {}).get("measurement")
    if not m:
        return ("systematic measurement uncertainty: none in this model (fitted before the term existed; "
                "refit it to include the calibration of the images)")
    parts = []
    if m.get("volume_rel") is not None:
        parts.append(f"in-flight volume {100 * m['volume_rel']:.3g} %")
    if m.get("velocity_rel") is not None:
        parts.append(f"jetting velocity {100 * m['velocity_rel']:.3g} %")
    if m.get("pinchoff_std_us") is not None:
        parts.append(f"pinch-off {m['pinchoff_std_us']:.3g} us")
    return ("systematic measurement uncertainty (1 sigma, shared by every sequence of the training campaign, "
            f"so invisible in residual scatter; in both intervals): {', '.join(parts) or 'none'}; "
            f"source: {m.get('source') or 'n/a'}")


__all__ = ["HybridModel", "ModelFileError", "OUTPUTS", "INTERVAL_OUTPUTS", "describe_measurement", "widening_reason",
           "local_model_std"]
