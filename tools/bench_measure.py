"""Speed and memory of `dropvision measure` against a plain scikit-image baseline.

    python tools/bench_measure.py [--frames 181] [--keep DIR]

Renders a default synthetic sequence (640 x 1024, 8-bit PNG), then on ONE core (one thread):

- PNG decoding alone: libpng (cv2.imread) vs dropvision's reader (`dropvision.readers.png`, checked
  bit-identical on every 20th frame);
- baseline: cv2 PNG decode (also skimage.io.imread, the plain choice), Otsu threshold, fill holes, label, regionprops, whole-pixel row
  widths (V = sum pi (w/2)^2) per body;
- dropvision, end to end (`measure_sequence`, calibration pass and PNG decode included);
- both with the frames already in memory (dropvision: `measure_frame`);

then the wall time of the command line on 2 workers including interpreter start-up, and the
peak resident memory of a run on N and on 3N frames (the same files listed three times) to
show that memory does not grow with the sequence length.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

os.environ.setdefault("OMP_NUM_THREADS", "1")


def baseline_frame(img: np.ndarray) -> list[float]:
    """Plain scikit-image measurement: Otsu, fill holes, label, regionprops, row widths."""
    from scipy import ndimage
    from skimage.filters import threshold_otsu
    from skimage.measure import label, regionprops

    mask = img < threshold_otsu(img)
    mask = ndimage.binary_fill_holes(mask)
    lab = label(mask)
    vols = []
    for rp in regionprops(lab):
        w = rp.image.sum(axis=1)
        vols.append(float(np.sum(np.pi * (w / 2.0) ** 2)))
    return vols


def _peak_rss_mb(seq: Path, workers: int) -> float:
    code = (
        "import resource, sys; from dropvision.measurement import measure_sequence; from dropvision.config import MeasureConfig;"
        f"measure_sequence({str(seq)!r}, config=MeasureConfig(workers={workers}));"
        "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    if out.returncode:
        raise RuntimeError(out.stderr)
    return int(out.stdout.strip().splitlines()[-1]) / 1024.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=181, help="number of delays (10 us apart)")
    ap.add_argument("--keep", help="render into this folder (reused if it exists)")
    args = ap.parse_args(argv)
    import cv2

    cv2.setNumThreads(1)
    from dropvision.sequence import open_sequence
    from dropvision.config import MeasureConfig
    from dropvision.frame import measure_frame
    from dropvision.measurement import measure_sequence
    from dropvision.synth import SynthConfig, write_synthetic_sequence

    tmp = tempfile.TemporaryDirectory()
    seq = Path(args.keep) if args.keep else Path(tmp.name) / "seq"
    if not (seq / "sequence.json").exists():
        cfg = SynthConfig(delays_us=tuple(float(10 * i) for i in range(args.frames)))
        write_synthetic_sequence(cfg, seq, progress=False)
    files = sorted(seq.glob("*.png"))
    n = len(files)
    report = {"frames": n, "shape": None}

    # --- baseline, end to end (decode + measure), one thread
    t = time.perf_counter()
    for f in files:
        baseline_frame(cv2.imread(str(f), cv2.IMREAD_UNCHANGED))
    base_e2e = n / (time.perf_counter() - t)
    from skimage.io import imread as sk_imread

    t = time.perf_counter()
    for f in files:
        baseline_frame(sk_imread(str(f)))
    base_e2e_sk = n / (time.perf_counter() - t)
    # --- PNG decoding alone: libpng (cv2) vs dropvision's reader (bit-identical, checked)
    from dropvision.readers.png import read_png

    t = time.perf_counter()
    for f in files:
        cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
    dec_libpng = (time.perf_counter() - t) / n * 1e3
    t = time.perf_counter()
    for f in files:
        read_png(f)
    dec_ours = (time.perf_counter() - t) / n * 1e3
    for f in files[:: max(1, n // 20)]:
        if not np.array_equal(read_png(f), cv2.imread(str(f), cv2.IMREAD_UNCHANGED)):
            raise AssertionError(f"{f}: dropvision's PNG decode differs from libpng")
    # --- dropvision end to end, one thread
    t = time.perf_counter()
    res = measure_sequence(seq, config=MeasureConfig(workers=1))
    ours_e2e = n / (time.perf_counter() - t)
    # --- in memory
    imgs = [cv2.imread(str(f), cv2.IMREAD_UNCHANGED) for f in files]
    report["shape"] = list(imgs[0].shape)
    t = time.perf_counter()
    for img in imgs:
        baseline_frame(img)
    base_mem = n / (time.perf_counter() - t)
    ctx = _context(seq)
    refs = open_sequence(seq).meta.frames
    t = time.perf_counter()
    reps = 3
    for _ in range(reps):
        for ref, img in zip(refs, imgs):
            measure_frame(img, ctx, ref)
    ours_mem = reps * n / (time.perf_counter() - t)
    del imgs
    # --- CLI wall time on 2 workers, interpreter start-up included
    with tempfile.TemporaryDirectory() as out:
        t = time.perf_counter()
        subprocess.run([sys.executable, "-m", "dropvision.app.cli", "measure", str(seq), "--out", str(Path(out) / "o"),
                        "--workers", "2"], check=True, capture_output=True, cwd=ROOT)
        cli_wall = time.perf_counter() - t
    # --- memory vs sequence length (the same frames three times, as repeats at each delay)
    import shutil

    long_seq = Path(tmp.name) / "long"
    long_seq.mkdir(exist_ok=True)
    listed = []
    for fr in json.loads((seq / "sequence.json").read_text())["frames"]:
        for k in range(3):
            name = f"r{k}_{fr['file']}"
            shutil.copyfile(seq / fr["file"], long_seq / name)
            listed.append({"file": name, "delay_us": fr["delay_us"]})
    meta = json.loads((seq / "sequence.json").read_text())
    meta["frames"] = listed
    (long_seq / "sequence.json").write_text(json.dumps(meta))
    rss_n = _peak_rss_mb(seq, 2)
    rss_3n = _peak_rss_mb(long_seq, 2)

    report.update({
        "png_decode_ms_libpng": dec_libpng,
        "png_decode_ms_dropvision": dec_ours,
        "baseline_end_to_end_fps": base_e2e,
        "dropvision_end_to_end_fps": ours_e2e,
        "end_to_end_speedup": ours_e2e / base_e2e,
        "baseline_skimage_imread_end_to_end_fps": base_e2e_sk,
        "end_to_end_speedup_vs_skimage_imread": ours_e2e / base_e2e_sk,
        "baseline_in_memory_fps": base_mem,
        "dropvision_in_memory_fps": ours_mem,
        "in_memory_speedup": ours_mem / base_mem,
        "cli_wall_s_2_workers": cli_wall,
        "peak_rss_mb_n": rss_n,
        "peak_rss_mb_3n": rss_3n,
        "pinchoff_us": res.summary["pinchoff_us"],
    })
    for k, v in report.items():
        print(f"{k:32s} {v:.4g}" if isinstance(v, float) else f"{k:32s} {v}")
    tmp.cleanup()
    return 0


def _context(seq: Path):
    """The per-frame context `measure_sequence` builds (calibration on the spread frames)."""
    from dropvision.sequence import open_sequence
    from dropvision.context import calibrate_sequence

    return calibrate_sequence(open_sequence(seq))[2]


if __name__ == "__main__":
    sys.exit(main())
