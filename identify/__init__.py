"""identify: ARX, equivalent-circuit and hybrid models of drop formation (Wang & Chiu).

The public API (loaded on first use, so ``import identify`` stays cheap)::

    import identify
    ds = identify.load_dataset("out/dataset")          # a campaign dataset folder
    model = identify.fit(ds)                           # HybridModel (structure selection, ECM, Eq. 8)
    model.predict(u1=70, u2=25)                        # {"inflight_volume_nl": ..., ...}
    model.design(volume_nl=18.9)                       # (u1, u2) for a target volume
    model.save("model.json"); identify.load_model("model.json")
    identify.tune(model, rig, volume_nl=20)            # closed loop on a rig (identify.tuning)

    # any drive with time series: a waveform template in the lab's parameters (identify.template_fit)
    tpm = identify.fit_template_model(identify.ThreePulseTemplate(), table, timeseries, dead_time_us=220,
                                      nozzle_inner_diameter_um=200)
    tpm.predict({"V1": 30, "w1": 200, ...}); tpm.save("model.json")

    table = identify.read_table("sweep.csv")           # a table of settings and end-point measurements
    tm = identify.fit_table(table, ["V3", "w1"], ["head_volume_px3", "n_drops"])  # identify.tabular
    tm.predict(rows); tm.save("model.json"); identify.TabularModel.from_json("model.json")
"""

from dvcore import __version__
from dvcore.lazy import lazy_exports

# public name -> "module:attribute" that defines it (tests/project/test_layers.py reads this map)
_LAZY = {
    "load_dataset": "identify.dataset_checks:load_dataset",
    "Dataset": "identify.dataset:Dataset",
    "DatasetError": "identify.dataset:DatasetError",
    "fit": "identify.api:fit",
    "load_model": "identify.api:load_model",
    "fit_hybrid": "identify.hybrid_fit:fit_hybrid",
    "HybridModel": "identify.hybrid:HybridModel",
    "FitReport": "identify.hybrid_fit:FitReport",
    "Waveform": "dvcore.waveform:Waveform",
    "ThreePulseTemplate": "dvcore.waveform:ThreePulseTemplate",
    "TrapezoidTemplate": "dvcore.waveform:TrapezoidTemplate",
    "Drive": "dvcore.waveform:Drive",
    "fit_template_model": "identify.template_fit:fit_template_model",
    "TemplateModel": "identify.template_fit:TemplateModel",
    "paper_prediction": "identify.paper:paper_prediction",
    "tune": "identify.tuning:tune",
    "read_tuning": "identify.tuning:read_tuning",
    "CallableRig": "identify.tuning:CallableRig",
    "fit_table": "identify.tabular:fit_table",
    "read_table": "identify.tabular:read_table",
    "TabularModel": "identify.tabular:TabularModel",
}
__all__ = ["__version__", *_LAZY]
__getattr__, __dir__ = lazy_exports(__name__, globals(), _LAZY)
