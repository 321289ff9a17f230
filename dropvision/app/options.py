"""Options shared by the commands that read sequences (`measure`, `campaign`, `init`).

- `add_metadata_args` / `overrides_from_args`: one option per key of sequence.json
  (docs/FORMAT.md); a given option overrides the file, passes the same validation
  (`dropvision.io.sequence.check_overrides`) and is named in summary.json (``*_source``:
  "command line --pixel-size-um").
- `add_output_args` / `progress_wanted`: ``--quiet``, ``--verbose``, ``--progress`` /
  ``--no-progress`` (default: a progress bar when stderr is a terminal).
- `captured_warnings` / `print_warnings`: library warnings become one line each,
  ``dropvision measure: warning: <file>: <message>``, without source lines or tracebacks.

Only the standard library is imported here (``dropvision --help`` stays fast).
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import warnings

#: (option, sequence.json key, type, help); waveform options are collected into ``waveform``.
_METADATA_OPTIONS = (
    ("--pixel-size-um", "pixel_size_um", float, "pixel size in µm (object plane)"),
    ("--nozzle-outer-diameter-um", "nozzle_outer_diameter_um", float,
     "nozzle outer diameter in µm; without a pixel size, the pixel size is this diameter over the nozzle's "
     "outer width measured in the first frame (px)"),
    ("--nozzle-inner-diameter-um", "nozzle_inner_diameter_um", float, "nozzle inner diameter in µm (flow velocity)"),
    ("--delay-us", "delay_us", float, "strobe delay of a sequence of ONE frame, or of every image of a folder of "
     "shots (µs after the trigger)"),
    ("--frame-rate-hz", "frame_rate_hz", float, "frame rate of a video or numbered image stack (Hz)"),
    ("--first-frame-delay-us", "first_frame_delay_us", float, "with --frame-rate-hz: delay of the trigger frame (µs)"),
    ("--trigger-frame", "trigger_frame", int, "with --frame-rate-hz: index of the frame taken at --first-frame-delay-us"),
    ("--bit-depth", "bit_depth", int, "significant bits of 16-bit images (8, 12 or 16)"),
    ("--nozzle-tip-row", "nozzle_tip_row", float, "row of the nozzle-tip centre in the stored image"),
    ("--axis-col", "axis_col", float, "column of the nozzle-tip centre in the stored image"),
)
_METAVAR = {"--pixel-size-um": "UM", "--nozzle-outer-diameter-um": "UM", "--nozzle-inner-diameter-um": "UM",
            "--delay-us": "US", "--frame-rate-hz": "HZ", "--first-frame-delay-us": "US", "--trigger-frame": "N",
            "--bit-depth": "BITS", "--nozzle-tip-row": "PX", "--axis-col": "PX"}
_WAVEFORM_OPTIONS = (
    ("--u1-um-per-ms", "u1_um_per_ms", "waveform stroke velocity u1 (µm/ms)"),
    ("--u2-um", "u2_um", "waveform stroke u2 (µm)"),
    ("--u3-um-per-ms", "u3_um_per_ms", "waveform instroke velocity u3 (µm/ms, default 2)"),
    ("--hold-us", "hold_us", "waveform hold time (µs, default 20)"),
    ("--dead-time-us", "dead_time_us", "trigger-to-piston dead time (µs, default 220)"),
)


def add_metadata_args(p: argparse.ArgumentParser) -> None:
    """Add one option per key of sequence.json (they override the file)."""
    g = p.add_argument_group("sequence metadata", "what sequence.json holds (docs/FORMAT.md); an option overrides "
                             "the file and summary.json names it as the source")
    for opt, key, typ, text in _METADATA_OPTIONS:
        g.add_argument(opt, dest=f"meta_{key}", type=typ, default=None, metavar=_METAVAR[opt], help=text)
    g.add_argument("--orientation", dest="meta_orientation", choices=("down", "up", "left", "right"), default=None,
                   help="direction the drops travel in the stored images (default: sequence.json, else detected "
                        "from the edge the nozzle or holder touches)")
    for opt, key, text in _WAVEFORM_OPTIONS:
        g.add_argument(opt, dest=f"wave_{key}", type=float, default=None,
                       metavar="UM_PER_MS" if key.endswith("per_ms") else key.rsplit("_", 1)[1].upper(), help=text)
    g.add_argument("--waveform-template", dest="wave_template", default=None, metavar="NAME",
                   help="waveform template (three_pulse, segments, trapezoid: identify.waveform) whose parameters "
                        "are each shot's labels (images_V1--86_V2-12_..._d2-5.jpg); its constants and dead time from "
                        "sequence.json's waveform of the same template")


def overrides_from_args(args: argparse.Namespace) -> tuple[dict, dict]:
    """(overrides, labels) for `dropvision.io.sequence.open_sequence` from the parsed options."""
    overrides, labels = {}, {"_caller": "command line"}  # dropvision.io.overrides.CALLER_KEY: messages name options
    for opt, key, _, _ in (*_METADATA_OPTIONS, ("--orientation", "orientation", str, "")):
        value = getattr(args, f"meta_{key}", None)
        if value is not None:
            overrides[key] = value
            labels[key] = f"command line {opt}"
    wave = {key: getattr(args, f"wave_{key}") for _, key, _ in _WAVEFORM_OPTIONS
            if getattr(args, f"wave_{key}", None) is not None}
    opts = [opt for opt, key, _ in _WAVEFORM_OPTIONS if key in wave]
    if getattr(args, "wave_template", None) is not None:
        wave["template"] = args.wave_template
        opts.insert(0, "--waveform-template")
    if wave:
        overrides["waveform"] = wave
        labels["waveform"] = "command line " + " ".join(opts)
    return overrides, labels


def add_output_args(p: argparse.ArgumentParser) -> None:
    """``--quiet``, ``--verbose``, ``--progress`` / ``--no-progress``."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors (no warnings, no progress)")
    g.add_argument("-v", "--verbose", action="store_true",
                   help="also print where each value came from and the measurement's notes")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                   help="progress bar on stderr (default: when stderr is a terminal)")


