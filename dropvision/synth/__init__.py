"""Physics-driven synthetic strobe sequences with exact ground truth (`dropvision synth`).

Modules: :mod:`~identify.physics` (waveform -> ECM -> pinch-off and adjusters; modelling
layer, no images),
:mod:`~dropvision.synth.shapes` (axisymmetric bodies, exact volumes, drop formation model),
:mod:`~dropvision.synth.render` (supersampled silhouettes, optics, sensor),
:mod:`~dropvision.synth.sequence` (configuration, synthesis, truth),
:mod:`~dropvision.synth.writer` (sequence folder), :mod:`~dropvision.app.synth_cli`.
"""

import importlib

# Imported on first use, so that `dropvision <command>` does not pay for scipy.interpolate etc.
_WHERE = {
    "DropHistory": "physics", "SynthPhysics": "physics", "drop_history": "physics",
    "FORMATS": "sequence", "TRUTH_COLUMNS": "sequence", "FrameTruth": "sequence", "SynthConfig": "sequence",
    "parse_delays": "sequence", "plan": "sequence", "sequence_truth": "sequence", "synthesize": "sequence",
    "DropShapeModel": "shapes", "ShapeParams": "shapes", "write_synthetic_sequence": "writer",
}
__all__ = list(_WHERE)


def __getattr__(name):
    if name in _WHERE:
        module = "identify.physics" if _WHERE[name] == "physics" else f"dropvision.synth.{_WHERE[name]}"
        return getattr(importlib.import_module(module), name)
    raise AttributeError(f"module 'dropvision.synth' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + __all__)
