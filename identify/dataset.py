"""Training dataset of the hybrid model: reader, validator and synthetic generator.

A dataset is a folder with three files:

``timeseries.parquet``
    One row per strobe sample: ``sequence_id`` (int or str), ``u1_um_per_ms``, ``u2_um``,
    ``delay_us`` (from the firing trigger), ``grown_volume_nl`` (grown drop volume, initial
    meniscus subtracted), ``flow_velocity_m_s`` (average flow velocity in the nozzle; may be
    NaN) and ``attached`` (bool: the drop is still attached to the nozzle). Volumes may be
    NaN only in rows with ``attached == False``.
``summary.parquet``
    One row per sequence: ``sequence_id``, ``u1_um_per_ms``, ``u2_um``, ``pinchoff_us``
    (pinch-off instant from the trigger), ``grown_volume_at_pinchoff_nl`` (grown volume right
    before pinch-off), ``inflight_volume_nl``, ``jetting_velocity_m_s``,
    ``flow_velocity_at_max_stroke_m_s`` (may be NaN).
``dataset.json``
    ``nozzle_inner_diameter_um`` (required), ``sample_interval_us`` (required),
    ``dead_time_us`` (default 220), ``u3_um_per_ms`` (default 2), ``hold_us`` (default 20),
    optional ``ink`` {density_kg_m3, viscosity_mPa_s, surface_tension_mN_m} and ``nozzle``
    {length_mm, reservoir_channel_radius_um, reservoir_channel_length_mm} for the hydraulic
    equivalents of Eq. (2); optional ``measurement_uncertainty`` {volume_rel, velocity_rel,
    pixel_size_rel, pinchoff_std_us, source}: the systematic measurement uncertainty every
    sequence shares (see :func:`measurement_uncertainty`).

Several sequences may share one (u1, u2). :func:`load_dataset` raises
:class:`DatasetError` naming the file and the column for every problem it finds.

Irregular campaigns are accepted (issue 13): missing frames (gaps in ``delay_us``, or attached
rows with NaN volume), repeated delays, a failed sequence (in one file only, or too short),
a sequence with no pinch-off seen (NaN ``pinchoff_us`` / volume / velocity in the summary).
:func:`timeseries_runs` and :func:`summary_usable` say what each fit can use and return notes
on what was dropped and why; :func:`validate` refuses only when nothing usable is left (fewer
than ``min_controls`` distinct (u1, u2) for a polynomial, or no sequence for the ECM) and keeps
refusing what cannot be true (constant outputs, swapped u1/u2, unit errors, wrong dtypes,
off-grid delays).

:func:`make_synthetic_dataset` writes such a folder from the default synthetic physics of
the project (ECM + pinch-off and adjuster laws), whose truth is exactly known.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from dvcore.atomic import atomic_dir, write_json
from dvcore import schema
from identify.ecm import flow_velocity_m_s, simulate
from identify.hydraulics import Hydraulics, hydraulics_from_dimensions
from identify.montecarlo import ecm_response_at
from identify.physics import SynthPhysics
from identify.waveform import DEAD_TIME_US, HOLD_PRESET_US, SAMPLE_INTERVAL_US, U3_PRESET_UM_PER_MS, Waveform

SCHEMA = schema.DATASET.schema

_KIND = {"id": "id", "float": "f", "bool": "b"}
#: Required columns of timeseries.parquet and their kinds ("f" float, "b" bool, "id"), from
#: `dvcore.schema.TIMESERIES`.
TIMESERIES_COLUMNS = {c.name: _KIND[c.dtype] for c in schema.TIMESERIES.columns if c.required}
#: Required columns of summary.parquet, from `dvcore.schema.DATASET_SUMMARY`.
SUMMARY_COLUMNS = {c.name: _KIND[c.dtype] for c in schema.DATASET_SUMMARY.columns if c.required}
#: Summary columns that may hold NaN (not measured; the fits drop that sequence where needed).
_SUMMARY_NAN_OK = {"flow_velocity_at_max_stroke_m_s", "pinchoff_us", "grown_volume_at_pinchoff_nl",
                   "inflight_volume_nl", "jetting_velocity_m_s"}
#: Least number of contiguous samples from delay 0 that a sequence needs for the ECM/ARX fits.
MIN_RUN_SAMPLES = 8


class DatasetError(ValueError):
    """Invalid training dataset; the message names the file, the column and the problem."""


# ---------------------------------------------------------------------------------------
# Default synthetic physics (the single place holding the numbers of notes/team.md)
# ---------------------------------------------------------------------------------------


def default_physics() -> SynthPhysics:
    """The project's default synthetic physics: ``identify.physics.SynthPhysics()``,
    the single place holding the numbers of the synthetic printhead (ECM, pinch-off law and
    adjusters)."""
    return SynthPhysics()


# ---------------------------------------------------------------------------------------
# Dataset
# ---------------------------------------------------------------------------------------


@dataclass
class Dataset:
    """A validated training dataset (see the module docstring for the columns)."""

    timeseries: pd.DataFrame
    summary: pd.DataFrame
    nozzle_inner_diameter_um: float
    sample_interval_us: float
    dead_time_us: float = DEAD_TIME_US
    u3_um_per_ms: float = U3_PRESET_UM_PER_MS
    hold_us: float = HOLD_PRESET_US
    ink: dict | None = None
    nozzle: dict | None = None
    path: Path | None = None
    extra: dict = field(default_factory=dict)

    @property
    def n_sequences(self) -> int:
        return len(self.summary)

    def waveform(self, u1: float, u2: float) -> Waveform:
        return Waveform(float(u1), float(u2), self.u3_um_per_ms, self.hold_us)

    def sequence(self, sequence_id) -> pd.DataFrame:
        """Time-series rows of one sequence, sorted by delay."""
        ts = self.timeseries
        return ts[ts["sequence_id"] == sequence_id].sort_values("delay_us")

    def distinct_controls(self) -> np.ndarray:
        """Distinct (u1, u2) pairs, shape (m, 2)."""
        return np.unique(self.summary[["u1_um_per_ms", "u2_um"]].to_numpy(float), axis=0)

    def hydraulics(self) -> Hydraulics | None:
        """Known hydraulic elements of Eq. (2) from the ink and nozzle geometry.

        Returns
        -------
        Hydraulics or None
            ``(LN, RN, LR, RR)`` in kg/m^4 and kg/(m^4 s)
            (:func:`identify.hydraulics.hydraulics_from_dimensions`), or None when
            ``dataset.json`` has no ``ink`` or ``nozzle`` block or misses one of their
            dimensions (the ECM is then fitted at the coefficient level).

        Raises
        ------
        DatasetError
            If the ink density/viscosity or a nozzle dimension is not a number.
        """
        if not self.ink or not self.nozzle:
            return None
        if any(self.ink.get(k) is None for k in ("density_kg_m3", "viscosity_mPa_s")) or any(
                self.nozzle.get(k) is None for k in ("length_mm", "reservoir_channel_radius_um",
                                                     "reservoir_channel_length_mm")):
            return None  # partial knowledge: the ECM coefficients are fitted directly
        try:
            rho = float(self.ink["density_kg_m3"])
            mu_mpa_s = float(self.ink["viscosity_mPa_s"])
            ln_mm = float(self.nozzle["length_mm"])
            rr_um = float(self.nozzle["reservoir_channel_radius_um"])
            lr_mm = float(self.nozzle["reservoir_channel_length_mm"])
        except (KeyError, TypeError, ValueError) as exc:
            raise DatasetError(f"{self.json_name}: ink/nozzle geometry incomplete or invalid ({exc})") from None
        return hydraulics_from_dimensions(rho, mu_mpa_s, self.nozzle_inner_diameter_um, ln_mm, rr_um, lr_mm)

    @property
    def json_name(self) -> str:
        """Path of this dataset's ``dataset.json`` as used in error messages."""
        return str(self.path / "dataset.json") if self.path else "dataset.json"

    def metadata(self) -> dict:
        out = {
            "schema": SCHEMA,
            "nozzle_inner_diameter_um": self.nozzle_inner_diameter_um,
            "sample_interval_us": self.sample_interval_us,
            "dead_time_us": self.dead_time_us,
            "u3_um_per_ms": self.u3_um_per_ms,
            "hold_us": self.hold_us,
        }
        if self.ink:
            out["ink"] = dict(self.ink)
        if self.nozzle:
            out["nozzle"] = dict(self.nozzle)
        out.update(self.extra)
        return out

    def save(self, out_dir, *, overwrite: bool = False) -> Path:
        """Write the three files into ``out_dir`` (atomically, as one folder).

        An existing ``out_dir`` is replaced only when it holds nothing but an earlier result of
        ours; ``overwrite`` writes into one holding other files (they are kept). See
        `dvcore.atomic.atomic_dir`.
        """
        out_dir = Path(out_dir)
        with atomic_dir(out_dir, overwrite=overwrite, kind="dataset") as tmp:
            self.timeseries.to_parquet(tmp / "timeseries.parquet", index=False)
            self.summary.to_parquet(tmp / "summary.parquet", index=False)
            write_json(tmp / "dataset.json", self.metadata())
        return out_dir


