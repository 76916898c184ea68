"""A regular (non-editable) install works from any folder: build a wheel from a copy of the sources,
install it into an empty target folder, and run `difflab demo` from an empty folder with nothing
of the source tree on the path."""

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(command, cwd, env=None) -> str:
    done = subprocess.run([str(c) for c in command], cwd=cwd, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, f"{command}\n--- stdout\n{done.stdout[-3000:]}\n--- stderr\n{done.stderr[-3000:]}"
    return done.stdout


def test_wheel_install_runs_the_demo_from_an_empty_folder(tmp_path):
    source = tmp_path / "source"  # a copy, so the build leaves nothing in the repository
    shutil.copytree(ROOT / "difflab", source / "difflab", ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md", "difflab_cli.py"):
        shutil.copy(ROOT / name, source / name)
    run([sys.executable, "-m", "pip", "wheel", ".", "--no-deps", "-w", tmp_path / "dist", "-q"], source)
    (wheel,) = (tmp_path / "dist").glob("difflab-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {"difflab/demos/scenes/lecture_teapot.json", "difflab/demos/scenes/glass_sphere.json",
            "difflab/scene/scene.schema.json", "difflab_cli.py"} <= names  # (the console entry point)
    assert not any(n.startswith(("tests/", "experiments/")) for n in names)

    site = tmp_path / "site"
    run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-index", "--target", site, wheel, "-q"], tmp_path)
    empty = tmp_path / "empty"
    empty.mkdir()
    env = {**os.environ, "PYTHONPATH": str(site), "MPLBACKEND": "Agg"}
    where = run([sys.executable, "-c", "import difflab, difflab.demos as d; print(difflab.__file__); "
                 "print(d.scene_path('lecture_teapot'))"], empty, env).split()
    assert all(Path(p).is_relative_to(site) for p in where), where

    out = run([site / "bin" / "difflab", "demo", "--quick", "-o", "figures"], empty, env)
    written = {p.name for p in (empty / "figures").iterdir()}
    for name in ("shading_models.png", "materials.csv", "texture_filtering.png", "raytrace_depth_series.png",
                 "raytrace_glass.png", "fractal_koch.png"):
        assert name in written and name in out, name
    assert sorted(p.name for p in empty.iterdir()) == ["figures"]  # nothing else written where it ran
