"""`identify predict` of a model on a waveform template (issue 31): a table of settings (`--table`,
`--out`) and one setting (`--set NAME=VALUE`), each with the outside_training_region flag.

The model is fitted noise free on the synthetic three-pulse head (as tests/identify/test_waveform_template.py);
the command lines' numbers are pinned to the Python API's `TemplateModel.predict` and to the head's
own truth (`identify.physics.drive_history`).
"""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest

from dvcore import schema
from identify.app.cli import main
from identify.physics import THREE_PULSE_CENTRE, THREE_PULSE_LAWS, SynthPhysics, drive_history
from identify.template_fit import PREDICTION_COLUMNS, TemplateModel, fit_template_model
from identify.waveform import Drive, ThreePulseTemplate


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    ph = SynthPhysics()
    c = THREE_PULSE_CENTRE
    train = [{**c, "V1": a, "w1": b} for a in (26.0, 34.0) for b in (180.0, 220.0)] + [dict(c)]
    rows, series = [], []
    t = np.arange(0.0, 1000.0, 10.0)
    for i, v in enumerate(train):
        h = drive_history(ph, Drive(ThreePulseTemplate(), v, ph.dead_time_us), THREE_PULSE_LAWS)
        att = t < np.ceil(h.pinchoff_instant_us / 10.0) * 10.0
        series.append(pd.DataFrame({"sequence_id": f"s{i}", "delay_us": t, "attached": att,
                                    "grown_volume_nl": np.where(att, h.grown_volume_nl_at(t), np.nan)}))
        rows.append({"sequence_id": f"s{i}", **v, "pinchoff_us": h.pinchoff_instant_us,
                     "inflight_volume_nl": h.inflight_volume_nl, "jetting_velocity_m_s": h.jetting_velocity_m_s})
    true = ph.ecm_parameters()
    m = fit_template_model({"template": "three_pulse", "edge_us": 2.0}, pd.DataFrame(rows),
                           pd.concat(series, ignore_index=True), dead_time_us=220.0,
                           nozzle_inner_diameter_um=ph.nozzle_inner_diameter_um,
                           hydraulics=(true.LN, true.RN, true.LR, true.RR), la=true.La)
    path = tmp_path_factory.mktemp("tpl") / "model.json"
    m.save(path)
    return path, ph


def _truth(ph, values):
    return drive_history(ph, Drive(ThreePulseTemplate(), {**THREE_PULSE_CENTRE, **values}, 220.0), THREE_PULSE_LAWS)


@pytest.mark.slow
def test_predict_a_table_of_settings(model_file, tmp_path, capsys):
    path, ph = model_file
    m = TemplateModel.from_json(path)
    assert m.inputs == ("V1", "w1")
    rows = pd.DataFrame({"label": ["a", "b", "c"], "V1": [31.0, 28.0, 40.0], "w1": [205.0, 190.0, 200.0],
                         "V2": [THREE_PULSE_CENTRE["V2"]] * 3})  # a fixed parameter's column at its value: accepted
    rows.to_csv(tmp_path / "rows.csv", index=False)
    out = tmp_path / "pred.csv"
    assert main(["predict", str(path), "--table", str(tmp_path / "rows.csv"), "--out", str(out)]) == 0
    text = capsys.readouterr()
    assert f"wrote {out}: 3 rows, 1 outside the training region" in text.out and "1 row(s) outside" in text.err
    got = pd.read_csv(out, keep_default_na=False)
    assert list(got.columns) == ["label", "V1", "w1", "V2", *PREDICTION_COLUMNS]
    assert list(got["label"]) == ["a", "b", "c"]
    for i, r in rows.iterrows():
        want = m.predict({"V1": r.V1, "w1": r.w1})
        for k in PREDICTION_COLUMNS[:-2]:
            assert got.loc[i, k] == pytest.approx(want[k], rel=1e-12)
    # pinned to the head's truth inside the region (noise free: the laws are the model's)
    truth = _truth(ph, {"V1": 31.0, "w1": 205.0})
    assert got.loc[0, "inflight_volume_nl"] == pytest.approx(truth.inflight_volume_nl, rel=2e-3)
    assert got.loc[0, "jetting_velocity_m_s"] == pytest.approx(truth.jetting_velocity_m_s, rel=2e-3)
    assert list(got["outside_training_region"].astype(str)) == ["False", "False", "True"]
    assert got.loc[2, "outside_training_region_why"] == "V1=40 > 34 (max seen)"
    assert got.loc[0, "outside_training_region_why"] == ""
    # Parquet by the suffix; replacing our own prediction table is allowed
    assert main(["predict", str(path), "--table", str(tmp_path / "rows.csv"), "--out", str(tmp_path / "p.parquet")]) == 0
    pq = pd.read_parquet(tmp_path / "p.parquet")
    assert pq["outside_training_region"].dtype == bool and list(pq["outside_training_region"]) == [False, False, True]
    assert main(["predict", str(path), "--table", str(tmp_path / "rows.csv"), "--out", str(out)]) == 0
    capsys.readouterr()
    assert set(PREDICTION_COLUMNS) <= {c.name for c in schema.TEMPLATE_PREDICTION.columns}


