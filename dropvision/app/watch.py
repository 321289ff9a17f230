"""Live measurement: measure a sequence folder while a drop watcher writes its frames into it.

`watch_sequence` runs the loop behind ``dropvision watch FOLDER --out OUT``:

1. A file-system observer (watchdog) reports what changes in FOLDER; a frame is taken once it
   is complete: its size and modification time unchanged for ``settle_s`` (or its writer
   closed it), and it decodes. A decode failure of a file that is still changing is "not yet";
   one that stays unreadable and unchanged for ``unreadable_after_s`` is reported, as the batch
   measurement reports it.
2. The sequence is calibrated (`dropvision.calibrate.calibration_pass.calibrate_sequence`) on the complete frames
   as soon as there is one, and again each time their number has doubled; every new frame is
   measured with the newest context (`dropvision.frame.measure_frame`) and its row appended to
   the journal ``OUT/live/frames.jsonl`` (one ``write`` of one line per frame, so a kill leaves
   whole rows; a cut last line, which only a power loss could leave, is dropped on resume).
   These rows are provisional: the frame's own measurement, before the sequence-level analysis.
3. When the sequence ends (the expected number of frames, ``idle_s`` without a new frame, or
   Ctrl-C) the final tables are measured by `dropvision.measurement.measure_sequence` over the
   complete frames and written by `dropvision.output.result_writer.write_result`: with every frame complete
   they equal ``dropvision measure FOLDER`` exactly. The journal is kept in the result.

A folder into which a drop watcher exports one image per shot (`dropvision.analysis.shots`: no delay in
the names, no frames list nor frame rate; ``WatchOptions.shots``, else decided by its first image,
`_watch_kind`) is watched the same way, each image measured alone once complete
(`dropvision.analysis.shots.measure_shots` of that image), its row appended to ``OUT/shots.parquet``
(rewritten atomically, the columns of ``dropvision measure``) and then to the journal; at the end
`_finish_shots` writes the tables of ``dropvision measure FOLDER`` over the complete images.

Nothing is ever written into FOLDER. OUT follows `dvcore.atomic`: refused when it holds files
we did not write (without ``overwrite``); a restart on the same OUT resumes from its journal
(frames already there and unchanged are not measured again).
"""

from __future__ import annotations

import json
import math
import os
import queue
import shutil
import stat
import statistics
import time
import warnings
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

from dropvision.config import MeasureConfig
from dropvision.calibrate.calibration_pass import calibrate_sequence
from dropvision.app.live_journal import JOURNAL, Journal, live_row, read_journal
from dropvision.frame.measure_frame import FrameRecord, measure_frame
from dropvision.measurement import MeasureResult, measure_sequence
from dropvision.output.result_writer import write_result
from dropvision.io.readers import IMAGE_SUFFIXES
from dropvision.io.sequence import SEQUENCE_JSON, SequenceError, open_sequence
from dvcore import schema
from dvcore.jsonio import loads_strict
from dvcore.atomic import atomic_dir, check_output_dir, foreign_files, output_lock, write_json, write_text

__all__ = ["WATCH_JSON", "WatchOptions", "WatchResult", "watch_sequence", "watch_sequences"]

#: What the watch did (sequence, end, latencies), relative to OUT (`dvcore.schema.WATCH`).
WATCH_JSON = schema.WATCH.file


@dataclass
class WatchOptions:
    """How `watch_sequence` watches and when it stops.

    Attributes
    ----------
    frames : int or None
        Expected number of frames: the sequence ends when that many are measured. None: the
        length of sequence.json's ``frames`` list when it has one, else no count.
    idle_s : float or None
        End after this many seconds without a new complete frame (None: never).
    settle_s : float
        A frame is complete when its size and modification time stayed unchanged this long
        (or its writer closed it) and it decodes.
    unreadable_after_s : float
        A file that does not decode and stays unchanged this long is reported as unreadable
        (``summary.json["errors"]``), as ``dropvision measure`` reports it.
    poll_s : float
        Longest wait for a file-system event before the files are looked at again.
    config : MeasureConfig
    csv : bool
        Also write frames.csv.
    overwrite : bool
        Write into an OUT that holds files we did not write (they are kept).
    overrides, labels : dict, optional
        sequence.json keys given as options (`dropvision.io.sequence.open_sequence`).
    shots : bool or None
        True: the folder receives shots (one image per shot, `dropvision.analysis.shots`); False: a
        sequence; None: decided by the first image (`_watch_kind`).
    label_pattern : str, optional
        Shots: the labels' regular expression (`dropvision.io.labels.labels_from_pattern`).
    """

    frames: int | None = None
    idle_s: float | None = None
    settle_s: float = 0.05
    unreadable_after_s: float = 2.0
    poll_s: float = 0.02
    config: MeasureConfig = field(default_factory=MeasureConfig)
    csv: bool = False
    overwrite: bool = False
    overrides: dict | None = None
    labels: dict | None = None
    shots: bool | None = None
    label_pattern: str | None = None


