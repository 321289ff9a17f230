"""Strobe-sequence reading and writing (dropvision.io.sequence, .readers, .writers): containers,
delays, order, orientation, errors."""

import json
import pickle
import struct
import zlib

import numpy as np
import pytest
import tifffile

import dropvision.io.readers.png as png_reader
from dropvision.io.discovery import parse_delay_from_name
from dropvision.io.orientation import canonical_to_original, from_canonical, original_to_canonical, to_canonical
from dropvision.io.sequence import RGBConvertedWarning, SequenceError, open_sequence
from dropvision.io.sequence_writer import write_image, write_multipage_tiff, write_sequence_json

RNG = np.random.default_rng(12345)


def _img(dtype=np.uint8, shape=(24, 32)):
    hi = 255 if dtype == np.uint8 else 65535
    return RNG.integers(0, hi + 1, size=shape, dtype=np.int64).astype(dtype)


def _seq(folder, files, delays, images=None, **meta):
    """Write images and a sequence.json listing them; returns the images."""
    images = images if images is not None else [_img() for _ in files]
    for name, im in zip(files, images):
        write_image(folder / name, im)
    meta.setdefault("pixel_size_um", 4.73)
    meta["frames"] = [{"file": f, "delay_us": d} for f, d in zip(files, delays)]
    write_sequence_json(folder, meta)
    return images


# --- containers ---------------------------------------------------------------------------

@pytest.mark.parametrize("suffix,dtype,bits", [
    (".png", np.uint8, 8), (".png", np.uint16, 16), (".tif", np.uint8, 8),
    (".tiff", np.uint16, 16), (".bmp", np.uint8, 8),
])
def test_round_trip_single_image_containers(tmp_path, suffix, dtype, bits):
    images = [_img(dtype) for _ in range(3)]
    files = [f"f_{i}{suffix}" for i in range(3)]
    _seq(tmp_path, files, [0.0, 10.0, 20.0], images)
    with open_sequence(tmp_path) as seq:
        assert seq.meta.shape == (24, 32) and seq.meta.bit_depth == bits
        assert seq.meta.pixel_size_um == 4.73 and len(seq) == 3
        frames = list(seq)
    for fr, im in zip(frames, images):
        assert fr.error is None and fr.image.dtype == dtype
        np.testing.assert_array_equal(fr.image, im)


@pytest.mark.parametrize("ome", [False, True])
def test_multipage_tiff_delays_from_pages(tmp_path, ome):
    pages = [_img(np.uint16) for _ in range(4)]
    delays = [30.0, 0.0, 10.0, 10.0]
    write_multipage_tiff(tmp_path / "stack.tif", pages, delays, ome=ome)
    write_sequence_json(tmp_path, {"pixel_size_um": 2.5})  # no frames list
    with open_sequence(tmp_path) as seq:
        m = seq.meta
        assert [f.delay_us for f in m.frames] == [0.0, 10.0, 10.0, 30.0]
        assert [f.page for f in m.frames] == [1, 2, 3, 0]
        assert [f.repeat for f in m.frames] == [0, 0, 1, 0]
        assert m.reordered
        for fr in seq:
            np.testing.assert_array_equal(fr.image, pages[fr.ref.page])
        assert not seq.open_files  # closed after iteration


def test_ome_delta_t_units_converted(tmp_path):
    stack = np.stack([_img() for _ in range(2)])
    tifffile.imwrite(tmp_path / "s.tif", stack, ome=True, photometric="minisblack",
                     metadata={"axes": "TYX", "Plane": {"DeltaT": [0.5, 1.25],
                                                        "DeltaTUnit": ["ms", "ms"]}})
    write_sequence_json(tmp_path, {"pixel_size_um": 1.0})
    with open_sequence(tmp_path) as seq:
        assert [f.delay_us for f in seq.meta.frames] == [500.0, 1250.0]


def test_frames_list_pages_use_cached_tiff_and_close(tmp_path):
    pages = [_img() for _ in range(3)]
    write_multipage_tiff(tmp_path / "stack.tif", pages, [0, 10, 20])
    write_sequence_json(tmp_path, {"pixel_size_um": 3.0, "frames": [
        {"file": "stack.tif", "page": 2, "delay_us": 5.0},
        {"file": "stack.tif", "page": 0, "delay_us": 7.0}]})
    seq = open_sequence(tmp_path)
    np.testing.assert_array_equal(seq.read(0).image, pages[2])  # the opening's probe decoded it
    np.testing.assert_array_equal(seq.read(1).image, pages[0])
    assert "stack.tif" in seq.open_files
    seq.close()
    assert not seq.open_files
    np.testing.assert_array_equal(seq.read(1).image, pages[0])  # reopens after close
    seq.close()


