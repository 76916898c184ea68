"""The import graph of the package: no cycles, and imports point down the layers
(scene / geometry -> lighting -> renderers -> fit -> demos / cli), read from the source with `ast`."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import difflab

PACKAGE = Path(difflab.__file__).resolve().parent


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path, modules: set[str]) -> set[str]:
    """Every module `path` imports (at module level or inside functions): difflab modules by their
    full dotted name, third-party ones by their top-level name."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            # `from pkg import sub` imports the submodule pkg.sub when there is one
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        else:
            continue
        for target in targets:
            if target.startswith("difflab"):
                while target not in modules:  # an attribute path: its longest module prefix
                    target = target.rpartition(".")[0]
                found.add(target)
            else:
                found.add(target.partition(".")[0])
    found.discard(name)
    return found


def import_graph() -> dict[str, set[str]]:
    files = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    return {name: imports_of(path, set(files)) for name, path in files.items()}


GRAPH = import_graph()


def in_layer(module: str, *layers: str) -> bool:
    return any(module == f"difflab.{layer}" or module.startswith(f"difflab.{layer}.") for layer in layers)


def test_graph_is_read():
    """The parser sees the known edges (a guard against a test that checks an empty graph)."""
    assert "difflab.scene" in GRAPH["difflab.renderers.api"]
    assert "warp" in GRAPH["difflab._warp"]
    assert "jax" in GRAPH["difflab.lighting.jax_model"]
    assert "difflab.demos.examples" in GRAPH["difflab.demos"]


def test_no_import_cycles():
    """Depth-first search over difflab's own modules: no module reaches itself."""
    state, stack = {}, []

    def visit(module):
        state[module] = "open"
        stack.append(module)
        for dep in sorted(d for d in GRAPH[module] if d in GRAPH):
            if state.get(dep) == "open":
                cycle = stack[stack.index(dep):] + [dep]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if dep not in state:
                visit(dep)
        stack.pop()
        state[module] = "done"

    for module in sorted(GRAPH):
        if module not in state:
            visit(module)


# (layer of the importer, what it must never import)
RULES = [
    (("scene", "geometry"), ("renderers", "fit", "lighting", "demos", "warp", "jax", "optimistix",
                             "difflab._warp")),
    (("lighting",), ("renderers", "fit", "demos")),
    (("renderers",), ("fit", "demos", "jax", "optimistix", "equinox", "lineax")),
    (("fit",), ("demos",)),
    (("fractals",), ("fit", "demos", "jax", "optimistix")),
    (("vocabulary",), ("warp", "jax", "numpy", "difflab._warp")),
    (("lighting.jax_model",), ("warp", "difflab._warp", "lighting.warp_model")),
]


@pytest.mark.parametrize("layers,forbidden", RULES, ids=["+".join(r[0]) for r in RULES])
def test_imports_point_down(layers, forbidden):
    bad = []
    for module, deps in GRAPH.items():
        if not in_layer(module, *layers):
            continue
        for dep in deps:
            if dep in forbidden or in_layer(dep, *forbidden) or dep.partition(".")[0] in forbidden:
                bad.append(f"{module} imports {dep}")
    assert not bad, "\n".join(sorted(bad))



def test_only_the_command_line_reaches_into_the_demos():
    """The engine never depends on its demos: besides the demos themselves only the CLI and the
    top-level `example_scene` re-export import them."""
    allowed = {"difflab", "difflab.cli", "difflab.commands"}
    bad = [f"{m} imports {d}" for m, deps in GRAPH.items() for d in deps
           if in_layer(d, "demos") and not in_layer(m, "demos") and m not in allowed]
    assert not bad, "\n".join(sorted(bad))
