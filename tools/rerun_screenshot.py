"""Open Rerun recordings in the headless Rerun viewer, save screenshots, check what they show.

Our tests read ``.rrd`` files back with ``rerun.chunk.RrdReader`` (the data is there); this tool
looks at what a person sees. For every recording it starts the Rerun 0.41 viewer headless (no
window; a software Vulkan driver is enough), opens the file, and through the viewer's control API
(``rerun.experimental.ViewerClient``):

1. waits until the recording is loaded and saves that default view, ``<stem>.png``. Times from
   the open request: ``index_s`` until the viewer's loading list is empty (the chunk index),
   ``load_s`` until the view stops changing (two small screenshots in a row alike outside the
   notification corner: the chunks fetched after the index are drawn, the plots rescaled),
   ``first_paint_s`` until the full-size screenshot is saved;
2. moves the time cursor of the ``delay`` timeline to a few times and saves the whole window,
   ``<stem>@<delay>us.png``, and every 2-D / 3-D view alone, ``<stem>@<delay>us-<view>.png``.
   Times: ``--times-us``, else for a measurement recording the frame with the most attached
   liquid, the middle of the frames with a main drop, the frame with the most satellite pixels
   (else the last frame) and the frame with the most pixels of the other body classes (out of
   focus, touching satellite, tail, cut by the border; when there are any); for other
   recordings the middle of the delay range;
3. quits the viewer through its own "Quit" command.

It asserts, per recording (a failed check is listed, and the exit status is 1):

* the viewer started, loaded the file and exited with status 0 within ``--timeout`` seconds;
* no error: no ERROR entry or "Failed to load" in the viewer's log (``ViewerClient.get_logs``)
  or its stderr, no view reporting an error (``ViewerState.views[].reports``); view warnings are
  listed, not failed;
* every PNG exists, decodes, has the window / view size and is not empty: more than
  ``MIN_COLOURS`` distinct colours and more than ``MIN_FOREGROUND`` of its pixels differ from its
  most common (background) colour;
* measurement recordings (with ``/frame/segmentation``): on the frame views (the camera frame as
  stored, where the canonical layer is placed by a transform, and the normalised layer) at each time, the
  colour of every segmentation class that covers at least ``MIN_CLASS_PIXELS`` image pixels in
  the frame shown (read from the recording) is present: pixels of the class hue (the overlay is
  the class colour blended over a grey image, which keeps the hue) at saturation >= 0.2; every
  class has its own hue (named by the recording's annotation context);
* identification recordings (with ``/identify/controls/training``): on the (u1, u2) view, the
  colour of every training point and of the predicted point is present.

Unless ``--no-oneshot``, it also runs the documented one-shot command
``rerun --headless --window-size WxH --screenshot-to <stem>-oneshot.png FILE`` (exit status 0
within the time limit, no error in stderr, PNG not empty), the way the issue's first-open
"Failed to load ... Data source finished without loading a recording" was seen. That command
shoots after a fixed number of frames whether the data has arrived or not: a one-shot PNG with
less than half the non-background pixels (or a fifth of the colours) of the loaded default view
is listed as a warning ("incomplete"), not a failure.

Needs a graphics adapter the viewer can use. On a machine without a GPU::

    apt-get install -y mesa-vulkan-drivers     # lavapipe: software Vulkan, CPU only

The viewer finds the driver by itself (``VK_ICD_FILENAMES`` is honoured when set). Without one the
tool says so and exits 2 (``probe()`` gives the reason; the tests skip on it).  Only a missing
graphics adapter and a viewer that does not answer in time are "no viewer": any other failure of
the probe (no rerun executable, the viewer exiting with an error of its own, a Rerun API change,
a screenshot that is no PNG) raises :class:`ViewerBroken`, exit status 1 here and a failure in
the tests.

Usage::

    python tools/rerun_screenshot.py                     # every out/*.rrd -> out/screenshots/
    python tools/rerun_screenshot.py a.rrd b.rrd --out shots/ [--times-us 300,1200] [--json]

Per recording it prints the file size, size per frame, load time and the checks; ``--json``
prints the results as JSON (also written to ``<out>/screenshots.json``).
"""

from __future__ import annotations

import argparse
import colorsys
import glob
import io
import json
import os
import platform
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

