"""Fitting the hybrid model (Eq. 8) to a dataset: ECM, polynomial orders by cross-validation,
and what the intervals need (drop scatter, model discrepancy, the flexible polynomials);
:func:`fit_hybrid` returns the :class:`identify.hybrid.HybridModel` in a :class:`FitReport`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from dvcore import __version__
from identify.ecm import EcmCoefficients, flow_velocity_m_s
from identify.hybrid import INTERVAL_OUTPUTS, HybridModel, local_model_std
from identify.kfold import grouped_kfold
from identify.montecarlo import ecm_response_at, modal_form
from identify.polynomial import DEFAULT_ORDERS, OrderSelection, PolynomialFit, PolynomialRankError, \
    design_matrix, fit_polynomial, select_order
from dvcore.versions import software_versions

if TYPE_CHECKING:
    import pandas as pd

    from identify.dataset import Dataset


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
    delay; :func:`identify.dataset_checks.timeseries_runs`). What was dropped goes to ``notes``."""
    from identify.dataset_checks import timeseries_runs
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


def _leverage(fit, u1_train, u2_train, u1, u2) -> np.ndarray:
    """x (XᵀX)⁻¹ xᵀ at (u1, u2) of a `PolynomialFit`'s terms fitted at (u1_train, u2_train)."""
    X = design_matrix(*fit.normalised(u1_train, u2_train), fit.terms)
    x = design_matrix(*fit.normalised(u1, u2), fit.terms)
    return np.einsum("ij,ij->i", x, np.linalg.lstsq(X.T @ X, x.T, rcond=None)[0].T)


#: Per output, the polynomials of the hybrid chain it depends on (volume: pinch-off and adjuster),
#: and the output's own polynomial (whose terms count against the residual degrees of freedom).
POLYNOMIALS_OF = {"pinchoff_us": ("pinchoff",), "inflight_volume_nl": ("pinchoff", "volume_adjuster"),
                  "jetting_velocity_m_s": ("velocity_adjuster",)}
OWN_POLYNOMIAL = {"pinchoff_us": "pinchoff", "inflight_volume_nl": "volume_adjuster",
                  "jetting_velocity_m_s": "velocity_adjuster"}


def _flexible_scatter(model: HybridModel, flexible: dict | None, output: str, u1, u2, y) -> tuple[float, int] | None:
    """Residual variance of ``output`` at the training controls when the flexible reference
    polynomials (``flexible``, :func:`_flexible_fits`) replace the chosen ones in the chain
    (:data:`POLYNOMIALS_OF`), and its degrees of freedom (n minus the terms of the output's own
    flexible polynomial); None where the output's own polynomial has no flexible reference."""
    from dataclasses import replace

    own = OWN_POLYNOMIAL[output]
    if not flexible or own not in flexible:
        return None
    ref = replace(model, **{name: flexible[name] for name in POLYNOMIALS_OF[output] if name in flexible})
    r = np.asarray(y, float) - ref.predict_grid(u1, u2)[output].to_numpy()
    dof = len(r) - len(flexible[own].terms)
    return (float(r @ r) / dof, int(dof)) if dof >= 1 else None


def _cv_chain_errors(model: HybridModel, u1, u2, measured: dict, targets: dict, *, folds: int, seed: int):
    """Grouped K-fold cross-validation of the whole chain: per output the error at each training
    control (nan where no fold was fitted), and per output the leverage of the folds' polynomials
    that predicted each control (averaged over its polynomials) and its ratio to the full fit's."""
    from dataclasses import replace

    n = len(u1)
    groups = np.column_stack([u1, u2])
    cv_err = {k: np.full(n, np.nan) for k in INTERVAL_OUTPUTS}
    # leverage at each training control of the fold's polynomial that predicted it, and of the full fit
    h_fold = {k: np.full(n, np.nan) for k in targets}
    h_full = {k: _leverage(getattr(model, k), u1, u2, u1, u2) for k in targets}
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
        for k in targets:
            h_fold[k][idx] = _leverage(polys[k], u1[train], u2[train], u1[idx], u2[idx])
    # per output, the polynomials its parameter variance comes from (volume: both, averaged)
    fold_leverage = {k: np.mean([h_fold[name] for name in ps], axis=0) for k, ps in POLYNOMIALS_OF.items()}
    fold_ratio = {k: np.mean([h_fold[name] / h_full[name] for name in ps], axis=0) for k, ps in POLYNOMIALS_OF.items()}
    return cv_err, fold_leverage, fold_ratio