def _check_columns(df: pd.DataFrame, spec: dict, fname: str) -> None:
    missing = [c for c in spec if c not in df.columns]
    if missing:
        raise DatasetError(f"{fname}: missing column(s) {', '.join(missing)}")
    for col, kind in spec.items():
        s = df[col]
        if kind == "f" and not (pd.api.types.is_numeric_dtype(s) and not pd.api.types.is_bool_dtype(s)):
            raise DatasetError(f"{fname}: column {col} must be numeric, got dtype {s.dtype}")
        if kind == "b" and not pd.api.types.is_bool_dtype(s):
            raise DatasetError(f"{fname}: column {col} must be boolean, got dtype {s.dtype}")
        if kind == "id" and s.isna().any():
            raise DatasetError(f"{fname}: column {col} has missing values")


def _finite(df: pd.DataFrame, col: str, fname: str, mask=None, *, nan_ok: bool = False) -> None:
    v = df[col].to_numpy(float)
    if mask is not None:
        v = v[np.asarray(mask)]
    bad = np.isinf(v) if nan_ok else ~np.isfinite(v)
    if bad.any():
        raise DatasetError(f"{fname}: column {col} has {int(bad.sum())} {'inf' if nan_ok else 'NaN/inf'} value(s)")


def _fmt_id(sid) -> str:
    return repr(sid.item() if hasattr(sid, "item") else sid)


