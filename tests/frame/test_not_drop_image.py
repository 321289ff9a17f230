"""An image that is no drop image at all (issue 30 item 6) is flagged `not_a_drop_image` (or refused), never
measured with quality ok: a backlit drop image is mostly bright background, a photograph is not.

The non-drop images are generated here: a natural-image-like texture (1/f noise, the spectrum of natural
scenes) over a gradient, and a plain gradient; the drop images are synthetic frames.
"""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pandas as pd
import pytest

from dropvision import quality as q
from dropvision.app.cli import main
from dropvision.measurement import measure_sequence
from dropvision.synth import SynthConfig, write_synthetic_sequence
from dvcore import schema

SMALL = dict(width_px=128, height_px=448, tip_row=30.3, axis_col=63.6, noise=0.3)


def natural_texture(shape, seed: int = 0) -> np.ndarray:
    """1/f noise (the amplitude spectrum of natural scenes) over a left-to-right gradient, in [0, 1]."""
    rng = np.random.default_rng(seed)
    h, w = shape
    fy, fx = np.meshgrid(np.fft.fftfreq(h), np.fft.fftfreq(w), indexing="ij")
    f = np.hypot(fy, fx)
    f[0, 0] = 1.0
    spectrum = rng.normal(size=shape) + 1j * rng.normal(size=shape)
    tex = np.real(np.fft.ifft2(spectrum / f))
    tex = (tex - tex.min()) / np.ptp(tex)
    grad = np.linspace(0.0, 1.0, w)[None, :]
    out = 0.6 * tex + 0.4 * grad
    return (out - out.min()) / np.ptp(out)


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    return write_synthetic_sequence(SynthConfig(**SMALL, delays_us=(0.0, 600.0, 1250.0, 1400.0)),
                                    tmp_path_factory.mktemp("seq") / "seq", progress=False)


def _frame_names(seq):
    return [f["file"] for f in json.loads((seq / "sequence.json").read_text())["frames"]]


def test_the_rule_tells_drop_images_from_others(sequence):
    drop = cv2.imread(str(sequence / _frame_names(sequence)[-1]), cv2.IMREAD_UNCHANGED)
    assert q.background_fraction(drop) > 0.8
    tex = natural_texture(drop.shape)
    assert q.background_fraction((tex * 255).astype(np.uint8)) < q.MIN_BACKGROUND_FRACTION
    gradient = np.tile(np.linspace(0, 4000, drop.shape[1]), (drop.shape[0], 1)).astype(np.uint16)
    assert q.background_fraction(gradient) < q.MIN_BACKGROUND_FRACTION
    # a vignetted backlight (a quarter darker at the corners) is still background; a black frame is none
    yy, xx = np.mgrid[0:drop.shape[0], 0:drop.shape[1]]
    r2 = ((yy - yy.mean()) / yy.max()) ** 2 + ((xx - xx.mean()) / xx.max()) ** 2
    assert q.background_fraction((3000 * (1 - 0.5 * r2)).astype(np.uint16)) > 0.95
    assert q.background_fraction(np.zeros_like(drop)) == 0.0


def test_a_non_drop_frame_is_flagged_and_gives_no_number(sequence, tmp_path):
    seq = tmp_path / "seq"
    shutil.copytree(sequence, seq)
    names = _frame_names(seq)
    frame = cv2.imread(str(seq / names[2]), cv2.IMREAD_UNCHANGED)
    lo, hi = float(frame.min()), float(frame.max())
    cv2.imwrite(str(seq / names[2]), (lo + (hi - lo) * natural_texture(frame.shape, seed=1)).astype(frame.dtype))
    res = measure_sequence(seq)
    frames = res.frames.set_index("file")
    bad = frames.loc[names[2]]
    assert schema.Quality.NOT_DROP_IMAGE in bad["quality"].split("; ")
    assert np.isnan(bad["drop_volume_nl"]) and np.isnan(bad["attached_volume_nl"]) and not bad["inflight"]
    assert any("look like no backlit drop image" in n and names[2] in n for n in res.summary["notes"])
    for name in names[:2] + names[3:]:  # the drop frames beside it are not touched by the rule
        assert schema.Quality.NOT_DROP_IMAGE not in frames.loc[name, "quality"]


def test_a_shot_folder_of_non_drop_images_has_no_ok_row(sequence, tmp_path, capsys):
    folder = tmp_path / "shots"
    folder.mkdir()
    drop = cv2.imread(str(sequence / _frame_names(sequence)[-1]), cv2.IMREAD_UNCHANGED)
    shutil.copy(sequence / _frame_names(sequence)[-1], folder / "shot_V-1.png")
    for seed in (2, 3):
        cv2.imwrite(str(folder / f"shot_V-{seed}.png"), (65535 * natural_texture(drop.shape, seed)).astype(np.uint16))
    with np.errstate(all="ignore"):
        assert main(["measure", str(folder), "--out", str(tmp_path / "out"), "--pixel-size-um", "4.73", "-q"]) == 0
    capsys.readouterr()
    table = pd.read_parquet(tmp_path / "out" / "shots.parquet").set_index("file")
    assert table.loc["shot_V-1.png", "quality"] == schema.Quality.OK  # the drop image
    for name in ("shot_V-2.png", "shot_V-3.png"):
        codes = table.loc[name, "quality"].split("; ")
        assert schema.Quality.NOT_DROP_IMAGE in codes or codes == [schema.Quality.NOT_MEASURED], codes
        assert schema.Quality.OK not in codes and np.isnan(table.loc[name, "drop_volume_nl"])
