"""Models of a campaign's shot table (issue 31 item 7: "the same from Python and from a dataset of our own
campaigns"): `identify fit DS --inputs V1,w1 --outputs drop_volume_nl --out model.json` on a
`dropvision campaign` dataset folder reads its shots.parquet (one row per image, the labels as columns),
as `identify.read_table(DS)` does for `identify.fit_table`.

The dataset is hand-made with the schema (dvcore.schema.DATASET_SHOTS, as `dropvision campaign` writes
it): 48 shots over a 6 x 8 grid of (V1, w1) labels, drop volumes from a known smooth law with scatter,
one shot unmeasured (NaN volume, quality not_measured).
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

import identify
from dvcore import schema
from identify.app.cli import main
from identify.tabular import TabularError, TabularModel


def _law(v1, w1):
    """The volume law of the hand-made shots (nl)."""
    return 20.0 + 0.12 * (v1 - 80.0) + 0.02 * (v1 - 80.0) ** 2 / 10.0 + 0.3 * (w1 - 20.0)


def _shots_table() -> pd.DataFrame:
    rng = np.random.default_rng(3)
    v1, w1 = np.meshgrid(np.arange(70.0, 96.0, 5.0), np.arange(14.0, 30.0, 2.0), indexing="ij")
    v1, w1 = v1.ravel(), w1.ravel()
    n = v1.size
    volume = _law(v1, w1) * (1.0 + 0.003 * rng.standard_normal(n))
    volume[7] = np.nan  # not measured
    dtypes = {"float": float, "str": object, "bool": bool}
    cols = {}
    for c in schema.DATASET_SHOTS.columns:
        if c.dtype == "int":
            cols[c.name] = pd.array([0] * n, dtype="Int64")
        else:
            cols[c.name] = pd.Series([np.nan] * n if c.dtype == "float" else
                                     ([True] * n if c.dtype == "bool" else [""] * n), dtype=dtypes[c.dtype])
    t = pd.DataFrame(cols)
    t["shot_folder"] = ["rig_a"] * 24 + ["rig_b"] * (n - 24)
    t["file"] = [f"images_V1-{a:g}_w1-{b:g}.png" for a, b in zip(v1, w1)]
    t["delay_us"] = 0.0
    t["drop_volume_nl"] = volume
    t["quality"] = ["ok"] * n
    t.loc[7, ["quality", "inflight"]] = [schema.Quality.NOT_MEASURED, False]
    t["V1"], t["w1"] = v1, w1
    return t


@pytest.fixture
def dataset(tmp_path):
    ds = tmp_path / "ds"
    ds.mkdir()
    table = _shots_table()
    schema.check_table(table, schema.DATASET_SHOTS, ds / "shots.parquet")
    table.to_parquet(ds / "shots.parquet", index=False)
    (ds / "dataset.json").write_text(json.dumps({"schema": schema.DATASET.schema, "nozzle_inner_diameter_um": None,
                                                 "sample_interval_us": None, "n_sequences": 0, "sequences": [],
                                                 "shot_folders": ["rig_a", "rig_b"], "n_shots": len(table)}))
    return ds


@pytest.mark.slow
def test_identify_fit_of_a_campaign_dataset_models_its_shot_rows(dataset, tmp_path, capsys):
    out = tmp_path / "model.json"
    assert main(["fit", str(dataset), "--inputs", "V1,w1", "--outputs", "drop_volume_nl", "--out", str(out),
                 "--folds", "3"]) == 0  # 3 folds: half the time of 5 (the candidates' cross-validation)
    assert f"48 rows of {dataset}" in capsys.readouterr().out
    m = TabularModel.from_json(out)
    assert m.inputs == ["V1", "w1"] and m.outputs == ["drop_volume_nl"]
    rows = pd.DataFrame({"V1": [72.5, 83.0, 91.0], "w1": [15.0, 21.0, 27.0]})
    p = m.predict(rows)
    truth = _law(rows["V1"].to_numpy(), rows["w1"].to_numpy())
    err = 100.0 * (p["drop_volume_nl_mean"].to_numpy() / truth - 1.0)
    assert np.all(np.isfinite(err)) and np.max(np.abs(err)) < 1.5, err
    assert np.all((p["drop_volume_nl_one_drop_low"] < truth) & (truth < p["drop_volume_nl_one_drop_high"]))
    assert not p["outside_training_region"].any()
    # the same from Python: identify.read_table of the folder is its shots.parquet
    table = identify.read_table(dataset)
    assert len(table) == 48 and list(table["V1"][:2]) == [70.0, 70.0]
    py = identify.fit_table(table, ["V1", "w1"], ["drop_volume_nl"], folds=3, source=str(dataset))
    assert np.allclose(py.predict(rows)["drop_volume_nl_mean"], p["drop_volume_nl_mean"], rtol=1e-9)


def test_a_folder_without_shot_table_is_one_line(dataset, tmp_path, capsys):
    (dataset / "shots.parquet").unlink()
    with pytest.raises(TabularError, match=r"ds: a folder: a table is a .csv or .parquet file, or a campaign dataset "
                                           r"folder holding shots.parquet"):
        identify.read_table(dataset)
    assert main(["fit", str(dataset), "--inputs", "V1", "--outputs", "drop_volume_nl",
                 "--out", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "holding shots.parquet" in err and not (tmp_path / "m.json").exists()
