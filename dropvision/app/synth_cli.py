"""`dropvision synth OUT ...`: write a synthetic strobe sequence with its ground truth."""

from __future__ import annotations

import argparse
import time

from dvcore.errors import UsageError

__all__ = ["register", "run"]


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size {text!r}: expected WIDTHxHEIGHT, e.g. 640x1024") from None
    return w, h


def _holder(text: str):
    t = text.strip().lower()
    if t in ("yes", "true", "on", "1"):
        return True
    if t in ("no", "false", "off", "0"):
        return False
    try:
        return float(t)
    except ValueError:
        raise argparse.ArgumentTypeError(f"holder {text!r}: expected yes, no or a width in µm") from None


def _waveform(text: str) -> dict:
    import json

    try:
        doc = json.loads(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"waveform {text!r}: not JSON ({exc})") from None
    if not isinstance(doc, dict) or "template" not in doc:
        raise argparse.ArgumentTypeError(f"waveform {text!r}: expected a JSON object with a 'template' key")
    return doc


def _rig_names() -> list[str]:
    # the preset names, without importing the synthesizer (kept in step by a test)
    return ["clean", "watcher-side", "watcher-blurred-holder", "pendant-saturated", "low-contrast", "tilted-dusty",
            "single-frame"]


#: command-line option -> SynthConfig field, for options whose default (None) means "the rig's"
_REALISM = {"orientation": "orientation", "jpeg_quality": "jpeg_quality", "colour": "colour",
            "exposure": "exposure", "clip_fraction": "clip_fraction", "vignetting": "vignetting",
            "mist": "mist", "path_dust": "path_dust", "holder": "holder",
            "nozzle_protrusion_um": "nozzle_protrusion_um", "holder_blur_px": "holder_blur_px"}


