"""Accuracy of `dropvision measure` against the synthesizer's exact truth, over a sweep.

    python tools/accuracy_report.py [--full] [--tier clean|realism|all] [--case NAME ...] [--seeds N]
                                    [--phases] [--seed-offset K] [--out report.csv]

Each run ends with a table of the stated uncertainties against the truth: per case, the median
|error| / u and the share within +-2u of the attached, grown and main-drop volumes (`*` where the
median is outside [0.3, 1.0] or the share below 0.95); ``--case`` runs single cases, ``--seeds``
and ``--seed-offset`` other noise draws of the same cases (with several seeds, each case's median
over them and the share within +-2u of all their frames pooled, `seeds_cell`: a single-frame case
has one frame a seed, and 30 seeds say more than 6), ``--phases`` with them other sub-pixel
positions of the nozzle (`with_phase`: the frames of one sequence share where its tip plane cuts a
row, and only other sequences sample that error).

Renders each case of the sweep (waveforms, noise, blur, tilt, bit depth, fall-off, dust,
satellites, repeated frames) into a temporary folder, measures it and compares with
truth.json / truth_frames.csv.  The same cases (smaller frames) run as
tests/analysis/test_measure_accuracy.py.  Metrics (all errors signed unless "abs"):

- grown_max_pct / grown_median_pct: abs grown-volume error in attached frames, % of the peak
  grown volume (targets 0.5 / 0.2);
- drop_max_pct: abs main-drop volume error in in-flight frames (truth and measured), % (0.3);
- inflight_pct, velocity_pct: summary in-flight volume and jetting velocity errors, % (0.3, 0.5);
- pinchoff_ok: measured pinch-off delay == truth (first detached frame);
- satellites_ok: per-frame satellite count exact wherever the truth's drop is in view and the
  measurement is trusted, and the summary count exact;
- dust_ok: no dust ever counted (no extra detached body in attached frames).

Realism tier (``--tier realism``): the rig presets of the synthesizer
(`dropvision.synth.RIGS`: drop watcher from the side in a holder block with colour JPEG, mist,
touching and dumbbell satellites, a bead; a clipped pendant drop; low contrast; tilted and
dusty; a single frame) and optics that are not Gaussian (an Airy pattern's diffraction rings, a
defocus disc, both JPEG-coded), measured with the same goals.  Metrics (`compare_realism`):
grown_max_pct, drop_max_pct, inflight_pct, velocity_pct, pinchoff_ok as above; attached_pct
(abs attached-volume error, %, over frames holding at least half the largest attached volume:
the pendant drop, the grown meniscus); satellite_frames / satellites_wrong (frames with a
known count compared with the truth's visible satellites); mist_counted (counted bodies within
4 px of a truth mist droplet or dust speck); false_ok (frames with quality "ok" whose grown
volume is off by more than 1 % of the peak, main-drop volume by more than 1 %, or satellite
count wrong, or attached volume off by more than 1 % of the largest); refused (the measurement
raised).
"""

from __future__ import annotations

import argparse
import math
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
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


#: Realism tier: rig preset -> overrides (frame size for the report; `realism_cases` adds delays).
REALISM = {
    "watcher-side": dict(width_px=640, height_px=1024, tip_row=120.4, axis_col=319.6, seed=31),
    "pendant-saturated": dict(seed=32),
    "low-contrast": dict(seed=33),
    "tilted-dusty": dict(seed=34),
    "single-frame": dict(seed=35),
    # a single drop-watcher frame (no background sequence) without nozzle diameters
    "watcher-single": dict(rig="watcher-side", width_px=640, height_px=1024, tip_row=120.4, axis_col=319.6,
                           delays_us=(1300.0,), write_nozzle_diameters=False, seed=36),
    # the nozzle and its holder out of focus (issue 18): in-focus judged from the drops
    "watcher-blurred-holder": dict(width_px=640, height_px=1024, tip_row=160.4, axis_col=319.6, seed=37),
    "watcher-blurred-single": dict(rig="watcher-blurred-holder", delays_us=(1300.0,), write_nozzle_diameters=False,
                                   seed=38),
    # optics that are not Gaussian (issue 29; `dropvision.synth.render.psf_kernel`): a drop watcher
    # whose lens shows diffraction rings (an Airy pattern, first dark ring 3 px: core sigma ~1 px,
    # tails as rho^-3) on a lightly Gaussian-blurred image, grey JPEG at quality 80
    "airy-jpeg": dict(rig="clean", psf="airy", psf_radius_px=3.0, blur_px=0.4, format="jpeg", jpeg_quality=80,
                      seed=39),
    # a defocused drop watcher: a uniform defocus disc of 2.5 px radius, colour JPEG at quality 85
    "defocus-disc": dict(rig="clean", psf="disc", psf_radius_px=2.5, blur_px=0.3, format="jpeg", jpeg_quality=85,
                         colour=True, seed=40),
}


