"""tools/rerun_screenshot.py: Rerun recordings opened in the real (headless) Rerun viewer.

The image checks and the reading of a recording run everywhere. The viewer tests need a
graphics adapter the viewer can use; on a machine without one (CI, containers), or when the
viewer does not answer in time, they skip with the install line (``apt-get install -y
mesa-vulkan-drivers``, a software Vulkan driver).  Any other failure of the probe (a broken
wrapper, a Rerun API change, a non-zero exit) fails them, and ``DROPVISION_REQUIRE_VIEWER=1``
turns the skip into a failure too (on a machine that is meant to have a viewer).
"""

from __future__ import annotations

import importlib.util
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from dropvision.app.rerun_log import (
    CLASS_ATTACHED,
    CLASS_BORDER,
    CLASS_DROP,
    CLASS_NOZZLE,
    CLASS_OUT_OF_FOCUS,
    CLASS_SATELLITE,
    CLASS_TAIL,
    CLASS_TOUCHING,
    CLASSES,
    RerunLogger,
)
from identify.app import rerun_log as irl
from dvcore.rerun_options import RerunOptions

#: seconds per test (fitted models, campaigns, subprocesses): left out of `make test-fast`
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]


def _load_tool():
    spec = importlib.util.spec_from_file_location("rerun_screenshot", ROOT / "tools" / "rerun_screenshot.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["rerun_screenshot"] = mod
    spec.loader.exec_module(mod)
    return mod


shot = _load_tool()
ROWS, COLS = 120, 64
DELAYS_US = [100.0, 400.0, 900.0, 1300.0]
#: the body classes of frame 3
OTHER_CLASSES = (CLASS_OUT_OF_FOCUS, CLASS_TOUCHING, CLASS_TAIL, CLASS_BORDER)


@dataclass(frozen=True)
class _Ref:
    index: int
    file: str
    page: int | None
    delay_us: float
    repeat: int


def _labels(i: int) -> np.ndarray:
    """Frame 0: nozzle + attached liquid; 1: + main drop; 2: main drop + a satellite; 3: main
    drop with a touching satellite, a tail above it, an out-of-focus droplet, a body cut by the
    bottom of the frame."""
    lab = np.zeros((ROWS, COLS), dtype=np.uint8)
    lab[:12, 20:44] = CLASS_NOZZLE
    if i < 2:
        lab[12:30 + 10 * i, 24:40] = CLASS_ATTACHED
    if 1 <= i <= 2:
        lab[50 + 20 * i:66 + 20 * i, 24:40] = CLASS_DROP
    if i == 2:
        lab[60:66, 48:54] = CLASS_SATELLITE  # off the axis (its label sits mid-frame)
    if i == 3:
        lab[40:62, 29:35] = CLASS_TAIL
        lab[66:82, 24:40] = CLASS_DROP
        lab[82:90, 28:36] = CLASS_TOUCHING
        lab[60:70, 4:14] = CLASS_OUT_OF_FOCUS
        lab[108:120, 22:42] = CLASS_BORDER
    return lab


@pytest.fixture(scope="module")
def measurement_rrd(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("shot") / "measure-tiny.rrd"
    with RerunLogger(RerunOptions(path=path, application_id="dv_test", recording_name="tiny")) as logger:
        logger.log_calibration({"tip_row": 11.0, "axis_col": 31.5, "tilt_deg": 0.0, "pixel_size_um": 4.0},
                               shape=(ROWS, COLS))
        for i, delay in enumerate(DELAYS_US):
            lab = _labels(i)
            transmission = np.where(lab > 0, 0.1, 1.0)
            camera = (200.0 * transmission).astype(np.uint8)  # the frame as stored (nozzle at the top already)
            logger.log_frame(_Ref(i, f"f{i}.png", None, delay, 0), camera, transmission, lab, None, None,
                             row={"grown_volume_nl": 1.0 + i, "flow_velocity_m_s": 1.0 - 0.2 * i})
        logger.log_summary({"inflight_volume_nl": 1.5})
    return path


@pytest.fixture(scope="module")
def identification_rrd(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("shot") / "identify-tiny.rrd"
    rec = irl.open_identify_recording(RerunOptions(path=path, application_id="dv_test"))
    grid = [(a, b) for a in (50.0, 80.0) for b in (20.0, 35.0)]
    colours = irl.sequence_colours([a for a, _ in grid], [b for _, b in grid])
    t = np.linspace(0.0, 1000.0, 21)
    for k, ((u1, u2), colour) in enumerate(zip(grid, colours)):
        vol = (u1 * u2 / 100.0) * np.sin(math.pi * t / 2000.0) ** 2
        irl.log_sequence_fit(rec, irl.control_name(u1, u2), t, vol, vol * (1.0 + 0.01 * k), colour=colour,
                             controls=(u1, u2), pinchoff=(t[-1], vol[-1]))
    irl.log_training_points(rec)
    irl.close_recording(rec)
    return path


# --- everywhere: reading the recording, the image checks ---------------------------------------


def test_read_facts_and_times(measurement_rrd, identification_rrd):
    facts = shot.read_facts(measurement_rrd)
    assert facts.frames == 4
    ns = [int(d * 1000) for d in DELAYS_US]
    assert sorted(facts.classes) == ns
    assert facts.classes[ns[0]][CLASS_ATTACHED] == 18 * 16
    assert facts.classes[ns[2]][CLASS_SATELLITE] == 36
    assert facts.classes[ns[3]][CLASS_TOUCHING] == 64
    assert facts.class_colours[CLASS_DROP] == CLASSES[CLASS_DROP][1]
    assert facts.class_names == {cid: label for cid, (label, _) in CLASSES.items()}
    # the frame with the most attached liquid, the middle frame with a drop, the most satellite,
    # the most of the other body classes
    assert shot.choose_times_ns(facts, ns[0], ns[-1]) == [ns[1], ns[2], ns[3]]
    ident = shot.read_facts(identification_rrd)
    assert ident.frames is None and ident.classes == {}
    assert len(ident.control_colours) == 4
    assert shot.choose_times_ns(ident, 0, 1_000_000) == [500_000]


def test_image_checks():
    flat = np.zeros((40, 60, 3), dtype=np.uint8)
    assert shot.image_stats(flat) == {"colours": 1, "foreground": 0.0}
    img = flat.copy()
    img[10:20, 10:30] = (255, 255, 255)
    assert shot.image_stats(img)["foreground"] == pytest.approx(200 / 2400)
    # a class colour blended at 45 % over grey keeps its hue: found; another hue is not
    red = np.asarray(CLASSES[CLASS_DROP][1][:3], dtype=float)
    grey = np.full((30, 30, 3), 200.0)
    blend = np.round(0.45 * red + 0.55 * grey).astype(np.uint8)
    assert shot.hue_pixels(blend, CLASSES[CLASS_DROP][1]) == 900
    assert shot.hue_pixels(blend, CLASSES[CLASS_ATTACHED][1]) == 0
    assert shot.hue_pixels(np.full((5, 5, 3), 128, np.uint8), CLASSES[CLASS_DROP][1]) == 0  # grey: no hue
    assert shot.colour_pixels(img, (250, 250, 250)) == 200


def test_no_viewer_is_reported_with_the_install_line(monkeypatch):
    monkeypatch.setattr(shot, "_PROBE", None)
    monkeypatch.setattr(shot, "vulkan_icds", lambda: [])
    monkeypatch.setattr(shot.platform, "system", lambda: "Linux")
    ok, why = shot.probe()
    assert not ok and "apt-get install -y mesa-vulkan-drivers" in why
    monkeypatch.setattr(shot, "_PROBE", None)


class _FakeViewer:
    """Stands in for `Viewer` in the probe: a screenshot (or an exception) and an exit status."""

    shot: object = b"\x89PNG fake"
    rc = 0

    def __init__(self, tmp, **kwargs):
        self.client = self

    def take_screenshot(self, max_size):
        if isinstance(self.shot, Exception):
            raise self.shot
        return self.shot

    def stderr(self):
        return "wgpu adapter: llvmpipe (LLVM 15.0.7, 256 bits)"

    def quit(self):
        return self.rc

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None


@pytest.fixture
def fake_viewer(monkeypatch):
    """A probe that finds an executable and a Vulkan driver and starts `_FakeViewer`."""
    monkeypatch.setattr(shot, "_PROBE", None)
    monkeypatch.setattr(shot, "rerun_executable", lambda: "/bin/true")
    monkeypatch.setattr(shot, "vulkan_icds", lambda: ["lvp_icd.json"])
    monkeypatch.setattr(shot, "Viewer", _FakeViewer)
    return _FakeViewer  # monkeypatch restores the class, the cached probe and the module


def test_probe_with_a_working_viewer(fake_viewer):
    assert shot.probe() == (True, "llvmpipe (LLVM 15.0.7, 256 bits)")


@pytest.mark.parametrize("error", [TimeoutError("screenshot"), RuntimeError("request timed out after 60 s")])
def test_a_viewer_timeout_is_no_viewer(fake_viewer, monkeypatch, error):
    monkeypatch.setattr(fake_viewer, "shot", error)
    ok, why = shot.probe()
    assert not ok and "timed out" in why


def test_a_viewer_too_slow_to_quit_is_no_viewer(fake_viewer, monkeypatch):
    """A screenshot taken, then no exit within the quit's 20 s (killed, status None: seen in a fresh
    clone's `make test` on 2 busy cores): a timeout like the others, a skip, not `ViewerBroken`."""
    monkeypatch.setattr(fake_viewer, "rc", None)
    ok, why = shot.probe()
    assert not ok and "did not quit" in why


@pytest.mark.parametrize("problem", ["api", "no png", "exit status"])
def test_a_broken_viewer_is_a_failure_not_a_skip(fake_viewer, monkeypatch, problem):
    if problem == "api":  # e.g. a Rerun API change under the wrapper
        monkeypatch.setattr(fake_viewer, "shot", AttributeError("'ViewerClient' object has no attribute 'take_screenshot'"))
    elif problem == "no png":
        monkeypatch.setattr(fake_viewer, "shot", b"")
    else:
        monkeypatch.setattr(fake_viewer, "rc", 3)
    with pytest.raises(shot.ViewerBroken):
        shot.probe()
    with pytest.raises(shot.ViewerBroken):  # cached: the second probe says the same
        viewer_or_skip()


@pytest.mark.parametrize("stderr, kind", [("wgpu: No graphics adapter found", "ViewerUnavailable"),
                                          ("Traceback: ImportError: libfoo.so", "ViewerBroken")])
def test_a_viewer_exiting_at_start(tmp_path, monkeypatch, stderr, kind):
    """Exiting at start is "no viewer" only when the viewer says it found no adapter."""
    exe = tmp_path / "rerun"
    exe.write_text(f"#!/bin/sh\necho '{stderr}' >&2\nexit 1\n")
    exe.chmod(0o755)
    monkeypatch.setattr(shot, "rerun_executable", lambda: str(exe))
    with pytest.raises(getattr(shot, kind)):
        shot.Viewer(tmp_path / "v", timeout=20)


def test_the_tool_exits_1_on_a_broken_viewer(fake_viewer, monkeypatch, measurement_rrd, tmp_path, capsys):
    monkeypatch.setattr(fake_viewer, "rc", 3)
    assert shot.main([str(measurement_rrd), "--out", str(tmp_path)]) == 1
    assert "the Rerun viewer is broken here: the viewer exited with status 3" in capsys.readouterr().err


def test_require_viewer_turns_the_skip_into_a_failure(monkeypatch):
    monkeypatch.setattr(shot, "_PROBE", (False, "no Vulkan driver"))
    monkeypatch.delenv("DROPVISION_REQUIRE_VIEWER", raising=False)
    with pytest.raises(pytest.skip.Exception):
        viewer_or_skip()
    monkeypatch.setenv("DROPVISION_REQUIRE_VIEWER", "1")
    with pytest.raises(pytest.fail.Exception, match="DROPVISION_REQUIRE_VIEWER=1: no Rerun viewer"):
        viewer_or_skip()
    monkeypatch.setattr(shot, "_PROBE", None)


# --- with a viewer ----------------------------------------------------------------------------


def viewer_or_skip() -> str:
    """The probe's adapter line; skip when there is no viewer (no adapter, a timeout) unless
    ``DROPVISION_REQUIRE_VIEWER=1``; a broken viewer (`ViewerBroken`) raises: a failure."""
    ok, why = shot.probe()
    if not ok:
        msg = f"no Rerun viewer can render here: {why} (install: {shot.INSTALL_HINT})"
        if os.environ.get("DROPVISION_REQUIRE_VIEWER") == "1":
            pytest.fail(f"DROPVISION_REQUIRE_VIEWER=1: {msg}")
        pytest.skip(msg)
    return why


@pytest.fixture(scope="module")
def viewer_ok():
    return viewer_or_skip()


def test_measurement_recording_in_the_viewer(viewer_ok, measurement_rrd, tmp_path):
    res = shot.check_recording(measurement_rrd, tmp_path, window_size="1000x700", timeout=120, oneshot=True)
    assert res.ok, "\n".join(res.failures)
    assert res.exit_status == 0 and res.oneshot_exit_status == 0
    assert res.frames == 4 and res.bytes_per_frame == pytest.approx(res.size_bytes / 4, abs=0.1)
    assert 0 <= res.index_s <= res.load_s <= res.first_paint_s <= res.total_s <= 120
    names = {Path(s.path).name for s in res.shots}
    assert {"measure-tiny.png", "measure-tiny@400us.png", "measure-tiny@900us.png",
            "measure-tiny-oneshot.png"} <= names
    # the main view: the frame as the camera stored it, with the classes drawn over it
    frame_views = {s.delay_us: s.found for s in res.shots if s.view == "camera frame (as stored)"}
    # at 400 us: nozzle (grey, not checked), attached liquid and the main drop; at 900 us the
    # satellite instead of the attached liquid
    assert set(frame_views[400.0]) == {"attached liquid", "main drop"}
    assert set(frame_views[900.0]) == {"main drop", "satellite"}
    # at 1300 us every other body class, each in its own colour
    assert set(frame_views[1300.0]) == {CLASSES[c][0] for c in (CLASS_DROP, *OTHER_CLASSES)}
    assert all(n >= shot.MIN_HUE_PIXELS for found in frame_views.values() for n in found.values())
    for s in res.shots:
        assert Path(s.path).stat().st_size > 0 and s.colours >= shot.MIN_COLOURS


def test_identification_recording_in_the_viewer(viewer_ok, identification_rrd, tmp_path):
    res = shot.check_recording(identification_rrd, tmp_path, window_size="1000x700", timeout=120,
                               oneshot=False)
    assert res.ok, "\n".join(res.failures)
    (plane,) = [s for s in res.shots if s.view and s.view.startswith("(u1 right, u2 down)")]
    assert len(plane.found) == 4 and min(plane.found.values()) >= 3  # every training point's colour


def test_a_missing_colour_fails(viewer_ok, measurement_rrd, tmp_path, monkeypatch):
    # the check is not vacuous: claim the main drop is green, and the screenshot says otherwise
    real = shot.read_facts

    def lying(path):
        facts = real(path)
        facts.class_colours[CLASS_DROP] = (0, 255, 0, 255)
        return facts

    monkeypatch.setattr(shot, "read_facts", lying)
    res = shot.check_recording(measurement_rrd, tmp_path, window_size="800x600", times_us=[900.0],
                               timeout=120, oneshot=False)
    assert not res.ok
    assert any("colour of main drop (0, 255, 0) not found" in f for f in res.failures)
