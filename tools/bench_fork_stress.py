"""Stress the forked frame workers of `dropvision measure`: many command-line runs beside busy loops.

Each run is the command line (`dropvision.app.cli.main`, in a fresh interpreter) measuring a long
sequence with ``--workers 2``, started while ``--busy`` processes spin on the cores (and, with
``--busy-native``, each also keeps OpenCV's and OpenBLAS's thread pools busy): the conditions
under which a worker forked from a process whose native pools had run hung for ever (issue 29).
A run that has not ended after ``--timeout-s`` is killed and counted as **hung**. Every run
reports which engine measured its frames (forked processes or threads) and whether a worker
stalled or died and its frames were measured again with threads (`WorkerProcessStalled`,
`WorkerProcessDied` warnings on stderr).

    .venv/bin/python tools/bench_fork_stress.py --runs 300 --busy 2

Prints one line per 25 runs and a summary: runs, forked, threads, hung, stalled-and-recovered,
died-and-recovered, failed (exit code other than 0), wall time per run (median, max). Exit 0
only when no run hung or failed. The figures go in docs/explanation/speed.md.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# run as the child: the command line itself, with a spy on the engine that measured the frames
_CHILD = """
import sys
import dropvision.app.cli as cli
import dvcore.parallel as engine
real = engine._map_forked
def spy(*a, **k):
    print("engine: processes", file=sys.stderr, flush=True)
    yield from real(*a, **k)
engine._map_forked = spy
sys.exit(cli.main(sys.argv[1:]))
"""


def _spin(native: bool, parent_pid: int) -> None:  # pragma: no cover - a busy loop in its own process
    from dvcore.process import die_with_parent

    die_with_parent(parent_pid)  # no busy loop left behind, however this tool ends
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if native:
        import cv2
        import numpy as np

        a = np.random.default_rng(0).random((1200, 1200), dtype=np.float32)
        while True:
            cv2.GaussianBlur(a, (0, 0), 3.0)
            a @ a[:, :64]
    while True:
        pass


def _sequence(work: Path, frames: int) -> Path:
    from dropvision.synth import SynthConfig, write_synthetic_sequence

    seq = work / f"seq_{frames}"
    if not (seq / "sequence.json").exists():
        write_synthetic_sequence(SynthConfig(delays_us=tuple(float(10 * i) for i in range(frames))), seq,
                                 progress=False)
    return seq


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=300, help="command-line runs")
    ap.add_argument("--busy", type=int, default=2, help="busy-loop processes beside the runs")
    ap.add_argument("--busy-native", action="store_true", help="the busy loops run OpenCV and BLAS pools")
    ap.add_argument("--frames", type=int, default=181, help="frames of the sequence measured")
    ap.add_argument("--timeout-s", type=float, default=60.0, help="a run still going after this is hung")
    ap.add_argument("--keep", type=Path, help="render the sequence into this folder (reused)")
    args = ap.parse_args(argv)

    tmp = tempfile.TemporaryDirectory()
    work = args.keep or Path(tmp.name)
    work.mkdir(parents=True, exist_ok=True)
    seq = _sequence(work, args.frames)
    spinners = [multiprocessing.get_context("spawn").Process(target=_spin, args=(args.busy_native, os.getpid()),
                                                                 daemon=True)
                for _ in range(args.busy)]
    for p in spinners:
        p.start()
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # a kill ends the spinners too (finally)
    counts = dict(runs=0, forked=0, threads=0, hung=0, stalled=0, died=0, failed=0)
    walls: list[float] = []
    env = {k: v for k, v in os.environ.items() if k != "DROPVISION_NO_FORK"}
    try:
        for i in range(args.runs):
            out = Path(tmp.name) / f"o{i}"
            t = time.perf_counter()
            try:
                r = subprocess.run([sys.executable, "-c", _CHILD, "measure", str(seq), "--out", str(out),
                                    "--workers", "2", "--quiet"], capture_output=True, text=True,
                                   timeout=args.timeout_s, cwd=ROOT, env=env)
            except subprocess.TimeoutExpired:
                counts["runs"] += 1
                counts["hung"] += 1
                print(f"run {i}: HUNG (killed after {args.timeout_s:.0f} s)", flush=True)
                continue
            walls.append(time.perf_counter() - t)
            counts["runs"] += 1
            counts["forked" if "engine: processes" in r.stderr else "threads"] += 1
            counts["stalled"] += "stalled" in r.stderr
            counts["died"] += "worker process died" in r.stderr
            if r.returncode != 0:
                counts["failed"] += 1
                print(f"run {i}: exit {r.returncode}: {r.stderr.strip().splitlines()[-1:]}", flush=True)
            if out.exists():
                import shutil

                shutil.rmtree(out)
            if (i + 1) % 25 == 0:
                print(f"{i + 1} runs: {counts}, median {statistics.median(walls):.2f} s", flush=True)
    finally:
        for p in spinners:
            p.terminate()
            p.join(timeout=5)
        tmp.cleanup()
    print(f"summary: {counts['runs']} runs beside {args.busy} busy loop(s)"
          f"{' (native pools)' if args.busy_native else ''}: forked {counts['forked']}, threads {counts['threads']}, "
          f"hung {counts['hung']}, stalled and recovered {counts['stalled']}, died and recovered {counts['died']}, "
          f"failed {counts['failed']}; wall per run median {statistics.median(walls) if walls else float('nan'):.2f} s, "
          f"max {max(walls) if walls else float('nan'):.2f} s")
    return 0 if counts["hung"] == 0 and counts["failed"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
