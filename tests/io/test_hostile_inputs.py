"""Hostile and lying input (input side): every case is either exit status 2 with one stderr
line naming the file and the problem, or a measured sequence with the bad frame skipped and
reported in summary.json["errors"]; never a traceback, a hang or a silent wrong answer.

Every input is generated in tmp_path (no stored files)."""

import json
import os
import shutil
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

import dropvision.io.readers.base as readers_base
import dropvision.io.readers.png as png_reader
from dropvision.app.cli import main
from dropvision.io.readers import UnreadableImage
from dropvision.io.sequence import open_sequence
from dropvision.io.sequence_writer import write_multipage_tiff


@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    """A small synthetic sequence (8-bit PNGs, sequence.json with a frames list)."""
    from dropvision.synth import SynthConfig, write_synthetic_sequence

    out = tmp_path_factory.mktemp("hostile") / "seq"
    cfg = SynthConfig(width_px=192, height_px=480,
                      delays_us=tuple(float(d) for d in range(0, 1001, 50)), seed=7)
    return write_synthetic_sequence(cfg, out, progress=False)


@pytest.fixture
def seq(synth, tmp_path):
    """A private copy of the synthetic sequence."""
    return Path(shutil.copytree(synth, tmp_path / "seq"))


def _doc(folder):
    return json.loads((folder / "sequence.json").read_text())


def _write_doc(folder, doc):
    (folder / "sequence.json").write_text(json.dumps(doc))


def _frames(folder):
    return [f["file"] for f in _doc(folder)["frames"]]


