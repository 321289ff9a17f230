"""A Rerun recording stream: open it with the sinks :class:`~dvcore.rerun_options.RerunOptions`
asks for, close it without blocking on an unreachable viewer, and the ``delay`` timeline unit.

Shared by the measurement views (:mod:`dropvision.app.rerun_log`) and the identification views
(:mod:`identify.app.rerun_log`). Nothing imports :mod:`rerun` until a stream is opened. The
options and the ``--rerun`` flags are in :mod:`dvcore.rerun_options`.
"""

from __future__ import annotations

import math
import uuid
from typing import TYPE_CHECKING, Any

from dvcore.rerun_options import DEFAULT_VIEWER_URL, RerunOptions, spawn_viewer, warn

if TYPE_CHECKING:  # pragma: no cover - typing only
    import rerun as rr
    import rerun.blueprint as rrb


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


#: Seconds the final flush waits for a viewer (a gRPC sink) before giving up with a warning.
FLUSH_TIMEOUT_S = 20.0

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
