"""MkDocs hook: API reference pages name the public facade, not the modules behind it.

A reference page writes ``::: dropvision.measure`` (a name of ``dropvision.__all__``); this hook
rewrites it, when the page is built, to the module the facade's lazy map (``_LAZY`` in the
package's ``__init__.py``, read as text: nothing is imported) says defines it, with the facade
name as the heading. When modules move, only ``_LAZY`` changes; the pages stay as they are.
A name that is in no facade map is left alone (mkdocstrings then reports it: a strict build fails).

Pages kept as they are in the repository (docs/FORMAT.md) link to source files outside docs/
(``[`dvcore/schema.py`](../dvcore/schema.py)``): such a link to a file that exists in the
repository becomes its text, the path, since the guide has no copy of it; a link to a file that
does not exist is left for MkDocs to report.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FACADES = ("dropvision", "identify")
OUTSIDE_LINK = re.compile(r"\[([^\]]+)\]\(((?:\.\./)+[^)#\s]+)\)")
DIRECTIVE = re.compile(r"^::: ((?:dropvision|identify)\.([A-Za-z_][A-Za-z0-9_]*))[ \t]*$", re.M)


def facade_map(package: str) -> dict[str, str]:
    """``{public name: "module.attribute"}`` from the literal ``_LAZY`` dict of ``package/__init__.py``."""
    tree = ast.parse((ROOT / package / "__init__.py").read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "_LAZY" for t in node.targets):
            return {k: v.replace(":", ".") for k, v in ast.literal_eval(node.value).items()}
    raise ValueError(f"{package}/__init__.py: no literal _LAZY map")


_MAPS = {p: facade_map(p) for p in FACADES}


def _rewrite(match: re.Match) -> str:
    full, name = match.group(1), match.group(2)
    target = _MAPS[full.split(".", 1)[0]].get(name)
    if target is None:
        return match.group(0)
    return f"::: {target}\n    options:\n      heading: \"{full}\"\n      toc_label: \"{full}\""


def _outside(match: re.Match, page_dir: Path) -> str:
    target = (page_dir / match.group(2)).resolve()
    docs = ROOT / "docs"
    if target.is_file() and docs not in target.parents and ROOT in target.parents:
        return match.group(1)
    return match.group(0)


def on_page_markdown(markdown: str, page, **kwargs) -> str:
    page_dir = (ROOT / "docs" / page.file.src_uri).parent
    markdown = OUTSIDE_LINK.sub(lambda m: _outside(m, page_dir), markdown)
    return DIRECTIVE.sub(_rewrite, markdown)
