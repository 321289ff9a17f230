"""A report a person can read: PNG figures in the style of the paper and one HTML page.

    identify report model.json --dataset DATASET --out DIR [--at U1,U2 ...] [--overwrite]
    identify fit DATASET --out model.json --report DIR

`write_report` renders, into one output folder written atomically (`dvcore.atomic.atomic_dir`):

* ``fig6_volume_flow.png``: measured (dots) vs ECM-simulated (lines) grown volume and flow
  velocity through the first chosen point, at fixed u1 (varying u2) and fixed u2 (varying u1),
  with the in-flight volume and jetting velocity (squares), like the paper's Fig. 6;
* ``sequences_volume_flow.png``: the same comparison for every training sequence;
* ``surfaces.png``: the pinch-off polynomial and both adjuster polynomials over (u1, u2) with
  the training targets (dots), like the paper's surface figures;
* ``cv_tables.png``: the 10-fold cross-validation tables (Tables 4-6);
* ``residuals.png``: measured minus predicted pinch-off, in-flight volume and jetting velocity
  vs u1 and u2;
* ``fig7_u1_<U1>_u2_<U2>.png`` per chosen point: the Monte Carlo band of the grown volume and
  flow velocity and the confidence (mean drop) and prediction (one drop) intervals of the
  in-flight volume and jetting velocity, like Fig. 7;
* ``index.html``: one self-contained page (no scripts, no external resources: the figures are
  embedded as base64 PNG data, each linked to its file beside the page), with the numbers as tables: model summary, ECM coefficients and physical parameters
  with their 95 % intervals, polynomial coefficients with intervals, CV tables, intervals at
  the chosen points, residual statistics, notes and versions.

The CV tables come from the fit (``fit_report``, a :class:`identify.hybrid_fit.FitReport`) when
given; from a model file they are recomputed from the dataset with the model's ECM (the same
targets and the same order selection as the fit).
"""

from __future__ import annotations

import base64
import html
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from dvcore import __version__
from dvcore.atomic import atomic_dir

REPORT_KIND = "identify-report"
OUTPUT_LABELS = {"pinchoff_us": ("pinch-off", "us"), "inflight_volume_nl": ("in-flight volume", "nl"),
                 "jetting_velocity_m_s": ("jetting velocity", "m/s")}
SURFACES = (("pinchoff", "pinchoff_us", "pinch-off instant", "us"),
            ("volume_adjuster", "volume_adjustment_nl", "volume adjuster", "nl"),
            ("velocity_adjuster", "velocity_adjustment_m_s", "velocity adjuster", "m/s"))


@dataclass
class ReportResult:
    """What `write_report` wrote: the folder, its index.html and the figures (final paths)."""

    out: Path
    index: Path
    figures: list = field(default_factory=list)
    points: list = field(default_factory=list)
    intervals: dict = field(default_factory=dict)  # (u1, u2) -> HybridModel.interval_prediction


def _plt():
    import matplotlib

    matplotlib.use("Agg")  # files only, no display
    import matplotlib.pyplot as plt

    return plt


def grid_centre(model, ds=None) -> tuple[float, float]:
    """Centre of the training grid: midpoint of the u1 and u2 ranges (snapped to the nearest
    training value of each, so that measured sequences lie on the Fig. 6 slices)."""
    ctrl = model.controls if model.controls is not None else ds.distinct_controls()
    ctrl = np.asarray(ctrl, float)
    out = []
    for k in range(2):
        vals = np.unique(ctrl[:, k])
        mid = 0.5 * (vals.min() + vals.max())
        out.append(float(vals[np.argmin(np.abs(vals - mid))]))
    return out[0], out[1]


