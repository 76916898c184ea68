"""The README's and docs' code blocks run as written: python blocks in one interpreter per page (in
order, sharing names), then the README's bash blocks line by line, all in an empty folder, with
`difflab` on PATH running the package under test."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# Pages whose every python block is a complete example (docs/batch.md shows cluster sessions instead).
PAGES = [ROOT / "README.md", *(ROOT / "docs" / name for name in ("scene-format.md", "api.md", "architecture.md"))]
# The Quickstart installs the package and runs the whole suite: .ci/run executes exactly that block.
INSTALL_MARK = "pip install"


def blocks(page: Path, language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", page.read_text(encoding="utf-8"), flags=re.S)


def environment(tmp_path: Path) -> dict:
    """PATH with a `difflab` that runs this interpreter on the package under test."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    shim = bin_dir / "difflab"
    shim.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m difflab.cli "$@"\n')
    shim.chmod(0o755)
    path = os.pathsep.join([str(bin_dir), os.environ.get("PATH", "")])
    return {**os.environ, "PATH": path, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}


def run(command: list[str], cwd: Path, env: dict) -> None:
    done = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, f"{command[-1][:300]}\n--- stdout\n{done.stdout[-3000:]}\n--- stderr\n{done.stderr[-3000:]}"


def test_quickstart_is_what_ci_runs():
    install = [b for b in blocks(ROOT / "README.md", "bash") if INSTALL_MARK in b]
    assert len(install) == 1
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    for line in install[0].strip().splitlines():
        assert line in ci, line


@pytest.mark.parametrize("page", [p for p in PAGES[1:] if blocks(p, "python")], ids=lambda p: p.name)
def test_docs_python_blocks_run(page, tmp_path):
    work = tmp_path / "work"
    work.mkdir()
    run([sys.executable, "-c", "\n\n".join(blocks(page, "python"))], work, environment(tmp_path))


def test_readme_python_then_bash_blocks_run(tmp_path):
    readme = ROOT / "README.md"
    work = tmp_path / "work"
    work.mkdir()
    env = environment(tmp_path)
    run([sys.executable, "-c", "\n\n".join(blocks(readme, "python"))], work, env)
    assert {"out.png", "scene.json", "target.png", "fitted.json"} <= {p.name for p in work.iterdir()}
    commands = [b for b in blocks(readme, "bash") if INSTALL_MARK not in b]
    assert commands
    for block in commands:
        for line in block.strip().splitlines():
            run(["bash", "-e", "-c", line], work, env)
    written = {p.name for p in work.iterdir()}
    assert {"render.png", "traced.png", "traced.npy", "fitted-cli.json", "koch.png", "figures"} <= written
