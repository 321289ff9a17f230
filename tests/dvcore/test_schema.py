"""One schema: every written table and document matches its declaration, loading checks it,
and docs/FORMAT.md documents the outputs from it."""

import json
from pathlib import Path

import pandas as pd
import pytest

from dropvision.measurement import measure_sequence
from dvcore import schema
from identify.dataset import DatasetError
from identify.dataset_checks import load_dataset
from identify.synthetic_dataset import make_synthetic_dataset

ROOT = Path(__file__).resolve().parents[2]


def test_format_md_is_generated_from_the_schema():
    text = (ROOT / "docs" / "FORMAT.md").read_text(encoding="utf-8")
    assert text.rstrip().endswith(schema.markdown().rstrip()), "run the generator named in docs/FORMAT.md"


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    out = tmp_path_factory.mktemp("schema") / "out"
    measure_sequence(ROOT / "sample_frames" / "u55_u30", out)
    return out


def test_measurement_outputs_match_their_declarations(measured):
    frames = pd.read_parquet(measured / "frames.parquet")
    assert list(frames.columns) == schema.FRAMES.column_names
    schema.check_table(frames, schema.FRAMES, measured / "frames.parquet")
    per_delay = pd.read_parquet(measured / "per_delay.parquet")
    assert list(per_delay.columns) == schema.PER_DELAY.column_names
    summary = json.loads((measured / "summary.json").read_text())
    assert sorted(summary) == sorted(schema.SUMMARY.key_names)
    schema.check_document(summary, schema.SUMMARY, measured / "summary.json")
    marker = json.loads((measured / schema.OUTPUT_MARKER.file).read_text())
    schema.check_document(marker, schema.OUTPUT_MARKER, "marker")


def test_mismatches_name_the_file_and_the_column(measured):
    frames = pd.read_parquet(measured / "frames.parquet")
    with pytest.raises(schema.SchemaError, match=r"frames.parquet: missing column 'grown_volume_nl'"):
        schema.check_table(frames.drop(columns="grown_volume_nl"), "frames", measured / "frames.parquet")
    bad = frames.assign(delay_us=frames["delay_us"].astype(str))
    with pytest.raises(schema.SchemaError, match=r"column 'delay_us' has dtype \w+, expected float \(us\)"):
        schema.check_table(bad, "frames", "frames.parquet")
    with pytest.raises(schema.SchemaError, match="missing values"):
        schema.check_table(frames.assign(delay_us=float("nan")), "frames", "frames.parquet")
    with pytest.raises(schema.SchemaError, match=r"x/summary.json: schema 'other/2' is not 'dropvision.measure/1'"):
        schema.check_document({"schema_version": "other/2"}, "summary", "x/summary.json")


def test_dataset_and_model_documents(tmp_path):
    ds = make_synthetic_dataset(tmp_path / "ds", grid=[(55, 20), (65, 27.5), (75, 35), (60, 30)])
    schema.check_table(ds.timeseries, schema.TIMESERIES, "timeseries")
    schema.check_table(ds.summary, schema.DATASET_SUMMARY, "summary")
    meta = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    assert meta["schema"] == schema.DATASET.schema
    meta["schema"] = "someone.else/3"
    (tmp_path / "ds" / "dataset.json").write_text(json.dumps(meta))
    with pytest.raises(DatasetError, match=r"dataset.json: schema 'someone.else/3' is not 'dropvision.dataset/1'"):
        load_dataset(tmp_path / "ds")
    meta["schema"] = "identify.dataset/1"  # written by earlier versions: still read
    (tmp_path / "ds" / "dataset.json").write_text(json.dumps(meta))
    assert load_dataset(tmp_path / "ds").nozzle_inner_diameter_um == meta["nozzle_inner_diameter_um"]


def test_every_quality_flag_is_explained():
    from dropvision import quality

    flags = {v for k, v in vars(quality).items() if k.isupper() and isinstance(v, str)}
    assert flags <= set(schema.QUALITY_CODES)