def training_targets(model, ds) -> pd.DataFrame:
    """Per sequence the targets of the three polynomials, with the model's ECM (as in the fit)."""
    from identify.montecarlo import ecm_response_at_controls, modal_form
    from identify.ecm import flow_velocity_m_s

    su = ds.summary
    u1 = su["u1_um_per_ms"].to_numpy(float)
    u2 = su["u2_um"].to_numpy(float)
    tp = su["pinchoff_us"].to_numpy(float)
    modal = modal_form(model.ecm_coefficients)
    args = (model.u3_um_per_ms, model.hold_us)
    v_ecm, _ = ecm_response_at_controls(modal, u1, u2, tp - model.dead_time_us, *args)
    _, q = ecm_response_at_controls(modal, u1, u2, 1000.0 * u2 / u1, *args)
    vel_ecm = flow_velocity_m_s(q, model.nozzle_inner_diameter_um)
    if model.adjuster_reference == "measured":
        v_ref = su["grown_volume_at_pinchoff_nl"].to_numpy(float)
        q_ref = su["flow_velocity_at_max_stroke_m_s"].to_numpy(float)
    else:
        v_ref, q_ref = v_ecm, vel_ecm
    return pd.DataFrame({
        "sequence_id": su["sequence_id"].to_numpy(), "u1_um_per_ms": u1, "u2_um": u2, "pinchoff_us": tp,
        "ecm_grown_volume_at_pinchoff_nl": v_ecm, "ecm_flow_velocity_at_max_stroke_m_s": vel_ecm,
        "volume_adjustment_nl": su["inflight_volume_nl"].to_numpy(float) - v_ref,
        "velocity_adjustment_m_s": su["jetting_velocity_m_s"].to_numpy(float) - q_ref,
    })


def cv_tables(model, training: pd.DataFrame, *, folds: int = 10, seed: int = 0) -> dict:
    """CV tables of the three polynomials recomputed from ``training`` (`training_targets`)."""
    from identify.polynomial import DEFAULT_ORDERS, select_order

    u1 = training["u1_um_per_ms"].to_numpy(float)
    u2 = training["u2_um"].to_numpy(float)
    groups = len(np.unique(np.column_stack([u1, u2]), axis=0))
    out = {}
    for name, col, _, unit in SURFACES:
        sel = select_order(u1, u2, training[col].to_numpy(float), DEFAULT_ORDERS, folds=min(folds, groups),
                           seed=seed, name=name, unit=unit)
        out[name] = sel.table
    return out