#: Realism cases of one frame (no delay series).
SINGLE_FRAME = ("pendant-saturated", "single-frame", "watcher-single", "watcher-blurred-single")


def realism_cases(full: bool = False) -> dict[str, dict]:
    """Realism cases: (rig, overrides); small frames and 20 us steps unless ``full``."""
    out = {}
    for name, kw in REALISM.items():
        kw = dict(kw)
        if name in ("low-contrast", "tilted-dusty", "airy-jpeg", "defocus-disc") and not full:
            kw.update(width_px=320, height_px=800)
        if name not in SINGLE_FRAME:
            step = 10 if full else 20
            kw["delays_us"] = tuple(float(d) for d in range(0, 1501 if not full else 1801, step))
        out[name] = kw
    return out


def compare_realism(result, seq_dir) -> dict:
    """Realism-tier metrics of a `MeasureResult` against the truth files in ``seq_dir``."""
    seq_dir = Path(seq_dir)
    truth = json.loads((seq_dir / "truth.json").read_text())
    tf = pd.read_csv(seq_dir / "truth_frames.csv")
    tb = pd.read_csv(seq_dir / "truth_bodies.csv")
    f, s, b = result.frames, result.summary, result.bodies
    m = f.merge(tf, on=["file", "delay_us", "repeat"], suffixes=("", "_t"), validate="one_to_one")
    nan = float("nan")
    out = {"frames": int(len(f)), "refused": False}
    att = m[m["attached_t"]]
    peak = float(tf["grown_volume_nl"].max()) if tf["grown_volume_nl"].notna().any() else nan
    g_err = (att["grown_volume_nl"] - att["grown_volume_nl_t"]).abs() / peak * 100 if peak > 0 else pd.Series(dtype=float)
    out["grown_max_pct"] = float(g_err.max()) if g_err.notna().any() else nan
    big = att[att["attached_volume_nl_t"] >= 0.5 * att["attached_volume_nl_t"].max()] if len(att) else att
    out["attached_pct"] = (float(100 * (big["attached_volume_nl"] / big["attached_volume_nl_t"] - 1).abs().max())
                           if len(big) else nan)
    inf = m[m["inflight_t"] & m["drop_in_view"] & m["drop_volume_nl"].notna()]
    d_err = (inf["drop_volume_nl"] / inf["drop_volume_nl_t"] - 1).abs() * 100
    out["drop_max_pct"] = float(d_err.max()) if len(d_err) else nan
    out["drop_frames"] = int(len(d_err))
    # NaN only where there is nothing to measure: the truth's attached and in-flight frames in view
    out["grown_frames"] = int(att["grown_volume_nl"].notna().sum())
    out["grown_nan"] = int(att["grown_volume_nl"].isna().sum()) if peak > 0 else 0
    out["attached_nan"] = int(att["attached_volume_nl"].isna().sum())
    out["drop_nan"] = int((m["inflight_t"] & m["drop_in_view"] & m["drop_volume_nl"].isna()
                           & ~m["quality"].str.contains(q.DROP_LEAVES)).sum())
    out.update(uncertainty_coverage(m))

    def rel(key_m, key_t):
        t = truth.get(key_t)
        v = s.get(key_m)
        return 100 * (v / t - 1) if t not in (None, 0) and v is not None and np.isfinite(t) else nan

    out["inflight_pct"] = rel("inflight_volume_nl", "inflight_volume_nl")
    out["velocity_pct"] = rel("jetting_velocity_m_s", "jetting_velocity_m_s")
    tp = truth.get("pinchoff_us")
    out["pinchoff_ok"] = bool(tp is None or not np.isfinite(tp) or len(f) < 5 or s["pinchoff_us"] == tp)
    view = m[~m["attached_t"] & m["drop_in_view"] & m["n_satellites"].notna()]
    sat_wrong = view["n_satellites"].astype(int) != view["n_satellites_visible"].astype(int)
    out["satellite_frames"] = int(len(view))
    out["satellites_wrong"] = int(sat_wrong.sum())
    soft = tb[tb["body_class"].isin(["mist", "dust"])]
    counted = b[b["counted"]]
    mist_counted = 0
    for key, grp in counted.groupby(["file", "delay_us", "repeat"]):
        sp = soft[(soft["file"] == key[0]) & (soft["delay_us"] == key[1]) & (soft["repeat"] == key[2])]
        for _, row in grp.iterrows():
            if len(sp) and (np.hypot(sp["row_px"] - row["row_px"], sp["col_px"] - row["col_px"]) < 4).any():
                mist_counted += 1
    out["mist_counted"] = mist_counted
    bad = pd.Series(False, index=m.index)
    if peak > 0:
        bad |= m["attached_t"] & ((m["grown_volume_nl"] - m["grown_volume_nl_t"]).abs() / peak > 0.01)
    att_peak = float(tf["attached_volume_nl"].max())
    if att_peak > 0:  # the attached volume itself (a wrong tip plane offsets it, not the grown volume)
        bad |= m["attached_t"] & ((m["attached_volume_nl"] - m["attached_volume_nl_t"]).abs() / att_peak > 0.01)
    bad |= (m["inflight_t"] & m["drop_in_view"] & m["drop_volume_nl"].notna()
            & ((m["drop_volume_nl"] / m["drop_volume_nl_t"] - 1).abs() > 0.01))
    bad.loc[view.index] |= sat_wrong
    out["false_ok"] = int((bad & (m["quality"] == q.OK)).sum())
    out["not_ok_frames"] = int((f["quality"] != q.OK).sum())
    return out


