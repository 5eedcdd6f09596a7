"""The arrows of docs/ARCHITECTURE.md, enforced on the source.

Every ``import`` and ``from ... import`` of every module of the package is parsed (with
``ast``, so imports inside functions count too) and checked against the layer table
below, which is the one in docs/ARCHITECTURE.md:

- a module may import its own package and any package of a **lower** layer, never one of
  a higher layer nor another package of its own layer;
- a private module or package (``_name``) may be imported only from inside the package
  that holds it;
- matplotlib is imported only in ``bayeshyst.plotting`` and arviz only in
  ``bayeshyst.diagnostics`` (the edges stay at the edges).

The oracle is the table itself; the test also checks that the table knows every
top-level module, so a new package has to be placed in a layer to be allowed in.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "bayeshyst"

#: lowest first; the same table as docs/ARCHITECTURE.md
LAYERS: tuple[tuple[str, ...], ...] = (
    ("errors", "files", "_version", "tables", "threads"),
    ("data",),
    ("params",),
    ("models", "likelihoods"),
    ("discrepancy", "workers"),
    ("inference",),
    ("diagnostics", "gp"),
    ("selection", "inverse"),
    ("diagnosis",),
    ("workflow", "study"),
    ("demo",),
    ("plotting",),
    ("outputs",),
    ("cli",),
    ("__init__", "__main__"),
)
LAYER = {name: i for i, names in enumerate(LAYERS) for name in names}
#: third-party imports that belong to one package only
EDGES = {"matplotlib": "plotting", "arviz": "diagnostics"}


def _modules() -> list[tuple[tuple[str, ...], ast.Module]]:
    return [(f.relative_to(PACKAGE).with_suffix("").parts, ast.parse(f.read_text()))
            for f in sorted(PACKAGE.rglob("*.py"))]


def _targets(node: ast.AST) -> list[str]:
    """Dotted names of the modules an import statement loads (bayeshyst and third party)."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
        if node.module == "bayeshyst":  # ``from bayeshyst import diagnostics`` loads a module
            return [f"bayeshyst.{a.name}" if ((PACKAGE / a.name).is_dir()
                                              or (PACKAGE / f"{a.name}.py").exists())
                    else "bayeshyst" for a in node.names]
        return [node.module]
    return []


def _imports() -> list[tuple[tuple[str, ...], str, int]]:
    out = []
    for parts, tree in _modules():
        for node in ast.walk(tree):
            out += [(parts, t, node.lineno) for t in _targets(node)]
    return out


def test_every_top_level_module_has_a_layer():
    tops = {parts[0] for parts, _ in _modules()}
    assert tops - set(LAYER) == set(), "place the new module in LAYERS and ARCHITECTURE.md"


def test_no_relative_imports():
    bad = [("/".join(parts), node.lineno) for parts, tree in _modules()
           for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.level]
    assert bad == []


def _upward(imports: list[tuple[tuple[str, ...], str, int]]) -> list[str]:
    """The imports that point up, or sideways into another package of the same layer."""
    bad = []
    for parts, target, line in imports:
        t = target.split(".")
        if t[0] != "bayeshyst":
            continue
        src, dst = parts[0], (t[1] if len(t) > 1 else "__init__")
        if src != dst and LAYER.get(dst, len(LAYERS)) >= LAYER[src]:
            bad.append(f"{'/'.join(parts)}.py:{line} imports {target} "
                       f"(layer {LAYER[src]} -> {LAYER.get(dst, 'none')})")
    return bad


def test_arrows_point_down():
    bad = _upward(_imports())
    assert bad == [], "\n".join(bad)


def test_private_modules_stay_in_their_package():
    bad = []
    for parts, target, line in _imports():
        t = target.split(".")
        if t[0] != "bayeshyst":
            continue
        for i, comp in enumerate(t[1:], start=1):
            owner = t[1:i]  # the package that holds the private part
            if comp.startswith("_") and comp != "_version" and list(parts[:len(owner)]) != owner:
                bad.append(f"{'/'.join(parts)}.py:{line} imports {target}")
    assert bad == [], "\n".join(bad)


@pytest.mark.parametrize("library", sorted(EDGES))
def test_edge_libraries_only_at_their_edge(library):
    bad = [f"{'/'.join(parts)}.py:{line}" for parts, target, line in _imports()
           if target.split(".")[0] == library and parts[0] != EDGES[library]]
    assert bad == [], f"{library} imported outside bayeshyst.{EDGES[library]}: {bad}"


def test_the_checker_sees_a_violation():
    """The checker's own oracle: imports written on purpose, up, sideways, down."""
    tree = ast.parse("def f():\n    from bayeshyst.cli import main\n")
    assert [t for node in ast.walk(tree) for t in _targets(node)] == ["bayeshyst.cli"]
    cases = [(("models", "base"), "bayeshyst.cli", 1),             # up: reported
             (("models", "pi"), "bayeshyst.likelihoods", 2),      # sideways: reported
             (("cli",), "bayeshyst.models.base", 3),              # down: fine
             (("models", "pi"), "bayeshyst.models.base", 4),      # own package: fine
             (("data", "io"), "bayeshyst.unknown_package", 5)]    # unplaced: reported
    assert [b.split(":")[1].split(" ")[0] for b in _upward(cases)] == ["1", "2", "5"]
