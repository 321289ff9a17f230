"""dropvision: stroboscopic measurement of drop-on-demand drop formation.

The public API (loaded on first use, so ``import dropvision`` stays cheap)::

    import dropvision
    res = dropvision.measure("sample_frames/colour_ink_u70_u25")    # a sequence folder
    res.frames, res.summary                                          # DataFrame, dict
    res.annotate(0)                       # frame 0 as the camera took it, bodies outlined (matplotlib Axes)
    res = dropvision.measure(stack, delays_us=d, pixel_size_um=4.73) # frames in memory
    seq = dropvision.open_sequence(folder, pixel_size_um=3.0)        # validate, read lazily (measure's keywords)
    shots = dropvision.measure_shots("small_samples", overrides={"pixel_size_um": 3.0})  # .shots: a row per image
    dropvision.write_synthetic_sequence(dropvision.SynthConfig(u1_um_per_ms=70, u2_um=25), "synthetic_seq")
    dropvision.run_campaign("campaign_root", "dataset")              # many sequences -> dataset
    dropvision.init_sequence("watcher", {"pixel_size_um": 3.0})      # images alone -> sequence.json

Layers: `dvcore` (foundations) < `identify` (models, no images) < `dropvision` (measurement) <
`dropvision.app` / `identify.app` (command lines, campaigns, demo, Rerun views); this package's
namespace is the facade on top (``run_campaign`` comes from the application layer) and nothing in
the project imports it. See docs/ARCHITECTURE.md and tests/project/test_layers.py.
"""

from dvcore import __version__
from dvcore.lazy import lazy_exports

# public name -> "module:attribute" that defines it (tests/project/test_layers.py reads this map)
_LAZY = {
    "measure": "dropvision.api:measure",
    "MeasureConfig": "dropvision.config:MeasureConfig",
    "MeasureResult": "dropvision.measurement:MeasureResult",
    "measure_sequence": "dropvision.measurement:measure_sequence",
    "measure_shots": "dropvision.analysis.shots:measure_shots",
    "open_sequence": "dropvision.io.sequence:open_sequence",
    "sequence_from_arrays": "dropvision.io.sequence:sequence_from_arrays",
    "SequenceError": "dropvision.io.sequence:SequenceError",
    "SynthConfig": "dropvision.synth.sequence:SynthConfig",
    "write_synthetic_sequence": "dropvision.synth.writer:write_synthetic_sequence",
    "run_campaign": "dropvision.app.campaign:run_campaign",
    "describe_folder": "dropvision.io.describe:describe_folder",
    "init_sequence": "dropvision.io.describe:init_sequence",
}
__all__ = ["__version__", *_LAZY]
__getattr__, __dir__ = lazy_exports(__name__, globals(), _LAZY)
