"""What a strobe sequence is made of: its frames' references, its metadata, and its errors.

`SequenceError` (an invalid sequence: the one-line message names the file and the problem) and
`RGBConvertedWarning` are raised by every part of reading a sequence (`dropvision.io.discovery`,
`dropvision.io.overrides`, `dropvision.io.sequence`); `dropvision.io.sequence` exports them all.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np


#: How ``SequenceMeta.pixel_size_source`` begins when the pixel size is the nozzle's outer diameter over its width
#: (`dropvision.calibrate.inspection.pixel_size_from_nozzle_width`).
NOZZLE_PIXEL_SIZE_SOURCE = "nozzle outer diameter"


class SequenceError(Exception):
    """Invalid sequence: the one-line message names the file and the problem."""


class RGBConvertedWarning(UserWarning):
    """Colour images were converted to grey by ITU-R BT.601 luminance; issued once per
    :class:`Sequence`, at the first colour frame read (the message names that file)."""


@dataclass(frozen=True)
class FrameRef:
    """One frame of a sequence (metadata only).

    Attributes
    ----------
    index : int
        Position in processing (ascending delay) order, 0..n-1.
    file : str
        Path relative to the sequence folder ('/'-separated).
    page : int or None
        Page of a multi-page TIFF, else None.
    delay_us : float
        Strobe delay after the firing trigger (µs).
    repeat : int
        0 for the first frame at this delay, 1 for the next, ...
    listed_index : int
        Position in the listed order (sequence.json ``frames``, else natural file-name order
        then page).
    """

    index: int
    file: str
    page: int | None
    delay_us: float
    repeat: int
    listed_index: int = -1


@dataclass(frozen=True)
class SequenceMeta:
    """Validated metadata of a sequence (see docs/FORMAT.md).

    ``nozzle_tip_row`` and ``axis_col`` are in the CANONICAL frame (drops travel down);
    ``shape`` is the canonical (rows, cols) of every frame; ``frames`` is in processing order.
    """

    path: Path
    pixel_size_um: float
    nozzle_inner_diameter_um: float | None
    nozzle_outer_diameter_um: float | None
    nozzle_tip_row: float | None
    axis_col: float | None
    orientation: str
    waveform: dict | None
    ink: dict | None
    frames: tuple[FrameRef, ...]
    shape: tuple[int, int]
    bit_depth: int
    reordered: bool
    extra: dict = field(default_factory=dict)
    #: Where the pixel size came from: "sequence.json", "ome" or "imagej" (TIFF metadata),
    #: "arguments" (frames in memory), an option (e.g. "command line --pixel-size-um") or
    #: the nozzle ("nozzle outer diameter 360 µm / 76.1 px measured (...)").
    pixel_size_source: str = "sequence.json"
    #: Where each value came from, for summary.json's ``*_source`` keys: ``pixel_size``,
    #: ``orientation`` ("sequence.json", an option, "detected: ..." or "default ..."),
    #: ``nozzle_outer_diameter``, ``nozzle_inner_diameter``, ``delay``, ``waveform``,
    #: ``bit_depth`` (None: not given).
    sources: dict = field(default_factory=dict)
    #: The orientation was neither given nor detected: ``"down"`` is assumed (``sources["orientation"]``
    #: says what was seen at each edge).
    orientation_assumed: bool = False
    #: The pixel size is the nozzle's outer diameter over its measured width (no pixel size given).
    pixel_size_from_nozzle: bool = False
    #: One frame without a delay anywhere: 0 µs is assumed (``sources["delay"]`` says so).
    delay_assumed: bool = False

    @property
    def delays_us(self) -> np.ndarray:
        """Delays of the frames in processing order (µs)."""
        return np.array([f.delay_us for f in self.frames], dtype=float)

    def to_dict(self) -> dict:
        """JSON-ready dict (frames as a list of dicts, path as a string)."""
        out = asdict(self)
        out["path"] = str(self.path)
        out["shape"] = list(self.shape)
        out["frames"] = [asdict(f) for f in self.frames]
        return out


@dataclass
class Frame:
    """A decoded frame: ``image`` (2-D, canonical orientation, uint8/uint16) or ``error``."""

    ref: FrameRef
    image: np.ndarray | None
    error: str | None = None