def timeseries_runs(ds: Dataset) -> tuple[dict, list[str]]:
    """Time series usable for the ECM and ARX fits, and notes on what was dropped.

    Per sequence of the summary: its rows sorted by delay, repeated delays averaged (volume and
    flow velocity; attached only if every repeat is), attached rows with NaN volume taken as
    missing frames, then the contiguous run of attached samples from delay 0 (the fits need
    uniform sampling from the piston at rest). A run with fewer than :data:`MIN_RUN_SAMPLES`
    samples or ending before the dead time drops the sequence from the time-series fits.

    Returns
    -------
    runs : dict
        sequence_id -> DataFrame (columns of timeseries.parquet, attached rows only).
    notes : list of str
    """
    h = ds.sample_interval_us
    notes: list[str] = []
    runs: dict = {}
    ts = ds.timeseries
    ids_su = list(ds.summary["sequence_id"])
    only_ts = sorted(set(ts["sequence_id"].unique()) - set(ids_su), key=str)
    if only_ts:
        notes.append(f"{len(only_ts)} sequence(s) in timeseries.parquet but not in summary.parquet dropped "
                     f"(e.g. {', '.join(_fmt_id(x) for x in only_ts[:3])})")
    groups = {sid: g for sid, g in ts.groupby("sequence_id", sort=False)}
    for sid in ids_su:
        g = groups.get(sid)
        if g is None or len(g) == 0:
            notes.append(f"sequence {_fmt_id(sid)}: no time-series rows (failed sequence?): dropped from the "
                         "ECM/ARX fits; its summary values are used")
            continue
        g = g.sort_values("delay_us", kind="stable")
        d = g["delay_us"].to_numpy(float)
        if np.any(np.diff(d) == 0):
            n_rep = int(len(d) - np.unique(d).size)
            agg = {c: "first" for c in g.columns}
            agg.update({"grown_volume_nl": "mean", "flow_velocity_m_s": "mean", "attached": "all"})
            g = g.groupby("delay_us", sort=True, as_index=False).agg(agg)[list(g.columns)]
            notes.append(f"sequence {_fmt_id(sid)}: {n_rep} repeated delay(s) averaged")
        att = g["attached"].to_numpy(bool)
        vol = g["grown_volume_nl"].to_numpy(float)
        missing = att & ~np.isfinite(vol)
        if missing.any():
            notes.append(f"sequence {_fmt_id(sid)}: {int(missing.sum())} attached frame(s) without a volume "
                         "treated as missing")
        g = g[att & np.isfinite(vol)]
        k = np.round(g["delay_us"].to_numpy(float) / h).astype(np.int64)
        if k.size == 0 or k[0] != 0:
            first = "none" if k.size == 0 else f"{k[0] * h:g} us"
            notes.append(f"sequence {_fmt_id(sid)}: no attached frame at delay 0 (first: {first}): dropped from "
                         "the ECM/ARX fits; its summary values are used")
            continue
        n_run = int(np.argmax(np.diff(k) != 1)) + 1 if np.any(np.diff(k) != 1) else k.size
        if n_run < k.size:
            gap_at = (k[n_run - 1] + 1) * h
            lost = k.size - n_run
        else:
            gap_at, lost = None, 0
        if n_run < MIN_RUN_SAMPLES or k[n_run - 1] * h <= ds.dead_time_us:
            why = f"frames missing from {gap_at:g} us" if gap_at is not None else "too few frames"
            notes.append(f"sequence {_fmt_id(sid)}: only {n_run} contiguous sample(s) from delay 0 ({why}): "
                         "dropped from the ECM/ARX fits; its summary values are used")
            continue
        if lost:
            notes.append(f"sequence {_fmt_id(sid)}: frames missing from {gap_at:g} us: the ECM/ARX fits use the "
                         f"{n_run} contiguous samples up to {k[n_run - 1] * h:g} us ({lost} later attached "
                         "sample(s) unused)")
        runs[sid] = g.iloc[:n_run]
    return runs, notes


#: What each polynomial target needs from the summary (adjuster reference "ecm"; "measured" adds
#: the measured grown volume and flow velocity).
_TARGET_COLUMNS = {
    "pinchoff": ("pinchoff_us",),
    "volume_adjuster": ("pinchoff_us", "inflight_volume_nl"),
    "velocity_adjuster": ("jetting_velocity_m_s",),
}


def summary_usable(ds: Dataset, adjuster_reference: str = "ecm") -> tuple[dict, list[str]]:
    """Which summary rows each polynomial can use (finite values), and notes on the others.

    Returns
    -------
    masks : dict
        ``"pinchoff"``, ``"volume_adjuster"``, ``"velocity_adjuster"`` -> boolean array over the
        summary rows.
    notes : list of str
    """
    su = ds.summary
    need = {k: list(v) for k, v in _TARGET_COLUMNS.items()}
    if adjuster_reference == "measured":
        need["volume_adjuster"] = ["inflight_volume_nl", "grown_volume_at_pinchoff_nl"]
        need["velocity_adjuster"] = ["jetting_velocity_m_s", "flow_velocity_at_max_stroke_m_s"]
    masks, notes = {}, []
    ids = su["sequence_id"].to_numpy()
    for name, cols in need.items():
        ok = np.ones(len(su), bool)
        for c in cols:
            fin = np.isfinite(su[c].to_numpy(float))
            bad = ~fin & ok
            if bad.any():
                notes.append(f"{name}: {int(bad.sum())} sequence(s) without {c} dropped "
                             f"(e.g. {', '.join(_fmt_id(x) for x in ids[bad][:3])})")
            ok &= fin
        masks[name] = ok
    return masks, notes


# ---------------------------------------------------------------------------------------
# Systematic measurement uncertainty (issue 13): what every sequence of a campaign shares
# ---------------------------------------------------------------------------------------

#: Relative standard uncertainties of dropvision's image measurement itself (edge positions,
#: disc integration, centroid tracking), from ``tools/accuracy_report.py`` (measured against the
#: synthesizer's exact truth over its 4-case sweep: 8/12-bit, blur 0.8-1.5 px, noise, dust, tilt,
#: fall-off, satellites, repeats): in-flight volume errors -0.04..0.00 % (main-drop volume per
#: frame at most 0.11 %), jetting velocity +0.00..+0.16 % (RMS 0.08 %; it was -0.39..+0.04 % before a
#: centroid fix, and up to -0.8 % at 1.8 px blur); rounded up to 0.1 % and, for velocity, kept at a
#: conservative 0.2 % (realism-tier presets reach 0.2 %).
METHOD_UNCERTAINTY = {"volume_rel": 0.001, "velocity_rel": 0.002}
#: Pixel-size relative standard uncertainty used when nothing better is known: about what
#: dropvision's cross-check against the nozzle's outer diameter resolves (0.09 % on a 76 px nozzle).
DEFAULT_PIXEL_SIZE_REL = 0.001
#: Keys of dataset.json ``measurement_uncertainty`` (all optional, relative standard
#: uncertainties, 1 sigma): ``volume_rel`` and ``velocity_rel`` (used as they are when both are
#: given), else ``pixel_size_rel`` (the user's calibration of the pixel size) combined with
#: :data:`METHOD_UNCERTAINTY`; ``pinchoff_std_us`` (absolute, µs); ``source`` (text).
MEASUREMENT_KEYS = ("volume_rel", "velocity_rel", "pixel_size_rel", "pinchoff_std_us")


