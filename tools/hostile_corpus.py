"""A corpus of hostile, corrupted and lying inputs, run through the command lines.

    .venv/bin/python tools/hostile_corpus.py [--quick] [--jobs 2] [--out report.csv] [--keep DIR]

Builds every case from small synthetic sequences with exact truth (nothing is stored), runs the
real command (`dropvision measure|campaign|synth`, `identify fit|predict|design`) in a
subprocess with a 60 s limit while watching its memory, and sorts each outcome:

- ``refused``: exit status 2 and one line on stderr (the input's or the environment's fault);
- ``flagged``: exit 0, and the result says what is wrong (skipped frames in ``errors``, frames
  not ``ok``, summary ``notes``, or ``note:`` lines of `identify`);
- ``correct``: exit 0, nothing flagged, and the figures agree with the truth (in-flight volume
  and jetting velocity within 1 %, pinch-off exact): the lie did not matter;
- bad outcomes: ``traceback`` (any Python traceback), ``hang`` (over 60 s), ``memory`` (over
  2 GB resident), ``silent_wrong`` (exit 0, nothing flagged, figures off the truth, or a case
  that must be refused accepted without a word), ``read_outside`` (a frame reached through a
  link out of the sequence folder was measured), ``destroyed`` (an input file changed).

Exit status 1 when any bad outcome occurs. ``--quick`` runs one case per family (the test tier
in `tests/project/test_hostile_corpus.py`).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
import zlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from dropvision.synth.sequence import SynthConfig  # noqa: E402  (after the path set-up)
from dropvision.synth.writer import write_synthetic_sequence  # noqa: E402
from identify.synthetic_dataset import make_synthetic_dataset  # noqa: E402

PY = sys.executable
LIMIT_S = 60.0
LIMIT_RSS = 2 * 1024**3
BAD = ("traceback", "hang", "memory", "silent_wrong", "read_outside", "destroyed")

SMALL = dict(width_px=128, height_px=448, tip_row=30.3, axis_col=63.6, noise=0.3, dust=1)


@dataclass
class Case:
    family: str
    name: str
    argv: list[str]
    folder: Path            # the case's own folder (inputs inside it)
    expect: str = "refuse_or_flag"   # "refuse", "refuse_or_flag", "correct", "correct_or_flag"
    truth: dict | None = None
    out: Path | None = None
    outside_file: str | None = None   # a frame name that links out of the folder
    watch: list[Path] = field(default_factory=list)  # inputs that must stay byte-identical


# ----------------------------------------------------------------------------- base inputs
def render_bases(work: Path) -> dict:
    bases = {}
    delays = tuple(float(d) for d in range(0, 1501, 20))
    bases["png"] = write_synthetic_sequence(SynthConfig(u1_um_per_ms=70, u2_um=25, seed=3, delays_us=delays,
                                                        **SMALL), work / "base_png", progress=False)
    bases["other"] = write_synthetic_sequence(SynthConfig(u1_um_per_ms=55, u2_um=32, seed=4, delays_us=delays,
                                                          **SMALL), work / "base_other", progress=False)
    bases["stack"] = write_synthetic_sequence(SynthConfig(u1_um_per_ms=70, u2_um=25, seed=5, delays_us=delays,
                                                          format="tiff-stack", bit_depth=16, **SMALL),
                                              work / "base_stack", progress=False)
    ds = work / "base_dataset"
    make_synthetic_dataset(ds, grid=[(u1, u2) for u1 in (55, 65, 75) for u2 in (20, 27.5, 35)])
    bases["dataset"] = ds
    return bases


def clone(src: Path, dst: Path) -> Path:
    """Copy a folder with hard links (cases replace files, never write through them)."""
    shutil.copytree(src, dst, copy_function=os.link, ignore=shutil.ignore_patterns(".dropvision-output.json"))
    return dst


def replace_bytes(path: Path, data: bytes) -> None:
    path.unlink()
    path.write_bytes(data)


def png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def forged_png(width: int, height: int, colour: int = 0) -> bytes:
    ihdr = struct.pack(">IIBBBBB", width, height, 8, colour, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", ihdr) + png_chunk(b"IDAT", zlib.compress(b"\0" * 64)) + \
        png_chunk(b"IEND", b"")


def frames_of(seq: Path) -> list[str]:
    return [f["file"] for f in json.loads((seq / "sequence.json").read_text())["frames"]]


def load_meta(seq: Path) -> dict:
    return json.loads((seq / "sequence.json").read_text(encoding="utf-8"))


def save_meta(seq: Path, doc, *, raw: str | None = None) -> None:
    p = seq / "sequence.json"
    p.unlink()
    p.write_text(raw if raw is not None else json.dumps(doc), encoding="utf-8")


def measure_argv(seq: Path, out: Path) -> list[str]:
    return [PY, "-m", "dropvision.app.cli", "measure", str(seq), "--out", str(out), "--workers", "1"]


# ----------------------------------------------------------------------------- case families
def sequence_json_cases(bases, work) -> list[Case]:
    """Every metadata key gets hostile values: out of range, overflowing, wrong types."""
    cases = []
    truth = json.loads((bases["png"] / "truth.json").read_text())
    values = {
        "huge": 1e308, "tiny": 1e-300, "zero": 0, "negative": -4.73, "digits400": int("9" * 400),
        "string": "4.73 um", "list": [4.73], "nested": {"v": 4.73}, "nan_text": "NaN", "bool": True,
        "minus_zero": -0.0, "inf_text": "Infinity", "empty_string": "", "huge_negative": -1e308, "exp_text": "1e400",
    }
    keys = [("pixel_size_um",), ("nozzle_inner_diameter_um",), ("nozzle_outer_diameter_um",),
            ("nozzle_tip_row",), ("axis_col",), ("bit_depth",), ("orientation",),
            ("waveform", "u1_um_per_ms"), ("waveform", "u2_um"), ("waveform", "dead_time_us"),
            ("waveform", "u3_um_per_ms"), ("waveform", "hold_us")]
    for key in keys:
        for vname, value in values.items():
            name = f"{'.'.join(key)}={vname}"
            folder = clone(bases["png"], work / "json" / name.replace("/", "_"))
            doc = load_meta(folder)
            target = doc
            for k in key[:-1]:
                target = target[k]
            target[key[-1]] = value
            # a value that is merely another valid setting may be measured: then it must be right or flagged
            expect = "refuse_or_flag"
            save_meta(folder, doc)
            cases.append(Case("sequence.json values", name, measure_argv(folder, folder.parent / (folder.name + "_out")),
                              folder, expect, truth))
    # whole-document corruptions
    raws = {
        "truncated": lambda t: t[: len(t) // 2],
        "nested_20000": lambda t: "[" * 20000 + "]" * 20000,
        "bom": lambda t: "\ufeff" + t,
        "not_json": lambda t: "pixel_size_um = 4.73",
        "empty": lambda t: "",
        "array": lambda t: "[1, 2, 3]",
        "nan_literal": lambda t: t.replace('"pixel_size_um": 4.73', '"pixel_size_um": NaN'),
        "infinity_literal": lambda t: t.replace('"pixel_size_um": 4.73', '"pixel_size_um": Infinity'),
        "schema_null": lambda t: t.replace('"schema": "dropvision.sequence/1"', '"schema": null'),
        "schema_other": lambda t: t.replace('"schema": "dropvision.sequence/1"', '"schema": "other/9"'),
        "latin1": lambda t: t.replace('"synthetic colour ink"', '"encre couleur \xe9"'),
    }
    benign = {"bom", "schema_null"}
    for name, fn in raws.items():
        folder = clone(bases["png"], work / "jsonraw" / name)
        text = (folder / "sequence.json").read_text(encoding="utf-8")
        raw = fn(text)
        if name == "latin1":
            (folder / "sequence.json").unlink()
            (folder / "sequence.json").write_bytes(raw.encode("latin-1"))
        else:
            save_meta(folder, None, raw=raw)
        cases.append(Case("sequence.json documents", name, measure_argv(folder, folder.parent / (name + "_out")),
                          folder, "correct" if name in benign else "refuse_or_flag", truth))
    # frames list entries
    entries = {
        "missing_file": {"file": "nope.png", "delay_us": 10.0},
        "escape": {"file": "../x.png", "delay_us": 10.0},
        "absolute": {"file": "/etc/passwd", "delay_us": 10.0},
        "long_name": {"file": "a" * 300 + ".png", "delay_us": 10.0},
        "delay_text": {"file": None, "delay_us": "ten"},
        "delay_huge": {"file": None, "delay_us": 1e308},
        "delay_digits": {"file": None, "delay_us": int("9" * 400)},
        "no_delay": {"file": None},
    }
    for name, entry in entries.items():
        folder = clone(bases["png"], work / "entries" / name)
        doc = load_meta(folder)
        if entry.get("file") is None:
            entry = {**entry, "file": doc["frames"][5]["file"]}
            doc["frames"][5] = entry
        else:
            doc["frames"][5] = entry
        save_meta(folder, doc)
        cases.append(Case("frames entries", name, measure_argv(folder, folder.parent / (name + "_out")), folder,
                          "refuse_or_flag", truth))
    return cases


def frame_cases(bases, work) -> list[Case]:
    """Broken, foreign and oversized frames: each is skipped and reported (or the run refused)."""
    cases = []
    truth = json.loads((bases["png"] / "truth.json").read_text())
    names = frames_of(bases["png"])
    target = names[40]
    data = (bases["png"] / target).read_bytes()
    rng = np.random.default_rng(0)
    mutations = {f"truncate_{k}": (lambda d, k=k: d[:k]) for k in (0, 4, 8, 20, 33, 60, 200, len(data) // 2, len(data) - 4)}
    for i in range(30):
        def flip(d, i=i):
            b = bytearray(d)
            pos = int(np.random.default_rng(i).integers(8, len(b)))
            b[pos] ^= 0xFF
            return bytes(b)
        mutations[f"flip_{i}"] = flip
    mutations.update({
        "random_bytes": lambda d: rng.bytes(len(d)),
        "text": lambda d: b"not an image\n",
        "forged_50000_grey": lambda d: forged_png(50000, 50000, 0),
        "forged_50000_rgb": lambda d: forged_png(50000, 50000, 2),
        "forged_1x1": lambda d: forged_png(1, 1, 0),
        "bad_crc": lambda d: d[:29] + bytes([d[29] ^ 1]) + d[30:],
        "jpeg_named_png": lambda d: __import__("cv2").imencode(".jpg", np.zeros((448, 128), np.uint8))[1].tobytes(),
        "rgb_frame": lambda d: __import__("cv2").imencode(".png", np.dstack([__import__("cv2").imdecode(
            np.frombuffer(d, np.uint8), 0)] * 3))[1].tobytes(),
        "other_size": lambda d: __import__("cv2").imencode(".png", np.zeros((300, 128), np.uint8))[1].tobytes(),
        "sixteen_bit": lambda d: __import__("cv2").imencode(".png", np.zeros((448, 128), np.uint16))[1].tobytes(),
    })
    for name, fn in mutations.items():
        folder = clone(bases["png"], work / "frames" / name)
        replace_bytes(folder / target, fn(data))
        expect = "correct_or_flag" if name == "rgb_frame" else "refuse_or_flag"
        cases.append(Case("corrupt frames", name, measure_argv(folder, folder.parent / (name + "_out")), folder,
                          expect, truth))
    # a 4 GiB sparse file behind a PNG signature
    folder = clone(bases["png"], work / "frames" / "sparse_4gib")
    p = folder / target
    p.unlink()
    with open(p, "wb") as fh:
        fh.write(data[:33])
        fh.truncate(4 * 1024**3)
    cases.append(Case("corrupt frames", "sparse_4gib", measure_argv(folder, folder.parent / "sparse_out"), folder,
                      "refuse_or_flag", truth))
    # TIFF stack truncated
    for frac in (0.3, 0.6, 0.95):
        folder = clone(bases["stack"], work / "stack" / f"truncated_{frac}")
        st = folder / "stack.tif"
        d = st.read_bytes()
        replace_bytes(st, d[: int(len(d) * frac)])
        cases.append(Case("corrupt frames", f"tiff_stack_truncated_{frac}",
                          measure_argv(folder, folder.parent / f"trunc_{frac}_out"), folder, "refuse_or_flag",
                          json.loads((bases["stack"] / "truth.json").read_text())))
    return cases


def lying_metadata_cases(bases, work) -> list[Case]:
    """Plausible-looking lies: the answer must be flagged (or refused), never silently wrong."""
    cases = []
    truth = json.loads((bases["png"] / "truth.json").read_text())

    def variant(name, edit, family="lying metadata", expect="refuse_or_flag"):
        folder = clone(bases["png"], work / "lies" / name)
        doc = load_meta(folder)
        edit(doc, folder)
        save_meta(folder, doc)
        cases.append(Case(family, name, measure_argv(folder, folder.parent / (name + "_out")), folder, expect, truth))

    for f in (2.0, 0.5, 1.015, 1.05, 0.97):
        variant(f"pixel_size_x{f}", lambda d, fo, f=f: d.update(pixel_size_um=d["pixel_size_um"] * f))
        variant(f"pixel_size_x{f}_no_outer", lambda d, fo, f=f: (d.update(pixel_size_um=d["pixel_size_um"] * f),
                                                                d.pop("nozzle_outer_diameter_um")))
    variant("inner_diameter_x2", lambda d, fo: d.update(nozzle_inner_diameter_um=d["nozzle_inner_diameter_um"] * 2))
    variant("inner_ge_outer", lambda d, fo: d.update(nozzle_inner_diameter_um=d["nozzle_outer_diameter_um"] * 1.2))
    for label, fn in {"ms": lambda t: t / 1000, "x10": lambda t: t * 10, "minus1000": lambda t: t - 1000,
                      "x0.5": lambda t: t / 2}.items():
        variant(f"delays_{label}", lambda d, fo, fn=fn: [fr.update(delay_us=fn(fr["delay_us"])) for fr in d["frames"]])
    variant("swap_two_delays", lambda d, fo: (d["frames"][50].update(delay_us=d["frames"][60]["delay_us"]),
                                              d["frames"][60].update(delay_us=1000.0 + 0 * d["frames"][50]["delay_us"])))
    variant("repeat_label", lambda d, fo: d["frames"][55].update(delay_us=d["frames"][54]["delay_us"]))
    variant("two_frames", lambda d, fo: d.update(frames=[d["frames"][0], d["frames"][60]]))
    variant("one_frame", lambda d, fo: d.update(frames=[d["frames"][60]]))
    variant("reversed_delays", lambda d, fo: [fr.update(delay_us=1500 - fr["delay_us"]) for fr in d["frames"]])
    variant("u1_1e308", lambda d, fo: d["waveform"].update(u1_um_per_ms=1e308))
    variant("dead_time_0", lambda d, fo: d["waveform"].update(dead_time_us=0.0), expect="correct_or_flag")
    other = frames_of(bases["other"])

    def mix(k):
        def edit(d, folder):
            for i in range(k):
                name = d["frames"][30 + 3 * i]["file"]
                replace_bytes(folder / name, (bases["other"] / other[30 + 3 * i]).read_bytes())
        return edit
    for k in (1, 3, 8):
        variant(f"mixed_{k}_frames_from_other_sequence", mix(k))
    return cases


def output_cases(bases, work) -> list[Case]:
    """Output locations that would destroy inputs or a user's files: refused, inputs intact."""
    cases = []
    for name in ("equal", "inside", "parent", "user_folder", "user_file", "below_file", "symlink"):
        folder = clone(bases["png"], work / "outputs" / name / "seq")
        out = {"equal": folder, "inside": folder / "res", "parent": folder.parent,
               "user_folder": folder.parent / "mine", "user_file": folder.parent / "notes.txt",
               "below_file": folder.parent / "notes.txt" / "res", "symlink": folder.parent / "link"}[name]
        if name == "user_folder":
            out.mkdir()
            (out / "thesis.docx").write_text("years of work")
        if name in ("user_file", "below_file"):
            (folder.parent / "notes.txt").write_text("my notes")
        if name == "symlink":
            out.symlink_to(folder, target_is_directory=True)
        watch = sorted(p for p in folder.parent.rglob("*") if p.is_file())
        cases.append(Case("output locations", name, measure_argv(folder, out), folder, "refuse", watch=watch))
        # the campaign's --out too
        camp = work / "outputs" / f"campaign_{name}"
        root = clone(bases["png"], camp / "root" / "seq").parent
        out_c = {"equal": root, "inside": root / "seq" / "ds", "parent": camp, "user_folder": camp / "mine",
                 "user_file": camp / "notes.txt", "below_file": camp / "notes.txt" / "ds",
                 "symlink": camp / "link"}[name]
        if name == "user_folder":
            out_c.mkdir()
            (out_c / "results.tmp").write_text("years of work")
        if name in ("user_file", "below_file"):
            (camp / "notes.txt").write_text("my notes")
        if name == "symlink":
            out_c.symlink_to(root / "seq", target_is_directory=True)
        watch = sorted(p for p in camp.rglob("*") if p.is_file())
        cases.append(Case("output locations", f"campaign_{name}",
                          [PY, "-m", "dropvision.app.cli", "campaign", str(root), "--out", str(out_c), "--workers", "1",
                           "--no-progress"], root, "refuse", watch=watch))
    return cases


