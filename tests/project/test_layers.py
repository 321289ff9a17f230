"""The layer contract: imports go one way, and there is no import cycle (docs/ARCHITECTURE.md).

    0 foundation   dvcore.*              (schema, input ranges, quality codes, atomic writes, versions,
                                          hardened JSON, error boundary, Rerun options, lazy exports)
    1 modelling    identify.*            (waveform, ECM, ARX, fits, hybrid, Monte Carlo, tuning, ...)
    2 measurement  dropvision.*          (readers, calibration, segmentation, volume, synthesis, ...)
    3 application  dropvision.app.*, identify.app.*   (CLIs, campaigns, demo, Rerun views)
    4 facade       the packages ``dropvision`` and ``identify`` themselves (their ``__init__``)

A module may import its own layer and the layers below it; ``identify`` (modelling and its
application) never imports ``dropvision``. Within the measurement layer only the synthesizer
(``dropvision.synth``: it renders drops from modelled physics) imports ``identify``; the measuring
modules take the drive and flow formulas they need from ``dvcore.waveform`` (issue 34). The facade is the user's entry point
(``dropvision.run_campaign``, ``identify.fit``): its lazy map may name any layer of its own
package (``dropvision.run_campaign`` is the application layer's), and in exchange nothing in the
project imports the facade (import ``dvcore.__version__``, ``dropvision.quality``, ... instead),
so it can never close a cycle.

Every import counts (a new module falls into a layer by where it sits: nothing to register):

- ``import`` statements anywhere, also inside functions (only ``if TYPE_CHECKING:`` blocks are
  skipped), so laziness cannot hide an upward edge;
- a package's ``__init__`` importing its own submodules (no skip: a submodule importing its
  package back is a cycle);
- a string that names a project module, ``"pkg.module"`` or ``"pkg.module:attribute"``: the lazy
  maps given to :func:`dvcore.lazy.lazy_exports`, ``importlib.import_module`` targets, command
  module lists. Docstrings are prose and do not count.

The graph functions are also run on planted mistakes (a synthetic graph and a copied source
tree) to show that they catch a cycle and an upward edge.
"""

from __future__ import annotations

import ast
import re
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("dvcore", "identify", "dropvision")
LAYER_NAMES = {0: "foundation", 1: "modelling", 2: "measurement", 3: "application", 4: "facade"}
#: Top-level packages whose ``__init__`` is the user-facing facade (layer 4).
FACADES = ("dropvision", "identify")
#: A string naming a project module (optionally ``:attribute``) counts as an import of it.
_MODULE_STRING = re.compile(r"^(?:%s)(?:\.[A-Za-z_]\w*)*(?::[A-Za-z_]\w*)?$" % "|".join(PACKAGES))


def layer(module: str) -> int:
    """Layer number of a project module (see the module docstring)."""
    parts = module.split(".")
    if module in FACADES:
        return 4
    if parts[0] == "dvcore":
        return 0
    if len(parts) > 1 and parts[1] == "app":
        return 3
    return 2 if parts[0] == "dropvision" else 1


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def project_modules(root: Path, packages=PACKAGES) -> dict[str, Path]:
    mods = {}
    for pkg in packages:
        for path in sorted((root / pkg).rglob("*.py")):
            mods[module_name(path, root)] = path
    return mods


def _type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def _docstring_nodes(tree: ast.AST) -> set[int]:
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) \
                    and isinstance(first.value.value, str):
                out.add(id(first.value))
    return out


