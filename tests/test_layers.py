"""The layer contract: imports go one way, and there is no import cycle.

    modelling     identify.*            (waveform, ECM, ARX, fits, hybrid, Monte Carlo, schema, ...)
    measurement   dropvision.*          (readers, calibration, segmentation, volume, synthesis, ...)
    application   dropvision.app.*, identify.app.*   (CLIs, campaigns, demo, Rerun views)

A module may import its own layer and the layers below it; ``identify`` (modelling and its
application) never imports ``dropvision``. Every import counts, also those inside functions
(only ``if TYPE_CHECKING:`` blocks are skipped), so laziness cannot hide an upward edge. A new
module falls into a layer by where it sits: nothing to register.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("dropvision", "identify")
LAYER_NAMES = {1: "modelling", 2: "measurement", 3: "application"}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def layer(module: str) -> int:
    if module.startswith(("dropvision.app", "identify.app")) and module.split(".")[1] == "app":
        return 3
    return 2 if module.split(".")[0] == "dropvision" else 1


def _type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def imports_of(path: Path, module: str) -> list[tuple[str, int, list[str]]]:
    """(imported module, line, imported names) for every project import in ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
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
            visit(child)

    visit(tree)
    return out


def project_modules() -> dict[str, Path]:
    mods = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            mods[module_name(path)] = path
    return mods


MODULES = project_modules()
EDGES = {m: imports_of(p, m) for m, p in MODULES.items()}


def resolve(target: str, names: list[str]) -> list[str]:
    """The project modules an import statement loads (``from pkg import submodule`` included)."""
    found = [target] if target in MODULES else []
    found += [f"{target}.{n}" for n in names if f"{target}.{n}" in MODULES]
    if not found:  # a name inside a module: the longest known prefix
        parts = target.split(".")
        while parts and ".".join(parts) not in MODULES:
            parts.pop()
        if parts:
            found = [".".join(parts)]
    return found


def test_imports_go_one_way():
    bad = []
    for mod, edges in EDGES.items():
        for target, line, names in edges:
            for dep in resolve(target, names):
                if layer(dep) > layer(mod):
                    bad.append(f"{MODULES[mod].relative_to(ROOT)}:{line}: {mod} ({LAYER_NAMES[layer(mod)]}) "
                               f"imports {dep} ({LAYER_NAMES[layer(dep)]})")
                if mod.startswith("identify") and dep.startswith("dropvision"):
                    bad.append(f"{MODULES[mod].relative_to(ROOT)}:{line}: identify must not import dropvision "
                               f"({mod} -> {dep})")
    assert not bad, "upward imports:\n" + "\n".join(bad)


def test_no_import_cycles():
    graph = {m: sorted({d for t, _, n in e for d in resolve(t, n) if d != m}) for m, e in EDGES.items()}
    # a package's __init__ importing its own submodules lazily is not a cycle of concepts
    cycles, state, stack = [], {}, []

    def dfs(m):
        state[m] = 1
        stack.append(m)
        for d in graph.get(m, []):
            if d.startswith(m + "."):  # a package's __init__ exposing its submodules
                continue
            if state.get(d) == 1:
                cycles.append(stack[stack.index(d):] + [d])
            elif d not in state:
                dfs(d)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            dfs(m)
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_no_private_names_across_modules():
    bad = []
    for mod, edges in EDGES.items():
        for target, line, names in edges:
            if target == mod:
                continue
            for n in names:
                if n.startswith("_") and not n.startswith("__"):
                    bad.append(f"{MODULES[mod].relative_to(ROOT)}:{line}: imports private {target}.{n}")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("mod", ["identify.atomic", "dropvision.app.cli", "identify.app.cli"])
def test_layers_are_assigned_as_documented(mod):
    assert layer(mod) == {"identify.atomic": 1, "dropvision.app.cli": 3, "identify.app.cli": 3}[mod]
