"""`dropvision watch FOLDER --out OUT`: measure frames as a drop watcher writes them
(`dropvision.app.watch.watch_sequence`).

The library is imported when the command runs, so that ``dropvision --help`` stays fast.
Ctrl-C (or SIGTERM) ends the sequence: the final tables are written from the frames complete
by then; what was measured before is in ``OUT/live/frames.jsonl`` whatever happens.
"""

from __future__ import annotations

import argparse
import signal
import statistics
import sys
from pathlib import Path

from dropvision.app.options import add_metadata_args, captured_warnings, overrides_from_args, print_warnings, \
    warning_lines
from identify.app.errors import UsageError
from identify.app.rerun_stream import add_rerun_args


def _interrupt(signum, frame):  # SIGTERM ends the sequence as Ctrl-C does
    raise KeyboardInterrupt


def _run(args: argparse.Namespace) -> int:
    from dropvision.app.rerun_log import logger_from_args
    from dropvision.app.watch import WatchOptions, watch_sequence
    from dropvision.config import MeasureConfig

    folder = Path(args.folder)
    if not folder.is_dir():
        raise UsageError(f"{folder}: no such folder")
    for name in ("frames", "idle_s", "settle_s"):
        value = getattr(args, name)
        if value is not None and not value > 0:
            raise UsageError(f"--{name.replace('_', '-')}: must be > 0, got {value:g}")
    overrides, labels = overrides_from_args(args)
    options = WatchOptions(frames=args.frames, idle_s=args.idle_s, settle_s=args.settle_s,
                           config=MeasureConfig(workers=args.workers), csv=args.csv, overwrite=args.overwrite,
                           overrides=overrides, labels=labels)
    logger = logger_from_args(args, "dropvision", recording_name=folder.resolve().name)

    def report(row: dict) -> None:
        if args.verbose:
            print(f"{row['file']}: delay {row['delay_us']:g} us, attached {row['attached_volume_nl'] or 0:.4g} nl, "
                  f"{row['n_detached']} detached, row on disk {row['latency_ms']:.0f} ms after the file's last change"
                  + (f"; {row['error']}" if row.get("error") else ""), flush=True)

    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        with captured_warnings() as caught:
            try:
                res = watch_sequence(folder, args.out, options, logger=logger, report=report)
            finally:
                if logger is not None:
                    logger.close()
                print_warnings("dropvision watch", warning_lines(caught), args)
    finally:
        signal.signal(signal.SIGTERM, previous)
    if args.quiet:
        return 0
    s = res.result.summary
    lat = (f"row on disk {statistics.median(res.latency_ms):.0f} ms (median), {max(res.latency_ms):.0f} ms (max) "
           f"after each of the {len(res.latency_ms)} frames written while watching was complete"
           if res.latency_ms else "no frame written while watching")
    print(f"watched {s['n_measured']} of {s['n_frames']} frames ({res.n_live} live, {res.n_resumed} from the "
          f"journal; ended by {res.ended_by}) -> {args.out}; {lat}; pinch-off {s['pinchoff_us']} us, in-flight "
          f"volume {s['inflight_volume_nl']:.4g} nl"
          + (f"; still being written, left out: {', '.join(res.left_out)}" if res.left_out else ""))
    sys.stdout.flush()
    return 0


def register(subparsers) -> None:
    """Add the ``watch`` sub-command."""
    p = subparsers.add_parser("watch", help="measure a sequence folder while a drop watcher writes its frames")
    p.add_argument("folder", help="sequence folder being written (never written to)")
    p.add_argument("--out", required=True, help="output folder: live/frames.jsonl grows as frames are measured, "
                   "the tables of `dropvision measure` at the end; an earlier watch of the same folder is resumed")
    p.add_argument("--frames", type=int, default=None, metavar="N",
                   help="end after N frames (default: the length of sequence.json's frames list, if any)")
    p.add_argument("--idle-s", type=float, default=None, metavar="S",
                   help="end after S seconds without a new frame (default: wait for --frames or Ctrl-C)")
    p.add_argument("--settle-s", type=float, default=0.05, metavar="S",
                   help="a frame is complete once unchanged for S seconds (or closed by its writer) and "
                        "decodable (default 0.05)")
    p.add_argument("--overwrite", action="store_true",
                   help="write into an existing --out that holds other files (those are kept)")
    p.add_argument("--csv", action="store_true", help="also write frames.csv")
    p.add_argument("--workers", type=int, default=2, help="decoding/measuring threads of the final measurement "
                   "(default 2, as dropvision measure; frames are measured live one at a time)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    g.add_argument("-v", "--verbose", action="store_true", help="also print one line per frame as it is measured")
    add_metadata_args(p)
    add_rerun_args(p)
    p.set_defaults(func=_run)
