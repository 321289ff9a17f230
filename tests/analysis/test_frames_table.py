"""frames.parquet is checked against its schema (dvcore.schema.FRAMES) when written.

A column missing from the table, one not declared, one out of order or of the wrong dtype is a
`SchemaError` naming it, and nothing is written (it used to become an all-None column silently).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from dropvision.output.result_writer import write_result
from dropvision.analysis.sequence_summary import FRAME_COLUMNS, check_frames_table
from dvcore import schema

_VALUES = {"float": lambda n: np.linspace(0.0, 1.0, n), "int": lambda n: np.arange(n),
           "bool": lambda n: np.zeros(n, bool), "str": lambda n: ["ok"] * n}


def _frames(n: int = 3) -> pd.DataFrame:
    """A valid frames table of ``n`` rows, one value kind per declared dtype."""
    cols = {c.name: _VALUES[c.dtype](n) for c in schema.FRAMES.columns}
    cols["page"] = pd.array([None] * n, dtype="Int64")
    cols["n_satellites"] = pd.array([0, None, 2][:n], dtype="Int64")
    return pd.DataFrame(cols, columns=FRAME_COLUMNS)


def _write(frames, tmp_path):
    result = SimpleNamespace(frames=frames, bodies=None, summary={"schema": schema.SUMMARY.schema})
    write_result(result, tmp_path / "out")


def test_valid_table_is_written(tmp_path):
    _write(_frames(), tmp_path)
    back = pd.read_parquet(tmp_path / "out" / "frames.parquet")
    assert list(back.columns) == FRAME_COLUMNS
    schema.check_table(back, schema.FRAMES, "frames.parquet read back")


def test_missing_column_is_named_and_nothing_written(tmp_path):
    frames = _frames().drop(columns=["grown_volume_nl"])
    with pytest.raises(schema.SchemaError, match=r"frames\.parquet: missing column 'grown_volume_nl'"):
        _write(frames, tmp_path)
    assert not (tmp_path / "out").exists()


def test_undeclared_column_is_named(tmp_path):
    frames = _frames().assign(grown_volume_ul=1.0)
    with pytest.raises(schema.SchemaError, match=r"column 'grown_volume_ul' is not declared"):
        _write(frames, tmp_path)


def test_wrong_dtype_is_named(tmp_path):
    frames = _frames()
    frames["drop_volume_nl"] = ["1.0"] * len(frames)  # numbers written as text
    with pytest.raises(schema.SchemaError, match=r"column 'drop_volume_nl' has dtype \w+, expected float"):
        _write(frames, tmp_path)


def test_order_checked_and_infinite_values_refused():
    frames = _frames()
    with pytest.raises(schema.SchemaError, match="order"):
        check_frames_table(frames[FRAME_COLUMNS[::-1]], "reordered")
    # the writer checks what a reader checks (dvcore.schema.check_table): an unmeasurable value is
    # NaN and flagged, never infinite (tests/calibrate/test_unmeasurable_blur.py)
    frames.loc[1, "blur_px"] = np.inf
    with pytest.raises(schema.SchemaError, match="column 'blur_px' holds infinite values"):
        check_frames_table(frames, "inf blur")