def _control_mc_variance(model: HybridModel, ctrl: np.ndarray, mc_samples: int, seed: int) -> dict:
    """Per output, the parameter Monte Carlo variance at each training control."""
    var_mc = {k: np.empty(len(ctrl)) for k in INTERVAL_OUTPUTS}
    for j, (a, b) in enumerate(ctrl):
        res = model.monte_carlo(a, b, samples=mc_samples, seed=seed)
        for k in INTERVAL_OUTPUTS:
            var_mc[k][j] = np.var(res.samples[k], ddof=1)
    return var_mc


def _drop_scatter(model: HybridModel, k: str, fit, u1, u2, y, resid, *, rep_dof: int, inv, counts, se,
                  flexible, seed: int) -> tuple[float, int, str]:
    """Output ``k``'s drop-to-drop variance, its degrees of freedom and its source
    (`_fit_intervals`' ``drop_std``)."""
    from identify.discrepancy import SCATTER_LIKELIHOOD_RATIO_THRESHOLD, smooth_scatter_variance

    n, p = len(u1), len(fit.terms)
    if rep_dof >= 2:
        means = np.bincount(inv, weights=y) / counts
        return float(np.sum((y - means[inv]) ** 2) / rep_dof), rep_dof, "repeats"
    if se is not None and np.all(np.isfinite(se)):
        # within-sequence noise; the residual dof keep the Student-t of the prediction modest
        return float(np.mean(np.asarray(se, float) ** 2)), max(1, n - p), "sequence_se"
    dof = max(1, n - p)
    drop_var, source = float(resid @ resid) / dof, "residuals"
    est = smooth_scatter_variance(u1, u2, resid, design_matrix(*fit.normalised(u1, u2), fit.terms), seed=seed)
    if est is not None and est[2] >= SCATTER_LIKELIHOOD_RATIO_THRESHOLD and est[0] < drop_var:
        drop_var, source = est[0], "smooth_scatter"
    flex = _flexible_scatter(model, flexible, k, u1, u2, y)
    if flex is not None and flex[0] < drop_var:
        drop_var, dof, source = flex[0], flex[1], "flexible_residuals"
    return drop_var, dof, source


def _reference_notes(flexible, flexible_u1) -> list[str]:
    """The notes on the flexible references the chosen polynomials' bias is estimated against."""
    notes = []
    if flexible:
        notes.append("intervals: the chosen polynomials' bias is estimated against more flexible ones (" +
                     ", ".join(f"{name} order ({f.n1}, {f.n2})" for name, f in flexible.items()) +
                     "); where it exceeds the model discrepancy at a control, it replaces it (model_std_source "
                     "'polynomial_bias')")
    if flexible_u1:
        notes.append("intervals: and against references flexible in u1 (" +
                     ", ".join(f"{name} order ({f.n1}, {f.n2})" for name, f in flexible_u1.items()) +
                     "), counted at a control where that bias is significant (pointwise test at 5 %); "
                     "then per output the larger of the two references' biases is used")
    return notes


