"""The package's layering, checked on the source with ``ast``: imports go only downwards, no cycles.

Every ``import`` / ``from ... import`` of an ``mi_svbrdf`` module counts, including those inside
functions (an import hidden in a function is still a dependency). ``plugins/`` and ``scenes/``
live at the top of the repository but are the subpackages ``mi_svbrdf.plugins`` and
``mi_svbrdf.scenes``.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Folder of each top-level part of the package (the rest are under mi_svbrdf/).
SOURCES = {"mi_svbrdf": ROOT / "mi_svbrdf", "mi_svbrdf.plugins": ROOT / "plugins",
           "mi_svbrdf.scenes": ROOT / "scenes"}

#: The layers, lowest first. A module may import from its own layer and the layers below it.
#: ``mi_svbrdf`` itself (the facade, ``__init__.py``) is above everything and imported by nothing.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("mi_svbrdf.threads", "mi_svbrdf.variant", "mi_svbrdf.plugins", "mi_svbrdf.assets"),
    ("mi_svbrdf.core",),
    ("mi_svbrdf.io", "mi_svbrdf.scenes"),
    ("mi_svbrdf.geometry",),
    ("mi_svbrdf.data",),
    ("mi_svbrdf.nets", "mi_svbrdf.optim"),
    ("mi_svbrdf.eval", "mi_svbrdf.eval.studies"),
    ("mi_svbrdf.cli",),
)
#: Pairs of one layer that must not import each other (peers, both built on the layers below).
PEERS = (("mi_svbrdf.nets", "mi_svbrdf.optim"), ("mi_svbrdf.io", "mi_svbrdf.scenes"))


def modules() -> dict[str, Path]:
    """``{dotted module name: file}`` of every module of the package."""
    found = {}
    for package, folder in SOURCES.items():
        for path in folder.rglob("*.py"):
            rel = path.relative_to(folder).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            if package == "mi_svbrdf" and parts and parts[0] in ("plugins", "scenes"):
                continue
            found[".".join([package, *parts])] = path
    return found


def _target(name: str, known: dict[str, Path]) -> str | None:
    """The longest known module that ``name`` is or lies in (``a.b.c`` -> ``a.b`` when c is a name)."""
    while name:
        if name in known:
            return name
        name = name.rpartition(".")[0]
    return None


def imports(known: dict[str, Path]) -> dict[str, set[str]]:
    """``{module: {modules it imports}}`` over every import statement, at any depth."""
    graph: dict[str, set[str]] = {}
    for module, path in known.items():
        is_package = path.name == "__init__.py"
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = module.split(".") if is_package else module.split(".")[:-1]
                    base = base[:len(base) - node.level + 1]
                    parent = ".".join(base + ([node.module] if node.module else []))
                else:
                    parent = node.module or ""
                names = [f"{parent}.{a.name}" for a in node.names]
            else:
                continue
            for name in names:
                if name.split(".")[0] != "mi_svbrdf":
                    continue
                target = _target(name, known)
                if target and target != module:
                    deps.add(target)
        graph[module] = deps
    return graph


def layer_of(module: str) -> int | None:
    """Index of the layer holding ``module`` (None for the facade ``mi_svbrdf``)."""
    for i, layer in enumerate(LAYERS):
        if any(module == p or module.startswith(p + ".") for p in layer):
            return i
    return None


def _group(module: str) -> str | None:
    for layer in LAYERS:
        for p in layer:
            if module == p or module.startswith(p + "."):
                return p
    return None


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle as a list of modules (first == last), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                return stack[stack.index(d):] + [d]
            if d not in state:
                found = visit(d)
                if found:
                    return found
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state:
            found = visit(m)
            if found:
                return found
    return None


def violations(graph: dict[str, set[str]]) -> list[str]:
    """Every import that goes up a layer, into the facade, or across a pair of peers."""
    bad = []
    for module, deps in sorted(graph.items()):
        here = layer_of(module)
        for dep in sorted(deps):
            there = layer_of(dep)
            if dep == "mi_svbrdf" and module != "mi_svbrdf":
                bad.append(f"{module} imports the facade mi_svbrdf (import from the layer instead)")
            elif here is None:
                continue  # the facade may import anything
            elif there is None:
                bad.append(f"{module} imports {dep}, which belongs to no layer")
            elif there > here:
                bad.append(f"{module} (layer {here}) imports {dep} (layer {there})")
            elif there == here and (_group(module), _group(dep)) in PEERS + tuple((b, a) for a, b in PEERS):
                bad.append(f"{module} imports its peer {dep}")
    return bad


def test_every_module_is_in_a_layer():
    known = modules()
    assert len(known) > 60, sorted(known)
    stray = sorted(m for m in known if m != "mi_svbrdf" and layer_of(m) is None)
    assert not stray, f"modules outside every layer: {stray}"


def test_imports_only_go_downwards():
    bad = violations(imports(modules()))
    assert not bad, "\n".join(bad)


def test_no_import_cycles():
    cycle = find_cycle(imports(modules()))
    assert cycle is None, " -> ".join(cycle)


def test_the_checks_catch_what_they_look_for():
    """The checkers on made-up graphs: an upward import, a peer import, the facade, a cycle."""
    graph = {"mi_svbrdf.core.loss": {"mi_svbrdf.nets.network"}, "mi_svbrdf.nets.train": {"mi_svbrdf.optim.fit"},
             "mi_svbrdf.io.strip": {"mi_svbrdf"}, "mi_svbrdf.data.bank": {"mi_svbrdf.core.maps"}}
    bad = violations(graph)
    assert len(bad) == 3 and "layer 1" in bad[0] or any("layer 1" in b for b in bad), bad
    assert any("peer" in b for b in bad) and any("facade" in b for b in bad), bad
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_inner_imports_are_counted(tmp_path):
    """An import inside a function is an edge like any other."""
    known = {"mi_svbrdf.core.x": tmp_path / "x.py", "mi_svbrdf.eval.y": tmp_path / "y.py"}
    known["mi_svbrdf.core.x"].write_text("def f():\n    from mi_svbrdf.eval.y import g\n")
    known["mi_svbrdf.eval.y"].write_text("")
    assert imports(known)["mi_svbrdf.core.x"] == {"mi_svbrdf.eval.y"}


@pytest.mark.parametrize("layer", [p for layer in LAYERS for p in layer if p not in ("mi_svbrdf.variant",)])
def test_each_layer_imports(layer):
    """Each subpackage imports on its own (no hidden dependency on import order)."""
    import importlib

    importlib.import_module(layer)