@dataclass
class WatchResult:
    """What `watch_sequence` did.

    Attributes
    ----------
    result : MeasureResult
        The final tables (as `dropvision.measurement.measure_sequence` gives them).
    ended_by : str
        ``"frames"`` (the expected count), ``"idle"`` (``idle_s``), ``"interrupt"`` (Ctrl-C) or
        ``"next sequence"`` (``stop``: the drop watcher began the next sequence).
    n_live : int
        Frames measured live by this run.
    n_resumed : int
        Frames found in the journal of an earlier run (not measured again).
    latency_ms : list of float
        Per frame written while watching and measured live: from the file's completion (its
        last modification time, on the kernel's coarse clock) to its row on disk (ms).
    left_out : list of str
        Files still being written when the sequence ended (not in the final tables).
    kind : str
        ``"sequence"``, or ``"shots"``: ``result`` is then a `dropvision.analysis.shots.ShotsResult`.
    """

    result: MeasureResult
    ended_by: str
    n_live: int
    n_resumed: int
    latency_ms: list[float]
    left_out: list[str]
    kind: str = "sequence"


def _start_out(out: Path, folder: Path, overwrite: bool, kind: str | None = None) -> tuple[list[dict], str | None]:
    """Check OUT before any work and make it ours; the journal rows of an earlier watch of the
    same folder when OUT holds one (resume), else an empty journal; and the kind (``"shots"``,
    ``"sequence"``) of the watch resumed (None: none). With ``kind``, an earlier watch of another
    kind is not resumed, and a new OUT records it (shots: with an empty shots.parquet)."""
    mode = check_output_dir(out, inputs=[folder], overwrite=overwrite)
    journal, state = out / JOURNAL, out / WATCH_JSON
    if mode != "new" and journal.is_file() and JOURNAL not in foreign_files(out):
        try:
            doc = loads_strict(state.read_text(encoding="utf-8"))
            same = doc.get("sequence") == str(folder)
            recorded = doc.get("kind", "sequence")
        except (OSError, ValueError, AttributeError):
            same, recorded = False, None
        if same and kind is not None and recorded != kind:
            same = False
        if same and kind == "shots" and "shots.parquet" in foreign_files(out):
            same = False
        if same:
            rows = read_journal(out)
            if not journal.read_bytes().endswith(b"\n") and journal.stat().st_size:  # a cut last line
                write_text(journal, "".join(json.dumps(r) + "\n" for r in rows))
            return rows, recorded
    with atomic_dir(out, inputs=[folder], overwrite=overwrite, kind="live measurement") as tmp:
        (tmp / JOURNAL).parent.mkdir(parents=True, exist_ok=True)
        (tmp / JOURNAL).write_bytes(b"")
        doc = {"schema": schema.WATCH.schema, "sequence": str(folder), "state": "watching"}
        if kind == "shots":
            doc["kind"] = "shots"
            _live_shots_table([]).to_parquet(tmp / "shots.parquet", index=False)
        write_json(tmp / WATCH_JSON, doc)
    return [], None


# --- completeness --------------------------------------------------------------------------------

@dataclass
class _Pending:
    size: int = -1
    mtime_ns: int = -1
    changed_at: float = 0.0  # monotonic time of the last change seen
    closed: bool = False  # the writer closed it after its last change
    failed: str | None = None  # the last decode failure


def _is_frame_name(name: str) -> bool:
    return (Path(name).suffix.lower() in IMAGE_SUFFIXES and not name.startswith(".")
            and not name.lower().startswith("truth"))


class _ListedCount:
    """The length of sequence.json's frames list, if it has one (read again when it changes)."""

    def __init__(self, folder: Path):
        self.path = folder / SEQUENCE_JSON
        self._key, self._count = None, None

    def count(self) -> int | None:
        try:
            st = self.path.stat()
        except OSError:
            return None
        key = (st.st_size, st.st_mtime_ns)
        if key != self._key:
            self._key = key
            try:
                doc = loads_strict(self.path.read_text(encoding="utf-8"))
            except (OSError, ValueError, RecursionError):
                doc = None
            frames = doc.get("frames") if isinstance(doc, dict) else None
            self._count = len(frames) if isinstance(frames, list) and frames else None
        return self._count


#: watchdog event types that say a file was written (not opened or read: our own reads are events too)
_WRITE_EVENTS = frozenset({"created", "modified", "moved", "closed"})


def _write_event_types() -> list:
    """The watchdog event classes of writes (the observer then leaves reads, ours included, unreported)."""
    from watchdog.events import FileClosedEvent, FileCreatedEvent, FileModifiedEvent, FileMovedEvent

    return [FileCreatedEvent, FileModifiedEvent, FileMovedEvent, FileClosedEvent]


def _event_handler(events: queue.Queue):
    """A watchdog handler queueing (name, closed) for each written entry of the folder:
    ``closed`` when its writer closed it or renamed it into place."""
    from watchdog.events import FileSystemEventHandler

    class Handler(FileSystemEventHandler):
        def dispatch(self, event) -> None:
            if event.is_directory or event.event_type not in _WRITE_EVENTS:
                return
            path = event.dest_path if event.event_type == "moved" else event.src_path
            # closed by its writer, or renamed into place (written under another name): complete
            events.put((os.path.basename(os.fsdecode(path)), event.event_type in ("closed", "moved")))

    return Handler()


# --- the loop --------------------------------------------------------------------------------------

