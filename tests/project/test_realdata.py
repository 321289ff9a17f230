"""Real frames are the first judge (issue 18): every folder of ``../shared/realdata`` with a
``truth.json`` is measured and held to the rules of its README (the same rules as its
``score.py``): no NaN, no refusal, each value with a finite positive uncertainty."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import pytest

from dropvision.measurement import measure_sequence
from realdata import REALDATA

# every test here needs the real frames: skipped on a fresh clone, a failure in CI (tests/realdata.py)
pytestmark = pytest.mark.usefixtures("realdata_dir")
FOLDERS = sorted(p.parent for p in REALDATA.glob("**/truth.json")) or [REALDATA / "(missing)"]


def test_the_real_frames_are_there():
    """CI clones the project with ../shared beside it: a missing folder is a failure, not a skip."""
    assert len(FOLDERS) >= 13, f"{REALDATA}: {len(FOLDERS)} real sequences with a truth.json"


def _within(value: float, ref: float, pct: float = 3.0) -> bool:
    return math.isfinite(value) and abs(value - ref) / ref * 100 <= pct


#: Frames whose nozzle cannot be found (issue 29): the holder at the left edge does not reach the frame's
#: edge as a dark body (vignetted dark corner, the background model lifts it), so there is no tip plane
#: and no attached liquid to measure: quality ``no_nozzle`` and the attached volume NaN, the drops still
#: measured (each about its own axis; the jet's axis is their line).
NO_NOZZLE = {"watcher-dod/V1--86_V2-14_V3--5_w1-23_w2-11_w3-1_d1-6_d2-7"}


@pytest.mark.parametrize("folder", FOLDERS, ids=[p.name if p.parent == REALDATA else str(p.relative_to(REALDATA)) for p in FOLDERS])
@pytest.mark.slow
def test_real_frame_meets_its_rules(folder):
    truth = json.loads((folder / "truth.json").read_text())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # colour JPEGs are noted once (RGBConvertedWarning)
        r = measure_sequence(folder)
    row = r.frames.iloc[0]
    if "attached_volume_nl" in truth:
        v, u = float(row["attached_volume_nl"]), float(row["attached_volume_uncertainty_nl"])
        assert _within(v, truth["attached_volume_nl"]), (v, truth["attached_volume_nl"])
    else:
        v, u = float(row["drop_volume_nl"]), float(row["drop_volume_uncertainty_nl"])
        assert not math.isnan(v)
        assert int(row["n_satellites"]) in truth["satellites_accepted"], (row["n_satellites"], r.bodies)
        if truth.get("main_drop_compact", True):
            assert _within(v, truth["main_drop_volume_nl"]), (v, truth["main_drop_volume_nl"])
        # the two bounds of score.py: nothing hangs from the capillary's face, the drops fly along its axis;
        # NaN fails both here (score.py lets a NaN attached volume pass), except where no nozzle exists
        name = str(folder.relative_to(REALDATA))
        att, dx = float(row["attached_volume_nl"]), float(row["drop_x_um"])
        if name in NO_NOZZLE:
            assert math.isnan(att), att  # nothing to hang from: NaN, not a number from somewhere else
        else:
            assert math.isfinite(att) and att <= truth["attached_volume_nl_max"], att
        assert math.isfinite(dx) and abs(dx) <= truth["drop_axis_offset_um_max"], dx
        # a single frame of a foreign rig: no waveform, no delay series, so no flag of either kind; a frame
        # without a nozzle says so
        assert row["quality"] == ("no_nozzle" if name in NO_NOZZLE else "ok"), row["quality"]
    assert math.isfinite(u) and 0 < u < 0.03 * v, (v, u)


def test_no_scale_from_an_out_of_focus_nozzle(tmp_path):
    """A real drop watcher's holder is out of focus: its width is no nozzle diameter, so a pixel size
    derived from --nozzle-outer-diameter-um is refused with a message saying what to give instead."""
    from dropvision.io.sequence import SequenceError

    src = REALDATA / "watcher-dod" / "V1--86_V2-12_V3--30_w1-26_w2-11_w3-25_d1-5_d2-6" / "frame.jpg"
    (tmp_path / "w").mkdir()
    (tmp_path / "w" / "frame.jpg").write_bytes(src.read_bytes())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # a Python caller is told its keyword, the command line its option (`dropvision.io.overrides.how_to_give`)
        with pytest.raises(SequenceError, match=r"nozzle walls are out of focus.*give the pixel size \(pixel_size_um="):
            measure_sequence(tmp_path / "w", overrides={"nozzle_outer_diameter_um": 360.0})
