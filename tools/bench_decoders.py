"""Decode speed of the JPEG decoders (and PNG/TIFF/video for reference), ms per frame.

Usage::

    .venv/bin/python tools/bench_decoders.py [--repeats 7] [--out bench.csv]

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
    from dropvision.readers import reader_for
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
        from dropvision.readers.video import OpenVideo, VideoReader
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7, help="rounds (median taken), >= 5")
    ap.add_argument("--inner", type=int, default=5, help="decodes per round")
    ap.add_argument("--out", type=Path, help="also write the table as CSV")
    args = ap.parse_args(argv)
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