INSTALL_HINT = "apt-get install -y mesa-vulkan-drivers  (software Vulkan driver, CPU only)"
#: a screenshot with fewer distinct colours is "empty"
MIN_COLOURS = 32
#: ... or with a smaller fraction of pixels differing from its most common colour
MIN_FOREGROUND = 0.02
#: a segmentation class must cover this many image pixels to be required in the screenshot
MIN_CLASS_PIXELS = 12
#: class ids from this one on are the body classes beyond nozzle, attached liquid, main drop,
#: satellite and static speck (`dropvision.frame.segmentation.CLASS_OUT_OF_FOCUS` ...)
OTHER_CLASSES_FROM = 6
#: screen pixels of a class hue needed to call the class "present"
MIN_HUE_PIXELS = 12
HUE_TOLERANCE_DEG = 8.0
#: the "loaded" screenshots (longest side, px) and how long to wait for the view to settle (s)
SETTLE_SIZE = 480
SETTLE_TIMEOUT = 30.0
#: Vulkan driver manifests are looked for here (the Vulkan loader's standard places)
ICD_DIRS = ("/usr/share/vulkan/icd.d", "/usr/local/share/vulkan/icd.d", "/etc/vulkan/icd.d")
_ERROR_PATTERNS = re.compile(r"Failed to load|panicked|\bERROR\b|No graphics adapter")
_ANSI = re.compile(r"\x1b\[[0-9;]*m")


class ViewerUnavailable(RuntimeError):
    """No Rerun viewer can render here: no graphics adapter, or the viewer does not answer in time."""


class ViewerBroken(RuntimeError):
    """The viewer is there but fails (a broken install or wrapper, a Rerun API change): an error,
    never a reason to skip."""


#: what the viewer writes when it finds no graphics adapter (wgpu / Vulkan loader messages)
_NO_ADAPTER = re.compile(r"no (suitable |graphics |compatible )?adapter|failed to find an? (appropriate |suitable )?adapter"
                         r"|ERROR_INCOMPATIBLE_DRIVER|vkCreateInstance|no vulkan", re.IGNORECASE)
#: an exception that says it timed out
_TIMED_OUT = re.compile(r"timed? ?out|deadline exceeded", re.IGNORECASE)


# --- environment -------------------------------------------------------------------------------


def rerun_executable() -> str | None:
    """The Rerun CLI binary of the installed rerun-sdk (``rerun_cli/rerun``), else ``rerun`` on
    PATH. The binary itself, not the Python shim, so that its exit status and pid are the viewer's."""
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).with_name("rerun.exe" if os.name == "nt" else "rerun")
        if exe.is_file():
            return str(exe)
    except ImportError:
        pass
    return shutil.which("rerun")


def vulkan_icds() -> list[str]:
    """Vulkan driver manifests (``VK_ICD_FILENAMES`` when set, else the standard folders)."""
    env = os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES")
    if env:
        return [p for p in env.split(os.pathsep) if Path(p).is_file()]
    return sorted(p for d in ICD_DIRS for p in glob.glob(os.path.join(d, "*.json")))


def viewer_env(tmp: Path) -> dict[str, str]:
    env = dict(os.environ)
    run_dir = tmp / "xdg"
    run_dir.mkdir(mode=0o700, exist_ok=True)
    env.setdefault("XDG_RUNTIME_DIR", str(run_dir))  # silences "XDG_RUNTIME_DIR is invalid"
    env.setdefault("RUST_BACKTRACE", "0")
    return env


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _tail(path: Path, n: int = 2000) -> str:
    try:
        text = _ANSI.sub("", path.read_text(errors="replace"))
    except OSError:
        return ""
    lines = [ln for ln in text.splitlines() if ln.strip() and not re.match(r"\s+(at |\d+: )", ln)]
    return "\n".join(lines)[-n:]


# --- the viewer --------------------------------------------------------------------------------