#: Measured volume columns whose uncertainty is checked against the truth: (name, frames used).
COVERAGE_COLUMNS = ("attached_volume_nl", "grown_volume_nl", "drop_volume_nl")


def uncertainty_coverage(m: pd.DataFrame) -> dict:
    """Share of frames whose true volume lies within 2 stated standard uncertainties.

    ``m`` is the frames table merged with truth_frames.csv (suffix ``_t``); attached and grown
    volumes over the truth's attached frames, the drop volume over its in-flight frames in view,
    wherever both the value and its uncertainty are finite.  Returns ``<column>_cov2`` (share),
    ``<column>_cov_n`` (frames compared) and ``<column>_z50`` (median |error| / uncertainty:
    0.67 for a calibrated Gaussian uncertainty, less when it is conservative) per column, and
    ``coverage_min`` over them.
    """
    out, shares = {}, []
    for col in COVERAGE_COLUMNS:
        key = col[:-3]
        sel = m["attached_t"] if col != "drop_volume_nl" else (m["inflight_t"] & m["drop_in_view"])
        u = m[f"{key}_uncertainty_nl"]
        ok = sel & m[col].notna() & u.notna() & m[f"{col}_t"].notna()
        err = (m.loc[ok, col] - m.loc[ok, f"{col}_t"]).abs()
        n = int(ok.sum())
        share = float((err <= 2.0 * u[ok]).mean()) if n else float("nan")
        out[f"{key}_cov2"], out[f"{key}_cov_n"] = share, n
        out[f"{key}_z50"] = float((err / u[ok]).median()) if n else float("nan")
        if n:
            shares.append(share)
    out["coverage_min"] = float(min(shares)) if shares else float("nan")
    return out


