"""First contact (issue 19): a folder of images straight from a drop watcher measures with one command.

1. options for everything sequence.json holds (measure, campaign, Python API), named as the
   source in summary.json; 2. the orientation detected from the frame; 3. ``dropvision init``;
4. clean command-line output; 6. campaigns whose sequences have their own pixel sizes.
Real frames: ../shared/realdata (beside the clone; skipped on a fresh clone without it, a failure in CI:
tests/realdata.py).
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

import dropvision
from dropvision.app.campaign import run_campaign
from dropvision.app.cli import main
from dropvision.app.options import progress_wanted
from dropvision.io.orientation import detect_orientation
from dropvision.io.orientation import from_canonical
from dropvision.io.sequence import SequenceError, open_sequence
from dropvision.synth import SynthConfig, write_synthetic_sequence
from realdata import REALDATA

WATCHER = sorted((REALDATA / "watcher-dod").glob("*/frame.jpg")) or [REALDATA / "watcher-dod" / "(missing)"]
# small and fast: 128 x 448 px, 31 delays
SMALL = dict(width_px=128, height_px=448, tip_row=30.3, axis_col=63.6,
             delays_us=tuple(float(d) for d in range(0, 1501, 50)), noise=0.3)


def test_the_real_frames_are_there(realdata_dir):
    assert len(WATCHER) == 8, f"{REALDATA}/watcher-dod: {len(WATCHER)} of the eight real drop-watcher frames"


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """A small synthetic sequence (truth pixel size 4.73 um, nozzle outer diameter 360 um)."""
    root = tmp_path_factory.mktemp("first_contact")
    return write_synthetic_sequence(SynthConfig(**SMALL), root / "seq", progress=False)


def _copy_without_pixel_size(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    doc = json.loads((dst / "sequence.json").read_text())
    for key in ("pixel_size_um", "nozzle_outer_diameter_um"):
        doc.pop(key, None)
    (dst / "sequence.json").write_text(json.dumps(doc))
    return dst


def _alone(frame: Path, folder: Path) -> Path:
    folder.mkdir(parents=True)
    shutil.copy(frame, folder / frame.name)
    return folder


# ----------------------------------------------------------------------------- 1. options
def test_options_give_and_override_the_pixel_size(synthetic, tmp_path, capsys):
    seq = _copy_without_pixel_size(synthetic, tmp_path / "seq")
    assert main(["measure", str(seq), "--out", str(tmp_path / "r0"), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "pixel_size_um is missing" in err and "--pixel-size-um" in err
    assert main(["measure", str(seq), "--out", str(tmp_path / "r1"), "--pixel-size-um", "4.73", "-q"]) == 0
    s = json.loads((tmp_path / "r1" / "summary.json").read_text())
    assert s["pixel_size_source"] == s["calibration"]["pixel_size_source"] == "command line --pixel-size-um"
    assert s["calibration"]["pixel_size_um"] == 4.73 and s["orientation_source"] == "sequence.json"
    # the same validation as the file's key: one line naming the option
    assert main(["measure", str(seq), "--out", str(tmp_path / "r2"), "--pixel-size-um", "5000"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("dropvision measure: error: ") and len(err.splitlines()) == 1
    assert "command line --pixel-size-um: pixel_size_um 5000 is outside the accepted range 0.01..1000" in err
    assert not (tmp_path / "r2").exists()
    with pytest.raises(SequenceError, match="argument nozzle_inner_diameter_um: .*outside the accepted range"):
        dropvision.measure(seq, pixel_size_um=4.73, nozzle_inner_diameter_um=0.1)


def test_pixel_size_from_the_nozzle_outer_diameter(synthetic, tmp_path):
    seq = _copy_without_pixel_size(synthetic, tmp_path / "seq")
    res = dropvision.measure(seq, nozzle_outer_diameter_um=360.0, waveform={"u1_um_per_ms": 70.0})
    s = res.summary
    assert s["calibration"]["pixel_size_um"] == pytest.approx(4.73, rel=0.01)
    assert s["pixel_size_source"].startswith("nozzle outer diameter 360 um / ")
    # one width from one rule: the calibration's straight outer walls in its first frame (the meniscus at rest),
    # with its uncertainty; nothing checked against a pixel size nobody gave
    assert "straight outer walls" in s["pixel_size_source"] and " +- " in s["pixel_size_source"]
    u = s["calibration"]["pixel_size_uncertainty_um"]
    assert 0 < u < 0.01 * 4.73 and abs(s["calibration"]["pixel_size_um"] - 4.73) <= 2 * u + 0.002 * 4.73
    assert "pixel_size_mismatch" not in set("; ".join(res.frames["quality"]).split("; "))
    assert s["nozzle_outer_diameter_source"] == "argument nozzle_outer_diameter_um"
    assert s["waveform_source"] == "argument waveform"  # a partial waveform replaces the file's u1 only


def test_open_sequence_overrides_delay_rate_and_orientation(synthetic, tmp_path):
    one = tmp_path / "one"
    one.mkdir()
    first = sorted(synthetic.glob("*.png"))[0]
    shutil.copy(first, one / "frame.png")  # no delay in the name
    meta = open_sequence(one, overrides={"pixel_size_um": 4.73}).meta
    assert meta.delays_us.tolist() == [0.0] and meta.sources["delay"].startswith("assumed 0 us")
    meta = open_sequence(one, overrides={"pixel_size_um": 4.73, "delay_us": 250},
                         labels={"delay_us": "command line --delay-us"}).meta
    assert meta.delays_us.tolist() == [250.0] and meta.sources["delay"] == "command line --delay-us"
    with pytest.raises(SequenceError, match="the delay of a single frame, but .* has 31 frames"):
        open_sequence(synthetic, overrides={"delay_us": 10})
    stack = tmp_path / "stack"
    stack.mkdir()
    for i, f in enumerate(sorted(synthetic.glob("*.png"))[:3]):
        shutil.copy(f, stack / f"img{i}.png")
    meta = open_sequence(stack, overrides={"pixel_size_um": 4.73, "frame_rate_hz": 1e5, "orientation": "DOWN"}).meta
    assert meta.delays_us.tolist() == [0.0, 10.0, 20.0] and meta.orientation == "down"
    assert meta.sources["orientation"] == "argument orientation"
    with pytest.raises(SequenceError, match="argument orientation: orientation must be one of"):
        open_sequence(stack, overrides={"orientation": "sideways"})


# ----------------------------------------------------------------------------- 2. orientation
@pytest.mark.parametrize("frame", WATCHER, ids=[f.parent.name[:12] for f in WATCHER])
def test_orientation_of_the_real_watcher_frames(frame, realdata_dir):
    image = cv2.imread(str(frame), cv2.IMREAD_GRAYSCALE)
    guess = detect_orientation(image)
    assert guess.orientation == "right" and guess.edge == "left", guess.reason  # holder at the left edge
    assert detect_orientation(np.rot90(image, 2)).orientation == "left"


def test_orientation_of_real_pendant_drops_with_a_cuvette_wall(realdata_dir):
    # a dark vertical line (cuvette wall) over the whole right edge; the needle touches the top
    for path in (REALDATA / "droppytension-saturated" / "water_in_hexadecane_1a" / "water_in_hexadecane_1a.jpg",
                 REALDATA / "menipy-pendant-drop" / "gota_pendiente_1.png"):
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        assert detect_orientation(image).orientation == "down", path
        assert detect_orientation(np.rot90(image, 1)).orientation == "right", path


@pytest.mark.parametrize("orientation", ["down", "up", "left", "right"])
def test_orientation_of_synthetic_frames(synthetic, orientation):
    canonical = cv2.imread(str(sorted(synthetic.glob("*.png"))[0]), cv2.IMREAD_UNCHANGED)
    assert detect_orientation(from_canonical(canonical, orientation)).orientation == orientation


def test_a_frame_that_does_not_tell_names_each_edge(tmp_path, capsys):
    folder = tmp_path / "blob"
    folder.mkdir()
    img = np.full((120, 160), 200, np.uint8)
    img[50:70, 70:90] = 20  # a dark body touching no edge
    cv2.imwrite(str(folder / "f_100us.png"), img)
    assert main(["measure", str(folder), "--out", str(tmp_path / "r"), "--pixel-size-um", "3"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "no nozzle" in err and "default (down): not detected" in err
    for edge in ("top: nothing dark", "bottom: nothing dark", "left: nothing dark", "right: nothing dark"):
        assert edge in err
    assert "--orientation or sequence.json orientation sets it" in err
    # in Python the same refusal names the keyword (issue 33)
    import dropvision
    from dropvision.io.sequence import SequenceError
    with pytest.raises(SequenceError, match="orientation= or sequence.json orientation sets it"):
        dropvision.measure(folder, pixel_size_um=3)


def test_a_real_watcher_frame_alone_measures_with_one_option(tmp_path, capsys, realdata_dir):
    folder = _alone(WATCHER[0], tmp_path / "watcher")
    assert main(["measure", str(folder), "--out", str(tmp_path / "r1"), "--pixel-size-um", "3"]) == 0
    out, err = capsys.readouterr()
    assert "measured 1 of 1 frames" in out
    assert "main drop " in out and " nl, " in out and "nan" not in out  # what one frame shows (issue 30)
    # issue 33: the colour note (the documented grey rule) is not repeated on every run: --verbose shows it,
    # one line without its source line
    assert err.strip() == ""
    assert main(["measure", str(folder), "--out", str(tmp_path / "r1v"), "--pixel-size-um", "3", "-v"]) == 0
    assert [ln for ln in capsys.readouterr().err.strip().splitlines() if "warning" in ln] == [
        "dropvision measure: warning: frame.jpg: 3-channel image converted to grey (ITU-R BT.601 luminance; noted "
        "once per sequence, further colour frames are converted alike)"]
    s = json.loads((tmp_path / "r1" / "summary.json").read_text())
    assert s["orientation"] == "right" and s["calibration"]["orientation"] == "right"
    assert s["orientation_source"].startswith("detected in frame.jpg: ") and "left edge" in s["orientation_source"]
    assert s["delay_source"].startswith("assumed 0 us") and s["pixel_size_source"] == "command line --pixel-size-um"


# ----------------------------------------------------------------------------- 3. init
@pytest.mark.slow
def test_init_writes_what_the_images_tell_and_never_overwrites(tmp_path, capsys, realdata_dir):
    folder = _alone(WATCHER[1], tmp_path / "watcher")
    assert main(["init", str(folder)]) == 0
    out = capsys.readouterr().out
    assert "orientation right" in out and "TO GIVE    pixel_size_um" in out and "outer width" in out
    doc = json.loads((folder / "sequence.json").read_text())
    assert doc["orientation"] == "right" and doc["bit_depth"] == 8 and doc["pixel_size_um"] is None
    # every value TO GIVE is null in the file, the assumed delay too (issue 33: it wrote 0.0)
    assert doc["frames"] == [{"file": "frame.jpg", "delay_us": None}] and doc["waveform"] is None
    assert doc["dropvision_init"]["nozzle_outer_width_px"] > 0 and len(doc["dropvision_init"]["to_give"]) == 3
    assert round(doc["dropvision_init"]["nozzle_outer_width_px"], 2) == doc["dropvision_init"]["nozzle_outer_width_px"]
    from dropvision.io.sequence import open_sequence
    with open_sequence(folder, pixel_size_um=3) as seq:  # the null delay of one frame: 0 assumed, and said
        assert seq.meta.frames[0].delay_us == 0.0 and seq.meta.sources["delay"].startswith("assumed 0 us")
        assert "delay_us" in seq.meta.sources["delay"]  # how to give it (a stored text: both ways named)
    # a user's file is sacred: refused without --overwrite, untouched
    (folder / "sequence.json").write_text('{"pixel_size_um": 2.5}')
    assert main(["init", str(folder), "--pixel-size-um", "3"]) == 2
    assert "exists" in capsys.readouterr().err
    assert (folder / "sequence.json").read_text() == '{"pixel_size_um": 2.5}'
    assert main(["init", str(folder), "--overwrite", "--pixel-size-um", "3", "--delay-us", "200",
                 "--u1-um-per-ms", "70", "--u2-um", "25"]) == 0
    doc = json.loads((folder / "sequence.json").read_text())
    assert doc["pixel_size_um"] == 3.0 and doc["frames"][0]["delay_us"] == 200.0
    assert doc["waveform"]["u1_um_per_ms"] == 70.0 and doc["dropvision_init"]["to_give"] == []
    capsys.readouterr()
    # the written file measures with no option
    assert main(["measure", str(folder), "--out", str(tmp_path / "r"), "-q"]) == 0
    assert capsys.readouterr() == ("", "")  # --quiet: nothing but errors
    s = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert s["orientation"] == "right" and s["pixel_size_source"] == "sequence.json"


# ----------------------------------------------------------------------------- 4. output
def test_progress_quiet_and_verbose(synthetic, tmp_path, capsys, monkeypatch):
    def ns(**kw):
        return argparse.Namespace(**{"quiet": False, "verbose": False, "progress": None, **kw})

    monkeypatch.setattr("sys.stderr.isatty", lambda: True)
    assert progress_wanted(ns()) and not progress_wanted(ns(quiet=True)) and not progress_wanted(ns(progress=False))
    monkeypatch.setattr("sys.stderr.isatty", lambda: False)
    assert not progress_wanted(ns()) and progress_wanted(ns(progress=True))
    assert main(["measure", str(synthetic), "--out", str(tmp_path / "r"), "-v", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "orientation down: sequence.json" in out and "pixel_size 4.73: sequence.json" in out


# ----------------------------------------------------------------------------- 6. campaigns
@pytest.mark.slow
def test_campaign_of_sequences_with_their_own_pixel_sizes(synthetic, tmp_path):
    root = tmp_path / "root"
    for name, px in (("a", 4.73), ("b", 4.80)):  # refocused between the two: 1.5 % apart
        shutil.copytree(synthetic, root / name)
        doc = json.loads((root / name / "sequence.json").read_text())
        doc["pixel_size_um"] = px
        (root / name / "sequence.json").write_text(json.dumps(doc))
    res = run_campaign(root, tmp_path / "ds", workers=1, progress=False)
    assert sorted(res.measured) == ["a", "b"] and not res.failed
    ds = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    assert ds["pixel_size_um"] is None and ds["pixel_size_um_by_sequence"] == {"a": 4.73, "b": 4.8}
    assert ds["nozzle_inner_diameter_um"] == 200.0 and ds["n_sequences"] == 2
    # another ink is a reason to refuse, naming the sequences
    doc = json.loads((root / "b" / "sequence.json").read_text())
    doc["ink"] = {**doc["ink"], "viscosity_mPa_s": 10.0}
    (root / "b" / "sequence.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"sequences disagree on ink: .* in a; .* in b; one dataset is one nozzle "
                                         r"and one ink"):
        run_campaign(root, tmp_path / "ds", workers=1, progress=False)


def test_campaign_options_apply_to_every_sequence(synthetic, tmp_path, capsys):
    root = tmp_path / "root"
    for name in ("a", "b"):
        _copy_without_pixel_size(synthetic, root / name)
    assert main(["campaign", str(root), "--out", str(tmp_path / "ds"), "--workers", "1", "--no-progress",
                 "--pixel-size-um", "4.73"]) == 0
    assert "2 measured" in capsys.readouterr().out
    shard = next((tmp_path / "ds" / "shards").glob("a-*"))
    assert json.loads((shard / "summary.json").read_text())["pixel_size_source"] == "command line --pixel-size-um"
    # a bad option is refused before any work, with one line naming it
    assert main(["campaign", str(root), "--out", str(tmp_path / "ds2"), "--pixel-size-um", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert "command line --pixel-size-um: pixel_size_um must be a number > 0" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "ds2").exists()


@pytest.mark.slow
def test_campaign_warnings_are_one_line_once_per_sequence(tmp_path, capsys):
    root = tmp_path / "root"
    cfg = SynthConfig(**{**SMALL, "delays_us": tuple(float(d) for d in range(0, 1501, 100))}, format="jpeg",
                      colour=True)
    for name in ("a", "b"):
        write_synthetic_sequence(cfg, root / name, progress=False)
    assert main(["campaign", str(root), "--out", str(tmp_path / "ds"), "--workers", "1", "--no-progress"]) == 0
    assert capsys.readouterr().err.strip() == ""  # the colour note only with --verbose (issue 33)
    assert main(["campaign", str(root), "--out", str(tmp_path / "ds-v"), "--workers", "1", "--no-progress",
                 "-v"]) == 0
    err = [ln for ln in capsys.readouterr().err.strip().splitlines() if "warning" in ln]
    assert len(err) == 2, err
    for name, line in zip("ab", err):
        assert line.startswith(f"dropvision campaign: warning: {name}: ") and "converted to grey" in line