class Viewer:
    """A headless Rerun viewer process on a free local port, driven by ``ViewerClient``.

    ``with Viewer(tmp) as v: v.client.open(...)``; :meth:`quit` asks the viewer to quit through
    its own command and returns its exit status (None: it had to be killed).
    """

    def __init__(self, tmp: Path, *, window_size: str = "1600x1000", timeout: float = 60.0) -> None:
        exe = rerun_executable()
        if exe is None:
            raise ViewerBroken("no rerun executable (pip install rerun-sdk==0.41.*)")
        self.tmp = Path(tmp)
        self.tmp.mkdir(parents=True, exist_ok=True)
        self.port = _free_port()
        self.stderr_path = self.tmp / f"viewer-{self.port}.stderr"
        self.timeout = timeout
        self.returncode: int | None = None
        cmd = [exe, "--headless", "--window-size", window_size, "--port", str(self.port),
               "--bind", "127.0.0.1", "--hide-welcome-screen", "--memory-limit", "2GB"]
        with open(self.stderr_path, "wb") as err:
            self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=err, stderr=err,
                                         env=viewer_env(self.tmp), start_new_session=True)
        self.client = self._connect(time.monotonic() + timeout)

    def _connect(self, deadline: float) -> Any:
        from rerun.experimental import ViewerClient

        last: Exception | None = None
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                self.returncode = self.proc.returncode
                why = f"the viewer exited with status {self.proc.returncode} at start: {_tail(self.stderr_path, 600)}"
                if _NO_ADAPTER.search(_tail(self.stderr_path, 100_000)):
                    raise ViewerUnavailable(why)
                raise ViewerBroken(why)
            try:
                client = ViewerClient(f"rerun+http://127.0.0.1:{self.port}/proxy")
                client.get_state()
                return client
            except Exception as exc:  # noqa: BLE001 - not listening yet
                last = exc
                time.sleep(0.05)
        self.kill()
        raise ViewerUnavailable(f"no answer from the viewer within {self.timeout:g} s ({last}): "
                                f"{_tail(self.stderr_path, 600)}")

    def stderr(self) -> str:
        return _tail(self.stderr_path, 100_000)

    def quit(self, timeout: float = 20.0) -> int | None:
        """Quit through the viewer's "Quit" command; exit status, or None when it had to be killed."""
        if self.proc.poll() is None:
            try:
                self.client.run_command("ui.quit")
            except Exception:  # noqa: BLE001 - it may close the connection while answering
                pass
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.kill()
                return None
        self.returncode = self.proc.returncode
        return self.returncode

    def kill(self) -> None:
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError, AttributeError):
                self.proc.kill()
            self.proc.wait(10)

    def __enter__(self) -> Viewer:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc.poll() is None:
            self.quit()


_PROBE: tuple[bool, str] | ViewerBroken | None = None


def probe(timeout: float = 60.0) -> tuple[bool, str]:
    """Whether a headless viewer can start and paint here: ``(True, adapter line)`` or
    ``(False, reason)`` when there is no graphics adapter or the viewer does not answer in time
    (the reason names the install line). Cached per process.

    Raises
    ------
    ViewerBroken
        Any other failure: no rerun executable, the viewer exiting with an error that is not a
        missing adapter, a screenshot that is no PNG, a non-zero exit status, an unexpected
        exception (a broken wrapper, a Rerun API change).
    """
    global _PROBE
    if isinstance(_PROBE, ViewerBroken):
        raise _PROBE
    if _PROBE is not None:
        return _PROBE
    try:
        _PROBE = _probe(timeout)
    except ViewerBroken as exc:
        _PROBE = exc
        raise
    return _PROBE


def _probe(timeout: float) -> tuple[bool, str]:
    """`probe` without the cache."""
    if rerun_executable() is None:
        raise ViewerBroken("no rerun executable (pip install rerun-sdk==0.41.*)")
    if platform.system() == "Linux" and not vulkan_icds():
        return (False, f"no Vulkan driver (no ICD manifest in {', '.join(ICD_DIRS)}); install one: {INSTALL_HINT}")
    with tempfile.TemporaryDirectory(prefix="rrshot-probe-") as tmp:
        try:
            with Viewer(Path(tmp), window_size="320x240", timeout=timeout) as viewer:
                png = viewer.client.take_screenshot(max_size=64)
                adapter = next((ln for ln in viewer.stderr().splitlines() if "adapter" in ln), "")
                rc = viewer.quit()
        except ViewerBroken:
            raise
        except ViewerUnavailable as exc:
            return (False, f"{exc}; install a Vulkan driver: {INSTALL_HINT}")
        except Exception as exc:  # noqa: BLE001 - a timeout is "no viewer", anything else is broken
            if isinstance(exc, TimeoutError) or _TIMED_OUT.search(str(exc)):
                return (False, f"the viewer timed out ({type(exc).__name__}: {exc})")
            raise ViewerBroken(f"the viewer probe failed: {type(exc).__name__}: {exc}") from exc
    if not isinstance(png, bytes) or not png.startswith(b"\x89PNG"):
        raise ViewerBroken(f"the viewer's screenshot is no PNG: {png[:16]!r}")
    if rc is None:  # a timeout like any other: it had to be killed (a machine too busy to quit in time)
        return (False, "the viewer took its screenshot but did not quit within 20 s (killed)")
    if rc != 0:
        raise ViewerBroken(f"the viewer exited with status {rc}")
    return (True, adapter.split(": ", 1)[-1].strip())


