"""`dropvision measure SEQ_DIR --out OUT_DIR`: the command over `dropvision.measurement.measure_sequence`.

The library is imported when the command runs, so that ``dropvision --help`` stays fast.
Options override what sequence.json holds (`dropvision.app.options`); warnings are one line
each (``dropvision measure: warning: ...``).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from dropvision.app.options import (
    add_metadata_args, add_output_args, captured_warnings, grouped_warnings, overrides_from_args, print_warnings,
    progress_wanted, warning_lines,
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
    from dropvision.io.readers import IMAGE_SUFFIXES
    from dropvision.io.sequence import open_sequence
    from dropvision.analysis.shots import find_shots

    paths = [Path(p) for p in args.seq_dir]
    for p in paths:
        if not p.exists():
            raise UsageError(f"{p}: no such folder" if len(paths) == 1 else f"{p}: no such file")
    overrides, labels = overrides_from_args(args)
    config = MeasureConfig(workers=args.workers)
    shots = find_shots(paths, overrides=overrides, label_pattern=args.label_pattern)
    if shots is not None:
        if args.report is not None:
            raise UsageError(f"--report: {paths[0]} is a folder of shots; the report page is a printhead row's")
        return _run_shots(args, shots, config, overrides, labels)
    if getattr(args, "strobe_interval_us", None) is not None:
        raise UsageError(f"--strobe-interval-us: {paths[0]} is a sequence (its frames tell their delays), not a "
                         "folder of shots; a double exposure's interval is read for shots only")
    if getattr(args, "wave_template", None) is not None:
        raise UsageError(f"--waveform-template: {paths[0]} is a sequence (its frames tell their delays), not a folder "
                         "of shots whose labels give the parameters: give them in sequence.json's waveform "
                         "(template and parameters)")
    if args.label_pattern is not None:
        raise UsageError(f"--label-pattern: {paths[0]} is a sequence (its frames tell their delays), not a folder "
                         "of shots; labels are read for shots only")
    seq, only = paths[0], None
    if seq.is_file() and seq.suffix.lower() in IMAGE_SUFFIXES:  # an image file: a folder of one
        seq, only = seq.parent, [seq.name]
    # a recording inside --out would be lost with the folder's replacement; inside the input, refused
    check_side_file(getattr(args, "rerun", None), replaced=[args.out], inputs=[seq])
    logger = logger_from_args(args, "dropvision", recording_name=paths[0].resolve().name)
    with captured_warnings() as caught:
        try:
            given = (overrides, labels)  # a row's views open the sequence again
            if only is not None:
                seq = open_sequence(seq, overrides=overrides, labels=labels, only_files=only)
                overrides = labels = None  # applied when opened
            if args.report is not None:  # before any work: the page's folder may destroy nothing
                from dvcore.atomic import check_output_dir
                if Path(args.report).resolve() == Path(args.out).resolve():
                    raise UsageError(f"--report {args.report}: give a folder other than --out")
                check_output_dir(args.report, inputs=[paths[0]], overwrite=args.overwrite)
                # the page is a printhead row's: a single nozzle is refused before anything is measured or written
                from dropvision.measurement import row_plate
                if only is None:
                    seq = open_sequence(seq, overrides=overrides, labels=labels)
                    overrides = labels = None  # applied when opened
                try:
                    is_row = row_plate(seq) is not None  # measurement's own row check
                except BaseException:
                    seq.close()
                    raise
                if not is_row:
                    seq.close()
                    raise UsageError(f"--report: {paths[0]} shows one nozzle; the report page is a printhead row's "
                                     "(identify report draws a model's); nothing measured")
            res = measure_sequence(seq, args.out, config, progress=progress_wanted(args), csv=args.csv,
                                   logger=logger, overwrite=args.overwrite, overrides=overrides, labels=labels,
                                   nozzle_pitch_um=args.nozzle_pitch_um, row_limits=_row_limits(args))
            if res.summary.get("kind") == "printhead-row" and (logger is not None or args.report is not None):
                _row_views(args, res, paths[0] if only is None else paths[0].parent, given[0], given[1], only, logger)
            elif args.report is not None:
                raise UsageError(f"--report: {paths[0]} shows one nozzle; the report page is a printhead row's "
                                 "(identify report draws a model's)")
        finally:
            if logger is not None:
                logger.close()
            print_warnings("dropvision measure", warning_lines(caught, args), args)
    s = res.summary
    if args.quiet:
        return 0
    if s.get("kind") == "printhead-row":  # issue 32: one line per row
        counts = ", ".join(f"{v} {k}" for k, v in s["state_counts"].items() if v)
        pitch = "a scan" if s.get("layout") == "scan" else f"pitch {s['pitch_um']:.1f} um"
        print(f"measured {s['n_measured']} of {s['n_frames']} frames -> {args.out}; printhead row of "
              f"{s['n_nozzles']} nozzles ({counts}), {pitch}, volume CV "
              f"{s['volume_cv']:.3g} +- {s['volume_cv_uncertainty']:.2g}")
        hp = s.get("head_pass")
        if hp is not None:
            print("head PASSES the limits" if hp["pass"] else
                  f"head FAILS the limits: nozzles {', '.join(map(str, hp['failed_nozzles']))} (nozzles.parquet pass_reason)")
        sys.stdout.flush()
        return 0
    if args.verbose:
        for key in _SOURCES:
            value = s.get("orientation") if key == "orientation" else s["calibration"].get("pixel_size_um")
            # a measured pixel size to 4 significant digits (a nozzle's width gives 0.9395483127...)
            shown = (f" {value:.4g}" if isinstance(value, float) else f" {value}") if key in ("orientation", "pixel_size") else ""
            print(f"{key}{shown}: {s.get(f'{key}_source') or 'not given'}")
        for note in s.get("notes") or []:
            print(f"note: {note}")
    if s["n_frames"] == 1 and len(res.frames):  # one frame: what it shows, not a time series' NaNs
        what = _one_frame(res.frames.iloc[0])
    else:
        pinch = s.get("pinchoff_us")
        what = (f"pinch-off {pinch if pinch is None else format(float(pinch), '.4g')} us, in-flight volume {s['inflight_volume_nl']:.4g} +- "
                f"{s.get('inflight_volume_uncertainty_nl', float('nan')):.2g} nl, "
                f"jetting velocity {s['jetting_velocity_m_s']:.4g} m/s")
    print(f"measured {s['n_measured']} of {s['n_frames']} frames -> {args.out}; {what}"
          + (f"; {len(s['errors'])} frame(s) skipped" if s["errors"] else ""))
    sys.stdout.flush()
    return 0


def _run_shots(args: argparse.Namespace, shots, config, overrides, labels) -> int:
    """A folder of shots (images with no delay to tell) or several image files: one row per image."""
    from dropvision.analysis.shots import measure_shots, one_line

    from dropvision.app.rerun_log import logger_from_args

    check_side_file(getattr(args, "rerun", None), replaced=[args.out], inputs=list(shots.inputs))
    with captured_warnings() as caught:
        try:
            res = measure_shots(shots, args.out, config, overrides=overrides, option_labels=labels, csv=args.csv,
                                overwrite=args.overwrite, strobe_interval_us=args.strobe_interval_us)
            # the shots' view (issue 33): each shot as stored with its bodies, a bar per shot, the table
            logger = logger_from_args(args, "dropvision", recording_name=Path(shots.inputs[0]).resolve().name)
            if logger is not None:
                try:
                    logger.log_shots(res)
                finally:
                    logger.close()
        finally:
            print_warnings("dropvision measure", grouped_warnings(warning_lines(caught, args), {p.name for p in shots.paths}),
                           args)
    s = res.summary
    if args.quiet:
        return 0
    if args.verbose:
        for name in s["labels"]:
            print(f"label {name}: {s['label_sources'][name]}")
        for note in s["notes"]:
            print(f"note: {note}")
        for err in s["errors"]:
            print(f"skipped {err['file']}: {err['reason']}")
    print(one_line(s, args.out))
    sys.stdout.flush()
    return 0


def _positive_us(text: str) -> float:
    """A strobe interval: a finite number of µs > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of µs") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: the interval must be a finite number of µs > 0")
    return value


