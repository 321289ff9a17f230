"""Our own JSON documents (dataset.json, tuning.json, the campaign manifest and its shards'
summary.json) are read with the hardened reader (`dvcore.jsonio.load_json_hardened`): NaN,
Infinity, an over-long integer or deep nesting is one error naming the file, as for sequence.json.
What our writers write (`dvcore.atomic.write_json`: NaN as null) is read back unchanged.
"""

from __future__ import annotations

import json
import shutil

import pytest

from dropvision.app.campaign import MANIFEST_SCHEMA, _load_manifest
from identify.dataset import DatasetError
from identify.dataset_checks import load_dataset
from identify.synthetic_dataset import make_synthetic_dataset

HOSTILE = {
    "nan": ('{"schema": %s, "x": NaN}', r"invalid JSON \(NaN is not a JSON number"),
    "infinity": ('{"schema": %s, "x": -Infinity}', r"invalid JSON \(-Infinity is not a JSON number"),
    "long_int": ('{"schema": %s, "x": ' + "9" * 5000 + "}", r"invalid JSON \(integer of 5000 digits"),
    "deep": ('{"schema": %s, "x": ' + "[" * 100 + "]" * 100 + "}", r"invalid JSON \(nested more than 64 levels"),
}


@pytest.fixture(scope="module")
def ds_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("ds") / "ds"
    make_synthetic_dataset(d, grid=[(u1, u2) for u1 in (50.0, 65.0, 80.0) for u2 in (20.0, 27.5, 35.0)],
                           noise_percent=0.0, seed=0)
    return d


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_dataset_json_hostile_literals_are_refused_naming_the_file(ds_dir, tmp_path, case):
    bad = tmp_path / "bad"
    shutil.copytree(ds_dir, bad)
    schema_id = json.loads((ds_dir / "dataset.json").read_text())["schema"]
    text, match = HOSTILE[case]
    (bad / "dataset.json").write_text(text % json.dumps(schema_id))
    with pytest.raises(DatasetError, match=r"bad[/\\]dataset\.json: " + match):
        load_dataset(bad)


def test_dataset_json_written_by_us_reads_back(ds_dir):
    assert load_dataset(ds_dir).n_sequences == 9


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_manifest_hostile_literals_are_refused_naming_the_file(tmp_path, case):
    text, match = HOSTILE[case]
    path = tmp_path / "manifest.json"
    path.write_text(text % json.dumps(MANIFEST_SCHEMA))
    with pytest.raises(ValueError, match=r"manifest\.json: " + match + r".*remove it to start afresh"):
        _load_manifest(path)


def test_manifest_of_another_program_is_refused(tmp_path):
    path = tmp_path / "manifest.json"
    path.write_text('{"schema": "other/1", "sequences": {}}')
    with pytest.raises(ValueError, match=r"manifest\.json: not a dropvision campaign manifest \(schema 'other/1'\)"):
        _load_manifest(path)
    path.write_text("[1, 2]")
    with pytest.raises(ValueError, match=r"manifest\.json: must hold a JSON object, got list"):
        _load_manifest(path)