def link_cases(bases, work) -> list[Case]:
    """Links out of the sequence folder: never followed (frames) or refused (sequence.json)."""
    cases = []
    truth = json.loads((bases["png"] / "truth.json").read_text())
    names = frames_of(bases["png"])
    outside = work / "outside"
    outside.mkdir(exist_ok=True)
    shutil.copy(bases["other"] / frames_of(bases["other"])[40], outside / "canary.png")
    for i, target in enumerate((outside / "canary.png", Path("/etc/passwd"), outside / "missing.png")):
        folder = clone(bases["png"], work / "links" / f"frame_{i}")
        (folder / names[40]).unlink()
        (folder / names[40]).symlink_to(target)
        cases.append(Case("links out of the folder", f"frame_link_{target.name}",
                          measure_argv(folder, folder.parent / f"frame_{i}_out"), folder, "refuse_or_flag", truth,
                          outside_file=names[40]))
    folder = clone(bases["png"], work / "links" / "json")
    shutil.copy(folder / "sequence.json", outside / "sequence.json")
    (folder / "sequence.json").unlink()
    (folder / "sequence.json").symlink_to(outside / "sequence.json")
    cases.append(Case("links out of the folder", "sequence_json_link", measure_argv(folder, folder.parent / "json_out"),
                      folder, "refuse"))
    # a link inside the folder is fine
    folder = clone(bases["png"], work / "links" / "inside")
    data = (folder / names[40]).read_bytes()
    (folder / names[40]).unlink()
    (folder / "store").mkdir()
    (folder / "store" / names[40]).write_bytes(data)
    (folder / names[40]).symlink_to(Path("store") / names[40])
    cases.append(Case("links out of the folder", "link_inside_ok", measure_argv(folder, folder.parent / "inside_out"),
                      folder, "correct", truth))
    return cases


