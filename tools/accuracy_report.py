"""Accuracy of `dropvision measure` against the synthesizer's exact truth, over a sweep.

    python tools/accuracy_report.py [--full] [--out report.csv]

Renders each case of the sweep (waveforms, noise, blur, tilt, bit depth, fall-off, dust,
satellites, repeated frames) into a temporary folder, measures it and compares with
truth.json / truth_frames.csv.  The same cases (smaller frames) run as
tests/test_measure_accuracy.py.  Metrics (all errors signed unless "abs"):

- grown_max_pct / grown_median_pct: abs grown-volume error in attached frames, % of the peak
  grown volume (targets 0.5 / 0.2);
- drop_max_pct: abs main-drop volume error in in-flight frames (truth and measured), % (0.3);
- inflight_pct, velocity_pct: summary in-flight volume and jetting velocity errors, % (0.3, 0.5);
- pinchoff_ok: measured pinch-off delay == truth (first detached frame);
- satellites_ok: per-frame satellite count exact wherever the truth's drop is in view and the
  measurement is trusted, and the summary count exact;
- dust_ok: no dust ever counted (no extra detached body in attached frames).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from dropvision import quality as q  # noqa: E402  (after the path set-up)

#: The sweep: name -> SynthConfig keyword arguments (frame size added by `cases`).
SWEEP = {
    "u70_u25_8bit": dict(u1_um_per_ms=70, u2_um=25, seed=11),
    "u62_u30_sat2_blur1.5_noise2_dust3": dict(u1_um_per_ms=62, u2_um=30, satellites=2, blur_px=1.5, noise=2.0,
                                              dust=3, seed=12),
    "u80_u22_tilt1.5_falloff0.3_12bit_tiff": dict(u1_um_per_ms=80, u2_um=22, tilt_deg=1.5, drift_mrad=4.0,
                                                 falloff=0.3, bit_depth=12, format="tiff", seed=13),
    "u65_u28_repeats3_sat1_stack": dict(u1_um_per_ms=65, u2_um=28, repeats=3, satellites=1,
                                        format="tiff-stack", seed=14),
}


def cases(full: bool = False) -> dict[str, dict]:
    """Sweep cases; small frames and 20 µs steps unless ``full`` (640x1024, 10 µs)."""
    out = {}
    for name, kw in SWEEP.items():
        kw = dict(kw)
        if full:
            kw.setdefault("delays_us", tuple(float(d) for d in range(0, 1801, 10)))
        else:
            kw.update(width_px=320, height_px=800, delays_us=tuple(float(d) for d in range(0, 1501, 20)))
        out[name] = kw
    return out


def compare(result, seq_dir) -> dict:
    """Error metrics of a `MeasureResult` against the truth files in ``seq_dir``."""
    seq_dir = Path(seq_dir)
    truth = json.loads((seq_dir / "truth.json").read_text())
    tf = pd.read_csv(seq_dir / "truth_frames.csv")
    f = result.frames
    s = result.summary
    m = f.merge(tf, on=["file", "delay_us", "repeat"], suffixes=("", "_t"), validate="one_to_one")
    peak = float(tf["grown_volume_nl"].max())
    att = m[m["attached_t"]]
    g_err = (att["grown_volume_nl"] - att["grown_volume_nl_t"]).abs() / peak * 100
    inf = m[m["inflight_t"] & m["inflight"]]
    d_err = (inf["drop_volume_nl"] / inf["drop_volume_nl_t"] - 1).abs() * 100
    view = m[~m["attached_t"] & m["drop_in_view"] & m["n_satellites"].notna()]
    sat_frames_ok = bool((view["n_satellites"].astype(int) == view["n_satellites_t"].astype(int)).all())
    dust_ok = bool((m.loc[m["attached_t"], "detached_volume_nl"].fillna(0) == 0).all())
    return {
        "frames": int(len(f)),
        "attached_frames": int(len(att)),
        "grown_nan": int(att["grown_volume_nl"].isna().sum()),
        "grown_max_pct": float(g_err.max()),
        "grown_median_pct": float(g_err.median()),
        "inflight_frames": int(len(inf)),
        "inflight_frames_truth": int(m["inflight_t"].sum()),
        "drop_max_pct": float(d_err.max()) if len(d_err) else float("nan"),
        "inflight_pct": 100 * (s["inflight_volume_nl"] / truth["inflight_volume_nl"] - 1),
        "velocity_pct": 100 * (s["jetting_velocity_m_s"] / truth["jetting_velocity_m_s"] - 1),
        "grown_at_pinchoff_pct": 100 * (s["grown_volume_at_pinchoff_nl"] / truth["grown_volume_at_pinchoff_nl"] - 1),
        "flow_at_max_stroke_pct": 100 * (s["flow_velocity_at_max_stroke_m_s"]
                                         / truth["flow_velocity_at_max_stroke_m_s"] - 1),
        "trajectory_mrad_err": s["trajectory_angle_mrad"] - truth["trajectory_angle_mrad"],
        "pinchoff_ok": bool(s["pinchoff_us"] == truth["pinchoff_us"]),
        "satellites_ok": bool(sat_frames_ok and s["satellites"] == truth["satellites"]),
        "dust_ok": dust_ok,
        "tip_err_px": s["calibration"]["tip_row"] - truth["calibration"]["tip_row"],
        "tilt_err_deg": s["calibration"]["tilt_deg"] - truth["calibration"]["tilt_deg"],
        "not_ok_frames": int((f["quality"] != "ok").sum()),
        # flags other than the drop leaving / having left the field of view
        "unexpected_flags": int((~f["quality"].isin([q.OK, q.DROP_LEAVES, q.NO_DROP])).sum()),
    }


def run_case(kw: dict, workdir) -> dict:
    """Render one case into ``workdir`` and return its metrics (+ timings)."""
    from dropvision.config import MeasureConfig
    from dropvision.measurement import measure_sequence
    from dropvision.synth import SynthConfig, write_synthetic_sequence

    seq = Path(workdir) / "seq"
    t0 = time.perf_counter()
    write_synthetic_sequence(SynthConfig(**kw), seq, progress=False)
    t1 = time.perf_counter()
    res = measure_sequence(seq, config=MeasureConfig(workers=1))
    t2 = time.perf_counter()
    out = compare(res, seq)
    out.update(render_s=t1 - t0, measure_s=t2 - t1)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="640x1024 frames every 10 us (slower)")
    ap.add_argument("--out", help="also write the table as CSV")
    args = ap.parse_args(argv)
    rows = []
    for name, kw in cases(args.full).items():
        with tempfile.TemporaryDirectory() as tmp:
            r = run_case(kw, tmp)
        r["case"] = name
        rows.append(r)
        print(f"{name}: grown max {r['grown_max_pct']:.3f} % median {r['grown_median_pct']:.3f} %, drop max "
              f"{r['drop_max_pct']:.3f} %, in-flight {r['inflight_pct']:+.3f} %, velocity {r['velocity_pct']:+.3f} %, "
              f"pinch-off {'ok' if r['pinchoff_ok'] else 'WRONG'}, satellites {'ok' if r['satellites_ok'] else 'WRONG'}, "
              f"dust {'ok' if r['dust_ok'] else 'WRONG'} ({r['measure_s']:.2f} s)", flush=True)
    table = pd.DataFrame(rows).set_index("case")
    with pd.option_context("display.width", 200, "display.max_columns", 50):
        print(table.T.to_string(float_format=lambda v: f"{v:.4g}"))
    if args.out:
        table.to_csv(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
