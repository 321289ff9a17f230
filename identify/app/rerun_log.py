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

The view (:func:`identify_blueprint`, sent when the recording is closed, when every sequence is
known): one colour per sequence, from its (u1, u2) (:func:`sequence_colours`: hue by u1, darker
with u2), measured samples as points and the simulation as a line of the same colour, series named
by their (u1, u2); pinch-off instants as markers; small multiples (one plot per sequence, worst fit
first) beside the overview; the fit table (RMSE per sequence, worst first); the prediction as a
filled band against the delay with its confidence / prediction intervals at the pinch-off, and as
a star among the training (u1, u2) points.

Entity paths (``<name>`` = sequence / band name, escaped with ``rr.escape_entity_path_part``)
-----------------------------------------------------------------------------------------
``/identify/volume_nl/<name>/measured``     Scalars, drawn as points (colour of the sequence)
``/identify/volume_nl/<name>/simulated``    Scalars, drawn as a line (same colour)
``/identify/volume_nl/<name>/pinchoff``     Scalars, cross marker: measured pinch-off instant at
                                            the grown volume there (if given)
``/identify/volume_nl/<name>/pinchoff_simulated``  Scalars, diamond marker: simulated pinch-off
``/identify/flow_m_s/<name>/measured``      Scalars, points (only if given)
``/identify/flow_m_s/<name>/simulated``     Scalars, line (only if given)
``/identify/fit/table``                     static TextDocument: RMSE per sequence, worst first
``/identify/fit/rmse_nl``                   static BarChart: RMSE per sequence, worst first (bar k =
                                            row k of the fit table)
``/identify/controls/training``             static Points2D at (u1, u2) [y axis = u2, downwards],
                                            sequence colours, radius grows with the RMSE, labels
                                            shown: "<x> nl" (the RMSE; "worst: <x> nl")
``/identify/controls/worst``                static Boxes2D, red frame around the worst fit
``/identify/controls/prediction``           static Points2D, the predicted (u1, u2) (white)
``/identify/controls/prediction_box``       static Boxes2D around it, labelled (shown) with the
                                            prediction; ``.../prediction_crosshair`` LineStrips2D
                                            through it across the training range
