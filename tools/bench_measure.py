"""Speed and memory of `dropvision measure` against a plain scikit-image baseline, per file kind.

    python tools/bench_measure.py [--frames 181] [--rounds 3] [--keep DIR] [--kinds pillow,opencv,jpeg,tiff16]
                                  [--tiers clean,low-contrast,tilted-dusty,watcher-side] [--profile-tier TIER]
                                  [--no-cli] [--no-rss] [--stages]

Renders a default synthetic sequence (640 x 1024) and writes it as (a) Pillow-written PNGs
(adaptive filtering: Sub, Up, Paeth rows), (b) OpenCV-written PNGs (every row Sub), (c) JPEG
quality 90 (skipped, and marked so, while no JPEG reader is registered in
``dropvision.io.readers``), (d) one 16-bit TIFF stack (uncompressed pages). For each kind, on ONE
core (one thread), in one process, ``--rounds`` rounds alternating baseline and ours (medians):

- the file's own properties (size per frame, bit depth, compression, PNG filter types used);
- decoding alone, ms/frame: the library default (cv2.imread = libpng / libjpeg-turbo;
  tifffile for TIFF pages) vs dropvision's reader (``reader_for(path).decode``, checked
  bit-identical on every 20th frame);
- baseline end to end: skimage.io.imread (tifffile for a stack), Otsu threshold, fill holes,
  label, regionprops, whole-pixel row widths (V = sum pi (w/2)^2) per body;
- dropvision end to end (`measure_sequence`, calibration pass and decoding included);

then the peak resident memory of a run on N and on 3N frames (every frame listed three times)
in a fresh process, and for (a) the wall time of the command line on 2 workers including
interpreter start-up.

Realism tiers (issue 12: per-frame cost independent of content): the clean synthetic sequence
and the synthesizer's rig presets ``low-contrast`` (weak contrast, shot noise, blur, dust),
``tilted-dusty`` (1.5 deg tilt, 12-bit TIFF, dust, vignetting) and ``watcher-side`` (holder block,
vignetting, colour JPEG, mist, satellites, tail with a bulb, orifice bead; shrunk to 640 x 1024
canonical), each decoded once into memory (`dropvision.io.sequence.sequence_from_arrays`) and
measured pipeline-only (calibration, per-frame pipeline, assembly; one thread), rounds
alternated over the tiers; reported: frames/s and the extra time per frame against clean
(goal <= +20 %). ``--profile-tier`` prints a cProfile of one run of that tier.

``--stages``: the pipeline's stages on every tier, from a cProfile of one pipeline-only run each
(cumulative time of each stage's function, ms per frame and fraction of the run; the profiler's
overhead inflates the Python-heavy stages a little, so the fractions are the figure to read):
the calibration pass, and per frame photometry, ROI smoothing, segmentation, the attached
liquid, the thin-thread rule, each detached body (edges and volume, appearance, description),
the touching-satellite split; then the assembly (frames table, summary) and the bodies table.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# one thread for BLAS too: OpenBLAS reads these when numpy loads it, so before the numpy import
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


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


def _png_filters(path: Path) -> np.ndarray:
    """Rows per PNG filter type (None, Sub, Up, Average, Paeth) of one file."""
    import struct
    import zlib

    data = path.read_bytes()
    pos, idat, width, depth = 8, [], 0, 8
    while pos < len(data):
        length, ctype = struct.unpack_from(">I4s", data, pos)
        if ctype == b"IHDR":
            width, _, depth = struct.unpack_from(">IIB", data, pos + 8)
        elif ctype == b"IDAT":
            idat.append(data[pos + 8:pos + 8 + length])
        pos += 12 + length
    raw = np.frombuffer(zlib.decompress(b"".join(idat)), np.uint8)
    return np.bincount(raw.reshape(-1, width * depth // 8 + 1)[:, 0], minlength=5)


def _write_variants(seq: Path, work: Path, kinds: list[str]) -> dict:
    """The rendered (OpenCV-written) sequence rewritten as each file kind: {kind: folder or None}."""
    import cv2

    from dropvision.io.readers import IMAGE_SUFFIXES

    meta = json.loads((seq / "sequence.json").read_text())
    frames = meta["frames"]
    out = {}
    for kind in kinds:
        if kind == "opencv":
            out[kind] = seq
            continue
        if kind == "jpeg" and ".jpg" not in IMAGE_SUFFIXES:
            out[kind] = None  # SKIPPED: no JPEG reader registered in dropvision.io.readers
            continue
        folder = work / kind
        if (folder / "sequence.json").exists():
            out[kind] = folder
            continue
        folder.mkdir(parents=True, exist_ok=True)
        m = dict(meta)
        if kind == "pillow":
            from PIL import Image

            for fr in frames:
                Image.fromarray(cv2.imread(str(seq / fr["file"]), cv2.IMREAD_UNCHANGED)).save(folder / fr["file"])
        elif kind == "jpeg":
            listed = []
            for fr in frames:
                name = Path(fr["file"]).with_suffix(".jpg").name
                cv2.imwrite(str(folder / name), cv2.imread(str(seq / fr["file"]), cv2.IMREAD_UNCHANGED),
                            [cv2.IMWRITE_JPEG_QUALITY, 90])
                listed.append({**fr, "file": name})
            m["frames"] = listed
        elif kind == "tiff16":
            import tifffile

            with tifffile.TiffWriter(folder / "stack.tif") as tw:
                for fr in frames:
                    img = cv2.imread(str(seq / fr["file"]), cv2.IMREAD_UNCHANGED).astype(np.uint16) * 257
                    tw.write(img, contiguous=False, compression=None)
            m["frames"] = [{**fr, "file": "stack.tif", "page": i} for i, fr in enumerate(frames)]
            m["bit_depth"] = 16
        else:
            raise SystemExit(f"unknown kind {kind!r}")
        (folder / "sequence.json").write_text(json.dumps(m))
        out[kind] = folder
    return out


def _tripled(seq: Path, dest: Path) -> Path:
    """The same sequence with every frame listed three times (repeats at each delay), as
    hard links (copies where links fail) named r0_, r1_, r2_ + the file's name."""
    meta = json.loads((seq / "sequence.json").read_text())
    dest.mkdir(parents=True, exist_ok=True)
    listed = []
    for k in range(3):
        for fr in meta["frames"]:
            name = f"r{k}_{fr['file']}"
            if not (dest / name).exists():
                try:
                    os.link(seq / fr["file"], dest / name)
                except OSError:
                    shutil.copyfile(seq / fr["file"], dest / name)
            listed.append({**fr, "file": name})
    meta["frames"] = listed
    (dest / "sequence.json").write_text(json.dumps(meta))
    return dest


