"""Optional Rerun logging of model identification (called by ``identify/cli.py``).

Stateless functions writing to an explicit :class:`rerun.RecordingStream` obtained from
:func:`open_identify_recording` (or :func:`recording_from_args`); when logging is off the caller
holds ``None`` and skips the calls. Nothing imports :mod:`rerun` until a recording is opened.

Typical use::

    rec = recording_from_args(args)                    # None without --rerun / --rerun-spawn
    if rec is not None:
        for name, fit in fits.items():
            log_sequence_fit(rec, name, fit.t_us, fit.measured_volume_nl, fit.simulated_volume_nl,
                             measured_flow_m_s=..., simulated_flow_m_s=...)
        log_cv_table(rec, cv_df, value_column="rmse_volume_nl")
        log_monte_carlo_band(rec, "u1=70 u2=25", t_us, mean, low, high, quantity="volume_nl")
        close_recording(rec)

Time axis: the ``delay`` duration timeline in integer nanoseconds after the firing trigger
(``round(t_us * 1000)``), the same timeline as the measurement recordings of
:mod:`dropvision.app.rerun_log`.

Entity paths (``<name>`` = sequence / band name, escaped with ``rr.escape_entity_path_part``)
-----------------------------------------------------------------------------------------
``/identify/volume_nl/<name>/measured``     Scalars, drawn as points
``/identify/volume_nl/<name>/simulated``    Scalars, drawn as a line
``/identify/flow_m_s/<name>/measured``      Scalars, points (only if given)
``/identify/flow_m_s/<name>/simulated``     Scalars, line (only if given)
``/identify/cv/table``                      static TextDocument (markdown of the CV DataFrame)
``/identify/cv/bar``                        static BarChart of one CV column (if requested)
``/identify/monte_carlo/<quantity>/<name>/{mean,low,high}``   Scalars, lines
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from identify.app.rerun_stream import RerunOptions, close_stream, delay_ns, open_stream, options_from_args

if TYPE_CHECKING:  # pragma: no cover - typing only
    import pandas as pd
    import rerun as rr
    import rerun.blueprint as rrb

__all__ = [
    "DEFAULT_APPLICATION_ID",
    "identify_blueprint",
    "open_identify_recording",
    "recording_from_args",
    "log_sequence_fit",
    "log_cv_table",
    "log_monte_carlo_band",
    "close_recording",
]

DEFAULT_APPLICATION_ID = "dropvision-identify"

_MEASURED = (230, 40, 40)
_SIMULATED = (40, 120, 255)
_BAND_MEAN = (40, 40, 40)
_BAND_EDGE = (150, 150, 150)


def identify_blueprint() -> rrb.Blueprint:
    """Layout: measured vs simulated volume and flow left; Monte Carlo band and CV table right."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.TimeSeriesView(name="volume: measured vs simulated [nl]", origin="/identify/volume_nl"),
                rrb.TimeSeriesView(name="flow velocity: measured vs simulated [m/s]",
                                   origin="/identify/flow_m_s"),
            ),
            rrb.Vertical(
                rrb.TimeSeriesView(name="Monte Carlo band", origin="/identify/monte_carlo"),
                rrb.Tabs(
                    rrb.TextDocumentView(name="cross-validation table", origin="/identify/cv/table"),
                    rrb.BarChartView(name="cross-validation", origin="/identify/cv/bar"),
                ),
            ),
        ),
        rrb.TimePanel(timeline="delay"),
        collapse_panels=False,
    )


def open_identify_recording(options: RerunOptions) -> rr.RecordingStream:
    """Open an explicit recording stream with :func:`identify_blueprint` saved alongside."""
    return open_stream(options, identify_blueprint())


def recording_from_args(args: argparse.Namespace, app_id: str = DEFAULT_APPLICATION_ID) -> rr.RecordingStream | None:
    """Recording from the ``dropvision.app.rerun_log.add_rerun_args`` flags, or None when off."""
    options = options_from_args(args, app_id)
    if options is not None:
        options = options.start_viewer()  # a viewer that cannot start: warned, work goes on
    return None if options is None or not options.enabled else open_identify_recording(options)


def close_recording(rec: rr.RecordingStream) -> None:
    """Flush and finalise the sinks (writes the .rrd footer); never blocks on an unreachable
    viewer (:func:`identify.app.rerun_stream.close_stream`)."""
    close_stream(rec)


# --- helpers ---------------------------------------------------------------------------------


def _vector(name: str, values: Any, n: int | None = None) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {arr.shape}")
    if n is not None and arr.shape[0] != n:
        raise ValueError(f"{name} has {arr.shape[0]} values, expected {n} (one per time)")
    return arr


