"""`dropvision measure SEQ_DIR --out OUT_DIR`: the command over `dropvision.measurement.measure_sequence`.

The library is imported when the command runs, so that ``dropvision --help`` stays fast.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from identify.app.errors import UsageError
from identify.app.rerun_stream import add_rerun_args


def _run(args: argparse.Namespace) -> int:
    # the measurement (numpy, pandas, OpenCV, numba) is imported when the command runs, not for --help
    from dropvision.app.rerun_log import logger_from_args
    from dropvision.config import MeasureConfig
    from dropvision.measurement import measure_sequence

    seq = Path(args.seq_dir)
    if not seq.exists():
        raise UsageError(f"{seq}: no such folder")
    config = MeasureConfig(workers=args.workers)
    logger = logger_from_args(args, "dropvision", recording_name=seq.resolve().name)
    try:
        res = measure_sequence(seq, args.out, config, progress=args.progress, csv=args.csv, logger=logger,
                               overwrite=args.overwrite)
    finally:
        if logger is not None:
            logger.close()
    s = res.summary
    print(f"measured {s['n_measured']} of {s['n_frames']} frames -> {args.out}; pinch-off {s['pinchoff_us']} us, "
          f"in-flight volume {s['inflight_volume_nl']:.4g} nl, jetting velocity {s['jetting_velocity_m_s']:.4g} m/s"
          + (f"; {len(s['errors'])} frame(s) skipped" if s["errors"] else ""))
    return 0


def register(subparsers) -> None:
    """Add the ``measure`` sub-command."""
    p = subparsers.add_parser("measure", help="measure drop volumes, pinch-off and velocities of a strobe sequence")
    p.add_argument("seq_dir", help="sequence folder (with sequence.json or delay-named frames)")
    p.add_argument("--out", required=True, help="output folder (written atomically; never the sequence folder, "
                   "inside it or around it; an existing folder only if it holds an earlier result of ours)")
    p.add_argument("--overwrite", action="store_true",
                   help="write into an existing --out that holds other files (those are kept)")
    p.add_argument("--csv", action="store_true", help="also write frames.csv")
    p.add_argument("--workers", type=int, default=2, help="decoding/measuring threads (default 2)")
    p.add_argument("--progress", action="store_true", help="progress bar on stderr")
    add_rerun_args(p)
    p.set_defaults(func=_run)
