"""Writing a synthetic sequence folder: images, sequence.json, truth.json, truth_frames.csv,
truth_bodies.csv.

All files go through the shared writers of :mod:`dropvision.io.sequence_writer` (images, multi-page TIFF,
sequence.json) and :mod:`dvcore.atomic`; the whole folder is built in a temporary sibling
and renamed into place at the end, so a failure never leaves a half-written sequence.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from dvcore.atomic import atomic_dir, check_output_dir, write_bytes, write_json, write_text
from dropvision.io.sequence_writer import write_image, write_multipage_tiff, write_sequence_json
from dropvision.synth.sequence import (STACK_FILE, SynthConfig, truth_bodies_table, truth_frames_table, plan, sequence_truth,
                                       synthesize)

__all__ = ["write_synthetic_sequence", "sequence_metadata", "encode_jpeg"]


def sequence_metadata(config: SynthConfig, frames) -> dict:
    """sequence.json content (without the schema key) for a config and its frame list."""
    cfg, ph = config, config.physics
    if cfg.scene == "pendant":  # the needle: its outer diameter as rendered, inner 0.6 x outer
        d_out = cfg.needle_outer_diameter_um
        d_in = float(ph.nozzle_inner_diameter_um) if cfg.needle_diameter_um is None else 0.6 * d_out
    else:
        d_out, d_in = float(ph.nozzle_outer_diameter_um), float(ph.nozzle_inner_diameter_um)
    drive = cfg.drive()
    meta = {
        "pixel_size_um": float(cfg.pixel_size_um),
        "nozzle_inner_diameter_um": d_in,
        "nozzle_outer_diameter_um": d_out,
        "orientation": cfg.orientation,
        "waveform": {"u1_um_per_ms": float(cfg.u1_um_per_ms), "u2_um": float(cfg.u2_um),
                     "u3_um_per_ms": float(ph.u3_um_per_ms), "hold_us": float(ph.hold_us),
                     "dead_time_us": float(ph.dead_time_us)} if drive is None else drive.to_dict(),
        "ink": {"name": ph.ink_name, "density_kg_m3": float(ph.density_kg_m3),
                "viscosity_mPa_s": float(ph.viscosity_mpa_s),
                "surface_tension_mN_m": float(ph.surface_tension_mn_m)},
        "nozzle": {"length_mm": float(ph.nozzle_length_mm),
                   "reservoir_channel_radius_um": float(ph.reservoir_channel_radius_um),
                   "reservoir_channel_length_mm": float(ph.reservoir_channel_length_mm)},
        "bit_depth": int(cfg.bit_depth),
        "synthetic": True,
        "frames": [({"file": f, "page": int(pg), "delay_us": float(d)} if pg is not None
                    else {"file": f, "delay_us": float(d)}) for _, f, pg, d, _ in frames],
    }
    if not cfg.write_nozzle_diameters:
        del meta["nozzle_inner_diameter_um"], meta["nozzle_outer_diameter_um"]
    return meta


def encode_jpeg(img: np.ndarray, quality: int) -> bytes:
    """JPEG bytes (OpenCV's libjpeg-turbo) of an 8-bit grey or RGB frame."""
    if img.dtype != np.uint8:
        raise ValueError(f"JPEG frames are 8-bit only, got {img.dtype}")
    arr = cv2.cvtColor(img, cv2.COLOR_RGB2BGR) if img.ndim == 3 else img
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(arr), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - cv2 encodes every 8-bit array
        raise ValueError("cv2 could not encode the JPEG frame")
    return buf.tobytes()


def _inflight_with_touching(truth: dict, rows) -> dict:
    """The in-flight volume as measured: the mean over the in-flight frames of the main drop's
    silhouette volume, which holds a satellite touching it (frames' ``drop_volume_nl``); the
    same as the drop's own volume when no satellite touches it."""
    own = truth.get("inflight_volume_nl")
    vols = np.array([r.drop_volume_nl for r in rows if r.inflight and np.isfinite(r.drop_volume_nl)], float)
    if own and np.isfinite(own) and vols.size and np.any(np.abs(vols / own - 1.0) > 1e-9):
        truth["inflight_volume_nl"] = float(vols.mean())
        truth["inflight_volume_own_nl"] = own
        truth["conventions"]["inflight_volume_nl"] = ("mean over the in-flight frames of the main drop's silhouette "
                                                      "volume (satellites touching it included); "
                                                      "inflight_volume_own_nl: the drop alone")
    return truth


def write_synthetic_sequence(config: SynthConfig, out_dir, *, progress: bool | None = None,
                             overwrite: bool = False) -> Path:
    """Render ``config`` and write the sequence folder with its ground truth.

    Parameters
    ----------
    config : SynthConfig
    out_dir : str or Path
        Target folder. It is created, or replaced if it holds only an earlier result of ours
        (see `dvcore.atomic.atomic_dir`); any other non-empty folder is refused.
    progress : bool or None
        tqdm progress bar (None: only on a terminal).
    overwrite : bool
        Write into an existing folder of ours (it carries our marker) that holds files we did
        not write: our earlier files are replaced or removed (a sequence never mixes frames of
        two renders), the others are kept. A folder we never wrote is refused even so.

    Returns
    -------
    Path
        The sequence folder.
    """
    out = Path(out_dir)
    check_output_dir(out, overwrite="marked" if overwrite else False)
    p = plan(config)
    rows = []
    with atomic_dir(out, overwrite="marked" if overwrite else False, kind="synthetic-sequence") as tmp:
        if config.format == "tiff-stack":
            pages = []
            for img, truth in synthesize(config, progress=progress, synth_plan=p):
                pages.append(img)
                rows.append(truth)
            write_multipage_tiff(tmp / STACK_FILE, pages, [r.delay_us for r in rows],
                                 pixel_size_um=config.pixel_size_um)
        else:
            for img, truth in synthesize(config, progress=progress, synth_plan=p):
                if config.format == "jpeg":
                    write_bytes(tmp / truth.file, encode_jpeg(img, config.jpeg_quality))
                else:
                    write_image(tmp / truth.file, img)
                rows.append(truth)
        write_sequence_json(tmp, sequence_metadata(config, p.frames))
        write_json(tmp / "truth.json", _inflight_with_touching(sequence_truth(p), rows))
        write_text(tmp / "truth_frames.csv", truth_frames_table(rows).to_csv(index=False, float_format="%.9g"))
        write_text(tmp / "truth_bodies.csv", truth_bodies_table(rows).to_csv(index=False, float_format="%.9g"))
    return out
