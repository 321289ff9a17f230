"""The report of a table model: the jetting window as a map, and the cross-validation.

    identify fit TABLE --inputs A,B,... --outputs Y,N --out model.json --report DIR

:func:`write_table_report` writes, into one folder written atomically (`dvcore.atomic.atomic_dir`):

* ``jetting_window.png``: per count output (``n_drops``), the probability of each count seen
  (no drop, single drop, satellites: the largest count seen meaning that many or more) over the
  two inputs that move the most common count's probability most (:func:`map_axes`), the other
  inputs held at the training value nearest their median; per continuous output, its predicted
  value and the relative width of its one-drop interval over the same plane. Grey dots: the
  training rows (all of them, projected on the plane); hatched: outside the training region;
* ``index.html``: the figure, the cross-validation table of the candidates, the training region
  and the notes.
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np
import pandas as pd

from dvcore.atomic import atomic_dir

REPORT_KIND = "identify-table-report"
#: Points per axis of the maps.
MAP_POINTS = 41


_CSS = """body{font-family:sans-serif;max-width:1200px;margin:1em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:0.5em 0 1.5em 0;font-size:0.9em}
caption{text-align:left;font-weight:bold;padding:0.3em 0}
th,td{border:1px solid #bbb;padding:0.2em 0.6em;text-align:right}th{background:#eee}
img{max-width:100%;border:1px solid #ddd}figure{margin:1em 0}figcaption{font-size:0.9em;color:#555}"""


def _cell(v) -> str:
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else ""
    if isinstance(v, (float, np.floating)):
        return "" if not np.isfinite(v) else f"{float(v):.5g}"
    return str(v)


def _html_table(df: pd.DataFrame, table_id: str, caption: str) -> str:
    e = html.escape
    head = "".join(f"<th>{e(str(c))}</th>" for c in df.columns)
    body = "".join("<tr>" + "".join(f"<td>{e(_cell(v))}</td>" for v in r) + "</tr>" for r in df.itertuples(index=False))
    return (f'<table id="{e(table_id)}"><caption>{e(caption)}</caption><thead><tr>{head}</tr></thead>'
            f"<tbody>{body}</tbody></table>")


def _held(model) -> np.ndarray:
    """Each input's training value nearest its median: where the inputs off the map are held."""
    X = model.data[model.inputs].to_numpy(float)
    med = np.median(X, axis=0)
    return np.array([X[np.argmin(np.abs(X[:, j] - med[j])), j] for j in range(X.shape[1])])


def _sweep(model, held, j, points=MAP_POINTS) -> pd.DataFrame:
    lo, hi = model.region.low[j], model.region.high[j]
    rows = np.tile(held, (points, 1))
    rows[:, j] = np.linspace(lo, hi, points)
    return pd.DataFrame(rows, columns=model.inputs)


def map_axes(model) -> tuple[int, int]:
    """The two inputs along which the first count output's most common count (else the first
    continuous output) moves most, one at a time from the held point (:func:`_held`)."""
    held = _held(model)
    if model.counts:
        o, c = next(iter(model.counts.items()))
        y = model.data[o].to_numpy(float)
        k = int(pd.Series(y[np.isfinite(y)]).mode().iloc[0])
        column = f"{o}_p{k}"
    else:
        o = model.outputs[0]
        column = f"{o}_mean"
    spread = []
    for j in range(len(model.inputs)):
        if model.region.high[j] <= model.region.low[j]:
            spread.append(-1.0)
            continue
        v = model.predict(_sweep(model, held, j))[column].to_numpy(float)
        spread.append(float(np.nanmax(v) - np.nanmin(v)) / (abs(float(np.nanmean(v))) if column.endswith("_mean") else 1.0))
    order = np.argsort(spread)[::-1]
    return int(order[0]), int(order[1])


def _panels(model) -> list[tuple[str, str, bool]]:
    """(column, title, is a probability) of each map."""
    out = []
    for o in model.outputs:
        if o in model.counts:
            cls = model.counts[o].classes
            for k in cls:
                more = " or more" if k == cls[-1] and len(cls) > 1 else ""
                out.append((f"{o}_p{k}", f"P({o} = {k}{more})", True))
        else:
            out.append((f"{o}_mean", f"{o} (predicted)", False))
            out.append((f"{o}_one_drop_width_percent", f"{o}: one-drop {100 * model.level:g} % interval width (%)",
                        False))
    return out


def window_grid(model, ax_i: int, ax_j: int, held, points: int = MAP_POINTS):
    """The model's predictions on a ``points`` x ``points`` grid over inputs ``ax_i`` (columns) and
    ``ax_j`` (rows) across the training region, the other inputs at ``held``: (grid of ax_i, grid of
    ax_j, predictions with ``<o>_one_drop_width_percent`` per continuous output; one row per grid
    point, row by row)."""
    xi = np.linspace(model.region.low[ax_i], model.region.high[ax_i], points)
    xj = np.linspace(model.region.low[ax_j], model.region.high[ax_j], points)
    gi, gj = np.meshgrid(xi, xj)
    rows = np.tile(held, (gi.size, 1))
    rows[:, ax_i], rows[:, ax_j] = gi.ravel(), gj.ravel()
    pred = model.predict(pd.DataFrame(rows, columns=model.inputs))
    for o in model.continuous:
        pred[f"{o}_one_drop_width_percent"] = (
            (pred[f"{o}_one_drop_high"] - pred[f"{o}_one_drop_low"]) / pred[f"{o}_mean"].abs() * 100)
    return gi, gj, pred


def window_panels(model) -> list[tuple[str, str, bool]]:
    """(prediction column, title, is a probability) of each map of the jetting window."""
    return _panels(model)


def held_point(model) -> np.ndarray:
    """Where the inputs off the map are held (each input's training value nearest its median)."""
    return _held(model)


def _figure(plt, path, model, ax_i, ax_j, held):
    gi, gj, pred = window_grid(model, ax_i, ax_j, held)
    panels = _panels(model)
    cols = min(3, len(panels))
    nrows = -(-len(panels) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(5.2 * cols, 4.2 * nrows), squeeze=False)
    X = model.data[model.inputs].to_numpy(float)
    outside = pred["outside_training_region"].to_numpy(bool).reshape(gi.shape)
    for ax, (col, title, prob) in zip(axes.ravel(), panels):
        z = pred[col].to_numpy(float).reshape(gi.shape)
        m = ax.pcolormesh(gi, gj, z, shading="auto", cmap="viridis", vmin=0 if prob else None, vmax=1 if prob else None)
        fig.colorbar(m, ax=ax)
        if prob:
            ax.contour(gi, gj, z, levels=[0.5, 0.9], colors="w", linewidths=0.8)
        if outside.any():
            ax.contourf(gi, gj, outside.astype(float), levels=[0.5, 1.5], colors="none", hatches=["//"])
        ax.plot(X[:, ax_i], X[:, ax_j], ".", color="0.6", ms=2)
        ax.set_xlabel(model.inputs[ax_i])
        ax.set_ylabel(model.inputs[ax_j])
        ax.set_title(title, fontsize=10)
    for ax in axes.ravel()[len(panels):]:
        ax.set_visible(False)
    others = ", ".join(f"{n} = {v:g}" for k, (n, v) in enumerate(zip(model.inputs, held)) if k not in (ax_i, ax_j))
    fig.suptitle(f"jetting window over ({model.inputs[ax_i]}, {model.inputs[ax_j]})" + (f"; held: {others}" if others else ""),
                 fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write_table_report(out, model, *, inputs=(), overwrite: bool = False) -> Path:
    """Write the report of a :class:`identify.tabular.TabularModel` into the folder ``out``.

    Parameters
    ----------
    out : path
        Output folder, written atomically; refused before any work when it overlaps ``inputs``
        or holds files we did not write (unless ``overwrite``).
    model : identify.tabular.TabularModel
    inputs : paths
        The table and the model file.
    overwrite : bool

    Returns
    -------
    Path
        ``out/index.html``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ax_i, ax_j = map_axes(model)
    held = _held(model)
    e = html.escape
    with atomic_dir(out, inputs=inputs, overwrite=overwrite, kind=REPORT_KIND) as tmp:
        _figure(plt, tmp / "jetting_window.png", model, ax_i, ax_j, held)
        r = model.region
        region = pd.DataFrame({"input": r.inputs, "min": r.low, "max": r.high, "grid step": r.step, "held at": held})
        page = [f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>identify table report"
                f"</title><style>{_CSS}</style></head><body><h1>Models of {e(', '.join(model.outputs))} on "
                f"{e(', '.join(model.inputs))}</h1>",
                f"<p>{len(model.data)} training rows{' of ' + e(model.source) if model.source else ''}; "
                f"{model.folds}-fold cross-validation, seed {model.seed}; intervals at {100 * model.level:g} %.</p>",
                '<figure><a href="jetting_window.png"><img src="jetting_window.png" alt="jetting window"></a>'
                "<figcaption>Probability of each drop count (white lines: 0.5 and 0.9) and the continuous outputs over "
                "the two inputs that move the most common count most; the other inputs held at the training value "
                "nearest their median; grey dots: the training rows projected; hatched: outside the training region"
                "</figcaption></figure>",
                _html_table(model.cv_table(), "cv", "cross-validation of the candidates (chosen: the smallest mean "
                            "absolute error, or Brier score, per output and step)"),
                _html_table(region, "region", f"training region (nearest-row distance at most {r.max_gap:.3g} grid "
                            "steps)")]
        if model.notes:
            page.append("<h2>Notes</h2><ul>" + "".join(f"<li>{e(n)}</li>" for n in model.notes) + "</ul>")
        page.append("</body></html>\n")
        (tmp / "index.html").write_text("\n".join(page), encoding="utf-8")
    return Path(out) / "index.html"