def test_pixel_size_from_ome_without_sequence_json(tmp_path):
    write_multipage_tiff(tmp_path / "stack.tif", [_img(), _img()], [0, 10], ome=True,
                         pixel_size_um=4.25)
    with open_sequence(tmp_path) as seq:
        assert seq.meta.pixel_size_um == pytest.approx(4.25)
        assert seq.meta.pixel_size_source == "ome"
        assert len(seq) == 2


def test_pixel_size_from_imagej_resolution(tmp_path):
    tifffile.imwrite(tmp_path / "a_100us.tif", _img(), imagej=True,
                     resolution=(1 / 2.0, 1 / 2.0), metadata={"unit": "um"})
    with open_sequence(tmp_path) as seq:
        assert seq.meta.pixel_size_um == pytest.approx(2.0)
        assert seq.meta.pixel_size_source == "imagej"


# --- delays, repeats, order ---------------------------------------------------------------

@pytest.mark.parametrize("name,delay", [
    ("f_0003_01150us.png", 1150.0), ("d01150us.tif", 1150.0), ("x_12.5us.png", 12.5),
    ("run2_cam1_30us_40us.bmp", 40.0), ("F_250US.PNG", 250.0), ("sub/f_7µs.png", 7.0),
    ("status.png", None), ("f_0001.png", None), ("f_10usable.png", None),
])
def test_parse_delay_from_name(name, delay):
    assert parse_delay_from_name(name) == delay


def test_delays_parsed_from_names_natural_order(tmp_path):
    names = ["f_2us.png", "f_10us.png", "d0100us.png", "x_12.5us.png"]
    for n in names:
        write_image(tmp_path / n, _img())
    write_image(tmp_path / "truth_overlay_5us.png", _img())  # never a frame
    (tmp_path / "truth.json").write_text("{}")
    write_sequence_json(tmp_path, {"pixel_size_um": 1.0})
    with open_sequence(tmp_path) as seq:
        assert [f.file for f in seq.meta.frames] == ["f_2us.png", "f_10us.png", "x_12.5us.png",
                                                     "d0100us.png"]
        assert [f.delay_us for f in seq.meta.frames] == [2.0, 10.0, 12.5, 100.0]
        # listed (natural name) order: d0100us, f_2us, f_10us, x_12.5us -> reordered
        assert seq.meta.reordered


def test_repeats_and_reordering_report(tmp_path):
    files = ["a.png", "b.png", "c.png", "d.png", "e.png"]
    delays = [20.0, 0.0, 10.0, 0.0, 10.0]
    images = _seq(tmp_path, files, delays)
    with open_sequence(tmp_path) as seq:
        m = seq.meta
        assert m.reordered
        assert [f.file for f in m.frames] == ["b.png", "d.png", "c.png", "e.png", "a.png"]
        assert [f.repeat for f in m.frames] == [0, 1, 0, 1, 0]
        assert [f.index for f in m.frames] == [0, 1, 2, 3, 4]
        assert [f.listed_index for f in m.frames] == [1, 3, 2, 4, 0]
        np.testing.assert_array_equal(m.delays_us, [0, 0, 10, 10, 20])
        for fr in seq:
            np.testing.assert_array_equal(fr.image, images[fr.ref.listed_index])


def test_sorted_list_not_reordered_and_single_frame_valid(tmp_path):
    _seq(tmp_path, ["only.png"], [1150.0])
    with open_sequence(tmp_path / "sequence.json") as seq:  # path of the json also accepted
        assert len(seq) == 1 and not seq.meta.reordered
        assert seq.read(0).image.shape == (24, 32)


def test_frames_entry_delay_string_and_from_name(tmp_path):
    write_image(tmp_path / "a.png", _img())
    write_image(tmp_path / "b_300us.png", _img())
    write_sequence_json(tmp_path, {"pixel_size_um": 1.0, "frames": [
        {"file": "a.png", "delay_us": "1150us"}, {"file": "b_300us.png"}]})
    with open_sequence(tmp_path) as seq:
        assert [(f.file, f.delay_us) for f in seq.meta.frames] == [("b_300us.png", 300.0),
                                                                   ("a.png", 1150.0)]