def print_uncertainty_table(table: pd.DataFrame) -> None:
    """One line per case: median |error| / u and the +-2u coverage of each volume (`uncertainty_coverage`),
    ``*`` beside a median outside [0.3, 1.0] or a coverage below 0.95; ``-`` where no frame is compared."""
    if table.empty:
        return
    print("median |err|/u (+-2u coverage, frames): " + " / ".join(c[:-10] for c in COVERAGE_COLUMNS))
    for case, r in table.iterrows():
        cells = []
        for col in COVERAGE_COLUMNS:
            key = col[:-3]
            n = r.get(f"{key}_cov_n", 0)
            if not (isinstance(n, (int, float, np.integer)) and n > 0):
                cells.append("-")
                continue
            z, cov = float(r[f"{key}_z50"]), float(r[f"{key}_cov2"])
            mark = "*" if not (0.3 <= z <= 1.0) or cov < 0.95 else ""
            cells.append(f"{z:.2f} ({cov:.3f}, {int(n)}){mark}")
        print(f"  {case}: " + " / ".join(cells))
    seeded = table.index.to_series().str.rsplit("#", n=1)
    if seeded.str.len().eq(2).any():
        print("over the seeds: median of the seeds' median |err|/u (+-2u coverage of all their frames "
              "pooled, frames; lowest seed's coverage)")
        for name, grp in table.groupby(seeded.str[0], sort=False):
            cells = []
            for col in COVERAGE_COLUMNS:
                cell = seeds_cell(grp, col[:-3])
                if cell is None:
                    cells.append("-")
                    continue
                z, cov, n, lowest = cell
                mark = "*" if not (0.3 <= z <= 1.0) or cov < 0.95 else ""
                cells.append(f"{z:.2f} ({cov:.3f}, {n}; {lowest:.3f}){mark}")
            print(f"  {name}: " + " / ".join(cells))


def seeds_cell(grp: pd.DataFrame, key: str) -> tuple[float, float, int, float] | None:
    """One case's cell over its seeds (rows of `uncertainty_coverage`): the median of the seeds'
    median |err|/u, the +-2u coverage of all their frames pooled (each seed's share weighted by
    its frames: the criterion's measure; a single-frame case's seeds have one frame each, so
    their lowest share is 0 or 1 and says nothing), the pooled frame count and the lowest
    seed's share; None where no seed compared a frame."""
    n = grp[f"{key}_cov_n"].fillna(0) if f"{key}_cov_n" in grp else pd.Series(0, index=grp.index)
    done = grp[n > 0]
    if done.empty:
        return None
    w = n[n > 0].astype(float)
    pooled = float((done[f"{key}_cov2"] * w).sum() / w.sum())
    return float(done[f"{key}_z50"].median()), pooled, int(w.sum()), float(done[f"{key}_cov2"].min())


def run_realism_case(name: str, kw: dict, workdir, transform=None) -> dict:
    """Render the rig preset ``name`` with overrides ``kw`` into ``workdir`` and compare.

    ``transform``, when given, is applied to the `MeasureResult` before the comparison (a test
    plants mistakes with it to show that the checks catch them)."""
    from dropvision.config import MeasureConfig
    from dropvision.measurement import measure_sequence
    from dropvision.synth import SynthConfig, write_synthetic_sequence

    seq = Path(workdir) / "seq"
    t0 = time.perf_counter()
    kw = dict(kw)
    write_synthetic_sequence(SynthConfig.for_rig(kw.pop("rig", name), **kw), seq, progress=False)
    t1 = time.perf_counter()
    try:
        res = measure_sequence(seq, config=MeasureConfig(workers=1))
    except Exception as exc:  # the report lists a refusal as a result
        return {"refused": True, "error": f"{type(exc).__name__}: {exc}", "render_s": t1 - t0}
    t2 = time.perf_counter()
    if transform is not None:
        transform(res)
    out = compare_realism(res, seq)
    out.update(render_s=t1 - t0, measure_s=t2 - t1)
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
        **uncertainty_coverage(m),
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


#: Default nozzle position of the synthesizer (its tip row; the axis column is the frame's middle less 0.4 px).
_DEFAULT_TIP_ROW = 59.4