def register(subparsers) -> None:
    """Add the ``measure`` sub-command."""
    p = subparsers.add_parser("measure", help="measure drop volumes, pinch-off and velocities of a strobe sequence")
    p.add_argument("seq_dir", nargs="+", metavar="FOLDER_OR_IMAGES",
                   help="sequence folder (sequence.json and images, or images alone with options such as "
                   "--pixel-size-um); a folder of images with no delay to tell (one shot each, labels from their "
                   "names: shots.parquet, one row per image); or image files (one: a folder of one; several: shots)")
    p.add_argument("--label-pattern", metavar="REGEX", default=None,
                   help="shots: read the labels from the file names with this regular expression of named groups, "
                   "e.g. 'run(?P<run>\\d+)_(?P<V>[-\\d.]+)V' (default: the name-value tokens, V1--86 is V1 = -86)")
    p.add_argument("--strobe-interval-us", metavar="US", type=_positive_us, default=None,
                   help="shots: every image is a double exposure, each drop seen twice this many µs apart: the main "
                   "drop's velocity (shots.parquet drop_velocity_m_s; a strobe_interval_us column of shots.csv "
                   "gives it per image)")
    p.add_argument("--out", required=True, help="output folder (written atomically; never the sequence folder, "
                   "inside it or around it; an existing folder only if it holds an earlier result of ours)")
    p.add_argument("--overwrite", action="store_true",
                   help="write into an existing --out that holds other files (those are kept)")
    p.add_argument("--csv", action="store_true", help="also write frames.csv")
    p.add_argument("--workers", type=int, default=2, help="decoding/measuring workers (default 2): processes on Linux for 32 frames or more, else threads (always with --rerun); DROPVISION_NO_FORK=1 keeps threads")
    p.add_argument("--nozzle-pitch-um", type=float, default=None, metavar="UM",
                   help="a printhead row's nozzle pitch (µm; default: sequence.json nozzle_pitch_um, else estimated "
                        "from the nozzles found)")
    p.add_argument("--nozzle-count", type=int, default=None, metavar="N",
                   help="a printhead row's number of nozzles (default: sequence.json nozzle_count): a nozzle missing "
                        "at either end of the row is found where the frame holds the grid on one side only; without "
                        "it the ends cannot be judged")
    for key, unit in (("volume-tolerance-percent", "%"), ("velocity-tolerance-percent", "%"),
                      ("angle-limit-mrad", "mrad")):
        p.add_argument(f"--{key}", type=float, default=None, metavar=unit.upper() if unit == "mrad" else "PCT",
                       help=f"a printhead row's pass/fail limit ({unit.replace('%', '%%')}; default: sequence.json "
                       f"{key.replace('-', '_')}): nozzles.parquet pass, summary.json head_pass")
    p.add_argument("--report", type=Path, default=None, metavar="DIR",
                   help="a printhead row: write a report page there (index.html with the nozzle map, the first frame "
                   "with each nozzle's axis and bodies, the nozzles table)")
    p.add_argument("--reference-nozzles", default=None, metavar="PATH",
                   help="a printhead row: a reference head's nozzles.parquet; the limits apply to each nozzle's "
                   "difference from its reference nozzle (default: sequence.json reference_nozzles; without it "
                   "volume and velocity are compared with the row's median, the angle with the plate normal)")
    add_output_args(p)
    add_metadata_args(p)
    add_rerun_args(p)
    p.set_defaults(func=_run)


