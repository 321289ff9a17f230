"""The user guide (mkdocs.yml, docs/): its tutorials run as written, its front pages hold what they promise.

Each page of docs/tutorials/ is run as one script, in a fresh folder where ``sample_frames`` is
the repository's: its ```python blocks as they are, and each ``$ command`` line of its ```console
blocks through bash (in order, between the Python blocks; ``dropvision`` and ``identify`` are the
entry points beside this interpreter). ```text and ```sh blocks are illustrations, never run.
Tutorials use sample_frames/ and synthetic data only (never ../shared). `make docs` runs this file
after the strict build; the screenshots of the built guide are tests/project/test_docs_screenshot.py.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.docs

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
TUTORIALS = sorted((DOCS / "tutorials").glob("*.md")) + [DOCS / "getting-started.md"]
FENCE = re.compile(r"^```(\w+)[^\n]*\n(.*?)^```[ \t]*$", re.M | re.S)


def page_script(text: str) -> str:
    """One Python script from a page: python fences verbatim, console ``$ `` lines as bash calls."""
    parts = ["import subprocess as _sp\n"
             "def _sh(cmd):\n"
             "    print('$', cmd, flush=True)\n"
             "    _sp.run(['bash', '-euo', 'pipefail', '-c', cmd], check=True)\n"]
    for lang, body in FENCE.findall(text):
        if lang == "python":
            parts.append(body)
        elif lang == "console":
            parts += [f"_sh({line[2:]!r})\n" for line in body.splitlines() if line.startswith("$ ")]
    return "\n".join(parts)


def run_page(page: Path, tmp_path: Path) -> subprocess.CompletedProcess:
    (tmp_path / "sample_frames").symlink_to(ROOT / "sample_frames", target_is_directory=True)
    script = tmp_path / f"{page.stem}.py"
    script.write_text(page_script(page.read_text(encoding="utf-8")), encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),
           "PATH": os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")]),
           "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    return subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)


def test_every_tutorial_has_code_to_run():
    assert len(TUTORIALS) >= 7
    for page in TUTORIALS:
        text = page.read_text(encoding="utf-8")
        assert "../shared" not in text, f"{page.name}: a tutorial uses sample_frames/ or synthetic data only"
        assert re.search(r"^```(python|console)", text, re.M), f"{page.name}: no code to run"


@pytest.mark.parametrize("page", TUTORIALS, ids=[p.stem for p in TUTORIALS])
def test_tutorial_runs_as_written(page, tmp_path):
    run = run_page(page, tmp_path)
    assert run.returncode == 0, f"{page.name}:\n{run.stdout[-2000:]}\n{run.stderr[-3000:]}"


def test_page_script_keeps_the_order_and_skips_illustrations():
    text = ("```python\na = 1\n```\n```console\n$ echo hi\nhi\n```\n```sh\nrm -rf /\n```\n"
            "```text\n$ nope\n```\n```python\nb = a\n```\n")
    script = page_script(text)
    assert script.index("a = 1") < script.index("_sh('echo hi')") < script.index("b = a")
    assert "rm -rf" not in script and "nope" not in script and "_sh('hi')" not in script


def test_readme_is_one_screen_and_links_into_the_guide():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 150
    for command in ("make demo", "make test", "make docs"):
        assert command in readme
    for target in re.findall(r"\]\((docs/[^)#]+)", readme):
        assert (ROOT / target).is_file(), f"README.md links to {target}, which is not there"


def test_readme_example_runs(tmp_path):
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    example = re.search(r"```python\n(.*?)```", readme, re.S).group(1)
    assert len(example.splitlines()) <= 12
    page = tmp_path / "readme.md"
    page.write_text(f"```python\n{example}```\n")
    run = run_page(page, tmp_path)
    assert run.returncode == 0, run.stderr[-3000:]


def test_api_reference_names_every_public_name_of_the_facade():
    """docs/reference/api.md documents each name of ``dropvision.__all__`` and ``identify.__all__`` by its
    facade name (docs/facade_hook.py resolves it), never by the module that happens to define it."""
    import dropvision
    import identify

    page = (DOCS / "reference" / "api.md").read_text(encoding="utf-8")
    directives = set(re.findall(r"^::: (\S+)\s*$", page, re.M))
    for package in (dropvision, identify):
        for name in package.__all__:
            if name != "__version__":
                assert f"{package.__name__}.{name}" in directives, f"api.md lacks ::: {package.__name__}.{name}"
    assert all(d.count(".") == 1 for d in directives), f"module paths in api.md: {sorted(directives)}"