def _properties(seq: Path, frames: list[dict]) -> str:
    files = sorted({seq / fr["file"] for fr in frames})
    size_kb = sum(f.stat().st_size for f in files) / len(frames) / 1024
    suffix = files[0].suffix.lower()
    if suffix == ".png":
        kinds = sum(_png_filters(f) for f in files[:: max(1, len(files) // 20)])
        names = ("None", "Sub", "Up", "Average", "Paeth")
        used = ", ".join(f"{n} {100 * k / kinds.sum():.1f}%" for n, k in zip(names, kinds) if k)
        return f"PNG deflate, {size_kb:.0f} KiB/frame, rows: {used}"
    if suffix in (".tif", ".tiff"):
        import tifffile

        with tifffile.TiffFile(files[0]) as tf:
            page = tf.pages[0]
            return (f"TIFF {page.bitspersample}-bit, {len(tf.pages)} pages, compression "
                    f"{page.compression.name}, {size_kb:.0f} KiB/frame")
    return f"{suffix[1:].upper()}, {size_kb:.0f} KiB/frame"


def bench_kind(kind: str, seq: Path, rounds: int, work: Path, rss: bool = True) -> dict:
    """Decode and end-to-end figures for one sequence folder (medians of alternated rounds)."""
    import cv2
    import tifffile
    from skimage.io import imread as sk_imread

    from dropvision.config import MeasureConfig
    from dropvision.measurement import measure_sequence
    from dropvision.io.readers import reader_for

    frames = json.loads((seq / "sequence.json").read_text())["frames"]
    n = len(frames)
    items = [(seq / fr["file"], fr.get("page")) for fr in frames]
    reader = reader_for(items[0][0])

    if items[0][1] is None:
        def lib_decode(path, page):
            return cv2.imread(str(path), cv2.IMREAD_UNCHANGED)

        def base_decode(path, page):
            return sk_imread(str(path))
    else:
        def lib_decode(path, page):
            return tifffile.imread(path, key=page)

        base_decode = lib_decode

    def timed(fn) -> float:
        t = time.perf_counter()
        fn()
        return time.perf_counter() - t

    dec_lib, dec_ours, base, ours = [], [], [], []
    for _ in range(rounds):  # alternated: a load change hits both sides alike
        dec_lib.append(timed(lambda: [lib_decode(p, k) for p, k in items]) / n * 1e3)
        dec_ours.append(timed(lambda: [reader.decode(p, k) for p, k in items]) / n * 1e3)
        base.append(n / timed(lambda: [baseline_frame(base_decode(p, k)) for p, k in items]))
        ours.append(n / timed(lambda: measure_sequence(seq, config=MeasureConfig(workers=1))))
    for p, k in items[:: max(1, n // 20)]:
        if not np.array_equal(reader.decode(p, k), lib_decode(p, k)):
            raise AssertionError(f"{p}: dropvision's decode differs from {kind}'s library decoder")
    med = statistics.median
    return {
        "kind": kind, "frames": n, "properties": _properties(seq, frames),
        "decode_ms_library": med(dec_lib), "decode_ms_dropvision": med(dec_ours),
        "baseline_fps": med(base), "dropvision_fps": med(ours), "speedup": med(ours) / med(base),
        "speedup_range": (min(ours) / max(base), max(ours) / min(base)),
        "peak_rss_mb_n": _peak_rss_mb(seq, 2) if rss else float("nan"),
        "peak_rss_mb_3n": _peak_rss_mb(_tripled(seq, work / f"{kind}_x3"), 2) if rss else float("nan"),
    }


#: Realism tiers: (rig preset of `dropvision.synth.RIGS`, overrides shrinking it to 640 x 1024 canonical)
TIERS = {
    "clean": ("clean", {}),
    "low-contrast": ("low-contrast", {}),
    "tilted-dusty": ("tilted-dusty", {}),
    "watcher-side": ("watcher-side", dict(width_px=640, height_px=1024, tip_row=120.4, axis_col=319.6)),
}


def _in_memory(folder: Path):
    """The sequence in ``folder`` decoded once into an in-memory sequence (canonical frames):
    measuring it costs the pipeline only, no decoding."""
    import warnings

    from dropvision.io.sequence import open_sequence, sequence_from_arrays

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # colour JPEGs of the watcher rig: converted to grey, noted once
        seq = open_sequence(folder)
        m = seq.meta
        images = [seq.read(i).image for i in range(len(seq))]
        seq.close()
    return lambda: sequence_from_arrays(
        images, m.delays_us, pixel_size_um=m.pixel_size_um, orientation="down",
        nozzle_inner_diameter_um=m.nozzle_inner_diameter_um, nozzle_outer_diameter_um=m.nozzle_outer_diameter_um,
        nozzle_tip_row=m.nozzle_tip_row, axis_col=m.axis_col, waveform=m.waveform, ink=m.ink,
        bit_depth=m.bit_depth, name=folder.name)


#: --stages: stage name -> (module file suffix, function name) whose cumulative time is the stage's
STAGES = {
    "calibration pass": ("dropvision/calibrate/calibration_pass.py", "calibrate_sequence"),
    "  background estimate": ("dropvision/calibrate/background.py", "estimate_background"),
    "per-frame pipeline (all)": ("dropvision/frame/measure_frame.py", "measure_frame"),
    "  photometry": ("dropvision/frame/measure_frame.py", "measure_photometry"),
    "  ROI smoothing": ("dropvision/calibrate/frame_context.py", "smooth_roi"),
    "  segmentation": ("dropvision/frame/measure_frame.py", "segment_frame"),
    "  attached liquid": ("dropvision/frame/bodies.py", "measure_attached"),
    "  thin-thread rule": ("dropvision/analysis/pinchoff.py", "thread_joined_labels"),
    "  detached body edges+volume": ("dropvision/frame/bodies.py", "measure_body"),
    "  detached body appearance": ("dropvision/frame/body_classes.py", "appearance"),
    "  detached body description": ("dropvision/frame/bodies.py", "describe_detached"),
    "  touching-satellite split": ("dropvision/frame/measure_frame.py", "_split_touching"),
    "assembly (frames, summary)": ("dropvision/analysis/sequence_summary.py", "assemble"),
    "bodies table": ("dropvision/output/bodies_table.py", "bodies_table"),
}


def stage_profile(measure, frames: int) -> list[tuple[str, float, float]]:
    """(stage, ms per frame, fraction of the run) of one cProfiled pipeline-only run."""
    import cProfile
    import pstats

    prof = cProfile.Profile()
    t = time.perf_counter()
    prof.enable()
    measure()
    prof.disable()
    total = time.perf_counter() - t
    stats = pstats.Stats(prof).stats
    rows = []
    for name, (suffix, func) in STAGES.items():
        ct = sum(v[3] for (file, _, fn), v in stats.items() if fn == func and file.replace("\\", "/").endswith(suffix))
        rows.append((name, 1e3 * ct / frames, ct / total))
    rows.append(("whole run (profiled)", 1e3 * total / frames, 1.0))
    return rows


def bench_tiers(tiers: list[str], frames: int, rounds: int, work: Path, profile: str | None = None,
                stages: bool = False) -> list[dict]:
    """Pipeline-only frames/s (frames already in memory, one thread) on the clean tier and on
    the synthesizer's rig presets, alternated rounds, medians; slow-down vs clean."""
    import warnings

    from dropvision.config import MeasureConfig
    from dropvision.measurement import measure_sequence
    from dropvision.synth import SynthConfig, write_synthetic_sequence

    delays = tuple(float(10 * i) for i in range(frames))
    makers = {}
    for tier in tiers:
        rig, overrides = TIERS[tier]
        folder = work / f"tier_{tier}_{frames}"
        if not (folder / "sequence.json").exists():
            write_synthetic_sequence(SynthConfig.for_rig(rig, delays_us=delays, **overrides), folder, progress=False)
        listed = json.loads((folder / "sequence.json").read_text())["frames"]
        makers[tier] = (_in_memory(folder), _properties(folder, listed))
    fps: dict[str, list[float]] = {t: [] for t in tiers}
    config = MeasureConfig(workers=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(rounds):  # alternated: a load change hits every tier alike
            for tier in tiers:
                seq = makers[tier][0]()
                t = time.perf_counter()
                measure_sequence(seq, config=config)
                fps[tier].append(frames / (time.perf_counter() - t))
        if profile:
            import cProfile
            import pstats

            prof = cProfile.Profile()
            seq = makers[profile][0]()
            prof.enable()
            measure_sequence(seq, config=config)
            prof.disable()
            print(f"[tier {profile}] cProfile of one pipeline-only run, top functions by own time:")
            pstats.Stats(prof).sort_stats("tottime").print_stats(20)
        if stages:
            table = {t: stage_profile(lambda t=t: measure_sequence(makers[t][0](), config=config), frames) for t in tiers}
            print("pipeline stages (one cProfiled pipeline-only run per tier): ms/frame (fraction of the run)")
            print(f"{'stage':<30s}" + "".join(f"{t:>24s}" for t in tiers))
            for i, (name, *_) in enumerate(table[tiers[0]]):
                print(f"{name:<30s}" + "".join(f"{table[t][i][1]:13.3f} ({100 * table[t][i][2]:5.1f} %)" for t in tiers))
    med = statistics.median
    # the slow-down is the median over rounds of (time of the tier / time of clean in the same
    # round): a load change between rounds cancels out
    return [{"tier": t, "frames": frames, "pipeline_fps": med(fps[t]), "fps_all": fps[t],
             "slowdown_vs_clean": (med(c / x for c, x in zip(fps["clean"], fps[t])) - 1.0) if "clean" in fps else None,
             "file": makers[t][1]} for t in tiers]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=181, help="number of delays (10 us apart)")
    ap.add_argument("--rounds", type=int, default=3, help="alternated rounds (medians reported; >= 3)")
    ap.add_argument("--kinds", default="pillow,opencv,jpeg,tiff16", help="file kinds to run (comma-separated)")
    ap.add_argument("--keep", help="render into this folder (reused if it exists)")
    ap.add_argument("--tiers", default=",".join(TIERS),
                    help=f"realism tiers for the pipeline-only figures (default {','.join(TIERS)}; '' = none)")
    ap.add_argument("--profile-tier", default=None, metavar="TIER", help="also cProfile one pipeline-only run of TIER")
    ap.add_argument("--stages", action="store_true", help="also the pipeline's stages per tier, ms/frame and fraction")
    ap.add_argument("--no-cli", action="store_true", help="skip the command-line wall time")
    ap.add_argument("--no-rss", action="store_true", help="skip the peak-memory runs")
    args = ap.parse_args(argv)
    tiers = [t.strip() for t in args.tiers.split(",") if t.strip()]
    unknown = [t for t in tiers if t not in TIERS]
    if unknown:
        ap.error(f"--tiers: unknown {unknown}; known: {', '.join(TIERS)}")
    if args.profile_tier and args.profile_tier not in tiers:
        ap.error("--profile-tier must be one of --tiers")
    import cv2

    cv2.setNumThreads(1)
    from dropvision.synth import SynthConfig, write_synthetic_sequence

    tmp = tempfile.TemporaryDirectory()
    work = Path(args.keep) if args.keep else Path(tmp.name)
    seq = work / f"opencv_png_{args.frames}"
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    if kinds and not (seq / "sequence.json").exists():
        cfg = SynthConfig(delays_us=tuple(float(10 * i) for i in range(args.frames)))
        write_synthetic_sequence(cfg, seq, progress=False)
    folders = _write_variants(seq, work, kinds) if kinds else {}
    rows = []
    for kind in kinds:
        if folders[kind] is None:
            print(f"[{kind}] SKIPPED: no JPEG reader registered in dropvision.io.readers (IMAGE_SUFFIXES has no .jpg)")
            continue
        rows.append(bench_kind(kind, folders[kind], args.rounds, work, rss=not args.no_rss))
        r = rows[-1]
        print(f"[{kind}] {r['properties']}")
        print(f"[{kind}] decode ms/frame: library {r['decode_ms_library']:.2f}, dropvision {r['decode_ms_dropvision']:.2f}; "
              f"end to end frames/s: baseline {r['baseline_fps']:.0f}, dropvision {r['dropvision_fps']:.0f}, "
              f"speed-up {r['speedup']:.2f}x ({r['speedup_range'][0]:.2f}-{r['speedup_range'][1]:.2f}); "
              f"peak RSS {r['peak_rss_mb_n']:.0f} MB at N={r['frames']}, {r['peak_rss_mb_3n']:.0f} MB at 3N", flush=True)
    if not args.no_cli and "pillow" in folders and folders["pillow"] is not None:
        walls = []
        with tempfile.TemporaryDirectory() as out:
            for i in range(args.rounds):  # CLI wall time on 2 workers, interpreter start-up included
                t = time.perf_counter()
                subprocess.run([sys.executable, "-m", "dropvision.app.cli", "measure", str(folders["pillow"]),
                                "--out", str(Path(out) / f"o{i}"), "--workers", "2"], check=True, capture_output=True, cwd=ROOT)
                walls.append(time.perf_counter() - t)
        print(f"[pillow] CLI wall time, 2 workers, start-up included: median {statistics.median(walls):.2f} s "
              f"(runs {', '.join(f'{w:.2f}' for w in walls)})")
    if rows:
        print()
        print(f"{'kind':8s} {'frames':>6s} {'dec lib ms':>10s} {'dec ours ms':>11s} {'base fps':>8s} {'ours fps':>8s} "
              f"{'speed-up':>8s} {'RSS N MB':>8s} {'RSS 3N MB':>9s}  file")
    for r in rows:
        print(f"{r['kind']:8s} {r['frames']:6d} {r['decode_ms_library']:10.2f} {r['decode_ms_dropvision']:11.2f} "
              f"{r['baseline_fps']:8.0f} {r['dropvision_fps']:8.0f} {r['speedup']:7.2f}x {r['peak_rss_mb_n']:8.0f} "
              f"{r['peak_rss_mb_3n']:9.0f}  {r['properties']}")
    if tiers:
        trows = bench_tiers(tiers, args.frames, args.rounds, work, args.profile_tier, args.stages)
        print(f"\nrealism tiers: pipeline only (frames in memory, no decoding, one thread), 640x1024 canonical, "
              f"{args.frames} frames, medians of {args.rounds} alternated rounds")
        print(f"{'tier':13s} {'frames/s':>8s} {'vs clean':>8s}  rounds (frames/s); file")
        for r in trows:
            vs = f"{100 * r['slowdown_vs_clean']:+7.0f}%" if r["slowdown_vs_clean"] is not None else "       -"
            print(f"{r['tier']:13s} {r['pipeline_fps']:8.0f} {vs}  {', '.join(f'{x:.0f}' for x in r['fps_all'])}; {r['file']}")
        print("(vs clean: extra time per frame, median over rounds of the ratio to clean in the same round; "
              "goal <= +20 %)")
    load = os.getloadavg()
    print(f"load average at the end: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} ({os.cpu_count()} cores)")
    tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
