"""Training dataset of the hybrid model: the container (:class:`Dataset`) and its files.

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
    sequence shares (see :func:`identify.measurement_uncertainty.measurement_uncertainty`).

Several sequences may share one (u1, u2). :func:`identify.dataset_checks.load_dataset` raises
:class:`DatasetError` naming the file and the column for every problem it finds.

Irregular campaigns are accepted (issue 13): missing frames (gaps in ``delay_us``, or attached
rows with NaN volume), repeated delays, a failed sequence (in one file only, or too short),
a sequence with no pinch-off seen (NaN ``pinchoff_us`` / volume / velocity in the summary).
:func:`identify.dataset_checks.timeseries_runs` and :func:`identify.dataset_checks.summary_usable` say what each fit can use and return notes
on what was dropped and why; :func:`identify.dataset_checks.validate` refuses only when nothing usable is left (fewer
than ``min_controls`` distinct (u1, u2) for a polynomial, or no sequence for the ECM) and keeps
refusing what cannot be true (constant outputs, swapped u1/u2, unit errors, wrong dtypes,
off-grid delays).

Modules: this one (the container, :class:`DatasetError`, the required columns, the
``measurement_uncertainty`` block of dataset.json); :mod:`identify.dataset_checks` (reading:
:func:`~identify.dataset_checks.load_dataset`, :func:`~identify.dataset_checks.validate`, what each
fit can use); :mod:`identify.measurement_uncertainty` (the systematic measurement uncertainty and
the sequences' standard errors); :mod:`identify.synthetic_dataset`
(:func:`~identify.synthetic_dataset.make_synthetic_dataset` writes such a folder from the default
synthetic physics of the project, whose truth is exactly known).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from dvcore.atomic import atomic_dir, write_json
from dvcore import schema
from identify.hydraulics import Hydraulics, hydraulics_from_dimensions
from identify.physics import SynthPhysics
from identify.waveform import DEAD_TIME_US, HOLD_PRESET_US, U3_PRESET_UM_PER_MS, Waveform

SCHEMA = schema.DATASET.schema

_KIND = {"id": "id", "float": "f", "bool": "b"}
#: The trapezoid's parameters: required here (a dataset of another waveform template has the
#: template's parameters in their place: `identify.template_dataset`).
_CONTROLS = ("u1_um_per_ms", "u2_um")
#: Required columns of timeseries.parquet and their kinds ("f" float, "b" bool, "id"), from
#: `dvcore.schema.TIMESERIES`.
TIMESERIES_COLUMNS = {c.name: _KIND[c.dtype] for c in schema.TIMESERIES.columns if c.required or c.name in _CONTROLS}
#: Required columns of summary.parquet, from `dvcore.schema.DATASET_SUMMARY`.
SUMMARY_COLUMNS = {c.name: _KIND[c.dtype] for c in schema.DATASET_SUMMARY.columns
                   if c.required or c.name in _CONTROLS}
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
