"""Where a Rerun recording goes: :class:`RerunOptions`, its command-line flags, a viewer to spawn.

Shared by the measurement views (:mod:`dropvision.app.rerun_log`), the identification views
(:mod:`identify.app.rerun_log`) and every command line with ``--rerun`` flags. Nothing imports
:mod:`rerun` until a viewer is spawned (:func:`spawn_viewer`); the recording stream itself is
opened by :mod:`identify.app.rerun_stream`.
"""

from __future__ import annotations

import argparse
import re
import sys
import uuid
from dataclasses import dataclass, replace
from pathlib import Path

from dvcore.errors import UsageError

__all__ = ["DEFAULT_APPLICATION_ID", "DEFAULT_VIEWER_URL", "RerunOptions", "add_rerun_args", "options_from_args",
           "is_rrd_file", "spawn_viewer", "warn"]

DEFAULT_APPLICATION_ID = "dropvision"
_APP_ID_RE = re.compile(r"[A-Za-z0-9_\- ]+")
DEFAULT_VIEWER_URL = "rerun+http://127.0.0.1:9876/proxy"


def is_rrd_file(path) -> bool:
    """True when ``path`` is a Rerun recording file (starts with the .rrd magic bytes)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(4) in (b"RRF2", b"RRF0", b"RRF1")
    except OSError:
        return False


@dataclass(frozen=True)
class RerunOptions:
    """Where a Rerun recording goes. Picklable; create the logger from it in the worker.

    Parameters
    ----------
    path : Path or None
        Write the recording (and its blueprint) to this ``.rrd`` file; parent folders are created.
    spawn : bool
        Start a local Rerun viewer and stream to it live.
    connect_url : str or None
        Stream to an already running viewer at this gRPC URL (e.g. :data:`DEFAULT_VIEWER_URL`).
    application_id : str
        Rerun application id (letters, digits, ``_``, ``-``, spaces); recordings with the same
        id share the viewer's blueprint.
    recording_id : str or None
        Rerun recording id; ``None`` gives a fresh random UUID per logger.
    recording_name : str or None
        Name shown in the viewer's recording list (e.g. the sequence folder name).
    raw : bool
        Measurement recordings: also log every raw frame losslessly at ``/frame/raw`` (large:
        one uncompressed frame each); by default only the JPEG of the normalised frame.
    """

    path: Path | None = None
    spawn: bool = False
    connect_url: str | None = None
    application_id: str = DEFAULT_APPLICATION_ID
    recording_id: str | None = None
    recording_name: str | None = None
    raw: bool = False

    def __post_init__(self) -> None:
        if self.path is not None:
            object.__setattr__(self, "path", Path(self.path))
            if self.path.is_dir():
                raise ValueError(f"--rerun {self.path}: is a directory, expected a .rrd file path")
            if self.path.exists() and not is_rrd_file(self.path):
                raise ValueError(f"--rerun {self.path}: exists and is not a Rerun recording; "
                                 "choose another name (dropvision replaces only its own .rrd files)")
        if not _APP_ID_RE.fullmatch(self.application_id or ""):
            raise ValueError(f"Rerun application id {self.application_id!r}: use only letters, digits, "
                             "'_', '-' and spaces (rerun 0.41 rewrites e.g. '.' or '/' into a hashed id)")

    @property
    def enabled(self) -> bool:
        """True when at least one sink (file, spawned viewer, viewer URL) is requested."""
        return self.path is not None or self.spawn or self.connect_url is not None

    def for_sequence(self, name: str) -> RerunOptions:
        """Options for one sequence of a campaign.

        The file ``campaign.rrd`` becomes ``campaign-<name>.rrd`` (same folder; ``name`` is made
        filename-safe), the recording is named ``name`` and gets a fresh recording id. A spawned
        viewer is not spawned again per sequence: call :meth:`start_viewer` once first.

        Parameters
        ----------
        name : str
            Sequence name (e.g. its folder name).
        """
        safe = re.sub(r"[^A-Za-z0-9._=+-]+", "_", str(name)).strip("._") or "sequence"
        path = None if self.path is None else self.path.with_name(f"{self.path.stem}-{safe}.rrd")
        return replace(self, path=path, recording_id=None, recording_name=str(name))

    def start_viewer(self, *, port: int = 9876) -> RerunOptions:
        """Spawn one viewer now and return options that connect to it (``spawn=False``).

        Use before fanning out to worker processes so they all stream to the same viewer.
        Returns ``self`` unchanged when ``spawn`` is False.
        """
        if not self.spawn:
            return self
        if not spawn_viewer(port=port):
            return replace(self, spawn=False)  # warned; the other sinks (a file) are kept
        return replace(self, spawn=False, connect_url=f"rerun+http://127.0.0.1:{port}/proxy")


def warn(message: str) -> None:
    """One ``warning: ...`` line on stderr."""
    print(f"warning: {' '.join(message.split())}", file=sys.stderr, flush=True)


def spawn_viewer(port: int = 9876) -> bool:
    """Start a local Rerun viewer listening on ``port``; on failure (no ``rerun`` executable,
    it cannot start) print one warning line and return False: the work goes on without it.

    ``rr.spawn`` without a global recording is silently ignored by rerun 0.41, so a throw-away
    stream does the spawning.
    """
    import rerun as rr

    try:
        rr.RecordingStream(DEFAULT_APPLICATION_ID, recording_id=uuid.uuid4()).spawn(port=port, connect=False)
    except (RuntimeError, OSError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        warn(f"--rerun-spawn: cannot start a Rerun viewer ({first}); continuing without it")
        return False
    return True


def add_rerun_args(parser: argparse.ArgumentParser) -> None:
    """Add ``--rerun FILE.rrd``, ``--rerun-spawn``, ``--rerun-connect [URL]`` and ``--rerun-raw``.

    Rerun's own ``rr.script_add_args`` flags (``--save``, ``--connect``, ``--url``,
    ``--headless``, ...) are deliberately not used: their generic names would clash with or
    confuse the dropvision options.
    """
    group = parser.add_argument_group("Rerun visualisation (optional)")
    group.add_argument("--rerun", type=Path, default=None, metavar="FILE.rrd",
                       help="write a Rerun recording (open it with `rerun FILE.rrd`)")
    group.add_argument("--rerun-spawn", action="store_true",
                       help="start a Rerun viewer and stream to it live")
    group.add_argument("--rerun-connect", nargs="?", const=DEFAULT_VIEWER_URL, default=None,
                       metavar="URL", help=f"stream to a running Rerun viewer (default {DEFAULT_VIEWER_URL})")
    group.add_argument("--rerun-raw", action="store_true",
                       help="also log every raw frame losslessly (large); by default only a JPEG "
                            "of the normalised frame is logged")


def options_from_args(args: argparse.Namespace, app_id: str = DEFAULT_APPLICATION_ID, *,
                      recording_name: str | None = None) -> RerunOptions | None:
    """:class:`RerunOptions` from parsed :func:`add_rerun_args` flags, or None when logging is off.

    Does not import rerun. Raises :class:`dvcore.errors.UsageError` for a bad ``--rerun`` path.
    """
    path = getattr(args, "rerun", None)
    spawn = bool(getattr(args, "rerun_spawn", False))
    url = getattr(args, "rerun_connect", None)
    if path is None and not spawn and url is None:
        return None
    try:
        return RerunOptions(path=path, spawn=spawn, connect_url=url, application_id=app_id,
                            recording_name=recording_name, raw=bool(getattr(args, "rerun_raw", False)))
    except ValueError as exc:
        raise UsageError(str(exc)) from exc