def _fit_intervals(model: HybridModel, u1, u2, measured: dict, vol_target, vel_target, *, folds: int,
                   seed: int, notes: list, mc_samples: int = 400, standard_errors: dict | None = None,
                   measurement: dict | None = None, flexible: dict | None = None,
                   flexible_u1: dict | None = None) -> dict:
    """Scatter of individual drops about the model, for `HybridModel.interval_prediction`.

    Per output (:data:`INTERVAL_OUTPUTS`):

    * ``drop_std``: drop-to-drop scatter: pooled standard deviation of repeated measurements
      of one (u1, u2) when the data have repeats; else, where every sequence carries its own
      standard error (``standard_errors``, :func:`identify.measurement_uncertainty.sequence_standard_errors`:
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
    * ``model_std``: model discrepancy: what cross-validation sees beyond the noise and the
      parameter uncertainty (e.g. a bias of the ECM or a law no polynomial holds), as the misfit
      of the full fit: sqrt(max(0, mean_i (e_i^2 - drop_std^2 - v_i) / (1 + h_i)^2)), e_i the
      cross-validation error at training control i, v_i the parameter variance there of the
      fold that predicted it (the full model's Monte Carlo variance times the ratio of the
      fold's leverage to the full fit's), h_i the fold's leverage x (X_fᵀX_f)⁻¹ xᵀ there. For
      leave-one-out least squares e_i = r_i / (1 - h_full,i) and 1 / (1 - h_full,i) = 1 + h_i
      exactly, so the fold's misfit at a control it does not hold (an edge it extrapolates to)
      is carried back to the full fit's (:func:`identify.discrepancy.cv_misfit_variance`);
    * ``local``: a Gaussian process of the cross-validation errors over (u1, u2)
      (:func:`identify.discrepancy.fit_discrepancy`, only where its discrepancy variance is not
      zero), so that `local_model_std` widens the interval where the misfit concentrates (a
      corner, a feature of the law) rather than spreading it evenly.

    Also ``pinchoff_volume_cross_covariance`` (see
    :func:`identify.montecarlo.pinchoff_volume_cross_covariance`) and ``measurement`` (the
    systematic measurement uncertainty, :func:`identify.measurement_uncertainty.measurement_uncertainty`).
    """
    from identify.discrepancy import cv_misfit_variance, fit_discrepancy

    fits = {k: getattr(model, name) for k, name in OWN_POLYNOMIAL.items()}
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
    targets = {"pinchoff": measured["pinchoff_us"], "volume_adjuster": vol_target, "velocity_adjuster": vel_target}
    cv_err, fold_leverage, fold_ratio = _cv_chain_errors(model, u1, u2, measured, targets, folds=folds, seed=seed)
    # parameter variance at the training controls
    ctrl, inv, counts = np.unique(np.column_stack([u1, u2]), axis=0, return_inverse=True, return_counts=True)
    inv = np.asarray(inv).ravel()
    var_mc = _control_mc_variance(model, ctrl, mc_samples, seed)
    rep_dof = int(np.sum(counts - 1))
    for k in INTERVAL_OUTPUTS:
        y = np.asarray(measured[k], float)
        resid = y - pred[k].to_numpy()
        p = len(fits[k].terms)
        se = None if standard_errors is None else standard_errors.get(k)
        drop_var, dof, source = _drop_scatter(model, k, fits[k], u1, u2, y, resid, rep_dof=rep_dof, inv=inv,
                                              counts=counts, se=se, flexible=flexible, seed=seed)
        e = cv_err[k]
        ok = np.isfinite(e)
        cv_mse = float(np.mean(e[ok] ** 2)) if ok.any() else float("nan")
        # the fold's parameter variance at its held-out control (not the full model's: a fold lacks
        # the point it predicts, and at the edge of the grid it extrapolates); ok: a fold was fitted
        fold_var = var_mc[k][inv] * fold_ratio[k]
        model_var = cv_misfit_variance(e[ok], drop_var, fold_var[ok], fold_leverage[k][ok]) if ok.any() else 0.0
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
    if flexible_u1:
        out["flexible_u1"] = {name: f.to_dict() for name, f in flexible_u1.items()}
    notes.extend(_reference_notes(flexible, flexible_u1))
    notes.extend(_interval_notes(out["scatter"], fits))
    return out


def _flexible_fits(u1, u2, chosen: dict, order=None) -> dict:
    """Per polynomial name, the flexible polynomial (``order(fit)``, by default
    :func:`identify.discrepancy.flexible_order`) fitted to the chosen one's targets and controls,
    where it differs from the chosen order, the data determine it and it leaves
    :data:`identify.discrepancy.MIN_FLEXIBLE_DOF` residual degrees of freedom."""
    from identify.discrepancy import MIN_FLEXIBLE_DOF, flexible_order
    from identify.polynomial import poly_terms

    order = order or flexible_order
    out = {}
    for name, (fit, mask, z) in chosen.items():
        n1, n2 = order(fit)
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
               "residuals": "residuals of the fit",
               "flexible_residuals": "residuals of the flexible reference polynomials (they leave less residual "
                                     "variance than the chosen order, whose excess is misfit, not drop scatter)"}[sc["source"]]
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


