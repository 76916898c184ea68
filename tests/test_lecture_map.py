"""docs/lecture.md points at things that exist: notebook sections at the cells it names, functions
in the modules it names, tests by their names, demo figures the demo writes."""

import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGE = (ROOT / "docs" / "lecture.md").read_text(encoding="utf-8")
ROWS = [line for line in PAGE.splitlines() if line.startswith("| ") and not line.startswith("| Lecture")
        and not line.startswith("|---")]


def cells(notebook: str) -> list:
    path = next((ROOT / "experiments" / "notebooks").glob(f"{notebook}_*.ipynb"))
    return json.loads(path.read_text(encoding="utf-8"))["cells"]


def test_the_map_has_a_row_per_lecture_topic():
    assert len(ROWS) >= 40


@pytest.mark.parametrize("notebook, cell, title", [
    (m.group(1), int(m.group(2)), m.group(3)) for row in ROWS
    for m in re.finditer(r"(0\d), cell (\d+) \"([^\"]+?)(?:…)?\"", row)])
def test_notebook_cells_are_where_the_map_says(notebook, cell, title):
    """The cell cited opens with the section's heading (04's cell 15 held it in its middle, after the
    previous section's closing paragraph)."""
    source = "".join(cells(notebook)[cell]["source"]).replace('"', "")
    assert source.startswith(f"## {title.rstrip('. ')}"), (notebook, cell, source[:80])


@pytest.mark.parametrize("module, names", [
    (m.group(1), m.group(2)) for row in ROWS for m in re.finditer(r"`([a-z_/]+\.py):([A-Za-z_]+(?:`, `[A-Za-z_]+)*)`", row)])
def test_code_references_exist(module, names):
    text = (ROOT / "difflab" / module).read_text(encoding="utf-8")
    for name in names.split("`, `"):
        assert re.search(rf"^(def|class) {name}\b|^{name}\s*=", text, flags=re.M), f"{module}:{name}"


@pytest.mark.parametrize("test_file, name", [
    (m.group(1), m.group(2)) for row in ROWS for m in re.finditer(r"`(test_[a-z_]+\.py)::(test_[a-z0-9_]+)`", row)])
def test_test_references_exist(test_file, name):
    assert f"def {name}(" in (ROOT / "tests" / test_file).read_text(encoding="utf-8"), f"{test_file}::{name}"


def test_demo_figures_named_are_written_by_the_demo():
    named = set(re.findall(r"`([a-z_]+\.(?:png|csv))`", PAGE))
    sources = "".join(p.read_text(encoding="utf-8") for p in (ROOT / "difflab" / "demos").glob("*.py"))
    for name in named:
        stem = name.split(".")[0]
        if stem.startswith("fractal_"):  # written as f"fractal_{kind}.png" for every kind
            assert 'f"fractal_{kind}.png"' in sources and f'"{stem[8:]}"' in sources, name
        else:
            assert f'"{name}"' in sources, name
