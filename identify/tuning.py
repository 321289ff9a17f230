"""Closed-loop tuning: propose (u1, u2), fire the rig, measure, update, propose again.

The identified model is the prior; what the rig measures corrects it. Each output (in-flight
volume, jetting velocity) carries a relative bias ``b`` between the printhead on the rig and the
model (``measured = predicted x (1 + b)``: another ink batch, a worn nozzle, another
temperature). Its prior is Gaussian with mean 0 and a standard deviation made of the model's
own mean-drop interval at the first proposal (`identify.hybrid.HybridModel.interval_prediction`,
relative) and ``prior_bias_percent`` (how far the rig may have drifted from the campaign the
model was fitted on), in quadrature. Every shot observes ``r = measured / predicted - 1`` with a
variance of the shot's own measurement uncertainty (when the rig reports one) plus the model's
drop-to-drop scatter; the posterior is the conjugate normal update (precision-weighted mean of
the shots, shrunk towards 0 by the prior), with its standard error. The next proposal is
:func:`identify.design.design` for the target divided by ``1 + b``, so the loop never restarts:
the model stays, only the bias learns.

The loop stops when a measured drop is within the tolerance of the target (volume, and velocity
when a velocity target is given), when the shot budget is spent, or when an infeasible corrected
target proposes the same nearest point twice (:func:`stuck`). Shot 1 is the open-loop
proposal of ``identify design`` (the bias is still 0), so its error is the open-loop error on
this rig.

Rigs are adapters (:class:`Rig`): ``rig(u1_um_per_ms, u2_um, shot) -> RigShot``. This module ships
:class:`CallableRig` (wraps any function of a lab's own hardware); the simulated printhead and the
folder rig, which need the measurement layer, are in ``dropvision.app.rigs`` and are found by
name through the ``identify.rigs`` entry points (:func:`load_rig`).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Protocol, runtime_checkable

import numpy as np

from dvcore.errors import ParameterError
from identify.design import Region, design

__all__ = ["RigShot", "Rig", "CallableRig", "BiasEstimate", "update_bias", "TuningResult", "tune",
           "write_tuning", "read_tuning", "load_rig", "RIG_ENTRY_POINTS", "TUNING_FILES"]

#: Entry-point group under which packages register rig factories ``factory(**options) -> Rig``.
RIG_ENTRY_POINTS = "identify.rigs"
#: The two files of a tuning run folder.
TUNING_FILES = ("tuning.parquet", "tuning.json")
#: Relative observation standard deviation used when neither the rig nor the model gives one.
DEFAULT_SHOT_STD_REL = 0.01


@dataclass
class RigShot:
    """What a rig measured for one shot.

    Attributes
    ----------
    inflight_volume_nl : float
        Measured in-flight volume (nl).
    jetting_velocity_m_s : float
        Measured jetting velocity (m/s); NaN when the rig cannot measure it.
    inflight_volume_uncertainty_nl : float
        Standard uncertainty of the volume (nl); NaN: unknown.
    jetting_velocity_se_m_s : float
        Standard error of the velocity (m/s); NaN: unknown.
    result : object
        The rig's own result (e.g. a `dropvision.measurement.MeasureResult`); not written.
    extra : dict
        Scalar values written as extra columns ``rig_<key>`` (e.g. a simulator's truth).
    """

    inflight_volume_nl: float
    jetting_velocity_m_s: float = float("nan")
    inflight_volume_uncertainty_nl: float = float("nan")
    jetting_velocity_se_m_s: float = float("nan")
    result: Any = None
    extra: dict = field(default_factory=dict)


@runtime_checkable
class Rig(Protocol):
    """A printhead with a drop watcher: fire at (u1 µm/ms, u2 µm) and measure the drop."""

    name: str

    def __call__(self, u1_um_per_ms: float, u2_um: float, shot: int) -> RigShot:  # pragma: no cover - protocol
        ...


def _as_shot(value, where: str) -> RigShot:
    """A rig's answer as a checked :class:`RigShot` (a RigShot, a dict with the RigShot keys, or a
    ``(volume_nl, velocity_m_s)`` pair)."""
    if isinstance(value, RigShot):
        shot = value
    elif isinstance(value, dict):
        if "inflight_volume_nl" not in value:
            raise ValueError(f"{where}: the rig's answer has no inflight_volume_nl")
        keys = ("inflight_volume_nl", "jetting_velocity_m_s", "inflight_volume_uncertainty_nl", "jetting_velocity_se_m_s")
        shot = RigShot(**{k: (float("nan") if value.get(k) is None else value[k]) for k in keys if k in value},
                       extra={k: v for k, v in value.items() if k not in keys})
    elif isinstance(value, (tuple, list)) and len(value) == 2:
        shot = RigShot(inflight_volume_nl=value[0], jetting_velocity_m_s=value[1])
    else:
        raise ValueError(f"{where}: the rig returned {type(value).__name__}; expected a RigShot, a dict with "
                         "inflight_volume_nl (and jetting_velocity_m_s) or a (volume_nl, velocity_m_s) pair")
    try:
        for k in ("inflight_volume_nl", "jetting_velocity_m_s", "inflight_volume_uncertainty_nl",
                  "jetting_velocity_se_m_s"):
            setattr(shot, k, float("nan") if getattr(shot, k) is None else float(getattr(shot, k)))
    except (TypeError, ValueError):
        raise ValueError(f"{where}: the rig returned a value that is not a number") from None
    if not (math.isfinite(shot.inflight_volume_nl) and shot.inflight_volume_nl > 0):
        raise ValueError(f"{where}: no in-flight volume measured (got {shot.inflight_volume_nl!r} nl); "
                         "is the drop in view at the rig's delays?")
    if math.isfinite(shot.jetting_velocity_m_s) and shot.jetting_velocity_m_s <= 0:
        raise ValueError(f"{where}: jetting velocity {shot.jetting_velocity_m_s!r} m/s is not positive")
    return shot


class CallableRig:
    """Adapter for a lab's own hardware: wraps any function ``fn(u1_um_per_ms, u2_um, shot)``.

    Parameters
    ----------
    fn : callable
        Fires the printhead with the waveform (u1 µm/ms, u2 µm) and measures the drop; returns a
        :class:`RigShot`, a dict with ``inflight_volume_nl`` (and ``jetting_velocity_m_s``,
        ``inflight_volume_uncertainty_nl``, ``jetting_velocity_se_m_s``; other scalar keys become
        ``rig_<key>`` columns) or a ``(volume_nl, velocity_m_s)`` pair. A function of two
        arguments (u1, u2) is accepted too.
    name : str
        Shown in messages and in tuning.json.

    Raises
    ------
    ValueError
        When called: the function's answer has no positive finite in-flight volume, or is not
        one of the accepted forms (one line naming the rig and the shot).
    """

    def __init__(self, fn: Callable, name: str | None = None):
        if not callable(fn):
            raise TypeError(f"CallableRig needs a callable, got {type(fn).__name__}")
        self.fn = fn
        self.name = name or getattr(fn, "__qualname__", None) or type(fn).__name__
        try:
            import inspect

            params = [p for p in inspect.signature(fn).parameters.values()
                      if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD, p.VAR_POSITIONAL)]
            self._takes_shot = len(params) >= 3 or any(p.kind == p.VAR_POSITIONAL for p in params)
        except (TypeError, ValueError):  # builtins without a signature: pass the shot
            self._takes_shot = True

    def __call__(self, u1_um_per_ms: float, u2_um: float, shot: int) -> RigShot:
        args = (float(u1_um_per_ms), float(u2_um)) + ((int(shot),) if self._takes_shot else ())
        return _as_shot(self.fn(*args), f"rig {self.name}: shot {shot}")


@dataclass(frozen=True)
class BiasEstimate:
    """Posterior of a relative bias at one (u1, u2): mean and standard error (fractions, not percent)."""

    mean: float
    se: float
    n_shots: int


def update_bias(observed_rel, observed_std_rel, prior_std_rel: float, *, positions=None, at=None,
                lengthscale: float | None = None) -> BiasEstimate:
    """Gaussian update of a relative bias from the shots so far.

    The bias is a Gaussian process over the normalised (u1, u2) plane with mean 0, standard
    deviation ``prior_std_rel`` and a squared-exponential correlation of ``lengthscale``: shots
    close to ``at`` count fully, shots far from it (the loop moved on) count less. Without
    ``lengthscale`` (or ``positions``) the bias is one constant and this is the conjugate normal
    update (the precision-weighted mean of the shots shrunk towards 0).

    Parameters
    ----------
    observed_rel : array_like
        ``measured / predicted - 1`` of each shot (NaN: not measured, ignored).
    observed_std_rel : array_like
        Standard deviation of each observation (relative; > 0).
    prior_std_rel : float
        Prior standard deviation of the bias (relative, > 0), prior mean 0.
    positions : array_like, shape (n, 2), optional
        Each shot's (u1, u2) in normalised units (divided by the training region's span).
    at : array_like, shape (2,), optional
        Where the bias is wanted (normalised units); default the last shot.
    lengthscale : float, optional
        Correlation length in normalised units; None: a constant bias.

    Returns
    -------
    BiasEstimate
        Posterior mean and standard deviation; the prior when no shot has a value.
    """
    r = np.asarray(observed_rel, float)
    s = np.asarray(observed_std_rel, float)
    if not (math.isfinite(prior_std_rel) and prior_std_rel > 0):
        raise ValueError(f"prior_std_rel must be a positive number, got {prior_std_rel!r}")
    ok = np.isfinite(r) & np.isfinite(s) & (s > 0)
    if not ok.any():
        return BiasEstimate(mean=0.0, se=float(prior_std_rel), n_shots=0)
    p2 = prior_std_rel**2
    if lengthscale is None or positions is None:
        precision = 1.0 / p2 + float(np.sum(1.0 / s[ok] ** 2))
        mean = float(np.sum(r[ok] / s[ok] ** 2)) / precision
        return BiasEstimate(mean=mean, se=float(1.0 / math.sqrt(precision)), n_shots=int(ok.sum()))
    if not (math.isfinite(lengthscale) and lengthscale > 0):
        raise ValueError(f"lengthscale must be a positive number, got {lengthscale!r}")
    x = np.asarray(positions, float).reshape(len(r), 2)
    where = x[-1] if at is None else np.asarray(at, float)
    x, r, s = x[ok], r[ok], s[ok]
    d2 = np.sum((x[:, None, :] - x[None, :, :]) ** 2, axis=-1)
    cov = p2 * np.exp(-0.5 * d2 / lengthscale**2) + np.diag(s**2)
    k = p2 * np.exp(-0.5 * np.sum((x - where) ** 2, axis=1) / lengthscale**2)
    w = np.linalg.solve(cov, k)
    var = max(p2 - float(k @ w), 0.0)
    return BiasEstimate(mean=float(w @ r), se=math.sqrt(var), n_shots=int(ok.sum()))


@dataclass
class TuningResult:
    """A tuning run: one record per shot and what it was run for.

    Attributes
    ----------
    shots : list of dict
        One record per shot (the columns of `dvcore.schema.TUNING`).
    target_volume_nl, target_velocity_m_s : float, float or None
    volume_tolerance_percent, velocity_tolerance_percent : float
    converged : bool
        The last shot is within tolerance.
    message : str
    meta : dict
        Seed, shot budget, prior, rig name, model file and hash, versions (tuning.json).
    """

    shots: list
    target_volume_nl: float
    target_velocity_m_s: float | None
    volume_tolerance_percent: float
    velocity_tolerance_percent: float
    converged: bool
    message: str
    meta: dict = field(default_factory=dict)

    def to_pandas(self):
        """One row per shot (`dvcore.schema.TUNING` columns, then the rig's ``rig_*`` extras)."""
        import pandas as pd

        from dvcore.schema import TUNING

        df = pd.DataFrame(self.shots)
        cols = TUNING.column_names + sorted(c for c in df.columns if c not in TUNING.column_names)
        df = df.reindex(columns=cols)
        df["shot"] = df["shot"].astype("int64")
        for c in ("feasible", "within_tolerance"):
            df[c] = df[c].astype(bool)
        return df

    def to_dict(self) -> dict:
        """tuning.json content (without the shots, which are tuning.parquet)."""
        from dvcore.schema import TUNING_RUN

        return {"schema": TUNING_RUN.schema, "target_volume_nl": self.target_volume_nl,
                "target_velocity_m_s": self.target_velocity_m_s,
                "volume_tolerance_percent": self.volume_tolerance_percent,
                "velocity_tolerance_percent": self.velocity_tolerance_percent,
                "converged": self.converged, "shots_fired": len(self.shots), "message": self.message, **self.meta}

    @property
    def final_volume_error_percent(self) -> float:
        return float(self.shots[-1]["volume_error_percent"]) if self.shots else float("nan")

    @property
    def open_loop_volume_error_percent(self) -> float:
        """Measured error of shot 1, the open-loop `identify design` proposal."""
        return float(self.shots[0]["volume_error_percent"]) if self.shots else float("nan")


def _rel(measured: float, target: float) -> float:
    return 100.0 * (measured / target - 1.0) if math.isfinite(measured) else float("nan")


def _shot_std_rel(unc: float, value: float, drop_std_rel: float) -> float:
    meas = unc / value if math.isfinite(unc) and value > 0 else float("nan")
    parts = [x for x in (meas, drop_std_rel) if math.isfinite(x) and x > 0]
    return math.sqrt(sum(x * x for x in parts)) if parts else DEFAULT_SHOT_STD_REL


def file_sha256(path) -> str:
    """SHA-256 of a file's bytes (hex)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def stuck(records: list) -> bool:
    """The last two proposals were infeasible and the same point: another shot would learn nothing
    the run can use (the corrected target lies outside the printable region)."""
    if len(records) < 2 or records[-1]["feasible"] or records[-2]["feasible"]:
        return False
    a, b = records[-1], records[-2]
    return abs(a["u1_um_per_ms"] - b["u1_um_per_ms"]) < 1e-3 and abs(a["u2_um"] - b["u2_um"]) < 1e-3


#: Two-output targets: the first trust radius (normalised (u1, u2), units of the region's span), its bounds.
TRUST_RADIUS_START, TRUST_RADIUS_MIN, TRUST_RADIUS_MAX = 0.3, 0.01, 1.5
#: Prior standard deviation of the correction of the model's log slopes (per unit of the region's span).
SLOPE_PRIOR_STD = 0.3
#: Distance (units of the region's span) over which a shot informs the slopes at the best shot.
SLOPE_LENGTHSCALE = 0.3
#: A step shorter than this (units of the region's span) that the corrected model says cannot meet
#: both targets: a local minimum off target; the next shot solves the corrected targets anew.
RESTART_STEP = 0.05


@dataclass(frozen=True)
class OutputColumns:
    """The per-shot columns of ``tuning.parquet`` for one tuned output (declared in `dvcore.schema.TUNING`)."""

    design_target: str
    predicted: str
    corrected: str
    one_drop_low: str
    one_drop_high: str
    measured: str
    measured_uncertainty: str
    error_percent: str
    bias_percent: str
    bias_se_percent: str


#: Output ("volume", "velocity") -> its per-shot columns of ``tuning.parquet``.
OUTPUT_COLUMNS: dict[str, OutputColumns] = {
    "volume": OutputColumns(
        design_target="design_target_volume_nl", predicted="predicted_volume_nl", corrected="corrected_volume_nl",
        one_drop_low="volume_one_drop_low_nl", one_drop_high="volume_one_drop_high_nl",
        measured="measured_volume_nl", measured_uncertainty="measured_volume_uncertainty_nl",
        error_percent="volume_error_percent", bias_percent="volume_bias_percent",
        bias_se_percent="volume_bias_se_percent"),
    "velocity": OutputColumns(
        design_target="design_target_velocity_m_s", predicted="predicted_velocity_m_s",
        corrected="corrected_velocity_m_s", one_drop_low="velocity_one_drop_low_m_s",
        one_drop_high="velocity_one_drop_high_m_s", measured="measured_velocity_m_s",
        measured_uncertainty="measured_velocity_uncertainty_m_s", error_percent="velocity_error_percent",
        bias_percent="velocity_bias_percent", bias_se_percent="velocity_bias_se_percent"),
}


def _joint_cost(errors: dict, outputs: dict) -> float:
    """Sum of the squared relative errors in units of each output's tolerance (1: on the edge)."""
    return float(sum((errors[o] / tol) ** 2 for o, (_, t, tol) in outputs.items() if t is not None))


def _shot_cost(rec: dict, outputs: dict) -> float:
    errs = {o: rec.get(OUTPUT_COLUMNS[o].error_percent, float("nan")) for o in outputs}
    c = _joint_cost(errs, outputs)
    return c if math.isfinite(c) else math.inf


def _trust_region_step(model, region, records, obs, outputs, trust):
    """Next (u1, u2) for a volume-and-velocity target: a damped (trust-region) step.

    The corrected model, around the best shot so far ``c`` (both outputs' residuals jointly: the
    sum of their squared relative errors in units of their tolerances), is the model's own
    nonlinear law through what was measured at ``c``, plus a linear correction of its slopes:
    ``log g(u) = log m(u) - log m(c) + log y(c) + D (u - c)`` per output (u normalised by the
    region's span). ``D`` is the ridge estimate (prior 0, standard deviation
    :data:`SLOPE_PRIOR_STD`) from the other shots' misfits of the same law (a secant update: the
    plant's slopes learnt where the model's are wrong). The step minimises the corrected joint
    cost over the printable region within ``trust["radius"]`` of ``c``; :func:`_update_trust`
    grows or shrinks the radius from how well the corrected model predicted the improvement.
    Solving the two targets anew over the whole region after every shot (what
    :func:`identify.design.design` does for a corrected target) jumps between far points on a
    plant whose bias curves: each jump lands where the learnt bias does not hold.

    Returns ``(u1, u2, feasible, goal)``: ``feasible`` when the corrected model meets both
    tolerances there; ``goal`` the design targets there (the model's values that the corrected
    model maps onto the targets).
    """
    from scipy.optimize import minimize

    span = region.span
    outs = [(o, key, t, tol) for o, (key, t, tol) in outputs.items() if t is not None]
    costs = [_shot_cost(r, outputs) for r in records]
    since = trust.get("since", 0)  # after a restart: the best shot since then
    ib = since + int(np.argmin(costs[since:]))
    c = np.array([records[ib]["u1_um_per_ms"], records[ib]["u2_um"]])
    X = np.array([[r["u1_um_per_ms"], r["u2_um"]] for r in records]) / span
    pm = model.predict_grid(X[:, 0] * span[0], X[:, 1] * span[1])
    # log misfit of each shot against the target, and of the model's law through the best shot
    y = np.column_stack([np.log(np.array([r[f"measured_{o}_{'nl' if o == 'volume' else 'm_s'}"] for r in records])
                                / t) for o, _, t, _ in outs])
    lm = np.column_stack([np.log(pm[key].to_numpy()) for _, key, _, _ in outs])
    e = (y - y[ib]) - (lm - lm[ib])  # what the model's law through c misses at the other shots
    dx = X - X[ib]
    std = np.array([[s for _, s in obs[o]] for o, _, _, _ in outs]).T  # (shots, outputs)
    D = np.zeros((len(outs), 2))
    ok = np.isfinite(e).all(axis=1) & (np.arange(len(records)) != ib) & (np.arange(len(records)) >= since)
    for j in range(len(outs)):
        if ok.any():
            # nearby shots tell the local slopes; far ones (the law curves) less
            near = np.exp(-0.5 * np.sum(dx[ok] ** 2, axis=1) / SLOPE_LENGTHSCALE**2)
            w = near / (std[ok, j] ** 2 + std[ib, j] ** 2)
            A = (dx[ok] * w[:, None]).T @ dx[ok] + np.eye(2) / SLOPE_PRIOR_STD**2
            D[j] = np.linalg.solve(A, (dx[ok] * w[:, None]).T @ e[ok, j])
    tol_log = np.array([math.log1p(tol / 100.0) for _, _, _, tol in outs])

    def cost_of(u1, u2):
        u1, u2 = np.atleast_1d(u1).astype(float), np.atleast_1d(u2).astype(float)
        p = model.predict_grid(u1, u2)
        d = np.column_stack([u1 / span[0], u2 / span[1]]) - X[ib]
        r = np.column_stack([np.log(p[key].to_numpy()) for _, key, _, _ in outs]) - lm[ib] + y[ib] + d @ D.T
        cst = np.sum((r / tol_log) ** 2, axis=1)
        return np.where(np.isfinite(cst), cst, np.inf), r

    rad = trust["radius"]
    g = np.linspace(-rad, rad, 41)
    A_, B_ = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    disk = A_**2 + B_**2 <= rad**2
    U1, U2 = c[0] + A_[disk] * span[0], c[1] + B_[disk] * span[1]
    inside = region.inside(U1, U2)
    U1, U2 = np.append(U1[inside], c[0]), np.append(U2[inside], c[1])
    cost, _ = cost_of(U1, U2)
    i = int(np.argmin(cost))
    x0 = np.array([U1[i], U2[i]])

    def f(x):
        dist = math.hypot((x[0] - c[0]) / span[0], (x[1] - c[1]) / span[1])
        if dist > rad * (1 + 1e-9) or not region.inside(x[0], x[1])[0]:
            return 1e12 + dist
        v = float(cost_of(x[0], x[1])[0][0])
        return v if math.isfinite(v) else 1e12

    res = minimize(f, x0, method="Nelder-Mead", options={"xatol": 1e-5, "fatol": 1e-10, "maxiter": 200})
    x = res.x if res.fun <= f(x0) else x0
    cst, r = cost_of(x[0], x[1])
    trust["predicted"], trust["from_cost"] = float(cst[0]), float(costs[ib])  # ib: the best since any restart
    trust["step"] = math.hypot((x[0] - c[0]) / span[0], (x[1] - c[1]) / span[1])
    p = model.predict_grid(x[0], x[1])
    goal = {o: None for o in outputs}
    for j, (o, key, t, _) in enumerate(outs):  # the model's value the corrected model maps onto the target
        goal[o] = float(p[key].iloc[0] * math.exp(-r[0, j]))
    return float(x[0]), float(x[1]), bool(cst[0] <= 1.0), goal


def _update_trust(trust: dict, records: list, rec: dict, outputs: dict) -> None:
    """The usual trust-region rule: a shot that improved on the best by at least a quarter of what
    the corrected model promised keeps the radius, or doubles it when the step went to its edge;
    any other shot halves the step it took (the model's correction does not hold that far)."""
    before = trust.get("from_cost", math.inf)
    if not math.isfinite(before):  # a restart: nothing was promised
        return
    now = _shot_cost(rec, outputs)
    promised = before - trust["predicted"]
    step = trust.get("step", trust["radius"])
    if math.isfinite(before) and promised > 0 and now <= before - 0.25 * promised:
        if step >= 0.9 * trust["radius"]:
            trust["radius"] = min(trust["radius"] * 2.0, TRUST_RADIUS_MAX)
    else:
        trust["radius"] = max(min(trust["radius"], step) / 2.0, TRUST_RADIUS_MIN)


def tune(model, rig, volume_nl: float, velocity_m_s: float | None = None, *, shots: int = 5,
         volume_tolerance_percent: float = 0.5, velocity_tolerance_percent: float = 1.0,
         prior_bias_percent: float = 5.0, bias_lengthscale: float | None = 0.25, samples: int = 2000,
         level: float = 0.95, seed: int = 0,
         model_path=None, progress: Callable[["TuningResult"], None] | None = None) -> TuningResult:
    """Tune (u1, u2) on a rig until the measured drop meets the target (see the module docstring).

    Parameters
    ----------
    model : identify.hybrid.HybridModel
    rig : Rig or callable
        ``rig(u1_um_per_ms, u2_um, shot) -> RigShot``; a plain function is wrapped in
        :class:`CallableRig`.
    volume_nl : float
        Target in-flight volume (nl).
    velocity_m_s : float, optional
        Target jetting velocity (m/s).
    shots : int
        Shot budget (>= 1).
    volume_tolerance_percent, velocity_tolerance_percent : float
        A measured drop within these relative errors of the targets ends the loop.
    prior_bias_percent : float
        Prior standard deviation (%) of the rig's bias beyond the model's own interval.
    bias_lengthscale : float or None
        Correlation length of the bias over (u1, u2), in units of the training region's span
        (:func:`update_bias`); None: one constant bias for the whole run.
    samples : int
        Monte Carlo samples of the model's interval at each proposal.
    level : float
        Level of the one-drop interval reported per shot.
    seed : int
        Seed of the Monte Carlo draws (shot k uses seed + k); the rig gets the shot number.
    model_path : path, optional
        The model file: its name and SHA-256 go into ``meta``.
    progress : callable, optional
        Called after every shot with the run so far (a :class:`TuningResult` whose last record
        is that shot; message "in progress: ..." until the run ends), e.g. to print the shot and
        write a snapshot (`identify tune` does both, so an interrupted run keeps its shots).

    Returns
    -------
    TuningResult

    Raises
    ------
    ValueError
        Bad targets, tolerances or budget; a rig answer without an in-flight volume.
    """
    from dvcore.versions import software_versions

    _check_tune_arguments(volume_nl, velocity_m_s, shots, volume_tolerance_percent, velocity_tolerance_percent,
                          prior_bias_percent, bias_lengthscale)
    if not isinstance(rig, Rig):
        rig = CallableRig(rig)
    if model.controls is None or len(model.controls) < 3:
        raise ValueError("the model has no training region (training_controls) to tune in")
    region = Region(model.controls)
    span = region.span
    positions: list = []
    outputs = {"volume": ("inflight_volume_nl", volume_nl, volume_tolerance_percent),
               "velocity": ("jetting_velocity_m_s", velocity_m_s, velocity_tolerance_percent)}
    prior: dict[str, float] = {}
    obs: dict[str, list] = {"volume": [], "velocity": []}
    bias = {k: BiasEstimate(0.0, float("nan"), 0) for k in outputs}
    records: list[dict] = []
    converged = False
    meta = {"seed": int(seed), "shot_budget": int(shots), "prior_bias_percent": float(prior_bias_percent),
            "bias_lengthscale": bias_lengthscale, "prior_std_percent": {}, "samples": int(samples),
            "level": float(level), "rig": str(getattr(rig, "name", type(rig).__name__)),
            "rig_options": dict(getattr(rig, "options", {}) or {}),
            "model_file": None if model_path is None else str(model_path),
            "model_sha256": None if model_path is None else file_sha256(model_path),
            "versions": software_versions()}

    def result(records: list, converged: bool, final: bool) -> TuningResult:
        meta["prior_std_percent"] = {o: 100.0 * v for o, v in prior.items()}
        return TuningResult(shots=list(records), target_volume_nl=float(volume_nl),
                            target_velocity_m_s=None if velocity_m_s is None else float(velocity_m_s),
                            volume_tolerance_percent=float(volume_tolerance_percent),
                            velocity_tolerance_percent=float(velocity_tolerance_percent),
                            converged=converged, message=_tuning_message(records, converged, final, volume_nl,
                                                                         velocity_m_s, volume_tolerance_percent,
                                                                         int(shots)),
                            meta=dict(meta))

    two = velocity_m_s is not None
    trust = {"radius": TRUST_RADIUS_START, "predicted": float("nan")}
    for k in range(1, int(shots) + 1):
        u1, u2, feasible, goal = _propose(model, region, records, obs, outputs, bias, trust, two)
        iv = model.interval_prediction(u1, u2, samples=samples, seed=seed + k, level=level)
        positions.append((u1 / span[0], u2 / span[1]))
        if not prior:
            for o, (key, _, _) in outputs.items():
                e = iv[key]
                prior[o] = math.hypot(e["mean_drop_std"] / abs(e["mean"]), prior_bias_percent / 100.0)
        measured = _as_shot(rig(u1, u2, k), f"rig {getattr(rig, 'name', 'rig')}: shot {k}")
        rec: dict = {"shot": k, "u1_um_per_ms": u1, "u2_um": u2, "feasible": bool(feasible)}
        within = True
        for o, (key, target, tol) in outputs.items():
            value, unc = ((measured.inflight_volume_nl, measured.inflight_volume_uncertainty_nl) if o == "volume"
                          else (measured.jetting_velocity_m_s, measured.jetting_velocity_se_m_s))
            col = OUTPUT_COLUMNS[o]
            columns, pred = _output_columns(iv[key], bias[o], goal[o], value, unc, target, col)
            drop_rel = (iv[key].get("drop_std") or 0.0) / abs(iv[key]["mean"])
            obs[o].append((value / pred - 1.0 if math.isfinite(value) else float("nan"),
                           _shot_std_rel(unc, value, drop_rel)))
            bias[o] = update_bias([r for r, _ in obs[o]], [s_ for _, s_ in obs[o]], prior[o], positions=positions,
                                  lengthscale=bias_lengthscale)
            rec.update(columns)
            rec.update({col.bias_percent: 100.0 * bias[o].mean, col.bias_se_percent: 100.0 * bias[o].se})
            err = columns[col.error_percent]
            if target is not None:
                within = within and math.isfinite(err) and abs(err) <= tol
        rec["within_tolerance"] = bool(within)
        rec.update({f"rig_{x}": v for x, v in measured.extra.items()})
        if two and records:  # the trust region: grows where the corrected model was right, shrinks where not
            _update_trust(trust, records, rec, outputs)
        records.append(rec)
        if progress is not None:
            progress(result(records, bool(within), final=False))
        if within:
            converged = True
            break
        if stuck(records):
            break
    return result(records, converged, final=True)


def _check_tune_arguments(volume_nl, velocity_m_s, shots, volume_tolerance_percent, velocity_tolerance_percent,
                          prior_bias_percent, bias_lengthscale) -> None:
    """`tune`'s numbers, checked before any shot (ParameterError names the parameter)."""
    for name, v in (("volume_nl", volume_nl), ("volume_tolerance_percent", volume_tolerance_percent),
                    ("velocity_tolerance_percent", velocity_tolerance_percent),
                    ("prior_bias_percent", prior_bias_percent)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ParameterError(name, f"must be a positive number, got {v!r}")
    if velocity_m_s is not None and not (math.isfinite(velocity_m_s) and velocity_m_s > 0):
        raise ParameterError("velocity_m_s", f"must be a positive number, got {velocity_m_s!r}")
    if int(shots) != shots or shots < 1:
        raise ParameterError("shots", f"must be an integer >= 1, got {shots!r}")
    if bias_lengthscale is not None and not (math.isfinite(bias_lengthscale) and bias_lengthscale > 0):
        raise ParameterError("bias_lengthscale", f"must be a positive number, got {bias_lengthscale!r}")


def _propose(model, region, records, obs, outputs, bias, trust, two: bool):
    """The next shot's (u1, u2, feasible, goal): the targets corrected by the bias so far, designed
    near the last shot; with both outputs after the first shot, a damped trust-region step from the
    best shot (restarted over the whole region from a local minimum off target)."""
    goal = {o: (t / (1.0 + bias[o].mean) if t is not None else None) for o, (_, t, _) in outputs.items()}
    last = (records[-1]["u1_um_per_ms"], records[-1]["u2_um"]) if records else None  # move as little as needed
    if two and records:  # both outputs: a damped step on the corrected model, from the best shot
        u1, u2, feasible, goal = _trust_region_step(model, region, records, obs, outputs, trust)
        if not feasible and trust["step"] < RESTART_STEP:
            # a local minimum off target (e.g. on the region's edge): the corrected targets solved anew
            # over the whole region, as for shot 1
            goal = {o: (t / (1.0 + bias[o].mean) if t is not None else None) for o, (_, t, _) in outputs.items()}
            d = design(model, goal["volume"], goal["velocity"], samples=0, near=last)
            u1, u2, feasible = d.u1_um_per_ms, d.u2_um, d.feasible
            trust.update(radius=TRUST_RADIUS_START, predicted=float("nan"), from_cost=math.inf,
                         since=len(records))  # the next steps start from this shot
        return u1, u2, feasible, goal
    # design's own default tolerance: shot 1 is exactly what `identify design` proposes
    d = design(model, goal["volume"], goal["velocity"], samples=0, near=last)
    return d.u1_um_per_ms, d.u2_um, d.feasible, goal


def _output_columns(e: dict, b_before: BiasEstimate, goal, value: float, unc: float, target,
                    col: OutputColumns):
    """One output's columns of a shot (before its bias update) and the model's nominal prediction:
    the prediction corrected by the bias so far, its one-drop interval, the measured value."""
    pred = float(e["nominal"])
    corrected = pred * (1.0 + b_before.mean)
    se_b = 0.0 if not math.isfinite(b_before.se) else b_before.se
    s = math.hypot(e["one_drop_std"] * (1.0 + b_before.mean), pred * se_b)
    q = (e["one_drop_high"] - e["mean"]) / e["one_drop_std"] if e["one_drop_std"] > 0 else 0.0
    return {
        col.design_target: goal if goal is not None else float("nan"),
        col.predicted: pred,
        col.corrected: corrected,
        col.one_drop_low: corrected - q * s,
        col.one_drop_high: corrected + q * s,
        col.measured: value,
        col.measured_uncertainty: unc,
        col.error_percent: _rel(value, target) if target is not None else float("nan"),
    }, pred


def _tuning_message(records, converged: bool, final: bool, volume_nl, velocity_m_s, volume_tolerance_percent,
                    shots: int) -> str:
    """The one-line outcome of a tuning run so far."""
    what = f"{volume_nl:g} nl" + ("" if velocity_m_s is None else f" at {velocity_m_s:g} m/s")
    last = records[-1]
    measured = (f"u1 = {last['u1_um_per_ms']:.2f} um/ms, u2 = {last['u2_um']:.2f} um measured "
                f"{last['measured_volume_nl']:.3f} nl ({last['volume_error_percent']:+.2f} %)")
    if converged:
        return f"target {what} met in {len(records)} shot(s): {measured}"
    if not final:
        return f"in progress: {len(records)} of at most {shots} shot(s) fired; last: {measured}"
    msg = f"target {what} not met within {volume_tolerance_percent:g} % in {len(records)} shot(s); last: {measured}"
    if not last["feasible"]:
        msg += "; the corrected target lies outside the printable region"
        if stuck(records):
            msg += f" (the nearest point was proposed again: stopped after {len(records)} of {shots} shots)"
    return msg


def write_tuning(result: TuningResult, out_dir, *, inputs=(), overwrite: bool = False) -> Path:
    """Write ``out_dir/tuning.parquet`` (one row per shot) and ``tuning.json`` atomically.

    Parameters
    ----------
    result : TuningResult
    out_dir : path
        Created, or replaced when it holds only an earlier result of ours
        (`dvcore.atomic.atomic_dir`).
    inputs : iterable of paths
        The model file: ``out_dir`` may not overlap it.
    overwrite : bool
        Write into an existing folder that holds other files (kept).
    """
    from dvcore.atomic import atomic_dir, write_json

    with atomic_dir(out_dir, inputs=inputs, overwrite=overwrite, kind="tuning") as tmp:
        result.to_pandas().to_parquet(tmp / TUNING_FILES[0], index=False)
        write_json(tmp / TUNING_FILES[1], result.to_dict())
    return Path(out_dir)


def read_run_folder(folder, run_document):
    """(tuning.parquet as read, tuning.json checked against ``run_document``, the table's path) of a
    tuning run folder; the table's columns are the caller's to check.

    Raises
    ------
    OSError
        A file is missing or unreadable.
    dvcore.schema.SchemaError
        tuning.json does not match ``run_document`` or tuning.parquet is no Parquet table (naming the file).
    """
    import pandas as pd

    from dvcore.jsonio import load_json_hardened
    from dvcore.schema import SchemaError, check_document

    folder = Path(folder)
    table, doc_path = folder / TUNING_FILES[0], folder / TUNING_FILES[1]
    if not doc_path.is_file():
        raise FileNotFoundError(f"{doc_path}: missing file (a tuning run folder holds {', '.join(TUNING_FILES)})")
    doc = load_json_hardened(doc_path, SchemaError)
    check_document(doc, run_document, doc_path)
    try:
        df = pd.read_parquet(table)
    except (OSError, ValueError) as exc:
        if isinstance(exc, FileNotFoundError):
            raise
        raise SchemaError(f"{table}: not a readable Parquet table ({exc})") from None
    return df, doc, table


def read_tuning(folder) -> TuningResult:
    """Read a tuning run folder back (tuning.parquet + tuning.json), checked against the schema.

    Raises
    ------
    OSError
        A file is missing or unreadable.
    dvcore.schema.SchemaError
        A file does not match its declaration (naming the file).
    """
    from dvcore.schema import TUNING, TUNING_RUN, check_table

    df, doc, table = read_run_folder(folder, TUNING_RUN)
    check_table(df, TUNING, table)
    keys = {"target_volume_nl", "target_velocity_m_s", "volume_tolerance_percent", "velocity_tolerance_percent",
            "converged", "message", "schema", "shots_fired"}
    shots = [{k: (None if isinstance(v, float) and math.isnan(v) and k.startswith("rig_") else v)
              for k, v in row.items()} for row in df.to_dict(orient="records")]
    return TuningResult(shots=shots, target_volume_nl=doc["target_volume_nl"],
                        target_velocity_m_s=doc.get("target_velocity_m_s"),
                        volume_tolerance_percent=doc["volume_tolerance_percent"],
                        velocity_tolerance_percent=doc["velocity_tolerance_percent"],
                        converged=bool(doc["converged"]), message=doc["message"],
                        meta={k: v for k, v in doc.items() if k not in keys})


def load_rig(spec: str, **options) -> Rig:
    """A rig by name or by ``module:function``.

    Parameters
    ----------
    spec : str
        A name registered under the ``identify.rigs`` entry points (``simulated``, ``folder``
        from dropvision), or ``package.module:function`` naming a lab's own function
        ``fn(u1_um_per_ms, u2_um, shot)`` (wrapped in :class:`CallableRig`).
    **options
        Passed to a registered rig factory (e.g. ``viscosity_factor``); a function rig takes none.

    Raises
    ------
    ValueError
        Unknown name, a module or function that cannot be found (one line).
    """
    import importlib
    from importlib.metadata import entry_points

    if ":" in spec:
        mod, _, attr = spec.partition(":")
        try:
            fn = getattr(importlib.import_module(mod), attr)
        except (ImportError, AttributeError) as exc:
            raise ParameterError("spec", f"{spec}: cannot load the function ({type(exc).__name__}: {exc})",
                                 option="--rig") from None
        return CallableRig(fn, name=spec)
    found = {ep.name: ep for ep in entry_points(group=RIG_ENTRY_POINTS)}
    if spec not in found:
        names = ", ".join(sorted(found)) or "none installed"
        raise ParameterError("spec", f"{spec}: unknown rig (registered: {names}; or give module:function)",
                             option="--rig")
    return found[spec].load()(**options)
