"""A Rerun recording stream and where it goes: options, sinks, command-line flags.

Shared by the measurement views (:mod:`dropvision.app.rerun_log`) and the identification views
(:mod:`identify.app.rerun_log`). Nothing imports :mod:`rerun` until a stream is opened.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
import uuid
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from identify.app.errors import UsageError

if TYPE_CHECKING:  # pragma: no cover - typing only
    import rerun as rr
    import rerun.blueprint as rrb

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


def delay_ns(delay_us: float) -> int:
    """Delay after the trigger in integer nanoseconds, the unit of the ``delay`` timeline.

    Parameters
    ----------
    delay_us : float
        Strobe delay in microseconds (finite).

    Returns
    -------
    int
        ``round(delay_us * 1000)``.
    """
    value = float(delay_us)
    if not math.isfinite(value):
        raise ValueError(f"delay_us must be finite, got {delay_us!r}")
    return int(round(value * 1000.0))


# --- options ---------------------------------------------------------------------------------


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


#: Seconds the final flush waits for a viewer (a gRPC sink) before giving up with a warning.
FLUSH_TIMEOUT_S = 20.0


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


_STREAM_URLS: dict[int, str] = {}


def close_stream(rec: rr.RecordingStream) -> None:
    """Flush and finalise the sinks (the .rrd footer is written) without ever blocking forever:
    a stream to a viewer is flushed with a :data:`FLUSH_TIMEOUT_S` timeout, and an unreachable
    viewer gives the warning "no Rerun viewer reached at URL; results were written"."""
    url = _STREAM_URLS.pop(id(rec), None)
    try:
        rec.flush(timeout_sec=FLUSH_TIMEOUT_S if url is not None else math.inf)
    except RuntimeError:
        if url is None:
            raise
        warn(f"no Rerun viewer reached at {url}; results were written")
    rec.disconnect()


def open_stream(options: RerunOptions, blueprint: rrb.BlueprintLike | None = None) -> rr.RecordingStream:
    """Create an explicit :class:`rerun.RecordingStream` with the sinks ``options`` asks for.

    The blueprint is written into the ``.rrd`` (and sent to a viewer) as the default blueprint,
    so the file opens with that layout. Shared by :class:`RerunLogger` and :mod:`identify.app.rerun_log`.

    Raises
    ------
    ValueError
        If no sink is requested (``options.enabled`` is False).
    """
    if not options.enabled:
        raise ValueError("RerunOptions: no sink requested (give path, spawn or connect_url)")
    import rerun as rr

    url = options.connect_url
    if options.spawn:
        if spawn_viewer():
            url = url or DEFAULT_VIEWER_URL
    rec = rr.RecordingStream(
        options.application_id,
        recording_id=options.recording_id or uuid.uuid4(),
        # nothing left to write to (a viewer could not be spawned): a disabled, no-op stream
        default_enabled=options.path is not None or url is not None,
    )
    # Timelines are only `delay` and `frame`: the wall-clock log_time would only clutter the
    # timeline menu and make files differ between identical runs.
    rec.set_log_time_enabled(False)
    sinks: list[Any] = []
    if options.path is not None:
        options.path.parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(options.path))
    if url is not None:
        sinks.append(rr.GrpcSink(url))
        _STREAM_URLS[id(rec)] = url
    if sinks:
        rec.set_sinks(*sinks, default_blueprint=blueprint)
    if options.recording_name:
        rec.send_recording_name(options.recording_name)
    return rec


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

    Does not import rerun. Raises ``dropvision.app.cli.UsageError`` for a bad ``--rerun`` path.
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
