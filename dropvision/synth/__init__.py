"""Physics-driven synthetic strobe sequences with exact ground truth (`dropvision synth`).

Modules: :mod:`~dropvision.synth.physics` (waveform -> ECM -> pinch-off and adjusters),
:mod:`~dropvision.synth.shapes` (axisymmetric bodies, exact volumes, drop formation model),
:mod:`~dropvision.synth.render` (supersampled silhouettes, optics, sensor),
:mod:`~dropvision.synth.sequence` (configuration, synthesis, truth),
:mod:`~dropvision.synth.writer` (sequence folder), :mod:`~dropvision.synth.cli`.
"""

from dropvision.synth.physics import DropHistory, SynthPhysics, drop_history
from dropvision.synth.sequence import (FORMATS, TRUTH_COLUMNS, FrameTruth, SynthConfig, parse_delays,
                                       plan, sequence_truth, synthesize)
from dropvision.synth.shapes import DropShapeModel, ShapeParams
from dropvision.synth.writer import write_synthetic_sequence

__all__ = ["DropHistory", "SynthPhysics", "drop_history", "FORMATS", "TRUTH_COLUMNS", "FrameTruth",
           "SynthConfig", "parse_delays", "plan", "sequence_truth", "synthesize", "DropShapeModel",
           "ShapeParams", "write_synthetic_sequence"]