def watch_sequence(folder, out_dir, options: WatchOptions = WatchOptions(), *, logger=None,
                   report=None, stop=None) -> WatchResult:
    """Measure a sequence folder while its frames are written; write the final tables at its end.

    Parameters
    ----------
    folder : str or Path
        The sequence folder a drop watcher writes into (never written to).
    out_dir : str or Path
        Output folder: ``live/frames.jsonl`` (rows as they are measured), then the files of
        ``dropvision measure`` (frames.parquet, bodies.parquet, per_delay.parquet, summary.json)
        and ``live/watch.json``. An OUT of an earlier watch of the same folder is resumed.
    options : WatchOptions
    logger : object, optional
        Rerun logger (`dropvision.app.rerun_log.RerunLogger`): each frame as it is measured,
        then the final measurement.
    report : callable, optional
        Called with each live row once it is on disk (e.g. a line on the terminal).
    stop : callable, optional
        ``stop() -> bool``, asked while no frame is being written: True ends the sequence
        (``ended_by`` ``"next sequence"``; `watch_sequences` asks whether the next one began).

    Returns
    -------
    WatchResult

    Raises
    ------
    dropvision.io.sequence.SequenceError
        FOLDER missing, or a sequence that cannot be measured (as ``dropvision measure``).
    dvcore.atomic.OutputError
        OUT overlaps FOLDER, holds files we did not write (without ``overwrite``), or another
        run writes it (OUT is locked for the watch's life: `dvcore.atomic.output_lock`).
    """
    folder = Path(folder).absolute()
    out = Path(out_dir)
    if not folder.is_dir():
        raise SequenceError(f"{folder}: no such folder")
    check_output_dir(out, inputs=[folder], overwrite=options.overwrite)
    with output_lock(out):  # held to the end: a second watch (or measure) on OUT is refused at once
        rows, recorded = _start_out(out, folder, options.overwrite)
        kind = _watch_kind(folder, options, recorded if rows else None, stop)
        if kind == "shots":
            if logger is not None:
                warnings.warn(f"{folder}: a folder of shots: not logged to Rerun (sequences only)", stacklevel=2)
            if recorded != "shots":  # a new watch of shots (or one of another kind before): OUT made for shots
                rows, _ = _start_out(out, folder, options.overwrite, kind="shots")
            return _watch_shots_locked(folder, out, options, report, stop, rows)
        if recorded == "shots":
            rows, _ = _start_out(out, folder, options.overwrite, kind="sequence")
        return _watch_locked(folder, out, options, logger, report, stop, rows)


def _watch_kind(folder: Path, opts: WatchOptions, recorded: str | None, stop) -> str:
    """``"shots"`` or ``"sequence"``: ``opts.shots`` when given, else what the earlier watch resumed
    was, else decided as `dropvision measure` decides (`dropvision.analysis.shots`) from what the folder holds,
    waiting for its first image: a sequence when a frames list or a frame rate is given (sequence.json
    or options), or an image tells a delay by its name or is a video; shots when the images tell none.

    The wait ends as the watch does (``idle_s`` without an image, ``stop``, Ctrl-C): then no frame
    arrived, and `dropvision.io.sequence.SequenceError` says so."""
    from dropvision.io.discovery import parse_delay_from_name
    from dropvision.io.readers import VIDEO_SUFFIXES
    from dropvision.analysis.shots import sequence_settings_given

    if opts.shots is not None:
        return "shots" if opts.shots else "sequence"
    if recorded is not None:
        return recorded
    started, ended_by = time.monotonic(), None
    broken: tuple | None = None  # (size, mtime_ns, since) of a sequence.json that does not parse (yet)
    try:
        while True:
            key = _json_unreadable(folder / SEQUENCE_JSON)
            if key is None:
                broken = None
            else:  # being written, or broken (then open_sequence reports it)
                if broken is None or broken[:2] != key:
                    broken = (*key, time.monotonic())
                if time.monotonic() - broken[2] < opts.unreadable_after_s:
                    time.sleep(opts.poll_s)
                    continue
            if sequence_settings_given(folder, overrides=opts.overrides):
                return "sequence"
            try:
                names = [e.name for e in os.scandir(folder) if _is_frame_name(e.name)]
            except OSError as exc:
                raise SequenceError(f"{folder}: cannot list the folder ({exc.strerror or exc})") from None
            if any(Path(n).suffix.lower() in VIDEO_SUFFIXES or parse_delay_from_name(n) is not None for n in names):
                return "sequence"
            pages = [_tiff_pages(folder / n) for n in names]
            if any(p == "several" for p in pages):  # a stack, or delays stored in the file
                return "sequence"
            if names and (None not in pages or time.monotonic() - started >= opts.unreadable_after_s + opts.settle_s):
                return "shots"
            if opts.idle_s is not None and time.monotonic() - started >= opts.idle_s:
                ended_by = "idle"
                break
            if stop is not None and stop():
                ended_by = "next sequence"
                break
            time.sleep(opts.poll_s)
    except KeyboardInterrupt:
        ended_by = "interrupt"
    raise SequenceError(f"{folder}: no complete frame arrived (the watch ended by {ended_by})")


