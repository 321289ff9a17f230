"""`dropvision synth OUT ...`: write a synthetic strobe sequence with its ground truth."""

from __future__ import annotations

import argparse
import time

from identify.app.errors import UsageError

__all__ = ["register", "run"]


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size {text!r}: expected WIDTHxHEIGHT, e.g. 640x1024") from None
    return w, h


def register(subparsers) -> argparse.ArgumentParser:
    """Add the ``synth`` sub-command."""
    p = subparsers.add_parser(
        "synth", help="write a physics-driven synthetic strobe sequence with exact ground truth",
        description=__doc__.splitlines()[0])
    p.add_argument("out", help="output sequence folder (replaced only if it holds nothing but an earlier "
                   "result of ours)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing OUT folder and everything in it")
    p.add_argument("--u1", type=float, default=70.0, help="stroke velocity u1 (µm/ms), default 70")
    p.add_argument("--u2", type=float, default=25.0, help="stroke u2 (µm), default 25")
    p.add_argument("--format", choices=("png", "tiff", "tiff-stack"), default="png")
    p.add_argument("--bit-depth", type=int, choices=(8, 12, 16), default=8)
    p.add_argument("--noise", type=float, default=1.0,
                   help="noise scale: 0 none, 1 default (full well 10000 e-, read noise 8 e-)")
    p.add_argument("--blur-px", type=float, default=0.8, help="Gaussian blur sigma (px)")
    p.add_argument("--tilt-deg", type=float, default=0.0, help="nozzle axis tilt in the image plane (deg)")
    p.add_argument("--drift-mrad", type=float, default=0.0, help="trajectory angle from the nozzle axis (mrad)")
    p.add_argument("--satellites", type=int, choices=(0, 1, 2), default=0)
    p.add_argument("--dust", type=int, default=2, help="dust specks near the drop path (+1 far away)")
    p.add_argument("--falloff", type=float, default=0.1, help="backlight fall-off: corner = (1 - f) x centre")
    p.add_argument("--repeats", type=int, default=1, help="frames per delay")
    p.add_argument("--delays", default="0:1800:10", help="start:stop:step (µs, stop inclusive) or a list")
    p.add_argument("--size", type=_size, default=(640, 1024), help="WIDTHxHEIGHT (px)")
    p.add_argument("--pixel-size-um", type=float, default=4.73)
    p.add_argument("--tip-row", type=float, default=None, help="nozzle tip row (default 59.4)")
    p.add_argument("--axis-col", type=float, default=None, help="axis column (default: width/2 - 0.4)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from dropvision.synth.sequence import SynthConfig, parse_delays
    from dropvision.synth.writer import write_synthetic_sequence

    w, h = args.size
    try:
        cfg = SynthConfig(
            u1_um_per_ms=args.u1, u2_um=args.u2, seed=args.seed, width_px=w, height_px=h,
            pixel_size_um=args.pixel_size_um,
            tip_row=59.4 if args.tip_row is None else args.tip_row,
            axis_col=args.axis_col,
            tilt_deg=args.tilt_deg, drift_mrad=args.drift_mrad, delays_us=parse_delays(args.delays),
            repeats=args.repeats, satellites=args.satellites, dust=args.dust, blur_px=args.blur_px,
            falloff=args.falloff, noise=args.noise, bit_depth=args.bit_depth, format=args.format)
        t0 = time.perf_counter()
        out = write_synthetic_sequence(cfg, args.out, progress=False if args.no_progress else None,
                                       overwrite=args.overwrite)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    n = len(cfg.delays_us) * cfg.repeats
    print(f"dropvision synth: wrote {n} frames to {out} in {time.perf_counter() - t0:.1f} s")
    return 0