def _delay_column(t_us: np.ndarray) -> Any:
    import rerun as rr

    if not np.all(np.isfinite(t_us)):
        raise ValueError("time values (t_us) must be finite")
    ns = np.array([delay_ns(t) for t in t_us], dtype=np.int64).astype("timedelta64[ns]")
    return rr.TimeColumn("delay", duration=ns)


def _send_series(rec: rr.RecordingStream, path: str, t_us: np.ndarray, values: np.ndarray) -> int:
    """Send the finite samples of one scalar series on the delay timeline; returns their count."""
    import rerun as rr

    keep = np.isfinite(values)
    if not keep.any():
        return 0
    rec.send_columns(path, indexes=[_delay_column(t_us[keep])],
                     columns=rr.Scalars.columns(scalars=values[keep]))
    return int(keep.sum())


def _style(rec: rr.RecordingStream, path: str, name: str, colour: tuple[int, int, int], *,
           points: bool, width: float = 2.0) -> None:
    import rerun as rr

    if points:
        rec.log(path, rr.SeriesPoints(names=name, colors=colour, marker_sizes=3.0), static=True)
    else:
        rec.log(path, rr.SeriesLines(names=name, colors=colour, widths=width), static=True)


def _part(name: str) -> str:
    import rerun as rr

    if not str(name):
        raise ValueError("name must be a non-empty string")
    return rr.escape_entity_path_part(str(name))


# --- public logging functions ----------------------------------------------------------------


def log_sequence_fit(rec: rr.RecordingStream, name: str, t_us: Sequence[float] | np.ndarray,
                     measured_volume_nl: Sequence[float] | np.ndarray,
                     simulated_volume_nl: Sequence[float] | np.ndarray, *,
                     measured_flow_m_s: Sequence[float] | np.ndarray | None = None,
                     simulated_flow_m_s: Sequence[float] | np.ndarray | None = None,
                     sim_t_us: Sequence[float] | np.ndarray | None = None) -> None:
    """Log measured vs simulated grown volume (and flow velocity) of one sequence.

    Parameters
    ----------
    rec : rerun.RecordingStream
        From :func:`open_identify_recording`.
    name : str
        Sequence name (entity path part, escaped).
    t_us : array (n,)
        Delays after the trigger of the measured samples [us].
    measured_volume_nl : array (n,)
        Measured grown volume [nl]; NaN samples are skipped.
    simulated_volume_nl : array (n,) or (m,)
        Simulated grown volume [nl] at ``sim_t_us`` (default ``t_us``).
    measured_flow_m_s, simulated_flow_m_s : array, optional
        Flow velocity [m/s] at ``t_us`` / ``sim_t_us``; NaN samples are skipped.
    sim_t_us : array (m,), optional
        Times of the simulated series [us], e.g. a fine grid; default ``t_us``.
    """
    part = _part(name)
    t = _vector("t_us", t_us)
    ts = t if sim_t_us is None else _vector("sim_t_us", sim_t_us)
    series = [
        ("volume_nl", "measured", _vector("measured_volume_nl", measured_volume_nl, t.size), t),
        ("volume_nl", "simulated", _vector("simulated_volume_nl", simulated_volume_nl, ts.size), ts),
    ]
    if measured_flow_m_s is not None:
        series.append(("flow_m_s", "measured", _vector("measured_flow_m_s", measured_flow_m_s, t.size), t))
    if simulated_flow_m_s is not None:
        series.append(("flow_m_s", "simulated", _vector("simulated_flow_m_s", simulated_flow_m_s, ts.size), ts))
    for quantity, kind, values, times in series:
        path = f"/identify/{quantity}/{part}/{kind}"
        measured = kind == "measured"
        _style(rec, path, f"{name} {kind}", _MEASURED if measured else _SIMULATED, points=measured)
        _send_series(rec, path, times, values)


