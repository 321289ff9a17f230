"""Latency of `dropvision watch`: a sequence written at a drop watcher's pace, measured as it comes.

Replays a sequence folder (default: sample_frames/colour_ink_u70_u25, 181 frames of 704 x 224 px)
into a temporary folder at ``--rate-hz`` frames per second (sequence.json first, each frame in
two writes 10 ms apart: `dropvision.app.replay.replay_sequence`) while ``dropvision watch`` runs
on it in its own process, then prints the time from each file's completion (the writer closed
it) to its row on disk in ``OUT/live/frames.jsonl``: median, 90th percentile, max, and the
first frame (which waits for the first calibration) apart. Finally it checks that the final
tables equal ``dropvision measure`` of the same folder.

``--synth`` replays a synthetic sequence of the default camera instead (181 frames of 640 x 1024 px,
`dropvision.synth.SynthConfig()`, rendered first).

``--shots DIR`` replays a folder of shots instead (a drop watcher's exports, one image per shot, no delay
in the names; its sequence.json and shots.csv first, then each image renamed into place at
``--rate-hz``) to ``dropvision watch --shots``, and checks that the final shots.parquet equals
``dropvision measure`` of the folder.

    python tools/bench_watch.py [--source SEQ_DIR | --synth | --shots DIR] [--rate-hz 20] [--frames N] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dropvision.app.live_journal import JOURNAL, read_journal  # noqa: E402
from dropvision.app.replay import replay_sequence  # noqa: E402
from dropvision.measurement import measure_sequence  # noqa: E402
from dropvision.io.sequence import open_sequence  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", type=Path, default=ROOT / "sample_frames" / "colour_ink_u70_u25",
                    help="a complete sequence folder to replay")
    ap.add_argument("--synth", action="store_true",
                    help="replay a synthetic sequence of 181 frames of 640 x 1024 px (rendered first) instead")
    ap.add_argument("--shots", type=Path, default=None, metavar="DIR",
                    help="replay this folder of shots (one image per shot) to dropvision watch --shots instead")
    ap.add_argument("--rate-hz", type=float, default=20.0, help="frames per second (default 20)")
    ap.add_argument("--frames", type=int, default=None, help="replay only the first N frames")
    ap.add_argument("--keep", type=Path, default=None, help="work in this (new) folder and keep it")
    args = ap.parse_args(argv)
    if args.shots is not None:
        return _bench_shots(args)
    with tempfile.TemporaryDirectory(prefix="bench_watch.") as tmp:
        work = args.keep or Path(tmp)
        watched, out = work / "watched", work / "out"
        watched.mkdir(parents=True)
        if args.synth:
            from dropvision.synth import SynthConfig, write_synthetic_sequence

            args.source = write_synthetic_sequence(SynthConfig(), work / "synth", progress=False)
        cmd = [sys.executable, "-m", "dropvision.app.cli", "watch", str(watched), "--out", str(out), "-q"]
        if args.frames is not None:
            cmd += ["--frames", str(args.frames)]
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
        load0 = os.getloadavg()[0]
        proc = subprocess.Popen(cmd, env=env)
        while not (out / JOURNAL).exists():  # the watcher is up (its output folder claimed)
            if proc.poll() is not None:
                raise SystemExit(f"bench_watch: dropvision watch exited {proc.returncode} before watching")
            time.sleep(0.01)
        t0 = time.monotonic()
        completed = replay_sequence(args.source, watched, rate_hz=args.rate_hz, stop_after=args.frames)
        written_s = time.monotonic() - t0
        if proc.wait(timeout=600) != 0:
            raise SystemExit(f"bench_watch: dropvision watch exited {proc.returncode}")
        end_s = time.monotonic() - t0
        rows = read_journal(out)
        lat = {r["file"]: (r["row_unix_s"] - completed[r["file"]]) * 1e3 for r in rows}
        first = next(iter(completed))
        rest = np.array([v for k, v in lat.items() if k != first])
        n = len(completed)
        with open_sequence(args.source) as src:
            shape = "x".join(str(v) for v in src.meta.shape[::-1])
        print(f"dropvision watch, {n} frames of {args.source.name} ({shape} px, width x height) written at "
              f"{args.rate_hz:g} frames/s ({written_s:.1f} s), load average {load0:.1f} -> {os.getloadavg()[0]:.1f}")
        print(f"rows on disk: {len(rows)}; completion to row on disk: median {statistics.median(lat.values()):.1f} ms, "
              f"p90 {np.percentile(list(lat.values()), 90):.1f} ms, max {max(lat.values()):.1f} ms; "
              f"first frame (first calibration) {lat[first]:.0f} ms, "
              f"the others max {rest.max() if rest.size else 0:.1f} ms")
        seq = open_sequence(watched, only_files=set(completed)) if args.frames else watched
        batch = measure_sequence(seq)
        final = pd.read_parquet(out / "frames.parquet")
        same = final.equals(batch.frames) and json.loads((out / "summary.json").read_text())["n_measured"] == n
        print(f"final tables {end_s - written_s:.2f} s after the last frame; equal to dropvision measure: "
              f"{'yes' if same else 'NO'}")
        return 0 if same and len(rows) == n else 1


def _bench_shots(args) -> int:
    """``--shots DIR``: each image renamed into the watched folder at the rate; latency per image, the
    final shots.parquet against ``measure_shots`` of the folder."""
    import shutil

    from dropvision.io.discovery import images_without_delay
    from dropvision.analysis.shots import measure_shots

    names = images_without_delay(args.shots)
    if names is None:
        raise SystemExit(f"bench_watch: {args.shots}: not a folder of shots")
    names = names[:args.frames] if args.frames else names
    with tempfile.TemporaryDirectory(prefix="bench_watch.") as tmp:
        work = args.keep or Path(tmp)
        watched, out = work / "watched", work / "out"
        watched.mkdir(parents=True)
        for side in ("sequence.json", "shots.csv"):
            if (args.shots / side).is_file():
                shutil.copyfile(args.shots / side, watched / side)
        cmd = [sys.executable, "-m", "dropvision.app.cli", "watch", str(watched), "--out", str(out), "-q", "--shots",
               "--frames", str(len(names))]
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
        load0 = os.getloadavg()[0]
        proc = subprocess.Popen(cmd, env=env)
        while not (out / JOURNAL).exists():
            if proc.poll() is not None:
                raise SystemExit(f"bench_watch: dropvision watch exited {proc.returncode} before watching")
            time.sleep(0.01)
        completed: dict[str, float] = {}
        t0 = time.monotonic()
        for i, name in enumerate(names):
            time.sleep(max(0.0, t0 + i / args.rate_hz - time.monotonic()))
            shutil.copyfile(args.shots / name, watched / f".{name}.part")
            os.replace(watched / f".{name}.part", watched / name)  # renamed into place: complete
            completed[name] = time.time()
        written_s = time.monotonic() - t0
        if proc.wait(timeout=600) != 0:
            raise SystemExit(f"bench_watch: dropvision watch exited {proc.returncode}")
        end_s = time.monotonic() - t0
        lat = [(r["row_unix_s"] - completed[r["file"]]) * 1e3 for r in read_journal(out)]
        print(f"dropvision watch --shots, {len(names)} images of {args.shots.name} written at {args.rate_hz:g} "
              f"images/s ({written_s:.1f} s), load average {load0:.1f} -> {os.getloadavg()[0]:.1f}")
        print(f"rows on disk: {len(lat)}; completion to row on disk: median {statistics.median(lat):.0f} ms, "
              f"max {max(lat):.0f} ms")
        import warnings

        with warnings.catch_warnings():  # the watch printed them
            warnings.simplefilter("ignore")
            batch = measure_shots(watched)
        same = pd.read_parquet(out / "shots.parquet").equals(batch.shots)
        print(f"final tables {end_s - written_s:.2f} s after the last image; equal to dropvision measure: "
              f"{'yes' if same else 'NO'}")
        return 0 if same and len(lat) == len(names) else 1


if __name__ == "__main__":
    sys.exit(main())
