"""Decode speed of the JPEG decoders (and PNG/TIFF/video for reference), ms per frame.

Usage::

    .venv/bin/python tools/bench_decoders.py [--repeats 7] [--out bench.csv]
    .venv/bin/python tools/bench_decoders.py --corpus [--repeats 7] [--realdata ../shared/realdata]

``--corpus``: every format we read, each decoder that can read it, one table (ms/frame, and
the ratio to the fastest maintained decoder): PNGs written by Pillow (adaptive filtering: Sub,
Up, Paeth rows) and by OpenCV (every row Sub), 8- and 16-bit grey and 8-bit colour, of
640x1024 drop frames at three noise levels; the real JPEGs of ``--realdata`` (colour, decoded to
grey) and synthetic grey/colour JPEGs; 16-bit TIFF pages. PNG decoders: our reader
(`dropvision.io.readers.png`), imagecodecs ``png_decode`` (libpng + zlib-ng) and ``spng_decode``
(libspng), pyspng (if installed), ``cv2.imdecode``, Pillow; JPEG: our reader (imagecodecs
libjpeg-turbo), ``cv2.imdecode``, Pillow; TIFF: our reader, tifffile, imagecodecs
``tiff_decode``. Every decoder's array is checked equal to OpenCV's (colour: channel order
aside) before it is timed; a decoder that cannot read a kind is listed as such.

Images: a synthetic backlit drop frame (dark nozzle and drops on a bright, slightly noisy
background, like ``dropvision synth``) at 2048x1536 and at 640x1024 (WxH), 8-bit grey, and a
colour (3-channel) copy. JPEGs are written by OpenCV at quality 90. Every decoder decodes the
full-resolution image (no reduced-size or region decoding: the measurement needs every pixel)
to a grey uint8 array where it can (``cv2.IMREAD_GRAYSCALE``, simplejpeg ``colorspace="GRAY"``,
TurboJPEG ``TJPF_GRAY``) and, for colour files, also to colour.

One thread: ``cv2.setNumThreads(1)`` (OpenCV) and the environment variables of the BLAS/OpenMP
pools are set to 1 before anything is imported. Each (image, decoder) pair is timed in
``--repeats`` rounds; the decoders alternate within a round (round-robin, so drift of the
machine hits all of them alike); each round times ``--inner`` decodes and keeps the mean; the
table gives the median over rounds. Decoders that are not installed are listed as absent:

- ``cv2.imdecode``: opencv-python-headless (bundles libjpeg-turbo);
- ``simplejpeg``: ``pip install simplejpeg`` (wheels bundle libjpeg-turbo);
- ``PyTurboJPEG``: ``pip install PyTurboJPEG`` AND a system libturbojpeg (Debian:
  ``apt-get install libturbojpeg0``, libjpeg-turbo 2.1 in bookworm, which needs
  PyTurboJPEG < 2; PyTurboJPEG 2.x needs libjpeg-turbo >= 3.0);
- ``PIL``: Pillow (bundles libjpeg-turbo in its wheels);
- for reference: our readers on PNG (OpenCV- and Pillow-written), TIFF 16-bit, and
  ``cv2.VideoCapture`` / PyAV on an MJPG AVI of the same frames (per frame, sequential).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import io  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

cv2.setNumThreads(1)


def frame(width: int, height: int, seed: int = 0) -> np.ndarray:
    """A backlit drop-watcher-like 8-bit frame: bright background, dark nozzle and drops."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    img = 215.0 - 25.0 * ((xx - width / 2) ** 2 + (yy - height / 2) ** 2) / (width ** 2)
    nozzle = (np.abs(xx - width / 2) < width * 0.06) & (yy < height * 0.15)
    img[nozzle] = 30.0
    for k in range(6):
        cy, r = height * (0.25 + 0.12 * k), width * (0.03 if k == 0 else 0.01)
        img[(xx - width / 2) ** 2 + (yy - cy) ** 2 < r * r] = 35.0
    img = cv2.GaussianBlur(img, (0, 0), 1.2) + rng.normal(0, 2.0, img.shape).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)


def _time(fn, inner: int) -> float:
    t0 = time.perf_counter()
    for _ in range(inner):
        fn()
    return (time.perf_counter() - t0) / inner * 1e3