# --- what the recording holds (read with rerun.chunk.RrdReader) -------------------------------


@dataclass
class RecordingFacts:
    frames: int | None = None  # number of frames (``frame`` timeline), measurement recordings
    delays_ns: list[int] = field(default_factory=list)
    #: delay_ns -> class id -> pixel count of /frame/segmentation
    classes: dict[int, dict[int, int]] = field(default_factory=dict)
    #: class id -> RGBA of the annotation context at /frame
    class_colours: dict[int, tuple[int, int, int, int]] = field(default_factory=dict)
    #: class id -> label of the annotation context at /frame
    class_names: dict[int, str] = field(default_factory=dict)
    #: RGBA colours of /identify/controls/{training, prediction}
    control_colours: list[tuple[int, int, int, int]] = field(default_factory=list)


def _rgba(packed: int) -> tuple[int, int, int, int]:
    packed = int(packed) & 0xFFFFFFFF
    return (packed >> 24) & 255, (packed >> 16) & 255, (packed >> 8) & 255, packed & 255


def read_facts(path: Path) -> RecordingFacts:
    """Frames, segmentation classes per delay and the colours to look for, from the file."""
    import pyarrow as pa
    import rerun as rr

    facts = RecordingFacts()
    frames: set[int] = set()
    delays: set[int] = set()
    for chunk in rr.chunk.RrdReader(path).stream():
        batch = chunk.to_record_batch()
        names = batch.schema.names
        entity = chunk.entity_path
        if not chunk.is_static:
            if "frame" in names:
                frames.update(v for v in batch.column("frame").to_pylist() if v is not None)
            if "delay" in names:
                delays.update(v for v in batch.column("delay").cast(pa.int64()).to_pylist() if v is not None)
        if entity == "/frame/segmentation" and "SegmentationImage:buffer" in names:
            times = batch.column("delay").cast(pa.int64()).to_pylist()
            for t, buf in zip(times, batch.column("SegmentationImage:buffer").to_pylist()):
                if t is None or not buf:
                    continue
                ids, counts = np.unique(np.asarray(buf[0], dtype=np.uint8), return_counts=True)
                facts.classes[int(t)] = {int(i): int(c) for i, c in zip(ids, counts)}
        elif entity == "/frame" and "AnnotationContext:context" in names:
            row = batch.column("AnnotationContext:context").to_pylist()[-1] or []
            for ctx in (row[0] if row and isinstance(row[0], list) else row):
                info = ctx["class_description"]["info"]
                if info.get("color") is not None:
                    facts.class_colours[int(info["id"])] = _rgba(info["color"])
                if info.get("label"):
                    facts.class_names[int(info["id"])] = str(info["label"])
        elif entity in ("/identify/controls/training", "/identify/controls/prediction") \
                and "Points2D:colors" in names:
            facts.control_colours += [_rgba(c) for c in batch.column("Points2D:colors").to_pylist()[-1] or []]
    facts.frames = len(frames) or None
    facts.delays_ns = sorted(delays)
    return facts