@pytest.mark.parametrize("rows, message", [
    ({"V1": [31.0]}, r"rows.csv: no column 'w1' \(the model's parameters: V1, w1; fixed, may be left out: .*V2"),
    ({"V1": [31.0, 30.0], "w1": [205.0, np.nan]}, r"rows.csv: row 2: parameter w1 is missing or not finite"),
    ({"V1": [31.0], "w1": [205.0], "V2": [12.0]}, r"rows.csv: row 1: V2 = 12 differs from the value 10"),
    ({"V1": ["x"], "w1": [205.0]}, r"rows.csv: parameter column 'V1' is not numeric"),
    ({"V1": [31.0], "w1": [-5.0]}, r"rows.csv: row 1: .*parameter w1 = -5.0 us is outside the accepted range"),
])
def test_a_bad_table_is_refused_in_one_line_and_nothing_written(model_file, tmp_path, capsys, rows, message):
    path, _ = model_file
    pd.DataFrame(rows).to_csv(tmp_path / "rows.csv", index=False)
    out = tmp_path / "pred.csv"
    assert main(["predict", str(path), "--table", str(tmp_path / "rows.csv"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and re.search(message, err), err
    assert not out.exists()


def test_a_file_that_is_not_ours_is_not_overwritten(model_file, tmp_path, capsys):
    path, _ = model_file
    pd.DataFrame({"V1": [31.0], "w1": [205.0]}).to_csv(tmp_path / "rows.csv", index=False)
    mine = tmp_path / "mine.csv"
    mine.write_text("a,b\n1,2\n")
    assert main(["predict", str(path), "--table", str(tmp_path / "rows.csv"), "--out", str(mine)]) == 2
    assert mine.read_text() == "a,b\n1,2\n"
    assert main(["predict", str(path), "--table", str(tmp_path / "rows.csv")]) == 2
    assert "--table needs --out" in capsys.readouterr().err


def test_predict_one_setting(model_file, capsys):
    path, ph = model_file
    m = TemplateModel.from_json(path)
    assert main(["predict", str(path), "--set", "V1=31", "--set", "w1=205", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["schema"] == schema.TEMPLATE_SETTING_PREDICTION.schema
    assert set(doc) == {k.name for k in schema.TEMPLATE_SETTING_PREDICTION.keys}
    want = m.predict({"V1": 31.0, "w1": 205.0})
    for k in PREDICTION_COLUMNS[:-2]:
        assert doc[k] == pytest.approx(want[k], rel=1e-12)
    assert doc["inflight_volume_nl"] == pytest.approx(_truth(ph, {"V1": 31.0, "w1": 205.0}).inflight_volume_nl, rel=2e-3)
    assert doc["settings"] == {**THREE_PULSE_CENTRE, "V1": 31.0, "w1": 205.0}
    assert doc["outside_training_region"] is False and doc["outside_training_region_why"] == ""
    # text form, outside the region: flagged, with a warning
    assert main(["predict", str(path), "--set", "V1=31", "--set", "w1=150"]) == 0
    text = capsys.readouterr()
    assert "waveform template three_pulse: V1 = 31 V" in text.out
    assert "inflight_volume_nl" in text.out and "yes: w1=150 < 180 (min seen)" in text.out
    assert "warning: outside the training region (w1=150 < 180 (min seen))" in text.err


@pytest.mark.parametrize("argv, message", [
    (["--set", "V1=31"], r"model.json: --set w1=VALUE missing \(the model's parameters: V1, w1; fixed"),
    (["--set", "V1=31", "--set", "w1=205", "--set", "Vx=3"], r"--set Vx: not a parameter of the template three_pulse"),
    (["--set", "V1"], r"--set must be NAME=VALUE"),
    (["--set", "V1=abc", "--set", "w1=205"], r"--set V1: the value must be a number"),
    (["--set", "V1=31", "--set", "V1=32"], r"--set V1 given twice"),
    (["--set", "V1=31", "--set", "w1=205", "--out", "x.csv"], r"--out is for --table"),
    (["--set", "V1=31", "--set", "w1=205", "--level", "0.9"], r"--level not available"),
    (["--u1", "70", "--u2", "25"], r"a model on a waveform template \(identify.template-model/1\): --u1/--u2 not"),
    ([], r"give its parameters with --set NAME=VALUE \(repeatable: V1, w1\) or --table"),
    (["--set", "V1=31", "--table", "rows.csv"], r"--set and --table exclude each other"),
])
def test_bad_settings_are_refused_in_one_line(model_file, capsys, argv, message):
    path, _ = model_file
    assert main(["predict", str(path), *argv]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and re.search(message, err), err


def test_the_other_commands_say_how_to_predict_a_template_model(model_file, capsys):
    path, _ = model_file
    assert main(["design", str(path), "--volume-nl", "30"]) == 2
    err = capsys.readouterr().err
    assert "a model on a waveform template (identify.template-model/1)" in err and "--set NAME=VALUE" in err


def test_predict_reads_the_ecm_once_and_equals_it_at_each_instant(model_file):
    """`TemplateModel.predict` evaluates the ECM once at both instants; its numbers are those of
    `ecm_response` at the pinch-off instant and at the velocity instant, each alone."""
    path, _ = model_file
    m = TemplateModel.from_json(path)
    values = {**THREE_PULSE_CENTRE, "V1": 31.0, "w1": 205.0}
    p = m.predict(values)
    d = m.drive(values)
    vol, _ = m.ecm_response(d, [p["pinchoff_us"]])
    _, vel = m.ecm_response(d, [d.velocity_instant_us])
    assert np.isfinite(vol[0]) and vel[0] > 0
    assert p["grown_volume_at_pinchoff_nl"] == float(vol[0])
    assert p["flow_velocity_at_velocity_instant_m_s"] == float(vel[0])


@pytest.mark.parametrize("edit, key", [
    (lambda d: d["ecm"]["coefficients"].__setitem__("A0", -abs(d["ecm"]["coefficients"]["A0"])),
     "ecm.coefficients describe no stable third-order system"),
    (lambda d: d.__setitem__("nozzle_inner_diameter_um", 1e9), "nozzle_inner_diameter_um must be at most"),
    (lambda d: d.__setitem__("dead_time_us", -1.0), "dead_time_us must be >= 0"),
])
def test_a_template_model_gets_the_checks_of_a_model_file(model_file, tmp_path, edit, key):
    """The checks `identify.model_file` applies to a (u1, u2) model (ranges, a stable ECM by
    Routh-Hurwitz) apply to a template model: one line naming the file and the key."""
    path, _ = model_file
    d = json.loads(path.read_text(encoding="utf-8"))
    TemplateModel.from_dict(d, source="ok.json")  # unedited: accepted
    edit(d)
    with pytest.raises(ValueError) as info:
        TemplateModel.from_dict(d, source="edited.json")
    msg = str(info.value)
    assert msg.startswith("edited.json: ") and key in msg and "\n" not in msg, msg


def test_one_function_tells_the_kind_of_a_model_file(model_file, tmp_path):
    """`identify.model_file.model_schema`: the schema id of each model identify writes, None for
    anything else; a file too large to parse is told by its head (identify writes ``schema`` first)."""
    from identify.model_file import model_schema

    path, _ = model_file
    assert model_schema(path) == schema.TEMPLATE_MODEL.schema
    big = tmp_path / "big.json"
    big.write_text('{"schema": "%s", "pad": "%s"}' % (schema.TABULAR_MODEL.schema, "x" * (1 << 21)), encoding="utf-8")
    assert model_schema(big) == schema.TABULAR_MODEL.schema
    hybrid = tmp_path / "hybrid.json"
    hybrid.write_text(json.dumps({"schema": schema.MODEL.schema}), encoding="utf-8")
    assert model_schema(hybrid) == schema.MODEL.schema
    for name, text in (("other.json", '{"schema": "dropvision.sequence/1"}'), ("list.json", "[1, 2]"),
                       ("notes.txt", "not json \xff")):
        (tmp_path / name).write_text(text, encoding="utf-8")
        assert model_schema(tmp_path / name) is None, name
    assert model_schema(tmp_path / "missing.json") is None
