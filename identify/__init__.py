"""identify: ARX, equivalent-circuit and hybrid models of drop formation (Wang & Chiu).

The public API (loaded on first use, so ``import identify`` stays cheap)::

    import identify
    ds = identify.load_dataset("out/dataset")          # a campaign dataset folder
    model = identify.fit(ds)                           # HybridModel (structure selection, ECM, Eq. 8)
    model.predict(u1=70, u2=25)                        # {"inflight_volume_nl": ..., ...}
    model.design(volume_nl=18.9)                       # (u1, u2) for a target volume
    model.save("model.json"); identify.load_model("model.json")
    identify.tune(model, rig, volume_nl=20)            # closed loop on a rig (identify.tuning)
"""

import importlib

__version__ = "0.1.0"

# public name -> module that defines it
_WHERE = {
    "load_dataset": "identify.dataset_checks",
    "Dataset": "identify.dataset",
    "DatasetError": "identify.dataset",
    "fit": "identify.api",
    "load_model": "identify.api",
    "fit_hybrid": "identify.hybrid_fit",
    "HybridModel": "identify.hybrid",
    "FitReport": "identify.hybrid_fit",
    "Waveform": "identify.waveform",
    "paper_prediction": "identify.paper",
    "tune": "identify.tuning",
    "read_tuning": "identify.tuning",
    "CallableRig": "identify.tuning",
}
__all__ = ["__version__", *_WHERE]


def __getattr__(name):
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'identify' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_WHERE))
