"""Figure of issue 31: a synthetic printhead driven by a waveform template, identified end to end
from its images, beside the paper's (u1, u2) trapezoid through the same pipeline.

For each case: render a campaign of synthetic sequences over training and held-out settings of the
template's parameters (`dropvision.synth.template_campaign`), measure them, fit the hybrid model on
the template (`identify.template_fit`), and print the ECM parameters recovered against the
synthesizer's truth (La fixed at the truth: not identifiable from volume data) and the held-out
in-flight volume and jetting velocity errors, against the measurement and against the truth.

    PYTHONPATH=$PWD python tools/template_identification.py [--cases three_pulse,trapezoid]
        [--keep DIR] [--json FILE] [--small]

``--small``: the test's campaign (6 training, 2 held-out settings per case, 160 px wide frames).

Figures (2026-11-26, default campaign, 12 training + 4 held-out settings per case, ~40 s each):
three-pulse ECM Ra/CN/Kc +1.14/+0.53/+0.27 %, rmse 0.0038 nl, held-out volume/velocity vs truth
<= 0.052/0.007 %, pinch-off <= 1.9 us; trapezoid +0.48/+0.12/+0.21 %, 0.0047 nl, <= 0.104/0.044 %,
3.1 us. ``--small``: three-pulse +1.19/+0.58/+0.27 %, <= 0.11/0.013 %, 6.5 us; trapezoid
+0.66/+0.21/+0.25 %, <= 0.06/0.023 %, 1.7 us.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from dropvision.synth.config import SynthConfig
from dropvision.synth.template_campaign import identify_campaign
from identify.physics import THREE_PULSE_CENTRE


def three_pulse_case(small: bool):
    """(base config, training settings, held-out settings, template) of the three-pulse dispenser:
    V1, w1, V2 varied (a 2^3 corner design around the centre plus the centre; small: 4 corners,
    the centre and one inner point), the other five parameters at the centre."""
    c = THREE_PULSE_CENTRE

    def s(**kw):
        return {**c, **kw}

    if small:
        train = [s(V1=26, w1=180, V2=6), s(V1=34, w1=180, V2=14), s(V1=26, w1=220, V2=14), s(V1=34, w1=220, V2=6),
                 s(V1=30, w1=200, V2=10), s(V1=28, w1=210, V2=8)]
        test = [s(V1=32, w1=190, V2=12), s(V1=29, w1=215, V2=7)]
    else:
        train = [s(V1=a, w1=b, V2=d) for a in (26, 34) for b in (180, 220) for d in (6, 14)]
        train += [s(V1=30, w1=200, V2=10), s(V1=28, w1=210, V2=8), s(V1=32, w1=190, V2=12), s(V1=27, w1=185, V2=11)]
        test = [s(V1=32, w1=190, V2=7), s(V1=29, w1=215, V2=12), s(V1=27, w1=205, V2=9), s(V1=33, w1=212, V2=10)]
    base = SynthConfig(width_px=160, height_px=400, tip_row=30.4, axis_col=79.6, supersample=4, seed=1,
                       delays_us=tuple(float(d) for d in range(0, 901, 10)))
    return base, train, test, {"template": "three_pulse", "edge_us": 2.0}


def trapezoid_case(small: bool):
    """The paper's trapezoid (u1 um/ms, u2 um) through the same pipeline: colour-ink physics, pinch-off
    near 1050 us, frames to 1300 us."""
    def s(u1, u2):
        return {"u1_um_per_ms": float(u1), "u2_um": float(u2)}

    if small:
        train = [s(65, 22), s(75, 22), s(65, 28), s(75, 28), s(70, 25), s(68, 26.25)]
        test = [s(72, 23.75), s(67, 27)]
    else:
        train = [s(a, b) for a in (62.5, 70, 77.5) for b in (21.25, 25, 28.75)] + [s(66, 23), s(74, 27), s(66, 27)]
        test = [s(72, 23.75), s(67, 27.5), s(64, 24), s(76, 26)]
    base = SynthConfig(width_px=160, height_px=448, tip_row=30.4, axis_col=79.6, supersample=4, seed=1,
                       delays_us=tuple(float(d) for d in range(0, 1301, 10)))
    return base, train, test, {"template": "trapezoid", "u3_um_per_ms": 2.0, "hold_us": 20.0}


CASES = {"three_pulse": three_pulse_case, "trapezoid": trapezoid_case}


def run(cases, out_dir: Path, small: bool) -> dict:
    figures = {}
    for name in cases:
        base, train, test, template = CASES[name](small)
        t0 = time.perf_counter()
        r = identify_campaign(base, train, test, out_dir / name, template=template)
        figures[name] = {"ecm": r["ecm"], "summary": r["summary"], "n_train": len(train), "n_test": len(test),
                         "inputs": r["model"]["inputs"], "seconds": time.perf_counter() - t0,
                         "holdout": json.loads(r["holdout"].to_json(orient="records"))}
    return figures


def report(figures: dict) -> str:
    lines = []
    for name, f in figures.items():
        lines.append(f"== {name}: {f['n_train']} training, {f['n_test']} held-out sequences; laws in "
                     f"{', '.join(f['inputs'])} ({f['seconds']:.0f} s)")
        for k in ("Ra", "CN", "Kc"):
            e = f["ecm"][k]
            lines.append(f"  ECM {k:2s} {e['estimate']:.4g} (truth {e['truth']:.4g}): {e['error_percent']:+.2f} %, "
                         f"95 % interval {'covers' if e['covers'] else 'misses'} the truth")
        lines.append(f"  ECM output-error rmse {f['ecm']['rmse_nl']:.4f} nl")
        s = f["summary"]
        lines.append(f"  held out, max |error| vs measured: volume {s['max_abs_inflight_volume_nl_error_percent']:.3f} %, "
                     f"velocity {s['max_abs_jetting_velocity_m_s_error_percent']:.3f} %; vs truth: volume "
                     f"{s['max_abs_inflight_volume_nl_error_vs_truth_percent']:.3f} %, velocity "
                     f"{s['max_abs_jetting_velocity_m_s_error_vs_truth_percent']:.3f} %; pinch-off "
                     f"{s['max_abs_pinchoff_error_us']:.1f} us")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", default="three_pulse,trapezoid")
    ap.add_argument("--keep", type=Path, help="keep the rendered campaigns here")
    ap.add_argument("--json", type=Path, help="write the figures here")
    ap.add_argument("--small", action="store_true", help="the test's campaign")
    a = ap.parse_args(argv)
    cases = [c.strip() for c in a.cases.split(",") if c.strip()]
    bad = [c for c in cases if c not in CASES]
    if bad:
        ap.error(f"unknown case(s) {', '.join(bad)} (known: {', '.join(CASES)})")
    with tempfile.TemporaryDirectory() as tmp:
        figures = run(cases, a.keep or Path(tmp), a.small)
    print(report(figures))
    if a.json:
        a.json.write_text(json.dumps(figures, indent=1, default=float))
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
