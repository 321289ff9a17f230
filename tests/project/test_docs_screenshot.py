"""What a person sees of the built guide: its front page and a tutorial page in headless Chromium.

The guide is built here (``mkdocs build --strict``, as `make docs` builds it) and each page is
shot at 1280 x 900 by Chromium in headless mode; a test then checks the picture (not blank: grey
levels spread, some dark text on the light page, the theme's dark navigation column on the left,
ink in the band where the page's title stands) and the page (its <title> and its <h1>).

Chromium is Debian's ``chromium`` (``apt-get install chromium``; `.ci/run` installs it) and
MkDocs comes with the ``docs`` extra (`make docs`). On a user's fresh clone without either the
tests are skipped with that reason; with ``CI`` set (or ``DROPVISION_REQUIRE_BROWSER=1``) a missing
one is a failure naming it (as tests/realdata.py does for the real frames).
``DROPVISION_DOCS_SCREENSHOTS=DIR`` also copies the two PNGs there, to look at them.
"""

from __future__ import annotations

import html
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
REQUIRE_ENV = "DROPVISION_REQUIRE_BROWSER"
BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
WIDTH, HEIGHT = 1280, 900
#: Chromium's flags for a closed network (no background connections) as root in a container
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--hide-scrollbars", "--force-device-scale-factor=1", f"--window-size={WIDTH},{HEIGHT}")
pytestmark = pytest.mark.docs
PAGES = {  # site page -> (its <title>, its <h1>)
    "index.html": ("dropvision user guide", "dropvision"),
    "tutorials/strobe-sequence/index.html": ("A strobe sequence - dropvision user guide", "A strobe sequence"),
}


def _missing(what: str):
    if os.environ.get("CI") or os.environ.get(REQUIRE_ENV) == "1":
        pytest.fail(f"{what}; with CI or {REQUIRE_ENV}=1 set it is required")
    pytest.skip(what)


def browser() -> str:
    for name in BROWSERS:
        found = shutil.which(name)
        if found:
            return found
    _missing(f"no headless browser on PATH ({', '.join(BROWSERS)}): apt-get install chromium")


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    try:
        import mkdocs  # noqa: F401
        import mkdocstrings  # noqa: F401
    except ImportError:
        _missing("MkDocs is not installed (pip install -e '.[docs]', or make docs)")
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-f", str(ROOT / "mkdocs.yml"),
                          "-d", str(out)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, f"mkdocs build --strict failed:\n{run.stderr[-3000:]}"
    return out


def shoot(page: Path, png: Path, profile: Path) -> str:
    """Screenshot of ``page`` into ``png``; returns the page's DOM as Chromium serialises it."""
    exe = browser()
    common = [exe, *FLAGS, f"--user-data-dir={profile}"]
    shot = subprocess.run([*common, f"--screenshot={png}", page.as_uri()], capture_output=True, text=True,
                          timeout=120)
    assert shot.returncode == 0 and png.is_file(), f"{exe} made no screenshot of {page}: {shot.stderr[-2000:]}"
    dom = subprocess.run([*common, "--dump-dom", page.as_uri()], capture_output=True, text=True, timeout=120)
    assert dom.returncode == 0, f"{exe} --dump-dom {page}: {dom.stderr[-2000:]}"
    return dom.stdout


def grey(png: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)
    assert img is not None, f"{png}: not a readable PNG"
    return img


@pytest.mark.parametrize("name", list(PAGES))
def test_guide_page_screenshot(site, name, tmp_path):
    page = site / name
    assert page.is_file(), f"the built guide has no {name}"
    png = tmp_path / (name.replace("/", "_").replace("index.html", "page") + ".png")
    dom = shoot(page, png, tmp_path / "profile")
    if os.environ.get("DROPVISION_DOCS_SCREENSHOTS"):
        keep = Path(os.environ["DROPVISION_DOCS_SCREENSHOTS"])
        keep.mkdir(parents=True, exist_ok=True)
        shutil.copy(png, keep / png.name)
    title, h1 = PAGES[name]
    found = re.search(r"<title>(.*?)</title>", dom, re.S)
    assert found and html.unescape(found.group(1)).strip() == title, f"{name}: <title> {found and found.group(1)!r}"
    headings = [html.unescape(re.sub(r"<[^>]+>", "", h)).replace("¶", "").strip()
                for h in re.findall(r"<h1[^>]*>(.*?)</h1>", dom, re.S)]
    assert h1 in headings, f"{name}: no <h1> {h1!r} (found {headings})"

    img = grey(png)
    assert img.shape == (HEIGHT, WIDTH), f"{name}: screenshot {img.shape}"
    assert img.std() > 25, f"{name}: nearly one colour (std {img.std():.1f}): a blank page"
    nav, content = img[:, :250], img[:, 320:]
    # the theme's navigation column: dark, with light text on it
    assert nav.mean() < 110 and (nav > 180).mean() > 0.002, f"{name}: no navigation column (mean {nav.mean():.0f})"
    # the content: a light page with dark text on it, neither empty nor a dark smear
    dark = (content < 100).mean()
    assert content.mean() > 200 and 0.003 < dark < 0.25, f"{name}: content mean {content.mean():.0f}, dark {dark:.3f}"
    # the title band: the page's <h1> is the first text of the content column, under the breadcrumbs
    rows = np.flatnonzero((content < 100).mean(axis=1) > 0.002)
    assert rows.size and rows[0] < 160, f"{name}: no text in the top of the content column"
    band = content[rows[0]:rows[0] + 140]
    assert (band < 100).mean() > 0.004, f"{name}: the title band holds no ink"
