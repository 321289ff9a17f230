"""The hostile-input tier: one generated case of every family of tools/hostile_corpus.py
(corrupt metadata values and documents, frame entries, corrupt frames, lying metadata, output
locations, links out of the folder, model files, identify arguments, lying datasets, identify outputs
onto or inside the dataset) runs
through the real command lines: no traceback, hang, runaway memory, silent wrong answer, read
outside the folder or changed input. The full corpus (>= 400 cases) is the tool itself."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_quick_corpus_has_no_bad_outcome(tmp_path):
    run = subprocess.run([sys.executable, str(ROOT / "tools" / "hostile_corpus.py"), "--quick", "--jobs", "1",
                          "--out", str(tmp_path / "table.csv")], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    assert "0 bad" in run.stdout