def decoders(jpeg: bytes, colour: bool) -> dict:
    """name -> zero-argument callable decoding ``jpeg`` at full resolution (absent: skipped)."""
    out = {}
    buf = np.frombuffer(jpeg, np.uint8)
    out["cv2.imdecode grey"] = lambda: cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
    if colour:
        out["cv2.imdecode colour"] = lambda: cv2.imdecode(buf, cv2.IMREAD_COLOR)
    out["cv2.imdecode unchanged"] = lambda: cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    try:
        import simplejpeg
        out["simplejpeg grey"] = lambda: simplejpeg.decode_jpeg(jpeg, colorspace="GRAY")
        if colour:
            out["simplejpeg colour"] = lambda: simplejpeg.decode_jpeg(jpeg, colorspace="BGR")
    except ImportError:
        out["simplejpeg (absent)"] = None
    try:
        import turbojpeg
        tj = turbojpeg.TurboJPEG()
        out["PyTurboJPEG grey"] = lambda: tj.decode(jpeg, pixel_format=turbojpeg.TJPF_GRAY)
        if colour:
            out["PyTurboJPEG colour"] = lambda: tj.decode(jpeg, pixel_format=turbojpeg.TJPF_BGR)
    except (ImportError, RuntimeError, OSError) as exc:
        out[f"PyTurboJPEG (absent: {type(exc).__name__})"] = None
    try:
        import io

        from PIL import Image

        def pil():
            with Image.open(io.BytesIO(jpeg)) as im:
                return np.asarray(im.convert("L") if colour else im)
        out["PIL grey"] = pil
    except ImportError:
        out["PIL (absent)"] = None
    return out


def reader_cases(folder: Path, img: np.ndarray) -> dict:
    """Reference: our readers on PNG/TIFF files of the same frame."""
    from dropvision.io.readers import reader_for
    cases = {}
    p = folder / "cv2.png"
    cv2.imwrite(str(p), img)
    cases["PNG 8-bit (cv2-written) via PngReader"] = p
    try:
        from PIL import Image
        p = folder / "pil.png"
        Image.fromarray(img).save(p)
        cases["PNG 8-bit (Pillow-written) via PngReader"] = p
    except ImportError:
        pass
    import tifffile
    p = folder / "t16.tif"
    tifffile.imwrite(p, img.astype(np.uint16) * 16)
    cases["TIFF 16-bit (uncompressed) via TiffReader"] = p
    p = folder / "t.jpg"
    cv2.imwrite(str(p), img, [cv2.IMWRITE_JPEG_QUALITY, 90])
    if reader_for(p) is not None:
        cases["JPEG 8-bit q90 via the registry reader"] = p
    return {k: (lambda path=v: reader_for(path).decode(path, None)) for k, v in cases.items()}


def video_cases(folder: Path, img: np.ndarray, n: int = 20) -> dict:
    """Reference: per-frame cost of sequential video decoding (MJPG AVI of ``n`` frames)."""
    path = folder / "v.avi"
    h, w = img.shape
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (w, h), False)
    for _ in range(n):
        vw.write(img)
    vw.release()
    out = {}

    def cap():
        from dropvision.io.readers.video import OpenVideo, VideoReader
        handle = OpenVideo(VideoReader(), path)
        try:
            for k in range(n):
                handle.decode(k)
        finally:
            handle.close()
        return n
    out[f"MJPG AVI via VideoReader/cv2.VideoCapture (per frame of {n})"] = (cap, n)
    try:
        import av

        def pyav():
            with av.open(str(path)) as c:
                k = 0
                for fr in c.decode(video=0):
                    fr.to_ndarray(format="gray")
                    k += 1
            return k
        out[f"MJPG AVI via PyAV (per frame of {n})"] = (pyav, n)
    except ImportError:
        out["PyAV (absent)"] = (None, n)
    return out


def _pil_png(img: np.ndarray) -> bytes:
    import io

    from PIL import Image
    buf = io.BytesIO()
    Image.fromarray(img[..., ::-1] if img.ndim == 3 else img).save(buf, format="PNG")
    return buf.getvalue()


