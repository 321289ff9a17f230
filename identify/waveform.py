"""Waveforms of the modelling layer: the paper's trapezoidal piston waveform (Eq. 1 and Eq. 9) and
the waveform templates (:class:`WaveformTemplate`, :data:`TEMPLATES`, :class:`Drive`,
:func:`drive_from_document`).

They are defined in :mod:`dvcore.waveform`, the drive vocabulary that the measurement layer
(sequence.json's ``waveform``, the dead time) and the modelling layer both stand on (issue 34:
measurement never imports modelling); this module re-exports them under their modelling names.
"""

from __future__ import annotations

from dvcore.waveform import (
    DEAD_TIME_US,
    EDGE_PRESET_US,
    HOLD_PRESET_US,
    SAMPLE_INTERVAL_US,
    TEMPLATES,
    U3_PRESET_UM_PER_MS,
    Drive,
    SegmentsTemplate,
    ThreePulseTemplate,
    TrapezoidTemplate,
    Waveform,
    WaveformParameter,
    WaveformTemplate,
    drive_from_document,
    template_from_dict,
)

__all__ = [
    "DEAD_TIME_US", "EDGE_PRESET_US", "HOLD_PRESET_US", "SAMPLE_INTERVAL_US", "TEMPLATES",
    "U3_PRESET_UM_PER_MS", "Drive", "SegmentsTemplate", "ThreePulseTemplate", "TrapezoidTemplate",
    "Waveform", "WaveformParameter", "WaveformTemplate", "drive_from_document", "template_from_dict",
]