def check_measurement_block(block, fname: str) -> dict:
    if not isinstance(block, dict):
        raise DatasetError(f"{fname}: measurement_uncertainty must be an object, got {type(block).__name__}")
    out = {}
    for k, v in block.items():
        if k == "source" or k == "note":
            if not isinstance(v, str):
                raise DatasetError(f"{fname}: measurement_uncertainty.{k} must be a string")
            out[k] = v
            continue
        if k not in MEASUREMENT_KEYS:
            raise DatasetError(f"{fname}: measurement_uncertainty.{k} is unknown (expected "
                               f"{', '.join(MEASUREMENT_KEYS)}, source)")
        if v is None:
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(float(v)) or float(v) < 0:
            raise DatasetError(f"{fname}: measurement_uncertainty.{k} must be a finite number >= 0, got {v!r}")
        if k != "pinchoff_std_us" and float(v) > 0.5:
            raise DatasetError(f"{fname}: measurement_uncertainty.{k} is a relative uncertainty (0.002 = 0.2 %), "
                               f"got {v!r}")
        out[k] = float(v)
    return out


#: Columns of summary.parquet with an image-measured campaign's per-sequence calibration checks
#: (declared in `dvcore.schema.DATASET_SUMMARY`; ``dropvision campaign`` copies them from each
#: sequence's summary.json).
CALIBRATION_COLUMNS = ("pixel_size_ratio", "pixel_size_ratio_uncertainty", "inflight_frames")


def campaign_calibration(ds: Dataset) -> pd.DataFrame | None:
    """Per-sequence calibration checks of an image-measured campaign, or None.

    Columns :data:`CALIBRATION_COLUMNS`: ``pixel_size_ratio`` (pixel size implied by the
    nozzle's outer diameter / the given one), ``pixel_size_ratio_uncertainty`` and
    ``inflight_frames``, one row per summary row (NaN where unknown), from summary.parquet as
    ``dropvision campaign`` writes it. None for datasets without these columns or with no value
    in them (synthetic, hand-made).
    """
    su = ds.summary
    if not all(c in su.columns for c in CALIBRATION_COLUMNS):
        return None
    df = pd.DataFrame({c: pd.to_numeric(su[c], errors="coerce").to_numpy(float) for c in CALIBRATION_COLUMNS})
    return None if df.isna().all().all() else df


def measurement_uncertainty(ds: Dataset) -> dict:
    """Systematic measurement uncertainty shared by every sequence of ``ds`` (issue 13).

    Residual scatter cannot show an error that is the same for every sequence of a campaign:
    the pixel size (volume ∝ px³, velocity ∝ px), the edge-position bias of the measurement, the
    strobe-delay grid of the pinch-off. The intervals of `HybridModel.interval_prediction` add it
    as relative standard uncertainties (1 sigma) ``volume_rel`` and ``velocity_rel``, and an
    absolute ``pinchoff_std_us``; ``source`` says where the figures come from, in this order:

    1. ``dataset.json`` ``measurement_uncertainty`` (:data:`MEASUREMENT_KEYS`): ``volume_rel``
       and ``velocity_rel`` as given; a ``pixel_size_rel`` alone is combined with the method
       terms below;
    2. an image-measured campaign (:func:`campaign_calibration`): pixel-size term from the
       cross-check against the nozzle's outer diameter, sqrt((mean ratio - 1)^2 + median
       ratio uncertainty^2): the given pixel size is trusted only as far as the images confirm
       it; method terms :data:`METHOD_UNCERTAINTY`; pinch-off: the strobe interval h / sqrt(6):
       the first detached frame resolves the instant only to one interval (uniform, variance
       h^2/12) at the predicted point, and the pinch-off polynomial has absorbed the same
       quantisation pattern of the training points (on a grid entirely: the residuals and the
       cross-validation then show nothing of it), another h^2/12;
    3. otherwise (origin unknown) the documented defaults: :data:`METHOD_UNCERTAINTY` with
       :data:`DEFAULT_PIXEL_SIZE_REL`, pinch-off as in 2.

    ``volume_rel = sqrt(volume_method^2 + (3 pixel_size_rel)^2)``,
    ``velocity_rel = sqrt(velocity_method^2 + pixel_size_rel^2)``.
    """
    fname = ds.json_name
    given = check_measurement_block(ds.extra["measurement_uncertainty"], fname) \
        if ds.extra.get("measurement_uncertainty") is not None else {}
    h_std = float(ds.sample_interval_us / np.sqrt(6.0))
    vm, qm = METHOD_UNCERTAINTY["volume_rel"], METHOD_UNCERTAINTY["velocity_rel"]
    if "volume_rel" in given and "velocity_rel" in given:
        return {"volume_rel": given["volume_rel"], "velocity_rel": given["velocity_rel"],
                "pixel_size_rel": given.get("pixel_size_rel"),
                "pinchoff_std_us": given.get("pinchoff_std_us", h_std),
                "source": "dataset.json measurement_uncertainty"
                          + (f": {given['source']}" if given.get("source") else "")}
    method = (f"method: dropvision vs synthetic truth (tools/accuracy_report.py) volume {100 * vm:g} %, "
              f"velocity {100 * qm:g} %")
    if "pixel_size_rel" in given:
        px = given["pixel_size_rel"]
        src = f"dataset.json measurement_uncertainty.pixel_size_rel {100 * px:.3g} %; {method}"
    else:
        cal = campaign_calibration(ds)
        r = None if cal is None else cal["pixel_size_ratio"].to_numpy(float)
        u = None if cal is None else cal["pixel_size_ratio_uncertainty"].to_numpy(float)
        ok = None if r is None else np.isfinite(r) & np.isfinite(u)
        if ok is not None and ok.any():
            dev, umed = float(np.mean(r[ok]) - 1.0), float(np.median(u[ok]))
            px = float(np.hypot(dev, umed))
            src = (f"dropvision campaign: pixel size checked against the nozzle's outer diameter in {int(ok.sum())} "
                   f"sequence(s): ratio - 1 = {100 * dev:+.3f} % (mean), uncertainty {100 * umed:.3f} % (median) "
                   f"-> pixel size {100 * px:.3f} %; {method}")
        else:
            px = DEFAULT_PIXEL_SIZE_REL
            src = (f"defaults (the dataset states no measurement uncertainty and carries no pixel-size check): "
                   f"pixel size {100 * px:g} %; {method}")
    return {"volume_rel": float(np.hypot(vm, 3.0 * px)), "velocity_rel": float(np.hypot(qm, px)),
            "pixel_size_rel": float(px), "pinchoff_std_us": given.get("pinchoff_std_us", h_std),
            "source": src + f"; pinch-off {given.get('pinchoff_std_us', h_std):.3g} us"
                      + ("" if "pinchoff_std_us" in given else " (strobe interval / sqrt(6))")}