def register(subparsers) -> argparse.ArgumentParser:
    """Add the ``synth`` sub-command."""
    p = subparsers.add_parser(
        "synth", help="write a physics-driven synthetic strobe sequence with exact ground truth",
        description=__doc__.splitlines()[0])
    p.add_argument("out", help="output sequence folder (replaced only if it holds nothing but an earlier "
                   "result of ours)")
    p.add_argument("--overwrite", action="store_true",
                   help="write into an OUT folder of ours that holds other files too: our earlier "
                   "files are replaced, the others kept (a folder dropvision did not write is refused)")
    p.add_argument("--u1", type=float, default=70.0, help="stroke velocity u1 (µm/ms), default 70")
    p.add_argument("--u2", type=float, default=25.0, help="stroke u2 (µm), default 25")
    p.add_argument("--waveform", type=_waveform, default=None,
                   help="drive the head with a waveform template instead of --u1/--u2: sequence.json's template "
                        "form as JSON, e.g. '{\"template\": \"three_pulse\", \"parameters\": {\"V1\": 30, \"V2\": 10, "
                        "\"V3\": 10, \"w1\": 200, \"w2\": 80, \"w3\": 80, \"d1\": 20, \"d2\": 20}}' (pinch-off and "
                        "adjusters: the template's synthetic laws, identify.physics.DEFAULT_LAWS, or a \"laws\" key)")
    p.add_argument("--format", choices=("png", "tiff", "tiff-stack"), default="png")
    p.add_argument("--bit-depth", type=int, choices=(8, 12, 16), default=8)
    p.add_argument("--noise", type=float, default=1.0,
                   help="noise scale: 0 none, 1 default (full well 10000 e-, read noise 8 e-)")
    p.add_argument("--blur-px", type=float, default=0.8, help="Gaussian blur sigma (px)")
    p.add_argument("--tilt-deg", type=float, default=0.0, help="nozzle axis tilt in the image plane (deg)")
    p.add_argument("--drift-mrad", type=float, default=0.0, help="trajectory angle from the nozzle axis (mrad)")
    p.add_argument("--satellites", type=int, choices=(0, 1, 2), default=0)
    p.add_argument("--dust", type=int, default=2, help="dust specks near the drop path (+1 far away)")
    p.add_argument("--falloff", type=float, default=0.1, help="backlight fall-off: corner = (1 - f) x centre")
    p.add_argument("--repeats", type=int, default=1, help="frames per delay")
    p.add_argument("--delays", default="0:1800:10", help="start:stop:step (µs, stop inclusive) or a list")
    p.add_argument("--size", type=_size, default=(640, 1024), help="WIDTHxHEIGHT (px)")
    p.add_argument("--pixel-size-um", type=float, default=4.73)
    p.add_argument("--tip-row", type=float, default=None, help="nozzle tip row (default 59.4)")
    p.add_argument("--axis-col", type=float, default=None, help="axis column (default: width/2 - 0.4)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    r = p.add_argument_group("realism tier (docs/SYNTH_REALISM.md); an option given explicitly overrides the rig")
    r.add_argument("--rig", default=None, help="start from a rig preset: " + ", ".join(_rig_names() + list(_ROW_RIGS))
                   + " (printhead-row: a row of nozzles under a flat plate, one frame at 120 µs unless --delays; "
                   "printhead-scan: one frame per nozzle, docs in dropvision.synth.printhead)")
    r.add_argument("--nozzles", type=int, default=None, help="printhead rigs: nozzles in the row (default 8)")
    r.add_argument("--nozzle-pitch-um", type=float, default=None,
                   help="printhead rigs: nozzle pitch (µm, default 423.3 = 60 per inch)")
    r.add_argument("--write-pitch", action="store_true", default=False,
                   help="printhead rigs: write nozzle_pitch_um into sequence.json")
    r.add_argument("--meniscus-nl", type=float, default=None,
                   help="printhead rigs: a meniscus bulge of this volume (nl) hanging from the plate at every live nozzle")
    r.add_argument("--ligament-um", type=float, default=None,
                   help="printhead rigs: a ligament of this length (µm) still attached below the plate at every live nozzle")
    r.add_argument("--crosstalk", default=None,
                   help="printhead rigs: nozzles (comma-separated) whose drop leans into its right-hand neighbour's "
                        "column (state deviated)")
    r.add_argument("--orientation", choices=("down", "up", "left", "right"), default=None,
                   help="direction the drops travel in the stored frames (default down)")
    r.add_argument("--jpeg-quality", type=int, default=None,
                   help="write 8-bit JPEG frames of this quality (1-100; implies --format jpeg)")
    r.add_argument("--colour", "--color", dest="colour", action="store_true", default=None,
                   help="RGB frames from a colour sensor (BT.601 luma = the grey scene)")
    r.add_argument("--exposure", type=float, default=None,
                   help="light gain (> 1: the background clips at full scale)")
    r.add_argument("--clip-fraction", type=float, default=None,
                   help="expose so that this fraction of the background pixels clips (0-0.99)")
    r.add_argument("--vignetting", type=float, default=None, help="corner light = 1 - vignetting (0-0.95)")
    r.add_argument("--mist", type=int, default=None, help="out-of-focus mist droplets per frame")
    r.add_argument("--path-dust", type=int, default=None, help="static dust specks on the drop path")
    r.add_argument("--holder", type=_holder, default=None,
                   help="holder block around the nozzle: 'yes' (5 x nozzle outer diameter), 'no', "
                        "or its width in µm")
    r.add_argument("--nozzle-protrusion-um", type=float, default=None,
                   help="nozzle length below the holder face (µm, default 60)")
    r.add_argument("--holder-blur-px", type=float, default=None,
                   help="the nozzle and holder out of focus: their extra Gaussian blur (px)")
    r.add_argument("--no-nozzle-diameters", action="store_true", default=None,
                   help="sequence.json without nozzle diameters (pixel size only)")
    p.set_defaults(func=run)
    return p


def _explicit(parser_defaults: dict, args) -> set:
    return {k for k, v in vars(args).items() if k in parser_defaults and v != parser_defaults[k]}


#: printhead rigs (`dropvision.synth.printhead.ROW_RIGS`, named here without importing it)
_ROW_RIGS = ("printhead-row", "printhead-scan")


def _run_row(args) -> int:
    """``--rig printhead-row`` / ``printhead-scan``: `dropvision.synth.printhead.write_row`."""
    from dropvision.synth.config import parse_delays
    from dropvision.synth.printhead import for_rig, write_row

    given = _explicit(_BASE_DEFAULTS, args)
    kw = {}
    if "size" in given:
        kw.update(width_px=args.size[0], height_px=args.size[1])
    for opt, name in (("pixel_size_um", "pixel_size_um"), ("seed", "seed"), ("noise", "noise"), ("blur_px", "blur_px"),
                      ("bit_depth", "bit_depth"), ("format", "format")):
        if opt in given:
            kw[name] = getattr(args, opt)
    if "delays" in given:
        kw["delays_us"] = parse_delays(args.delays)
    if args.orientation is not None:
        kw["orientation"] = args.orientation
    if args.nozzles is not None:
        kw["n_nozzles"] = args.nozzles
    if args.nozzle_pitch_um is not None:
        kw["pitch_um"] = args.nozzle_pitch_um
    if args.write_pitch:
        kw["write_pitch"] = True
    if args.meniscus_nl is not None:
        kw["meniscus_nl"] = args.meniscus_nl
    if args.ligament_um is not None:
        kw["ligament_um"] = args.ligament_um
    try:
        if args.crosstalk is not None:
            try:
                kw["crosstalk"] = tuple(int(x) for x in args.crosstalk.split(",") if x.strip())
            except ValueError:
                raise ValueError(f"--crosstalk: nozzle numbers separated by commas, got {args.crosstalk!r}") from None
        cfg = for_rig(args.rig, **kw)
        t0 = time.perf_counter()
        out = write_row(cfg, args.out, overwrite=args.overwrite)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    n = cfg.n_nozzles if cfg.scan else len(cfg.delays_us)
    print(f"dropvision synth: wrote {n} frames of a {cfg.n_nozzles}-nozzle row to {out} in "
          f"{time.perf_counter() - t0:.1f} s")
    return 0


def run(args) -> int:
    if args.rig in _ROW_RIGS:
        return _run_row(args)
    from dropvision.synth.sequence import SynthConfig, parse_delays

    from dropvision.synth.writer import write_synthetic_sequence

    w, h = args.size
    try:
        base = dict(
            u1_um_per_ms=args.u1, u2_um=args.u2, seed=args.seed, width_px=w, height_px=h,
            pixel_size_um=args.pixel_size_um,
            tip_row=59.4 if args.tip_row is None else args.tip_row,
            axis_col=args.axis_col,
            tilt_deg=args.tilt_deg, drift_mrad=args.drift_mrad, delays_us=parse_delays(args.delays),
            repeats=args.repeats, satellites=args.satellites, dust=args.dust, blur_px=args.blur_px,
            falloff=args.falloff, noise=args.noise, bit_depth=args.bit_depth, format=args.format)
        if args.waveform is not None:
            base["waveform"] = args.waveform
        realism = {field: getattr(args, opt) for opt, field in _REALISM.items() if getattr(args, opt) is not None}
        if args.jpeg_quality is not None:
            realism["format"] = "jpeg"
        if args.no_nozzle_diameters:
            realism["write_nozzle_diameters"] = False
        if args.rig is None:
            cfg = SynthConfig(**{**base, **realism})
        else:
            # the rig's values, then every option given on the command line (differing from its default)
            given = _explicit(_BASE_DEFAULTS, args)
            keep = {k: v for k, v in base.items() if _BASE_FIELDS.get(k) in given}
            if "size" in given:
                keep.update(width_px=w, height_px=h)
                if args.axis_col is None:
                    keep["axis_col"] = None
            cfg = SynthConfig.for_rig(args.rig, **{**keep, **realism})
        t0 = time.perf_counter()
        out = write_synthetic_sequence(cfg, args.out, progress=False if args.no_progress else None,
                                       overwrite=args.overwrite)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    n = len(cfg.delays_us) * cfg.repeats
    print(f"dropvision synth: wrote {n} frames to {out} in {time.perf_counter() - t0:.1f} s")
    return 0


#: defaults of the plain options (to tell which ones the user gave with --rig)
_BASE_DEFAULTS = {"u1": 70.0, "u2": 25.0, "waveform": None, "seed": 0, "size": (640, 1024), "pixel_size_um": 4.73,
                  "tip_row": None, "axis_col": None, "tilt_deg": 0.0, "drift_mrad": 0.0, "delays": "0:1800:10",
                  "repeats": 1, "satellites": 0, "dust": 2, "blur_px": 0.8, "falloff": 0.1, "noise": 1.0,
                  "bit_depth": 8, "format": "png"}
_BASE_FIELDS = {"u1_um_per_ms": "u1", "u2_um": "u2", "waveform": "waveform", "seed": "seed", "pixel_size_um": "pixel_size_um",
                "tip_row": "tip_row", "axis_col": "axis_col", "tilt_deg": "tilt_deg", "drift_mrad": "drift_mrad",
                "delays_us": "delays", "repeats": "repeats", "satellites": "satellites", "dust": "dust",
                "blur_px": "blur_px", "falloff": "falloff", "noise": "noise", "bit_depth": "bit_depth",
                "format": "format"}
