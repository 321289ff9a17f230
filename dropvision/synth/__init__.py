"""Physics-driven synthetic strobe sequences with exact ground truth (`dropvision synth`).

Modules: :mod:`~identify.physics` (waveform -> ECM -> pinch-off and adjusters; modelling
layer, no images),
:mod:`~dropvision.synth.shapes` (axisymmetric bodies, exact volumes, drop formation model),
:mod:`~dropvision.synth.render` (supersampled silhouettes, optics, sensor),
:mod:`~dropvision.synth.sequence` (configuration, synthesis, truth),
:mod:`~dropvision.synth.writer` (sequence folder), :mod:`~dropvision.app.synth_cli`.

Realism tier (docs/SYNTH_REALISM.md): options of :class:`SynthConfig` (all off by default, so
a default render is bit-identical to the plain synthesizer) for rotated frames, a holder block,
vignetting, a clipped background, colour sensors and JPEG, optics that are not Gaussian (an Airy
pattern's rings, a defocus disc), mist and dust on the drop path, a
bead on the orifice, touching/dumbbell satellites, a tail with a bulb, a static pendant drop
and sequence.json without nozzle diameters; rig presets in :data:`RIGS`
(``SynthConfig.for_rig(name, **overrides)``); per-body truth in truth_bodies.csv.
"""

from dvcore.lazy import lazy_exports

# Imported on first use, so that `dropvision <command>` does not pay for scipy.interpolate etc.
# public name -> "module:attribute" (tests/project/test_layers.py reads this map)
_LAZY = {
    "DropHistory": "identify.physics:DropHistory",
    "SynthPhysics": "identify.physics:SynthPhysics",
    "drop_history": "identify.physics:drop_history",
    "FORMATS": "dropvision.synth.sequence:FORMATS",
    "TRUTH_COLUMNS": "dropvision.synth.sequence:TRUTH_COLUMNS",
    "FrameTruth": "dropvision.synth.sequence:FrameTruth",
    "SynthConfig": "dropvision.synth.sequence:SynthConfig",
    "parse_delays": "dropvision.synth.sequence:parse_delays",
    "plan": "dropvision.synth.sequence:plan",
    "sequence_truth": "dropvision.synth.sequence:sequence_truth",
    "synthesize": "dropvision.synth.sequence:synthesize",
    "DropShapeModel": "dropvision.synth.shapes:DropShapeModel",
    "ShapeParams": "dropvision.synth.shapes:ShapeParams",
    "write_synthetic_sequence": "dropvision.synth.writer:write_synthetic_sequence",
    # realism tier (docs/SYNTH_REALISM.md)
    "RIGS": "dropvision.synth.sequence:RIGS",
    "BODY_COLUMNS": "dropvision.synth.sequence:BODY_COLUMNS",
    "BODY_CLASSES": "dropvision.synth.sequence:BODY_CLASSES",
    "BodyTruth": "dropvision.synth.sequence:BodyTruth",
    "PendantShapeModel": "dropvision.synth.shapes:PendantShapeModel",
    "young_laplace_profile": "dropvision.synth.shapes:young_laplace_profile",
}
__all__ = list(_LAZY)
__getattr__, __dir__ = lazy_exports(__name__, globals(), _LAZY)
