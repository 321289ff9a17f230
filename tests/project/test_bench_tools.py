"""Smoke tests of the benchmark tools: each runs end to end on a tiny configuration.

The figures themselves are not checked (timings on a shared machine say nothing); what is
checked is that a user can rerun every benchmark: it finishes, exits 0 and prints its table.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TOOLS = ROOT / "tools"


def _run(tool: str, *args: str, timeout: float = 120.0) -> tuple[str, float]:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    t = time.perf_counter()
    r = subprocess.run([sys.executable, str(TOOLS / tool), *args], capture_output=True, text=True, cwd=ROOT,
                       env=env, timeout=timeout)
    dt = time.perf_counter() - t
    assert r.returncode == 0, f"{tool} {' '.join(args)} exited {r.returncode}:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r.stdout, dt


@pytest.mark.slow
def test_bench_measure_tiny(tmp_path):
    out, _ = _run("bench_measure.py", "--frames", "6", "--rounds", "1", "--kinds", "opencv",
                  "--tiers", "clean,watcher-side", "--no-cli", "--no-rss", "--keep", str(tmp_path))
    assert "[opencv] decode ms/frame" in out
    assert "realism tiers" in out and "watcher-side" in out


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("distributed") is None, reason="Dask (distributed) not installed")
def test_bench_campaign_tiny(tmp_path):
    out, _ = _run("bench_campaign.py", "--sequences", "1", "--frames", "5", "--size", "160x512", "--rounds", "1",
                  "--workers", "1", "--keep", str(tmp_path), "--json", str(tmp_path / "figures.json"),
                  "--timeout", "110")
    rows = json.loads((tmp_path / "figures.json").read_text())["rows"]
    assert [r["executor"] for r in rows] == ["in-process", "dask-1"]
    assert rows[1]["efficiency"] == pytest.approx(1.0)
    assert all(r["frames_per_s"] > 0 and r["peak_rss_worker_mb"] > 0 for r in rows)
    assert "dask-1" in out


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("distributed") is None, reason="Dask (distributed) not installed")
def test_bench_campaign_overheads_tiny(tmp_path):
    out, _ = _run("bench_campaign.py", "--overheads", "--sequences", "2", "--frames", "5", "--size", "160x512",
                  "--manifest-entries", "20", "--project", "2,4", "--keep", str(tmp_path),
                  "--json", str(tmp_path / "o.json"))
    fig = json.loads((tmp_path / "o.json").read_text())
    assert fig["task_s"] > 0 and fig["client_fraction"] > 0 and fig["dask_task_overhead_s"] > 0
    assert fig["read_bytes_per_task"] > 0 and fig["written_bytes_per_task"] > 0
    proj = fig["projection"]
    assert {(p["sequences"], p["workers"]) for p in proj} == {(n, w) for n in (2, 64, 1000) for w in (2, 4)}
    assert all(0 < p["efficiency"] <= 1 for p in proj)
    assert "E(W)" not in out and "Dask per-task overhead" in out


@pytest.mark.slow
def test_bench_montecarlo_tiny():
    out, _ = _run("bench_montecarlo.py", "--samples", "200", "--steps", "50", "--subset", "3", "--repeat", "1")
    assert out.strip()


@pytest.mark.slow
def test_bench_decoders_tiny():
    out, _ = _run("bench_decoders.py", "--repeats", "5", "--inner", "1")
    assert "cv2.imdecode" in out


@pytest.mark.slow
def test_bench_decoders_corpus_tiny(tmp_path):
    out, _ = _run("bench_decoders.py", "--corpus", "--repeats", "1", "--out", str(tmp_path / "c.csv"))
    import csv
    with (tmp_path / "c.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    ours = {r["kind"]: r for r in rows if r["decoder"] == "dropvision reader"}
    # our reader reads every kind, identical to OpenCV, with a real time
    assert {"PNG 8-bit grey, Pillow", "PNG 16-bit grey, OpenCV", "PNG 8-bit colour, Pillow",
            "JPEG colour q90 640x1024 -> grey", "TIFF 16-bit grey, uncompressed"} <= set(ours)
    assert all(r["note"] == "" and float(r["ms_per_frame"]) > 0 for r in ours.values()), ours
    assert "vs best other" in out


@pytest.mark.slow
def test_bench_watch_tiny():
    out, _ = _run("bench_watch.py", "--frames", "6", "--rate-hz", "50")
    assert "completion to row on disk: median" in out and "equal to dropvision measure: yes" in out