def identify_cases(bases, work) -> list[Case]:
    """Broken model files, absurd sample counts, lying datasets."""
    cases = []
    ds = bases["dataset"]
    model = work / "identify" / "model.json"
    model.parent.mkdir(parents=True, exist_ok=True)
    subprocess.run([PY, "-m", "identify.app.cli", "fit", str(ds), "--out", str(model), "--no-arx"], check=True,
                   capture_output=True)
    good = json.loads(model.read_text())
    predict = ["predict", "--u1", "70", "--u2", "25", "--samples", "200", "--json"]
    ref = json.loads(subprocess.run([PY, "-m", "identify.app.cli", predict[0], str(model), *predict[1:]], check=True,
                                    capture_output=True, text=True).stdout)

    def mutated(name, fn):
        p = work / "identify" / "models" / f"{name}.json"
        p.parent.mkdir(parents=True, exist_ok=True)
        doc = json.loads(json.dumps(good))
        doc = fn(doc)
        p.write_text(doc if isinstance(doc, str) else json.dumps(doc))
        return p

    def walk_numbers(doc, path=()):
        if isinstance(doc, dict):
            for k, v in doc.items():
                yield from walk_numbers(v, path + (k,))
        elif isinstance(doc, list) and doc and all(isinstance(x, (int, float)) for x in doc):
            yield path
        elif isinstance(doc, (int, float)) and not isinstance(doc, bool):
            yield path

    def setp(doc, path, value):
        t = doc
        for k in path[:-1]:
            t = t[k]
        t[path[-1]] = value
        return doc

    paths = [p for p in walk_numbers(good) if p and p[0] not in ("versions",)][:30]
    for path in paths:
        for vname, value in (("string", "abc"), ("null", None), ("huge", 1e308)):
            name = f"{'.'.join(map(str, path))}={vname}"
            p = mutated(name.replace("/", "_"), lambda d, path=path, value=value: setp(d, path, value))
            cases.append(Case("model files", name, [PY, "-m", "identify.app.cli", predict[0], str(p), *predict[1:]],
                              p.parent, "refuse_or_flag", truth={"predict": ref}))
    for name, fn in {"truncated": lambda d: json.dumps(d)[:100], "nested": lambda d: "[" * 20000 + "]" * 20000,
                     "schema_other": lambda d: {**d, "schema": "x/1"}, "empty_object": lambda d: {},
                     "not_json": lambda d: "model"}.items():
        p = mutated(name, fn)
        cases.append(Case("model files", name, [PY, "-m", "identify.app.cli", "predict", str(p), "--u1", "70", "--u2",
                                                "25"], p.parent, "refuse"))
    for samples in ("1000000000", "0", "-5", "1e3"):
        cases.append(Case("identify arguments", f"samples_{samples}",
                          [PY, "-m", "identify.app.cli", "predict", str(model), "--u1", "70", "--u2", "25",
                           "--samples", samples], model.parent, "refuse"))
    for u in ("0", "-1", "nan", "1e308", "inf"):
        cases.append(Case("identify arguments", f"u1_{u}",
                          [PY, "-m", "identify.app.cli", "predict", str(model), "--u1", u, "--u2", "25"],
                          model.parent, "refuse"))
    # lying datasets
    def dataset_variant(name, edit):
        folder = work / "identify" / "datasets" / name
        shutil.copytree(ds, folder, ignore=shutil.ignore_patterns(".dropvision-output.json"))
        ts = pd.read_parquet(folder / "timeseries.parquet")
        su = pd.read_parquet(folder / "summary.parquet")
        meta = json.loads((folder / "dataset.json").read_text())
        ts, su, meta = edit(ts, su, meta)
        ts.to_parquet(folder / "timeseries.parquet", index=False)
        su.to_parquet(folder / "summary.parquet", index=False)
        (folder / "dataset.json").write_text(json.dumps(meta))
        out = work / "identify" / "datasets" / f"{name}.model.json"
        cases.append(Case("lying datasets", name, [PY, "-m", "identify.app.cli", "fit", str(folder), "--out", str(out),
                                                   "--no-arx"], folder, "refuse_or_flag"))

    dataset_variant("constant_outputs", lambda ts, su, m: (ts, su.assign(inflight_volume_nl=19.0,
                                                                           jetting_velocity_m_s=1.3), m))
    dataset_variant("swapped_u1_u2", lambda ts, su, m: (ts.rename(columns={"u1_um_per_ms": "u2_um", "u2_um": "u1_um_per_ms"}),
                                                        su.rename(columns={"u1_um_per_ms": "u2_um", "u2_um": "u1_um_per_ms"}), m))
    dataset_variant("pl_as_nl", lambda ts, su, m: (ts.assign(grown_volume_nl=ts.grown_volume_nl * 1000),
                                                   su.assign(inflight_volume_nl=su.inflight_volume_nl * 1000,
                                                             grown_volume_at_pinchoff_nl=su.grown_volume_at_pinchoff_nl * 1000), m))
    dataset_variant("strings_in_volumes", lambda ts, su, m: (ts.assign(grown_volume_nl=ts.grown_volume_nl.astype(str)), su, m))
    dataset_variant("diameter_1e308", lambda ts, su, m: (ts, su, {**m, "nozzle_inner_diameter_um": 1e308}))
    dataset_variant("interval_0", lambda ts, su, m: (ts, su, {**m, "sample_interval_us": 0}))
    dataset_variant("one_sequence", lambda ts, su, m: (ts[ts.sequence_id == ts.sequence_id.iloc[0]],
                                                       su.iloc[:1], m))
    dataset_variant("velocity_mm_s_as_m_s", lambda ts, su, m: (
        ts.assign(flow_velocity_m_s=ts.flow_velocity_m_s * 1000),
        su.assign(jetting_velocity_m_s=su.jetting_velocity_m_s * 1000,
                  flow_velocity_at_max_stroke_m_s=su.flow_velocity_at_max_stroke_m_s * 1000), m))
    # outputs onto or inside the input dataset, whatever --overwrite says (issue 29 item 1)
    for name, target in (("model_over_summary", "summary.parquet"), ("model_over_manifest", "manifest.json"),
                         ("model_inside_dataset", "model.json")):
        folder = work / "identify" / "outputs" / name / "ds"
        shutil.copytree(ds, folder)
        (folder / "manifest.json").write_text('{"schema": "dropvision.manifest/1", "sequences": {}}')
        cases.append(Case("identify outputs", name, [PY, "-m", "identify.app.cli", "fit", str(folder), "--out",
                                                     str(folder / target), "--overwrite", "--no-arx"],
                          folder, "refuse"))
    return cases