def choose_times_ns(facts: RecordingFacts, start: int | None, end: int | None) -> list[int]:
    """A few delays worth looking at (see the module docstring)."""
    seg = facts.classes
    if seg:
        out = []
        attached = {t: c.get(2, 0) for t, c in seg.items()}
        if max(attached.values()) > 0:
            out.append(max(attached, key=attached.get))
        with_drop = sorted(t for t, c in seg.items() if c.get(3, 0) > 0)
        if with_drop:
            out.append(with_drop[len(with_drop) // 2])
        sats = {t: c.get(4, 0) for t, c in seg.items()}
        out.append(max(sats, key=sats.get) if max(sats.values()) > 0 else max(seg))
        # the other body classes (out of focus, touching satellite, tail, cut by the border)
        others = {t: sum(n for cid, n in c.items() if cid >= OTHER_CLASSES_FROM) for t, c in seg.items()}
        if max(others.values()) >= MIN_CLASS_PIXELS:
            out.append(max(others, key=others.get))
        return sorted(set(out))
    if start is None or end is None:
        return []
    return [int(start + (end - start) // 2)]


# --- image checks ------------------------------------------------------------------------------


def _load_png(data: bytes | Path) -> np.ndarray:
    from PIL import Image

    with Image.open(io.BytesIO(data) if isinstance(data, bytes) else data) as im:
        return np.asarray(im.convert("RGB"))


def image_stats(img: np.ndarray) -> dict[str, float]:
    """Distinct colours, and the fraction of pixels differing from the most common colour."""
    flat = img.reshape(-1, img.shape[-1]).astype(np.uint32)
    packed = (flat[:, 0] << 16) | (flat[:, 1] << 8) | flat[:, 2]
    values, counts = np.unique(packed, return_counts=True)
    return {"colours": int(values.size), "foreground": float(1.0 - counts.max() / packed.size)}


def _hsv(img: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rgb = img.astype(np.float64) / 255.0
    mx, mn = rgb.max(-1), rgb.min(-1)
    d = mx - mn
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.where(mx == r, ((g - b) / d) % 6, np.where(mx == g, (b - r) / d + 2, (r - g) / d + 4))
        s = np.where(mx > 0, d / mx, 0.0)
    return np.nan_to_num(h * 60.0), s, mx


def hue_pixels(img: np.ndarray, rgb: Sequence[int], *, tol_deg: float = HUE_TOLERANCE_DEG) -> int:
    """Pixels of ``img`` with the hue of colour ``rgb`` (saturation >= 0.2, value >= 0.12)."""
    h0, _s0, _v0 = colorsys.rgb_to_hsv(*(c / 255.0 for c in rgb[:3]))
    h, s, v = _hsv(img)
    dh = np.abs((h - 360.0 * h0 + 180.0) % 360.0 - 180.0)
    return int(np.count_nonzero((dh <= tol_deg) & (s >= 0.2) & (v >= 0.12)))


def colour_pixels(img: np.ndarray, rgb: Sequence[int], *, tol: int = 24) -> int:
    """Pixels within ``tol`` (per channel) of colour ``rgb``."""
    diff = np.abs(img.astype(np.int16) - np.asarray(rgb[:3], dtype=np.int16)).max(-1)
    return int(np.count_nonzero(diff <= tol))


def _chromatic(rgba: Sequence[int]) -> bool:
    _h, s, v = colorsys.rgb_to_hsv(*(c / 255.0 for c in rgba[:3]))
    return s >= 0.4 and v >= 0.3 and (len(rgba) < 4 or rgba[3] > 0)


# --- one recording -----------------------------------------------------------------------------


@dataclass
class Shot:
    path: str
    delay_us: float | None
    view: str | None  # None: the whole window
    colours: int = 0
    foreground: float = 0.0
    found: dict[str, int] = field(default_factory=dict)  # expected colour -> pixels found


@dataclass
class Result:
    recording: str
    size_bytes: int
    frames: int | None = None
    bytes_per_frame: float | None = None
    start_s: float | None = None  # viewer started and answering
    index_s: float | None = None  # open -> the viewer's loading list empty (the chunk index)
    load_s: float | None = None  # open -> the view stops changing (the data shown)
    first_paint_s: float | None = None  # open -> the first screenshot painted
    total_s: float | None = None
    exit_status: int | None = None
    oneshot_s: float | None = None
    oneshot_exit_status: int | None = None
    shots: list[Shot] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.failures


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_")[:40] or "view"


def _check_png(res: Result, shot: Shot, img: np.ndarray | None, expect_size: tuple[int, int] | None) -> None:
    if img is None:
        res.failures.append(f"{shot.path}: no PNG")
        return
    st = image_stats(img)
    shot.colours, shot.foreground = st["colours"], round(st["foreground"], 4)
    if expect_size is not None and (img.shape[1], img.shape[0]) != expect_size:
        res.warnings.append(f"{shot.path}: {img.shape[1]}x{img.shape[0]} px, expected {expect_size}")
    if st["colours"] < MIN_COLOURS or st["foreground"] < MIN_FOREGROUND:
        res.failures.append(f"{shot.path}: empty ({st['colours']} colours, "
                            f"{100 * st['foreground']:.1f} % non-background pixels)")


def _check_colours(res: Result, shot: Shot, img: np.ndarray, expected: dict[str, tuple[int, ...]],
                   *, by_hue: bool) -> None:
    for name, rgba in expected.items():
        n = hue_pixels(img, rgba) if by_hue else colour_pixels(img, rgba)
        shot.found[name] = n
        if n < (MIN_HUE_PIXELS if by_hue else 3):
            res.failures.append(f"{shot.path}: colour of {name} {tuple(rgba[:3])} not found "
                                f"({n} px)")


def _wait_settled(client: Any, deadline: float) -> float:
    """Screenshots (small) until two in a row are equal, outside the notification corner (top
    right, where toasts come and go): the time of the first of the two (the view is complete:
    the viewer fetches chunks after the index, and plots rescale as they arrive)."""
    prev: np.ndarray | None = None
    t_prev = time.monotonic()
    while True:
        t = time.monotonic()
        img = _load_png(client.take_screenshot(max_size=SETTLE_SIZE)).astype(np.int16)
        h, w = img.shape[:2]
        img[: int(0.45 * h), int(0.72 * w):] = 0
        if prev is not None and prev.shape == img.shape and np.abs(img - prev).max() <= 2:
            return t_prev
        if t > deadline:
            return t
        prev, t_prev = img, t


def _wait_loaded(client: Any, deadline: float) -> Any:
    while True:
        st = client.get_state()
        rec = next((r for r in st.recordings if r.store_id == st.active_recording), None)
        if not st.loading and rec is not None and rec.timelines:
            return st, rec
        if time.monotonic() > deadline:
            raise TimeoutError(f"still loading: {[s.status for s in st.loading]}")
        time.sleep(0.02)


_CLASS_NAMES = {1: "nozzle", 2: "attached liquid", 3: "main drop", 4: "satellite", 5: "static speck",
                6: "out of focus", 7: "touching satellite", 8: "tail", 9: "cut by the border"}


def check_recording(path: Path, out_dir: Path, *, times_us: Sequence[float] | None = None,
                    window_size: str = "1600x1000", timeout: float = 120.0, oneshot: bool = True,
                    tmp: Path | None = None) -> Result:
    """Open ``path`` in a fresh headless viewer, save the screenshots into ``out_dir`` and check
    them (module docstring). Raises :class:`ViewerUnavailable` when no graphics adapter or no
    answer in time lets a viewer start, :class:`ViewerBroken` when it starts and fails."""
    path = Path(path).resolve()
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = path.stem
    res = Result(recording=str(path), size_bytes=path.stat().st_size)
    facts = read_facts(path)
    res.frames = facts.frames
    if facts.frames:
        res.bytes_per_frame = round(res.size_bytes / facts.frames, 1)
    w, h = (int(v) for v in window_size.lower().split("x"))
    own_tmp = tempfile.TemporaryDirectory(prefix="rrshot-") if tmp is None else None
    tmpdir = Path(own_tmp.name) if own_tmp is not None else Path(tmp)
    t_start = time.monotonic()
    deadline = t_start + timeout
    try:
        viewer = Viewer(tmpdir, window_size=window_size, timeout=min(60.0, timeout))
        res.start_s = round(time.monotonic() - t_start, 3)
        try:
            _session(viewer, res, path, out_dir, stem, facts, times_us, (w, h), deadline)
        except Exception as exc:  # noqa: BLE001 - a check failed by an exception: report it
            res.failures.append(f"{type(exc).__name__}: {exc}")
        finally:
            res.exit_status = viewer.quit()
            res.total_s = round(time.monotonic() - t_start, 3)
        if res.exit_status != 0:
            res.failures.append(f"the viewer exited with status {res.exit_status} "
                                f"(None: killed after not quitting)")
        if time.monotonic() > deadline:
            res.failures.append(f"took {res.total_s:g} s, over the {timeout:g} s limit")
        for line in viewer.stderr().splitlines():
            if _ERROR_PATTERNS.search(line):
                res.failures.append(f"viewer stderr: {line.strip()[:300]}")
        if oneshot:
            _oneshot(res, path, out_dir / f"{stem}-oneshot.png", window_size, timeout, tmpdir)
    finally:
        if own_tmp is not None:
            own_tmp.cleanup()
    return res


def _session(viewer: Viewer, res: Result, path: Path, out_dir: Path, stem: str, facts: RecordingFacts,
             times_us: Sequence[float] | None, size: tuple[int, int], deadline: float) -> None:
    client = viewer.client
    seq0 = max((e.sequence for e in client.get_logs()), default=None)
    t0 = time.monotonic()
    client.open(str(path))
    _state, rec = _wait_loaded(client, deadline)
    res.index_s = round(time.monotonic() - t0, 3)
    res.load_s = round(_wait_settled(client, min(deadline, time.monotonic() + SETTLE_TIMEOUT)) - t0, 3)
    default = out_dir / f"{stem}.png"
    client.save_screenshot(str(default))
    res.first_paint_s = round(time.monotonic() - t0, 3)
    shot = Shot(str(default), None, None)
    res.shots.append(shot)
    _check_png(res, shot, _load_png(default) if default.is_file() else None, None)

    delay = next((t for t in rec.timelines if t.name == "delay"), None)
    if times_us is not None:
        times_ns = [int(round(float(t) * 1000)) for t in times_us]
    else:
        times_ns = choose_times_ns(facts, None if delay is None else delay.start,
                                   None if delay is None else delay.end)
    if delay is None and times_ns:
        res.failures.append("the recording has no delay timeline")
        times_ns = []
    spatial = [v for v in client.get_state().views if v.view_class in ("2D", "3D") and v.visible]
    expected_controls = {f"point {i} {c[:3]}": c for i, c in enumerate(facts.control_colours)}
    for t_ns in times_ns:
        client.set_time("delay", duration=np.timedelta64(int(t_ns), "ns"), play_state="paused")
        tag = f"{t_ns / 1000:g}us"
        full = out_dir / f"{stem}@{tag}.png"
        client.save_screenshot(str(full))
        shot = Shot(str(full), t_ns / 1000.0, None)
        res.shots.append(shot)
        _check_png(res, shot, _load_png(full) if full.is_file() else None, None)
        # latest-at: the segmentation shown is the one at the last frame <= t
        shown = max((t for t in facts.classes if t <= t_ns), default=None)
        for view in spatial:
            try:
                png = client.take_screenshot(view.view_id)
            except Exception as exc:  # noqa: BLE001 - a view in a tab not shown has nothing painted
                if "not found" not in str(exc):
                    raise
                note = f"view {view.name!r} not on screen (a tab not shown): no view screenshot"
                if note not in res.warnings:
                    res.warnings.append(note)
                continue
            vpath = out_dir / f"{stem}@{tag}-{_slug(view.name)}.png"
            vpath.write_bytes(png)
            vshot = Shot(str(vpath), t_ns / 1000.0, view.name)
            res.shots.append(vshot)
            img = _load_png(png) if png.startswith(b"\x89PNG") else None
            _check_png(res, vshot, img, None)
            if img is None:
                continue
            # the classes are drawn on the camera frame (the main view, origin "/") and on the normalised layer
            if view.origin in ("/", "/frame") and shown is not None:
                name = {cid: facts.class_names.get(cid) or _CLASS_NAMES.get(cid, f"class {cid}")
                        for cid in facts.classes[shown]}
                expected = {name[cid]: facts.class_colours[cid]
                            for cid, n in facts.classes[shown].items()
                            if cid in facts.class_colours and n >= MIN_CLASS_PIXELS
                            and _chromatic(facts.class_colours[cid])}
                _check_colours(res, vshot, img, expected, by_hue=True)
            elif view.origin == "/identify/controls" and expected_controls:
                _check_colours(res, vshot, img, expected_controls, by_hue=False)
    # errors: the viewer's log, the views' own reports
    for entry in client.get_logs(after_sequence=seq0):
        if entry.level == "ERROR" or "Failed to load" in entry.message:
            res.failures.append(f"viewer log {entry.level}: {entry.message[:300]}")
    for view in client.get_state().views:
        for rep in view.reports:
            text = f"view {view.name!r} {rep.severity}: {rep.summary}"
            (res.failures if rep.severity == "error" else res.warnings).append(text)


def _oneshot(res: Result, path: Path, png: Path, window_size: str, timeout: float, tmp: Path) -> None:
    exe = rerun_executable()
    cmd = [str(exe), "--headless", "--window-size", window_size, "--port", str(_free_port()),
           "--bind", "127.0.0.1", "--screenshot-to", str(png), str(path)]
    t0 = time.monotonic()
    try:
        proc = subprocess.run(cmd, stdin=subprocess.DEVNULL, capture_output=True, timeout=timeout,
                              env=viewer_env(tmp), start_new_session=True)
    except subprocess.TimeoutExpired:
        res.failures.append(f"one-shot screenshot: no exit within {timeout:g} s")
        return
    res.oneshot_s = round(time.monotonic() - t0, 3)
    res.oneshot_exit_status = proc.returncode
    err = _ANSI.sub("", proc.stderr.decode(errors="replace") + proc.stdout.decode(errors="replace"))
    if proc.returncode != 0:
        res.failures.append(f"one-shot screenshot: exit status {proc.returncode}: {err[-400:]}")
    for line in err.splitlines():
        if _ERROR_PATTERNS.search(line):
            res.failures.append(f"one-shot stderr: {line.strip()[:300]}")
    shot = Shot(str(png), None, None)
    res.shots.append(shot)
    _check_png(res, shot, _load_png(png) if png.is_file() else None, None)
    # `--screenshot-to` shoots after a fixed number of frames, loaded or not: compare with the
    # settled default view of the session (a warning: the viewer's timing, not the recording)
    ref = res.shots[0] if res.shots and res.shots[0].view is None and res.shots[0] is not shot else None
    if ref is not None and shot.colours and (shot.foreground < 0.5 * ref.foreground
                                             or shot.colours < 0.2 * ref.colours):
        res.warnings.append(f"{shot.path}: incomplete ({100 * shot.foreground:.0f} % non-background pixels, "
                            f"{shot.colours} colours; loaded view: {100 * ref.foreground:.0f} %, "
                            f"{ref.colours}): `rerun --screenshot-to` does not wait for the data to load")


# --- command line ------------------------------------------------------------------------------


def _format(res: Result) -> str:
    mb = res.size_bytes / 1e6
    per = "" if res.bytes_per_frame is None else f", {res.frames} frames, {res.bytes_per_frame / 1e3:.1f} kB/frame"
    lines = [f"{Path(res.recording).name}: {'ok' if res.ok else 'FAILED'}  {mb:.2f} MB{per}; "
             f"viewer up {res.start_s} s, index {res.index_s} s, loaded (view settled) {res.load_s} s, "
             f"first screenshot {res.first_paint_s} s, "
             f"exit {res.exit_status}, total {res.total_s} s"
             + ("" if res.oneshot_s is None else f"; one-shot {res.oneshot_s} s (exit {res.oneshot_exit_status})")]
    for shot in res.shots:
        found = "" if not shot.found else "  " + ", ".join(f"{k}: {v} px" for k, v in shot.found.items())
        lines.append(f"  {shot.path}  ({shot.colours} colours, {100 * shot.foreground:.0f} % fg){found}")
    lines += [f"  warning: {w}" for w in res.warnings]
    lines += [f"  FAILED: {f}" for f in res.failures]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("recordings", nargs="*", type=Path, help="the .rrd files (default: out/*.rrd)")
    parser.add_argument("--out", type=Path, default=None,
                        help="folder for the PNGs (default: out/screenshots)")
    parser.add_argument("--times-us", default=None,
                        help="delays to look at, comma separated [us] (default: chosen per recording)")
    parser.add_argument("--window-size", default="1600x1000", help="viewer size in points (default 1600x1000)")
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds per recording (default 120)")
    parser.add_argument("--no-oneshot", action="store_true",
                        help="skip the one-shot `rerun --screenshot-to` run")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    args = parser.parse_args(argv)

    recordings = args.recordings or sorted(Path("out").glob("*.rrd"))
    if not recordings:
        print("rerun_screenshot: no recordings (run `make demo` for out/*.rrd)", file=sys.stderr)
        return 2
    out = args.out or Path("out/screenshots")
    try:
        ok, why = probe()
    except ViewerBroken as exc:
        print(f"rerun_screenshot: the Rerun viewer is broken here: {exc}", file=sys.stderr)
        return 1
    if not ok:
        print(f"rerun_screenshot: no Rerun viewer can render here: {why}", file=sys.stderr)
        return 2
    print(f"viewer: {why}", file=sys.stderr)
    times = None if args.times_us is None else [float(t) for t in args.times_us.split(",") if t.strip()]
    results = []
    for rrd in recordings:
        res = check_recording(rrd, out, times_us=times, window_size=args.window_size,
                              timeout=args.timeout, oneshot=not args.no_oneshot)
        results.append(res)
        if not args.json:
            print(_format(res), flush=True)
    payload = [dict(asdict(r), ok=r.ok) for r in results]
    (Path(out) / "screenshots.json").write_text(json.dumps(payload, indent=1))
    if args.json:
        print(json.dumps(payload, indent=1))
    return 0 if all(r.ok for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