def with_phase(kw: dict, k: int, rig: str | None = None) -> dict:
    """``kw`` with the nozzle's sub-pixel position of draw ``k``: the tip row and axis column at
    fractions ``(0.4 + 0.618 k) mod 1`` and ``(0.6 + 0.382 k) mod 1`` of a pixel past their
    presets' whole pixels (draw 0 keeps the presets' .4 / .6).  Where the tip plane cuts a row is an
    error common to a whole sequence: the frames of one sequence draw it once, and only sequences
    of other phases judge its uncertainty."""
    from dropvision.synth.config import RIGS

    base = {**RIGS.get(rig, {}), **kw} if rig is not None else dict(kw)
    tip = float(base.get("tip_row", _DEFAULT_TIP_ROW))
    axis = base.get("axis_col")
    if axis is None:
        axis = base.get("width_px", 640) / 2.0 - 0.4
    return {**kw, "tip_row": math.floor(tip) + (0.4 + 0.618034 * k) % 1.0,
            "axis_col": math.floor(float(axis)) + (0.6 + 0.381966 * k) % 1.0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="640x1024 frames every 10 us (slower)")
    ap.add_argument("--tier", choices=("clean", "realism", "all"), default="all",
                    help="clean sweep, realism tier (rig presets), or both (default)")
    ap.add_argument("--seeds", type=int, default=1, help="render each case with this many seeds")
    ap.add_argument("--phases", action="store_true",
                    help="with --seeds: each seed also moves the nozzle by a fraction of a pixel (`with_phase`)")
    ap.add_argument("--seed-offset", type=int, default=0,
                    help="add this to every case's seed (another noise draw of the same cases)")
    ap.add_argument("--case", action="append", default=[], metavar="NAME",
                    help="run only this case (realism preset or sweep name; repeatable)")
    ap.add_argument("--out", help="also write the table(s) as CSV (realism tier: NAME-realism.csv)")
    args = ap.parse_args(argv)
    known = set(REALISM) | set(SWEEP)
    unknown = [c for c in args.case if c not in known]
    if unknown:
        ap.error(f"unknown case {unknown[0]!r}: one of {', '.join(sorted(known))}")
    if args.tier in ("realism", "all"):
        rrows = []
        for name, kw in realism_cases(args.full).items():
            if args.case and name not in args.case:
                continue
            for k in range(args.seeds):
                kwk = {**kw, "seed": kw.get("seed", 0) + 100 * k + args.seed_offset}
                if args.phases:
                    kwk = with_phase(kwk, k, kw.get("rig", name))
                with tempfile.TemporaryDirectory() as tmp:
                    r = run_realism_case(name, kwk, tmp)
                r["case"] = name if args.seeds == 1 else f"{name}#{k}"
                rrows.append(r)
                print(f"realism {r['case']}: " + ", ".join(f"{key} {v:.3g}" if isinstance(v, float) else f"{key} {v}"
                                                          for key, v in r.items() if key != "case"), flush=True)
        rtable = pd.DataFrame(rrows).set_index("case") if rrows else pd.DataFrame()
        with pd.option_context("display.width", 200, "display.max_columns", 50):
            print(rtable.T.to_string(float_format=lambda v: f"{v:.4g}"))
        print_uncertainty_table(rtable)
        if args.out:
            out = Path(args.out)
            rtable.to_csv(out.with_name(out.stem + "-realism" + out.suffix))
        if args.tier == "realism":
            return 0
    rows = []
    for name, kw in cases(args.full).items():
        if args.case and name not in args.case:
            continue
        for k in range(args.seeds):
            kwk = {**kw, "seed": kw.get("seed", 0) + 100 * k + args.seed_offset}
            if args.phases:
                kwk = with_phase(kwk, k)
            with tempfile.TemporaryDirectory() as tmp:
                r = run_case(kwk, tmp)
            r["case"] = name if args.seeds == 1 else f"{name}#{k}"
            rows.append(r)
            print(f"{r['case']}: grown max {r['grown_max_pct']:.3f} % median {r['grown_median_pct']:.3f} %, drop max "
                  f"{r['drop_max_pct']:.3f} %, in-flight {r['inflight_pct']:+.3f} %, velocity {r['velocity_pct']:+.3f} %, "
                  f"pinch-off {'ok' if r['pinchoff_ok'] else 'WRONG'}, satellites {'ok' if r['satellites_ok'] else 'WRONG'}, "
                  f"dust {'ok' if r['dust_ok'] else 'WRONG'} ({r['measure_s']:.2f} s)", flush=True)
    table = pd.DataFrame(rows).set_index("case") if rows else pd.DataFrame()
    with pd.option_context("display.width", 200, "display.max_columns", 50):
        print(table.T.to_string(float_format=lambda v: f"{v:.4g}"))
    print_uncertainty_table(table)
    if args.out:
        table.to_csv(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
