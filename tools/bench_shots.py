"""Benchmark of a folder of shots (issue 30 item 4): one `dropvision measure` of 20 shots against 20
one-image runs, end to end (the command line, each one-image run on its own folder).

The 20 shots: the 8 real ../shared/realdata/watcher-dod frames as published (``images_<folder>.jpg``)
and 12 synthetic drop-watcher shots of one rig (`dropvision synth --rig watcher-blurred-holder`, 2048 x
1536 colour JPEG, u1 = 60, 70, 80 um/ms at 4 delays each, seed 1, renamed ``images_U-<u1>_k-<k>.jpg``).
All measured at --pixel-size-um 3 (the real frames' assumption; the synthetic ones' volumes are then
relative, as for any comparison alone against in the folder).

Prints: the wall times and the speed-up (CPU seconds too: the robust figure on a loaded machine), for the
20 shots and for the 8 real ones alone (one folder of the 8 against their 8 one-image runs); the per-shot
cost of a 2048 x 1536 JPEG of one rig (the marginal cost: a folder of the 12 synthetic shots against one
of 4, over the 8 more) and of one calibrated alone (a folder of the last 4 real frames, each at its own
holder place, against one of the last 2 of them, over the 2 more); per shot, the
main drop's volume alone and in the folder and their difference in units of its uncertainty; and
whether the 8 real rows of the folder of 8 meet the rules of ../shared/realdata/README.md (score.py's).

    PYTHONPATH=$PWD .venv/bin/python tools/bench_shots.py [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REALDATA = ROOT.parent / "shared" / "realdata"
if not REALDATA.is_dir():
    REALDATA = Path("/work/shared/realdata")
EXE = [sys.executable, "-m", "dropvision.app.cli"]
PIXEL = ["--pixel-size-um", "3"]


CPU = [0.0]  # CPU seconds (user + system) of the runs so far


def run(args: list[str]) -> float:
    """Wall seconds of one command line (its CPU seconds added to ``CPU``)."""
    import resource

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run(EXE + args, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    CPU[0] += (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall


def make_shots(root: Path) -> tuple[Path, Path, list[str]]:
    """(folder of the 20 shots, folder of the 8 real ones, the real names)."""
    real = root / "real8"
    both = root / "shots20"
    real.mkdir()
    both.mkdir()
    names = []
    for frame in sorted((REALDATA / "watcher-dod").glob("V*/frame.jpg")):
        name = f"images_{frame.parent.name}.jpg"
        shutil.copy(frame, real / name)
        shutil.copy(frame, both / name)
        names.append(name)
    for u1 in (60, 70, 80):
        syn = root / f"syn{u1}"
        subprocess.run(EXE + ["synth", str(syn), "--rig", "watcher-blurred-holder", "--u1", str(u1), "--delays",
                              "1200,1300,1400,1500", "--seed", "1", "--no-progress"], check=True,
                       stdout=subprocess.DEVNULL)
        for k, f in enumerate(sorted(syn.glob("f_*.jpg")), 1):
            shutil.copy(f, both / f"images_U-{u1}_k-{k}.jpg")
    return both, real, names


def make_shifted(root: Path, real: Path) -> Path:
    """A folder of 20 real-like shots of which nearly none shares a calibration: the 8 real frames and
    12 copies of them shifted by -20..+19 px across and -12..+11 px down (the holder at other places,
    re-encoded as JPEG q95): the worst case of a folder of real shots."""
    import cv2
    import numpy as np

    out = root / "shifted20"
    out.mkdir()
    frames = sorted(real.glob("*.jpg"))
    for f in frames:
        shutil.copy(f, out / f.name)
    for i in range(12):
        f = frames[i % len(frames)]
        img = cv2.imread(str(f))
        dx, dy = 9 * (i + 1) % 40 - 20, 5 * (i + 2) % 24 - 12
        moved = cv2.warpAffine(img, np.float32([[1, 0, dx], [0, 1, dy]]), (img.shape[1], img.shape[0]),
                               borderMode=cv2.BORDER_REPLICATE)
        cv2.imwrite(str(out / f"{f.stem}_copy{i}.jpg"), moved, [cv2.IMWRITE_JPEG_QUALITY, 95])
    return out


def rules(row, truth: dict) -> bool:
    """score.py's rules of a drop-watcher frame on a shots.parquet row."""
    ns = row["n_satellites"]
    sat_ok = ns is not None and not (isinstance(ns, float) and math.isnan(ns)) and int(ns) in truth["satellites_accepted"]
    v, ref = float(row["drop_volume_nl"]), truth["main_drop_volume_nl"]
    vol_ok = abs(v - ref) <= 0.03 * ref or not truth.get("main_drop_compact", True)
    att_ok = not (float(row["attached_volume_nl"]) > truth.get("attached_volume_nl_max", math.inf))
    dx = float(row["drop_x_um"])
    axis_ok = math.isfinite(dx) and abs(dx) <= truth.get("drop_axis_offset_um_max", math.inf)
    return sat_ok and vol_ok and att_ok and axis_ok


