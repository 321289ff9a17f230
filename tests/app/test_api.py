"""The public API: the guide's Python example (docs/reference/api.md) runs as written; in-memory frames equal
a folder. (The README's short example runs in tests/project/test_docs.py.)"""

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import dropvision
import identify

ROOT = Path(__file__).resolve().parents[2]


def api_example() -> str:
    text = (ROOT / "docs" / "reference" / "api.md").read_text(encoding="utf-8")
    section = text.split("## Overview", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


@pytest.mark.slow
def test_api_page_python_example_runs(tmp_path):
    (tmp_path / "sample_frames").symlink_to(ROOT / "sample_frames", target_is_directory=True)
    script = tmp_path / "example.py"
    script.write_text(api_example())
    run = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "pinch-off" in run.stdout and (tmp_path / "model.json").is_file()


@pytest.mark.slow
def test_import_is_cheap_and_names_load_lazily():
    code = ("import sys, dropvision, identify; "
            "assert 'pandas' not in sys.modules and 'dropvision.measurement' not in sys.modules; "
            "dropvision.measure; identify.fit; assert 'dropvision.measurement' in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
    assert set(dropvision.__all__) <= set(dir(dropvision)) and set(identify.__all__) <= set(dir(identify))
    with pytest.raises(AttributeError):
        dropvision.no_such_name  # noqa: B018


@pytest.mark.slow
def test_measure_from_memory_equals_the_folder():
    folder = ROOT / "sample_frames" / "u55_u30"
    seq = dropvision.open_sequence(folder)
    stack = np.stack([seq.read(i).image for i in range(len(seq))])
    meta = seq.meta
    ref = dropvision.measure(folder)
    # frames given in reverse order and as recorded: the delays sort them
    got = dropvision.measure(stack[::-1], delays_us=meta.delays_us[::-1], pixel_size_um=meta.pixel_size_um,
                             nozzle_inner_diameter_um=meta.nozzle_inner_diameter_um,
                             nozzle_outer_diameter_um=meta.nozzle_outer_diameter_um, waveform=meta.waveform)
    cols = [c for c in ref.frames.columns if c != "file"]
    pd.testing.assert_frame_equal(got.frames[cols], ref.frames[cols])
    for key in ("pinchoff_us", "inflight_volume_nl", "jetting_velocity_m_s"):
        assert got.summary[key] == ref.summary[key]


def test_measure_from_memory_refuses_bad_arguments():
    frames = np.zeros((3, 40, 30), np.uint8)
    with pytest.raises(TypeError, match="delays_us and pixel_size_um"):
        dropvision.measure(frames)
    with pytest.raises(dropvision.SequenceError, match="3 frame.*2 delay"):
        dropvision.measure(frames, delays_us=[0, 10], pixel_size_um=4.73)
    with pytest.raises(dropvision.SequenceError, match="pixel_size_um must be a number > 0"):
        dropvision.measure(frames, delays_us=[0, 10, 20], pixel_size_um=-1)
    with pytest.raises(dropvision.SequenceError, match="differ in size"):
        dropvision.measure([frames[0], frames[0][:, :20]], delays_us=[0, 10], pixel_size_um=4.73)
    with pytest.raises(TypeError, match="delays_us applies to frames in memory"):  # a folder has its delays
        dropvision.measure(str(ROOT / "sample_frames" / "u55_u30"), delays_us=[0, 10])
    with pytest.raises(TypeError, match="unknown metadata"):
        dropvision.measure(str(ROOT / "sample_frames" / "u55_u30"), pixel_size=4.73)