def sequence_standard_errors(ds: Dataset) -> dict:
    """Standard error of each sequence's own summary value, from within the sequence.

    ``inflight_volume_nl``: inflight_volume_std_nl / sqrt(in-flight frames) (the frames are
    different drops); ``jetting_velocity_m_s``: jetting_velocity_se_m_s (the track fit). Arrays
    over the summary rows (NaN where unknown); an output is absent when the dataset carries
    nothing for it. `identify.hybrid` uses them to tell drop-to-drop noise from the model's
    lack of fit when there are no repeated (u1, u2).
    """
    su = ds.summary
    out = {}
    if "jetting_velocity_se_m_s" in su.columns:
        se = pd.to_numeric(su["jetting_velocity_se_m_s"], errors="coerce").to_numpy(float)
        if np.isfinite(se).any():
            out["jetting_velocity_m_s"] = se
    if "inflight_volume_std_nl" in su.columns:
        cal = campaign_calibration(ds)
        if cal is not None:
            n = cal["inflight_frames"].to_numpy(float)
            sd = pd.to_numeric(su["inflight_volume_std_nl"], errors="coerce").to_numpy(float)
            with np.errstate(invalid="ignore", divide="ignore"):
                se = np.where(n >= 2, sd / np.sqrt(n), np.nan)
            if np.isfinite(se).any():
                out["inflight_volume_nl"] = se
    return out


def validate(ds: Dataset, *, min_controls: int = 3) -> Dataset:
    """Check a dataset's content; raise :class:`DatasetError` on the first problem.

    ``min_controls`` is the least number of distinct (u1, u2) pairs accepted (the linear
    polynomial of Eq. 7 has three coefficients).
    """
    base = ds.path if ds.path is not None else Path(".")
    f_ts, f_su, f_js = str(base / "timeseries.parquet"), str(base / "summary.parquet"), str(base / "dataset.json")
    if not np.isfinite(ds.nozzle_inner_diameter_um) or ds.nozzle_inner_diameter_um <= 0:
        raise DatasetError(f"{f_js}: nozzle_inner_diameter_um must be > 0, got {ds.nozzle_inner_diameter_um!r}")
    if not np.isfinite(ds.sample_interval_us) or ds.sample_interval_us <= 0:
        raise DatasetError(f"{f_js}: sample_interval_us must be > 0, got {ds.sample_interval_us!r}")
    if not np.isfinite(ds.dead_time_us) or ds.dead_time_us < 0:
        raise DatasetError(f"{f_js}: dead_time_us must be >= 0, got {ds.dead_time_us!r}")
    for name in ("u3_um_per_ms", "hold_us"):
        v = getattr(ds, name)
        if not np.isfinite(v) or v < 0 or (name == "u3_um_per_ms" and v == 0):
            raise DatasetError(f"{f_js}: {name} invalid: {v!r}")

    ts, su = ds.timeseries, ds.summary
    _check_columns(ts, TIMESERIES_COLUMNS, f_ts)
    _check_columns(su, SUMMARY_COLUMNS, f_su)
    if len(ts) == 0:
        raise DatasetError(f"{f_ts}: no rows")
    if ds.extra.get("measurement_uncertainty") is not None:
        check_measurement_block(ds.extra["measurement_uncertainty"], f_js)
    for col in ("u1_um_per_ms", "u2_um", "delay_us"):
        _finite(ts, col, f_ts)
    att = ts["attached"].to_numpy(bool)
    _finite(ts, "grown_volume_nl", f_ts, mask=att, nan_ok=True)  # NaN: a missing frame
    for col in SUMMARY_COLUMNS:
        if SUMMARY_COLUMNS[col] == "f":
            _finite(su, col, f_su, nan_ok=col in _SUMMARY_NAN_OK)
    for fname, df in ((f_ts, ts), (f_su, su)):
        for col in ("u1_um_per_ms", "u2_um"):
            if (df[col].to_numpy(float) <= 0).any():
                raise DatasetError(f"{fname}: column {col} must be > 0 (found {df[col].min()!r})")
    if (ts["delay_us"].to_numpy(float) < 0).any():
        raise DatasetError(f"{f_ts}: column delay_us must be >= 0")
    for col in ("inflight_volume_nl", "grown_volume_at_pinchoff_nl"):
        if (su[col].to_numpy(float) < 0).any():
            raise DatasetError(f"{f_su}: column {col} has negative volumes")
    if (su["pinchoff_us"].to_numpy(float) <= ds.dead_time_us).any():
        raise DatasetError(f"{f_su}: column pinchoff_us must exceed the dead time {ds.dead_time_us} us")
    if (su["jetting_velocity_m_s"].to_numpy(float) <= 0).any():
        raise DatasetError(f"{f_su}: column jetting_velocity_m_s must be > 0")
    gv = ts["grown_volume_nl"].to_numpy(float)[att]
    gv = gv[np.isfinite(gv)]
    # grown volumes are meniscus-subtracted, so slightly negative values from noise are fine;
    # a clearly negative volume signals a sign or unit error.
    scale = max(float(np.nanmax(np.abs(gv))) if gv.size else 0.0, 1e-12)
    if gv.size and gv.min() < -0.5 * scale:
        raise DatasetError(f"{f_ts}: column grown_volume_nl has strongly negative volumes (min {gv.min():.3g} nl)")

    if su["sequence_id"].duplicated().any():
        dup = su["sequence_id"][su["sequence_id"].duplicated()].iloc[0]
        raise DatasetError(f"{f_su}: sequence_id {dup!r} appears more than once")
    if len(su) < 2:
        raise DatasetError(f"{f_su}: only {len(su)} sequence; identification needs several sequences")

    h = ds.sample_interval_us
    su_idx = su.set_index("sequence_id")
    for sid, g in ts.groupby("sequence_id", sort=False):
        d = g["delay_us"].to_numpy(float)
        if np.unique(g["u1_um_per_ms"]).size != 1 or np.unique(g["u2_um"]).size != 1:
            raise DatasetError(f"{f_ts}: sequence {sid!r} has several (u1_um_per_ms, u2_um) values")
        if sid not in su_idx.index:
            continue  # in timeseries.parquet only: dropped by the fits with a note
        row = su_idx.loc[sid]
        if not np.isclose(g["u1_um_per_ms"].iloc[0], row["u1_um_per_ms"]) or not np.isclose(g["u2_um"].iloc[0], row["u2_um"]):
            raise DatasetError(f"{f_ts}: sequence {sid!r} (u1_um_per_ms, u2_um) differs from {f_su}")
        ds_sorted = np.sort(d)
        k = ds_sorted / h
        if not np.allclose(k, np.round(k), atol=1e-6):
            raise DatasetError(
                f"{f_ts}: sequence {sid!r} column delay_us is not on the {h} us sampling grid "
                "(non-uniform sampling)"
            )
        # gaps, repeated delays and short sequences are irregular, not wrong: see timeseries_runs
    n_ctrl = len(ds.distinct_controls())
    if n_ctrl < min_controls:
        raise DatasetError(
            f"{f_su}: only {n_ctrl} distinct (u1_um_per_ms, u2_um) pair(s); the polynomial models "
            f"need at least {min_controls}"
        )
    masks, _ = summary_usable(ds)
    ctrl = su[["u1_um_per_ms", "u2_um"]].to_numpy(float)
    for name, m in masks.items():
        n_use = len(np.unique(ctrl[m], axis=0)) if m.any() else 0
        if n_use < min_controls:
            cols = ", ".join(_TARGET_COLUMNS[name])
            raise DatasetError(
                f"{f_su}: only {n_use} distinct (u1_um_per_ms, u2_um) pair(s) with finite {cols}; the "
                f"{name} polynomial needs at least {min_controls}")
    runs, _ = timeseries_runs(ds)
    if not runs:
        raise DatasetError(
            f"{f_ts}: no sequence usable for the ECM: each needs at least {MIN_RUN_SAMPLES} contiguous "
            "attached samples from delay 0 past the dead time")
    _check_plausible(ds, f_ts, f_su, f_js)
    return ds


