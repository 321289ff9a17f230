"""`identify report` / `identify.app.report.write_report`: the HTML page links only figures that
exist (non-empty PNGs), its tables hold the model's numbers, and the output folder is written
non-destructively."""

from __future__ import annotations

import math
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import identify
from identify.app.cli import main
from identify.app.report import grid_centre, write_report
from identify.synthetic_dataset import make_synthetic_dataset
from identify.hybrid_fit import fit_hybrid

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
GRID = [(a, b) for a in (55.0, 65.0, 75.0) for b in (20.0, 27.5, 35.0)]


class _Page(HTMLParser):
    """Links, images and tables (id -> rows of cell texts, header first) of a page."""

    def __init__(self):
        super().__init__()
        self.links, self.images, self.tables, self.external = [], [], {}, []
        self._table = self._row = self._cell = None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "a" and a.get("href"):
            self.links.append(a["href"])
        if tag == "img":
            self.images.append(a["src"])
        if tag in ("script", "link", "iframe"):
            self.external.append(tag)
        if tag == "table":
            self._table = self.tables.setdefault(a.get("id"), [])
        elif tag == "tr" and self._table is not None:
            self._row = []
            self._table.append(self._row)
        elif tag in ("td", "th") and self._row is not None:
            self._cell = []

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self._row.append("".join(self._cell).strip())
            self._cell = None
        elif tag == "table":
            self._table = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)


def _parse(index: Path) -> _Page:
    p = _Page()
    p.feed(index.read_text(encoding="utf-8"))
    return p


def _close(text: str, value: float) -> bool:
    if value is None or not math.isfinite(float(value)):
        return text in ("nan", "n/a")
    return math.isclose(float(text), float(value), rel_tol=1e-5, abs_tol=1e-12)


def _column(rows, name):
    j = rows[0].index(name)
    return [r[j] for r in rows[1:]]


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    root = tmp_path_factory.mktemp("report")
    ds = make_synthetic_dataset(root / "dataset", grid=GRID)
    rep = fit_hybrid(ds, arx=False)
    model = rep.model
    model.save(root / "model.json")
    return root, ds, rep, model


@pytest.mark.slow
def test_report_links_existing_figures_and_holds_the_models_numbers(fitted, tmp_path):
    _, ds, rep, model = fitted
    assert identify.fit(ds, arx=False).to_dict()["ecm"]["coefficients"] == model.to_dict()["ecm"]["coefficients"]
    res = write_report(tmp_path / "rep", model, ds, fit_report=rep, samples=2000)
    page = _parse(res.index)
    assert not page.external  # self-contained: no scripts or style sheets from elsewhere
    pngs = {x for x in page.links + page.images if x.endswith(".png")}
    assert len(pngs) >= 6 and {p.name for p in res.figures} == pngs
    for name in pngs:
        f = res.index.parent / name
        assert f.is_file() and f.stat().st_size > 1000
        assert f.read_bytes()[:8] == PNG_MAGIC
    # issue 33: self-contained means the figures are in the page (base64 PNG), the CV tables shown once
    import base64
    assert page.images and all(src.startswith("data:image/png;base64,") for src in page.images)
    assert all(base64.b64decode(src.split(",", 1)[1])[:8] == PNG_MAGIC for src in page.images)
    assert len(page.images) == len(pngs) - 1  # cv_tables.png is linked, not shown beside its own tables
    assert '<div class="scroll"><table id="intervals">' in res.index.read_text()  # a wide table scrolls
    # the ECM physical parameters with the fit's intervals (were n/a)
    params = model.to_dict()["ecm"]["parameters"]
    assert params and any(p["ci95_low"] is not None for p in params.values())
    rows = page.tables["ecm-parameters"]
    assert _column(rows, "parameter") == list(params)
    for name, lo, hi in zip(_column(rows, "parameter"), _column(rows, "low"), _column(rows, "high")):
        assert _close(lo, params[name]["ci95_low"]) and _close(hi, params[name]["ci95_high"])
    assert any(lo not in ("n/a", "nan") for lo in _column(rows, "low"))

    # ECM coefficients with their 95 % intervals
    d = model.to_dict()["ecm"]
    rows = page.tables["ecm-coefficients"]
    for name, value, ci in zip(_column(rows, "coefficient"), _column(rows, "value"), _column(rows, "ci95")):
        assert _close(value, d["coefficients"][name]) and _close(ci, d["coefficients_ci95"][name])
    # polynomial coefficients
    for attr in ("pinchoff", "volume_adjuster", "velocity_adjuster"):
        df = getattr(model, attr).to_pandas()
        rows = page.tables[f"{attr}-coefficients"]
        assert _column(rows, "term") == list(df.term)
        assert all(_close(a, b) for a, b in zip(_column(rows, "coefficient"), df.coefficient))
        assert all(_close(a, b) for a, b in zip(_column(rows, "low"), df.low))
    # CV tables of the fit
    for name, df in rep.tables().items():
        rows = page.tables[f"cv-{name}"]
        assert len(rows) == len(df) + 1
        assert all(_close(a, b) for a, b in zip(_column(rows, "val_rmse"), df.val_rmse))
    # intervals at the default point, the centre of the grid
    assert res.points == [grid_centre(model, ds)] == [(65.0, 27.5)]
    iv = res.intervals[(65.0, 27.5)]["inflight_volume_nl"]
    rows = page.tables["intervals"]
    i = _column(rows, "output").index("inflight_volume_nl")
    for key in ("mean", "mean_drop_low", "mean_drop_high", "one_drop_low", "one_drop_high"):
        assert _close(_column(rows, key)[i], iv[key])
    assert iv["one_drop_low"] < iv["mean_drop_low"] < iv["mean"] < iv["mean_drop_high"] < iv["one_drop_high"]
    assert "versions" in page.tables