# ----------------------------------------------------------------------------- figures
def _fig6(plt, path, ds, model, u1, u2):
    ts, su = ds.timeseries, ds.summary
    fig, axes = plt.subplots(2, 2, figsize=(12, 8), sharex=True)
    for col, (fixed, varying, value) in enumerate((("u1_um_per_ms", "u2_um", u1), ("u2_um", "u1_um_per_ms", u2))):
        sel = su[np.isclose(su[fixed], value)].sort_values(varying)
        cmap = plt.get_cmap("viridis", max(len(sel), 2))
        for i, row in enumerate(sel.itertuples()):
            g = ts[ts.sequence_id == row.sequence_id].sort_values("delay_us")
            g = g[g.attached]
            t = np.arange(0.0, float(max(g.delay_us.max(), row.pinchoff_us)) + 1.0, 1.0)
            vol, vel = model.simulate(row.u1_um_per_ms, row.u2_um, t)
            c = cmap(i)
            lab = f"{varying.split('_')[0]} = {getattr(row, varying):g}"
            axes[0, col].plot(g.delay_us, g.grown_volume_nl, "o", ms=3, color=c, label=lab)
            axes[0, col].plot(t, vol, "-", lw=1, color=c)
            axes[0, col].plot([row.pinchoff_us + 30], [row.inflight_volume_nl], "s", color=c, ms=6)
            axes[1, col].plot(g.delay_us, g.flow_velocity_m_s, "o", ms=3, color=c)
            axes[1, col].plot(t, vel, "-", lw=1, color=c)
            axes[1, col].plot([row.pinchoff_us + 30], [row.jetting_velocity_m_s], "s", color=c, ms=6)
        unit = "um/ms" if fixed.startswith("u1") else "um"
        axes[0, col].set_title(f"{fixed.split('_')[0]} = {value:g} {unit}: measured (dots), ECM (lines), "
                               "in-flight (squares)", fontsize=10)
        if len(sel):
            axes[0, col].legend(fontsize=8)
    axes[0, 0].set_ylabel("grown volume (nl)")
    axes[1, 0].set_ylabel("flow velocity (m/s)")
    for ax in axes[1]:
        ax.set_xlabel("delay after trigger (us)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _sequences_fig(plt, path, ds, model):
    ts, su = ds.timeseries, ds.summary.sort_values(["u1_um_per_ms", "u2_um"])
    n = len(su)
    ncol = min(4, n)
    nrow = math.ceil(n / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.2 * ncol, 2.4 * nrow), sharex=True, squeeze=False)
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    for ax, row in zip(axes.flat, su.itertuples()):
        g = ts[(ts.sequence_id == row.sequence_id) & ts.attached].sort_values("delay_us")
        t = np.arange(0.0, float(max(g.delay_us.max(), row.pinchoff_us)) + 1.0, 1.0)
        vol, vel = model.simulate(row.u1_um_per_ms, row.u2_um, t)
        ax.plot(g.delay_us, g.grown_volume_nl, "o", ms=2, color="C0")
        ax.plot(t, vol, "-", lw=1, color="C0")
        ax.tick_params(labelsize=7)
        ax2 = ax.twinx()
        ax2.plot(g.delay_us, g.flow_velocity_m_s, "o", ms=2, color="C3")
        ax2.plot(t, vel, "-", lw=1, color="C3")
        ax2.tick_params(labelsize=7, colors="C3")
        ax.set_title(f"{row.sequence_id}: u1 {row.u1_um_per_ms:g}, u2 {row.u2_um:g}", fontsize=8)
    fig.suptitle("every sequence: grown volume (blue, nl) and flow velocity (red, m/s); measured (dots), "
                 "ECM (lines); x: delay after trigger (us)", fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.35 / fig.get_figheight()))
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _surfaces_fig(plt, path, model, training):
    u1 = training["u1_um_per_ms"].to_numpy(float)
    u2 = training["u2_um"].to_numpy(float)
    g1, g2 = np.meshgrid(np.linspace(u1.min(), u1.max(), 25), np.linspace(u2.min(), u2.max(), 25))
    fig = plt.figure(figsize=(15, 4.8))
    for k, (attr, col, label, unit) in enumerate(SURFACES):
        poly = getattr(model, attr)
        ax = fig.add_subplot(1, 3, k + 1, projection="3d")
        ax.plot_surface(g1, g2, poly.predict(g1, g2), cmap="viridis", alpha=0.6, linewidth=0)
        ax.scatter(u1, u2, training[col].to_numpy(float), color="k", s=12, depthshade=False)
        ax.set_xlabel("u1 (um/ms)", fontsize=8)
        ax.set_ylabel("u2 (um)", fontsize=8)
        ax.set_zlabel(unit, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.set_title(f"{label}: orders (n1, n2) = ({poly.n1}, {poly.n2})", fontsize=10)
    fig.suptitle("polynomial surfaces (Eq. 7) and the training targets (dots)", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _tables_fig(plt, path, tables: dict):
    tables = {n: _head(df, FIGURE_ROWS)[0] for n, df in tables.items()}
    names = list(tables)
    heights = [len(tables[n]) + 2 for n in names]
    fig, axes = plt.subplots(len(names), 1, figsize=(9, 0.28 * sum(heights) + 0.5), squeeze=False,
                             gridspec_kw={"height_ratios": heights})
    for ax, name in zip(axes[:, 0], names):
        df = tables[name]
        ax.axis("off")
        cells = [[_cell(v) for v in r] for r in df.itertuples(index=False)]
        tab = ax.table(cellText=cells, colLabels=list(df.columns), loc="center", cellLoc="center")
        tab.auto_set_font_size(False)
        tab.set_fontsize(8)
        if "selected" in df.columns:
            for i, sel in enumerate(df["selected"].to_numpy(bool)):
                if sel:
                    for j in range(len(df.columns)):
                        tab[i + 1, j].set_facecolor("#dde8f7")
        ax.set_title(f"{name}: cross-validation" + (" (best rows)" if name == "arx" else ""), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _residuals_fig(plt, path, residuals: pd.DataFrame):
    fig, axes = plt.subplots(2, 3, figsize=(13, 6.5))
    for j, key in enumerate(OUTPUT_LABELS):
        label, unit = OUTPUT_LABELS[key]
        for i, u in enumerate(("u1_um_per_ms", "u2_um")):
            ax = axes[i, j]
            ax.axhline(0.0, color="0.6", lw=0.8)
            ax.plot(residuals[u], residuals[key], "o", ms=4)
            ax.set_xlabel("u1 (um/ms)" if i == 0 else "u2 (um)")
            ax.set_ylabel(f"{label} residual ({unit})")
            ax.tick_params(labelsize=8)
    fig.suptitle("residuals: measured - model prediction", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _fig7(plt, path, ds, model, mc, iv, u1, u2, truth_fn=None):
    ts, su = ds.timeseries, ds.summary
    band = mc.band
    sel = su[np.isclose(su.u1_um_per_ms, u1) & np.isclose(su.u2_um, u2)]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for ax, (vcol, bcol, out_key, unit) in zip(
        axes,
        (("grown_volume_nl", "volume", "inflight_volume_nl", "nl"),
         ("flow_velocity_m_s", "flow_velocity", "jetting_velocity_m_s", "m/s")),
    ):
        suffix = "_nl" if unit == "nl" else "_m_s"
        if band is not None:
            ax.fill_between(band.delay_us, band[f"{bcol}_low{suffix}"], band[f"{bcol}_high{suffix}"], color="r",
                            alpha=0.2, label="ECM 95 % band (Monte Carlo)")
            ax.plot(band.delay_us, band[f"{bcol}_nominal{suffix}"], "r-", label="ECM nominal")
        for n, row in enumerate(sel.itertuples()):
            g = ts[(ts.sequence_id == row.sequence_id) & ts.attached].sort_values("delay_us")
            ax.plot(g.delay_us, g[vcol], "k.-", lw=0.8, label="measured" if n == 0 else None)
            ax.plot([row.pinchoff_us + 40], [getattr(row, out_key)], "ko")
        e = iv[out_key]
        x = float(mc.nominal["pinchoff_us"]) + 60
        pct = f"{100 * e['level']:g} %"
        ax.errorbar([x], [e["mean"]], yerr=[[e["mean"] - e["mean_drop_low"]], [e["mean_drop_high"] - e["mean"]]],
                    fmt="ro", capsize=4, label=f"hybrid model: mean, confidence {pct} (mean drop)")
        ax.errorbar([x + 25], [e["mean"]],
                    yerr=[[e["mean"] - e["one_drop_low"]], [e["one_drop_high"] - e["mean"]]],
                    fmt="bs", ms=4, capsize=4, label=f"prediction {pct} (one drop)")
        if truth_fn is not None:
            ax.axhline(truth_fn(u1, u2)[out_key], color="g", ls=":", label="synthetic truth")
        ax.set_xlabel("delay after trigger (us)")
        ax.set_ylabel(f"{out_key} / {vcol} ({unit})")
        ax.legend(fontsize=8)
    fig.suptitle(f"u1 = {u1:g} um/ms, u2 = {u2:g} um")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# ----------------------------------------------------------------------------- HTML
FIGURE_ROWS = 10  # rows of a long table (the ARX structure selection) shown in cv_tables.png
PAGE_ROWS = 40  # ... and on the page


def _head(df: pd.DataFrame, rows: int) -> tuple[pd.DataFrame, str]:
    if len(df) <= rows:
        return df, ""
    return df.head(rows), f" (first {rows} of {len(df)} rows)"


def _cell(v) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else ""
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return "nan" if not math.isfinite(float(v)) else f"{float(v):.6g}"
    return str(v)


def _html_table(df: pd.DataFrame, table_id: str, caption: str) -> str:
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in df.columns)
    rows = []
    for r in df.itertuples(index=False):
        rows.append("<tr>" + "".join(f"<td>{html.escape(_cell(v))}</td>" for v in r) + "</tr>")
    # in a scrolling box: a wide table (the intervals) scrolls instead of running off the page
    return (f'<div class="scroll"><table id="{html.escape(table_id)}"><caption>{html.escape(caption)}</caption>'
            f"<thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table></div>")


def _embedded_figure(name: str, caption: str, folder: Path | None = None) -> str:
    """A figure of the page: the PNG embedded (a data URI: the page is self-contained) when ``folder``
    holds it, with a link to the file beside the page."""
    n = html.escape(name)
    src = n
    if folder is not None and (Path(folder) / name).is_file():
        src = "data:image/png;base64," + base64.b64encode((Path(folder) / name).read_bytes()).decode("ascii")
    return (f'<figure><a href="{n}"><img src="{src}" alt="{html.escape(caption)}"></a>'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


#: rows of the ARX structure table on the page: the best by validation RMSE among the sane fits
ARX_PAGE_ROWS = 15


def _arx_rows(df: pd.DataFrame) -> tuple[pd.DataFrame, str]:
    """The ARX structure table's best rows: by validation RMSE, among fits that beat the mean (fit >= 0 %
    on training and validation: a fit of -1e6 % is a diverged simulation, not a candidate)."""
    fits = [c for c in ("train_fit_percent", "val_fit_percent") if c in df]
    sane = df
    for c in fits:
        sane = sane[np.isfinite(sane[c].to_numpy(float)) & (sane[c].to_numpy(float) >= 0.0)]
    if "val_rmse_nl" in sane:
        sane = sane.sort_values("val_rmse_nl", kind="stable")
    shown = sane.head(ARX_PAGE_ROWS)
    return shown, (f" (best {len(shown)} of {len(df)} structures by validation RMSE, among the {len(sane)} whose "
                   "fits beat the mean, fit >= 0 %)")


_CSS = """body{font-family:sans-serif;max-width:1200px;margin:1em auto;padding:0 1em;color:#222}
.scroll{overflow-x:auto;max-width:100%}
table{border-collapse:collapse;margin:0.5em 0 1.5em 0;font-size:0.85em}
caption{text-align:left;font-weight:bold;padding:0.3em 0}
th,td{border:1px solid #bbb;padding:0.2em 0.6em;text-align:right}th{background:#eee}
img{max-width:100%;border:1px solid #ddd}figure{margin:1em 0}figcaption{font-size:0.9em;color:#555}
li{margin:0.2em 0}"""


def _model_tables(model) -> list[tuple[str, str, pd.DataFrame]]:
    d = model.to_dict()
    out = []
    summary = pd.DataFrame({"quantity": [
        "nozzle inner diameter (um)", "dead time (us)", "sample interval (us)", "u3 (um/ms)", "hold (us)",
        "ARX structure (na, nb, nk)", "adjuster reference", "ECM method", "training sequences",
        "distinct training (u1, u2)"],
        "value": [model.nozzle_inner_diameter_um, model.dead_time_us, model.sample_interval_us,
                  model.u3_um_per_ms, model.hold_us,
                  "n/a" if not model.arx_structure else "({na}, {nb}, {nk})".format(**model.arx_structure),
                  model.adjuster_reference, str(model.extra.get("ecm_method", "n/a")),
                  model.extra.get("n_sequences", "n/a"),
                  "n/a" if model.controls is None else len(model.controls)]})
    summary["value"] = summary["value"].map(_cell)
    out.append(("model-summary", "model", summary))
    e = d["ecm"]
    ci = e.get("coefficients_ci95") or {}
    coef = pd.DataFrame({"coefficient": list(e["coefficient_order"]),
                         "value": [e["coefficients"][k] for k in e["coefficient_order"]],
                         "ci95": [ci.get(k) for k in e["coefficient_order"]]})
    coef["low"] = [None if c is None else v - c for v, c in zip(coef.value, coef.ci95)]
    coef["high"] = [None if c is None else v + c for v, c in zip(coef.value, coef.ci95)]
    out.append(("ecm-coefficients", "ECM coefficients (SI) with 95 % intervals", coef))
    params = e.get("parameters") or {}
    if params:
        rows = []
        for k, v in params.items():  # {"value", "ci95_low", "ci95_high"} (identify.hybrid_fit; was read as "ci95": n/a)
            if isinstance(v, dict):
                rows.append({"parameter": k, "value": v.get("value"), "low": v.get("ci95_low"),
                             "high": v.get("ci95_high")})
            else:
                rows.append({"parameter": k, "value": v, "low": None, "high": None})
        out.append(("ecm-parameters", "ECM physical parameters (SI) with 95 % intervals", pd.DataFrame(rows)))
    for attr, _, label, unit in SURFACES:
        poly = getattr(model, attr)
        out.append((f"{attr}-coefficients", f"{label} ({unit}): polynomial coefficients, orders (n1, n2) = "
                    f"({poly.n1}, {poly.n2}), residual std {poly.residual_std:.4g}, with 95 % intervals",
                    poly.to_pandas()))
    return out


def _interval_table(intervals: dict) -> pd.DataFrame:
    rows = []
    for (u1, u2), iv in intervals.items():
        for key, (label, unit) in OUTPUT_LABELS.items():
            e = iv[key]
            rows.append({"u1_um_per_ms": u1, "u2_um": u2, "output": key, "unit": unit, "mean": e["mean"],
                         "level": e["level"], "mean_drop_low": e["mean_drop_low"],
                         "mean_drop_high": e["mean_drop_high"],
                         "one_drop_low": e["one_drop_low"] if e["one_drop_available"] else None,
                         "one_drop_high": e["one_drop_high"] if e["one_drop_available"] else None,
                         "parameter_std": e.get("parameter_std"), "model_std": e.get("model_std"),
                         "measurement_std": e.get("measurement_std", 0.0), "drop_std": e.get("drop_std")})
    return pd.DataFrame(rows)


def _measurement_text(model) -> str:
    """One sentence on the systematic measurement term of the intervals and its source."""
    from identify.hybrid import describe_measurement

    text = describe_measurement(model)
    return text[:1].upper() + text[1:] + "."


def _residual_stats(residuals: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for key, (label, unit) in OUTPUT_LABELS.items():
        r = residuals[key].to_numpy(float)
        rows.append({"output": key, "unit": unit, "n": int(np.isfinite(r).sum()), "mean": float(np.nanmean(r)),
                     "rmse": float(np.sqrt(np.nanmean(r**2))), "max_abs": float(np.nanmax(np.abs(r)))})
    return pd.DataFrame(rows)


def _versions(model) -> pd.DataFrame:
    import matplotlib

    v = {f"model: {k}": str(x) for k, x in (model.versions or {}).items()}
    v.update({"report: identify": __version__, "report: matplotlib": matplotlib.__version__})
    return pd.DataFrame({"component": list(v), "version": list(v.values())})


# ----------------------------------------------------------------------------- entry point
def _point_name(u1: float, u2: float) -> str:
    return f"fig7_u1_{u1:g}_u2_{u2:g}.png"


def write_report(out, model, ds, *, fit_report=None, at=None, samples: int = 10_000, seed: int = 0,
                 level: float = 0.95, overwrite: bool | str = False, inputs=(), mc: dict | None = None,
                 truth_fn=None, title: str = "identify report", folds: int = 10) -> ReportResult:
    """Render the report of ``model`` trained on ``ds`` into the folder ``out``.

    Parameters
    ----------
    out : path
        Output folder, written atomically (`dvcore.atomic.atomic_dir`: refused with
        :class:`dvcore.atomic.OutputError` before any work when it holds files we did not
        write, unless ``overwrite``).
    model : identify.hybrid.HybridModel
    ds : identify.dataset.Dataset
        The training dataset (measured curves, data points of the surfaces, residuals).
    fit_report : identify.hybrid_fit.FitReport, optional
        The fit's CV tables and notes; without it the CV tables are recomputed (`cv_tables`).
    at : list of (u1, u2), optional
        Points of the interval figures and table (default: the centre of the training grid,
        `grid_centre`). The first one also fixes the Fig. 6 slices.
    samples, seed, level :
        Monte Carlo of the intervals (`HybridModel.monte_carlo`, `HybridModel.interval_prediction`).
    inputs : paths
        Inputs the folder may not overlap (model file, dataset folder).
    mc : dict, optional
        Already computed Monte Carlo results, {(u1, u2): MonteCarloResult with a band}.
    truth_fn : callable, optional
        ``truth_fn(u1, u2) -> {output: value}`` of a synthetic campaign, drawn in Fig. 7.
    """
    from dvcore.atomic import check_output_dir

    check_output_dir(out, inputs=inputs, overwrite=overwrite)
    points = [(float(a), float(b)) for a, b in (at or [grid_centre(model, ds)])]
    plt = _plt()
    if fit_report is not None:
        training, tables, notes = fit_report.training, dict(fit_report.tables()), list(fit_report.notes)
        cv_source = "from the fit"
    else:
        training = training_targets(model, ds)
        tables = cv_tables(model, training, folds=folds, seed=seed)
        notes = [str(n) for n in (model.extra.get("notes") or [])]
        cv_source = (f"recomputed from the dataset with the model's ECM ({min(folds, len(ds.distinct_controls()))} "
                     f"folds, seed {seed})")
    su = ds.summary
    pred = model.predict_grid(su["u1_um_per_ms"].to_numpy(float), su["u2_um"].to_numpy(float))
    residuals = pd.DataFrame({"sequence_id": su["sequence_id"].to_numpy(), "u1_um_per_ms": pred.u1_um_per_ms,
                              "u2_um": pred.u2_um,
                              **{k: su[k].to_numpy(float) - pred[k].to_numpy(float) for k in OUTPUT_LABELS}})
    intervals, mcs = {}, {}
    for u1, u2 in points:
        res = (mc or {}).get((u1, u2))
        if res is None or res.band is None:
            res = model.monte_carlo(u1, u2, samples=samples, seed=seed, band=True)
        mcs[(u1, u2)] = res
        intervals[(u1, u2)] = model.interval_prediction(u1, u2, level=level, mc=res)

    figures = [("fig6_volume_flow.png", f"measured vs ECM grown volume and flow velocity at u1 = {points[0][0]:g} "
                "um/ms (varying u2, left) and u2 = {:g} um (varying u1, right); squares: in-flight volume and "
                "jetting velocity (Fig. 6)".format(points[0][1])),
               ("sequences_volume_flow.png", "measured vs ECM grown volume and flow velocity, every sequence"),
               ("surfaces.png", "pinch-off and adjuster polynomial surfaces over (u1, u2) with the training targets"),
               ("cv_tables.png", f"cross-validation tables ({cv_source}); selected order shaded"),
               ("residuals.png", "residuals (measured - predicted) vs u1 and u2")]
    figures += [(_point_name(u1, u2), f"Monte Carlo band and {100 * level:g} % confidence / prediction intervals "
                 f"at u1 = {u1:g} um/ms, u2 = {u2:g} um (Fig. 7)") for u1, u2 in points]
    with atomic_dir(out, inputs=inputs, overwrite=overwrite, kind=REPORT_KIND) as tmp:
        cx, cy = points[0]
        _fig6(plt, tmp / figures[0][0], ds, model, cx, cy)
        _sequences_fig(plt, tmp / figures[1][0], ds, model)
        _surfaces_fig(plt, tmp / figures[2][0], model, training)
        _tables_fig(plt, tmp / figures[3][0], tables)
        _residuals_fig(plt, tmp / figures[4][0], residuals)
        for (u1, u2) in points:
            _fig7(plt, tmp / _point_name(u1, u2), ds, model, mcs[(u1, u2)], intervals[(u1, u2)], u1, u2, truth_fn)
        page = _page(title, model, ds, figures, tables, cv_source, intervals, residuals, notes, samples, level, tmp)
        (tmp / "index.html").write_text(page, encoding="utf-8")
    out = Path(out)
    return ReportResult(out=out, index=out / "index.html", figures=[out / n for n, _ in figures], points=points,
                        intervals=intervals)


def _page(title, model, ds, figures, tables, cv_source, intervals, residuals, notes, samples, level,
          folder: Path | None = None) -> str:
    e = html.escape

    def _figure(name, caption):  # embedded from the folder being written
        return _embedded_figure(name, caption, folder)

    parts = [f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{e(title)}</title>"
             f"<style>{_CSS}</style></head><body>", f"<h1>{e(title)}</h1>",
             f"<p>Hybrid drop-formation model (Wang &amp; Chiu, Eq. 8) trained on "
             f"{len(ds.summary)} sequences{'' if ds.path is None else ' of ' + e(str(ds.path))}.</p>",
             "<h2>Figures</h2><ul>" + "".join(f'<li><a href="{e(n)}">{e(n)}</a>: {e(c)}</li>' for n, c in figures)
             + "</ul>",
             "<h2>Intervals at chosen points</h2>",
             f"<p>{samples} Monte Carlo samples. Confidence: where the mean of many drops lies (parameter "
             "uncertainty, model discrepancy seen in cross-validation and the systematic measurement "
             "uncertainty); prediction: where one individual drop lies (confidence plus drop-to-drop scatter of "
             "the training data). Standard deviations of each part in the table.</p>",
             f"<p id=\"measurement\">{e(_measurement_text(model))}</p>",
             _html_table(_interval_table(intervals), "intervals", f"{100 * level:g} % intervals"),
             *[_figure(_point_name(u1, u2), f"u1 = {u1:g} um/ms, u2 = {u2:g} um") for u1, u2 in intervals],
             "<h2>Measured vs ECM</h2>", _figure(*figures[0]), _figure(*figures[1]),
             "<h2>Model</h2>"]
    for tid, cap, df in _model_tables(model):
        parts.append(_html_table(df, tid, cap))
    parts += ["<h2>Pinch-off and adjuster surfaces</h2>", _figure(*figures[2]),
              f"<h2>Cross-validation</h2><p>CV tables {e(cv_source)}; RMSEs averaged over the folds.</p>"]
    for name, df in tables.items():
        df, more = _arx_rows(df) if name == "arx" else _head(df, PAGE_ROWS)
        parts.append(_html_table(df, f"cv-{name}", f"{name}: cross-validation{more}"))
    # the tables above are the CV tables; cv_tables.png (the same, as a picture) is linked, not shown again
    parts += ["<h2>Residuals</h2>",
              _html_table(_residual_stats(residuals), "residual-stats", "residuals: measured - predicted"),
              _figure(*figures[4]), "<h2>Notes</h2>",
              ("<ul>" + "".join(f"<li>{e(str(n))}</li>" for n in notes) + "</ul>") if notes else "<p>none</p>",
              "<h2>Versions</h2>", _html_table(_versions(model), "versions", "software versions"),
              "</body></html>\n"]
    return "\n".join(parts)


__all__ = ["write_report", "ReportResult", "grid_centre", "training_targets", "cv_tables", "REPORT_KIND"]