#: Plausible range of (grown volume at pinch-off) / (nozzle cross-section x stroke u2): the
#: piston displaces the liquid that grows the drop, and its area is larger than the nozzle's
#: (the synthetic printhead: ~20; a 50 µm nozzle with the paper's ~18 nl drops at 25 µm: ~370).
#: Generous bounds, a factor 100 beyond either: volumes in pl labelled nl come out 1000 x too
#: large, in µl 1000 x too small.
VOLUME_PER_STROKE_RANGE = (1e-2, 1e4)


def _check_plausible(ds: Dataset, f_ts: str, f_su: str, f_js: str) -> None:
    """Refuse data that pass the format checks but cannot be what the columns say.

    - constant outputs: every sequence with the same in-flight volume, grown volume at
      pinch-off or jetting velocity (an export that filled a column with one value): the
      adjusters would be fitted to nothing;
    - swapped u1/u2 columns: the piston reaches its maximum stroke at dead time +
      1000 u2/u1 µs; the drop cannot pinch off while the piston is still pushing it out, so
      pinch-off before the maximum stroke in most sequences means u1 (µm/ms) and u2 (µm) are
      swapped (on the paper's grid u1 50-80, u2 20-35: pinch-off 1.7-2.8 stroke durations
      after the dead time; swapped: 0.2-0.9);
    - volume units: the grown volume at pinch-off against the nozzle cross-section x stroke
      (:data:`VOLUME_PER_STROKE_RANGE`), e.g. pl labelled nl.
    """
    su = ds.summary
    for col in ("inflight_volume_nl", "grown_volume_at_pinchoff_nl", "jetting_velocity_m_s"):
        v = su[col].to_numpy(float)
        v = v[np.isfinite(v)]
        if v.size >= 2 and np.all(v == v[0]):
            raise DatasetError(
                f"{f_su}: column {col} is constant ({v[0]:.6g} in all {v.size} sequences): nothing to "
                "identify; an export that filled the column with one value?")
    u1 = su["u1_um_per_ms"].to_numpy(float)
    u2 = su["u2_um"].to_numpy(float)
    stroke_us = 1000.0 * u2 / u1
    tp_all = su["pinchoff_us"].to_numpy(float)
    seen = np.isfinite(tp_all)
    early = (tp_all[seen] - ds.dead_time_us) < stroke_us[seen]
    if early.sum() > 0.5 * early.size:
        raise DatasetError(
            f"{f_su}: columns u1_um_per_ms and u2_um look swapped: in {int(early.sum())} of {early.size} "
            f"sequences pinch-off comes before the maximum stroke (dead time + 1000 u2/u1 us: median "
            f"{ds.dead_time_us + float(np.median(stroke_us)):.4g} us, pinch-off median "
            f"{float(np.median(tp_all[seen])):.4g} us); u1 (um/ms) median {float(np.median(u1)):.4g}, "
            f"u2 (um) median {float(np.median(u2)):.4g}")
    area_um2 = np.pi / 4.0 * ds.nozzle_inner_diameter_um**2
    per_stroke_nl = area_um2 * u2 * 1e-6  # um^3 -> nl
    lo, hi = VOLUME_PER_STROKE_RANGE
    for fname, col, values in (
        (f_su, "grown_volume_at_pinchoff_nl", su["grown_volume_at_pinchoff_nl"].to_numpy(float)),
        (f_su, "inflight_volume_nl", su["inflight_volume_nl"].to_numpy(float)),
    ):
        fin = np.isfinite(values)
        if not fin.any():
            continue
        ratio = float(np.median(values[fin] / per_stroke_nl[fin]))
        values = values[fin]
        if not lo <= ratio <= hi:
            unit = "pl labelled nl" if ratio > hi else "ul or m^3 labelled nl"
            raise DatasetError(
                f"{fname}: column {col} (median {float(np.median(values)):.4g} nl) is {ratio:.3g} x the "
                f"nozzle cross-section x stroke (nozzle_inner_diameter_um {ds.nozzle_inner_diameter_um:g} "
                f"of {f_js}), outside the plausible {lo:g}-{hi:g}: volumes in {unit}, or a wrong nozzle "
                "diameter?")
    gv = ds.timeseries["grown_volume_nl"].to_numpy(float)
    att = ds.timeseries["attached"].to_numpy(bool)
    top = float(np.nanmax(gv[att])) if np.isfinite(gv[att]).any() else 0.0
    top_ref = float(np.max(per_stroke_nl))
    if top > hi * top_ref:
        raise DatasetError(
            f"{f_ts}: column grown_volume_nl (max {top:.4g} nl) is {top / top_ref:.3g} x the nozzle "
            f"cross-section x largest stroke, above the plausible {hi:g}: volumes in pl labelled nl?")


