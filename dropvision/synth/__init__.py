"""Physics-driven synthetic strobe sequences with exact ground truth (`dropvision synth`).

Modules: :mod:`~identify.physics` (waveform -> ECM -> pinch-off and adjusters; modelling
layer, no images),
:mod:`~dropvision.synth.shapes` (axisymmetric bodies, exact volumes, drop formation model),
:mod:`~dropvision.synth.render` (supersampled silhouettes, optics, sensor),
:mod:`~dropvision.synth.sequence` (configuration, synthesis, truth),
:mod:`~dropvision.synth.writer` (sequence folder), :mod:`~dropvision.app.synth_cli`.

Realism tier (docs/SYNTH_REALISM.md): options of :class:`SynthConfig` (all off by default, so
a default render is bit-identical to the plain synthesizer) for rotated frames, a holder block,
vignetting, a clipped background, colour sensors and JPEG, mist and dust on the drop path, a
bead on the orifice, touching/dumbbell satellites, a tail with a bulb, a static pendant drop
and sequence.json without nozzle diameters; rig presets in :data:`RIGS`
(``SynthConfig.for_rig(name, **overrides)``); per-body truth in truth_bodies.csv.
"""

import importlib

# Imported on first use, so that `dropvision <command>` does not pay for scipy.interpolate etc.
_WHERE = {
    "DropHistory": "physics", "SynthPhysics": "physics", "drop_history": "physics",
    "FORMATS": "sequence", "TRUTH_COLUMNS": "sequence", "FrameTruth": "sequence", "SynthConfig": "sequence",
    "parse_delays": "sequence", "plan": "sequence", "sequence_truth": "sequence", "synthesize": "sequence",
    "DropShapeModel": "shapes", "ShapeParams": "shapes", "write_synthetic_sequence": "writer",
    # realism tier (docs/SYNTH_REALISM.md)
    "RIGS": "sequence", "BODY_COLUMNS": "sequence", "BODY_CLASSES": "sequence", "BodyTruth": "sequence",
    "PendantShapeModel": "shapes", "young_laplace_profile": "shapes",
}
__all__ = list(_WHERE)


def __getattr__(name):
    if name in _WHERE:
        module = "identify.physics" if _WHERE[name] == "physics" else f"dropvision.synth.{_WHERE[name]}"
        return getattr(importlib.import_module(module), name)
    raise AttributeError(f"module 'dropvision.synth' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + __all__)