def _tiff_pages(path: Path) -> str | None:
    """``"one"`` or ``"several"`` (pages, or delays stored in the file) for a TIFF that probes whole; ``"one"``
    for other image formats (single frames); None while a TIFF cannot be probed whole (being written)."""
    from dropvision.io.readers import reader_for

    if path.suffix.lower() not in (".tif", ".tiff"):
        return "one"
    reader = reader_for(path)
    try:
        info = reader.probe(path)
    except Exception:  # noqa: BLE001 - being written (or broken: the measurement reports it)
        return None
    if not info.complete:
        return None
    return "several" if info.n_pages > 1 or info.page_delays else "one"


def _json_unreadable(path: Path) -> tuple[int, int] | None:
    """(size, mtime_ns) of a JSON file that is there and does not parse; None when it parses or is absent."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    try:
        loads_strict(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return st.st_size, st.st_mtime_ns
    return None


def _watch_locked(folder: Path, out: Path, opts: WatchOptions, logger, report, stop, rows: list[dict]
                  ) -> WatchResult:
    """`watch_sequence` with OUT locked (``rows``: the journal resumed)."""
    n_resumed = len(rows)
    done: dict[str, tuple[int, int]] = {}  # complete file -> (size, mtime_ns) it was taken at
    measured = set()  # (file, page) of the rows
    for r in rows:
        done[r["file"]] = (int(r.get("size") or -1), int(r.get("mtime_ns") or -1))
        measured.add((r["file"], r.get("page")))
    journal = Journal(out / JOURNAL)
    observer, events, pending = _start_watching(folder)
    state = _LiveState(folder, opts, logger)
    listed = _ListedCount(folder)
    latency: list[float] = []
    n_live, started_ns = 0, time.time_ns()
    last_frame_at = time.monotonic()
    ended_by = "interrupt"
    try:
        while True:
            ended = _why_ended(opts, len(measured), opts.frames if opts.frames is not None else listed.count(),
                               pending, last_frame_at, stop)
            if ended is not None:
                ended_by = ended
                break
            _drain(events, pending, opts.poll_s)
            ready = _settled(folder, pending, done, state.unlisted, opts)
            if not ready:
                continue
            for row, file_stat in state.measure(ready, done, pending):
                done[row["file"]] = file_stat  # first: a frame in the journal is in the final tables
                measured.add((row["file"], row["page"]))
                _journal_row(journal, row, file_stat, started_ns, latency)
                n_live += 1
                last_frame_at = time.monotonic()
                if report is not None:
                    report(row)
    except KeyboardInterrupt:
        ended_by = "interrupt"
    finally:
        observer.stop()
        journal.close()
        state.close()
    observer.join()
    left_out = sorted(pending)
    result = _finish(folder, out, opts, logger, done, left_out,
                     {"ended_by": ended_by, "n_live": n_live, "n_resumed": n_resumed,
                      "latency_ms_median": statistics.median(latency) if latency else None,
                      "latency_ms_max": max(latency) if latency else None})
    return WatchResult(result, ended_by, n_live, n_resumed, latency, left_out)


def _journal_row(journal, row: dict, file_stat: tuple[int, int], started_ns: int, latency: list) -> None:
    """Stamp ``row`` with its file's (size, mtime_ns), the time and the latency from the file's last
    write, append it to the journal; the latency counts (``latency``) only for a file written while
    watching (not there before the watch started at ``started_ns``)."""
    row["size"], row["mtime_ns"] = file_stat
    row["row_unix_s"] = time.time()
    row["latency_ms"] = (row["row_unix_s"] - file_stat[1] / 1e9) * 1e3
    journal.append(row)
    if file_stat[1] >= started_ns:
        latency.append(row["latency_ms"])


def _why_ended(opts, n_done: int, expected, pending: dict, last_frame_at: float, stop) -> str | None:
    """Why a watch ends now (``frames``: ``expected`` measured and nothing pending; ``idle``: no
    frame for ``opts.idle_s``; ``next sequence``: ``stop()`` with nothing pending), or None."""
    if expected is not None and n_done >= expected and not pending:
        return "frames"
    if opts.idle_s is not None and time.monotonic() - last_frame_at >= opts.idle_s:
        return "idle"
    if stop is not None and not pending and stop():
        return "next sequence"
    return None


def _start_watching(folder: Path):
    """(observer, its event queue, the frames already there): the observer starts before the first
    look at the folder, so that nothing written meanwhile is missed; what was there is settled."""
    from watchdog.observers import Observer  # the command's own dependency, imported when it runs

    events: queue.Queue = queue.Queue()
    observer = Observer()
    observer.schedule(_event_handler(events), str(folder), recursive=False, event_filter=_write_event_types())
    observer.start()
    pending: dict[str, _Pending] = {}
    for p in folder.iterdir():
        if _is_frame_name(p.name):
            pending[p.name] = _Pending(changed_at=-math.inf)  # there before we looked: settled
    return observer, events, pending


def _drain(events: queue.Queue, pending: dict, wait_s: float) -> None:
    """Take the queued file-system events in order (waiting up to ``wait_s`` for the first): a
    write makes a file pending, its writer closing it makes it ready to be decoded."""
    try:
        item = events.get(timeout=wait_s)
    except queue.Empty:
        return
    while True:
        name, closed = item
        if _is_frame_name(name):
            p = pending.setdefault(name, _Pending(changed_at=time.monotonic()))
            p.closed = closed
            if not closed:
                p.failed = None  # written again: worth another try
        try:
            item = events.get_nowait()
        except queue.Empty:
            return


def _settled(folder: Path, pending: dict, done: dict, unlisted: dict, opts: WatchOptions) -> list[str]:
    """Pending files whose size and modification time stayed unchanged ``settle_s`` (or that
    their writer closed since their last change): ready to be decoded. Those measured already,
    or that are no frame of the sequence (``unlisted``), are dropped while unchanged."""
    now = time.monotonic()
    ready = []
    for name in sorted(pending):
        p = pending[name]
        try:
            st = os.stat(folder / name)
        except OSError:  # gone (renamed away, deleted)
            del pending[name]
            continue
        if not stat.S_ISREG(st.st_mode):  # a FIFO or device named like a frame: never opened here
            del pending[name]
            continue
        key = (st.st_size, st.st_mtime_ns)
        if key in (done.get(name), unlisted.get(name)):  # measured already (an earlier run), or no frame
            del pending[name]
            continue
        if key != (p.size, p.mtime_ns):
            p.size, p.mtime_ns, p.changed_at, p.failed = key[0], key[1], now, None
        if p.failed is not None and now - p.changed_at < opts.unreadable_after_s:
            continue  # did not decode: tried again when it changes, or reported when it does not
        if st.st_size > 0 and (p.closed or now - p.changed_at >= opts.settle_s):
            ready.append(name)
    return ready


class _LiveState:
    """The live calibration and the frames measured with it.

    The first calibration is made before the first frame is measured; each refinement (when
    the complete frames have doubled) runs in a background thread while the frames go on being
    measured with the current context, which it replaces once ready.
    """

    def __init__(self, folder: Path, opts: WatchOptions, logger):
        self.folder, self.opts, self.logger = folder, opts, logger
        self.ctx = None
        self.cal_frames = 0  # frames the context was calibrated on (their number, not the picks)
        self.arrived = 0  # arrival order: the Rerun "frame" timeline
        self.error_since: float | None = None
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="dropvision-calibrate")
        #: image files that are no frame of the sequence (not in sequence.json's frames list) -> (size, mtime_ns)
        self.unlisted: dict[str, tuple[int, int]] = {}
        self._refining: Future | None = None

    def close(self) -> None:
        """Stop refining (a calibration under way is finished and dropped)."""
        self._pool.shutdown(wait=True, cancel_futures=True)

    def _calibrated(self, files: frozenset) -> tuple:
        """(cal, ctx, number of frames) of the complete ``files`` (run in the background)."""
        with open_sequence(self.folder, overrides=self.opts.overrides, labels=self.opts.labels,
                           only_files=files) as seq:
            cal, _sigma, ctx = calibrate_sequence(seq, self.opts.config)
            return cal, ctx, len(seq)

    def _take_refinement(self) -> None:
        if self._refining is None or not self._refining.done():
            return
        future, self._refining = self._refining, None
        try:
            cal, ctx, n = future.result()
        except SequenceError:  # the context it has is kept; the final measurement reports what is wrong
            self.cal_frames *= 2
            return
        self.ctx, self.cal_frames = ctx, n
        if self.logger is not None:  # the orientation given in the first calibration stays
            self.logger.log_calibration(cal, shape=cal.shape)

    def measure(self, ready: list[str], done: dict, pending: dict):
        """Decode and measure the ready files; yield (row, (size, mtime_ns)) for each frame
        on disk complete, leave the not-yet-complete ones pending."""
        opts = self.opts
        now = time.monotonic()
        try:
            seq = open_sequence(self.folder, overrides=opts.overrides, labels=opts.labels,
                                only_files=set(done) | set(ready))
        except SequenceError:
            # a ready file that was not complete after all (its delay or size unreadable yet),
            # or a sequence that cannot be measured: retried; raised when nothing changes
            if self.error_since is None:
                self.error_since = now
            if now - self.error_since >= opts.unreadable_after_s:
                raise
            for name in ready:
                pending[name].changed_at = now
                pending[name].closed = False
            return
        self.error_since = None
        try:
            n_complete = len(seq)
            self._take_refinement()
            if self.ctx is None:
                self._calibrate(seq)
            elif n_complete >= 2 * self.cal_frames and self._refining is None:
                self._refining = self._pool.submit(self._calibrated, frozenset(set(done) | set(ready)))
            wanted = set(ready)
            for name in wanted - {ref.file for ref in seq.meta.frames}:
                p = pending.pop(name)
                self.unlisted[name] = (p.size, p.mtime_ns)
            for i, ref in enumerate(seq.meta.frames):
                if ref.file not in wanted:
                    continue
                p = pending.get(ref.file)
                fr = seq.read(i)
                st = os.stat(self.folder / ref.file)
                file_stat = (st.st_size, st.st_mtime_ns)
                if fr.image is None:
                    changed = p is not None and file_stat != (p.size, p.mtime_ns)
                    if p is not None and (changed or now - p.changed_at < opts.unreadable_after_s):
                        p.failed, p.closed = fr.error, False  # not yet: retried on its next change
                        if changed:
                            p.size, p.mtime_ns, p.changed_at = file_stat[0], file_stat[1], now
                        continue
                    rec = FrameRecord(ref.index, ref.file, ref.page, ref.delay_us, ref.repeat, error=fr.error)
                elif self.ctx is None:  # no calibration yet: measured once one is possible
                    if p is not None:
                        p.changed_at, p.closed = now, False
                    continue
                else:
                    rec = measure_frame(fr.image, self.ctx, replace(ref, index=self.arrived), self.logger)
                self.arrived += 1
                pending.pop(ref.file, None)
                yield live_row(rec, self.cal_frames), file_stat
        finally:
            seq.close()

    def _calibrate(self, seq) -> None:
        try:
            cal, _sigma, ctx = calibrate_sequence(seq, self.opts.config)
        except SequenceError:
            # not yet (e.g. only unreadable frames): tried again with more frames; the final
            # measurement reports what stays wrong
            self.cal_frames = len(seq)
            return
        self.ctx, self.cal_frames = ctx, len(seq)
        if self.logger is not None:
            self.logger.log_calibration(cal, shape=cal.shape, orientation=seq.meta.orientation)


def _finish(folder: Path, out: Path, opts: WatchOptions, logger, done: dict, left_out: list[str],
            stats: dict) -> MeasureResult:
    """The final tables: `measure_sequence` over the complete frames (the whole folder when none
    is left out: the batch measurement itself), written as ``dropvision measure`` writes them,
    with the journal kept."""
    if not done:
        raise SequenceError(f"{folder}: no complete frame arrived (the watch ended by {stats['ended_by']})")
    # the complete files: with every frame complete, the same listing as the folder's own
    seq = open_sequence(folder, overrides=opts.overrides, labels=opts.labels, only_files=set(done))
    result = measure_sequence(seq, None, opts.config, logger=logger)
    journal = out / JOURNAL
    with atomic_dir(out, inputs=[folder], overwrite=opts.overwrite, kind="measurement") as tmp:
        write_result(result, tmp, csv=opts.csv)
        (tmp / JOURNAL).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(journal, tmp / JOURNAL)
        write_json(tmp / WATCH_JSON, {"schema": schema.WATCH.schema, "sequence": str(folder), "state": "finished",
                                      **stats, "left_out": left_out})
    return result


# --- shots: one image per shot ------------------------------------------------------------------

def _live_shots_table(rows: list[dict]):
    """The live shots.parquet: rows (one dict each: `dvcore.schema.SHOTS` columns, then labels) in
    arrival order, the label columns in the order first met."""
    import pandas as pd

    declared = schema.SHOTS.column_names
    labels: list[str] = []
    for r in rows:
        labels += [k for k in r if k not in declared and k not in labels]
    table = pd.DataFrame(rows, columns=declared + labels)
    for col in schema.SHOTS.columns:
        if col.dtype == "int":
            table[col.name] = table[col.name].astype("Int64")
        elif col.dtype == "float":
            table[col.name] = pd.to_numeric(table[col.name]).astype(float)
        elif col.dtype == "bool":
            table[col.name] = table[col.name].astype(bool)
        else:
            table[col.name] = table[col.name].astype(object)
    for col in labels:
        table[col] = pd.to_numeric(table[col]).astype(float)
    return table


def _shot_rows(folder: Path, name: str, opts: WatchOptions) -> tuple[dict, dict]:
    """Measure one image as a shot, alone (`dropvision.analysis.shots.measure_shots`): its shots row (the
    shot's own notes with it) and its journal row (`dvcore.schema.LIVE_FRAMES`)."""
    import pandas as pd

    from dropvision.io.labels import LabelError
    from dropvision.analysis.shots import measure_shots, shots_of, shots_table

    try:
        shots = shots_of(folder, [name], label_pattern=opts.label_pattern)
    except LabelError as exc:  # the final measurement refuses the folder as `dropvision measure` does
        from dropvision.analysis.shots import ShotInput

        shots, reason = ShotInput([folder / name], [name], [folder]), str(exc)
    else:
        reason = None
    if reason is None:
        try:
            res = measure_shots(shots, None, opts.config, overrides=opts.overrides, option_labels=opts.labels)
        except SequenceError as exc:
            reason = str(exc)
    delay_us = float((opts.overrides or {}).get("delay_us") or 0.0)
    if reason is not None:
        empty = pd.DataFrame({c: pd.Series(dtype=object) for c in schema.FRAMES.column_names})
        row = shots_table(empty, shots, {}, {name: reason}, delay_us=delay_us).iloc[0].to_dict()
        live = {"file": name, "page": None, "delay_us": delay_us, "repeat": 0, "attached_volume_nl": math.nan,
                "attached_volume_uncertainty_nl": math.nan, "n_detached": 0, "drop_volume_nl": math.nan,
                "drop_z_um": math.nan, "drop_x_um": math.nan, "quality": schema.Quality.NOT_MEASURED,
                "blur_px": math.nan, "gain": math.nan, "error": reason, "calibration_frames": 1}
        return row, live
    row = res.shots.iloc[0].to_dict()
    row["notes"] = "; ".join([*res.summary["notes"], *([row["notes"]] if row["notes"] else [])])
    f = res.frames.iloc[0]
    bodies = res.bodies
    n_detached = 0 if bodies is None else int(bodies["body_class"].isin(("main_drop", "satellite", "tail")).sum())
    page = f["page"]
    live = {"file": name, "page": None if pd.isna(page) else int(page), "delay_us": float(f["delay_us"]),
            "repeat": int(f["repeat"]), "attached_volume_nl": float(f["attached_volume_nl"]),
            "attached_volume_uncertainty_nl": float(f["attached_volume_uncertainty_nl"]), "n_detached": n_detached,
            "drop_volume_nl": float(f["drop_volume_nl"]), "drop_z_um": float(f["drop_z_um"]),
            "drop_x_um": float(f["drop_x_um"]), "quality": str(f["quality"]), "blur_px": float(f["blur_px"]),
            "gain": float(f["gain"]), "error": None, "calibration_frames": 1}
    return row, live


def _decodes(folder: Path, name: str, opts: WatchOptions) -> str | None:
    """None when the image decodes (complete), else why not."""
    try:
        with open_sequence(folder, overrides=opts.overrides, labels=opts.labels, only_files=[name]) as seq:
            fr = seq.read(0)
    except SequenceError as exc:
        return str(exc)
    return None if fr.image is not None else (fr.error or "not decoded")


def _watch_shots_locked(folder: Path, out: Path, opts: WatchOptions, report, stop, rows: list[dict]
                        ) -> WatchResult:
    """`watch_sequence` of a folder that receives shots, OUT locked (``rows``: the journal resumed).

    Each image, once complete (as a sequence's frames: `_settled`, then it decodes), is measured alone
    (`_shot_rows`); its row is appended to OUT/shots.parquet (rewritten atomically, the rows so far in
    arrival order), then its journal row to ``live/frames.jsonl`` (so every image in the journal is in
    the table). The watch ends at ``opts.frames`` images, ``idle_s`` without one, ``stop`` or Ctrl-C;
    then `_finish_shots` writes the tables of ``dropvision measure``."""
    import pandas as pd

    from dropvision.app.campaign_dataset import parquet_bytes
    from dvcore.atomic import write_bytes

    n_resumed = len(rows)
    done = {r["file"]: (int(r.get("size") or -1), int(r.get("mtime_ns") or -1)) for r in rows}
    table_path = out / "shots.parquet"
    try:
        earlier = pd.read_parquet(table_path)
    except (OSError, ValueError):
        earlier = _live_shots_table([])
    table_rows = [r for r in earlier.to_dict("records") if r["file"] in done]
    missing = set(done) - {r["file"] for r in table_rows}
    for name in missing:  # never: the table is written before the journal
        done.pop(name)
    journal = Journal(out / JOURNAL)
    observer, events, pending = _start_watching(folder)
    latency: list[float] = []
    n_live, started_ns = 0, time.time_ns()
    last_frame_at = time.monotonic()
    ended_by = "interrupt"
    try:
        while True:
            ended = _why_ended(opts, len(done), opts.frames, pending, last_frame_at, stop)
            if ended is not None:
                ended_by = ended
                break
            _drain(events, pending, opts.poll_s)
            for name in _settled(folder, pending, done, {}, opts):
                p = pending[name]
                failed = _decodes(folder, name, opts)
                now = time.monotonic()
                try:
                    st = os.stat(folder / name)
                except OSError:
                    continue  # gone: dropped by the next look
                file_stat = (st.st_size, st.st_mtime_ns)
                if failed is not None and (file_stat != (p.size, p.mtime_ns) or now - p.changed_at
                                           < opts.unreadable_after_s):
                    p.failed, p.closed = failed, False  # not yet: tried again on its next change
                    continue
                row, live = _shot_rows(folder, name, opts)  # an image that stays unreadable: not_measured
                table_rows = [r for r in table_rows if r["file"] != name] + [row]
                write_bytes(table_path, parquet_bytes(_live_shots_table(table_rows)))
                done[name] = file_stat
                pending.pop(name, None)
                _journal_row(journal, live, file_stat, started_ns, latency)
                n_live += 1
                last_frame_at = time.monotonic()
                if report is not None:
                    report(live)
    except KeyboardInterrupt:
        ended_by = "interrupt"
    finally:
        observer.stop()
        journal.close()
    observer.join()
    left_out = sorted(pending)
    result = _finish_shots(folder, out, opts, done, left_out,
                           {"ended_by": ended_by, "n_live": n_live, "n_resumed": n_resumed,
                            "latency_ms_median": statistics.median(latency) if latency else None,
                            "latency_ms_max": max(latency) if latency else None})
    return WatchResult(result, ended_by, n_live, n_resumed, latency, left_out, kind="shots")


def _finish_shots(folder: Path, out: Path, opts: WatchOptions, done: dict, left_out: list[str], stats: dict):
    """The final tables of a shot watch: `dropvision.analysis.shots.measure_shots` over the complete images
    (when they are the folder's shots, exactly the input of ``dropvision measure FOLDER``), written
    as ``dropvision measure`` writes them, with the journal kept."""
    from dropvision.io.discovery import images_without_delay, natural_key
    from dropvision.analysis.shots import find_shots, measure_shots, shots_of

    if not done:
        raise SequenceError(f"{folder}: no complete image arrived (the watch ended by {stats['ended_by']})")
    listed = images_without_delay(folder)
    shots = None
    if listed is not None and set(listed) == set(done):
        shots = find_shots(folder, overrides=opts.overrides, label_pattern=opts.label_pattern)
    if shots is None or set(shots.names) != set(done):
        shots = shots_of(folder, sorted(done, key=natural_key), label_pattern=opts.label_pattern)
    result = measure_shots(shots, None, opts.config, overrides=opts.overrides, option_labels=opts.labels)
    from dropvision.output.result_writer import check_shots_result, write_shots_result

    checked = check_shots_result(result, out)
    journal = out / JOURNAL
    with atomic_dir(out, inputs=[folder], overwrite=opts.overwrite, kind="measurement") as tmp:
        write_shots_result(result, tmp, checked, csv=opts.csv)
        (tmp / JOURNAL).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(journal, tmp / JOURNAL)
        write_json(tmp / WATCH_JSON, {"schema": schema.WATCH.schema, "sequence": str(folder), "kind": "shots",
                                      "state": "finished", **stats, "left_out": left_out})
    return result


# --- one sequence after the other ---------------------------------------------------------------

def _sequence_folders(root: Path) -> list[Path]:
    """The sub-folders of ``root`` (not hidden), in name order."""
    try:
        entries = [e for e in os.scandir(root) if e.is_dir(follow_symlinks=False) and not e.name.startswith(".")]
    except OSError as exc:
        raise SequenceError(f"{root}: cannot list the folder ({exc.strerror or exc})") from None
    return [Path(e.path) for e in sorted(entries, key=lambda e: e.name)]


def _finished(out: Path) -> bool:
    """An earlier watch of this sequence ended by itself (not interrupted): its tables are final."""
    try:
        doc = loads_strict((out / WATCH_JSON).read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return False
    return isinstance(doc, dict) and doc.get("state") == "finished" and doc.get("ended_by") != "interrupt"


def watch_sequences(root, out_root, options: WatchOptions = WatchOptions(), *, logger_for=None, report=None,
                    announce=None) -> tuple[list[WatchResult], dict[str, str]]:
    """Watch a folder in which a drop watcher writes one sequence per sub-folder, one after the other.

    Each sub-folder (in name order) is watched with `watch_sequence` into ``OUT_ROOT/<name>``;
    it ends at its expected frame count, after ``options.idle_s`` without a new frame, or
    when a later sub-folder appears while none of its frames is being written. The watch ends
    ``options.idle_s`` after the last sequence ended without a new sub-folder (never, when
    None), or on Ctrl-C. Sequences an earlier watch finished are not watched again; one it
    was interrupted in is resumed.

    Parameters
    ----------
    root : str or Path
        The folder the sequence folders appear in (never written to).
    out_root : str or Path
        One output folder per sequence inside it (a folder of ours, `dvcore.atomic.claim_dir`:
        never replaced as a whole).
    options : WatchOptions
        For every sequence.
    logger_for : callable, optional
        ``logger_for(name)``: a Rerun logger for the sequence (or None), closed after it.
    report : callable, optional
        Called with each live row (see `watch_sequence`).
    announce : callable, optional
        Called with ``(name, WatchResult)`` when a sequence is finished, ``(name, SequenceError)``
        when it could not be measured (the watch goes on with the next).

    Returns
    -------
    results : list of WatchResult
        The sequences watched by this run, in order.
    failed : dict
        Sequence name -> why it could not be measured.
    """
    from dvcore.atomic import claim_dir

    root, out_root = Path(root).absolute(), Path(out_root)
    if not root.is_dir():
        raise SequenceError(f"{root}: no such folder")
    claim_dir(out_root, inputs=[root], overwrite=options.overwrite, kind="live measurements")
    with output_lock(out_root):  # held to the end: a second watch on OUT_ROOT is refused at once
        return _watch_all(root, out_root, options, logger_for, report, announce)


def _watch_all(root: Path, out_root: Path, options: WatchOptions, logger_for, report, announce
               ) -> tuple[list[WatchResult], dict[str, str]]:
    """`watch_sequences` with OUT_ROOT claimed and locked."""
    results: list[WatchResult] = []
    failed: dict[str, str] = {}
    watched: set[str] = set()
    last_end = time.monotonic()
    try:
        while True:
            todo = [f for f in _sequence_folders(root) if f.name not in watched]
            if not todo:
                if options.idle_s is not None and time.monotonic() - last_end >= options.idle_s:
                    break
                time.sleep(options.poll_s)
                continue
            folder = todo[0]
            watched.add(folder.name)
            out = out_root / folder.name
            if _finished(out):
                continue

            def later_began(name=folder.name) -> bool:
                return any(f.name > name for f in _sequence_folders(root))

            logger = logger_for(folder.name) if logger_for is not None else None
            try:
                res = watch_sequence(folder, out, options, logger=logger, report=report, stop=later_began)
            except SequenceError as exc:  # this sequence cannot be measured: the others can
                res = exc
            finally:
                if logger is not None:
                    logger.close()
            if announce is not None:
                announce(folder.name, res)
            last_end = time.monotonic()
            if isinstance(res, SequenceError):
                failed[folder.name] = str(res)
                continue
            results.append(res)
            if res.ended_by == "interrupt":
                break
    except KeyboardInterrupt:  # between two sequences
        pass
    return results, failed