def _row_views(args, res, folder, overrides, labels, only, logger) -> None:
    """A printhead row's views: its frames and nozzle map in the Rerun recording, its report page."""
    from dropvision.app.row_views import log_row, write_row_report
    from dropvision.io.sequence import open_sequence

    seq = open_sequence(folder, overrides=overrides, labels=labels, only_files=only)
    first: list = []  # the first readable frame's image (the report's), kept as the frames stream by

    def frames(count: int):
        for k in range(count):
            fr = seq.read(k)
            if fr.error is None:
                if not first:
                    first.append(fr.image)
                yield k, fr.ref.delay_us, fr.image

    try:  # the frames logged one at a time, none held
        if logger is not None:
            log_row(logger, res.nozzles, res.bodies, res.summary, frames(len(seq)))
        elif args.report is not None:
            for _ in frames(1):
                pass
    finally:
        seq.close()
    if args.report is not None:
        write_row_report(args.report, res.nozzles, res.bodies, res.summary, first[0] if first else None,
                         overwrite=args.overwrite)


def _row_limits(args) -> dict:
    """The row's pass/fail options (None: not given)."""
    return {k: getattr(args, k, None) for k in ("volume_tolerance_percent", "velocity_tolerance_percent",
                                                  "angle_limit_mrad", "reference_nozzles", "nozzle_count")}


def _one_frame(row) -> str:
    """The one-line result of a single frame (a shot, a pendant drop): its main drop and
    satellites, the liquid hanging from the nozzle, its quality (frames.parquet has the rest)."""
    import math

    parts = []
    v, u = float(row["drop_volume_nl"]), float(row["drop_volume_uncertainty_nl"])
    if math.isfinite(v):
        n = int(row["n_satellites"])
        parts.append(f"main drop {v:.4g} +- {u:.2g} nl, {n} satellite{'' if n == 1 else 's'}")
    a, ua = float(row["attached_volume_nl"]), float(row["attached_volume_uncertainty_nl"])
    if math.isfinite(a) and (a > 0 or not parts):
        parts.append(f"attached volume {a:.4g} +- {ua:.2g} nl")
    return "; ".join(parts or ["nothing measured"]) + f"; quality {row['quality']}"