def main() -> int:
    import pandas as pd

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--keep", type=Path, help="work in this (new) folder and keep it")
    args = ap.parse_args()
    os.environ.setdefault("PYTHONPATH", str(ROOT))
    root = args.keep or Path(tempfile.mkdtemp(prefix="bench_shots_"))
    root.mkdir(parents=True, exist_ok=True)
    try:
        both, real, real_names = make_shots(root)
        images = sorted(both.glob("*.jpg"))
        c0 = CPU[0]
        t_folder = run(["measure", str(both), "--out", str(root / "out20")] + PIXEL)
        c_folder, c0 = CPU[0] - c0, CPU[0]
        t_alone = t_alone8 = c_alone8 = 0.0
        alone = {}
        for i, image in enumerate(images):
            one = root / f"alone{i:02d}"
            one.mkdir()
            shutil.copy(image, one / image.name)
            c1 = CPU[0]
            t = run(["measure", str(one), "--out", str(root / f"out{i:02d}")] + PIXEL)
            t_alone += t
            if image.name in real_names:
                t_alone8 += t
                c_alone8 += CPU[0] - c1
            alone[image.name] = pd.read_parquet(root / f"out{i:02d}" / "frames.parquet").iloc[0]
        c_alone = CPU[0] - c0
        # the marginal cost of a shot of one rig: 12 synthetic shots against 4
        syn12, syn4 = root / "syn12", root / "syn4"
        syn12.mkdir()
        syn4.mkdir()
        synthetic = [p for p in images if p.name.startswith("images_U-")]
        for k, p in enumerate(synthetic):
            shutil.copy(p, syn12 / p.name)
            if k % 3 == 0:
                shutil.copy(p, syn4 / p.name)
        c0 = CPU[0]
        t12 = run(["measure", str(syn12), "--out", str(root / "o12")] + PIXEL)
        c12, c0 = CPU[0] - c0, CPU[0]
        t4 = run(["measure", str(syn4), "--out", str(root / "o4")] + PIXEL)
        c4 = CPU[0] - c0
        c0 = CPU[0]
        t8 = run(["measure", str(real), "--out", str(root / "out8")] + PIXEL)
        c8 = CPU[0] - c0
        # the marginal cost of a shot calibrated alone: the last 4 real frames (4 holder places) against 2
        own4, own2 = root / "own4", root / "own2"
        own4.mkdir()
        own2.mkdir()
        for k, name in enumerate(sorted(real_names)[-4:]):
            shutil.copy(real / name, own4 / name)
            if k >= 2:
                shutil.copy(real / name, own2 / name)
        c0 = CPU[0]
        t_own4 = run(["measure", str(own4), "--out", str(root / "oo4")] + PIXEL)
        c_own4, c0 = CPU[0] - c0, CPU[0]
        t_own2 = run(["measure", str(own2), "--out", str(root / "oo2")] + PIXEL)
        c_own2 = CPU[0] - c0
        # the worst case: 20 real-like shots, nearly each at its own holder place (calibrated alone)
        shifted = make_shifted(root, real)
        c0 = CPU[0]
        t_shift_alone = 0.0
        for i, image in enumerate(sorted(shifted.glob("*.jpg"))):
            one = root / f"shifted_alone{i:02d}"
            one.mkdir()
            shutil.copy(image, one / image.name)
            t_shift_alone += run(["measure", str(one), "--out", str(root / f"shifted_out{i:02d}")] + PIXEL)
        c_shift_alone, c0 = CPU[0] - c0, CPU[0]
        t_shift = run(["measure", str(shifted), "--out", str(root / "shifted_folder")] + PIXEL)
        c_shift = CPU[0] - c0
        n_shared = sum(bool(s.get("shared_calibration")) for s in
                       json.loads((root / "shifted_folder" / "summary.json").read_text())["shots"])
        print(f"20 real-like shots (8 real + 12 shifted copies; {n_shared} of 20 share a calibration, the others "
              f"calibrated alone): 20 one-image runs {t_shift_alone:.1f} s wall ({c_shift_alone:.1f} s CPU); one "
              f"folder run {t_shift:.1f} s wall ({c_shift:.1f} s CPU): {t_shift_alone / t_shift:.1f}x faster "
              f"({c_shift_alone / c_shift:.1f}x less CPU)")
        print(f"20 shots (8 real watcher-dod + 12 synthetic watcher-blurred-holder, 2048x1536 JPEG), "
              f"{os.cpu_count()} CPUs, workers 2:")
        print(f"  20 one-image runs {t_alone:.1f} s wall ({c_alone:.1f} s CPU); one folder run {t_folder:.1f} s wall "
              f"({c_folder:.1f} s CPU): {t_alone / t_folder:.1f}x faster ({c_alone / c_folder:.1f}x less CPU)")
        print(f"  the 8 real shots alone: 8 one-image runs {t_alone8:.1f} s wall ({c_alone8:.1f} s CPU); one folder run "
              f"{t8:.1f} s wall ({c8:.1f} s CPU): {t_alone8 / t8:.1f}x faster ({c_alone8 / c8:.1f}x less CPU)")
        print(f"  per shot of one rig (2048x1536 JPEG): {1000 * (t12 - t4) / 8:.0f} ms wall, {1000 * (c12 - c4) / 8:.0f} ms "
              f"CPU (folder of 12 against folder of 4, over the 8 more); calibrated alone "
              f"{1000 * (t_own4 - t_own2) / 2:.0f} ms wall, {1000 * (c_own4 - c_own2) / 2:.0f} ms CPU; one-image run "
              f"{1000 * t_alone / len(images):.0f} ms wall, {1000 * c_alone / len(images):.0f} ms CPU per image")
        table = pd.read_parquet(root / "out20" / "shots.parquet").set_index("file")
        summary = json.loads((root / "out20" / "summary.json").read_text())
        shared = {s["file"]: s.get("shared_calibration") for s in summary["shots"]}
        groups = [summary["shared_calibration"]] + list(summary["shared_calibration"].get("others", []))
        print(f"  {len(groups)} shared calibration(s) (references "
              + ", ".join(str(g["reference"]) for g in groups) + "); "
              f"{sum(bool(v) for v in shared.values())} of {len(shared)} shots measured with one")
        print(f"  {'shot':<62} {'shared':>6} {'alone nl':>10} {'folder nl':>10} {'u nl':>7} {'diff/u':>7}")
        for name in table.index:
            a = alone[name]
            row = table.loc[name]
            u = float(row["drop_volume_uncertainty_nl"])
            diff = (float(row["drop_volume_nl"]) - float(a["drop_volume_nl"])) / u if u > 0 else math.nan
            print(f"  {name:<62} {str(shared.get(name)):>6} {float(a['drop_volume_nl']):>10.4f} "
                  f"{float(row['drop_volume_nl']):>10.4f} {u:>7.4f} {diff:>+7.2f}")
        t8 = pd.read_parquet(root / "out8" / "shots.parquet").set_index("file")
        s8 = json.loads((root / "out8" / "summary.json").read_text())
        shared8 = {s["file"]: s.get("shared_calibration") for s in s8["shots"]}
        groups8 = [s8["shared_calibration"]] + list(s8["shared_calibration"].get("others", []))
        print("  the 8 real shots as one folder (shared calibrations from "
              + "; ".join(", ".join(g["calibrated_from"]) for g in groups8) + "):")
        for name in real_names:
            a, row = alone[name], t8.loc[name]
            u = float(row["drop_volume_uncertainty_nl"])
            diff = (float(row["drop_volume_nl"]) - float(a["drop_volume_nl"])) / u if u > 0 else math.nan
            print(f"  {name:<62} {str(shared8.get(name)):>6} {float(a['drop_volume_nl']):>10.4f} "
                  f"{float(row['drop_volume_nl']):>10.4f} {u:>7.4f} {diff:>+7.2f}")
        met = 0
        for name in real_names:
            truth = json.loads((REALDATA / "watcher-dod" / name[len("images_"):-len(".jpg")] / "truth.json").read_text())
            ok = rules(t8.loc[name], truth)
            met += ok
            if not ok:
                print(f"  FAIL {name}: {t8.loc[name, ['drop_volume_nl', 'n_satellites', 'drop_x_um']].to_dict()}")
        print(f"  the 8 real shots as one folder: {met} of 8 meet score.py's rules")
        return 0 if met == len(real_names) else 1
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