def test_unicode_paths_and_subfolders(tmp_path):
    folder = tmp_path / "Tröpfchen ø"
    images = _seq(folder, ["sub/ß_0us.png", "unterordner/é/x.tif"], [0.0, 5.0])
    with open_sequence(folder) as seq:
        assert [f.file for f in seq.meta.frames] == ["sub/ß_0us.png", "unterordner/é/x.tif"]
        for fr, im in zip(seq, images):
            np.testing.assert_array_equal(fr.image, im)


# --- metadata -----------------------------------------------------------------------------

def test_metadata_fields_defaults_and_extra(tmp_path):
    _seq(tmp_path, ["a.png"], [0.0], nozzle_inner_diameter_um=200, nozzle_outer_diameter_um=360,
         waveform={"u1_um_per_ms": 70, "u2_um": 25}, camera="X-1",
         ink={"name": "cyan", "density_kg_m3": 993, "viscosity_mPa_s": 2.21,
              "surface_tension_mN_m": 28.72})
    with open_sequence(tmp_path) as seq:
        m = seq.meta
    assert m.nozzle_inner_diameter_um == 200.0 and m.nozzle_outer_diameter_um == 360.0
    assert m.waveform == {"u1_um_per_ms": 70.0, "u2_um": 25.0, "u3_um_per_ms": 2.0,
                          "hold_us": 20.0, "dead_time_us": 220.0}
    assert m.ink["name"] == "cyan" and m.ink["density_kg_m3"] == 993.0
    assert m.extra == {"camera": "X-1"}
    assert m.nozzle_tip_row is None and m.axis_col is None and m.orientation == "down"
    assert json.loads(json.dumps(m.to_dict()))["frames"][0]["file"] == "a.png"


def test_write_sequence_json_atomic_schema_nan(tmp_path):
    p = write_sequence_json(tmp_path / "new", {"pixel_size_um": np.float64(1.5),
                                               "nozzle_tip_row": float("nan")})
    assert json.loads(p.read_text()) == {"schema": "dropvision.sequence/1",
                                         "pixel_size_um": 1.5, "nozzle_tip_row": None}
    assert [f.name for f in p.parent.iterdir()] == ["sequence.json"]


def test_open_decodes_only_first_frame(tmp_path, monkeypatch):
    _seq(tmp_path, [f"f{i}.png" for i in range(5)], [0, 1, 2, 3, 4])
    calls = []
    real = png_reader.read_png
    monkeypatch.setattr(png_reader, "read_png", lambda path: calls.append(str(path)) or real(path))
    seq = open_sequence(tmp_path)
    assert len(calls) == 1 and calls[0].endswith("f0.png")
    it = iter(seq)
    next(it)  # the first frame: the opening's decode
    assert len(calls) == 1
    next(it)
    assert len(calls) == 2 and calls[1].endswith("f1.png")
    it.close()


def test_pickle_round_trip(tmp_path):
    images = _seq(tmp_path, ["a.png", "b.png"], [0, 1])
    seq = pickle.loads(pickle.dumps(open_sequence(tmp_path)))
    np.testing.assert_array_equal(seq.read(1).image, images[1])


# --- bit depth ----------------------------------------------------------------------------

def _png_with_sbit(png: bytes, bits: int) -> bytes:
    data = bytes([bits])
    chunk = struct.pack(">I", 1) + b"sBIT" + data + struct.pack(">I", zlib.crc32(b"sBIT" + data))
    ihdr_end = 8 + 8 + 13 + 4
    return png[:ihdr_end] + chunk + png[ihdr_end:]