def load_dataset(path, *, min_controls: int = 3) -> Dataset:
    """Read and validate a dataset folder.

    Raises
    ------
    DatasetError
        Missing folder/file, bad JSON, missing columns, wrong dtypes, inf, out-of-range
        values, delays off the sampling grid, a single sequence, too few distinct (u1, u2)
        pairs usable for a polynomial, no sequence usable for the ECM, implausible data.
    """
    path = Path(path)
    if not path.is_dir():
        raise DatasetError(f"{path}: dataset folder not found")
    files = {n: path / n for n in ("timeseries.parquet", "summary.parquet", "dataset.json")}
    for n, f in files.items():
        if not f.is_file():
            raise DatasetError(f"{f}: missing file")
    try:
        meta = json.loads(files["dataset.json"].read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{files['dataset.json']}: invalid JSON ({exc})") from None
    try:
        schema.check_document(meta, schema.DATASET, files["dataset.json"])
    except schema.SchemaError as exc:
        raise DatasetError(str(exc)) from None
    frames = {}
    for n in ("timeseries.parquet", "summary.parquet"):
        try:
            frames[n] = pd.read_parquet(files[n])
        except Exception as exc:  # noqa: BLE001 - pyarrow raises many types
            raise DatasetError(f"{files[n]}: cannot read parquet ({type(exc).__name__}: {exc})") from None

    def num(key, default=None, required=False):
        if key not in meta or meta[key] is None:
            if required:
                raise DatasetError(f"{files['dataset.json']}: missing key {key}")
            return default
        try:
            return float(meta[key])
        except (TypeError, ValueError):
            raise DatasetError(f"{files['dataset.json']}: {key} must be a number, got {meta[key]!r}") from None

    known = {"schema", "nozzle_inner_diameter_um", "sample_interval_us", "dead_time_us", "u3_um_per_ms", "hold_us", "ink", "nozzle"}
    ds = Dataset(
        timeseries=frames["timeseries.parquet"],
        summary=frames["summary.parquet"],
        nozzle_inner_diameter_um=num("nozzle_inner_diameter_um", required=True),
        sample_interval_us=num("sample_interval_us", required=True),
        dead_time_us=num("dead_time_us", DEAD_TIME_US),
        u3_um_per_ms=num("u3_um_per_ms", U3_PRESET_UM_PER_MS),
        hold_us=num("hold_us", HOLD_PRESET_US),
        ink=meta.get("ink"),
        nozzle=meta.get("nozzle"),
        path=path,
        extra={k: v for k, v in meta.items() if k not in known},
    )
    validate(ds, min_controls=min_controls)
    ds.hydraulics()  # validates ink/nozzle geometry if given
    return ds


# ---------------------------------------------------------------------------------------
# Synthetic dataset
# ---------------------------------------------------------------------------------------


def paper_grid(step_u1: float = 5.0, step_u2: float = 1.25) -> list[tuple[float, float]]:
    """Colour-ink campaign grid of Table 1: u1 50..80 um/ms, u2 20..35 um."""
    u1 = np.arange(50.0, 80.0 + 1e-9, step_u1)
    u2 = np.arange(20.0, 35.0 + 1e-9, step_u2)
    return [(float(a), float(b)) for a in u1 for b in u2]


def ecm_truth(physics: SynthPhysics, u1: float, u2: float, t_us: np.ndarray, t_p: float):
    """Exact ECM response of a synthetic physics for one waveform.

    Parameters
    ----------
    physics : SynthPhysics
    u1, u2 : float
        Stroke velocity (µm/ms) and stroke (µm).
    t_us : ndarray
        Uniform sample times from the trigger (µs).
    t_p : float
        Pinch-off instant from the trigger (µs).

    Returns
    -------
    volume_nl, flow_nl_per_us : ndarray
        Grown volume (nl) and flow (nl/µs) at ``t_us`` (:func:`identify.ecm.simulate`).
    volume_at_pinchoff_nl : float
        Grown volume at ``t_p`` (nl), exact (:func:`identify.montecarlo.ecm_response_at`).
    flow_at_max_stroke_nl_per_us : float
        Flow at the maximum-stroke instant (nl/µs), exact.
    """
    coeffs = physics.ecm_parameters().coefficients()
    w = Waveform(u1, u2, physics.u3_um_per_ms, physics.hold_us)
    u = w.displacement_um(t_us - physics.dead_time_us)
    vol, flow = simulate(coeffs, t_us, u)
    c = coeffs.to_array()[None, :]
    v_p, _ = ecm_response_at(c, w, np.array([t_p - physics.dead_time_us]))
    _, q_max = ecm_response_at(c, w, np.array([w.max_stroke_us]))
    return vol, flow, float(v_p[0]), float(q_max[0])


def make_synthetic_dataset(
    out_dir,
    grid=None,
    noise_percent: float = 1.0,
    seed: int = 0,
    physics=None,
    *,
    repeats: int = 1,
    sample_interval_us: float = SAMPLE_INTERVAL_US,
    tail_samples: int = 3,
    noise_draw=None,
) -> Dataset:
    """Write a synthetic dataset with exactly known truth and return it.

    For each (u1, u2) of ``grid`` (default :func:`paper_grid`) and each repeat, the grown
    volume is the ECM response of ``physics`` to the delayed waveform, sampled every
    ``sample_interval_us`` from the trigger until pinch-off (+ ``tail_samples`` detached
    rows with NaN volume). The summary holds the pinch-off law, the ECM grown volume at the
    pinch-off instant, in-flight volume = that + volume adjuster, and jetting velocity = ECM
    flow velocity at maximum stroke + velocity adjuster (Eq. 8).

    Noise: every volume, velocity and pinch-off value gets independent Gaussian noise of
    ``noise_percent`` % of its own magnitude (time series: of the sequence's peak volume /
    velocity). The truth is written to ``truth.json``.

    ``noise_draw``: another scatter of the same size, a function ``(rng, size)`` returning
    draws of zero mean and unit variance (``size`` None: one float), e.g. a scaled Student t
    for heavier tails (`tools/interval_coverage.py`); default ``rng.standard_normal``.
    """
    physics = physics or default_physics()
    grid = paper_grid() if grid is None else [(float(a), float(b)) for a, b in grid]
    rng = np.random.default_rng(seed)
    sigma = noise_percent / 100.0
    draw = (lambda r, size=None: r.standard_normal(size)) if noise_draw is None else noise_draw
    d_um = physics.nozzle_inner_diameter_um
    h = float(sample_interval_us)
    ts_rows, su_rows, truth_rows = [], [], []
    sid = 0
    for u1, u2 in grid:
        t_p = float(physics.pinchoff_instant_us(u1, u2))
        n = int(np.floor(t_p / h)) + 1 + tail_samples
        t = np.arange(n) * h
        vol, flow, v_p, q_max = ecm_truth(physics, u1, u2, t, t_p)
        vel = flow_velocity_m_s(flow, d_um)
        v_max = flow_velocity_m_s(q_max, d_um)
        inflight = v_p + float(physics.volume_adjuster_nl_at(u1, u2))
        jet = v_max + float(physics.velocity_adjuster_m_s_at(u1, u2))
        truth_rows.append({"u1_um_per_ms": u1, "u2_um": u2, "pinchoff_us": t_p, "grown_volume_at_pinchoff_nl": v_p,
                           "inflight_volume_nl": inflight, "jetting_velocity_m_s": jet,
                           "flow_velocity_at_max_stroke_m_s": v_max})
        for _ in range(repeats):
            tp_meas = t_p * (1 + sigma * draw(rng))
            attached = t < tp_meas
            vn = vol + sigma * np.abs(vol).max() * draw(rng, n)
            fn = vel + sigma * np.abs(vel).max() * draw(rng, n)
            vn[~attached] = np.nan
            fn[~attached] = np.nan
            ts_rows.append(pd.DataFrame({
                "sequence_id": sid, "u1_um_per_ms": u1, "u2_um": u2, "delay_us": t,
                "grown_volume_nl": vn, "flow_velocity_m_s": fn, "attached": attached,
            }))
            su_rows.append({
                "sequence_id": sid, "u1_um_per_ms": u1, "u2_um": u2, "pinchoff_us": tp_meas,
                "grown_volume_at_pinchoff_nl": v_p * (1 + sigma * draw(rng)),
                "inflight_volume_nl": inflight * (1 + sigma * draw(rng)),
                "jetting_velocity_m_s": jet * (1 + sigma * draw(rng)),
                "flow_velocity_at_max_stroke_m_s": v_max * (1 + sigma * draw(rng)),
            })
            sid += 1
    ts = pd.concat(ts_rows, ignore_index=True)
    ts["sequence_id"] = ts["sequence_id"].astype("int64")
    su = pd.DataFrame(su_rows)
    ds = Dataset(
        timeseries=ts, summary=su, nozzle_inner_diameter_um=d_um, sample_interval_us=h,
        dead_time_us=physics.dead_time_us, u3_um_per_ms=physics.u3_um_per_ms, hold_us=physics.hold_us,
        ink={"name": "synthetic colour ink", "density_kg_m3": physics.density_kg_m3,
             "viscosity_mPa_s": physics.viscosity_mpa_s, "surface_tension_mN_m": physics.surface_tension_mn_m},
        nozzle={"length_mm": physics.nozzle_length_mm, "outer_diameter_um": physics.nozzle_outer_diameter_um,
                "reservoir_channel_radius_um": physics.reservoir_channel_radius_um,
                "reservoir_channel_length_mm": physics.reservoir_channel_length_mm},
        extra={"synthetic": {"noise_percent": noise_percent, "seed": seed, "repeats": repeats},
               "measurement_uncertainty": {
                   "volume_rel": 0.0, "velocity_rel": 0.0, "pinchoff_std_us": 0.0,
                   "source": "make_synthetic_dataset: exact truth plus independent noise per sequence, no "
                             "systematic error"}},
    )
    out_dir = Path(out_dir)
    ds.save(out_dir)
    p = physics.ecm_parameters()
    write_json(out_dir / "truth.json", {
        "schema": "identify.truth/1",
        "physics": physics.to_dict(),
        "ecm_parameters": p.to_dict(),
        "ecm_coefficients": p.coefficients().to_dict(),
        "per_control": truth_rows,
    })
    ds.path = out_dir
    return ds
