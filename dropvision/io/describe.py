"""`dropvision init`: look at a folder of images and write the sequence.json they need.

What the images tell is written (the frames and their delays from the file names or the image
metadata, the orientation from the edge the nozzle or holder touches, the bit depth) together
with what was seen (the nozzle's outer width in px); what only the user can give (the pixel
size or the nozzle's outer diameter, the waveform, a delay nothing states) is written as
``null`` and listed under ``dropvision_init.to_give``. Values given as options (the keys of
sequence.json, `dropvision.io.sequence.OVERRIDE_KEYS`) are validated as the file's and written.

An existing sequence.json is never replaced unless ``overwrite`` (a user's data is sacred).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dvcore import __version__
from dropvision.calibrate.calibration import CalibrationError
from dropvision.calibrate.inspection import nozzle_outer_width_px
from dropvision.io.overrides import from_command_line, how_to_give
from dropvision.io.sequence import SEQUENCE_JSON, SequenceError, check_overrides, open_sequence
from dropvision.io.sequence_writer import write_sequence_json

__all__ = ["FolderDescription", "describe_folder", "init_sequence"]


@dataclass
class FolderDescription:
    """What `describe_folder` found in a folder of images.

    Attributes
    ----------
    folder : Path
    doc : dict
        The sequence.json to write (``null`` where only the user can give the value).
    to_give : list of str
        What only the user can give, one sentence each.
    lines : list of str
        A one-screen summary of the folder, for people.
    nozzle_outer_width_px : float or None
        The nozzle's outer width, median over up to 7 frames spread over the folder (None: not found).
    """

    folder: Path
    doc: dict
    to_give: list = field(default_factory=list)
    lines: list = field(default_factory=list)
    nozzle_outer_width_px: float | None = None


def _label(labels: dict, key: str, option: str) -> str:
    return labels.get(key, option)


def describe_folder(folder, overrides: dict | None = None, labels: dict | None = None) -> FolderDescription:
    """Look at the images of a folder (an existing sequence.json is ignored).

    Parameters
    ----------
    folder : str or Path
        A folder of images (any format of docs/FORMAT.md).
    overrides, labels : dict, optional
        Values of sequence.json keys given by the user, and how (see
        `dropvision.io.sequence.open_sequence`).

    Returns
    -------
    FolderDescription

    Raises
    ------
    dropvision.io.sequence.SequenceError
        No images, delays that cannot be told apart, a bad option.
    """
    labels = dict(labels or {})
    given = check_overrides(overrides, labels)
    folder = Path(folder)
    with open_sequence(folder, overrides=given, labels=labels, ignore_sequence_json=True,
                       require_pixel_size=False) as seq:
        meta = seq.meta
        n = len(seq)
        spread = [seq.read(int(i)) for i in np.unique(np.round(np.linspace(0, n - 1, min(n, 7))).astype(int))]
        frames = [fr for fr in spread if fr.image is not None]
    first = frames[0] if frames else None
    width_px, nozzle_note, nozzle_frames = None, "", 0
    if first is not None:
        try:
            width_px, nozzle_frames = nozzle_outer_width_px([fr.image for fr in frames],
                                                            max_value=2 ** meta.bit_depth - 1)
        except CalibrationError as exc:
            nozzle_note = f"not found in {len(frames)} frame(s) from {first.ref.file} ({exc})"
    doc, to_give = _document(meta, given, labels, width_px)
    lines = _summary_lines(folder, meta, given, width_px, nozzle_frames, nozzle_note, to_give)
    return FolderDescription(folder, doc, to_give, lines, width_px)


def _document(meta, given: dict, labels: dict, width_px) -> tuple[dict, list[str]]:
    """The sequence.json that ``dropvision init`` writes for a folder, and what is left TO GIVE (null)."""
    src = meta.sources
    to_give: list[str] = []
    doc: dict = {}
    if "pixel_size_um" in given:
        doc["pixel_size_um"] = given["pixel_size_um"]
    elif math.isnan(meta.pixel_size_um) and "nozzle_outer_diameter_um" not in given:
        doc["pixel_size_um"] = None
        implied = "" if width_px is None else f" (the nozzle is {width_px:.1f} px wide)"
        to_give.append(f"pixel_size_um ({how_to_give('pixel_size_um', labels)}), or the nozzle's outer diameter "
                       f"({how_to_give('nozzle_outer_diameter_um', labels)}: the pixel size is then that diameter over "
                       f"its width in px){implied}")
    for key in ("nozzle_outer_diameter_um", "nozzle_inner_diameter_um"):
        doc[key] = given.get(key)
    doc["orientation"] = meta.orientation
    doc["bit_depth"] = meta.bit_depth
    if "waveform" in given:
        doc["waveform"] = meta.waveform
    else:
        doc["waveform"] = None
        to_give.append("waveform: u1_um_per_ms and u2_um at least (" + (
            "--u1-um-per-ms, --u2-um" if from_command_line(labels) else "waveform={...}")
            + "; needed by "
                       "dropvision campaign and identify, not by measure)")
    if "ink" in given:
        doc["ink"] = given["ink"]
    for key in ("nozzle_tip_row", "axis_col"):
        if key in given:
            doc[key] = given[key]
    rate_keys = ("frame_rate_hz", "first_frame_delay_us", "trigger_frame")
    if "frame_rate_hz" in given:
        doc.update({k: given[k] for k in rate_keys if k in given})
    else:
        listed = sorted(meta.frames, key=lambda f: f.listed_index)
        assumed = meta.delay_assumed
        # a value TO GIVE is written null (measure then assumes 0 us and says so), never a made-up 0.0
        doc["frames"] = [{"file": f.file, **({} if f.page is None else {"page": f.page}),
                          "delay_us": None if assumed else f.delay_us} for f in listed]
        if assumed:
            to_give.append(f"delay_us of {listed[0].file} (null: nothing in its name or metadata "
                           f"states the strobe delay; {how_to_give('delay_us', labels)})")
    doc["dropvision_init"] = {
        "written_by": f"dropvision init {__version__}",
        "orientation_source": src.get("orientation"),
        "delay_source": src.get("delay"),
        "bit_depth_source": src.get("bit_depth"),
        "pixel_size_source": src.get("pixel_size"),
        "nozzle_outer_width_px": None if width_px is None else round(float(width_px), 2),  # a measured width: 0.01 px
        "to_give": to_give,
    }
    return doc, to_give


def _summary_lines(folder, meta, given: dict, width_px, nozzle_frames: int, nozzle_note: str,
                   to_give: list[str]) -> list[str]:
    """The one-screen summary of what the images say and what is to give."""
    src = meta.sources
    delays = meta.delays_us
    n = len(meta.frames)
    files = sorted({f.file for f in meta.frames})
    h, w = meta.shape if meta.orientation in ("down", "up") else meta.shape[::-1]
    lines = [
        f"{folder}: {n} frame{'s' if n != 1 else ''} in {len(files)} file{'s' if len(files) != 1 else ''} "
        f"({', '.join(files[:3])}{', ...' if len(files) > 3 else ''})",
        f"  delays     {delays.min():g}" + (f" .. {delays.max():g}" if n > 1 else "") + f" us ({src.get('delay')})",
        f"  images     {w} x {h} px as stored, {meta.bit_depth}-bit ({src.get('bit_depth')})",
        f"  orientation {meta.orientation}: drops travel {meta.orientation} ({src.get('orientation')})",
        "  nozzle     " + (f"outer width {width_px:.1f} px (median over {nozzle_frames} frame"
                           f"{'s' if nozzle_frames != 1 else ''})" if width_px is not None
                           else nozzle_note or "no readable frame"),
    ]
    if not math.isnan(meta.pixel_size_um):
        lines.append(f"  pixel size {meta.pixel_size_um:g} um ({src.get('pixel_size')})")
    elif "nozzle_outer_diameter_um" in given:
        d = given["nozzle_outer_diameter_um"]
        lines.append(f"  pixel size from the nozzle: {d:g} um / "
                     + (f"{width_px:.1f} px = {d / width_px:.4g} um (measured again by measure)" if width_px
                        else "its width in px (not found here)"))
    if meta.waveform and "template" in meta.waveform:  # a waveform template (issue 31)
        params = meta.waveform.get("parameters")
        lines.append(f"  waveform   {meta.waveform['template']}: "
                     + (", ".join(f"{k} {v:g}" for k, v in params.items()) if params
                        else "its parameters from each shot's labels"))
    elif meta.waveform:
        lines.append(f"  waveform   u1 {meta.waveform['u1_um_per_ms']:g} um/ms, u2 {meta.waveform['u2_um']:g} um")
    for item in to_give:
        lines.append(f"  TO GIVE    {item}")
    return lines


def init_sequence(folder, overrides: dict | None = None, labels: dict | None = None, *,
                  overwrite: bool = False) -> FolderDescription:
    """`describe_folder`, then write its sequence.json into the folder (atomically).

    Parameters
    ----------
    folder : str or Path
    overrides, labels : dict, optional
        See `describe_folder`.
    overwrite : bool
        Replace an existing sequence.json (without it, an existing one is refused before
        anything is looked at).

    Raises
    ------
    dropvision.io.sequence.SequenceError
        The folder holds a sequence.json (without ``overwrite``), or `describe_folder` fails.
    """
    json_path = Path(folder) / SEQUENCE_JSON
    give = "--overwrite" if from_command_line(labels) else "overwrite=True"  # the caller's words
    if not overwrite and (json_path.exists() or json_path.is_symlink()):
        raise SequenceError(f"{json_path}: exists; dropvision init never replaces a sequence.json "
                            f"({give} replaces it)")
    desc = describe_folder(folder, overrides, labels)
    if not overwrite and (json_path.exists() or json_path.is_symlink()):  # appeared meanwhile
        raise SequenceError(f"{json_path}: exists; dropvision init never replaces a sequence.json "
                            f"({give} replaces it)")
    write_sequence_json(folder, desc.doc)
    return desc