def _hybrid_model(ds: Dataset, efit, c_arr, selections, arx_sel, controls, *, adjuster_reference: str,
                  ecm_method: str, notes: list) -> HybridModel:
    """The fitted model (intervals still to come): the ECM, the three chosen polynomials, the ARX
    structure, the training controls and the software versions."""
    sel_p, sel_v, sel_q = selections
    versions = software_versions()
    versions["identify"] = __version__
    cov = getattr(efit, "coeff_cov", None)
    return HybridModel(
        dead_time_us=ds.dead_time_us, sample_interval_us=ds.sample_interval_us,
        nozzle_inner_diameter_um=ds.nozzle_inner_diameter_um, u3_um_per_ms=ds.u3_um_per_ms, hold_us=ds.hold_us,
        ecm_coefficients=EcmCoefficients(*c_arr[0]),
        ecm_coeff_cov=None if cov is None else np.asarray(cov, float),
        pinchoff=sel_p.fit, volume_adjuster=sel_v.fit, velocity_adjuster=sel_q.fit,
        arx_structure=_arx_structure(arx_sel), ecm_parameters=_param_dict(efit), controls=controls,
        adjuster_reference=adjuster_reference, versions=versions,
        extra={"ecm_method": ecm_method, "notes": notes, "n_sequences": ds.n_sequences},
        ecm_level=efit.level, notes=notes,
    )


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
    Irregular campaigns: each fit uses what it can (:func:`identify.dataset_checks.timeseries_runs`,
    :func:`identify.dataset_checks.summary_usable`); ``FitReport.notes`` (and ``notes`` of model.json)
    say what was dropped and why.

    Intervals: ``model.intervals["measurement"]`` is the systematic measurement uncertainty of
    :func:`identify.measurement_uncertainty.measurement_uncertainty` (dataset.json, the campaign's pixel-size
    check, or documented defaults), or ``measurement`` when given: a dict like dataset.json's
    ``measurement_uncertainty`` (``volume_rel`` and ``velocity_rel``, optional
    ``pinchoff_std_us``, ``source``). Training controls (the region of `identify.design`): only
    the (u1, u2) where every polynomial had a usable sequence.
    """
    import pandas as pd

    from identify.measurement_uncertainty import sequence_standard_errors
    from identify.dataset_checks import summary_usable
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
    v_ecm, vel_ecm, vol_target, vel_target = _adjuster_targets(ds, modal, adjuster_reference)
    _check_usable_pairs(ds, masks, u1, u2)
    kw = dict(orders=orders, folds=folds, seed=seed)
    mp, mv, mq = masks["pinchoff"], masks["volume_adjuster"], masks["velocity_adjuster"]
    sel_p = select_order(u1[mp], u2[mp], tp[mp], name="pinchoff", unit="us", **kw)
    bar.update(1)
    sel_v = select_order(u1[mv], u2[mv], vol_target[mv], name="volume_adjuster", unit="nl", **kw)
    bar.update(1)
    sel_q = select_order(u1[mq], u2[mq], vel_target[mq], name="velocity_adjuster", unit="m/s", **kw)
    bar.update(1)
    notes.extend(_order_note(sel) for sel in (sel_p, sel_v, sel_q))
    from identify.discrepancy import flexible_u1_order

    chosen = {"pinchoff": (sel_p.fit, mp, tp), "volume_adjuster": (sel_v.fit, mv, vol_target),
              "velocity_adjuster": (sel_q.fit, mq, vel_target)}
    flexible = _flexible_fits(u1, u2, chosen)
    flexible_u1 = _flexible_fits(u1, u2, chosen, order=flexible_u1_order)
    bar.close()
    model = _hybrid_model(ds, efit, c_arr, (sel_p, sel_v, sel_q), arx_sel, _fitted_controls(u1, u2, masks, notes),
                          adjuster_reference=adjuster_reference, ecm_method=ecm_method, notes=notes)
    mall = mp & mv & mq
    if not mall.all():
        notes.append(f"intervals: drop scatter and cross-validation from the {int(mall.sum())} of {len(mall)} "
                     "sequences with every summary value")
    ses = {k: v[mall] for k, v in sequence_standard_errors(ds).items()}
    meas = _measurement_block(ds, measurement, notes)
    model.intervals = _fit_intervals(model, u1[mall], u2[mall],
                                     {"pinchoff_us": tp[mall], "inflight_volume_nl": inflight[mall],
                                      "jetting_velocity_m_s": jet[mall]}, vol_target[mall], vel_target[mall],
                                     folds=folds, seed=seed, notes=notes, standard_errors=ses,
                                     measurement=meas, flexible=flexible,
                                     flexible_u1=flexible_u1)
    training = pd.DataFrame({
        "sequence_id": su["sequence_id"].to_numpy(), "u1_um_per_ms": u1, "u2_um": u2, "pinchoff_us": tp,
        "ecm_grown_volume_at_pinchoff_nl": v_ecm, "ecm_flow_velocity_at_max_stroke_m_s": vel_ecm,
        "volume_adjustment_nl": vol_target, "velocity_adjustment_m_s": vel_target,
    })
    return FitReport(model=model, arx_selection=arx_sel, ecm_fit=efit, pinchoff_selection=sel_p,
                     volume_selection=sel_v, velocity_selection=sel_q, training=training, notes=notes)


def _adjuster_targets(ds: Dataset, modal, adjuster_reference: str):
    """The ECM's grown volume at pinch-off and flow velocity at the maximum stroke of every sequence,
    and the adjusters' targets (Eq. 7): what the ECM (or the measured flow) leaves to explain."""
    from identify.dataset import DatasetError

    su = ds.summary
    u1 = su["u1_um_per_ms"].to_numpy(float)
    u2 = su["u2_um"].to_numpy(float)
    tp = su["pinchoff_us"].to_numpy(float)
    v_ecm = np.full(len(su), np.nan)
    q_ecm = np.empty(len(su))
    for i in range(len(su)):
        w = ds.waveform(u1[i], u2[i])
        if np.isfinite(tp[i]):
            v_ecm[i] = ecm_response_at(modal, w, np.array([tp[i] - ds.dead_time_us]))[0][0]
        q_ecm[i] = ecm_response_at(modal, w, np.array([w.max_stroke_us]))[1][0]
    vel_ecm = flow_velocity_m_s(q_ecm, ds.nozzle_inner_diameter_um)
    inflight = su["inflight_volume_nl"].to_numpy(float)
    jet = su["jetting_velocity_m_s"].to_numpy(float)
    if adjuster_reference == "ecm":
        return v_ecm, vel_ecm, inflight - v_ecm, jet - vel_ecm
    meas_vel = su["flow_velocity_at_max_stroke_m_s"].to_numpy(float)
    if not np.any(np.isfinite(meas_vel)):
        raise DatasetError(
            f"{ds.path or '.'}/summary.parquet: column flow_velocity_at_max_stroke_m_s has only NaN; "
            "it is needed with adjuster_reference='measured'"
        )
    return v_ecm, vel_ecm, inflight - su["grown_volume_at_pinchoff_nl"].to_numpy(float), jet - meas_vel