def _markdown(table: pd.DataFrame, title: str) -> str:
    cols = [str(table.index.name or "")] + [str(c) for c in table.columns]
    lines = [f"## {title}", "", "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for idx, row in table.iterrows():
        cells = [str(idx)]
        for value in row.tolist():
            if isinstance(value, (float, np.floating)):
                cells.append("NaN" if not math.isfinite(value) else f"{value:.4g}")
            else:
                cells.append(str(value))
        lines.append("| " + " | ".join(c.replace("|", "/") for c in cells) + " |")
    return "\n".join(lines)


def log_cv_table(rec: rr.RecordingStream, table: pd.DataFrame, *, value_column: str | None = None,
                 title: str = "Cross-validation") -> None:
    """Log the cross-validation table as markdown, and optionally one column as a bar chart.

    Parameters
    ----------
    rec : rerun.RecordingStream
    table : pandas.DataFrame
        One row per fold / model / sequence (the index is the first markdown column).
    value_column : str, optional
        Numeric column drawn as a bar chart at ``/identify/cv/bar`` (bars in row order; the
        table names the rows). None: no bar chart.
    title : str
        Markdown heading.
    """
    import pandas as pd
    import rerun as rr

    if not isinstance(table, pd.DataFrame):
        raise ValueError(f"log_cv_table: table must be a pandas DataFrame, got {type(table).__name__}")
    rec.log("/identify/cv/table", rr.TextDocument(_markdown(table, title), media_type="text/markdown"),
            static=True)
    if value_column is not None:
        if value_column not in table.columns:
            raise ValueError(f"log_cv_table: value_column {value_column!r} not in the table columns "
                             f"{list(table.columns)}")
        values = pd.to_numeric(table[value_column], errors="raise").to_numpy(dtype=float)
        rec.log("/identify/cv/bar", rr.BarChart(values), static=True)


def log_monte_carlo_band(rec: rr.RecordingStream, name: str, t_us: Sequence[float] | np.ndarray,
                         mean: Sequence[float] | np.ndarray, low: Sequence[float] | np.ndarray,
                         high: Sequence[float] | np.ndarray, *, quantity: str = "volume_nl") -> None:
    """Log a Monte Carlo band (mean and low/high bounds, e.g. 5 % / 95 %) over delay.

    Parameters
    ----------
    rec : rerun.RecordingStream
    name : str
        Band name (e.g. the waveform ``"u1=70 u2=25"``).
    t_us : array (n,)
        Delays after the trigger [us].
    mean, low, high : array (n,)
        Band in the unit named by ``quantity``; ``low <= high`` is required where finite.
    quantity : str
        Entity path part naming the quantity and unit, e.g. ``"volume_nl"`` or ``"flow_m_s"``.
    """
    t = _vector("t_us", t_us)
    m = _vector("mean", mean, t.size)
    lo = _vector("low", low, t.size)
    hi = _vector("high", high, t.size)
    both = np.isfinite(lo) & np.isfinite(hi)
    if np.any(lo[both] > hi[both]):
        raise ValueError("log_monte_carlo_band: low > high at some times (swapped bounds?)")
    base = f"/identify/monte_carlo/{_part(quantity)}/{_part(name)}"
    for kind, values, colour, width in (("mean", m, _BAND_MEAN, 2.0), ("low", lo, _BAND_EDGE, 1.0),
                                        ("high", hi, _BAND_EDGE, 1.0)):
        path = f"{base}/{kind}"
        _style(rec, path, f"{name} {kind}", colour, points=False, width=width)
        _send_series(rec, path, t, values)


def log_model_fit(rec: "rr.RecordingStream", dataset, model, arx_selection=None, *, max_cv_rows: int = 20) -> None:
    """Log an identified model against its training dataset.

    For every sequence of ``dataset`` (an :class:`identify.dataset.Dataset`): the measured grown
    volume and flow velocity before pinch-off and the nominal ECM simulation of ``model``
    (:class:`identify.hybrid.HybridModel`) at the same delays; plus the ARX structure-selection
    table when given.
    """
    ts = dataset.timeseries
    for row in dataset.summary.itertuples():
        g = ts[(ts.sequence_id == row.sequence_id) & ts.attached].sort_values("delay_us")
        if len(g) < 2:
            continue
        t = g.delay_us.to_numpy(float)
        vol, vel = model.simulate(row.u1_um_per_ms, row.u2_um, t)
        log_sequence_fit(rec, str(row.sequence_id), t, g.grown_volume_nl.to_numpy(float), vol,
                         measured_flow_m_s=g.flow_velocity_m_s.to_numpy(float), simulated_flow_m_s=vel)
    if arx_selection is not None:
        log_cv_table(rec, arx_selection.table.head(max_cv_rows), value_column="val_rmse_nl",
                     title="ARX structure selection")


def log_prediction(rec: "rr.RecordingStream", mc) -> None:
    """Log the per-time Monte Carlo band of a prediction (:class:`identify.montecarlo.MonteCarloResult`
    computed with ``band=True``): volume and flow velocity, mean between low and high."""
    b = mc.band
    if b is None:
        raise ValueError("the Monte Carlo result has no band: run it with band=True")
    name = f"u1={mc.u1_um_per_ms:g},u2={mc.u2_um:g}"
    log_monte_carlo_band(rec, name, b.delay_us, b.volume_mean_nl, b.volume_low_nl, b.volume_high_nl,
                         quantity="volume_nl")
    log_monte_carlo_band(rec, name, b.delay_us, b.flow_velocity_mean_m_s, b.flow_velocity_low_m_s,
                         b.flow_velocity_high_m_s, quantity="flow_m_s")