def _exit2(folder, tmp_path, capsys, *fragments):
    """`dropvision measure` exits with 2 and one stderr line holding every fragment."""
    capsys.readouterr()
    assert main(["measure", str(folder), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    for frag in fragments:
        assert frag in lines[0], lines[0]
    return lines[0]


def _measured(folder, tmp_path, capsys):
    """`dropvision measure` exits with 0; returns summary.json["errors"]."""
    out = tmp_path / "out"
    assert main(["measure", str(folder), "--out", str(out)]) == 0, capsys.readouterr().err
    return json.loads((out / "summary.json").read_text())["errors"]


def _reason(errors, name):
    found = [e for e in errors if Path(e["file"]).name == name or e["file"].startswith(name)]
    assert found, errors
    return found[0]["reason"]


def _png_chunk(ctype: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + ctype + data + struct.pack(">I", zlib.crc32(ctype + data))


# --- 1. JSON safety -----------------------------------------------------------------------

def test_deeply_nested_json_is_refused(seq, tmp_path, capsys):
    text = (seq / "sequence.json").read_text()
    (seq / "sequence.json").write_text(text[:-1].rstrip().rstrip("}") + ', "x": '
                                       + "[" * 100_000 + "]" * 100_000 + "}")
    _exit2(seq, tmp_path, capsys, "sequence.json", "nested more than 64 levels")


def test_moderately_nested_extra_key_is_refused(seq, tmp_path, capsys):
    doc = _doc(seq)
    nested = []
    for _ in range(200):  # parses, but would break copies and writers later
        nested = [nested]
    doc["x"] = nested
    _write_doc(seq, doc)
    _exit2(seq, tmp_path, capsys, "sequence.json", "nested more than")


def test_400_digit_integer_is_refused(seq, tmp_path, capsys):
    text = json.dumps(_doc(seq) | {"pixel_size_um": 0}).replace(
        '"pixel_size_um": 0', '"pixel_size_um": ' + "9" * 400)
    (seq / "sequence.json").write_text(text)
    _exit2(seq, tmp_path, capsys, "sequence.json", "integer of 400 digits")


def test_utf8_bom_is_accepted(seq, tmp_path, capsys):
    (seq / "sequence.json").write_bytes(b"\xef\xbb\xbf" + (seq / "sequence.json").read_bytes())
    assert _measured(seq, tmp_path, capsys) == []


def test_schema_null_is_the_default_schema(seq, tmp_path, capsys):
    _write_doc(seq, _doc(seq) | {"schema": None, "orientation": None})
    assert _measured(seq, tmp_path, capsys) == []


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity"])
def test_nan_and_infinity_literals_are_refused(seq, tmp_path, capsys, literal):
    text = json.dumps(_doc(seq) | {"nozzle_tip_row": 0}).replace(
        '"nozzle_tip_row": 0', f'"nozzle_tip_row": {literal}')
    (seq / "sequence.json").write_text(text)
    _exit2(seq, tmp_path, capsys, "sequence.json", literal, "not a JSON number")


def test_float_literal_overflowing_is_refused(seq, tmp_path, capsys):
    text = json.dumps(_doc(seq) | {"pixel_size_um": 0}).replace(
        '"pixel_size_um": 0', '"pixel_size_um": 1e400')
    (seq / "sequence.json").write_text(text)
    _exit2(seq, tmp_path, capsys, "sequence.json", "1e400", "too large")


# --- 2. physical ranges -------------------------------------------------------------------

@pytest.mark.parametrize("change,fragments", [
    ({"pixel_size_um": 1e308}, ["pixel_size_um", "1e+308", "0.01..1000 µm"]),
    ({"pixel_size_um": 1e-300}, ["pixel_size_um", "1e-300", "0.01..1000 µm"]),
    ({"pixel_size_um": 5000}, ["pixel_size_um", "5000", "0.01..1000 µm"]),
    ({"nozzle_inner_diameter_um": 0.5}, ["nozzle_inner_diameter_um", "1..10000 µm"]),
    ({"nozzle_outer_diameter_um": 1e6}, ["nozzle_outer_diameter_um", "1..10000 µm"]),
    ({"nozzle_inner_diameter_um": 300, "nozzle_outer_diameter_um": 200},
     ["nozzle_outer_diameter_um 200", "larger than", "nozzle_inner_diameter_um 300"]),
    ({"waveform": {"u1_um_per_ms": 1e308, "u2_um": 25}}, ["u1_um_per_ms", "..10000 µm/ms"]),
    ({"waveform": {"u1_um_per_ms": 70, "u2_um": 1e5}}, ["u2_um", "..10000 µm"]),
    ({"waveform": {"u1_um_per_ms": 70, "u2_um": 25, "u3_um_per_ms": 1e-300}},
     ["u3_um_per_ms", "1e-300", "µm/ms"]),
    ({"waveform": {"u1_um_per_ms": 70, "u2_um": 25, "hold_us": 1e9}}, ["hold_us", "0..1e+06 µs"]),
    ({"waveform": {"u1_um_per_ms": 70, "u2_um": 25, "dead_time_us": 1e12}},
     ["dead_time_us", "0..1e+06 µs"]),
    ({"ink": {"viscosity_mPa_s": 1e308}}, ["viscosity_mPa_s", "mPa·s"]),
    ({"ink": {"density_kg_m3": 1e-300}}, ["density_kg_m3", "kg/m³"]),
])
def test_numbers_outside_their_range_are_refused(seq, tmp_path, capsys, change, fragments):
    _write_doc(seq, _doc(seq) | change)
    _exit2(seq, tmp_path, capsys, "sequence.json", *fragments)


@pytest.mark.parametrize("delay", [1e308, -1e300, 2e7])
def test_delay_outside_its_range_is_refused(seq, tmp_path, capsys, delay):
    doc = _doc(seq)
    doc["frames"][3]["delay_us"] = delay
    _write_doc(seq, doc)
    _exit2(seq, tmp_path, capsys, doc["frames"][3]["file"], "delay_us", "-1e+06..1e+07 µs")


@pytest.mark.parametrize("key,value", [
    ("nozzle_tip_row", 480.0), ("nozzle_tip_row", -3.0), ("nozzle_tip_row", 1e300),
    ("axis_col", 192.0), ("axis_col", -1.0),
])
def test_tip_row_or_axis_col_outside_the_image_is_refused(seq, tmp_path, capsys, key, value):
    _write_doc(seq, _doc(seq) | {key: value})
    _exit2(seq, tmp_path, capsys, "sequence.json", f"{key} {value:g}", "192x480")


def _tiff_sequence(seq, tmp_path, **tiff_kwargs):
    """The first frames of ``seq`` as single-page TIFFs with ``tiff_kwargs``, no pixel size
    in sequence.json."""
    folder = tmp_path / "tif"
    folder.mkdir()
    doc = _doc(seq)
    for entry in doc["frames"][:4]:
        img = cv2.imread(str(seq / entry["file"]), cv2.IMREAD_UNCHANGED)
        entry["file"] = entry["file"].replace(".png", ".tif")
        tifffile.imwrite(folder / entry["file"], img, **tiff_kwargs)
    doc["frames"] = doc["frames"][:4]
    del doc["pixel_size_um"]
    _write_doc(folder, doc)
    return folder, doc["frames"][0]["file"]


def test_imagej_resolution_giving_absurd_pixel_size_is_refused(seq, tmp_path, capsys):
    folder, first = _tiff_sequence(seq, tmp_path, imagej=True, resolution=(1e-9, 1e-9),
                                   metadata={"unit": "um"})
    _exit2(folder, tmp_path, capsys, first, "pixel size from the imagej metadata",
           "0.01..1000 µm")


def test_ome_physical_size_absurd_is_refused(seq, tmp_path, capsys):
    folder, first = _tiff_sequence(seq, tmp_path, ome=True,
                                   metadata={"PhysicalSizeX": 1e9, "PhysicalSizeY": 1e9})
    _exit2(folder, tmp_path, capsys, first, "pixel size from the ome metadata", "1e+09")


# --- 3. names the OS refuses --------------------------------------------------------------

def test_frame_name_over_255_characters_is_refused(seq, tmp_path, capsys):
    doc = _doc(seq)
    long_name = "f" * 300 + "_00050us.png"
    doc["frames"][1]["file"] = long_name
    _write_doc(seq, doc)
    _exit2(seq, tmp_path, capsys, long_name, "cannot be accessed", "too long")


def test_frame_unreadable_by_the_os_is_skipped_and_reported(seq, tmp_path, capsys, monkeypatch):
    name = _frames(seq)[4]
    real_open = open

    def failing_open(path, *args, **kwargs):  # as EACCES/EIO when opening one frame
        if str(path).endswith(name):
            raise PermissionError(13, "Permission denied", str(path))
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(readers_base, "open", failing_open, raising=False)  # where the readers open files
    errors = _measured(seq, tmp_path, capsys)
    assert [Path(e["file"]).name for e in errors] == [name]
    assert "Permission denied" in errors[0]["reason"]


# --- 4. bounded resources -----------------------------------------------------------------

def _forged_png(path, width, height, colour_type, bit_depth=8):
    ihdr = struct.pack(">IIBBBBB", width, height, bit_depth, colour_type, 0, 0, 0)
    path.write_bytes(png_reader.PNG_SIGNATURE + _png_chunk(b"IHDR", ihdr)
                     + _png_chunk(b"IDAT", zlib.compress(b"\0" * 1000)) + _png_chunk(b"IEND", b""))


@pytest.mark.parametrize("colour_type", [2, 0])  # RGB (libpng path), grey (fast path)
def test_png_header_claiming_50000x50000_is_a_skipped_frame(seq, tmp_path, capsys, colour_type):
    name = _frames(seq)[5]
    _forged_png(seq / name, 50000, 50000, colour_type)
    errors = _measured(seq, tmp_path, capsys)
    reason = _reason(errors, name)  # refused from its header (the limit named), never decoded
    assert "50000x50000" in reason and "megapixels" in reason and "MAX_PIXELS" in reason
    assert len(errors) == 1


def test_png_max_pixels_is_configurable(tmp_path, monkeypatch):
    path = tmp_path / "a.png"
    cv2.imwrite(str(path), np.zeros((20, 30), np.uint8))
    assert png_reader.read_png(path).shape == (20, 30)
    monkeypatch.setattr(readers_base, "MAX_PIXELS", 500)
    with pytest.raises(UnreadableImage, match="30x20 pixels"):
        png_reader.read_png(path)


def test_bmp_header_claiming_huge_image_is_a_skipped_frame(seq, tmp_path, capsys):
    doc = _doc(seq)
    for entry in doc["frames"]:
        img = cv2.imread(str(seq / entry["file"]), cv2.IMREAD_UNCHANGED)
        (seq / entry["file"]).unlink()
        entry["file"] = entry["file"].replace(".png", ".bmp")
        cv2.imwrite(str(seq / entry["file"]), img)
    _write_doc(seq, doc)
    name = doc["frames"][6]["file"]
    data = bytearray((seq / name).read_bytes())
    struct.pack_into("<ii", data, 18, 60000, -60000)
    (seq / name).write_bytes(bytes(data))
    errors = _measured(seq, tmp_path, capsys)
    assert len(errors) == 1 and "60000x60000" in _reason(errors, name)


def test_tiff_page_claiming_huge_image_is_a_skipped_frame(seq, tmp_path, capsys):
    doc = _doc(seq)
    for entry in doc["frames"]:
        img = cv2.imread(str(seq / entry["file"]), cv2.IMREAD_UNCHANGED)
        (seq / entry["file"]).unlink()
        entry["file"] = entry["file"].replace(".png", ".tif")
        tifffile.imwrite(seq / entry["file"], img)
    _write_doc(seq, doc)
    name = doc["frames"][2]["file"]
    with tifffile.TiffFile(seq / name, mode="r+b") as tif:
        tif.pages[0].tags["ImageWidth"].overwrite(50000)
        tif.pages[0].tags["ImageLength"].overwrite(50000)
    errors = _measured(seq, tmp_path, capsys)
    assert len(errors) == 1 and "50000x50000" in _reason(errors, name)


def test_sparse_4gib_png_is_a_skipped_frame_without_reading_it(seq, tmp_path, capsys):
    name = _frames(seq)[7]
    with open(seq / name, "r+b") as fh:  # the real frame, then 4 GiB of holes
        fh.truncate(4 * 1024 ** 3)
    errors = _measured(seq, tmp_path, capsys)
    reason = _reason(errors, name)  # refused from its size (the limit named), never read
    assert len(errors) == 1 and "over the limit" in reason and "MAX_FILE_BYTES" in reason


def test_png_of_many_empty_chunks_is_refused_quickly(tmp_path, monkeypatch):
    monkeypatch.setattr(png_reader, "MAX_CHUNKS", 10_000)
    ihdr = struct.pack(">IIBBBBB", 8, 8, 8, 0, 0, 0, 0)
    path = tmp_path / "chunks.png"
    path.write_bytes(png_reader.PNG_SIGNATURE + _png_chunk(b"IHDR", ihdr)
                     + _png_chunk(b"teXt", b"") * 20_000)
    with pytest.raises(UnreadableImage, match="more than 10000 chunks"):
        png_reader.read_png(path)


# --- 5. truncated multi-page TIFF ---------------------------------------------------------

def _stack_file(seq, tmp_path):
    """The sequence's frames as one multi-page TIFF ``stack/s.tif``: (folder, its doc, delays)."""
    folder = tmp_path / "stack"
    folder.mkdir()
    doc = _doc(seq)
    pages = [cv2.imread(str(seq / e["file"]), cv2.IMREAD_UNCHANGED) for e in doc["frames"]]
    delays = [e["delay_us"] for e in doc["frames"]]
    write_multipage_tiff(folder / "s.tif", pages, delays)
    return folder, doc, delays


def _stack(seq, tmp_path, with_frames_list):
    folder, doc, delays = _stack_file(seq, tmp_path)
    with tifffile.TiffFile(folder / "s.tif") as tif:
        cut = tif.pages[15].dataoffsets[0] + 100  # inside page 15's data
    data = (folder / "s.tif").read_bytes()
    (folder / "s.tif").write_bytes(data[:cut])
    if with_frames_list:
        doc["frames"] = [{"file": "s.tif", "page": i, "delay_us": d} for i, d in enumerate(delays)]
    else:
        del doc["frames"]
    _write_doc(folder, doc)
    return folder, len(delays)


def test_truncated_multipage_tiff_listed_pages_skipped_and_reported(seq, tmp_path, capsys):
    folder, n = _stack(seq, tmp_path, with_frames_list=True)
    errors = _measured(folder, tmp_path, capsys)
    assert sorted(e["page"] for e in errors) == list(range(15, n))
    assert all("truncated" in e["reason"] for e in errors)
    assert any("page chain is cut" in e["reason"] for e in errors)


def test_truncated_multipage_tiff_folder_scan_measures_readable_pages(seq, tmp_path, capsys):
    folder, n = _stack(seq, tmp_path, with_frames_list=False)
    errors = _measured(folder, tmp_path, capsys)
    assert [e["page"] for e in errors] == [15]  # later pages cannot be found without a list
    with open_sequence(folder) as s:
        assert len(s) == 16


# --- 6. staying inside the folder ---------------------------------------------------------

def test_frame_linked_outside_the_folder_is_skipped_and_reported(seq, tmp_path, capsys):
    name = _frames(seq)[8]
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    shutil.move(seq / name, elsewhere / name)
    (seq / name).symlink_to(elsewhere / name)
    errors = _measured(seq, tmp_path, capsys)
    assert len(errors) == 1
    assert "outside the sequence folder" in _reason(errors, name)
    with open_sequence(seq, allow_outside_links=True) as s:  # explicitly allowed
        assert all(fr.error is None for fr in s)


def test_link_to_etc_passwd_in_a_folder_scan_is_skipped_and_reported(seq, tmp_path, capsys):
    doc = _doc(seq)
    del doc["frames"]
    _write_doc(seq, doc)
    (seq / "f_9999_00525us.png").symlink_to("/etc/passwd")
    errors = _measured(seq, tmp_path, capsys)
    assert len(errors) == 1
    assert "outside the sequence folder (to /etc/passwd)" in _reason(errors, "f_9999_00525us.png")


def test_sequence_json_linked_outside_is_refused(seq, tmp_path, capsys):
    shutil.move(seq / "sequence.json", tmp_path / "meta.json")
    (seq / "sequence.json").symlink_to(tmp_path / "meta.json")
    _exit2(seq, tmp_path, capsys, "sequence.json", "outside the sequence folder")
    assert open_sequence(seq, allow_outside_links=True).meta.pixel_size_um > 0


def test_subfolder_linked_outside_is_skipped_and_reported(seq, tmp_path, capsys):
    doc = _doc(seq)
    name = doc["frames"][9]["file"]
    outside = tmp_path / "outside"
    outside.mkdir()
    shutil.move(seq / name, outside / name)
    (seq / "sub").symlink_to(outside, target_is_directory=True)
    doc["frames"][9]["file"] = f"sub/{name}"
    _write_doc(seq, doc)
    errors = _measured(seq, tmp_path, capsys)
    assert len(errors) == 1 and "outside the sequence folder" in errors[0]["reason"]


def test_links_resolving_inside_the_folder_are_read(seq, tmp_path, capsys):
    doc = _doc(seq)
    name = doc["frames"][10]["file"]
    (seq / "real").mkdir()
    shutil.move(seq / name, seq / "real" / name)
    (seq / "alias").symlink_to("real", target_is_directory=True)
    doc["frames"][10]["file"] = f"alias/{name}"
    _write_doc(seq, doc)
    assert _measured(seq, tmp_path, capsys) == []


# --- 7. issue 29: duplicate keys, names, special files, page chains, header sizes ------------

def test_duplicate_key_in_sequence_json_is_refused(seq, tmp_path, capsys):
    text = json.dumps(_doc(seq))
    (seq / "sequence.json").write_text('{"pixel_size_um": 99.0, ' + text[1:])  # the file's own value last
    _exit2(seq, tmp_path, capsys, str(seq / "sequence.json"), "'pixel_size_um' given twice")
    nested = _doc(seq)
    (seq / "sequence.json").write_text(json.dumps(nested).replace('"delay_us":', '"delay_us": 1, "delay_us":', 1))
    _exit2(seq, tmp_path, capsys, "sequence.json", "'delay_us' given twice")


def test_json_documents_we_read_refuse_duplicate_keys(tmp_path):
    from dvcore.atomic import foreign_files
    from dvcore.jsonio import JsonRefused, loads_strict

    with pytest.raises(JsonRefused, match="'a' given twice"):
        loads_strict('{"a": 1, "b": {"a": 2}, "a": 3}')
    assert loads_strict('{"a": 1, "b": {"a": 2}}') == {"a": 1, "b": {"a": 2}}
    (tmp_path / "x.txt").write_text("user")  # a marker listing it twice under "files" is no marker of ours
    (tmp_path / ".dropvision-output.json").write_text(
        '{"schema": "dropvision.output-marker/1", "files": [], "files": ["x.txt"]}')
    assert foreign_files(tmp_path) == ["x.txt"]


def test_frame_name_that_is_not_utf8_is_refused_up_front(seq, tmp_path, capsys):
    doc = _doc(seq)
    del doc["frames"]
    _write_doc(seq, doc)
    bad = os.fsencode(str(seq)) + b"/frame_\xff_00525us.png"
    with open(bad, "wb") as fh:
        fh.write((seq / _frames_of(seq)[0]).read_bytes())
    line = _exit2(seq, tmp_path, capsys, "frame_\\xff_00525us.png", "not valid UTF-8")
    assert str(seq) in line
    assert not (tmp_path / "out").exists()


def _frames_of(folder):
    return sorted(p.name for p in folder.iterdir() if p.suffix == ".png")


def test_fifo_among_frames_is_named_for_what_it_is(seq, tmp_path, capsys):
    name = _frames(seq)[3]
    (seq / name).unlink()
    os.mkfifo(seq / name)  # a reader opening it would wait forever
    _exit2(seq, tmp_path, capsys, name, "a FIFO, not a regular file")
    doc = _doc(seq)
    del doc["frames"]  # a folder scan: reported as a skipped frame, never opened
    _write_doc(seq, doc)
    errors = _measured(seq, tmp_path, capsys)
    assert [e["file"] for e in errors] == [name] and "a FIFO, not a regular file" in errors[0]["reason"]


def test_cyclic_tiff_page_chain_is_reported_without_raw_tifffile_lines(seq, tmp_path, capsys):
    folder, doc, delays = _stack_file(seq, tmp_path)
    with tifffile.TiffFile(folder / "s.tif") as tif:
        offsets, head = [p.offset for p in tif.pages], tif.tiff
    data = bytearray((folder / "s.tif").read_bytes())
    (n_tags,) = struct.unpack_from(head.tagnoformat, data, offsets[10])
    struct.pack_into(head.offsetformat, data, offsets[10] + head.tagnosize + n_tags * head.tagsize, offsets[3])
    (folder / "s.tif").write_bytes(bytes(data))  # page 10 points back to page 3
    doc["frames"] = [{"file": "s.tif", "page": i, "delay_us": d} for i, d in enumerate(delays)]
    _write_doc(folder, doc)
    capsys.readouterr()
    errors = _measured(folder, tmp_path, capsys)
    assert "tifffile" not in capsys.readouterr().err
    assert errors and all(e["file"] == "s.tif" for e in errors)
    assert "circular" in errors[0]["reason"] and "page chain is cut" in errors[0]["reason"]


def test_png_header_of_another_size_is_refused_before_decoding(seq, tmp_path, capsys, monkeypatch):
    name = _frames(seq)[6]
    _forged_png(seq / name, 9999, 9999, 6, bit_depth=16)  # 16-bit RGBA: 800 MB to decode
    decoded = []
    real = png_reader.read_png
    monkeypatch.setattr(png_reader, "read_png", lambda p: (decoded.append(Path(p).name), real(p))[1])
    _exit2(seq, tmp_path, capsys, name, "9999x9999", "from its header", "differs from the first frame's 192x480")
    assert name not in decoded and decoded  # the others were decoded, this one never