@pytest.mark.slow
def test_report_from_model_file_recomputes_the_fits_cv_tables(fitted, tmp_path):
    _, ds, rep, model = fitted
    res = write_report(tmp_path / "rep", model, ds, samples=500, at=[(60.0, 25.0), (70.0, 30.0)])
    page = _parse(res.index)
    for name in ("pinchoff", "volume_adjuster", "velocity_adjuster"):
        df = rep.tables()[name]
        assert all(_close(a, b) for a, b in zip(_column(page.tables[f"cv-{name}"], "val_rmse"), df.val_rmse))
    assert {"fig7_u1_60_u2_25.png", "fig7_u1_70_u2_30.png"} <= {p.name for p in res.figures}
    assert all(p.is_file() for p in res.figures)


@pytest.mark.slow
def test_report_cli(fitted, tmp_path, capsys):
    root, _, _, model = fitted
    out = tmp_path / "rep"
    argv = ["report", str(root / "model.json"), "--dataset", str(root / "dataset"), "--out", str(out),
            "--samples", "500", "--at", "60,25", "--at", "70,30"]
    assert main(argv) == 0
    page = _parse(out / "index.html")
    assert {"fig7_u1_60_u2_25.png", "fig7_u1_70_u2_30.png"} <= set(page.links)
    assert main(argv) == 0  # our own earlier report is replaced
    # a folder holding the user's files is refused (exit 2) and left as it was
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    capsys.readouterr()
    assert main([*argv[:4], "--out", str(mine), "--samples", "500"]) == 2
    assert "did not write" in capsys.readouterr().err
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
    # --overwrite writes our files into it and keeps the user's
    assert main([*argv[:4], "--out", str(mine), "--samples", "500", "--overwrite"]) == 0
    assert (mine / "notes.txt").read_text() == "keep me" and (mine / "index.html").is_file()
    # a malformed --at is a usage error (argparse: exit status 2)
    with pytest.raises(SystemExit) as exc:
        main([*argv[:6], "--at", "60"])
    assert exc.value.code == 2


@pytest.mark.slow
def test_fit_report_flag(fitted, tmp_path):
    root = fitted[0]
    model, rep_dir = tmp_path / "model.json", tmp_path / "rep"
    assert main(["fit", str(root / "dataset"), "--out", str(model), "--no-arx", "--report", str(rep_dir)]) == 0
    assert model.is_file() and (rep_dir / "index.html").is_file()
    page = _parse(rep_dir / "index.html")
    assert all((rep_dir / x).is_file() for x in page.links if x.endswith(".png"))


def test_arx_table_shows_the_best_sane_structures():
    """issue 33: the page showed the first 40 of 1148 ARX rows, a fit of -1.2e6 % among them."""
    from identify.app.report import ARX_PAGE_ROWS, _arx_rows
    n = 200
    rng = np.random.default_rng(0)
    df = pd.DataFrame({"na": np.arange(n), "nb": 1, "nk": 1, "train_rmse_nl": rng.uniform(0.1, 1, n),
                       "train_fit_percent": rng.uniform(50, 90, n), "val_rmse_nl": rng.uniform(0.1, 1, n),
                       "val_fit_percent": rng.uniform(40, 90, n)})
    df.loc[df["val_rmse_nl"].idxmin(), "val_fit_percent"] = -1.2e6  # the best RMSE, a diverged fit
    shown, caption = _arx_rows(df)
    assert len(shown) == ARX_PAGE_ROWS and (shown["val_fit_percent"] >= 0).all() and (shown["train_fit_percent"] >= 0).all()
    assert list(shown["val_rmse_nl"]) == sorted(shown["val_rmse_nl"])
    sane = df[df["val_fit_percent"] >= 0]
    assert shown["val_rmse_nl"].iloc[0] == sane["val_rmse_nl"].min()
    assert f"of {n} structures" in caption
