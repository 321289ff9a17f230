"""`dropvision` command line. Each command lives in its own module exposing
``register(subparsers)``; that adds a sub-parser whose ``func(args) -> int`` runs it."""

from __future__ import annotations

import os

# Before NumPy loads OpenBLAS (the commands import it when they run): one BLAS thread. The
# measurement's solves are small (more threads only slow them on a loaded machine), and a process
# that runs no thread but its own can fork its frame workers safely
# (`dropvision.frame.measure_frame.processes_usable`). A value the user set is kept.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import importlib  # noqa: E402
import sys  # noqa: E402
import warnings  # noqa: E402

from dvcore.errors import run_command
from dvcore.atomic import OutputError

#: Modules that contribute sub-commands, in the order they appear in --help.
COMMAND_MODULES = (
    "dropvision.app.init_cli",
    "dropvision.app.synth_cli",
    "dropvision.app.measure_cli",
    "dropvision.app.campaign_cli",
    "dropvision.app.watch_cli",
)


#: What ``dropvision --help`` says above the commands (the module's docstring is for its readers).
DESCRIPTION = ("Measure drop formation in images of drop-on-demand printing: drop volumes, pinch-off, velocities "
               "and satellites from a strobe sequence, a drop watcher's shots or a live folder. Start with "
               "'dropvision init FOLDER' (what the images say, what to give), then 'dropvision measure FOLDER "
               "--out RESULT'; 'dropvision COMMAND --help' lists a command's options.")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dropvision", description=DESCRIPTION)
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:  # command not built yet
            if exc.name is not None and name.startswith(exc.name):
                continue
            raise
        module.register(sub)
    return parser


def _quiet_opencv() -> None:
    """Our reader reports undecodable frames itself (one line, in summary.json): silence
    OpenCV's own decoder warnings so that they do not interleave with ours."""
    try:
        import cv2

        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    except (ImportError, AttributeError):  # pragma: no cover - depends on the OpenCV build
        pass


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:
        unknown_options(parser, args, extra)
    from dropvision.io.sequence import SequenceError  # after parsing: --help does not pay for the readers

    _quiet_opencv()
    with warnings.catch_warnings():
        # a warning no command collected itself: one line, without its source line
        warnings.showwarning = _one_line_warning
        # one error boundary: input/environment failures exit 2 with one line, bugs exit 1
        return run_command("dropvision", args, expected=(SequenceError, OutputError))


def suggestion(token: str, options) -> str | None:
    """The option a mistyped ``token`` meant: underscores for hyphens (``--pixel_size_um``), other case,
    or the closest spelling; None when nothing is close."""
    import difflib

    name = token.split("=", 1)[0]
    fixed = name.replace("_", "-").lower()
    if fixed in options:
        return fixed
    close = difflib.get_close_matches(fixed, list(options), n=1, cutoff=0.8)
    return close[0] if close else None


def unknown_options(parser: argparse.ArgumentParser, args, extra: list[str]) -> None:
    """Refuse arguments no parser took with the usage of the command they were given to and, for a
    mistyped option, the option meant (argparse alone shows the top-level usage and no hint)."""
    sub = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
    target = sub.choices.get(getattr(args, "command", None), parser) if sub is not None else parser
    options = [o for a in target._actions for o in a.option_strings if o.startswith("--")]
    hints = []
    for token in extra:
        if token.startswith("-"):
            meant = suggestion(token, options)
            if meant is not None:
                hints.append(f"{token.split('=', 1)[0]}: did you mean {meant}?")
    target.error(f"unrecognized arguments: {' '.join(extra)}" + (f" ({'; '.join(hints)})" if hints else ""))


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """``dropvision: warning: <message>`` on stderr (`warnings.showwarning` of the command line)."""
    print(f"dropvision: warning: {' '.join(str(message).split())}", file=file or sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
