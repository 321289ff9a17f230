"""A first look at a frame: how wide the nozzle is in pixels (where it is: `dropvision.io.orientation`).

What a user of a drop watcher does not want to type, read from the frame itself:

- `nozzle_outer_width_px`: the nozzle's outer width in pixels, by the measurement's own
  calibration (`dropvision.calibrate.calibration.calibrate_frames` on each frame; the median over frames spread
  over the sequence, as a neck hanging from the nozzle can be narrower than its walls), so that
  a pixel size can come from a known outer diameter (as OpenDrop and DropPyTension take it
  from the needle).
- `pixel_size_from_nozzle_width`: a sequence's metadata with that pixel size (the reader,
  `dropvision.io.sequence.open_sequence`, hands it the frames it decoded).

This module knows nothing of sequence folders: it looks at arrays and metadata
(`dropvision.io.sequence` and `dropvision.io.describe` call it).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from dropvision.calibrate.calibration import CalibrationError, calibrate_frames
from dropvision.io.overrides import ranged_value
from dropvision.io.sequence_meta import NOZZLE_PIXEL_SIZE_SOURCE, SequenceError, SequenceMeta

__all__ = ["NOZZLE_FRAMES", "nozzle_outer_width_px", "pixel_size_from_nozzle_width"]

#: Frames spread over a sequence in which the nozzle's outer width is measured.
NOZZLE_FRAMES = 7


def nozzle_outer_width_px(images, *, max_value: int | None = None) -> tuple[float, int]:
    """Outer width of the nozzle in pixels, measured as the calibration measures it.

    Each frame is calibrated alone (`dropvision.calibrate.calibration.calibrate_frames`: without an expected
    width the narrowest straight walls of the top body); a neck or a thread of liquid hanging
    from the nozzle can be narrower than its walls in some frames, so the median over the
    frames is returned (give frames spread over the sequence).

    Parameters
    ----------
    images : ndarray or list of ndarray
        Frames, 2-D grey, in the canonical orientation (nozzle at the top).
    max_value : int, optional
        Sensor maximum (a clipped backlight is then handled as in the measurement).

    Returns
    -------
    width_px : float
        Median outer diameter in px (the walls' horizontal width times the cosine of the tilt).
    n_frames : int
        Frames in which the nozzle was found.

    Raises
    ------
    dropvision.calibrate.calibration.CalibrationError
        No nozzle found in any frame (the first frame's reason).
    """
    images = [images] if isinstance(images, np.ndarray) else list(images)
    widths, first_error = [], None
    for image in images:
        try:  # the pixel size does not enter the wall positions: 1 µm/px is a placeholder
            widths.append(float(calibrate_frames(image, [image], 1.0, max_value=max_value).nozzle_outer_diameter_px))
        except CalibrationError as exc:
            first_error = first_error or exc
    if not widths:
        raise first_error or CalibrationError("no frame to measure the nozzle in")
    return float(np.median(widths)), len(widths)


def pixel_size_from_nozzle_width(meta: SequenceMeta, images, first_file: str, where: str) -> SequenceMeta:
    """The metadata with the pixel size = ``nozzle_outer_diameter_um`` over the nozzle's outer
    width in px (`nozzle_outer_width_px`: the median over ``images``, up to `NOZZLE_FRAMES`
    frames spread over the sequence, the first one ``first_file``).

    Raises
    ------
    SequenceError
        One line naming ``first_file``: the width cannot be measured; or naming ``where`` (the
        diameter's source): the pixel size it gives is outside its accepted range.
    """
    d_out = meta.nozzle_outer_diameter_um
    try:
        width_px, used = nozzle_outer_width_px(images, max_value=2 ** meta.bit_depth - 1)
    except CalibrationError as exc:
        raise SequenceError(f"{meta.path / first_file}: no pixel size given, and the nozzle's outer width "
                            f"cannot be measured to take it from nozzle_outer_diameter_um ({exc})") from None
    pixel_size_um = ranged_value(d_out / width_px, "pixel_size_um",
                                 f"pixel size from nozzle_outer_diameter_um {d_out:g} µm over {width_px:.2f} px", where)
    source = (f"{NOZZLE_PIXEL_SIZE_SOURCE} {d_out:g} um / {width_px:.2f} px (median over {used} frame"
              f"{'s' if used != 1 else ''} from {first_file}; diameter from "
              f"{meta.sources.get('nozzle_outer_diameter')})")
    return dataclasses.replace(meta, pixel_size_um=pixel_size_um, pixel_size_source=source, pixel_size_from_nozzle=True,
                               sources={**meta.sources, "pixel_size": source})