def test_bit_depth_sources(tmp_path):
    im12 = (_img(np.uint16) >> 4).astype(np.uint16)
    # key in sequence.json
    a = tmp_path / "a"
    _seq(a, ["x.png"], [0], [im12], bit_depth=12)
    assert open_sequence(a).meta.bit_depth == 12
    # TIFF MaxSampleValue tag
    b = tmp_path / "b"
    b.mkdir()
    tifffile.imwrite(b / "x_0us.tif", im12, photometric="minisblack",
                     extratags=[(281, "H", 1, 4095, True)])
    write_sequence_json(b, {"pixel_size_um": 1.0})
    assert open_sequence(b).meta.bit_depth == 12
    # PNG sBIT chunk
    c = tmp_path / "c"
    write_image(c / "x_0us.png", im12)
    (c / "x_0us.png").write_bytes(_png_with_sbit((c / "x_0us.png").read_bytes(), 12))
    write_sequence_json(c, {"pixel_size_um": 1.0})
    with open_sequence(c) as seq:
        assert seq.meta.bit_depth == 12
        np.testing.assert_array_equal(seq.read(0).image, im12)
    # uint16 without hints -> 16, even if the values are small
    d = tmp_path / "d"
    _seq(d, ["x.png"], [0], [im12])
    assert open_sequence(d).meta.bit_depth == 16


# --- orientation --------------------------------------------------------------------------

@pytest.mark.parametrize("orientation,expected", [
    ("down", [[0, 1, 2], [3, 4, 5]]),
    ("up", [[5, 4, 3], [2, 1, 0]]),
    ("left", [[2, 5], [1, 4], [0, 3]]),
    ("right", [[3, 0], [4, 1], [5, 2]]),
])
def test_to_canonical_hand_computed(orientation, expected):
    original = np.arange(6, dtype=np.uint8).reshape(2, 3)
    canon = to_canonical(original, orientation)
    np.testing.assert_array_equal(canon, expected)
    np.testing.assert_array_equal(from_canonical(canon, orientation), original)


@pytest.mark.parametrize("orientation", ["down", "up", "left", "right"])
def test_orientation_image_and_tip_mapping(tmp_path, orientation):
    """Asymmetric stored image: a dark 'nozzle' on the upstream edge, a drop downstream, and a
    marker pixel at the stored tip point. Canonical: nozzle on top, marker at (tip_row, axis_col)."""
    h, w = 30, 44
    img = np.full((h, w), 200, np.uint8)
    r0, c0 = 7, 11  # stored tip point (row, col)
    if orientation == "down":
        img[:r0, c0 - 2:c0 + 3] = 10
        img[r0 + 12:r0 + 15, c0 - 1:c0 + 2] = 20  # drop below
    elif orientation == "up":
        img[r0 + 1:, c0 - 2:c0 + 3] = 10
        img[r0 - 6:r0 - 3, c0 - 1:c0 + 2] = 20  # drop above
    elif orientation == "left":
        img[r0 - 2:r0 + 3, c0 + 1:] = 10
        img[r0 - 1:r0 + 2, c0 - 8:c0 - 5] = 20  # drop to the left
    else:
        img[r0 - 2:r0 + 3, :c0] = 10
        img[r0 - 1:r0 + 2, c0 + 12:c0 + 15] = 20  # drop to the right
    img[r0, c0] = 255
    write_image(tmp_path / "f_0us.png", img)
    write_sequence_json(tmp_path, {"pixel_size_um": 1.0, "orientation": orientation,
                                   "nozzle_tip_row": r0, "axis_col": c0})
    with open_sequence(tmp_path) as seq:
        canon = seq.read(0).image
        m = seq.meta
    assert canon.shape == m.shape == ((h, w) if orientation in ("down", "up") else (w, h))
    mr, mc = np.unravel_index(np.argmax(canon), canon.shape)
    assert (m.nozzle_tip_row, m.axis_col) == (mr, mc)
    nozzle_rows = np.nonzero((canon == 10).any(axis=1))[0]
    drop_rows = np.nonzero((canon == 20).any(axis=1))[0]
    assert nozzle_rows.min() == 0 and nozzle_rows.max() < mr < drop_rows.min()
    nozzle_cols = np.nonzero((canon == 10).any(axis=0))[0]
    assert nozzle_cols.mean() == mc  # the axis passes through the nozzle centre


@pytest.mark.parametrize("orientation,expected", [
    ("down", (7.25, 11.5)), ("up", (21.75, 31.5)), ("left", (31.5, 7.25)), ("right", (11.5, 21.75)),
])
def test_subpixel_tip_mapping_hand_computed(orientation, expected):
    # stored shape (H, W) = (30, 44); pixel centres are integers, so flips map r -> H-1-r:
    # up (29-7.25, 43-11.5); left (43-11.5, 7.25); right (11.5, 29-7.25)
    got = original_to_canonical(7.25, 11.5, orientation, (30, 44))
    assert got == expected
    canon_shape = (30, 44) if orientation in ("down", "up") else (44, 30)
    assert canonical_to_original(*got, orientation, canon_shape) == (7.25, 11.5)


