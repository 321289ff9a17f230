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
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from identify import __version__, schema
from identify.atomic import write_json
from identify.ecm import COEFF_NAMES, EcmCoefficients, flow_velocity_m_s, nozzle_area_m2
from identify.ecm import simulate as ecm_simulate
from identify.montecarlo import OUTPUTS, ecm_response_at, ecm_response_at_controls, modal_form, run_monte_carlo
from identify.kfold import grouped_kfold
from identify.polynomial import DEFAULT_ORDERS, OrderSelection, PolynomialFit, PolynomialRankError, \
    design_matrix, fit_polynomial, select_order
from identify.versions import software_versions
from identify.waveform import Waveform

if TYPE_CHECKING:  # fitting only: imported where used, so that loading a model and predicting stay light
    import pandas as pd

    from identify.dataset import Dataset
    from identify.design import DesignResult

SCHEMA = schema.MODEL.schema

#: Outputs with a confidence and a prediction interval (measured per drop in the training data).
INTERVAL_OUTPUTS = ("pinchoff_us", "inflight_volume_nl", "jetting_velocity_m_s")


class ModelFileError(ValueError):
    """model.json missing, unreadable or of the wrong schema."""


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
        """Nominal prediction: dict of :data:`identify.montecarlo.OUTPUTS` (+ ECM flow velocity at max stroke)."""
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
          the residuals of the fit), Student-t with the scatter's degrees of freedom;
          ``one_drop_std``.

        ``mean_drop_dominant_term`` and ``one_drop_dominant_term`` name the largest variance
        term of each interval ("parameters", "model_discrepancy", "measurement", "drop_scatter");
        ``variance_shares`` gives every term's share of the one-drop variance, and
        ``model_std_source`` whether the discrepancy is the global or the local estimate, or
        "polynomial_bias": where the chosen polynomials' estimated bias at (u1, u2)
        (:meth:`polynomial_bias_sq`, against the more flexible polynomials the fit stored) exceeds
        them, it is the model discrepancy there.

        Measurement term (``intervals["measurement"]`` of the model, from
        :func:`identify.dataset.measurement_uncertainty`): what every sequence of the training
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
            terms = {"parameters": s_mc**2, "model_discrepancy": s_model**2, "measurement": s_meas**2}
            entry = {"mean": mean, "nominal": float(nominal[k]), "level": float(level),
                     "parameters_only_low": float(lo), "parameters_only_high": float(hi),
                     "parameter_std": s_mc, "model_std": s_model, "model_std_source": model_source,
                     "measurement_std": s_meas, "measurement_source": meas.get("source") if meas else None,
                     "mean_drop_std": s_conf, "mean_drop_low": mean - z * s_conf, "mean_drop_high": mean + z * s_conf,
                     "mean_drop_dominant_term": _dominant(terms)}
            if s_drop is not None:
                dof = sc.get("dof")
                q = float(special.stdtrit(dof, 0.5 + level / 2)) if dof else z
                s_pred = float(np.sqrt(s_conf**2 + float(s_drop) ** 2))
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
        flexible polynomials (``intervals["flexible"]``; :func:`identify.discrepancy.polynomial_bias`):
        b² with b the change of the output when the flexible polynomials replace the chosen ones
        (for the in-flight volume: the pinch-off's change through the ECM growth plus the volume
        adjuster's). b² is not reduced by the variance of b: E[b²] = bias² + var(b), so on laws
        the chosen polynomial holds the mean-drop interval becomes about as wide as the flexible
        polynomial's own (the linear laws' coverage moves by at most 1.5 points), while a
        debiased max(0, b² - var(b)) left the misfit families' velocity at 82 %. Empty for models
        without them."""
        from identify.discrepancy import polynomial_bias

        flex = (self.intervals or {}).get("flexible") or {}
        b = {name: float(np.ravel(polynomial_bias(getattr(self, name), PolynomialFit.from_dict(d), u1, u2)[0])[0])
             for name, d in flex.items()}
        out = {}
        if "pinchoff" in b:
            out["pinchoff_us"] = b["pinchoff"]
        if "velocity_adjuster" in b:
            out["jetting_velocity_m_s"] = b["velocity_adjuster"]
        if "pinchoff" in b or "volume_adjuster" in b:
            t_p = float(self.pinchoff.predict(u1, u2))
            t = np.array([t_p, t_p + b.get("pinchoff", 0.0)]) - self.dead_time_us
            v_p, _ = ecm_response_at_controls(modal_form(self.ecm_coefficients), np.full(2, float(u1)),
                                              np.full(2, float(u2)), t, self.u3_um_per_ms, self.hold_us)
            out["inflight_volume_nl"] = float(v_p[1] - v_p[0]) + b.get("volume_adjuster", 0.0)
        return {k: v * v for k, v in out.items()}

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
        _check_model_dict(d, source)
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
        try:
            d = json.loads(path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ModelFileError(f"{path}: invalid JSON ({exc})") from None
        except RecursionError:
            raise ModelFileError(f"{path}: invalid JSON (nested too deeply)") from None
        return cls.from_dict(d, source=str(path))


def _dominant(terms: dict) -> str:
    """Name of the largest variance term (the first on ties)."""
    return max(terms, key=lambda t: terms[t])


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


def _model_error(source, key: str, problem: str) -> ModelFileError:
    return ModelFileError(f"{source}: invalid model file: {key} {problem}")


def _number(value, source, key: str, *, positive: bool = False, nonnegative: bool = False,
            at_most: float | None = None) -> float:
    """A finite JSON number (not a bool, not a string), within the given bounds, or
    :class:`ModelFileError`."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _model_error(source, key, f"must be a number, got {type(value).__name__} {_short(value)}")
    try:
        v = float(value)
    except OverflowError:
        raise _model_error(source, key, "is out of range") from None
    if not np.isfinite(v):
        raise _model_error(source, key, f"must be finite, got {v}")
    if positive and v <= 0:
        raise _model_error(source, key, f"must be > 0, got {v}")
    if nonnegative and v < 0:
        raise _model_error(source, key, f"must be >= 0, got {v}")
    if at_most is not None and v > at_most:
        raise _model_error(source, key, f"must be at most {at_most:g}, got {v:g}")
    return v