def _check_usable_pairs(ds: Dataset, masks: dict, u1, u2) -> None:
    """Each polynomial needs at least 3 distinct usable (u1, u2) settings."""
    from identify.dataset import DatasetError

    for name, m in masks.items():
        n_ctrl = len(np.unique(np.column_stack([u1[m], u2[m]]), axis=0)) if m.any() else 0
        if n_ctrl < 3:
            raise DatasetError(f"{ds.path or '.'}/summary.parquet: only {n_ctrl} distinct (u1_um_per_ms, u2_um) "
                               f"pair(s) usable for the {name} polynomial; it needs at least 3")


def _arx_structure(arx_sel) -> dict | None:
    """The selected ARX orders as model.json stores them (None without a selection)."""
    if arx_sel is None or getattr(arx_sel, "selected", None) is None:
        return None
    na, nb, nk = arx_sel.selected
    return {"na": int(na), "nb": int(nb), "nk": int(nk)}


def _measurement_block(ds: Dataset, measurement: dict | None, notes: list) -> dict:
    """The systematic measurement uncertainty of the intervals: the dataset's, or the one given."""
    from identify.dataset import check_measurement_block
    from identify.measurement_uncertainty import measurement_uncertainty

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
    return meas


__all__ = ["FitReport", "fit_hybrid", "arx_sequences", "ecm_sequences"]