# --- RGB ----------------------------------------------------------------------------------

@pytest.mark.parametrize("suffix", [".png", ".tif", ".bmp"])
def test_rgb_converted_with_warning(tmp_path, suffix):
    rgb = np.zeros((6, 8, 3), np.uint8)
    rgb[...] = (100, 150, 200)  # R, G, B
    name = f"colour_0us{suffix}"
    write_image(tmp_path / name, rgb)
    write_sequence_json(tmp_path, {"pixel_size_um": 1.0})
    seq = open_sequence(tmp_path)
    with pytest.warns(RGBConvertedWarning, match=name):
        fr = seq.read(0)
    # ITU-R BT.601 luma: 0.299 R + 0.587 G + 0.114 B = 140.75
    assert fr.image.shape == (6, 8) and abs(int(fr.image[0, 0]) - 140.75) <= 1


# --- bad input: Frame.error ---------------------------------------------------------------

@pytest.mark.parametrize("suffix", [".png", ".tif", ".bmp"])
def test_zero_byte_and_truncated_frames_yield_error(tmp_path, suffix):
    images = _seq(tmp_path, [f"a{suffix}", f"b{suffix}", f"c{suffix}"], [0, 10, 20])
    (tmp_path / f"b{suffix}").write_bytes(b"")
    data = (tmp_path / f"c{suffix}").read_bytes()
    (tmp_path / f"c{suffix}").write_bytes(data[: len(data) // 2])
    with open_sequence(tmp_path) as seq:
        frames = list(seq)
    np.testing.assert_array_equal(frames[0].image, images[0])
    assert frames[1].image is None and "zero-byte" in frames[1].error
    assert f"b{suffix}" in frames[1].error
    assert frames[2].image is None and f"c{suffix}" in frames[2].error


def test_unreadable_first_frame_shape_from_next(tmp_path):
    _seq(tmp_path, ["a.png", "b.png"], [0, 10])
    (tmp_path / "a.png").write_bytes(b"not an image at all")
    with open_sequence(tmp_path) as seq:
        assert seq.meta.shape == (24, 32)
        assert seq.read(0).error is not None and seq.read(1).error is None


def test_truncated_tiff_page_in_stack_yields_error(tmp_path):
    write_multipage_tiff(tmp_path / "s.tif", [_img(), _img(), _img()], [0, 1, 2])
    data = (tmp_path / "s.tif").read_bytes()
    with tifffile.TiffFile(tmp_path / "s.tif") as tif:
        end_first = tif.pages[0].dataoffsets[0] + tif.pages[0].databytecounts[0]
        offsets = [p.dataoffsets[0] for p in tif.pages]
    (tmp_path / "s.tif").write_bytes(data[: max(end_first, max(offsets) + 10)])
    write_sequence_json(tmp_path, {"pixel_size_um": 1.0, "frames": [
        {"file": "s.tif", "page": 0, "delay_us": 0}, {"file": "s.tif", "page": 2, "delay_us": 1}]})
    with open_sequence(tmp_path) as seq:
        f0, f1 = list(seq)
    assert f0.error is None and f1.image is None and "s.tif page 2" in f1.error


# --- bad input: SequenceError -------------------------------------------------------------

def _raises(folder, *fragments):
    with pytest.raises(SequenceError) as info:
        open_sequence(folder).close()
    msg = str(info.value)
    assert "\n" not in msg
    for frag in fragments:
        assert frag in msg, msg
    return msg


def test_error_folder_missing_empty_or_file(tmp_path):
    _raises(tmp_path / "nope", "nope", "does not exist")
    (tmp_path / "empty").mkdir()
    _raises(tmp_path / "empty", "empty", "no image files")
    (tmp_path / "f.png").write_bytes(b"x")
    _raises(tmp_path / "f.png", "f.png", "not a folder")


def test_error_no_sequence_json_pixel_size_unknown(tmp_path):
    write_image(tmp_path / "f_0us.png", _img())
    _raises(tmp_path, "sequence.json (pixel_size_um) is missing")


def test_error_no_sequence_json_names_without_delay(tmp_path):
    write_image(tmp_path / "f_0us.png", _img())
    write_image(tmp_path / "snapshot.png", _img())
    _raises(tmp_path, "snapshot.png", "no delay in the file name")


@pytest.mark.parametrize("value,fragment", [
    (None, "pixel_size_um is missing"), (-1.0, "pixel_size_um must be a number > 0"),
    ("4.7", "pixel_size_um must be a number > 0"), (True, "pixel_size_um must be"),
])
def test_error_pixel_size(tmp_path, value, fragment):
    _seq(tmp_path, ["a.png"], [0], pixel_size_um=value)
    _raises(tmp_path, "sequence.json", fragment)


def test_error_invalid_json(tmp_path):
    write_image(tmp_path / "a_0us.png", _img())
    (tmp_path / "sequence.json").write_text('{"pixel_size_um": 4.7,')
    _raises(tmp_path, "sequence.json", "invalid JSON")


@pytest.mark.parametrize("meta,fragments", [
    ({"orientation": "sideways"}, ["sequence.json", "orientation"]),
    ({"bit_depth": 10}, ["sequence.json", "bit_depth"]),
    ({"waveform": {"u1_um_per_ms": 70}}, ["sequence.json", "u2_um"]),
    ({"waveform": {"u1_um_per_ms": -70, "u2_um": 25}}, ["sequence.json", "u1_um_per_ms"]),
    ({"nozzle_inner_diameter_um": 0}, ["sequence.json", "nozzle_inner_diameter_um"]),
    ({"nozzle_tip_row": "top"}, ["sequence.json", "nozzle_tip_row"]),
    ({"schema": "dropvision.sequence/9"}, ["sequence.json", "schema"]),
    ({"ink": {"density_kg_m3": -1}}, ["sequence.json", "density_kg_m3"]),
])
def test_error_invalid_keys(tmp_path, meta, fragments):
    _seq(tmp_path, ["a.png"], [0], **meta)
    _raises(tmp_path, *fragments)


@pytest.mark.parametrize("frames,fragments", [
    ([{"file": "gone.png", "delay_us": 0}], ["gone.png", "missing"]),
    ([{"file": "../x.png", "delay_us": 0}], ["../x.png", "outside the sequence folder"]),
    ([{"file": "/etc/x.png", "delay_us": 0}], ["/etc/x.png", "outside the sequence folder"]),
    ([{"file": "sub/../../x.png", "delay_us": 0}], ["x.png", "outside"]),
    ([{"file": "a.png", "delay_us": "soon"}], ["a.png", "unparsable delay"]),
    ([{"file": "a.png", "delay_us": "Infinity"}], ["a.png", "unparsable delay"]),
    ([{"file": "a.png", "delay_us": [5]}], ["a.png", "unparsable delay"]),
    ([{"file": "a.png", "delay_us": 0, "page": 1}], ["a.png", "not a TIFF"]),
    ([{"file": "a.png", "delay_us": 0}, {"file": "a.png", "delay_us": 5}], ["a.png", "twice"]),
    ([{"file": "notes.txt", "delay_us": 0}], ["notes.txt", "unsupported image type"]),
    ([], ["sequence.json", "non-empty list"]),
])
def test_error_frames_entries(tmp_path, frames, fragments):
    write_image(tmp_path / "a.png", _img())
    (tmp_path / "notes.txt").write_text("x")
    write_sequence_json(tmp_path, {"pixel_size_um": 1.0, "frames": frames})
    _raises(tmp_path, *fragments)


def test_frames_entry_without_delay(tmp_path):
    """A frames list of several entries needs each one's delay; a list of ONE frame without it (what
    dropvision init writes for a delay TO GIVE: null, issue 33) is a single frame: 0 us assumed, and said."""
    write_image(tmp_path / "a.png", _img())
    write_image(tmp_path / "b.png", _img())
    write_sequence_json(tmp_path, {"pixel_size_um": 1.0, "frames": [{"file": "a.png", "delay_us": 0},
                                                                    {"file": "b.png"}]})
    _raises(tmp_path, "b.png", "no delay_us")
    write_sequence_json(tmp_path, {"pixel_size_um": 1.0, "frames": [{"file": "a.png", "delay_us": None}]})
    with open_sequence(tmp_path) as seq:
        assert seq.meta.frames[0].delay_us == 0.0 and seq.meta.sources["delay"].startswith("assumed 0 us")


def test_error_size_differs_raised_when_met(tmp_path):
    _seq(tmp_path, ["a.png", "b.png", "c.png"], [0, 1, 2],
         [_img(), _img(), _img(shape=(24, 31))])
    seq = open_sequence(tmp_path)  # metadata only: no error yet
    assert seq.read(1).error is None
    with pytest.raises(SequenceError, match=r"c\.png.*differs from the first frame"):
        seq.read(2)


def test_error_pixel_type_differs(tmp_path):
    _seq(tmp_path, ["a.png", "b.png"], [0, 1], [_img(), _img(np.uint16)])
    with open_sequence(tmp_path) as seq, pytest.raises(SequenceError, match=r"b\.png.*uint16"):
        list(seq)


def test_error_bit_depth_key_contradicts_8bit(tmp_path):
    _seq(tmp_path, ["a.png"], [0], bit_depth=12)
    _raises(tmp_path, "a.png", "8-bit")


def test_error_tiff_pages(tmp_path):
    write_multipage_tiff(tmp_path / "s.tif", [_img(), _img()], [0, 1])
    write_sequence_json(tmp_path, {"pixel_size_um": 1.0, "frames": [
        {"file": "s.tif", "delay_us": 0}]})
    with pytest.raises(SequenceError, match=r"s\.tif.*needs a 'page'"):
        open_sequence(tmp_path)
    write_sequence_json(tmp_path, {"pixel_size_um": 1.0, "frames": [
        {"file": "s.tif", "page": 0, "delay_us": 0}, {"file": "s.tif", "page": 5, "delay_us": 1}]})
    with open_sequence(tmp_path) as seq, pytest.raises(SequenceError, match=r"s\.tif.*page 5"):
        list(seq)


def test_error_multipage_without_delays(tmp_path):
    with tifffile.TiffWriter(tmp_path / "s.tif") as tw:
        for _ in range(2):
            tw.write(_img(), photometric="minisblack", metadata=None)
    write_sequence_json(tmp_path, {"pixel_size_um": 1.0})
    _raises(tmp_path, "s.tif", "without a delay")


def test_error_no_readable_frame(tmp_path):
    _seq(tmp_path, ["a.png"], [0])
    (tmp_path / "a.png").write_bytes(b"")
    _raises(tmp_path, "no readable image", "a.png", "zero-byte")


def test_writer_rejects_bad_input(tmp_path):
    with pytest.raises(ValueError, match="BMP"):
        write_image(tmp_path / "a.bmp", _img(np.uint16))
    with pytest.raises(ValueError, match="uint8 or uint16"):
        write_image(tmp_path / "a.png", np.zeros((4, 4), np.float32))
    with pytest.raises(ValueError, match="TIFF"):
        write_image(tmp_path / "a.png", _img(), page_description="{}")
    with pytest.raises(ValueError, match="one finite delay per page"):
        write_multipage_tiff(tmp_path / "s.tif", [_img(), _img()], [0.0])


def test_opening_and_reading_the_first_frame_decode_it_once(tmp_path, monkeypatch):
    """The opening's probe decodes the first frame; reading it, or opening the unchanged folder
    again (the shot watch's check, then its measurement), takes that decode; a rewritten file
    is decoded again (its identity changed)."""
    import dropvision.io.sequence as S

    images = _seq(tmp_path, ["a.png", "b.png"], [0.0, 10.0])
    calls = []
    native = S.Sequence._decode_native
    monkeypatch.setattr(S.Sequence, "_decode_native", lambda self, r, p, ref: calls.append(ref.file) or native(self, r, p, ref))
    with open_sequence(tmp_path) as seq:
        first = seq.read(0).image
        second = seq.read(1).image
    with open_sequence(tmp_path) as seq:
        again = seq.read(0).image
    assert calls == ["a.png", "b.png"]
    np.testing.assert_array_equal(first, images[0])
    np.testing.assert_array_equal(again, images[0])
    np.testing.assert_array_equal(second, images[1])
    first[:] = 0  # a caller's copy: the kept frame is not changed through it
    other = _img()
    write_image(tmp_path / "a.png", other)
    with open_sequence(tmp_path) as seq:
        np.testing.assert_array_equal(seq.read(0).image, other)
    assert calls == ["a.png", "b.png", "a.png"]
