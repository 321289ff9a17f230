"""`dropvision measure SEQ_DIR --out OUT_DIR`: the command over `dropvision.measurement.measure_sequence`.

The library is imported when the command runs, so that ``dropvision --help`` stays fast.
Options override what sequence.json holds (`dropvision.app.options`); warnings are one line
each (``dropvision measure: warning: ...``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dropvision.app.options import (
    add_metadata_args, add_output_args, captured_warnings, overrides_from_args, print_warnings, progress_wanted,
    warning_lines,
)
from dvcore.atomic import check_side_file
from dvcore.errors import UsageError
from dvcore.rerun_options import add_rerun_args

_SOURCES = ("orientation", "pixel_size", "delay", "nozzle_outer_diameter", "nozzle_inner_diameter", "waveform",
            "bit_depth")


def _run(args: argparse.Namespace) -> int:
    # the measurement (numpy, pandas, OpenCV, numba) is imported when the command runs, not for --help
    from dropvision.app.rerun_log import logger_from_args
    from dropvision.config import MeasureConfig
    from dropvision.measurement import measure_sequence

    seq = Path(args.seq_dir)
    if not seq.exists():
        raise UsageError(f"{seq}: no such folder")
    # a recording inside --out would be lost with the folder's replacement; inside the input, refused
    check_side_file(getattr(args, "rerun", None), replaced=[args.out], inputs=[seq if seq.is_dir() else seq.parent])
    overrides, labels = overrides_from_args(args)
    config = MeasureConfig(workers=args.workers)
    logger = logger_from_args(args, "dropvision", recording_name=seq.resolve().name)
    with captured_warnings() as caught:
        try:
            res = measure_sequence(seq, args.out, config, progress=progress_wanted(args), csv=args.csv,
                                   logger=logger, overwrite=args.overwrite, overrides=overrides, labels=labels)
        finally:
            if logger is not None:
                logger.close()
            print_warnings("dropvision measure", warning_lines(caught), args)
    s = res.summary
    if args.quiet:
        return 0
    if args.verbose:
        for key in _SOURCES:
            value = s.get("orientation") if key == "orientation" else s["calibration"].get("pixel_size_um")
            shown = f" {value}" if key in ("orientation", "pixel_size") else ""
            print(f"{key}{shown}: {s.get(f'{key}_source') or 'not given'}")
        for note in s.get("notes") or []:
            print(f"note: {note}")
    print(f"measured {s['n_measured']} of {s['n_frames']} frames -> {args.out}; pinch-off {s['pinchoff_us']} us, "
          f"in-flight volume {s['inflight_volume_nl']:.4g} +- "
          f"{s.get('inflight_volume_uncertainty_nl', float('nan')):.2g} nl, "
          f"jetting velocity {s['jetting_velocity_m_s']:.4g} m/s"
          + (f"; {len(s['errors'])} frame(s) skipped" if s["errors"] else ""))
    sys.stdout.flush()
    return 0


def register(subparsers) -> None:
    """Add the ``measure`` sub-command."""
    p = subparsers.add_parser("measure", help="measure drop volumes, pinch-off and velocities of a strobe sequence")
    p.add_argument("seq_dir", help="sequence folder (sequence.json and images, or images alone with options such "
                   "as --pixel-size-um)")
    p.add_argument("--out", required=True, help="output folder (written atomically; never the sequence folder, "
                   "inside it or around it; an existing folder only if it holds an earlier result of ours)")
    p.add_argument("--overwrite", action="store_true",
                   help="write into an existing --out that holds other files (those are kept)")
    p.add_argument("--csv", action="store_true", help="also write frames.csv")
    p.add_argument("--workers", type=int, default=2, help="decoding/measuring workers (default 2): processes on Linux for 32 frames or more, else threads (always with --rerun); DROPVISION_NO_FORK=1 keeps threads")
    add_output_args(p)
    add_metadata_args(p)
    add_rerun_args(p)
    p.set_defaults(func=_run)
