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
from dvcore.errors import UsageError
from dvcore.atomic import check_side_file
from dvcore.rerun_options import add_rerun_args


def _interrupt(signum, frame):  # SIGTERM ends the sequence as Ctrl-C does
    raise KeyboardInterrupt


#: Signals that end a watch cleanly (final tables of the frames so far). SIGINT is set
#: explicitly: a process started in the background by a non-interactive shell inherits SIGINT
#: ignored, and `kill -INT` would then do nothing.
_ENDING_SIGNALS = (signal.SIGTERM, signal.SIGINT)


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
    # a recording inside the watched folder or inside an OUT replaced at the end: refused before any work
    check_side_file(getattr(args, "rerun", None), replaced=[] if args.sequences else [args.out], inputs=[folder])
    overrides, labels = overrides_from_args(args)
    options = WatchOptions(frames=args.frames, idle_s=args.idle_s, settle_s=args.settle_s,
                           config=MeasureConfig(workers=args.workers), csv=args.csv, overwrite=args.overwrite,
                           overrides=overrides, labels=labels, shots=True if args.shots else None,
                           label_pattern=args.label_pattern)
    def report(row: dict) -> None:
        if args.verbose:
            print(f"{row['file']}: delay {row['delay_us']:g} us, attached {row['attached_volume_nl'] or 0:.4g} nl, "
                  f"{row['n_detached']} detached, row on disk {row['latency_ms']:.0f} ms after the file's last change"
                  + (f"; {row['error']}" if row.get("error") else ""), flush=True)

    previous = {sig: signal.signal(sig, _interrupt) for sig in _ENDING_SIGNALS}
    try:
        with captured_warnings() as caught:
            try:
                if args.sequences:
                    return _run_sequences(args, folder, options, report)
                logger = logger_from_args(args, "dropvision", recording_name=folder.resolve().name)
                try:
                    res = watch_sequence(folder, args.out, options, logger=logger, report=report)
                finally:
                    if logger is not None:
                        logger.close()
            finally:
                print_warnings("dropvision watch", warning_lines(caught, args), args)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if not args.quiet:
        print(_summary_line(res, args.out), flush=True)
    return 0


def _summary_line(res, out) -> str:
    """One line: frames, how the sequence ended, latency, the main results."""
    s = res.result.summary
    if res.kind == "shots":
        from dropvision.analysis.shots import one_line

        lat = (f"row on disk {statistics.median(res.latency_ms):.0f} ms (median), {max(res.latency_ms):.0f} ms (max) "
               f"after each of the {len(res.latency_ms)} images written while watching was complete"
               if res.latency_ms else "no image written while watching")
        return (f"watched {s['n_shots']} shots ({res.n_live} live, {res.n_resumed} from the journal; ended by "
                f"{res.ended_by}); {lat}; {one_line(s, out)}"
                + (f"; still being written, left out: {', '.join(res.left_out)}" if res.left_out else ""))
    lat = (f"row on disk {statistics.median(res.latency_ms):.0f} ms (median), {max(res.latency_ms):.0f} ms (max) "
           f"after each of the {len(res.latency_ms)} frames written while watching was complete"
           if res.latency_ms else "no frame written while watching")
    if s.get("kind") == "printhead-row":  # issue 32: nozzles.parquet, no single drop's pinch-off
        counts = ", ".join(f"{v} {k}" for k, v in s["state_counts"].items() if v)
        what = f"printhead row of {s['n_nozzles']} nozzles ({counts}), volume CV {s['volume_cv']:.3g}"
    else:
        what = f"pinch-off {s['pinchoff_us']} us, in-flight volume {s['inflight_volume_nl']:.4g} nl"
    return (f"watched {s['n_measured']} of {s['n_frames']} frames ({res.n_live} live, {res.n_resumed} from the "
            f"journal; ended by {res.ended_by}) -> {out}; {lat}; {what}"
            + (f"; still being written, left out: {', '.join(res.left_out)}" if res.left_out else ""))


def _run_sequences(args: argparse.Namespace, root: Path, options, report) -> int:
    """``--sequences``: one sequence per sub-folder, one after the other, into OUT/<name>."""
    from dropvision.app.rerun_log import RerunLogger
    from dropvision.app.watch import watch_sequences
    from dvcore.rerun_options import options_from_args

    rerun = options_from_args(args, "dropvision")
    if rerun is not None:
        rerun = rerun.start_viewer()  # a viewer that cannot start: warned, work goes on
    logger_for = None if rerun is None or not rerun.enabled else (lambda name: RerunLogger(rerun.for_sequence(name)))

    def announce(name: str, res) -> None:
        if isinstance(res, Exception):
            print(f"dropvision watch: error: {res}", file=sys.stderr, flush=True)
        elif not args.quiet:
            print(f"{name}: {_summary_line(res, Path(args.out) / name)}", flush=True)

    _results, failed = watch_sequences(root, args.out, options, logger_for=logger_for, report=report,
                                       announce=announce)
    return 2 if failed else 0


def register(subparsers) -> None:
    """Add the ``watch`` sub-command."""
    p = subparsers.add_parser("watch", help="measure a sequence folder (or shots) while a drop watcher writes them")
    p.add_argument("folder", help="sequence folder (or folder of shots) being written (never written to)")
    p.add_argument("--out", required=True, help="output folder: live/frames.jsonl grows as frames are measured, "
                   "the tables of `dropvision measure` at the end; an earlier watch of the same folder is resumed")
    p.add_argument("--sequences", action="store_true",
                   help="FOLDER receives one sequence per sub-folder, one after the other: each is watched in turn "
                        "into OUT/<name> (it ends at its frame count, --idle-s without a frame, or when a later "
                        "sub-folder appears); the watch ends --idle-s after the last one, or on Ctrl-C")
    p.add_argument("--shots", action="store_true",
                   help="FOLDER receives one image per shot (a drop watcher's exports, no delay in the names): each "
                        "measured alone as it lands, its row appended to OUT/shots.parquet; at the end the tables of "
                        "`dropvision measure FOLDER` (default: shots when the first image tells no delay and no "
                        "frames list or frame rate is given)")
    p.add_argument("--label-pattern", metavar="REGEX", default=None,
                   help="shots: read the labels from the file names with this regular expression of named groups "
                        "(as dropvision measure)")
    p.add_argument("--frames", type=int, default=None, metavar="N",
                   help="end after N frames (shots: N images; default: the length of sequence.json's frames list, if "
                        "any)")
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
