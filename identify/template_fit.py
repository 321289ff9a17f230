"""The hybrid model (Eq. 8) on a waveform template: the ECM driven by any template's drive, the
pinch-off instant and the adjusters linear in the lab's own waveform parameters (issue 31).

:func:`fit_template_model` takes one row per sequence (the parameters, in the template's names
and units, and the measured end points) and the sequences' growing-volume time series, as
`dropvision` measures them (:func:`sequence_tables` turns one measured sequence into them), and
returns a :class:`TemplateModel`:

- the ECM of Eqs. (4)-(6), identified by :func:`identify.ecm_fit.fit_ecm` (output error) from the
  grown volume up to pinch-off with the template's drive as its input (simulated on a grid ten
  times finer than the strobe delays, so that pulse edges between two delays are followed);
  physical parameters Ra, CN, Kc (La fixed) where the hydraulics of Eq. (2) are known;
- the pinch-off instant (µs after the trigger), the volume adjuster (nl) and the velocity adjuster
  (m/s) as first-order polynomials of the parameters that vary in the training data (Eq. 7 at
  n1 = n2 = 1, the paper's choice for its (u1, u2), Eqs. 15-17), least squares on centred, scaled
  parameters; parameters constant in the training data are recorded and required at prediction;
- prediction (:meth:`TemplateModel.predict`): the grown volume at the predicted pinch-off instant
  plus the volume adjuster, the ECM flow velocity at the template's velocity instant (the paper:
  the maximum stroke) plus the velocity adjuster, exact for the piecewise-linear drive
  (:func:`identify.ecm.pwl_response`).

Adjuster targets are the paper-consistent ``"ecm"`` reference of :mod:`identify.hybrid`: measured
in-flight volume minus the ECM volume at the measured pinch-off instant; measured jetting velocity
minus the ECM flow velocity at the velocity instant.

With the trapezoid template this is the (u1, u2) hybrid model at polynomial orders (1, 1) without
the intervals of :mod:`identify.hybrid` (no order selection, no Monte Carlo): the paper's case is
one case of it, and its figures stay with :func:`identify.hybrid_fit.fit_hybrid`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from dvcore import schema
from identify.ecm import COEFF_NAMES, EcmCoefficients, flow_velocity_m_s, pwl_response
from identify.ecm_fit import EcmData, EcmFit, fit_ecm
from identify.hydraulics import Hydraulics
from identify.model_file import ModelFileError, check_ecm_coefficients, check_nozzle_and_dead_time
from identify.waveform import Drive, WaveformTemplate, template_from_dict

#: Outputs of :meth:`TemplateModel.predict` compared with the measured ones.
OUTPUTS = ("pinchoff_us", "inflight_volume_nl", "jetting_velocity_m_s")
#: Columns of :meth:`TemplateModel.predict_table` (`identify predict --table` of a template model;
#: ``dvcore.schema.TEMPLATE_PREDICTION``).
PREDICTION_COLUMNS = ("pinchoff_us", "grown_volume_at_pinchoff_nl", "inflight_volume_nl", "jetting_velocity_m_s",
                      "flow_velocity_at_velocity_instant_m_s", "outside_training_region", "outside_training_region_why")
#: The linear laws of the model, by the output they give.
LAWS = ("pinchoff", "volume_adjuster", "velocity_adjuster")
#: Fewest attached samples from delay 0 for a sequence to enter the ECM fit.
MIN_RUN_SAMPLES = 8


@dataclass
class LinearFit:
    """``z = c0 + sum_k c_k (x_k - centre_k) / scale_k`` over ``inputs`` (least squares)."""

    inputs: tuple
    centre: np.ndarray
    scale: np.ndarray
    coefficients: np.ndarray
    rmse: float
    n: int

    def predict(self, values: Mapping) -> float:
        x = np.array([float(values[k]) for k in self.inputs])
        return float(self.coefficients[0] + ((x - self.centre) / self.scale) @ self.coefficients[1:])

    def to_dict(self) -> dict:
        return {"inputs": list(self.inputs), "centre": self.centre.tolist(), "scale": self.scale.tolist(),
                "coefficients": self.coefficients.tolist(), "rmse": float(self.rmse), "n": int(self.n)}

    @classmethod
    def from_dict(cls, d: Mapping) -> "LinearFit":
        return cls(tuple(d["inputs"]), np.asarray(d["centre"], float), np.asarray(d["scale"], float),
                   np.asarray(d["coefficients"], float), float(d["rmse"]), int(d["n"]))


def fit_linear(X: np.ndarray, z: np.ndarray, inputs: Sequence[str], what: str) -> LinearFit:
    """Least squares of ``z`` on the columns of ``X`` (one per input) and a constant."""
    X = np.asarray(X, float)
    z = np.asarray(z, float)
    ok = np.isfinite(z) & np.all(np.isfinite(X), axis=1)
    X, z = X[ok], z[ok]
    p = X.shape[1]
    if z.size < p + 2:
        raise ValueError(f"{what}: {z.size} usable sequence(s) for a law linear in {p} parameter(s) "
                         f"({', '.join(inputs)}): need at least {p + 2}")
    centre = X.mean(axis=0)
    scale = X.std(axis=0)
    scale[scale == 0] = 1.0
    A = np.column_stack([np.ones(z.size), (X - centre) / scale])
    coef, *_ = np.linalg.lstsq(A, z, rcond=None)
    if np.linalg.matrix_rank(A) < A.shape[1]:
        raise ValueError(f"{what}: the training settings cannot separate the effects of {', '.join(inputs)} "
                         "(rank-deficient design): vary them independently")
    r = A @ coef - z
    return LinearFit(tuple(inputs), centre, scale, coef, float(np.sqrt(np.mean(r**2))), int(z.size))


@dataclass
class TemplateModel:
    """Hybrid model on a waveform template (module docstring)."""

    template: WaveformTemplate
    dead_time_us: float
    nozzle_inner_diameter_um: float
    ecm_coefficients: EcmCoefficients
    inputs: tuple
    fixed: dict
    pinchoff: LinearFit
    volume_adjuster: LinearFit
    velocity_adjuster: LinearFit
    training_region: dict
    ecm: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    def drive(self, values: Mapping) -> Drive:
        """The drive at ``values`` (every template parameter: the fixed ones may be left out)."""
        full = {**self.fixed, **{k: float(v) for k, v in values.items()}}
        for k, v in self.fixed.items():
            if not np.isclose(full[k], v, rtol=1e-9, atol=1e-12):
                raise ValueError(f"{k} = {full[k]:g} differs from the value {v:g} every training sequence had: the "
                                 "model knows nothing of its effect")
        return Drive(self.template, full, self.dead_time_us)

    def ecm_response(self, drive: Drive, t_us) -> tuple[np.ndarray, np.ndarray]:
        """ECM grown volume (nl) and flow velocity (m/s) at ``t_us`` after the trigger, exact."""
        knots, jumps = drive.knots()
        vol, flow = pwl_response(self.ecm_coefficients.ratios(), knots, jumps, np.atleast_1d(np.asarray(t_us, float)))
        return vol, flow_velocity_m_s(flow, self.nozzle_inner_diameter_um)

    def outside(self, values: Mapping) -> list[str]:
        """The varied parameters of ``values`` outside their training range (names)."""
        return [k for k in self.inputs
                if not self.training_region[k][0] - 1e-9 <= float(values[k]) <= self.training_region[k][1] + 1e-9]

    def predict(self, values: Mapping) -> dict:
        """Pinch-off instant (µs), grown and in-flight volume (nl), jetting velocity (m/s) and the ECM
        flow velocity at the velocity instant (m/s) at ``values``; ``outside_training_region`` names
        the varied parameters outside their training range (empty inside)."""
        d = self.drive(values)
        t_p = self.pinchoff.predict(d.values)
        # one ECM evaluation at both instants, each its own column: the sums over the knots are
        # then those of one instant at a time (a flat vector of instants may round differently)
        vol, vel = self.ecm_response(d, np.array([[t_p], [d.velocity_instant_us]]))
        vol, vel = vol[0, 0], vel[1, 0]
        return {
            "pinchoff_us": t_p,
            "grown_volume_at_pinchoff_nl": float(vol),
            "inflight_volume_nl": float(vol + self.volume_adjuster.predict(d.values)),
            "jetting_velocity_m_s": float(vel + self.velocity_adjuster.predict(d.values)),
            "flow_velocity_at_velocity_instant_m_s": float(vel),
            "outside_training_region": self.outside(d.values),
        }

    def outside_why(self, values: Mapping) -> str:
        """Why ``values`` lie outside the training region (each varied parameter beyond its range seen,
        in the form of :mod:`identify.tabular`: ``"V1=40 > 34 (max seen)"``); ``""`` inside."""
        why = []
        for k in self.inputs:
            lo, hi = self.training_region[k]
            v = float(values[k])
            if v < lo - 1e-9:
                why.append(f"{k}={v:g} < {lo:g} (min seen)")
            elif v > hi + 1e-9:
                why.append(f"{k}={v:g} > {hi:g} (max seen)")
        return "; ".join(why)

    def predict_table(self, table: pd.DataFrame, source: str = "the table") -> pd.DataFrame:
        """:meth:`predict` at every row of ``table``: one row per input row, in order.

        Parameters
        ----------
        table : DataFrame
            A column per varied parameter (:attr:`inputs`, the template's units); a column of a fixed
            parameter may be there (then at its training value in every row); other columns are ignored.
        source : str
            Named in errors.

        Returns
        -------
        DataFrame
            :data:`PREDICTION_COLUMNS`: the predicted outputs, ``outside_training_region`` (bool) and
            ``outside_training_region_why`` (``""`` inside).

        Raises
        ------
        ValueError
            A parameter column missing or not numeric, a value missing, not finite or outside the
            template's accepted range, a fixed parameter at another value (one line naming ``source``
            and the row: the first row of data is row 1).
        """
        missing = [k for k in self.inputs if k not in table.columns]
        if missing:
            raise ValueError(f"{source}: no column {missing[0]!r} (the model's parameters: {', '.join(self.inputs)}"
                             + (f"; fixed, may be left out: {', '.join(self.fixed)}" if self.fixed else "") + ")")
        names = [k for k in self.template.parameter_names if k in table.columns]
        cols = {}
        for k in names:
            col = table[k]
            if col.dtype == bool or not pd.api.types.is_numeric_dtype(col):
                raise ValueError(f"{source}: parameter column {k!r} is not numeric (dtype {col.dtype})")
            cols[k] = col.to_numpy(dtype=float, na_value=np.nan)
        rows = []
        for i in range(len(table)):
            values = {k: cols[k][i] for k in names}
            bad = [k for k, v in values.items() if not np.isfinite(v)]
            try:
                if bad:
                    raise ValueError(f"parameter {bad[0]} is missing or not finite")
                p = self.predict(values)
            except ValueError as exc:
                raise ValueError(f"{source}: row {i + 1}: {exc}") from None
            why = self.outside_why(values)
            rows.append({**{k: p[k] for k in PREDICTION_COLUMNS[:-2]}, "outside_training_region": bool(why),
                         "outside_training_region_why": why})
        return pd.DataFrame(rows, columns=list(PREDICTION_COLUMNS), index=table.index).astype(
            {"outside_training_region": bool, "outside_training_region_why": object})

    def to_dict(self) -> dict:
        c = self.ecm_coefficients
        return {
            "schema": schema.TEMPLATE_MODEL.schema,
            "waveform": self.template.to_dict(),
            "parameters": {p.name: p.unit for p in self.template.parameters},
            "drive_unit": self.template.drive_unit,
            "dead_time_us": float(self.dead_time_us),
            "nozzle_inner_diameter_um": float(self.nozzle_inner_diameter_um),
            "inputs": list(self.inputs),
            "fixed": dict(self.fixed),
            "training_region": {k: [float(a), float(b)] for k, (a, b) in self.training_region.items()},
            "ecm": {**self.ecm, "coefficients": {k: getattr(c, k) for k in COEFF_NAMES}},
            **{name: getattr(self, name).to_dict() for name in LAWS},
            "notes": list(self.notes),
        }

    def save(self, path):
        """Write the model's JSON atomically (`dvcore.atomic.write_json`); read it back with
        :meth:`from_json`."""
        from dvcore.atomic import write_json

        return write_json(path, self.to_dict())

    @classmethod
    def from_json(cls, path) -> "TemplateModel":
        """A model from its JSON file (hardened reading: size, encoding, NaN; one-line errors naming the file)."""
        from pathlib import Path

        from dvcore.jsonio import load_json_hardened

        path = Path(path)
        if not path.is_file():
            raise ValueError(f"{path}: model file not found")
        return cls.from_dict(load_json_hardened(path, ValueError), source=str(path))

    @classmethod
    def from_dict(cls, d: Mapping, source: str = "model.json") -> "TemplateModel":
        """A model from :meth:`to_dict`; every number checked (finite, the laws' shapes), so that an edited
        file fails here with one line naming ``source``, never later in a prediction."""
        if not isinstance(d, Mapping) or d.get("schema") != schema.TEMPLATE_MODEL.schema:
            raise ValueError(f"{source}: not a template model (schema {schema.TEMPLATE_MODEL.schema!r} expected)")
        try:
            schema.check_document(dict(d), schema.TEMPLATE_MODEL, source)
            check_nozzle_and_dead_time(d, source)  # the checks of a (u1, u2) model.json: ranges,
            check_ecm_coefficients(d["ecm"], source)  # a stable ECM
            inputs = list(d["inputs"])
            for name in LAWS:
                law = d[name]
                k = len(inputs)
                shapes = {"inputs": k, "centre": k, "scale": k, "coefficients": k + 1}
                for key, n in shapes.items():
                    if not isinstance(law.get(key), list) or len(law[key]) != n:
                        raise ValueError(f"{name}.{key} must be a list of {n}")
                if list(law["inputs"]) != inputs:
                    raise ValueError(f"{name}.inputs differ from inputs")
                vals = np.asarray(law["centre"] + law["scale"] + law["coefficients"], float)
                if not np.all(np.isfinite(vals)) or not np.all(np.asarray(law["scale"], float) > 0):
                    raise ValueError(f"{name}: numbers must be finite, scales > 0")
            return cls(
                template=template_from_dict(d["waveform"]), dead_time_us=float(d["dead_time_us"]),
                nozzle_inner_diameter_um=float(d["nozzle_inner_diameter_um"]),
                ecm_coefficients=EcmCoefficients(**{k: float(d["ecm"]["coefficients"][k]) for k in COEFF_NAMES}),
                inputs=tuple(d["inputs"]), fixed={k: float(v) for k, v in d["fixed"].items()},
                **{name: LinearFit.from_dict(d[name]) for name in LAWS},
                training_region={k: (float(a), float(b)) for k, (a, b) in d["training_region"].items()},
                ecm={k: v for k, v in d["ecm"].items() if k != "coefficients"}, notes=list(d.get("notes") or []),
            )
        except (schema.SchemaError, ModelFileError):
            raise
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ValueError(f"{source}: invalid template model ({type(exc).__name__}: {exc})") from None


# --------------------------------------------------------------------------- data


def sequence_tables(sequence_id, waveform: Mapping, frames: pd.DataFrame, summary: Mapping
                    ) -> tuple[dict, pd.DataFrame]:
    """One measured sequence as a row of the training table and its time series.

    Parameters
    ----------
    sequence_id : str
    waveform : dict
        The sequence's ``waveform`` (sequence.json, template form or the paper's flat form).
    frames : DataFrame
        `dropvision`'s frames table (``delay_us``, ``attached``, ``grown_volume_nl``).
    summary : dict
        `dropvision`'s summary (``pinchoff_us``, ``inflight_volume_nl``, ``jetting_velocity_m_s``).

    Returns
    -------
    row : dict
        ``sequence_id``, the template's parameters, the three measured outputs.
    timeseries : DataFrame
        ``sequence_id, delay_us, grown_volume_nl, attached`` (repeats averaged, attached only if
        every repeat is).
    """
    from identify.waveform import drive_from_document

    drive = drive_from_document(waveform, f"sequence {sequence_id}")
    f = frames.copy()
    f["_grown"] = f["grown_volume_nl"].where(f["attached"])
    g = f.groupby("delay_us", sort=True)
    ts = pd.DataFrame({"delay_us": g.size().index.to_numpy(float), "grown_volume_nl": g["_grown"].mean().to_numpy(float),
                       "attached": g["attached"].all().to_numpy(bool)})
    ts.insert(0, "sequence_id", sequence_id)
    row = {"sequence_id": sequence_id, **drive.values,
           **{k: float(summary.get(k)) if summary.get(k) is not None else float("nan") for k in OUTPUTS}}
    return row, ts


def _run(ts: pd.DataFrame, h: float) -> pd.DataFrame | None:
    """The contiguous attached samples from delay 0 (None when fewer than MIN_RUN_SAMPLES)."""
    g = ts.sort_values("delay_us")
    g = g[g["attached"].to_numpy(bool) & np.isfinite(g["grown_volume_nl"].to_numpy(float))]
    k = np.round(g["delay_us"].to_numpy(float) / h).astype(np.int64)
    if k.size == 0 or k[0] != 0:
        return None
    steps = np.diff(k) != 1
    n = int(np.argmax(steps)) + 1 if np.any(steps) else k.size
    return g.iloc[:n] if n >= MIN_RUN_SAMPLES else None


# --------------------------------------------------------------------------- fit


def fit_template_model(template: WaveformTemplate | Mapping, table: pd.DataFrame, timeseries: pd.DataFrame, *,
                       dead_time_us: float, nozzle_inner_diameter_um: float,
                       hydraulics: Hydraulics | Sequence[float] | None = None, la: float | None = None,
                       substeps: int = 10) -> TemplateModel:
    """Fit the hybrid model on a waveform template (module docstring).

    Parameters
    ----------
    template : WaveformTemplate or dict
        The template (or its ``to_dict()``); the table's parameter columns are its parameters.
    table : DataFrame
        One row per sequence: ``sequence_id``, every parameter of the template (its units),
        ``pinchoff_us``, ``inflight_volume_nl``, ``jetting_velocity_m_s``.
    timeseries : DataFrame
        ``sequence_id``, ``delay_us``, ``grown_volume_nl``, ``attached`` (strobe delays on one
        uniform grid from 0).
    dead_time_us : float
        Trigger to the start of the drive (µs).
    nozzle_inner_diameter_um : float
    hydraulics : Hydraulics or (LN, RN, LR, RR), optional
        Known elements of Eq. (2): the ECM's physical parameters Ra, CN, Kc are fitted (La fixed);
        without them its coefficients (A3 = 1).
    la : float, optional
        La at which the physical fit fixes it (default `identify.ecm_fit.LA_DEFAULT`).
    substeps : int
        Drive sub-samples per strobe interval in the ECM fit.
    """
    tpl = template if isinstance(template, WaveformTemplate) else template_from_dict(template)
    names = tpl.parameter_names
    missing = [c for c in ("sequence_id", *names, *OUTPUTS) if c not in table.columns]
    if missing:
        raise ValueError(f"training table: missing column(s) {', '.join(missing)} (template {tpl.describe()})")
    for c in ("sequence_id", "delay_us", "grown_volume_nl", "attached"):
        if c not in timeseries.columns:
            raise ValueError(f"time series: missing column {c!r}")
    notes: list[str] = []
    delays = np.unique(timeseries["delay_us"].to_numpy(float))
    h = float(np.min(np.diff(delays))) if delays.size > 1 else float("nan")
    if not h > 0:
        raise ValueError("time series: need at least two distinct delays")
    drives = {}
    for _, row in table.iterrows():
        drives[row["sequence_id"]] = Drive(tpl, {k: row[k] for k in names}, dead_time_us)
    groups = {sid: g for sid, g in timeseries.groupby("sequence_id", sort=False)}
    data = []
    for sid, drive in drives.items():
        g = groups.get(sid)
        run = None if g is None else _run(g, h)
        if run is None:
            notes.append(f"sequence {sid}: fewer than {MIN_RUN_SAMPLES} contiguous attached samples from delay 0: "
                         "left out of the ECM fit")
            continue
        data.append(EcmData.from_drive(drive, run["delay_us"].to_numpy(float), run["grown_volume_nl"].to_numpy(float),
                                       substeps=substeps))
    if not data:
        raise ValueError("no sequence usable for the ECM fit: " + "; ".join(notes))
    kw = {} if la is None else {"la": la}
    ecm_fit: EcmFit = fit_ecm(data, hydraulics, method="oe", **kw)
    coeffs = ecm_fit.coefficients

    X_all = table[list(names)].to_numpy(float)
    varied = [k for j, k in enumerate(names) if np.unique(X_all[:, j]).size > 1]
    fixed = {k: float(X_all[0, j]) for j, k in enumerate(names) if k not in varied}
    X = table[varied].to_numpy(float)
    model = TemplateModel(tpl, float(dead_time_us), float(nozzle_inner_diameter_um), coeffs, tuple(varied), fixed,
                          None, None, None, {k: (float(X[:, j].min()), float(X[:, j].max())) for j, k in enumerate(varied)})
    v_ecm, q_ecm = [], []
    for (_, row), sid in zip(table.iterrows(), table["sequence_id"]):
        d = drives[sid]
        tp = float(row["pinchoff_us"])
        v, _ = model.ecm_response(d, [tp if np.isfinite(tp) else d.velocity_instant_us])
        _, q = model.ecm_response(d, [d.velocity_instant_us])
        v_ecm.append(float(v[0]) if np.isfinite(tp) else np.nan)
        q_ecm.append(float(q[0]))
    model.pinchoff = fit_linear(X, table["pinchoff_us"], varied, "pinch-off instant")
    model.volume_adjuster = fit_linear(X, table["inflight_volume_nl"].to_numpy(float) - np.array(v_ecm), varied,
                                       "volume adjuster")
    model.velocity_adjuster = fit_linear(X, table["jetting_velocity_m_s"].to_numpy(float) - np.array(q_ecm), varied,
                                         "velocity adjuster")
    params = None
    if ecm_fit.parameters is not None:
        params = {k: {"value": float(getattr(ecm_fit.parameters, k)),
                      "ci95": [float(a) for a in ecm_fit.param_ci95.get(k, (np.nan, np.nan))]}
                  for k in ("La", "Ra", "CN", "Kc")}
    model.ecm = {"level": ecm_fit.level, "parameters": params, "rmse_nl": float(ecm_fit.rmse_nl),
                 "n_sequences": int(ecm_fit.n_sequences), "n_samples": int(ecm_fit.n_samples),
                 "units": f"SI; the drive in {tpl.drive_unit} enters Eq. (6) as if in um (Kc per {tpl.drive_unit})"}
    if fixed:
        notes.append("constant in the training data (required at these values): "
                     + ", ".join(f"{k} = {v:g} {tpl.units()[k]}" for k, v in fixed.items()))
    model.notes = notes
    return model


def holdout_errors(model: TemplateModel, table: pd.DataFrame) -> pd.DataFrame:
    """Per row of ``table`` (parameters and measured outputs): predicted, measured and the error
    (predicted - measured) of each of :data:`OUTPUTS`, and the relative error (%) of the volume and
    the velocity."""
    rows = []
    names = model.template.parameter_names
    for _, r in table.iterrows():
        p = model.predict({k: r[k] for k in names})
        out = {"sequence_id": r["sequence_id"]}
        for k in OUTPUTS:
            out[f"{k}_predicted"] = p[k]
            out[f"{k}_measured"] = float(r[k])
            out[f"{k}_error"] = p[k] - float(r[k])
        for k in ("inflight_volume_nl", "jetting_velocity_m_s"):
            out[f"{k}_error_percent"] = 100.0 * out[f"{k}_error"] / float(r[k])
        out["outside_training_region"] = ", ".join(p["outside_training_region"])
        rows.append(out)
    return pd.DataFrame(rows)


__all__ = ["TemplateModel", "LinearFit", "fit_template_model", "sequence_tables", "holdout_errors", "OUTPUTS",
           "PREDICTION_COLUMNS"]
