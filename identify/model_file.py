"""Validation of model.json (:meth:`identify.hybrid.HybridModel.from_dict`): every key's type,
shape and range, the ECM's stability and the intervals' blocks, with an error naming the file and
the key (:class:`ModelFileError`); and :func:`model_schema`, the one test of which kind of model a
file holds."""

from __future__ import annotations

import json

import numpy as np

from dvcore import schema
from identify.ecm import COEFF_NAMES, nozzle_area_m2


#: The model files identify writes, by schema id: a (u1, u2) hybrid model, a model on a waveform
#: template, a table model.
MODEL_SCHEMAS = (schema.MODEL.schema, schema.TEMPLATE_MODEL.schema, schema.TABULAR_MODEL.schema)
#: Bytes of a file read to tell its kind: parsed whole when the file is no larger, else its first
#: 4096 bytes are searched for the ``"schema": "<id>"`` pair (identify writes ``schema`` first).
_SNIFF_BYTES, _HEAD_BYTES = 1 << 20, 4096


def model_schema(path) -> str | None:
    """The schema id (one of :data:`MODEL_SCHEMAS`) of the model file at ``path``, or None when
    it is no model file of identify (missing, unreadable, not JSON, another document): the one
    place that tells a hybrid model, a template model and a table model apart (the command line
    dispatches on it, and replaces a file only when it is ours)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(_SNIFF_BYTES)
    except OSError:
        return None
    try:
        found = json.loads(head).get("schema")
    except (ValueError, AttributeError, RecursionError):
        found = None
    if found in MODEL_SCHEMAS:
        return found
    text = head[:_HEAD_BYTES].decode("utf-8", "replace")
    return next((s for s in MODEL_SCHEMAS if f'"schema": "{s}"' in text), None)


class ModelFileError(ValueError):
    """model.json missing, unreadable or of the wrong schema."""


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


#: Upper limits of a model's scalars: the ranges sequence.json is read with (`dvcore.schema.RANGES`).
MODEL_RANGES = {key: schema.RANGES[name][1] for key, name in (
    ("nozzle_inner_diameter_um", "nozzle_diameter_um"), ("dead_time_us", "dead_time_us"),
    ("sample_interval_us", "sample_interval_us"), ("waveform.u3_um_per_ms", "u3_um_per_ms"),
    ("waveform.hold_us", "hold_us"))}


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


def check_nozzle_and_dead_time(d, source) -> float:
    """The nozzle's inner diameter (µm, returned) and the dead time of a model file within the
    ranges sequence.json is read with (:data:`MODEL_RANGES`); :class:`ModelFileError` naming
    ``source`` and the key. Every model file of identify gets it (a (u1, u2) model,
    :func:`check_model_dict`; a template model, `identify.template_fit.TemplateModel.from_dict`)."""
    d_um = _number(d["nozzle_inner_diameter_um"], source, "nozzle_inner_diameter_um", positive=True,
                   at_most=MODEL_RANGES["nozzle_inner_diameter_um"])
    _number(d["dead_time_us"], source, "dead_time_us", nonnegative=True, at_most=MODEL_RANGES["dead_time_us"])
    return d_um


def check_ecm_coefficients(e, source) -> None:
    """A model file's ``ecm`` object: its six coefficients numbers describing a stable system
    (Routh-Hurwitz); :class:`ModelFileError` naming ``source`` and the key (as
    :func:`check_nozzle_and_dead_time`, for every model file)."""
    if not isinstance(e, dict):
        raise _model_error(source, "ecm", f"must be an object, got {type(e).__name__}")
    c = e.get("coefficients")
    if not isinstance(c, dict):
        raise _model_error(source, "ecm.coefficients", f"must be an object, got {type(c).__name__}")
    for k in COEFF_NAMES:
        if k not in c:
            raise _model_error(source, "ecm.coefficients", f"misses {k}")
        _number(c[k], source, f"ecm.coefficients.{k}")
    _check_ecm_stable(c, source)


def check_model_dict(d: dict, source) -> None:
    """Types, shapes and finiteness of every value of a model document (see
    `dvcore.schema.MODEL` for its required keys)."""
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
    d_um = check_nozzle_and_dead_time(d, source)
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
    check_ecm_coefficients(e, source)
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
    for key in ("flexible", "flexible_u1"):
        fl = iv.get(key)
        if fl is None:
            continue
        if not isinstance(fl, dict):
            raise _model_error(source, f"intervals.{key}", f"must be an object, got {type(fl).__name__}")
        for name, p in fl.items():
            if name not in ("pinchoff", "volume_adjuster", "velocity_adjuster"):
                raise _model_error(source, f"intervals.{key}.{name}", "is unknown (expected pinchoff, "
                                   "volume_adjuster, velocity_adjuster)")
            _check_polynomial(p, source, f"intervals.{key}.{name}")
    c = iv.get("pinchoff_volume_cross_covariance")
    if c is not None:
        shape = (len(d["pinchoff"]["terms"]), len(d["volume_adjuster"]["terms"]))
        _array(c, source, "intervals.pinchoff_volume_cross_covariance", shape)
