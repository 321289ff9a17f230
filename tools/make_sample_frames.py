"""Regenerate the committed synthetic sample sequences in sample_frames/ (deterministic).

    .venv/bin/python tools/make_sample_frames.py [--out sample_frames] [--only NAME ...]

Each folder is a complete strobe sequence (sequence.json + images) with its ground truth
(truth.json, truth_frames.csv), written by `dropvision.synth.write_synthetic_sequence`.
Crops and noise are chosen to keep the whole folder under 20 MB (see sample_frames/README.md).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from dropvision.synth import SynthConfig, parse_delays, write_synthetic_sequence

ROOT = Path(__file__).resolve().parents[1]

#: name -> configuration of each sample sequence.
SAMPLES = {
    # The paper's colour ink at u1 = 70 µm/ms, u2 = 25 µm: full 10 µs strobe sequence, 8-bit PNG.
    "colour_ink_u70_u25": SynthConfig(
        u1_um_per_ms=70.0, u2_um=25.0, seed=70025, width_px=224, height_px=704, tip_row=59.4,
        axis_col=111.6, delays_us=parse_delays("0:1800:10"), noise=0.25, falloff=0.1, dust=2,
        bit_depth=8, format="png"),
    # One satellite, dust (two near the path + one far), 16-bit multi-page TIFF every 20 µs.
    "satellite_dust_tiff16": SynthConfig(
        u1_um_per_ms=70.0, u2_um=25.0, seed=1, width_px=176, height_px=512, tip_row=40.7,
        axis_col=87.3, delays_us=parse_delays("940:1660:20"), satellites=1, dust=2, dust_far=True,
        noise=0.5, falloff=0.3, bit_depth=16, format="tiff-stack"),
    # Another waveform, nozzle tilted by 1 degree, 5 mrad trajectory drift, 8-bit PNG every 20 µs.
    "u55_u30": SynthConfig(
        u1_um_per_ms=55.0, u2_um=30.0, seed=5530, width_px=192, height_px=640, tip_row=52.8,
        axis_col=95.2, tilt_deg=1.0, drift_mrad=5.0, delays_us=parse_delays("0:1800:20"),
        noise=0.25, falloff=0.15, dust=1, bit_depth=8, format="png"),
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "sample_frames")
    ap.add_argument("--only", nargs="*", choices=sorted(SAMPLES), default=None)
    args = ap.parse_args(argv)
    for name in args.only or SAMPLES:
        t0 = time.perf_counter()
        out = write_synthetic_sequence(SAMPLES[name], args.out / name, progress=False, overwrite=True)
        size = sum(p.stat().st_size for p in out.iterdir()) / 1e6
        print(f"{name}: {len(SAMPLES[name].delays_us)} frames, {size:.1f} MB, "
              f"{time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
