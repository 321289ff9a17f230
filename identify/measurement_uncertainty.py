"""Systematic measurement uncertainty of a training campaign (issue 13): what every sequence
shares (pixel size, the measurement method), and the sequences' own standard errors."""

from __future__ import annotations

import numpy as np
import pandas as pd

from identify.dataset import Dataset, campaign_calibration, check_measurement_block

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
