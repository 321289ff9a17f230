"""`make demo` runs end to end (quick grid, no recordings): the sample sequences are found and
measured, the campaign is fitted, a prediction printed and the report (`identify.app.report`)
written to out/report/."""

import subprocess
import sys

import pytest


@pytest.mark.slow
def test_quick_demo_runs(tmp_path):
    out = tmp_path / "out"
    run = subprocess.run([sys.executable, "-m", "dropvision.app.demo", "--quick", "--no-rerun", "--workers", "1",
                          "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    text = run.stdout
    for name in ("colour_ink_u70_u25", "satellite_dust_tiff16", "u55_u30"):
        assert name in text
    assert "in-flight volume (nl)" in text and "== 5. prediction at u1 =" in text and "inverse design" in text
    assert (out / "model.json").is_file() and (out / "report" / "index.html").is_file()
    assert (out / "report" / "fig7_u1_65_u2_27.5.png").is_file() and "report/index.html" in text
