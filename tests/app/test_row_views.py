"""Views of a printhead row (issue 32 item 5, dropvision.app.row_views): the Rerun recording read back
with Rerun's own reader (rerun.chunk.RrdReader, tests/rrdtools.py) and the report page, against the
measured nozzles.parquet and the synthetic truth."""

from __future__ import annotations

import html
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from dropvision.synth.printhead import RowConfig, write_row

sys.path.insert(0, str(Path(__file__).parents[1]))
from rrdtools import Rrd  # noqa: E402

ROW = dict(n_nozzles=5, pitch_um=200.0, width_px=640, height_px=320, pixel_size_um=2.0, volume_nl=0.05,
           velocity_m_s=4.0, planted={1: "missing", 2: "deviated", 3: "weak", 4: "satellites"}, supersample=4,
           break_um=60.0, satellite_gap_um=20.0, write_pitch=True)


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    from dropvision.app.cli import main

    tmp = tmp_path_factory.mktemp("views")
    folder = write_row(RowConfig(delays_us=(50.0, 60.0, 70.0), **ROW), tmp / "row")
    assert main(["measure", str(folder), "--out", str(tmp / "out"), "--rerun", str(tmp / "row.rrd"),
                 "--report", str(tmp / "report"), "--angle-limit-mrad", "5", "--quiet"]) == 0
    return tmp, pd.read_csv(folder / "truth_nozzles.csv"), pd.read_parquet(tmp / "out" / "nozzles.parquet")


def test_recording_holds_the_nozzle_map_and_the_frames(measured):
    tmp, truth, nz = measured
    rrd = Rrd(tmp / "row.rrd")
    ents = rrd.entities()
    for e in ("/row/frame", "/row/bodies", "/row/plate", "/row/axes", "/row/nozzles", "/summary"):
        assert e in ents, e
    # the nozzle map: every live nozzle's value on the nozzle timeline, under its state (the truth's)
    for q in ("volume_nl", "velocity_m_s", "angle_mrad"):
        got = {}
        for state in set(truth.state) - {"missing"}:
            for batch in rrd.temporal[f"/nozzles/{q}/{state}"]:
                for i, v in zip(batch.column("nozzle").to_pylist(), batch.column("Scalars:scalars").to_pylist()):
                    got[i] = (state, v[0])
        live = nz[nz.state != "missing"]
        assert sorted(got) == live.nozzle.tolist()
        for _, r in live.iterrows():
            assert got[r.nozzle][0] == truth.state[r.nozzle]
            assert got[r.nozzle][1] == pytest.approx(r[q])
    # the frames: three delays; bodies coloured by nozzle, as many as bodies.parquet has per frame
    bodies = pd.read_parquet(tmp / "out" / "bodies.parquet")
    pos = rrd.series("/row/bodies", "Points2D:positions")
    assert len(pos) == 3 and sum(len(v) for v in pos.value) == len(bodies)
    cols = rrd.series("/row/bodies", "Points2D:colors")
    assert len({c for v in cols.value for c in v}) == bodies.nozzle.nunique()
    # one axis per live nozzle
    assert len(rrd.static["/row/axes"]["LineStrips2D:strips"]) == int((nz.state != "missing").sum())


def test_report_page_holds_the_table_and_the_figures(measured):
    tmp, truth, nz = measured
    page = (tmp / "report" / "index.html").read_text(encoding="utf-8")
    assert (tmp / "report" / "nozzle_map.png").stat().st_size > 1000
    assert (tmp / "report" / "row_frame.png").stat().st_size > 1000
    assert 'src="nozzle_map.png"' in page and 'src="row_frame.png"' in page
    table = page[page.index('<table id="nozzles">'):]
    rows = table.split("<tr>")[2:]
    assert len(rows) == len(truth)
    for r, (_, t) in zip(rows, truth.iterrows()):
        cells = [html.unescape(c.split("</td>")[0]) for c in r.split("<td>")[1:]]
        assert cells[0] == str(t.nozzle) and cells[1] == t.state
    assert "FAIL (nozzles 1, 2)" in page  # missing, and deviated 40 mrad > 5 mrad


def test_report_refused_for_a_single_nozzle(tmp_path):
    from dropvision.app.cli import main
    from dropvision.synth.sequence import SynthConfig
    from dropvision.synth.writer import write_synthetic_sequence

    cfg = SynthConfig.for_rig("clean", delays_us=(400.0,), width_px=320, height_px=512, tip_row=60.4,
                              axis_col=159.6, supersample=2, orientation="down", colour=False, format="png", mist=0)
    folder = write_synthetic_sequence(cfg, tmp_path / "one", progress=False)
    assert main(["measure", str(folder), "--out", str(tmp_path / "out"), "--report", str(tmp_path / "rep")]) != 0
    assert not (tmp_path / "rep").exists()
    assert not (tmp_path / "out").exists()  # refused before measuring: --out not written either


def test_identify_fit_of_a_row_output_is_one_line(measured, capsys):
    from identify.app.cli import main

    tmp, _, _ = measured
    assert main(["fit", str(tmp / "out"), "--out", str(tmp / "model")]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "printhead row's output" in err[0] and str(tmp / "out") in err[0]
    assert not (tmp / "model").exists()
