"""Score a printhead-row measurement against its synthetic truth (issue 32):
python tools/row_score.py SYNTH_FOLDER OUT_FOLDER  -> a per-nozzle table and the CV check."""

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd


def score(synth, out) -> dict:
    truth = pd.read_csv(Path(synth) / "truth_nozzles.csv")
    got = pd.read_parquet(Path(out) / "nozzles.parquet")
    s = json.loads((Path(out) / "summary.json").read_text())
    if len(got) != len(truth):
        print(f"nozzle count {len(got)} != truth {len(truth)}")
    rows = []
    for _, t in truth.iterrows():
        g = got[got.nozzle == t.nozzle]
        if g.empty:
            rows.append({"nozzle": t.nozzle, "truth": t.state, "got": "-"})
            continue
        g = g.iloc[0]
        rows.append({"nozzle": int(t.nozzle), "truth": t.state, "got": g.state, "state_ok": g.state == t.state,
                     "vol_err_%": 100 * (g.volume_nl / t.volume_nl - 1), "vol_u_%": 100 * g.volume_uncertainty_nl / t.volume_nl,
                     "vel_err_%": 100 * (g.velocity_m_s / t.velocity_m_s - 1),
                     "ang_err_mrad": g.angle_mrad - t.angle_mrad, "ang_u_mrad": g.angle_uncertainty_mrad})
    tab = pd.DataFrame(rows)
    live = truth[truth.state != "missing"]
    res = {"table": tab}
    for key, col in (("volume", "volume_nl"), ("velocity", "velocity_m_s")):
        x = live[col].to_numpy(float)
        cv_t = float(x.std(ddof=1) / x.mean())
        cv, u = s[f"{key}_cv"], s[f"{key}_cv_uncertainty"]
        res[key] = (cv_t, cv, u)
    return res


if __name__ == "__main__":
    r = score(sys.argv[1], sys.argv[2])
    with pd.option_context("display.width", 200, "display.precision", 3):
        print(r["table"].to_string(index=False))
    for key in ("volume", "velocity"):
        cv_t, cv, u = r[key]
        print(f"{key} CV: truth {cv_t if cv_t is not None else float('nan'):.5f}, measured {cv if cv is not None else float('nan'):.5f} "
              f"+- {u if u is not None else float('nan'):.5f}")
