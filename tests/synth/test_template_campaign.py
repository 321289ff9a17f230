"""A campaign of waveform-template sequences end to end through the command lines (issue 31):
`dropvision campaign` of synthetic three-pulse sequences records each sequence's template and
parameters in the dataset (dvcore.schema: the parameters in place of u1/u2, dataset.json
``waveform`` and ``waveform_parameters``), and `identify fit DATASET` fits the hybrid model on the
template from it, recovering the synthesizer's ECM within the bound of
tests/identify/test_template_identification.py (3 %; La is not fixed at the truth here but at
identify.ecm_fit.LA_DEFAULT, 0.25 % from it, as a user's fit is).

The campaign is the small one of tools/template_identification.py (6 training settings of V1, w1, V2;
160 x 400 px frames every 10 us), rendered by dropvision.synth.template_campaign.
"""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from dropvision.app.cli import main as dropvision_main
from dvcore import schema
from identify.app.cli import main as identify_main
from identify.dataset import DatasetError
from identify.dataset_checks import load_dataset
from identify.template_fit import TemplateModel

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow  # a small campaign rendered and measured (~20 s), as test_template_identification


def _tool():
    spec = importlib.util.spec_from_file_location("template_identification", ROOT / "tools" / "template_identification.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """(campaign root, its dataset folder, the base config, the training settings): rendered and
    measured once by `dropvision campaign`."""
    from dropvision.synth.template_campaign import render_campaign

    base, train, _, template = _tool().three_pulse_case(small=True)
    tmp = tmp_path_factory.mktemp("tplcampaign")
    root = tmp / "root"
    render_campaign(base, train, root, template=template)
    ds = tmp / "ds"
    assert dropvision_main(["campaign", str(root), "--out", str(ds), "--workers", "1", "-q"]) == 0
    return root, ds, base, train


def test_the_dataset_records_the_template_and_its_parameters(campaign):
    root, ds, _, train = campaign
    meta = json.loads((ds / "dataset.json").read_text())
    schema.check_document(meta, schema.DATASET, ds / "dataset.json")
    assert meta["waveform"] == {"template": "three_pulse", "edge_us": 2.0}
    assert meta["waveform_parameters"] == {"V1": "V", "V2": "V", "V3": "V", "w1": "us", "w2": "us", "w3": "us",
                                           "d1": "us", "d2": "us"}
    assert "u3_um_per_ms" not in meta and "hold_us" not in meta and meta["failed"] == {}
    assert meta["n_sequences"] == len(train) and meta["dead_time_us"] == 220.0
    names = list(meta["waveform_parameters"])
    su = pd.read_parquet(ds / "summary.parquet")
    ts = pd.read_parquet(ds / "timeseries.parquet")
    schema.check_table(su, schema.DATASET_SUMMARY, ds / "summary.parquet")
    schema.check_table(ts, schema.TIMESERIES, ds / "timeseries.parquet")
    assert list(su.columns[:9]) == ["sequence_id", *names] and "u1_um_per_ms" not in su.columns
    assert list(ts.columns) == ["sequence_id", *names, "delay_us", "grown_volume_nl", "flow_velocity_m_s", "attached"]
    # each sequence's parameters, as its sequence.json gives them
    for _, row in su.iterrows():
        given = json.loads((root / row["sequence_id"] / "sequence.json").read_text())["waveform"]["parameters"]
        assert {k: row[k] for k in names} == pytest.approx(given)
        assert (ts.loc[ts["sequence_id"] == row["sequence_id"], "V1"] == given["V1"]).all()
    assert sorted(map(tuple, su[["V1", "w1", "V2"]].to_numpy())) == sorted((s["V1"], s["w1"], s["V2"]) for s in train)
    assert np.isfinite(su["inflight_volume_nl"]).all() and su["flow_velocity_at_max_stroke_m_s"].isna().all()
    # the (u1, u2) reader says what the folder is instead of a missing column
    with pytest.raises(DatasetError, match=r"dataset.json: a dataset of the waveform template 'three_pulse'"):
        load_dataset(ds)


def test_identify_fit_of_the_campaign_recovers_the_ecm(campaign, tmp_path, capsys):
    _, ds, base, train = campaign
    out = tmp_path / "model.json"
    assert identify_main(["fit", str(ds), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "waveform template three_pulse: V1 (V)" in text and f"wrote {out}" in text
    m = TemplateModel.from_json(out)
    assert m.inputs == ("V1", "V2", "w1") and m.ecm["level"] == "physical"
    true = base.physics.ecm_parameters()
    for k in ("Ra", "CN", "Kc"):
        est = m.ecm["parameters"][k]["value"]
        assert abs(est / getattr(true, k) - 1.0) < 0.03, (k, est, getattr(true, k))
    assert 0 < m.ecm["rmse_nl"] < 0.02
    # the model predicts its training settings as the Python API's fit of the same data does
    p = m.predict({k: train[0][k] for k in ("V1", "V2", "w1")})
    assert p["outside_training_region"] == [] and np.isfinite(p["inflight_volume_nl"])
    # refitting over it is allowed (ours); options of the (u1, u2) model are refused in one line
    assert identify_main(["fit", str(ds), "--out", str(out)]) == 0
    capsys.readouterr()
    assert identify_main(["fit", str(ds), "--out", str(out), "--folds", "4"]) == 2
    assert "--folds not available" in capsys.readouterr().err
    # the (u1, u2) commands say what the file is and where it is read
    assert identify_main(["predict", str(out), "--u1", "70", "--u2", "25"]) == 2
    assert "a model on a waveform template (identify.template-model/1)" in capsys.readouterr().err


def test_a_campaign_mixing_templates_is_refused(campaign, tmp_path, capsys):
    root, _, _, _ = campaign
    mixed = tmp_path / "mixed"
    shutil.copytree(root / "seq_000", mixed / "a")
    shutil.copytree(root / "seq_001", mixed / "b")
    doc = json.loads((mixed / "b" / "sequence.json").read_text())
    doc["waveform"] = {"u1_um_per_ms": 70.0, "u2_um": 25.0}
    (mixed / "b" / "sequence.json").write_text(json.dumps(doc))
    assert dropvision_main(["campaign", str(mixed), "--out", str(tmp_path / "ds"), "--workers", "1", "-q"]) == 2
    err = capsys.readouterr().err
    assert "sequences disagree on waveform template" in err and "one waveform template" in err
    # a sequence of a template without its parameters (only shots' labels may give them): left out, saying why
    doc["waveform"] = {"template": "three_pulse"}
    (mixed / "b" / "sequence.json").write_text(json.dumps(doc))
    assert dropvision_main(["campaign", str(mixed), "--out", str(tmp_path / "ds"), "--workers", "1"]) == 0
    out = capsys.readouterr().out
    assert "1 failed" in out and "failed b: sequence.json waveform template 'three_pulse' has no parameters" in out
    assert json.loads((tmp_path / "ds" / "dataset.json").read_text())["sequences"] == ["a"]
