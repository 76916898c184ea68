"""The tutorial notebooks: stored with their figures, public API only, and still running.

`python experiments/notebooks/run_all.py` regenerates the stored outputs at full size; here each
notebook is re-executed at DIFFLAB_NOTEBOOK_SCALE = 0.25 (small images) and nothing is written back.
The numeric checks inside the notebooks are `assert`s, so a figure that stops showing what its text
says fails here.
"""

import ast
import importlib.util
import re
import types
from pathlib import Path

import nbformat
import pytest

import difflab

FOLDER = Path(__file__).resolve().parents[1] / "experiments" / "notebooks"
NOTEBOOKS = sorted(FOLDER.glob("*.ipynb"))
IDS = [p.stem for p in NOTEBOOKS]


def load_run_all():
    spec = importlib.util.spec_from_file_location("run_all", FOLDER / "run_all.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def code_cells(path):
    return [c.source for c in nbformat.read(path, as_version=4).cells if c.cell_type == "code"]


def test_there_is_a_notebook_per_lecture_part():
    assert len(NOTEBOOKS) >= 7


@pytest.mark.parametrize("path", NOTEBOOKS, ids=IDS)
def test_notebook_is_stored_with_figures_and_no_errors(path):
    notebook = nbformat.read(path, as_version=4)
    assert notebook.cells[0].cell_type == "markdown" and notebook.cells[0].source.startswith("# ")
    outputs = [o for c in notebook.cells if c.cell_type == "code" for o in c.outputs]
    figures = sum("image/png" in o.get("data", {}) for o in outputs)
    assert figures >= 3, f"{path.name}: {figures} figures stored; run experiments/notebooks/run_all.py"
    assert not [o for o in outputs if o.output_type == "error"]
    noise = [o.text[:80] for o in outputs if o.output_type == "stream" and o.name == "stderr"]
    assert not noise, f"{path.name}: stderr stored (a one-time notice? run run_all.py again): {noise}"
    assert path.stat().st_size <= load_run_all().MAX_BYTES


def deep_references(source: str) -> list[str]:
    """Names a cell reaches that are private or live in a module below difflab's public packages:
    every module reached through `difflab.X.<module>` (X a public package) or any `_name`."""
    found = []
    chains = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("difflab"):
            chains += [f"{node.module}.{alias.name}" for alias in node.names]
        elif isinstance(node, ast.Import):
            chains += [alias.name for alias in node.names if alias.name.startswith("difflab")]
    chains += re.findall(r"\bdifflab(?:\.\w+)+", source)
    for chain in chains:
        parts = chain.split(".")
        obj = difflab
        for depth, part in enumerate(parts[1:], start=2):
            if part.startswith("_"):
                found.append(chain)
                break
            try:
                obj = getattr(obj, part) if hasattr(obj, part) else importlib.import_module(".".join(parts[:depth]))
            except ImportError:
                found.append(chain)
                break
            if isinstance(obj, types.ModuleType) and depth > 2:
                found.append(chain)
                break
    return found


@pytest.mark.parametrize("path", NOTEBOOKS, ids=IDS)
def test_notebook_uses_only_the_public_api(path):
    deep = [name for source in code_cells(path) for name in deep_references(source)]
    assert not deep, f"{path.name} reaches into difflab's internals: {sorted(set(deep))}"


def test_deep_reference_detector():
    assert deep_references("import difflab\nfrom difflab import geometry\ngeometry.teapot(2)") == []
    assert deep_references("from difflab.lighting import jax_model") == ["difflab.lighting.jax_model"]
    assert deep_references("from difflab.io import _as_image") == ["difflab.io._as_image"]
    assert deep_references("x = difflab.renderers.api.render") != []


@pytest.mark.parametrize("path", NOTEBOOKS, ids=IDS)
def test_notebook_executes_at_a_small_size(path):
    load_run_all().execute(path, scale=0.25)