def progress_wanted(args: argparse.Namespace) -> bool:
    """The progress bar: as asked, else on a terminal unless ``--quiet``."""
    if getattr(args, "quiet", False):
        return bool(getattr(args, "progress", None))
    if getattr(args, "progress", None) is not None:
        return bool(args.progress)
    return sys.stderr.isatty()


@contextlib.contextmanager
def captured_warnings():
    """Collect the library's warnings (a list of `warnings.WarningMessage`) instead of
    printing them with their source lines."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield caught


def warning_lines(caught, args: argparse.Namespace | None = None) -> list[str]:
    """The distinct messages of captured warnings, in order (one line each).

    The note that colour images were made grey (`dropvision.io.sequence.RGBConvertedWarning`: the documented
    BT.601 rule, which changes no measurement of a backlit frame) is shown with ``--verbose`` only: a
    drop watcher's colour files would otherwise repeat it on every run."""
    out = []
    verbose = args is None or bool(getattr(args, "verbose", False))  # no args: kept (the command decides later)
    for w in caught:
        if not verbose and is_colour_note(w):
            continue
        text = " ".join(str(getattr(w, "message", w)).split())
        if text not in out:
            out.append(text)
    return out


def is_colour_note(w) -> bool:
    """A captured warning (or its line) that colour images were made grey (`RGBConvertedWarning`)."""
    if getattr(getattr(w, "category", None), "__name__", "") == "RGBConvertedWarning":
        return True
    return isinstance(w, str) and "-channel image converted to grey (ITU-R BT.601" in w


def grouped_warnings(lines: list[str], names: set[str]) -> list[str]:
    """Warnings that differ only by the image they name (``<file>: <message>``) once, with the count."""
    files: dict[str, list[str]] = {}
    for text in lines:
        head, sep, rest = text.partition(": ")
        files.setdefault(rest if sep and head in names else text, []).append(head if sep and head in names else "")
    return [message if not heads[0] else heads[0] + (f" and {len(heads) - 1} other image(s)" if len(heads) > 1 else "")
            + ": " + message for message, heads in files.items()]


def print_warnings(prog: str, lines, args: argparse.Namespace | None = None) -> None:
    """``<prog>: warning: <message>`` on stderr, one line each (nothing with ``--quiet``)."""
    if args is not None and getattr(args, "quiet", False):
        return
    for text in lines:
        print(f"{prog}: warning: {text}", file=sys.stderr)