def build(work: Path, quick: bool) -> list[Case]:
    bases = render_bases(work)
    families = [sequence_json_cases, frame_cases, lying_metadata_cases, output_cases, link_cases, identify_cases]
    cases = [c for fam in families for c in fam(bases, work)]
    if quick:
        seen, picked = set(), []
        for c in cases:
            if c.family not in seen:
                seen.add(c.family)
                picked.append(c)
        cases = picked
    return cases


# ----------------------------------------------------------------------------- running
def _hashes(paths) -> dict:
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in paths if p.is_file()}


def _input_files(case: Case) -> list[Path]:
    if case.watch:
        return case.watch
    if case.folder.is_dir():
        return sorted(p for p in case.folder.rglob("*") if p.is_file() and not p.is_symlink()
                      and p.stat().st_size < 50_000_000)
    return []


def run_case(case: Case) -> dict:
    import psutil

    watched = _input_files(case)
    before = _hashes(watched)
    out = None
    try:
        out = Path(case.argv[case.argv.index("--out") + 1])
    except ValueError:
        pass
    t0 = time.perf_counter()
    proc = subprocess.Popen(case.argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, env={**os.environ, "PYTHONWARNINGS": "ignore"})
    peak = [0]
    done = threading.Event()

    def watch():
        try:
            ps = psutil.Process(proc.pid)
            while not done.is_set():
                rss = sum(p.memory_info().rss for p in [ps, *ps.children(recursive=True)])
                peak[0] = max(peak[0], rss)
                if rss > LIMIT_RSS:
                    os.killpg(proc.pid, signal.SIGKILL)
                    return
                time.sleep(0.05)
        except (psutil.Error, ProcessLookupError):
            return

    threading.Thread(target=watch, daemon=True).start()
    try:
        stdout, stderr = proc.communicate(timeout=LIMIT_S)
        hung = False
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        stdout, stderr = proc.communicate()
        hung = True
    done.set()
    seconds = time.perf_counter() - t0
    changed = [p for p, h in before.items() if not Path(p).is_file() or _hashes([Path(p)]).get(p) != h]
    outcome, detail = classify(case, proc.returncode, stdout, stderr, hung, peak[0], out, changed)
    return {"family": case.family, "case": case.name, "expect": case.expect, "outcome": outcome,
            "exit": proc.returncode, "seconds": round(seconds, 2), "peak_mb": round(peak[0] / 1e6, 1),
            "detail": detail[:300]}