def _corpus(realdata: Path | None) -> dict:
    """kind -> (list of file bytes, suffix, how OpenCV decodes it for the reference)."""
    frames = []
    for k, sigma in enumerate((0.0, 2.0, 6.0)):
        img = frame(640, 1024, seed=k).astype(np.float32)
        img += np.random.default_rng(k).normal(0, sigma, img.shape).astype(np.float32)
        frames.append(np.clip(img, 0, 255).astype(np.uint8))
    colour = [cv2.merge([g, (g * 0.9).astype(np.uint8), g]) for g in frames]
    wide = [g.astype(np.uint16) * 257 for g in frames]
    cv2png = lambda im: cv2.imencode(".png", im)[1].tobytes()  # noqa: E731
    unchanged, grey = cv2.IMREAD_UNCHANGED, cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION
    out = {
        "PNG 8-bit grey, Pillow": ([_pil_png(g) for g in frames], ".png", unchanged),
        "PNG 8-bit grey, OpenCV": ([cv2png(g) for g in frames], ".png", unchanged),
        "PNG 16-bit grey, Pillow": ([_pil_png(g) for g in wide], ".png", unchanged),
        "PNG 16-bit grey, OpenCV": ([cv2png(g) for g in wide], ".png", unchanged),
        "PNG 8-bit colour, Pillow": ([_pil_png(c) for c in colour], ".png", unchanged),
        "PNG 8-bit colour, OpenCV": ([cv2png(c) for c in colour], ".png", unchanged),
        "JPEG grey q90 640x1024": ([cv2.imencode(".jpg", g, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()
                                    for g in frames], ".jpg", unchanged),
        "JPEG colour q90 640x1024 -> grey": ([cv2.imencode(".jpg", c, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()
                                             for c in colour], ".jpg", grey),
    }
    if realdata is not None:
        real = sorted(realdata.glob("watcher-dod/*/*.jpg"))
        if real:
            out["JPEG colour 2048x1536 real watcher -> grey"] = ([p.read_bytes() for p in real], ".jpg", grey)
    import tifffile
    tiffs = []
    for g in wide:
        buf = io.BytesIO()
        tifffile.imwrite(buf, g)
        tiffs.append(buf.getvalue())
    out["TIFF 16-bit grey, uncompressed"] = (tiffs, ".tif", unchanged)
    return out


def _corpus_decoders(suffix: str, flags: int, folder: Path) -> dict:
    """name -> (decode(bytes, path) -> array, maintained?) for files of ``suffix``."""
    import imagecodecs

    from dropvision.io.readers import reader_for
    to_grey = flags != cv2.IMREAD_UNCHANGED
    reader = reader_for("x" + suffix)
    out = {"dropvision reader": (lambda d, p: reader.decode(p, None), False),
           "cv2.imdecode": (lambda d, p: cv2.imdecode(np.frombuffer(d, np.uint8), flags), True)}
    if suffix == ".png":
        out["imagecodecs png (libpng)"] = (lambda d, p: imagecodecs.png_decode(d), True)
        out["imagecodecs spng"] = (lambda d, p: imagecodecs.spng_decode(d), True)
        try:
            import pyspng
            out["pyspng"] = (lambda d, p: pyspng.load(d), True)
        except ImportError:
            out["pyspng (absent)"] = (None, True)
    elif suffix == ".jpg":
        out["imagecodecs jpeg8"] = (lambda d, p: imagecodecs.jpeg8_decode(
            d, outcolorspace="GRAY" if to_grey else None), True)
    else:
        import tifffile
        out["tifffile"] = (lambda d, p: tifffile.imread(io.BytesIO(d)), True)
        out["imagecodecs tiff"] = (lambda d, p: imagecodecs.tiff_decode(d), True)

    def pil(d, p):
        from PIL import Image
        with Image.open(io.BytesIO(d)) as im:
            return np.asarray(im.convert("L") if to_grey else im)
    out["Pillow"] = (pil, True)
    return out


def _same(a: np.ndarray, ref: np.ndarray) -> bool:
    a = np.asarray(a)
    if a.shape != ref.shape or a.dtype != ref.dtype:
        return False
    return bool(np.array_equal(a, ref) or (a.ndim == 3 and np.array_equal(a[..., ::-1], ref)))


def run_corpus(repeats: int, realdata: Path | None) -> list[tuple]:
    """Rows (kind, decoder, ms/frame or nan, note): every decoder on every kind, checked
    equal to OpenCV's array first, timed in interleaved rounds (median)."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for kind, (datas, suffix, flags) in _corpus(realdata).items():
            folder = Path(tmp) / f"k{len(rows)}"
            folder.mkdir()
            paths = []
            for i, d in enumerate(datas):
                paths.append(folder / f"{i}{suffix}")
                paths[-1].write_bytes(d)
            refs = [cv2.imdecode(np.frombuffer(d, np.uint8), flags) for d in datas]
            live, notes = {}, {}
            for name, (fn, maintained) in _corpus_decoders(suffix, flags, folder).items():
                if fn is None:
                    notes[name] = "not installed"
                    continue
                try:
                    ok = all(_same(fn(d, p), r) for d, p, r in zip(datas, paths, refs))
                except Exception as exc:  # noqa: BLE001 - a decoder that cannot read the kind
                    notes[name] = f"cannot: {type(exc).__name__}: {str(exc)[:50]}"
                    continue
                # Pillow's own colour->grey rounds differently: timed, flagged
                notes[name] = "" if ok else "NOT identical to OpenCV"
                live[name] = fn
            times = {k: [] for k in live}
            for _ in range(repeats):
                for name, fn in live.items():
                    t0 = time.perf_counter()
                    for d, p in zip(datas, paths):
                        fn(d, p)
                    times[name].append((time.perf_counter() - t0) / len(datas) * 1e3)
            for name in notes:
                ms = statistics.median(times[name]) if name in times else float("nan")
                rows.append((kind, name, ms, notes[name]))
    return rows


def print_corpus(rows: list[tuple]) -> None:
    """The corpus table, with each decoder's time relative to the fastest other decoder."""
    width = max(len(r[1]) for r in rows)
    kwidth = max(len(r[0]) for r in rows)
    print(f"{'kind':<{kwidth}}  {'decoder':<{width}}  ms/frame  vs best other  note")
    for kind, name, ms, note in rows:
        others = [r[2] for r in rows if r[0] == kind and r[1] != name and r[2] == r[2] and not r[3]]
        ratio = ms / min(others) if others and ms == ms else float("nan")
        print(f"{kind:<{kwidth}}  {name:<{width}}  {ms:8.2f}  {ratio:12.2f}x  {note}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--corpus", action="store_true",
                    help="every format we read x every decoder (see the module docstring)")
    ap.add_argument("--realdata", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "realdata",
                    help="folder of the real frames (its watcher-dod JPEGs join --corpus)")
    ap.add_argument("--repeats", type=int, default=7, help="rounds (median taken), >= 5")
    ap.add_argument("--inner", type=int, default=5, help="decodes per round")
    ap.add_argument("--out", type=Path, help="also write the table as CSV")
    args = ap.parse_args(argv)
    if args.corpus:
        rows = run_corpus(args.repeats, args.realdata if args.realdata.is_dir() else None)
        print_corpus(rows)
        if args.out:
            import csv
            with open(args.out, "w", newline="") as fh:
                wr = csv.writer(fh)
                wr.writerow(["kind", "decoder", "ms_per_frame", "note"])
                wr.writerows(rows)
        return 0
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for w, h in ((2048, 1536), (640, 1024)):
            grey = frame(w, h)
            colour = cv2.merge([grey, (grey * 0.9).astype(np.uint8), grey])
            for label, img, is_colour in (("grey", grey, False), ("colour", colour, True)):
                ok, enc = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
                jpeg_input = f"{label} JPEG q90"
                cases = {k: (v, 1, jpeg_input)
                         for k, v in decoders(enc.tobytes(), is_colour).items()}
                if not is_colour:
                    sub = tmp / f"{w}x{h}"
                    sub.mkdir()
                    cases.update({k: (v, 1, "grey file") for k, v in reader_cases(sub, grey).items()})
                    cases.update({k: (v[0], v[1], "grey video") for k, v in video_cases(sub, grey).items()})
                live = {k: v for k, v in cases.items() if v[0] is not None}
                for fn, *_ in live.values():  # warm up
                    fn()
                times = {k: [] for k in live}
                for _ in range(args.repeats):
                    for k, (fn, per, _) in live.items():
                        inner = 1 if per > 1 else args.inner
                        times[k].append(_time(fn, inner) / per)
                for k in cases:
                    med = statistics.median(times[k]) if k in times else float("nan")
                    rows.append((f"{w}x{h}", cases[k][2], k, med, len(enc)))
    width = max(len(r[2]) for r in rows)
    print(f"{'size':>9}  {'input':<15} {'decoder':<{width}}  ms/frame  (JPEG q90 bytes)")
    for size, inp, name, ms, nbytes in rows:
        print(f"{size:>9}  {inp:<15} {name:<{width}}  {ms:8.2f}  ({nbytes})")
    if args.out:
        import csv
        with open(args.out, "w", newline="") as fh:
            wr = csv.writer(fh)
            wr.writerow(["size", "input", "decoder", "ms_per_frame"])
            wr.writerows([r[:4] for r in rows])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