def imports_of(path: Path, module: str, modules=()) -> list[tuple[str, int, list[str]]]:
    """(imported module, line, imported names) for every project import in ``path``: statements
    and strings naming one of ``modules`` exactly, with a dot (``"pkg.module"``) or an attribute
    (``"pkg:attr"``; see the module docstring). A bare ``"dropvision"`` is a program or
    distribution name, ``"identify.rigs"`` (no such module) an entry-point group: neither counts."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    docstrings = _docstring_nodes(tree)
    out = []

    def visit(node):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _type_checking(child):
                for sub in child.orelse:
                    visit(sub)
                continue
            if isinstance(child, ast.Import):
                for a in child.names:
                    if a.name.split(".")[0] in PACKAGES:
                        out.append((a.name, child.lineno, []))
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = package.split(".")[: len(package.split(".")) - child.level + 1]
                    target = ".".join(base + ([child.module] if child.module else []))
                else:
                    target = child.module or ""
                if target.split(".")[0] in PACKAGES:
                    out.append((target, child.lineno, [a.name for a in child.names]))
            elif isinstance(child, ast.Constant) and isinstance(child.value, str) \
                    and id(child) not in docstrings and _MODULE_STRING.match(child.value):
                mod, colon, attr = child.value.partition(":")
                if mod in modules and ("." in mod or colon):
                    out.append((mod, child.lineno, [attr] if attr else []))
            visit(child)

    visit(tree)
    return out


def resolve(target: str, names: list[str], modules) -> list[str]:
    """The project modules an import statement names: ``from pkg import x`` is the package
    ``pkg`` (its ``__init__`` runs and is asked for ``x``) and, where ``x`` is a submodule, that
    too; ``import pkg.module`` is the module; a dotted name inside a module its longest known prefix."""
    found = [target] if target in modules else []
    found += [f"{target}.{n}" for n in names if f"{target}.{n}" in modules]
    if not found:
        parts = target.split(".")
        while parts and ".".join(parts) not in modules:
            parts.pop()
        if parts:
            found = [".".join(parts)]
    return found


def scan(root: Path, packages=PACKAGES) -> tuple[dict[str, Path], dict[str, list]]:
    """Modules under ``root`` and their import edges ``(target, line, names)``."""
    modules = project_modules(root, packages)
    return modules, {m: imports_of(p, m, modules) for m, p in modules.items()}


def graph_of(modules, edges) -> dict[str, dict[str, int]]:
    """module -> {imported project module: first line}, every edge kept (package -> submodule too)."""
    graph = {}
    for m, es in edges.items():
        g = graph.setdefault(m, {})
        for target, line, names in es:
            for d in resolve(target, names, modules):
                if d != m:
                    g.setdefault(d, line)
    return graph


def upward_edges(graph, paths, layer_of=layer) -> list[str]:
    """One line per import of a higher layer, and per import of dropvision by identify."""
    bad = []
    for mod, deps in graph.items():
        for dep, line in deps.items():
            where = f"{paths[mod]}:{line}"
            if layer_of(dep) > layer_of(mod):
                bad.append(f"{where}: {mod} ({LAYER_NAMES[layer_of(mod)]}) imports {dep} "
                           f"({LAYER_NAMES[layer_of(dep)]})")
            if mod.split(".")[0] == "identify" and dep.split(".")[0] == "dropvision":
                bad.append(f"{where}: identify must not import dropvision ({mod} -> {dep})")
    return bad


#: Measurement-layer packages that may import the modelling layer (the synthesizer renders drops
#: from ``identify.physics`` and fits its template campaigns with ``identify.template_fit``).
MODELLING_USERS = ("dropvision.synth",)


def measurement_imports_modelling(graph, paths, layer_of=layer) -> list[str]:
    """One line per import of ``identify`` by a measuring module (layer 2 outside
    :data:`MODELLING_USERS`): measuring an image must not depend on a model."""
    bad = []
    for mod, deps in graph.items():
        if layer_of(mod) != 2 or any(mod == p or mod.startswith(p + ".") for p in MODELLING_USERS):
            continue
        for dep, line in deps.items():
            if dep.split(".")[0] == "identify":
                bad.append(f"{paths[mod]}:{line}: measuring module {mod} imports modelling {dep}")
    return bad


def import_cycles(graph) -> list[list[str]]:
    """Every cycle found by a depth-first search (each reported once, as a closed path)."""
    cycles, state, stack = [], {}, []

    def dfs(m):
        state[m] = 1
        stack.append(m)
        for d in sorted(graph.get(m, {})):
            if state.get(d) == 1:
                cycles.append(stack[stack.index(d):] + [d])
            elif d not in state:
                dfs(d)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            dfs(m)
    return cycles


MODULES, EDGES = scan(ROOT)
GRAPH = graph_of(MODULES, EDGES)
PATHS = {m: p.relative_to(ROOT) for m, p in MODULES.items()}


def test_imports_go_one_way():
    bad = upward_edges(GRAPH, PATHS)
    assert not bad, "upward imports:\n" + "\n".join(bad)


def test_measurement_does_not_import_modelling():
    bad = measurement_imports_modelling(GRAPH, PATHS)
    assert not bad, "measurement imports modelling:\n" + "\n".join(bad)


def test_no_import_cycles():
    cycles = import_cycles(GRAPH)
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_the_graph_sees_lazy_exports_and_package_edges():
    """The facades' lazy maps and the packages' own submodule imports are edges of the graph
    (so the two tests above see them); the facade's edge to the application layer is the one
    allowed upward edge, and only because nothing imports the facade."""
    assert "dropvision.app.campaign" in GRAPH["dropvision"]  # dropvision.run_campaign
    assert "dropvision.synth.writer" in GRAPH["dropvision"]
    assert "identify.tuning" in GRAPH["identify"]
    assert "identify.physics" in GRAPH["dropvision.synth"]
    assert "dropvision.io.readers.png" in GRAPH["dropvision.io.readers"]
    assert "dropvision.measurement" in GRAPH["dropvision.app.executors"]  # importlib.import_module
    assert "dropvision.app.measure_cli" in GRAPH["dropvision.app.cli"]  # COMMAND_MODULES
    assert not [m for m, deps in GRAPH.items() if set(deps) & set(FACADES)]


def test_no_private_names_across_modules():
    bad = []
    for mod, edges in EDGES.items():
        for target, line, names in edges:
            if target == mod:
                continue
            for n in names:
                if n.startswith("_") and not n.startswith("__"):
                    bad.append(f"{PATHS[mod]}:{line}: imports private {target}.{n}")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("mod, expected", [
    ("dvcore.atomic", 0), ("dvcore.schema", 0), ("identify.hybrid", 1), ("dropvision.frame.volume", 2),
    ("dropvision.io.readers.png", 2), ("dropvision.app.cli", 3), ("identify.app.cli", 3),
    ("dropvision", 4), ("identify", 4), ("dvcore", 0), ("dropvision.synth", 2),
])
def test_layers_are_assigned_as_documented(mod, expected):
    assert layer(mod) == expected


# --- the machinery catches planted mistakes ---------------------------------------------------


def test_a_planted_cycle_and_upward_edge_are_caught_in_a_synthetic_graph():
    graph = {
        "dvcore.schema": {"identify.hybrid": 7},  # foundation -> modelling: upward
        "identify.hybrid": {"identify.ecm": 3},
        "identify.ecm": {"identify.kfold": 4},
        "identify.kfold": {"identify.hybrid": 5},  # closes hybrid -> ecm -> kfold -> hybrid
        "dropvision.frame.volume": {"dvcore.schema": 1},
    }
    paths = {m: f"{m.replace('.', '/')}.py" for m in graph}
    up = upward_edges(graph, paths)
    assert up == ["dvcore/schema.py:7: dvcore.schema (foundation) imports identify.hybrid (modelling)"]
    assert import_cycles(graph) == [["identify.hybrid", "identify.ecm", "identify.kfold", "identify.hybrid"]]


def test_a_measuring_module_importing_modelling_is_caught():
    graph = {
        "dropvision.analysis.flow": {"identify.ecm": 16, "dvcore.waveform": 17},  # measuring -> modelling
        "dropvision.synth.planning": {"identify.physics": 15},  # the synthesizer may
        "dropvision.app.campaign_dataset": {"identify.waveform": 32},  # the application may
        "identify.ecm": {"dvcore.waveform": 35},
    }
    paths = {m: f"{m.replace('.', '/')}.py" for m in graph}
    assert measurement_imports_modelling(graph, paths) == [
        "dropvision/analysis/flow.py:16: measuring module dropvision.analysis.flow imports modelling identify.ecm"]


def _plant(root: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text), encoding="utf-8")


def test_planted_mistakes_in_source_files_are_caught(tmp_path):
    """A copied-style source tree with the mistakes the old test let through: a package <->
    submodule cycle, an upward edge through a lazy map, one through importlib, one inside a
    function; ``if TYPE_CHECKING:`` and docstrings do not count."""
    _plant(tmp_path, {
        "dvcore/__init__.py": '"""Mentions dropvision.app.cli in prose only."""\n',
        "dvcore/lazy.py": "def lazy_exports(*a):\n    return None, None\n",
        "dvcore/schema.py": """\
            from typing import TYPE_CHECKING
            if TYPE_CHECKING:
                import identify.hybrid
            def later():
                import identify.hybrid
                return identify.hybrid
            """,
        "identify/__init__.py": "",
        "identify/hybrid.py": "",
        "dropvision/__init__.py": "",
        "dropvision/io/readers/__init__.py": "from dropvision.io.readers.png import PngReader\n",
        "dropvision/io/readers/base.py": "",
        "dropvision/io/readers/png.py": "from dropvision.io.readers import base\nPngReader = 1\n",
        "dropvision/frame/volume.py": """\
            from dvcore.lazy import lazy_exports
            __getattr__, __dir__ = lazy_exports(__name__, globals(), {"run": "dropvision.app.campaign:run"})
            """,
        "dropvision/app/__init__.py": "",
        "dropvision/app/campaign.py": "run = 1\n",
        "dropvision/frame/segmentation.py": """\
            import importlib
            def cli():
                return importlib.import_module("dropvision.app.campaign")
            """,
    })
    modules, edges = scan(tmp_path)
    graph = graph_of(modules, edges)
    paths = {m: p.relative_to(tmp_path) for m, p in modules.items()}
    up = upward_edges(graph, paths)
    cycles = import_cycles(graph)
    report = "\n".join(["upward imports:", *up, "import cycles:", *(" -> ".join(c) for c in cycles)])
    print(report)  # the lead's record: `pytest -s -k planted tests/project/test_layers.py`
    assert sorted(up) == [
        "dropvision/frame/segmentation.py:3: dropvision.frame.segmentation (measurement) imports dropvision.app.campaign "
        "(application)",
        "dropvision/frame/volume.py:2: dropvision.frame.volume (measurement) imports dropvision.app.campaign (application)",
        "dvcore/schema.py:5: dvcore.schema (foundation) imports identify.hybrid (modelling)",
    ]
    assert cycles == [["dropvision.io.readers", "dropvision.io.readers.png", "dropvision.io.readers"]]