def classify(case, rc, stdout, stderr, hung, peak, out, changed):
    if changed:
        return "destroyed", f"changed: {changed[:2]}"
    if hung:
        return "hang", f"over {LIMIT_S:.0f} s"
    if peak > LIMIT_RSS:
        return "memory", f"{peak / 1e9:.1f} GB"
    if "Traceback (most recent call last)" in stderr:
        return "traceback", stderr.strip().splitlines()[-1]
    lines = [ln for ln in stderr.strip().splitlines() if ln.strip()]
    if rc == 2:
        return ("refused", lines[-1] if lines else "") if len(lines) == 1 else ("traceback", " | ".join(lines[-3:]))
    if rc != 0:
        return "traceback", f"exit {rc}: {' | '.join(lines[-2:])}"
    if case.expect == "refuse":
        return "silent_wrong", "accepted where it must be refused"
    # exit 0: what did it say?
    if case.argv[2] == "identify.app.cli":
        if case.truth and "predict" in case.truth:  # a damaged field that does not change the prediction
            try:
                got = pd.json_normalize(json.loads(stdout)).iloc[0]
                ref = pd.json_normalize(case.truth["predict"]).iloc[0]
                same = list(got.index) == list(ref.index) and all(
                    np.isclose(g, r, rtol=1e-9, equal_nan=True)
                    if isinstance(r, (int, float)) and not isinstance(r, bool) else g == r
                    for g, r in zip(got.tolist(), ref.tolist()))
            except (ValueError, TypeError):
                same = False
            return ("correct", "prediction unchanged") if same else ("silent_wrong", "prediction changed, no word")
        return ("flagged", "note") if "note:" in stdout or "warning" in stdout.lower() else (
            ("silent_wrong", f"{case.argv[3]} without a note") if case.expect != "correct" else ("correct", ""))
    if out is None or not (out / "summary.json").is_file():
        return "silent_wrong", "exit 0 without a result"
    summary = json.loads((out / "summary.json").read_text())
    frames = pd.read_parquet(out / "frames.parquet")
    if case.outside_file and case.outside_file in set(frames["file"]):
        return "read_outside", f"{case.outside_file} was measured"
    flagged = bool(summary.get("errors")) or bool(summary.get("notes")) or (frames["quality"] != "ok").any() \
        or any("note" in str(v) for v in (summary.get("calibration") or {}).get("notes", []) or [])
    truth = case.truth or {}
    ok = True
    if truth:
        for key, tol in (("inflight_volume_nl", 0.01), ("jetting_velocity_m_s", 0.01)):
            m, t = summary.get(key), truth.get(key)
            if t is not None and (m is None or not np.isfinite(m) or abs(m / t - 1) > tol):
                ok = False
        if truth.get("pinchoff_us") is not None and summary.get("pinchoff_us") != truth["pinchoff_us"]:
            ok = False
    if flagged:
        return "flagged", "; ".join(str(e.get("reason", e))[:80] for e in (summary.get("errors") or [])[:2]) or \
            "; ".join(summary.get("notes") or []) or "frames flagged"
    if ok:
        return "correct", ""
    return "silent_wrong", (f"in-flight {summary.get('inflight_volume_nl')} vs {truth.get('inflight_volume_nl')}, "
                            f"v {summary.get('jetting_velocity_m_s')} vs {truth.get('jetting_velocity_m_s')}, "
                            f"pinch-off {summary.get('pinchoff_us')} vs {truth.get('pinchoff_us')}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one case per family")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None, help="write the per-case table (CSV)")
    ap.add_argument("--keep", type=Path, default=None, help="build the corpus here and keep it")
    args = ap.parse_args(argv)
    work = args.keep or Path(tempfile.mkdtemp(prefix="dv-hostile-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        t0 = time.perf_counter()
        cases = build(work, args.quick)
        print(f"{len(cases)} cases built in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
        with ThreadPoolExecutor(args.jobs) as ex:
            rows = list(ex.map(run_case, cases))
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)
    table = pd.DataFrame(rows)
    if args.out:
        table.to_csv(args.out, index=False)
    counts = table.pivot_table(index="family", columns="outcome", values="case", aggfunc="count", fill_value=0)
    counts.loc["total"] = counts.sum()
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(counts.to_string())
    bad = table[table["outcome"].isin(BAD)]
    for r in bad.itertuples():
        print(f"BAD {r.outcome:12s} {r.family} / {r.case}: {r.detail}")
    print(f"{len(table)} cases: {len(bad)} bad ({', '.join(BAD)}); peak memory {table['peak_mb'].max():.0f} MB, "
          f"slowest {table['seconds'].max():.1f} s")
    return 1 if len(bad) else 0


if __name__ == "__main__":
    sys.exit(main())
