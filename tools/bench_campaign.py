"""Campaign throughput with 1 and 2 workers, and peak memory per worker.

    python tools/bench_campaign.py [--sequences 8] [--size 320x1024] [--keep DIR]

Renders a synthetic campaign (default 8 sequences of 181 frames, 0-1800 us every 10 us), then
measures it into a fresh dataset with 1 worker (in-process) and with 2 worker processes, each in
its own subprocess so that peak memory is measured per run (ru_maxrss of the worker processes).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = r"""
import json, resource, sys, time
from dropvision.app.campaign import run_campaign
root, out, workers = sys.argv[1], sys.argv[2], int(sys.argv[3])
t0 = time.perf_counter()
res = run_campaign(root, out, workers=workers, progress=False)
dt = time.perf_counter() - t0
self_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
child_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
print(json.dumps({"seconds": dt, "measured": len(res.measured), "failed": len(res.failed),
                  "peak_rss_parent_mb": self_kb / 1024, "peak_rss_worker_mb": child_kb / 1024}))
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequences", type=int, default=8)
    ap.add_argument("--size", default="320x1024", help="frame size WxH (default 320x1024)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the rendered campaign here")
    args = ap.parse_args(argv)
    from dropvision.app.campaign import synth_campaign

    w, h = (int(x) for x in args.size.lower().split("x"))
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench_campaign_"))
    root = work / "campaign"
    u1 = [50.0 + 30.0 * i / max(args.sequences - 1, 1) for i in range(args.sequences)]
    if not root.exists():
        t0 = time.perf_counter()
        synth_campaign(root, u1, [25.0], progress=False,
                       overrides={"width_px": w, "height_px": h, "axis_col": w / 2 - 0.4})
        print(f"rendered {args.sequences} sequences of 181 frames ({w}x{h}) in {time.perf_counter() - t0:.1f} s")
    frames = 181 * args.sequences
    print(f"{'workers':>7s} {'seconds':>8s} {'seq/s':>7s} {'frames/s':>9s} {'peak RSS parent MB':>19s} {'peak RSS worker MB':>19s}")
    for workers in (1, 2):
        out = work / f"dataset_w{workers}"
        shutil.rmtree(out, ignore_errors=True)  # a fresh dataset: resuming would skip everything
        r = subprocess.run([sys.executable, "-c", CHILD, str(root), str(out), str(workers)],
                           check=True, capture_output=True, text=True)
        res = json.loads(r.stdout.strip().splitlines()[-1])
        worker_mb = res["peak_rss_worker_mb"] if workers > 1 else res["peak_rss_parent_mb"]
        print(f"{workers:7d} {res['seconds']:8.2f} {res['measured'] / res['seconds']:7.2f} {frames / res['seconds']:9.0f} "
              f"{res['peak_rss_parent_mb']:19.0f} {worker_mb:19.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