#: Physical ranges of a model's scalars (the same generous ranges sequence.json is read with).
MODEL_RANGES = {"nozzle_inner_diameter_um": 1e4, "dead_time_us": 1e6, "sample_interval_us": 1e4,
                "waveform.u3_um_per_ms": 1e4, "waveform.hold_us": 1e6}


def _check_ecm_stable(c: dict, source) -> None:
    """The identified ECM (Eq. 6) must be a stable third-order system (Routh-Hurwitz):
    A3..A0 of one sign and A2 A1 > A3 A0. A hand-edited or corrupted coefficient is caught here
    instead of predicting nonsense."""
    a3, a2, a1, a0 = (float(c[k]) for k in ("A3", "A2", "A1", "A0"))
    sign = np.sign(a3)
    with np.errstate(over="ignore"):
        stable = sign != 0 and all(np.sign(a) == sign for a in (a2, a1, a0)) and a2 * a1 > a3 * a0 and \
            np.isfinite(a2 * a1) and np.isfinite(a3 * a0)
    if not stable:
        raise _model_error(source, "ecm.coefficients", "describe no stable third-order system "
                           f"(A3..A0 = {a3:.4g}, {a2:.4g}, {a1:.4g}, {a0:.4g}): the file is corrupt or edited")


def _optional_numbers(value, source, key: str) -> None:
    """Nested objects/lists of finite numbers or nulls (confidence intervals, physical
    parameters); text only under descriptive keys (unit, units, note, source)."""
    if value is None:
        return
    if isinstance(value, dict):
        for k, v in value.items():
            _optional_numbers(v, source, f"{key}.{k}")
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _optional_numbers(v, source, f"{key}[{i}]")
    elif isinstance(value, str):
        if key.rsplit(".", 1)[-1] not in ("unit", "units", "note", "source"):
            raise _model_error(source, key, f"must be a number or null, got {_short(value)}")
    elif isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _model_error(source, key, f"must be a number or null, got {_short(value)}")
    elif isinstance(value, float) and not np.isfinite(value):
        raise _model_error(source, key, f"must be finite, got {value}")


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _array(value, source, key: str, shape: tuple) -> np.ndarray:
    """A finite numeric array of ``shape`` (``None`` entries: any size)."""
    def numeric(v, depth=0):
        if isinstance(v, list):
            return depth < len(shape) and all(numeric(x, depth + 1) for x in v)
        return depth == len(shape) and isinstance(v, (int, float)) and not isinstance(v, bool)

    if not numeric(value):
        raise _model_error(source, key, f"must be a {len(shape)}-D list of numbers, got {_short(value)}")
    try:
        arr = np.asarray(value, dtype=float)
    except (ValueError, OverflowError):
        raise _model_error(source, key, "is not a regular array of numbers") from None
    if arr.ndim != len(shape) or any(n is not None and n != m for n, m in zip(shape, arr.shape)):
        want = " x ".join("n" if n is None else str(n) for n in shape)
        raise _model_error(source, key, f"must have shape {want}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise _model_error(source, key, "holds NaN or infinite values")
    return arr


def _check_polynomial(p, source, key: str) -> None:
    if not isinstance(p, dict):
        raise _model_error(source, key, f"must be an object, got {type(p).__name__}")
    missing = [k for k in ("n1", "n2", "terms", "coefficients", "covariance", "ci95", "centre", "scale",
                           "scaled_coefficients", "scaled_covariance", "residual_std", "dof", "n_samples",
                           "train_rmse") if k not in p]
    if missing:
        raise _model_error(source, key, f"misses {', '.join(missing)}")
    for k in ("n1", "n2", "dof", "n_samples"):
        v = _number(p[k], source, f"{key}.{k}", nonnegative=True)
        if v != int(v):
            raise _model_error(source, f"{key}.{k}", f"must be an integer, got {v}")
    terms = _array(p["terms"], source, f"{key}.terms", (None, 2))
    if np.any(terms < 0) or np.any(terms != np.round(terms)) or np.any(terms > 64):
        raise _model_error(source, f"{key}.terms", "must be pairs of small non-negative integer powers")
    n = len(terms)
    if n == 0:
        raise _model_error(source, f"{key}.terms", "is empty")
    for k in ("coefficients", "ci95", "scaled_coefficients"):
        _array(p[k], source, f"{key}.{k}", (n,))
    for k in ("covariance", "scaled_covariance"):
        _array(p[k], source, f"{key}.{k}", (n, n))
    _array(p["centre"], source, f"{key}.centre", (2,))
    scale = _array(p["scale"], source, f"{key}.scale", (2,))
    if np.any(scale == 0):
        raise _model_error(source, f"{key}.scale", "must be non-zero")
    for k in ("residual_std", "train_rmse"):
        _number(p[k], source, f"{key}.{k}", nonnegative=True)
    for k in ("name", "unit"):
        if k in p and not isinstance(p[k], str):
            raise _model_error(source, f"{key}.{k}", f"must be a string, got {type(p[k]).__name__}")


def _check_model_dict(d: dict, source) -> None:
    """Types, shapes and finiteness of every value of a model document (see
    `identify.schema.MODEL` for its required keys)."""
    try:
        schema.check_document(d, schema.MODEL, source)
    except schema.SchemaError as exc:
        raise ModelFileError(f"{exc}") from None
    missing = [k for k in ("dead_time_us", "sample_interval_us", "waveform") if k not in d]
    if missing:
        raise ModelFileError(f"{source}: invalid model file: missing key {', '.join(missing)}")
    for f in schema.MODEL.keys:  # the declared types first
        if f.name in d and f.dtype == "object" and not (d[f.name] is None and not f.required) \
                and not isinstance(d[f.name], dict):
            raise _model_error(source, f.name, f"must be an object, got {type(d[f.name]).__name__}")
    d_um = _number(d["nozzle_inner_diameter_um"], source, "nozzle_inner_diameter_um", positive=True,
                   at_most=MODEL_RANGES["nozzle_inner_diameter_um"])
    _number(d["dead_time_us"], source, "dead_time_us", nonnegative=True, at_most=MODEL_RANGES["dead_time_us"])
    _number(d["sample_interval_us"], source, "sample_interval_us", positive=True,
            at_most=MODEL_RANGES["sample_interval_us"])
    if d.get("nozzle_area_m2") is not None:  # derived: must agree with the diameter
        area = _number(d["nozzle_area_m2"], source, "nozzle_area_m2", positive=True)
        if not np.isclose(area, nozzle_area_m2(d_um), rtol=1e-6):
            raise _model_error(source, "nozzle_area_m2", f"{area:.6g} m^2 disagrees with nozzle_inner_diameter_um "
                               f"{d_um:g} (area {nozzle_area_m2(d_um):.6g} m^2)")
    w = d["waveform"]
    if not isinstance(w, dict) or "u3_um_per_ms" not in w or "hold_us" not in w:
        raise _model_error(source, "waveform", "must be an object with u3_um_per_ms and hold_us")
    _number(w["u3_um_per_ms"], source, "waveform.u3_um_per_ms", positive=True,
            at_most=MODEL_RANGES["waveform.u3_um_per_ms"])
    _number(w["hold_us"], source, "waveform.hold_us", nonnegative=True, at_most=MODEL_RANGES["waveform.hold_us"])
    e = d["ecm"]
    c = e.get("coefficients")
    if not isinstance(c, dict):
        raise _model_error(source, "ecm.coefficients", f"must be an object, got {type(c).__name__}")
    for k in COEFF_NAMES:
        if k not in c:
            raise _model_error(source, "ecm.coefficients", f"misses {k}")
        _number(c[k], source, f"ecm.coefficients.{k}")
    _check_ecm_stable(c, source)
    _optional_numbers(e.get("coefficients_ci95"), source, "ecm.coefficients_ci95")
    if e.get("coefficient_covariance") is not None:
        _array(e["coefficient_covariance"], source, "ecm.coefficient_covariance", (6, 6))
    if e.get("parameters") is not None and not isinstance(e["parameters"], dict):
        raise _model_error(source, "ecm.parameters", "must be an object or null")
    _optional_numbers(e.get("parameters"), source, "ecm.parameters")
    if e.get("level") is not None and e["level"] not in ("physical", "coefficients"):
        raise _model_error(source, "ecm.level", f"must be 'physical' or 'coefficients', got {_short(e['level'])}")
    if e.get("parameters_note") is not None and not isinstance(e["parameters_note"], str):
        raise _model_error(source, "ecm.parameters_note", "must be a string")
    if d.get("notes") is not None and (not isinstance(d["notes"], list)
                                       or not all(isinstance(x, str) for x in d["notes"])):
        raise _model_error(source, "notes", "must be a list of strings")
    for k in ("pinchoff", "volume_adjuster", "velocity_adjuster"):
        _check_polynomial(d[k], source, k)
    if d.get("training_controls") is not None:
        _array(d["training_controls"], source, "training_controls", (None, 2))
    if d.get("adjuster_reference", "ecm") not in ("ecm", "measured"):
        raise _model_error(source, "adjuster_reference", f"must be 'ecm' or 'measured', got {_short(d['adjuster_reference'])}")
    if d.get("arx_structure") is not None and not isinstance(d["arx_structure"], dict):
        raise _model_error(source, "arx_structure", "must be an object or null")
    for k in ("versions", "extra"):
        if d.get(k) is not None and not isinstance(d[k], dict):
            raise _model_error(source, k, "must be an object")
    _check_intervals(d, source)


def _check_local(loc, source, key: str) -> None:
    """The Gaussian process of the cross-validation errors (`identify.discrepancy.fit_discrepancy`)."""
    if not isinstance(loc, dict):
        raise _model_error(source, key, f"must be an object, got {type(loc).__name__}")
    missing = [k for k in ("u1_um_per_ms", "u2_um", "cv_error", "centre", "scale", "lengthscale",
                           "discrepancy_variance", "scatter_variance") if k not in loc]
    if missing:
        raise _model_error(source, key, f"misses {', '.join(missing)}")
    n = len(_array(loc["cv_error"], source, f"{key}.cv_error", (None,)))
    for k in ("u1_um_per_ms", "u2_um"):
        _array(loc[k], source, f"{key}.{k}", (n,))
    _array(loc["centre"], source, f"{key}.centre", (2,))
    for k in ("scale", "lengthscale"):
        if np.any(_array(loc[k], source, f"{key}.{k}", (2,)) <= 0):
            raise _model_error(source, f"{key}.{k}", "must be > 0")
    _number(loc["discrepancy_variance"], source, f"{key}.discrepancy_variance", nonnegative=True)
    _number(loc["scatter_variance"], source, f"{key}.scatter_variance", positive=True)
    if loc.get("likelihood_ratio") is not None:
        _number(loc["likelihood_ratio"], source, f"{key}.likelihood_ratio", nonnegative=True)


def _check_intervals(d: dict, source) -> None:
    """The optional ``intervals`` object (`fit_hybrid`): scatter per output, cross-covariance."""
    iv = d.get("intervals")
    if iv is None:
        return
    if not isinstance(iv, dict):
        raise _model_error(source, "intervals", f"must be an object, got {type(iv).__name__}")
    sc = iv.get("scatter")
    if sc is not None:
        if not isinstance(sc, dict):
            raise _model_error(source, "intervals.scatter", "must be an object")
        for k, v in sc.items():
            if not isinstance(v, dict):
                raise _model_error(source, f"intervals.scatter.{k}", "must be an object")
            for name in ("drop_std", "model_std", "cv_rmse", "in_sample_rmse"):
                if v.get(name) is not None:
                    _number(v[name], source, f"intervals.scatter.{k}.{name}", nonnegative=True)
            if v.get("dof") is not None:
                dof = _number(v["dof"], source, f"intervals.scatter.{k}.dof", positive=True)
                if dof != int(dof):
                    raise _model_error(source, f"intervals.scatter.{k}.dof", f"must be an integer, got {dof}")
            if v.get("local") is not None:
                _check_local(v["local"], source, f"intervals.scatter.{k}.local")
    m = iv.get("measurement")
    if m is not None:
        if not isinstance(m, dict):
            raise _model_error(source, "intervals.measurement", f"must be an object, got {type(m).__name__}")
        for name, v in m.items():
            if name in ("source", "note"):
                if v is not None and not isinstance(v, str):
                    raise _model_error(source, f"intervals.measurement.{name}", "must be a string")
            elif name in ("volume_rel", "velocity_rel", "pixel_size_rel"):
                if v is not None:
                    _number(v, source, f"intervals.measurement.{name}", nonnegative=True, at_most=0.5)
            elif name == "pinchoff_std_us":
                if v is not None:
                    _number(v, source, f"intervals.measurement.{name}", nonnegative=True,
                            at_most=MODEL_RANGES["dead_time_us"])
            else:
                raise _model_error(source, f"intervals.measurement.{name}", "is unknown (expected volume_rel, "
                                   "velocity_rel, pixel_size_rel, pinchoff_std_us, source)")
    fl = iv.get("flexible")
    if fl is not None:
        if not isinstance(fl, dict):
            raise _model_error(source, "intervals.flexible", f"must be an object, got {type(fl).__name__}")
        for name, p in fl.items():
            if name not in ("pinchoff", "volume_adjuster", "velocity_adjuster"):
                raise _model_error(source, f"intervals.flexible.{name}", "is unknown (expected pinchoff, "
                                   "volume_adjuster, velocity_adjuster)")
            _check_polynomial(p, source, f"intervals.flexible.{name}")
    c = iv.get("pinchoff_volume_cross_covariance")
    if c is not None:
        shape = (len(d["pinchoff"]["terms"]), len(d["volume_adjuster"]["terms"]))
        _array(c, source, "intervals.pinchoff_volume_cross_covariance", shape)


@dataclass
class FitReport:
    """Everything :func:`fit_hybrid` produced: the model and the selection tables."""

    model: HybridModel
    arx_selection: object | None
    ecm_fit: object
    pinchoff_selection: OrderSelection
    volume_selection: OrderSelection
    velocity_selection: OrderSelection
    training: pd.DataFrame  # per-sequence targets of the polynomials
    notes: list = field(default_factory=list)

    def tables(self) -> dict[str, pd.DataFrame]:
        out = {
            "pinchoff": self.pinchoff_selection.table,
            "volume_adjuster": self.volume_selection.table,
            "velocity_adjuster": self.velocity_selection.table,
        }
        if self.arx_selection is not None and getattr(self.arx_selection, "table", None) is not None:
            out["arx"] = self.arx_selection.table
        return out


# ---------------------------------------------------------------------------------------
# adapters to identify.arx_selection and identify.ecm_fit
# ---------------------------------------------------------------------------------------


def _sequences(ds: Dataset, notes: list | None = None):
    """Per usable sequence: (summary row, attached rows from delay 0 without gaps, sorted by
    delay; :func:`identify.dataset.timeseries_runs`). What was dropped goes to ``notes``."""
    from identify.dataset import timeseries_runs
    runs, why = timeseries_runs(ds)
    if notes is not None:
        notes.extend(why)
    out = []
    for _, row in ds.summary.iterrows():
        g = runs.get(row["sequence_id"])
        if g is not None:
            out.append((row, g))
    return out


def arx_sequences(ds: Dataset, notes: list | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """ARX data: u = Eq. (9) waveform without dead time sampled from the trigger, y = grown volume.

    Each sequence is cut at its last attached sample; samples start at delay 0 (missing
    leading samples are not allowed by the validator's no-gap rule only within a sequence,
    so sequences not starting at delay 0 are skipped).
    """
    h = ds.sample_interval_us
    out = []
    for row, g in _sequences(ds, notes):
        d = g["delay_us"].to_numpy(float)
        if d.size < 5 or abs(d[0]) > 1e-6:
            continue
        kp = int(round(d[-1] / h))
        u = ds.waveform(row["u1_um_per_ms"], row["u2_um"]).sampled_um(kp, h)
        out.append((u, g["grown_volume_nl"].to_numpy(float)))
    return out


def ecm_sequences(ds: Dataset, notes: list | None = None) -> list[dict]:
    """ECM identification data of a dataset, one dict per sequence.

    Parameters
    ----------
    ds : Dataset

    Returns
    -------
    list of dict
        The fields of :class:`identify.ecm_fit.EcmData`: ``t_us`` (attached sample delays
        from the trigger, µs), ``u_um`` (waveform delayed by the dead time, µm),
        ``volume_nl`` (grown volume, nl), ``pinchoff_volume_nl`` (nl),
        ``pinchoff_displacement_um`` (µm), ``u1_um_per_ms``, ``u2_um``.
    """
    out = []
    for row, g in _sequences(ds, notes):
        w = ds.waveform(row["u1_um_per_ms"], row["u2_um"])
        t = g["delay_us"].to_numpy(float)
        vol = g["grown_volume_nl"].to_numpy(float)
        # y_ss, K_ss of Eq. (13) (delta method only): the last sample where pinch-off was not seen
        y_ss = float(row["grown_volume_at_pinchoff_nl"])
        t_ss = float(row["pinchoff_us"])
        if not np.isfinite(y_ss) or not np.isfinite(t_ss):
            y_ss, t_ss = float(vol[-1]), float(t[-1])
        out.append({
            "t_us": t,
            "u_um": w.displacement_um(t - ds.dead_time_us),
            "volume_nl": vol,
            "pinchoff_volume_nl": y_ss,
            "pinchoff_displacement_um": float(w.displacement_um(t_ss - ds.dead_time_us)),
            "u1_um_per_ms": float(row["u1_um_per_ms"]),
            "u2_um": float(row["u2_um"]),
        })
    return out


def _fit_ecm(ds: Dataset, method: str, notes: list):
    """Fit the ECM through :func:`identify.ecm_fit.fit_ecm` (Section 4.3)."""
    from identify.dataset import DatasetError
    from identify.ecm_fit import EcmData, fit_ecm
    hyd = _hydraulics_or_none(ds)
    data = [EcmData(**s) for s in ecm_sequences(ds, notes)]
    if not data:
        raise DatasetError(f"{ds.json_name}: no sequence usable for the ECM (see the notes: {'; '.join(notes)})")
    if hyd is None:
        notes.append("ECM level: coefficients: A3..B0 fitted directly (output error, scale A3 = 1); physical "
                     "parameters La, Ra, CN, Kc not identifiable: dataset.json lacks the ink (density_kg_m3, "
                     "viscosity_mPa_s) or the nozzle geometry (length_mm, reservoir_channel_radius_um, "
                     "reservoir_channel_length_mm) of Eq. (2)")
        if method != "oe":
            notes.append(f"ECM method {method!r} needs the hydraulics of Eq. (2): output error ('oe') used instead")
        return fit_ecm(data, None, method="oe")
    notes.append(f"ECM level: physical: Ra, CN, Kc fitted given the hydraulics of Eq. (2) (method {method!r})")
    return fit_ecm(data, hyd, method=method)


def _hydraulics_or_none(ds: Dataset):
    """The hydraulics of Eq. (2), or None where the ink or any nozzle dimension is missing."""
    ink, noz = ds.ink or {}, ds.nozzle or {}
    if not all(ink.get(k) is not None for k in ("density_kg_m3", "viscosity_mPa_s")) or \
            not all(noz.get(k) is not None for k in ("length_mm", "reservoir_channel_radius_um",
                                                      "reservoir_channel_length_mm")):
        return None
    return ds.hydraulics()


def _arx_select(ds: Dataset, notes: list, ranges: dict | None, folds: int, progress: bool):
    from identify.arx_selection import grid_for_dead_time, select_structure
    seqs = arx_sequences(ds)  # what was dropped is noted once, by the ECM fit
    if len(seqs) < 2:
        notes.append("ARX structure selection skipped: fewer than 2 sequences start at delay 0")
        return None
    # identify.arx_selection.DEFAULT_GRID (Table 2 and beyond), its delays extended past the
    # dead time if that is longer; the delay is found from the data, not assumed from dataset.json.
    nk0 = int(round(ds.dead_time_us / ds.sample_interval_us))
    r = grid_for_dead_time(nk0)._asdict()
    r.update(ranges or {})
    return select_structure(seqs, r["na_range"], r["nb_range"], r["nk_range"], folds=min(folds, len(seqs)), seed=0)


def _param_dict(fit) -> dict | None:
    p = getattr(fit, "parameters", None)
    if p is None:
        return None
    ci = getattr(fit, "param_ci95", None) or {}
    pd_ = p.to_dict() if hasattr(p, "to_dict") else dict(p)
    out = {}
    for k, v in pd_.items():
        # the parameter's own 95 % interval (named, no bare low/high: issue 19)
        entry = {"value": float(v), "ci95_low": None, "ci95_high": None}
        c = ci.get(k)
        if c is not None and np.ndim(c) == 1 and len(c) == 2:  # (low, high)
            entry["ci95_low"], entry["ci95_high"] = float(c[0]), float(c[1])
        elif c is not None and np.ndim(c) == 0:  # half-width
            entry["ci95_low"], entry["ci95_high"] = float(v) - float(c), float(v) + float(c)
        out[k] = entry
    return out


# ---------------------------------------------------------------------------------------
# fitting
# ---------------------------------------------------------------------------------------


def _cross_covariance(a: PolynomialFit, b: PolynomialFit, u1, u2, ra, rb) -> np.ndarray:
    """Covariance of the scaled coefficients of two least-squares polynomials fitted on the same
    (u1, u2) with correlated residuals ``ra``, ``rb`` (per point, one common correlation)."""
    Xa = design_matrix(*a.normalised(u1, u2), a.terms)
    Xb = design_matrix(*b.normalised(u1, u2), b.terms)
    dof = max(1, len(u1) - max(len(a.terms), len(b.terms)))
    s_ab = float(ra @ rb) / dof
    return s_ab * (np.linalg.pinv(Xa) @ np.linalg.pinv(Xb).T)


def _fit_intervals(model: HybridModel, u1, u2, measured: dict, vol_target, vel_target, *, folds: int,
                   seed: int, notes: list, mc_samples: int = 400, standard_errors: dict | None = None,
                   measurement: dict | None = None, flexible: dict | None = None) -> dict:
    """Scatter of individual drops about the model, for `HybridModel.interval_prediction`.

    Per output (:data:`INTERVAL_OUTPUTS`):

    * ``drop_std``: drop-to-drop scatter: pooled standard deviation of repeated measurements
      of one (u1, u2) when the data have repeats; else, where every sequence carries its own
      standard error (``standard_errors``, :func:`identify.dataset.sequence_standard_errors`:
      an image-measured campaign), their RMS (source ``sequence_se``): the residuals then also
      hold the model's lack of fit, which is the same for every drop at one (u1, u2) and goes to
      ``model_std`` (confidence) instead of being taken for drop scatter; else the residual
      standard deviation of the whole hybrid chain at the training points (residual sum of
      squares / (n - p), p the coefficients of the output's own polynomial; source
      ``residuals``), unless those residuals hold a smooth departure from the chosen polynomial
      (a law it lacks): then the scatter about polynomial + smooth departure
      (:func:`identify.discrepancy.smooth_scatter_variance`, restricted maximum likelihood,
      kept only where the likelihood ratio says so; source ``smooth_scatter``), so that the
      misfit is not taken for drop scatter, which would leave the mean-drop interval too narrow
      where the laws are not polynomials of the chosen order; ``dof`` its degrees of freedom;
    * ``cv_rmse``: RMS error of the whole chain predicting held-out measured drops in grouped
      K-fold cross-validation (polynomials of the chosen orders refitted per fold, ECM kept);
    * ``model_std``: model discrepancy: sqrt(max(0, cv_rmse^2 - drop_std^2 - mean parameter
      variance at the training controls)): what cross-validation sees beyond the noise and
      the parameter uncertainty (e.g. a bias of the ECM or a law no polynomial holds);
    * ``local``: a Gaussian process of the cross-validation errors over (u1, u2)
      (:func:`identify.discrepancy.fit_discrepancy`, only where its discrepancy variance is not
      zero), so that `local_model_std` widens the interval where the misfit concentrates (a
      corner, a feature of the law) rather than spreading it evenly.

    Also ``pinchoff_volume_cross_covariance`` (see
    :func:`identify.montecarlo.pinchoff_volume_cross_covariance`) and ``measurement`` (the
    systematic measurement uncertainty, :func:`identify.dataset.measurement_uncertainty`).
    """
    from dataclasses import replace

    from identify.discrepancy import SCATTER_LIKELIHOOD_RATIO_THRESHOLD, fit_discrepancy, smooth_scatter_variance

    fits = {"pinchoff_us": model.pinchoff, "inflight_volume_nl": model.volume_adjuster,
            "jetting_velocity_m_s": model.velocity_adjuster}
    n = len(u1)
    pred = model.predict_grid(u1, u2)
    r_p = measured["pinchoff_us"] - model.pinchoff.predict(u1, u2)
    r_v = vol_target - model.volume_adjuster.predict(u1, u2)
    cross = _cross_covariance(model.pinchoff, model.volume_adjuster, u1, u2, r_p, r_v) \
        if model.adjuster_reference == "ecm" else np.zeros((len(model.pinchoff.terms), len(model.volume_adjuster.terms)))
    out = {"method": "mean drop (confidence): parameter Monte Carlo + model_std (local where cross-validation "
                     "sees uneven misfit) + measurement; one drop (prediction): mean drop + drop_std",
           "pinchoff_volume_cross_covariance": cross.tolist(), "scatter": {}}
    model.intervals = {"pinchoff_volume_cross_covariance": out["pinchoff_volume_cross_covariance"]}
    # grouped K-fold CV of the whole chain
    groups = np.column_stack([u1, u2])
    cv_err = {k: np.full(n, np.nan) for k in INTERVAL_OUTPUTS}
    targets = {"pinchoff": measured["pinchoff_us"], "volume_adjuster": vol_target, "velocity_adjuster": vel_target}
    for idx in grouped_kfold(groups, folds, seed, layout="round_robin"):
        train = np.setdiff1d(np.arange(n), idx)
        try:
            polys = {k: fit_polynomial(u1[train], u2[train], targets[k][train], getattr(model, k).n1,
                                       getattr(model, k).n2, name=k) for k in targets}
        except PolynomialRankError:
            continue
        g = replace(model, **polys).predict_grid(u1[idx], u2[idx])
        for k in INTERVAL_OUTPUTS:
            cv_err[k][idx] = g[k].to_numpy() - measured[k][idx]
    # parameter variance at the training controls
    ctrl, inv, counts = np.unique(groups, axis=0, return_inverse=True, return_counts=True)
    inv = np.asarray(inv).ravel()
    var_mc = {k: np.empty(len(ctrl)) for k in INTERVAL_OUTPUTS}
    for j, (a, b) in enumerate(ctrl):
        res = model.monte_carlo(a, b, samples=mc_samples, seed=seed)
        for k in INTERVAL_OUTPUTS:
            var_mc[k][j] = np.var(res.samples[k], ddof=1)
    rep_dof = int(np.sum(counts - 1))
    for k in INTERVAL_OUTPUTS:
        y = np.asarray(measured[k], float)
        resid = y - pred[k].to_numpy()
        p = len(fits[k].terms)
        se = None if standard_errors is None else standard_errors.get(k)
        if rep_dof >= 2:
            means = np.bincount(inv, weights=y) / counts
            drop_var, dof, source = float(np.sum((y - means[inv]) ** 2) / rep_dof), rep_dof, "repeats"
        elif se is not None and np.all(np.isfinite(se)):
            # within-sequence noise; the residual dof keep the Student-t of the prediction modest
            drop_var, dof, source = float(np.mean(np.asarray(se, float) ** 2)), max(1, n - p), "sequence_se"
        else:
            dof = max(1, n - p)
            drop_var, source = float(resid @ resid) / dof, "residuals"
            est = smooth_scatter_variance(u1, u2, resid, design_matrix(*fits[k].normalised(u1, u2), fits[k].terms),
                                          seed=seed)
            if est is not None and est[2] >= SCATTER_LIKELIHOOD_RATIO_THRESHOLD and est[0] < drop_var:
                drop_var, source = est[0], "smooth_scatter"
        e = cv_err[k]
        ok = np.isfinite(e)
        cv_mse = float(np.mean(e[ok] ** 2)) if ok.any() else float("nan")
        model_var = max(0.0, cv_mse - drop_var - float(np.mean(var_mc[k]))) if ok.any() else 0.0
        if source == "sequence_se":  # lack of fit seen in-sample counts too (at least)
            model_var = max(model_var, float(resid @ resid) / max(1, n - p) - drop_var)
        entry = {"drop_std": float(np.sqrt(drop_var)), "dof": int(dof), "source": source,
                 "model_std": float(np.sqrt(model_var)),
                 "cv_rmse": float(np.sqrt(cv_mse)) if ok.any() else None,
                 "in_sample_rmse": float(np.sqrt(np.mean(resid**2)))}
        gp = fit_discrepancy(u1[ok], u2[ok], e[ok], seed=seed) if ok.sum() >= 6 else None
        if gp is not None and gp["discrepancy_variance"] > 0:
            entry["local"] = gp
        out["scatter"][k] = entry
        if not ok.any():
            notes.append(f"{k}: no cross-validation fold could be fitted; model_std set to 0")
    if measurement is not None:
        out["measurement"] = dict(measurement)
    if flexible:
        out["flexible"] = {name: f.to_dict() for name, f in flexible.items()}
        notes.append("intervals: the chosen polynomials' bias is estimated against more flexible ones (" +
                      ", ".join(f"{name} order ({f.n1}, {f.n2})" for name, f in flexible.items()) +
                      "); where it exceeds the model discrepancy at a control, it replaces it (model_std_source "
                      "'polynomial_bias')")
    notes.extend(_interval_notes(out["scatter"], fits))
    return out


def _flexible_fits(u1, u2, chosen: dict) -> dict:
    """Per polynomial name, the flexible polynomial (:func:`identify.discrepancy.flexible_order`)
    fitted to the chosen one's targets and controls, where it differs from the chosen order and
    leaves :data:`identify.discrepancy.MIN_FLEXIBLE_DOF` residual degrees of freedom."""
    from identify.discrepancy import MIN_FLEXIBLE_DOF, flexible_order
    from identify.polynomial import poly_terms

    out = {}
    for name, (fit, mask, z) in chosen.items():
        n1, n2 = flexible_order(fit)
        if (n1, n2) == (fit.n1, fit.n2) or int(mask.sum()) - len(poly_terms(n1, n2)) < MIN_FLEXIBLE_DOF:
            continue
        try:
            out[name] = fit_polynomial(u1[mask], u2[mask], z[mask], n1, n2, name=name, unit=fit.unit)
        except PolynomialRankError:
            continue
    return out


def _order_note(sel: OrderSelection) -> str:
    """What `select_order` chose and why, with the misfit in mind."""
    t = sel.table.dropna(subset=["val_rmse"])
    chosen = t[t.selected].iloc[0]
    best = t.sort_values("val_rmse").iloc[0]
    text = (f"{sel.name}: order {sel.selected} ({int(chosen.n_terms)} terms) chosen by {len(sel.table)}-candidate "
            f"cross-validation: validation RMSE {chosen.val_rmse:.4g}")
    if (int(best.n1), int(best.n2)) == sel.selected:
        return text + ", the least of all candidates"
    return (text + f" within 5 % of the least, {best.val_rmse:.4g} of order ({int(best.n1)}, {int(best.n2)}) with "
            f"{int(best.n_terms)} terms: the fewer terms are preferred (stabler coefficients, the paper's rule); the "
            "misfit they may leave is what the intervals' model discrepancy carries (below)")


def _interval_notes(scatter: dict, fits: dict) -> list:
    """One sentence per output: the chosen order, the drop scatter, the discrepancy and why."""
    lines = []
    for k, sc in scatter.items():
        f = fits[k]
        why = {"repeats": "pooled over repeated controls",
               "sequence_se": "the sequences' own standard errors",
               "smooth_scatter": "the scatter about the chosen polynomial plus a smooth (Gaussian-process) "
                                 "departure that the residuals show (restricted maximum likelihood), so that the "
                                 "misfit of the chosen order is not taken for drop scatter",
               "residuals": "residuals of the fit"}[sc["source"]]
        loc = sc.get("local")
        uneven = ""
        if loc:
            hot = _local_hotspots(sc)
            uneven = (f"; the cross-validated misfit is uneven: the mean-drop interval widens locally near "
                      f"{hot}" if hot else "; the cross-validated misfit is even over the training controls "
                      "(no local widening)")
        lines.append(f"intervals {k} (polynomial order ({f.n1}, {f.n2})): drop scatter {sc['drop_std']:.3g} from {why}; "
                     f"model discrepancy {sc['model_std']:.3g} (cross-validation RMSE {sc['cv_rmse'] or float('nan'):.3g} "
                     f"beyond drop scatter and parameter uncertainty){uneven}")
    return lines


def _local_hotspots(scatter: dict, top: int = 3) -> str:
    """Training controls where `local_model_std` exceeds the global model_std, as text."""
    loc = scatter["local"]
    pts = sorted({(a, b) for a, b in zip(loc["u1_um_per_ms"], loc["u2_um"])})
    rows = []
    for a, b in pts:
        s, src = local_model_std(scatter, a, b)
        if src == "local":
            rows.append((s, a, b))
    rows.sort(reverse=True)
    return ", ".join(f"({a:g}, {b:g})" for _, a, b in rows[:top]) + (f" and {len(rows) - top} more" if len(rows) > top else "")


def _fitted_controls(u1, u2, masks: dict, notes: list) -> np.ndarray:
    """Distinct (u1, u2) where every polynomial had a usable sequence: the training region of
    `identify.design` (a control whose only sequences the fits dropped is not part of it)."""
    every = np.unique(np.column_stack([u1, u2]), axis=0)
    keep = np.ones(len(every), bool)
    for m in masks.values():
        have = {tuple(c) for c in np.column_stack([u1[m], u2[m]])}
        keep &= np.array([tuple(c) in have for c in every], bool)
    if not keep.all():
        eg = ", ".join(f"({a:g}, {b:g})" for a, b in every[~keep][:3])
        notes.append(f"training region: {int((~keep).sum())} (u1, u2) without a usable sequence for every "
                     f"polynomial left out of training_controls (e.g. {eg})")
    return every[keep]


def fit_hybrid(
    ds: Dataset, *, orders=DEFAULT_ORDERS, folds: int = 10, seed: int = 0, ecm_method: str = "oe",
    adjuster_reference: str = "ecm", arx: bool = True, arx_ranges: dict | None = None,
    progress: bool = False, measurement: dict | None = None,
) -> FitReport:
    """Identify the hybrid model of Eq. (8) from a validated dataset.

    Steps: ARX structure selection (Section 4.2, reported only), ECM identification
    (Section 4.3, through :mod:`identify.ecm_fit`), then 10-fold CV order selection and
    fits of the pinch-off polynomial and the two adjusters (Section 4.4).

    Level of prior knowledge: with the ink and the full nozzle geometry in ``dataset.json`` the
    physical parameters are fitted (``ecm.level == "physical"``); otherwise the coefficients
    A3..B0 directly (``"coefficients"``, :func:`identify.ecm_fit.fit_ecm_coefficients`).
    Irregular campaigns: each fit uses what it can (:func:`identify.dataset.timeseries_runs`,
    :func:`identify.dataset.summary_usable`); ``FitReport.notes`` (and ``notes`` of model.json)
    say what was dropped and why.

    Intervals: ``model.intervals["measurement"]`` is the systematic measurement uncertainty of
    :func:`identify.dataset.measurement_uncertainty` (dataset.json, the campaign's pixel-size
    check, or documented defaults), or ``measurement`` when given: a dict like dataset.json's
    ``measurement_uncertainty`` (``volume_rel`` and ``velocity_rel``, optional
    ``pinchoff_std_us``, ``source``). Training controls (the region of `identify.design`): only
    the (u1, u2) where every polynomial had a usable sequence.
    """
    import pandas as pd

    from identify.dataset import DatasetError, check_measurement_block, measurement_uncertainty, \
        sequence_standard_errors, summary_usable
    from tqdm import tqdm

    if adjuster_reference not in ("ecm", "measured"):
        raise ValueError(f"adjuster_reference must be 'ecm' or 'measured', got {adjuster_reference!r}")
    notes: list = []
    bar = tqdm(total=5, desc="identify fit", disable=not progress, leave=False)
    arx_sel = _arx_select(ds, notes, arx_ranges, folds, progress) if arx else None
    bar.update(1)
    efit = _fit_ecm(ds, ecm_method, notes)
    bar.update(1)
    c_arr = efit.coefficients.to_array()[None, :]
    modal = modal_form(c_arr)
    su = ds.summary
    masks, su_notes = summary_usable(ds, adjuster_reference)
    notes.extend(su_notes)
    u1 = su["u1_um_per_ms"].to_numpy(float)
    u2 = su["u2_um"].to_numpy(float)
    tp = su["pinchoff_us"].to_numpy(float)
    inflight = su["inflight_volume_nl"].to_numpy(float)
    jet = su["jetting_velocity_m_s"].to_numpy(float)
    v_ecm = np.full(len(su), np.nan)
    q_ecm = np.empty(len(su))
    for i in range(len(su)):
        w = ds.waveform(u1[i], u2[i])
        if np.isfinite(tp[i]):
            v_ecm[i] = ecm_response_at(modal, w, np.array([tp[i] - ds.dead_time_us]))[0][0]
        q_ecm[i] = ecm_response_at(modal, w, np.array([w.max_stroke_us]))[1][0]
    vel_ecm = flow_velocity_m_s(q_ecm, ds.nozzle_inner_diameter_um)
    if adjuster_reference == "ecm":
        vol_target = inflight - v_ecm
        vel_target = jet - vel_ecm
    else:
        meas_vel = su["flow_velocity_at_max_stroke_m_s"].to_numpy(float)
        if not np.any(np.isfinite(meas_vel)):
            raise DatasetError(
                f"{ds.path or '.'}/summary.parquet: column flow_velocity_at_max_stroke_m_s has only NaN; "
                "it is needed with adjuster_reference='measured'"
            )
        vol_target = inflight - su["grown_volume_at_pinchoff_nl"].to_numpy(float)
        vel_target = jet - meas_vel
    kw = dict(orders=orders, folds=folds, seed=seed)
    for name, m in masks.items():
        n_ctrl = len(np.unique(np.column_stack([u1[m], u2[m]]), axis=0)) if m.any() else 0
        if n_ctrl < 3:
            raise DatasetError(f"{ds.path or '.'}/summary.parquet: only {n_ctrl} distinct (u1_um_per_ms, u2_um) "
                               f"pair(s) usable for the {name} polynomial; it needs at least 3")
    mp, mv, mq = masks["pinchoff"], masks["volume_adjuster"], masks["velocity_adjuster"]
    sel_p = select_order(u1[mp], u2[mp], tp[mp], name="pinchoff", unit="us", **kw)
    bar.update(1)
    sel_v = select_order(u1[mv], u2[mv], vol_target[mv], name="volume_adjuster", unit="nl", **kw)
    bar.update(1)
    sel_q = select_order(u1[mq], u2[mq], vel_target[mq], name="velocity_adjuster", unit="m/s", **kw)
    bar.update(1)
    notes.extend(_order_note(sel) for sel in (sel_p, sel_v, sel_q))
    flexible = _flexible_fits(u1, u2, {"pinchoff": (sel_p.fit, mp, tp), "volume_adjuster": (sel_v.fit, mv, vol_target),
                                       "velocity_adjuster": (sel_q.fit, mq, vel_target)})
    bar.close()
    versions = software_versions()
    versions["identify"] = __version__
    arx_struct = None
    if arx_sel is not None and getattr(arx_sel, "selected", None) is not None:
        na, nb, nk = arx_sel.selected
        arx_struct = {"na": int(na), "nb": int(nb), "nk": int(nk)}
    cov = getattr(efit, "coeff_cov", None)
    model = HybridModel(
        dead_time_us=ds.dead_time_us, sample_interval_us=ds.sample_interval_us,
        nozzle_inner_diameter_um=ds.nozzle_inner_diameter_um, u3_um_per_ms=ds.u3_um_per_ms, hold_us=ds.hold_us,
        ecm_coefficients=EcmCoefficients(*c_arr[0]),
        ecm_coeff_cov=None if cov is None else np.asarray(cov, float),
        pinchoff=sel_p.fit, volume_adjuster=sel_v.fit, velocity_adjuster=sel_q.fit,
        arx_structure=arx_struct, ecm_parameters=_param_dict(efit), controls=_fitted_controls(u1, u2, masks, notes),
        adjuster_reference=adjuster_reference, versions=versions,
        extra={"ecm_method": ecm_method, "notes": notes, "n_sequences": ds.n_sequences},
        ecm_level=efit.level, notes=notes,
    )
    mall = mp & mv & mq
    if not mall.all():
        notes.append(f"intervals: drop scatter and cross-validation from the {int(mall.sum())} of {len(mall)} "
                     "sequences with every summary value")
    ses = {k: v[mall] for k, v in sequence_standard_errors(ds).items()}
    if measurement is None:
        meas = measurement_uncertainty(ds)
    else:
        meas = check_measurement_block(measurement, "fit_hybrid(measurement=...)")
        if "volume_rel" not in meas or "velocity_rel" not in meas:
            raise ValueError("fit_hybrid(measurement=...): needs volume_rel and velocity_rel")
        meas.setdefault("pinchoff_std_us", 0.0)
        meas["source"] = "given to fit_hybrid" + (f": {meas['source']}" if meas.get("source") else "")
    notes.append(f"intervals: systematic measurement uncertainty volume {100 * meas['volume_rel']:.3g} %, velocity "
                 f"{100 * meas['velocity_rel']:.3g} %, pinch-off {meas.get('pinchoff_std_us') or 0:.3g} us "
                 f"({meas['source']})")
    model.intervals = _fit_intervals(model, u1[mall], u2[mall],
                                     {"pinchoff_us": tp[mall], "inflight_volume_nl": inflight[mall],
                                      "jetting_velocity_m_s": jet[mall]}, vol_target[mall], vel_target[mall],
                                     folds=folds, seed=seed, notes=notes, standard_errors=ses,
                                     measurement=meas, flexible=flexible)
    training = pd.DataFrame({
        "sequence_id": su["sequence_id"].to_numpy(), "u1_um_per_ms": u1, "u2_um": u2, "pinchoff_us": tp,
        "ecm_grown_volume_at_pinchoff_nl": v_ecm, "ecm_flow_velocity_at_max_stroke_m_s": vel_ecm,
        "volume_adjustment_nl": vol_target, "velocity_adjustment_m_s": vel_target,
    })
    return FitReport(model=model, arx_selection=arx_sel, ecm_fit=efit, pinchoff_selection=sel_p,
                     volume_selection=sel_v, velocity_selection=sel_q, training=training, notes=notes)


__all__ = ["HybridModel", "FitReport", "fit_hybrid", "ModelFileError", "OUTPUTS", "describe_measurement",
           "widening_reason", "local_model_std"]