``/identify/surfaces/<surface>``            static ViewCoordinates (z up)
``/identify/surfaces/<surface>/*``          static Transform3D on every child: z scaled so that the
                                            value range is 0.6 x the larger (u1, u2) range (the
                                            logged values stay true)
``/identify/surfaces/<surface>/mesh``       static Mesh3D: the polynomial over the training (u1, u2)
                                            range (25 x 25 grid), vertices (u1, u2, value), coloured
                                            by value (viridis)
``/identify/surfaces/<surface>/training``   static Points3D: the training targets (u1, u2, target),
                                            sequence colours, labels with target / surface / residual
``/identify/surfaces/<surface>/residuals``  static LineStrips3D: target -> surface, sequence colours
``/identify/surfaces/<surface>/prediction`` static Points3D: the surface at the predicted (u1, u2)
    ``<surface>``: ``pinchoff`` [us], ``volume_adjuster`` [nl], ``velocity_adjuster`` [m/s]
``/identify/cv/table``                      static TextDocument (markdown of the CV DataFrame)
``/identify/cv/bar``                        static BarChart of one CV column (if requested)
``/identify/monte_carlo/<quantity>/<name>/{mean,low,high}``   Scalars, lines
``/identify/monte_carlo/<quantity>/<name>/fill``   Scalars, translucent hatching low..high (the band)
``/identify/monte_carlo/<quantity>/<name>/<output>/{confidence,prediction}``   Scalars, two-sample
    segments: the interval of ``pinchoff_us`` (horizontal, at the mean grown volume at pinch-off),
    ``inflight_volume_nl`` / ``jetting_velocity_m_s`` (vertical, at the mean pinch-off)
``/identify/monte_carlo/<quantity>/<name>/<output>/mean``   Scalars, marker at the point prediction
``/identify/prediction/table``              static TextDocument: mean, confidence and prediction
                                            intervals of the prediction
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from dvcore.rerun_options import RerunOptions, options_from_args
from identify.app.rerun_stream import close_stream, delay_ns, open_stream

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
    "control_name",
    "log_model_fit",
    "log_prediction",
    "log_surfaces",
    "log_training_points",
    "sequence_colours",
    "SURFACES",
]

DEFAULT_APPLICATION_ID = "dropvision-identify"

# the viewer's background is dark: the prediction is drawn in white / gold / orange
_BAND = (245, 245, 245)
_BAND_FILL = (200, 200, 200, 60)
_BAND_EDGE = (170, 170, 170)
_CONFIDENCE = (255, 200, 0)
_PREDICTION = (255, 120, 0)
_PREDICTION_POINT = (255, 255, 255)
_WORST = (255, 60, 60)
#: colours of sequences logged without one (cycled)
_PALETTE = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
            (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]


def sequence_colours(u1: Any, u2: Any) -> list[tuple[int, int, int]]:
    """One RGB colour per (u1, u2): hue from u1 (red ... blue over the u1 range), darker and more
    saturated with u2, so that neighbours in the training grid have related but distinct colours.

    Parameters
    ----------
    u1, u2 : array (n,)
        Controls of the sequences (any units; only their ranks within the grid matter).
    """
    import colorsys

    x1 = _ranks(np.asarray(u1, dtype=float))
    x2 = _ranks(np.asarray(u2, dtype=float))
    out = []
    for a, b in zip(x1, x2):
        r, g, bl = colorsys.hsv_to_rgb(0.78 * a, 0.55 + 0.45 * b, 0.95 - 0.4 * b)
        out.append((int(round(255 * r)), int(round(255 * g)), int(round(255 * bl))))
    return out


def _ranks(x: np.ndarray) -> np.ndarray:
    """Position of each value among the distinct values, in [0, 1] (0.5 when all equal)."""
    levels = np.unique(x[np.isfinite(x)])
    if levels.size <= 1:
        return np.full(x.shape, 0.5)
    return np.searchsorted(levels, x) / (levels.size - 1)


def control_name(u1: float, u2: float) -> str:
    """Name of a sequence / prediction by its controls, e.g. ``"u1=70 u2=25"``."""
    return f"u1={float(u1):g} u2={float(u2):g}"


@dataclass
class _Sequence:
    name: str
    part: str
    colour: tuple[int, int, int]
    rmse_nl: float
    u1: float | None = None
    u2: float | None = None


@dataclass
class _State:
    sequences: list[_Sequence] = field(default_factory=list)
    bands: list[tuple[str, str]] = field(default_factory=list)  # (quantity part, name part)
    training: bool = False
    prediction: bool = False
    model: Any = None
    #: (view title, path part, (camera position, look target) in the view's space)
    surfaces: list[tuple[str, str, Any]] = field(default_factory=list)
    tuning: bool = False
    #: (title, prediction column) of each jetting-window map logged (a table model)
    window: list[tuple[str, str]] = field(default_factory=list)


_STATES: dict[int, _State] = {}


def _state(rec: rr.RecordingStream) -> _State:
    return _STATES.setdefault(id(rec), _State())


def identify_blueprint(sequences: Sequence[tuple[str, str]] = (), *, prediction: bool = True,
                       surfaces: Sequence[tuple[str, str]] = ()) -> rrb.Blueprint:
    """Layout of the identification recording.

    Left: all sequences in one volume plot and one flow plot (colour = sequence, points =
    measured, lines = simulated, markers = pinch-off). Right, top: which sequence fits worst and
    where the prediction lies: the (u1, u2) plane with the training points (labelled with their
    RMSE, the worst marked) and the predicted point, beside the RMSE bar chart (worst first) and the
    fit table. Right, bottom, tabs: the polynomial surfaces over (u1, u2) with the training
    targets (3-D, one view per surface); small multiples (one volume plot per sequence, worst fit
    first); the prediction band against the delay and its intervals; the cross-validation.

    Parameters
    ----------
    sequences : sequence of (name, escaped entity path part)
        The small multiples, in display order.
    prediction : bool
        Show the (u1, u2) plane and the prediction views.
    surfaces : sequence of (title, surface entity path part[, (eye position, look target)])
        The 3-D surface views (``/identify/surfaces/<part>``), with their camera.
    """
    import rerun.blueprint as rrb

    per_sequence: list[Any] = [
        rrb.TimeSeriesView(name=name, origin=f"/identify/volume_nl/{part}",
                           plot_legend=rrb.PlotLegend(visible=False))
        for name, part in sequences]
    fit_views: list[Any] = []
    if prediction:
        fit_views.append(rrb.Spatial2DView(
            name="(u1 right, u2 down): training points with their RMSE, prediction (white)",
            origin="/identify/controls"))
    fit_views.append(rrb.Tabs(
        rrb.BarChartView(name="RMSE per sequence [nl], worst first (bar k = row k of the table)",
                         origin="/identify/fit/rmse_nl"),
        rrb.TextDocumentView(name="fit per sequence (RMSE)", origin="/identify/fit/table"),
    ))
    tabs: list[Any] = []
    if surfaces:
        views3d = []
        for title, part, *eye in surfaces:
            controls = None
            if eye and eye[0] is not None:
                controls = rrb.EyeControls3D(position=eye[0][0], look_target=eye[0][1], eye_up=(0.0, 0.0, 1.0))
            views3d.append(rrb.Spatial3DView(name=title, origin=f"/identify/surfaces/{part}",
                                             eye_controls=controls))
        tabs.append(rrb.Horizontal(
            *views3d,
            name="surfaces over (u1, u2): mesh = polynomial, dots = training targets"))
    if per_sequence:
        tabs.append(rrb.Grid(*per_sequence, name="per sequence: volume (worst fit first)",
                             grid_columns=min(4, len(per_sequence))))
    if prediction:
        tabs += [
            rrb.TimeSeriesView(name="prediction: grown volume band [nl]", origin="/identify/monte_carlo/volume_nl"),
            rrb.TimeSeriesView(name="prediction: flow velocity band [m/s]", origin="/identify/monte_carlo/flow_m_s"),
            rrb.TextDocumentView(name="prediction intervals", origin="/identify/prediction/table"),
        ]
    tabs += [
        rrb.TextDocumentView(name="cross-validation table", origin="/identify/cv/table"),
        rrb.BarChartView(name="cross-validation", origin="/identify/cv/bar"),
    ]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.TimeSeriesView(name="grown volume [nl]: points measured, lines simulated, "
                                        "markers pinch-off", origin="/identify/volume_nl",
                                   plot_legend=rrb.PlotLegend(corner="LeftTop")),
                rrb.TimeSeriesView(name="flow velocity [m/s]: points measured, lines simulated",
                                   origin="/identify/flow_m_s", plot_legend=rrb.PlotLegend(visible=False)),
                row_shares=[3, 2],
            ),
            rrb.Vertical(
                rrb.Horizontal(*fit_views, column_shares=[3, 2] if len(fit_views) == 2 else None),
                rrb.Tabs(*tabs),
                row_shares=[1, 1],
            ),
            column_shares=[1, 1],
        ),
        rrb.TimePanel(timeline="delay", state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
        collapse_panels=False,
    )


def open_identify_recording(options: RerunOptions) -> rr.RecordingStream:
    """Open an explicit recording stream; :func:`close_recording` sends :func:`identify_blueprint`
    (it needs the sequences) as the default blueprint and finalises the file."""
    rec = open_stream(options, None)
    _STATES[id(rec)] = _State()
    return rec


def recording_from_args(args: argparse.Namespace, app_id: str = DEFAULT_APPLICATION_ID) -> rr.RecordingStream | None:
    """Recording from the ``dropvision.app.rerun_log.add_rerun_args`` flags, or None when off."""
    options = options_from_args(args, app_id)
    if options is not None:
        options = options.start_viewer()  # a viewer that cannot start: warned, work goes on
    return None if options is None or not options.enabled else open_identify_recording(options)


def close_recording(rec: rr.RecordingStream) -> None:
    """Send the blueprint and the fit table, then flush and finalise the sinks (writes the .rrd
    footer); never blocks on an unreachable viewer (:func:`identify.app.rerun_stream.close_stream`)."""
    import rerun as rr

    st = _STATES.pop(id(rec), _State())
    order = sorted(st.sequences, key=lambda q: -q.rmse_nl if math.isfinite(q.rmse_nl) else math.inf)
    if order:
        lines = ["## Fit per sequence (worst first)", "",
                 "RMSE of the simulated grown volume at the measured delays.", "",
                 "| sequence | u1 [um/ms] | u2 [um] | RMSE volume [nl] |", "|---|---|---|---|"]
        for q in order:
            lines.append(f"| {q.name} | {'' if q.u1 is None else f'{q.u1:g}'} | "
                         f"{'' if q.u2 is None else f'{q.u2:g}'} | {q.rmse_nl:.4g} |")
        rec.log("/identify/fit/table", rr.TextDocument("\n".join(lines), media_type="text/markdown"),
                static=True)
        rmse = np.array([q.rmse_nl for q in order], dtype=float)
        rec.log("/identify/fit/rmse_nl", rr.BarChart(np.nan_to_num(rmse, nan=0.0), color=(230, 80, 60),
                                                     abscissa=np.arange(1, rmse.size + 1)), static=True)
    if st.window and not order:
        blueprint = window_blueprint(st.window)
    elif st.tuning and not order:
        blueprint = tuning_blueprint()
    else:
        blueprint = identify_blueprint([(f"{q.rmse_nl:.2g} nl: {q.name}", q.part) for q in order],
                                       prediction=st.prediction or st.training or bool(st.bands),
                                       surfaces=st.surfaces)
    rec.send_blueprint(blueprint, make_active=True, make_default=True)
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


def _style(rec: rr.RecordingStream, path: str, name: str, colour: tuple[int, ...], *,
           points: bool, width: float = 2.0, marker: str = "circle", marker_size: float = 3.0) -> None:
    import rerun as rr

    if points:
        rec.log(path, rr.SeriesPoints(names=name, colors=colour, markers=marker,
                                      marker_sizes=marker_size), static=True)
    else:
        rec.log(path, rr.SeriesLines(names=name, colors=colour, widths=width), static=True)


def _send_rows(rec: rr.RecordingStream, path: str, t_us: Sequence[float], values: Sequence[float]) -> None:
    """Send rows as given (repeated delays allowed: a vertical segment in a time-series plot)."""
    import rerun as rr

    t = np.asarray(t_us, dtype=float)
    v = np.asarray(values, dtype=float)
    keep = np.isfinite(t) & np.isfinite(v)
    if keep.any():
        rec.send_columns(path, indexes=[_delay_column(t[keep])], columns=rr.Scalars.columns(scalars=v[keep]))


def _rmse(t: np.ndarray, measured: np.ndarray, ts: np.ndarray, simulated: np.ndarray) -> float:
    """RMSE of the simulation (linearly interpolated at the measured delays) against the measurement."""
    ok_s = np.isfinite(ts) & np.isfinite(simulated)
    if ok_s.sum() < 1:
        return math.nan
    order = np.argsort(ts[ok_s])
    tt, ss = ts[ok_s][order], simulated[ok_s][order]
    ok = np.isfinite(t) & np.isfinite(measured) & (t >= tt[0]) & (t <= tt[-1])
    if not ok.any():
        return math.nan
    return float(np.sqrt(np.mean((np.interp(t[ok], tt, ss) - measured[ok]) ** 2)))


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
                     sim_t_us: Sequence[float] | np.ndarray | None = None,
                     colour: tuple[int, int, int] | None = None,
                     controls: tuple[float, float] | None = None,
                     pinchoff: tuple[float, float] | None = None,
                     simulated_pinchoff: tuple[float, float] | None = None) -> None:
    """Log measured vs simulated grown volume (and flow velocity) of one sequence.

    Parameters
    ----------
    rec : rerun.RecordingStream
        From :func:`open_identify_recording`.
    name : str
        Sequence name (entity path part, escaped; also the legend name), e.g.
        :func:`control_name` ``(u1, u2)``.
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
    colour : (r, g, b), optional
        Colour of every series of this sequence (:func:`sequence_colours`); default: the next
        colour of a 10-colour palette.
    controls : (u1, u2), optional
        The sequence's controls, for the fit table.
    pinchoff, simulated_pinchoff : (t_us, volume_nl), optional
        Measured / simulated pinch-off instant and the grown volume there: a cross / diamond
        marker on the volume plot.
    """
    part = _part(name)
    st = _state(rec)
    if colour is None:
        colour = _PALETTE[len(st.sequences) % len(_PALETTE)]
    colour = tuple(int(c) for c in colour)
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
    rmse = _rmse(t, series[0][2], ts, series[1][2])
    for quantity, kind, values, times in series:
        path = f"/identify/{quantity}/{part}/{kind}"
        label = f"{name} {kind}"
        if quantity == "volume_nl" and kind == "simulated" and math.isfinite(rmse):
            label += f" (RMSE {rmse:.2g} nl)"
        _style(rec, path, label, colour, points=kind == "measured")
        _send_series(rec, path, times, values)
    for kind, marker, at in (("pinchoff", "cross", pinchoff), ("pinchoff_simulated", "diamond", simulated_pinchoff)):
        if at is None:
            continue
        path = f"/identify/volume_nl/{part}/{kind}"
        _style(rec, path, f"{name} {kind.replace('_', ' ')}", colour, points=True, marker=marker,
               marker_size=7.0)
        _send_rows(rec, path, [at[0]], [at[1]])
    u1, u2 = (None, None) if controls is None else (float(controls[0]), float(controls[1]))
    st.sequences.append(_Sequence(name, part, colour, rmse, u1, u2))


def log_training_points(rec: rr.RecordingStream) -> None:
    """Log the (u1, u2) of the sequences logged so far (with ``controls``) at
    ``/identify/controls/training``: their colours, radius growing with the RMSE, labels shown:
    the RMSE (``"worst: <x> nl"`` on the sequence with the largest; the position names the
    sequence)."""
    import rerun as rr

    seqs = [q for q in _state(rec).sequences if q.u1 is not None]
    if not seqs:
        return
    rmse = np.array([q.rmse_nl for q in seqs])
    top = np.nanmax(rmse) if np.isfinite(rmse).any() and np.nanmax(rmse) > 0 else 1.0
    radii = [0.4 + 0.8 * (0.0 if not math.isfinite(r) else r / top) for r in rmse]
    worst = int(np.nanargmax(rmse)) if np.isfinite(rmse).any() else -1
    labels = [f"{'worst: ' if i == worst else ''}{q.rmse_nl:.2g} nl" for i, q in enumerate(seqs)]
    rec.log("/identify/controls/training", rr.Points2D(
        [(q.u1, q.u2) for q in seqs], colors=[q.colour for q in seqs], radii=radii,
        labels=labels, show_labels=True), static=True)
    if worst >= 0:  # a red frame around the worst-fitting sequence
        q = seqs[worst]
        r = radii[worst] * 1.6
        rec.log("/identify/controls/worst", rr.Boxes2D(
            centers=[(q.u1, q.u2)], half_sizes=[(r, r)], colors=[_WORST], radii=-2.0,
            labels=[f"worst fit: {q.name}"], show_labels=False), static=True)
    _state(rec).training = True


#: the polynomial surfaces of the hybrid model: (model attribute, training column, title, unit)
SURFACES = (("pinchoff", "pinchoff_us", "pinch-off instant", "us"),
            ("volume_adjuster", "volume_adjustment_nl", "volume adjuster", "nl"),
            ("velocity_adjuster", "velocity_adjustment_m_s", "velocity adjuster", "m/s"))
_VIRIDIS = np.array([(68, 1, 84), (59, 82, 139), (33, 145, 140), (94, 201, 98), (253, 231, 37)], dtype=float)


def _viridis(x: np.ndarray) -> np.ndarray:
    """RGB (uint8) of values in [0, 1] on a 5-stop viridis scale."""
    x = np.clip(np.nan_to_num(np.asarray(x, dtype=float), nan=0.0), 0.0, 1.0) * (len(_VIRIDIS) - 1)
    i = np.minimum(x.astype(int), len(_VIRIDIS) - 2)
    f = (x - i)[..., None]
    return np.round(_VIRIDIS[i] * (1 - f) + _VIRIDIS[i + 1] * f).astype(np.uint8)


def _grid_triangles(n1: int, n2: int) -> np.ndarray:
    """Two triangles per cell of an (n2, n1) vertex grid stored row by row."""
    i, j = np.meshgrid(np.arange(n2 - 1), np.arange(n1 - 1), indexing="ij")
    a = (i * n1 + j).ravel()
    b, c, d = a + 1, a + n1, a + n1 + 1
    return np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])]).astype(np.uint32)


def log_surfaces(rec: rr.RecordingStream, model: Any, training: pd.DataFrame, *,
                 colours: Sequence[tuple[int, int, int]] | None = None,
                 names: Sequence[str] | None = None, grid: int = 25) -> None:
    """Log the pinch-off and adjuster polynomials of ``model`` over (u1, u2) with their training
    targets, one 3-D scene per surface at ``/identify/surfaces/<surface>`` (:data:`SURFACES`).

    Each scene: the polynomial on a ``grid`` x ``grid`` mesh over the training (u1, u2) range,
    coloured by value (viridis, low = violet, high = yellow); the training targets as dots in
    their sequence colours, with a line to the surface (the residual). Positions are the true
    values (u1 [um/ms], u2 [um], value in the surface's unit; hover a dot for its numbers); a
    ``Transform3D`` on every entity scales the value axis so that its range is 0.6 x the larger
    control range (the scene is readable whatever the unit).

    Parameters
    ----------
    rec : rerun.RecordingStream
    model : identify.hybrid.HybridModel
        Its ``pinchoff``, ``volume_adjuster`` and ``velocity_adjuster`` polynomials.
    training : pandas.DataFrame
        One row per sequence: ``u1_um_per_ms``, ``u2_um`` and the targets (columns of
        :data:`SURFACES`, e.g. :func:`identify.app.report.training_targets`).
    colours, names : sequence, optional
        Colour and name of each row (default: :func:`sequence_colours`, :func:`control_name`).
    """
    import rerun as rr

    u1 = training["u1_um_per_ms"].to_numpy(float)
    u2 = training["u2_um"].to_numpy(float)
    ok_u = np.isfinite(u1) & np.isfinite(u2)
    if not ok_u.any():
        return
    colours = list(colours) if colours is not None else sequence_colours(u1, u2)
    names = list(names) if names is not None else [control_name(a, b) for a, b in zip(u1, u2)]
    lo1, hi1 = float(u1[ok_u].min()), float(u1[ok_u].max())
    lo2, hi2 = float(u2[ok_u].min()), float(u2[ok_u].max())
    if hi1 == lo1:
        lo1, hi1 = lo1 - 1.0, hi1 + 1.0
    if hi2 == lo2:
        lo2, hi2 = lo2 - 1.0, hi2 + 1.0
    g1, g2 = np.meshgrid(np.linspace(lo1, hi1, grid), np.linspace(lo2, hi2, grid))
    span = max(hi1 - lo1, hi2 - lo2)
    st = _state(rec)
    for attr, column, title, unit in SURFACES:
        poly = getattr(model, attr, None)
        if poly is None or column not in training.columns:
            continue
        z = np.asarray(poly.predict(g1, g2), dtype=float)
        target = training[column].to_numpy(float)
        at = np.asarray(poly.predict(u1, u2), dtype=float)
        ok = ok_u & np.isfinite(target) & np.isfinite(at)
        values = np.concatenate([z[np.isfinite(z)], target[ok], at[ok]])
        if values.size == 0:
            continue
        zmin, zmax = float(values.min()), float(values.max())
        if zmax <= zmin:
            zmax = zmin + 1.0
        k = 0.6 * span / (zmax - zmin)
        transform = rr.Transform3D(translation=(0.0, 0.0, -k * zmin), scale=(1.0, 1.0, k))
        base = f"/identify/surfaces/{attr}"
        rec.log(base, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for child in ("mesh", "training", "residuals", "prediction"):
            rec.log(f"{base}/{child}", transform, static=True)
        rec.log(f"{base}/mesh", rr.Mesh3D(
            vertex_positions=np.column_stack([g1.ravel(), g2.ravel(), z.ravel()]),
            triangle_indices=_grid_triangles(grid, grid),
            vertex_colors=_viridis((z.ravel() - zmin) / (zmax - zmin))), static=True)
        idx = np.flatnonzero(ok)
        rmse = float(np.sqrt(np.mean((target[ok] - at[ok]) ** 2))) if idx.size else math.nan
        if idx.size:
            rec.log(f"{base}/training", rr.Points3D(
                np.column_stack([u1[ok], u2[ok], target[ok]]), colors=[colours[i] for i in idx], radii=-6.0,
                labels=[f"{names[i]}: {target[i]:.4g} {unit} (surface {at[i]:.4g}, residual "
                        f"{target[i] - at[i]:+.2g})" for i in idx], show_labels=False), static=True)
            rec.log(f"{base}/residuals", rr.LineStrips3D(
                [[(u1[i], u2[i], target[i]), (u1[i], u2[i], at[i])] for i in idx],
                colors=[colours[i] for i in idx], radii=-1.5), static=True)
        label = f"{title} [{unit}]" + (f", RMSE {rmse:.2g}" if math.isfinite(rmse) else "")
        # camera: in front (low u2), left (low u1) and above, far enough for the whole surface
        centre = np.array([(lo1 + hi1) / 2, (lo2 + hi2) / 2, 0.3 * span])
        eye = (tuple(centre + span * np.array([-0.9, -1.9, 1.1])), tuple(centre))
        st.surfaces = [q for q in st.surfaces if q[1] != attr] + [(label, attr, eye)]


def _log_surface_prediction(rec: rr.RecordingStream, model: Any, u1: float, u2: float) -> None:
    """The surfaces at the predicted (u1, u2): a white dot per logged surface scene."""
    import rerun as rr

    units = {attr: unit for attr, _c, _t, unit in SURFACES}
    for _label, attr, _eye in _state(rec).surfaces:
        poly = getattr(model, attr, None)
        if poly is None:
            continue
        value = float(np.asarray(poly.predict(np.array([u1]), np.array([u2])), dtype=float).ravel()[0])
        if not math.isfinite(value):
            continue
        rec.log(f"/identify/surfaces/{attr}/prediction", rr.Points3D(
            [(u1, u2, value)], colors=[_PREDICTION_POINT], radii=-9.0,
            labels=[f"prediction: {value:.4g} {units[attr]}"], show_labels=True), static=True)


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
                         high: Sequence[float] | np.ndarray, *, quantity: str = "volume_nl",
                         fill_samples: int = 200) -> None:
    """Log a Monte Carlo band (mean and low/high bounds, e.g. 2.5 % / 97.5 %) over delay.

    The mean is a thick dark line, the bounds thin grey lines, and ``fill`` a translucent
    hatching of ``fill_samples`` vertical strokes from low to high (Rerun 0.41 time-series plots
    have no filled area).

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
    fill_samples : int
        Number of hatching strokes (0: no fill).
    """
    t = _vector("t_us", t_us)
    m = _vector("mean", mean, t.size)
    lo = _vector("low", low, t.size)
    hi = _vector("high", high, t.size)
    both = np.isfinite(lo) & np.isfinite(hi)
    if np.any(lo[both] > hi[both]):
        raise ValueError("log_monte_carlo_band: low > high at some times (swapped bounds?)")
    qpart, npart = _part(quantity), _part(name)
    base = f"/identify/monte_carlo/{qpart}/{npart}"
    for kind, values, colour, width in (("mean", m, _BAND, 2.5), ("low", lo, _BAND_EDGE, 1.0),
                                        ("high", hi, _BAND_EDGE, 1.0)):
        path = f"{base}/{kind}"
        _style(rec, path, f"{name} {kind}", colour, points=False, width=width)
        _send_series(rec, path, t, values)
    ok = both & np.isfinite(t)
    if fill_samples > 0 and ok.sum() >= 2:
        tt = np.linspace(t[ok].min(), t[ok].max(), int(fill_samples))
        order = np.argsort(t[ok])
        flo = np.interp(tt, t[ok][order], lo[ok][order])
        fhi = np.interp(tt, t[ok][order], hi[ok][order])
        # lo(t0) hi(t0) hi(t1) lo(t1) lo(t2) ...: vertical strokes joined along the bounds
        pairs = np.where((np.arange(tt.size) % 2 == 0)[:, None], np.column_stack([flo, fhi]),
                         np.column_stack([fhi, flo]))
        _style(rec, f"{base}/fill", f"{name} band", _BAND_FILL, points=False, width=1.0)
        _send_rows(rec, f"{base}/fill", np.repeat(tt, 2), pairs.ravel())
    st = _state(rec)
    if (qpart, npart) not in st.bands:
        st.bands.append((qpart, npart))


def log_model_fit(rec: rr.RecordingStream, dataset: Any, model: Any, arx_selection: Any = None, *,
                  max_cv_rows: int = 20) -> None:
    """Log an identified model against its training dataset.

    For every sequence of ``dataset`` (an :class:`identify.dataset.Dataset`), named by its
    (u1, u2) and coloured by :func:`sequence_colours`: the measured grown volume and flow velocity
    before pinch-off and the nominal ECM simulation of ``model``
    (:class:`identify.hybrid.HybridModel`) at the same delays, the measured and simulated
    pinch-off instants; the training points in the (u1, u2) plane; the ARX structure-selection
    table when given. The model is kept for :func:`log_prediction` on the same recording.
    """
    ts = dataset.timeseries
    summary = dataset.summary.reset_index(drop=True)
    u1s = summary.u1_um_per_ms.to_numpy(float)
    u2s = summary.u2_um.to_numpy(float)
    colours = sequence_colours(u1s, u2s)
    names = [control_name(a, b) for a, b in zip(u1s, u2s)]
    dup = {n for n in names if names.count(n) > 1}
    for i, row in enumerate(summary.itertuples()):
        g = ts[(ts.sequence_id == row.sequence_id) & ts.attached].sort_values("delay_us")
        if len(g) < 2:
            continue
        name = names[i] + (f" ({row.sequence_id})" if names[i] in dup else "")
        t = g.delay_us.to_numpy(float)
        vol, vel = model.simulate(row.u1_um_per_ms, row.u2_um, t)
        nominal = model.nominal(row.u1_um_per_ms, row.u2_um)
        pin = (float(row.pinchoff_us), float(getattr(row, "grown_volume_at_pinchoff_nl", math.nan)))
        log_sequence_fit(rec, name, t, g.grown_volume_nl.to_numpy(float), vol,
                         measured_flow_m_s=g.flow_velocity_m_s.to_numpy(float), simulated_flow_m_s=vel,
                         colour=colours[i], controls=(float(u1s[i]), float(u2s[i])), pinchoff=pin,
                         simulated_pinchoff=(nominal["pinchoff_us"], nominal["grown_volume_at_pinchoff_nl"]))
    log_training_points(rec)
    try:
        from identify.app.report import training_targets

        training = training_targets(model, dataset)
    except Exception as exc:  # noqa: BLE001 - the view without surfaces rather than no recording
        import warnings

        warnings.warn(f"rerun: polynomial surfaces not logged ({type(exc).__name__}: {exc})", stacklevel=2)
    else:
        log_surfaces(rec, model, training, colours=colours,
                     names=[n + (f" ({sid})" if n in dup else "") for n, sid in zip(names, summary.sequence_id)])
    _state(rec).model = model
    if arx_selection is not None:
        log_cv_table(rec, arx_selection.table.head(max_cv_rows), value_column="val_rmse_nl",
                     title="ARX structure selection")


def log_prediction(rec: rr.RecordingStream, mc: Any, *, model: Any = None, level: float = 0.95) -> None:
    """Log a prediction (:class:`identify.montecarlo.MonteCarloResult` computed with ``band=True``).

    * the per-time Monte Carlo band of the grown volume and of the flow velocity (mean between
      low and high, filled);
    * at the pinch-off: the confidence and prediction intervals (``level``) of the pinch-off
      instant (horizontal segments), of the in-flight volume (vertical, volume plot) and of the
      jetting velocity (vertical, flow plot), from ``model.interval_prediction`` (the model given,
      else the one of :func:`log_model_fit` on this recording; without a model: the Monte Carlo
      percentiles, as the confidence interval only);
    * the predicted (u1, u2) among the training points (``model.controls`` when they were not
      logged by :func:`log_model_fit`) and a table of the intervals.
    """
    import rerun as rr

    b = mc.band
    if b is None:
        raise ValueError("the Monte Carlo result has no band: run it with band=True")
    st = _state(rec)
    model = model if model is not None else st.model
    u1, u2 = float(mc.u1_um_per_ms), float(mc.u2_um)
    name = control_name(u1, u2)
    log_monte_carlo_band(rec, name, b.delay_us, b.volume_mean_nl, b.volume_low_nl, b.volume_high_nl,
                         quantity="volume_nl")
    log_monte_carlo_band(rec, name, b.delay_us, b.flow_velocity_mean_m_s, b.flow_velocity_low_m_s,
                         b.flow_velocity_high_m_s, quantity="flow_m_s")

    if model is not None and callable(getattr(model, "interval_prediction", None)):
        iv = model.interval_prediction(u1, u2, level=level, mc=mc)
        how = f"{100 * level:g} % intervals of the hybrid model"
    else:
        iv = {}
        for k, v in mc.summary().items():
            iv[k] = {"mean": v["mean"], "parameters_only_low": v["parameters_only_low"],
                     "parameters_only_high": v["parameters_only_high"], "mean_drop_low": math.nan,
                     "mean_drop_high": math.nan, "one_drop_low": math.nan, "one_drop_high": math.nan}
        lo_p, hi_p = getattr(mc, "percentiles", (2.5, 97.5))
        how = f"Monte Carlo {lo_p:g} / {hi_p:g} % percentiles, parameters only (no model: no mean-drop or one-drop interval)"
    grown = np.asarray(mc.samples.get("grown_volume_at_pinchoff_nl", [math.nan]), dtype=float)
    v_at = float(np.mean(grown)) if grown.size else math.nan
    t_p = float(iv["pinchoff_us"]["mean"]) if "pinchoff_us" in iv else math.nan
    qv, qf = _part("volume_nl"), _part("flow_m_s")
    npart = _part(name)
    segments = [("pinchoff_us", qv, True, v_at), ("inflight_volume_nl", qv, False, t_p),
                ("jetting_velocity_m_s", qf, False, t_p)]
    for output, qpart, horizontal, at in segments:
        e = iv.get(output)
        if e is None or not math.isfinite(at):
            continue
        base = f"/identify/monte_carlo/{qpart}/{npart}/{output}"
        # entity names stay confidence / prediction; the keys name what they cover (mean drop / one drop)
        for kind, key, colour, width in (("prediction", "one_drop", _PREDICTION, 6.0),
                                         ("confidence", "mean_drop", _CONFIDENCE, 3.0)):
            lo, hi = float(e[f"{key}_low"]), float(e[f"{key}_high"])
            if not (math.isfinite(lo) and math.isfinite(hi)):
                continue
            _style(rec, f"{base}/{kind}", f"{output} {kind} interval", colour, points=False, width=width)
            if horizontal:
                _send_rows(rec, f"{base}/{kind}", [lo, hi], [at, at])
            else:
                _send_rows(rec, f"{base}/{kind}", [at, at], [lo, hi])
        _style(rec, f"{base}/mean", f"{output} predicted", _PREDICTION_POINT, points=True,
               marker="diamond" if horizontal else "circle", marker_size=6.0)
        if horizontal:
            _send_rows(rec, f"{base}/mean", [e["mean"]], [at])
        else:
            _send_rows(rec, f"{base}/mean", [at], [e["mean"]])

    # the (u1, u2) plane: training points and the predicted point
    if not st.training and model is not None and getattr(model, "controls", None) is not None:
        c = np.asarray(model.controls, dtype=float).reshape(-1, 2)
        rec.log("/identify/controls/training", rr.Points2D(
            c, colors=sequence_colours(c[:, 0], c[:, 1]), radii=0.6,
            labels=[control_name(a, b) for a, b in c], show_labels=False), static=True)
        st.training = True
    if model is not None and st.surfaces:
        _log_surface_prediction(rec, model, u1, u2)
    label = f"prediction {name}"
    if "inflight_volume_nl" in iv:
        e = iv["inflight_volume_nl"]
        label += f": in-flight {e['mean']:.3g} nl"
    rec.log("/identify/controls/prediction", rr.Points2D(
        [(u1, u2)], colors=[_PREDICTION_POINT], radii=1.2, labels=[label], show_labels=False), static=True)
    # a labelled box around it (the label clear of a training point's label at the same place) and
    # a crosshair across the training range: where the prediction lies among the data
    grid_u = (np.asarray(model.controls, dtype=float).reshape(-1, 2)
              if model is not None and getattr(model, "controls", None) is not None else np.array([[u1, u2]]))
    lo, hi = np.minimum(grid_u.min(0), (u1, u2)), np.maximum(grid_u.max(0), (u1, u2))
    steps = [np.diff(np.unique(grid_u[:, k])) for k in (0, 1)]
    half = [0.45 * (float(d.min()) if d.size else 1.0) for d in steps]
    short = "prediction" + (f" {iv['inflight_volume_nl']['mean']:.3g} nl" if "inflight_volume_nl" in iv else "")
    rec.log("/identify/controls/prediction_box", rr.Boxes2D(
        centers=[(u1, u2)], half_sizes=[half], colors=[_PREDICTION_POINT], radii=-1.5, labels=[short],
        show_labels=True), static=True)
    rec.log("/identify/controls/prediction_crosshair", rr.LineStrips2D(
        [[(lo[0] - half[0], u2), (hi[0] + half[0], u2)], [(u1, lo[1] - half[1]), (u1, hi[1] + half[1])]],
        colors=[(255, 255, 255, 110)], radii=-0.75), static=True)
    lines = [f"## Prediction at {name}", "", how, "",
             "| output | mean | parameters only low | parameters only high | mean drop (confidence) low | "
             "mean drop (confidence) high | one drop (prediction) low | one drop (prediction) high |",
             "|---|---|---|---|---|---|---|---|"]
    for k, e in iv.items():
        cells = [e.get(c, math.nan) for c in ("mean", "parameters_only_low", "parameters_only_high", "mean_drop_low",
                                              "mean_drop_high", "one_drop_low", "one_drop_high")]
        lines.append(f"| {k} | " + " | ".join("" if not math.isfinite(float(x)) else f"{float(x):.4g}"
                                             for x in cells) + " |")
    rec.log("/identify/prediction/table", rr.TextDocument("\n".join(lines), media_type="text/markdown"),
            static=True)
    st.prediction = True


# --- closed-loop tuning (identify tune) --------------------------------------------------------

_TUNING_OUTPUTS = (("volume", "nl", "in-flight volume [nl]"), ("velocity", "m_s", "jetting velocity [m/s]"))


def log_jetting_window(rec: rr.RecordingStream, model: Any) -> None:
    """Log a table model's jetting window (issue 31 item 4), the maps of the report's
    ``jetting_window.png`` (`identify.app.tabular_report`): per count output the probability of each
    count, per continuous output its prediction, over the two inputs that move the window most, the
    others held at their training medians.

    * ``/identify/window/<column>``: an image per map (viridis: 0 to 1 for a probability, the map's
      own range otherwise; the first input to the right, the second downwards, grey where the
      setting lies outside the training region);
    * ``/identify/window/<column>/training``: the training settings as points in the same pixels;
    * ``/identify/window/about``: the axes, their ranges, the held values and each map's range.
    """
    import rerun as rr

    from identify.app.tabular_report import held_point, map_axes, window_grid, window_panels

    ax_i, ax_j = map_axes(model)
    held = held_point(model)
    gi, gj, pred = window_grid(model, ax_i, ax_j, held)
    n = gi.shape[0]
    outside = pred["outside_training_region"].to_numpy(bool).reshape(gi.shape)
    lo_i, hi_i = model.region.low[ax_i], model.region.high[ax_i]
    lo_j, hi_j = model.region.low[ax_j], model.region.high[ax_j]
    X = model.data[model.inputs].to_numpy(float)
    px = np.column_stack([(X[:, ax_i] - lo_i) / max(hi_i - lo_i, 1e-300) * (n - 1) + 0.5,
                          (X[:, ax_j] - lo_j) / max(hi_j - lo_j, 1e-300) * (n - 1) + 0.5])
    lines = [f"## Jetting window over ({model.inputs[ax_i]} right, {model.inputs[ax_j]} down)", "",
             f"{model.inputs[ax_i]}: {lo_i:g} to {hi_i:g}; {model.inputs[ax_j]}: {lo_j:g} to {hi_j:g}; "
             + ("held: " + ", ".join(f"{nm} = {v:g}" for k, (nm, v) in enumerate(zip(model.inputs, held))
                                     if k not in (ax_i, ax_j)) if len(model.inputs) > 2 else "no other input"),
             "", "| map | low | high |", "|---|---|---|"]
    for col, title, prob in window_panels(model):
        z = pred[col].to_numpy(float).reshape(gi.shape)
        lo, hi = (0.0, 1.0) if prob else (float(np.nanmin(z)), float(np.nanmax(z)))
        rgb = _viridis((z - lo) / (hi - lo) if hi > lo else np.zeros_like(z))
        rgb[outside] = (128, 128, 128)
        rec.log(f"/identify/window/{col}", rr.Image(rgb), static=True)
        rec.log(f"/identify/window/{col}/training", rr.Points2D(px, radii=0.4, colors=(200, 200, 200)), static=True)
        lines.append(f"| {title} | {lo:.4g} | {hi:.4g} |")
    rec.log("/identify/window/about", rr.TextDocument("\n".join(lines), media_type="text/markdown"), static=True)
    _state(rec).window = [(title, col) for col, title, _ in window_panels(model)]


def window_blueprint(panels: Sequence[tuple[str, str]]) -> rrb.Blueprint:
    """Layout of a table model's recording: one 2-D view per map of the jetting window, and the
    axes and ranges as text."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Grid(*[rrb.Spatial2DView(name=title, origin=f"/identify/window/{col}") for title, col in panels],
                 rrb.TextDocumentView(name="axes, held values, ranges", origin="/identify/window/about")),
        rrb.SelectionPanel(state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
        collapse_panels=False,
    )


def tuning_blueprint() -> rrb.Blueprint:
    """Layout of a tuning recording: per output the measured drop, the target and the model's
    bias-corrected prediction with its one-drop interval against the shot; the path of the
    proposals in the (u1, u2) plane among the training points; the shot table."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(*[rrb.TimeSeriesView(name=f"{title}: measured (points), target, corrected prediction "
                                                   "and its one-drop interval", origin=f"/identify/tuning/{o}_{u}")
                           for o, u, title in _TUNING_OUTPUTS]),
            rrb.Vertical(
                rrb.Spatial2DView(name="(u1 right, u2 down): proposals shot by shot among the training points",
                                  origin="/identify/tuning/controls"),
                rrb.TextDocumentView(name="shots", origin="/identify/tuning/table"),
            ),
            column_shares=[1, 1],
        ),
        rrb.TimePanel(timeline="shot", state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
        collapse_panels=False,
    )


def log_tuning(rec: rr.RecordingStream, result: Any, *, model: Any = None) -> None:
    """Log a closed-loop tuning run (:class:`identify.tuning.TuningResult`) on the ``shot`` timeline.

    * ``/identify/tuning/volume_nl`` and ``/identify/tuning/velocity_m_s``: ``measured``,
      ``target``, ``corrected`` (the model's prediction x (1 + bias before the shot)) and the
      corrected prediction's one-drop interval ``one_drop_low``/``one_drop_high``;
    * ``/identify/tuning/controls``: the proposals' path in (u1, u2) and, with ``model``, its
      training points;
    * ``/identify/tuning/table``: the shots as a markdown table.
    """
    import rerun as rr

    from identify.tuning import OUTPUT_COLUMNS

    df = result.to_pandas()
    shots = df["shot"].to_numpy(dtype=np.int64)
    targets = {"volume": result.target_volume_nl, "velocity": result.target_velocity_m_s}
    for o, u, title in _TUNING_OUTPUTS:
        base = f"/identify/tuning/{o}_{u}"
        col = OUTPUT_COLUMNS[o]
        series = {"measured": df[col.measured], "corrected": df[col.corrected],
                  "one_drop_low": df[col.one_drop_low], "one_drop_high": df[col.one_drop_high]}
        if targets[o] is not None:
            series["target"] = np.full(len(df), float(targets[o]))
        for name, values in series.items():
            v = np.asarray(values, dtype=float)
            keep = np.isfinite(v)
            if not keep.any():
                continue
            colour = {"measured": _PREDICTION_POINT, "target": (80, 200, 120), "corrected": _PREDICTION}.get(
                name, _CONFIDENCE)
            _style(rec, f"{base}/{name}", f"{o} {name.replace('_', ' ')}", colour, points=name == "measured",
                   marker_size=5.0)
            rec.send_columns(f"{base}/{name}", indexes=[rr.TimeColumn("shot", sequence=shots[keep])],
                             columns=rr.Scalars.columns(scalars=v[keep]))
    path = df[["u1_um_per_ms", "u2_um"]].to_numpy(dtype=float)
    if model is not None and getattr(model, "controls", None) is not None:
        c = np.asarray(model.controls, dtype=float).reshape(-1, 2)
        rec.log("/identify/tuning/controls/training", rr.Points2D(c, colors=[(120, 120, 120)], radii=0.6), static=True)
    rec.log("/identify/tuning/controls/path", rr.LineStrips2D([path], colors=[_PREDICTION], radii=-1.0), static=True)
    rec.log("/identify/tuning/controls/shots", rr.Points2D(
        path, colors=[(80, 200, 120) if w else _PREDICTION_POINT for w in df["within_tolerance"]], radii=0.5,
        labels=[f"shot {k}" for k in shots], show_labels=True), static=True)
    cols = ["shot", "u1_um_per_ms", "u2_um", "corrected_volume_nl", "measured_volume_nl", "volume_error_percent",
            "volume_bias_percent", "volume_bias_se_percent", "within_tolerance"]
    rec.log("/identify/tuning/table", rr.TextDocument(
        _markdown(df[cols].set_index("shot"), f"Tuning: {result.message}"), media_type="text/markdown"), static=True)
    _state(rec).tuning = True
