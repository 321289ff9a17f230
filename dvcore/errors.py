"""The one error type of both command lines, and their one error boundary (:func:`run_command`)."""

from __future__ import annotations

import sys
import traceback

#: Where to report internal errors (bugs). Overridden by the installed package's
#: ``Project-URL: Issues`` / ``Bug Tracker`` metadata when it declares one.
ISSUES = "the dropvision issue tracker"


class UsageError(Exception):
    """Bad input the user can fix: printed as one line, exit status 2."""


class ParameterError(ValueError):
    """A bad value of a library function's parameter, said in Python terms: ``str(exc)`` is
    ``"<parameter> <problem>"`` (``"volume_nl must be a positive number, got -1"``).  A command
    line shows it with its option's name instead (:meth:`for_command_line`, applied by
    :func:`describe`): ``"--volume-nl must be a positive number, got -1"``.

    Attributes
    ----------
    parameter : str
        The parameter's name.
    problem : str
        What is wrong with its value (the message after the name).
    option : str or None
        The command line option that sets it, where it is not ``--`` + the name with dashes.
    """

    def __init__(self, parameter: str, problem: str, option: str | None = None):
        super().__init__(f"{parameter} {problem}")
        self.parameter, self.problem, self.option = parameter, problem, option

    def __reduce__(self):
        return type(self), (self.parameter, self.problem, self.option)

    def for_command_line(self) -> str:
        """The message with the option's name in place of the parameter's."""
        option = self.option or "--" + self.parameter.replace("_", "-")
        return f"{option} {self.problem}"


#: Failures that are the input's or the environment's fault (exit status 2, one line): files
#: missing, unreadable, not a folder, names too long, a full disk (OSError); undecodable text
#: and out-of-range values (ValueError, UnicodeError, OverflowError); pathologically nested
#: JSON (RecursionError); a request too large for the memory (MemoryError).
INPUT_ERRORS: tuple[type[BaseException], ...] = (
    UsageError, OSError, ValueError, UnicodeError, OverflowError, RecursionError, MemoryError,
)

#: Attributes of the parsed arguments that name a command's main input, in order of preference:
#: the file named in a message that does not carry one itself.
_INPUT_ARGS = ("model", "dataset", "seq_dir", "root", "out")


def _issues() -> str:
    try:
        from importlib.metadata import metadata

        for entry in metadata("dropvision").get_all("Project-URL") or []:
            label, _, url = entry.partition(",")
            if label.strip().lower() in ("issues", "bug tracker", "tracker", "bugs"):
                return url.strip()
    except Exception:  # noqa: BLE001 - metadata is a nicety, never a second failure
        pass
    return ISSUES


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _input_name(args) -> str | None:
    for name in _INPUT_ARGS:
        value = getattr(args, name, None)
        if isinstance(value, (list, tuple)):  # measure's several image files: each message names its own
            return str(value[0]) if len(value) == 1 else None
        if value is not None:
            return str(value)
    return None


def _names_a_file(problem: str) -> bool:
    head = problem.split(" ", 1)[0]
    return head.endswith(":") and ("/" in head or "." in head)


def describe(exc: BaseException, args=None) -> str:
    """``<file>: <problem>`` for an input or environment failure (one line)."""
    where = _input_name(args)
    if isinstance(exc, OSError):
        filename = exc.filename if exc.filename is not None else where
        problem = exc.strerror or str(exc) or type(exc).__name__
        if exc.filename2 is not None:
            problem = f"{problem} ({exc.filename2})"
        return _one_line(f"{filename}: {problem}" if filename else problem)
    if isinstance(exc, RecursionError):
        problem = "input nested too deeply to be read (pathological JSON?)"
    elif isinstance(exc, MemoryError):
        problem = "not enough memory for this request" + (f" ({exc})" if str(exc) else "")
    elif isinstance(exc, OverflowError):
        problem = f"number out of range ({exc})"
    else:
        problem = (exc.for_command_line() if isinstance(exc, ParameterError) else str(exc)) or type(exc).__name__
        if isinstance(exc, UnicodeError):
            problem = f"cannot decode the text ({exc})"
        elif isinstance(exc, UsageError) or where is None or where in problem or _names_a_file(problem):
            return _one_line(problem)  # most messages name their file (dataset, model, sequence)
    return _one_line(f"{where}: {problem}" if where else problem)


def run_command(prog: str, args, expected: tuple[type[BaseException], ...] = ()) -> int:
    """Run ``args.func(args)`` behind the error boundary of a command line.

    Input and environment failures (:data:`INPUT_ERRORS` and ``expected``) print one line
    ``<prog> <command>: error: <file>: <problem>`` and give exit status 2; anything else is a
    bug: a short "internal error, please report it" line plus the traceback, exit status 1.
    """
    command = getattr(args, "command", None) or "?"
    try:
        return int(args.func(args) or 0)
    except tuple(expected) + INPUT_ERRORS as exc:
        print(f"{prog} {command}: error: {describe(exc, args)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog} {command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - the boundary: a bug, reported as such
        print(f"{prog} {command}: internal error, please report it at {_issues()}: "
              f"{type(exc).__name__}: {_one_line(exc)}", file=sys.stderr)
        traceback.print_exc(file=sys.stderr)
        return 1
