"""dvcore: the foundations dropvision and identify both stand on (no images, no models).

Modules: :mod:`~dvcore.schema` (every table and document written, the input ranges, the quality
codes), :mod:`~dvcore.atomic` (atomic, non-destructive writes), :mod:`~dvcore.versions`
(software versions of a result), :mod:`~dvcore.jsonio` (hardened JSON reading),
:mod:`~dvcore.errors` (the command lines' error boundary), :mod:`~dvcore.rerun_options`
(where a Rerun recording goes; no rerun import), :mod:`~dvcore.lazy` (lazily loaded public names),
:mod:`~dvcore.waveform` (a printhead's drive: the paper's trapezoid, the waveform templates, the
nozzle's flow formulas; re-exported by :mod:`identify.waveform` and :mod:`identify.ecm`).

Layers (docs/ARCHITECTURE.md, enforced by tests/project/test_layers.py): ``dvcore`` < ``identify`` <
``dropvision`` < ``dropvision.app`` / ``identify.app``. Nothing here imports a layer above.
"""

#: Version of the dropvision distribution (dropvision, identify and dvcore ship together).
__version__ = "0.1.0"
