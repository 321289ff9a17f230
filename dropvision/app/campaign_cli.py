"""`dropvision campaign` and `dropvision synth-campaign`: the commands over `dropvision.app.campaign`.

The library is imported when a command runs, not when the parser is built, so that
``dropvision --help`` stays fast (measured: docs/explanation/speed.md, start-up).
"""

from __future__ import annotations

import argparse
import sys

from dropvision.app.options import (
    add_metadata_args, add_output_args, captured_warnings, is_colour_note, overrides_from_args, print_warnings, progress_wanted,
    warning_lines,
)
from dvcore.errors import UsageError
from dvcore.rerun_options import add_rerun_args, options_from_args


def _add_executor_args(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, default=None, help="local worker processes (default: all cores; 1 = serial)")
    g.add_argument("--dask-local", type=int, default=None, metavar="N", help="start a Dask LocalCluster with N workers")
    g.add_argument("--scheduler", default=None, metavar="tcp://HOST:8786", help="use an existing Dask cluster")


def _run_campaign_cmd(args) -> int:
    from dropvision.app.campaign import run_campaign  # heavy (numpy, pandas): only when run, not for --help

    overrides, labels = overrides_from_args(args)
    with captured_warnings() as caught:
        try:
            res = run_campaign(
                args.root, args.out, workers=args.workers, dask_local=args.dask_local, scheduler=args.scheduler,
                progress=progress_wanted(args), rerun_options=options_from_args(args, "dropvision"),
                overwrite=args.overwrite, overrides=overrides, labels=labels,
            )
        except (FileNotFoundError, ValueError, RuntimeError) as exc:
            raise UsageError(str(exc)) from exc
        finally:
            print_warnings("dropvision campaign", warning_lines(caught, args), args)
    # the sequences' own warnings (measured in workers): one line each, once per sequence
    print_warnings("dropvision campaign", [f"{sid}: {text}" for sid, texts in sorted(res.warnings.items())
                                           for text in texts if args.verbose or not is_colour_note(text)], args)
    if args.quiet:
        return 0
    print(
        f"campaign: {len(res.measured)} measured, {len(res.skipped)} unchanged (skipped), "
        f"{len(res.failed)} failed -> {res.dataset_dir}" + _shots_text(res.dataset_dir)
    )
    for sid, err in sorted(res.failed.items()):
        print(f"  failed {sid}: {err}")
    if args.verbose:
        for sid in sorted(res.measured):
            print(f"  measured {sid}")
        for sid in sorted(res.skipped):
            print(f"  unchanged {sid}")
    return 0


def _shots_text(dataset_dir) -> str:
    """``; shots.parquet: N rows from M shot folders`` where the campaign held shot folders."""
    import json
    from pathlib import Path

    try:
        doc = json.loads((Path(dataset_dir) / "dataset.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return ""
    if not isinstance(doc, dict) or doc.get("n_shots") is None:
        return ""
    return f"; shots.parquet: {doc['n_shots']} rows from {len(doc.get('shot_folders') or [])} shot folder(s)"


def _run_synth_campaign_cmd(args) -> int:
    from dropvision.app.campaign import parse_range, synth_campaign

    try:
        u1 = parse_range(args.u1, "--u1")
        u2 = parse_range(args.u2, "--u2")
    except ValueError as exc:
        raise UsageError(str(exc)) from exc
    paths = synth_campaign(args.out, u1, u2, repeats_per_point=args.repeats_per_point, seed=args.seed,
                           workers=args.workers, progress=not args.no_progress and sys.stderr.isatty(),
                           overwrite=args.overwrite)
    print(f"synth-campaign: {len(paths)} sequences in {args.out}")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser("campaign", help="measure every sequence (and shot folder) below ROOT into a dataset")
    p.add_argument("root", help="campaign root folder (every folder with a sequence.json is a sequence; every "
                   "folder of images with no delay to tell is a shot folder, its rows in OUT/shots.parquet)")
    p.add_argument("--out", required=True, help="dataset folder to write (re-running resumes); never a sequence "
                   "folder, inside one or around one")
    p.add_argument("--overwrite", action="store_true",
                   help="write into an existing --out that holds other files (those are kept)")
    _add_executor_args(p)
    add_output_args(p)
    add_metadata_args(p)
    add_rerun_args(p)
    p.set_defaults(func=_run_campaign_cmd)

    s = subparsers.add_parser("synth-campaign", help="render a synthetic campaign grid with truth")
    s.add_argument("out", help="output folder (one sequence folder per grid point)")
    s.add_argument("--u1", default="50:80:5", help="stroke velocities um/ms, start:stop:step or list (default 50:80:5)")
    s.add_argument("--u2", default="20:35:2.5", help="strokes um, start:stop:step or list (default 20:35:2.5)")
    s.add_argument("--repeats-per-point", type=int, default=1, help="sequences per (u1, u2)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--workers", type=int, default=None)
    s.add_argument("--overwrite", action="store_true",
                   help="write into an existing OUT holding other files; same-named sequences are replaced")
    s.add_argument("--no-progress", action="store_true")
    s.set_defaults(func=_run_synth_campaign_cmd)
