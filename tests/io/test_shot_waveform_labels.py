"""Shot labels as a waveform template's parameters (issue 31 item 1: parameters declared "in the shot
labels"): `dropvision measure FOLDER --waveform-template three_pulse`, or sequence.json
``waveform: {"template": "three_pulse"}`` without parameters, makes each shot's labels
(``images_V1--86_V2-12_V3--30_w1-26_w2-10_w3-31_d1-7_d2-5.png``) its three-pulse parameters; a missing
or unknown one, or one outside the template's range, is a one-line error naming the image, before
anything is measured.

Shots: two frames of one small synthetic sequence copied under drop-watcher names.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pandas as pd
import pytest

from dropvision.app.cli import main
from dropvision.analysis.shots import find_shots, label_waveform
from dropvision.synth import SynthConfig, write_synthetic_sequence
from dvcore import schema

SMALL = dict(width_px=128, height_px=448, tip_row=30.3, axis_col=63.6, noise=0.3)
NAMES = ("images_V1--86_V2-12_V3--30_w1-26_w2-10_w3-31_d1-7_d2-5.png",
         "images_V1--80_V2-14_V3--30_w1-24_w2-10_w3-31_d1-9_d2-5.png")
TEMPLATE = {"template": "three_pulse", "edge_us": 2.0, "dead_time_us": 220.0, "parameters_from": "labels"}


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    seq = write_synthetic_sequence(SynthConfig(**SMALL, delays_us=(1150.0, 1250.0), u1_um_per_ms=75.0),
                                   tmp_path_factory.mktemp("src") / "seq", progress=False)
    return [seq / f["file"] for f in json.loads((seq / "sequence.json").read_text())["frames"]]


def _folder(path: Path, frames, names=NAMES, waveform=None) -> Path:
    path.mkdir(parents=True)
    for frame, name in zip(frames, names):
        shutil.copy(frame, path / name)
    doc = {"pixel_size_um": 4.73, **({"waveform": waveform} if waveform is not None else {})}
    (path / "sequence.json").write_text(json.dumps(doc))
    return path


def test_measure_with_waveform_template_takes_the_labels_as_parameters(frames, tmp_path, capsys):
    folder = _folder(tmp_path / "shots", frames)
    out = tmp_path / "out"
    assert main(["measure", str(folder), "--out", str(out), "--waveform-template", "three_pulse", "-q"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    schema.check_document(summary, schema.SHOTS_SUMMARY, out / "summary.json")
    assert summary["waveform"] == TEMPLATE
    shots = pd.read_parquet(out / "shots.parquet")
    params = ["V1", "V2", "V3", "w1", "w2", "w3", "d1", "d2"]
    assert list(shots.columns[-8:]) == params
    got = dict(zip(shots["file"], shots[params].to_numpy().tolist()))
    assert got == {NAMES[0]: [-86, 12, -30, 26, 10, 31, 7, 5], NAMES[1]: [-80, 14, -30, 24, 10, 31, 9, 5]}
    # sequence.json's template without parameters does the same, its constants kept
    folder2 = _folder(tmp_path / "shots2", frames, waveform={"template": "three_pulse", "edge_us": 3.0,
                                                            "dead_time_us": 100.0})
    out2 = tmp_path / "out2"
    assert main(["measure", str(folder2), "--out", str(out2), "-q"]) == 0
    assert json.loads((out2 / "summary.json").read_text())["waveform"] == {**TEMPLATE, "edge_us": 3.0,
                                                                          "dead_time_us": 100.0}
    # without a template waiting for them, labels stay labels
    assert label_waveform(find_shots(_folder(tmp_path / "plain", frames))) is None


@pytest.mark.parametrize("names, message", [
    ((NAMES[0], "images_V1--80_V2-14_V3--30_w1-24_w2-10_w3-31_d1-9.png"),
     r"images_V1--80_V2-14_V3--30_w1-24_w2-10_w3-31_d1-9.png: no label d2 of waveform template three_pulse "
     r"\(its parameters: V1, V2, V3, w1, w2, w3, d1, d2; this image's labels: V1, V2, V3, w1, w2, w3, d1\)"),
    ((NAMES[0], "images_V1--80_V2-14_V3--30_w1-24_w2-10_w3-31_d1-9_d2-5_T-25.png"),
     r"_T-25.png: label T is no parameter of waveform template three_pulse"),
    ((NAMES[0], "images_V1--80_V2-14_V3--30_w1-1_w2-10_w3-31_d1-9_d2-5.png"),
     r"_d2-5.png: three_pulse w1 = 1 us is shorter than the pulse edge"),
])
def test_a_missing_unknown_or_bad_parameter_is_one_line_naming_the_image(frames, tmp_path, capsys, names, message):
    folder = _folder(tmp_path / "shots", frames, names)
    out = tmp_path / "out"
    assert main(["measure", str(folder), "--out", str(out), "--waveform-template", "three_pulse"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(folder) in err, err
    assert re.search(message, err), err
    assert not out.exists()  # nothing measured, nothing written


def test_unknown_template_and_a_sequence_are_refused(frames, tmp_path, capsys):
    folder = _folder(tmp_path / "shots", frames)
    assert main(["measure", str(folder), "--out", str(tmp_path / "o"), "--waveform-template", "four_pulse"]) == 2
    err = capsys.readouterr().err.strip()
    assert "command line --waveform-template: unknown waveform template 'four_pulse'" in err and len(err.splitlines()) == 1
    seq = frames[0].parent
    assert main(["measure", str(seq), "--out", str(tmp_path / "o"), "--waveform-template", "three_pulse"]) == 2
    assert "--waveform-template: " in capsys.readouterr().err and not (tmp_path / "o").exists()
