"""Shared fixtures: small scenes built as dicts in the file format."""

import sys

import numpy as np
import pytest

from difflab.io import save_image


@pytest.fixture(autouse=True, scope="module")
def release_compiled_programs():
    """Let go of JAX's compiled programs after each test module: each holds ~15 memory maps of
    machine code, and the fit tests compile thousands -- in one process the suite reached the
    kernel's 65530 maps (vm.max_map_count) and XLA crashed loading the next program (a null
    pointer from a failed mmap). Later modules read what they share from the persistent cache."""
    yield
    if "jax" in sys.modules:
        sys.modules["jax"].clear_caches()


def scene_dict(objects, materials, *, camera=None, lights=None, ambient=(0.0, 0.0, 0.0), render=None, **extra):
    """A scene dict with an orthographic 32x32 camera looking down -z unless `camera` is given."""
    d = {
        "camera": camera or {"eye": [0, 0, 5], "target": [0, 0, 0], "projection": "orthographic",
                             "ortho_height": 2.0, "width": 32, "height": 32, "near": 0.1, "far": 20},
        "ambient": list(ambient),
        "lights": lights or [],
        "materials": materials,
        "objects": objects,
        "render": render or {},
    }
    d.update(extra)
    return d


#: One polygon face each, in the z = 0 plane facing +z, spanning [-1, 1]^2.
POLYGONS = {"quad": [(-1, -1), (1, -1), (1, 1), (-1, 1)], "pentagon": [(-1, -1), (1, -1), (1, 1), (0, 1), (-1, 1)]}


def polygon_obj(points) -> str:
    """OBJ text of one polygon face over `points` (x, y), each corner with its own `vt`, the uv
    (x + 1, y + 1) / 2 (OBJ's v = 0 at the bottom), and one shared `vn` 0 0 1."""
    lines = [f"v {x} {y} 0" for x, y in points] + [f"vt {(x + 1) / 2} {(y + 1) / 2}" for x, y in points]
    lines += ["vn 0 0 1", "f " + " ".join(f"{k}/{k}/1" for k in range(1, len(points) + 1))]
    return "\n".join(lines) + "\n"


@pytest.fixture
def compare_images(tmp_path):
    """Assert two images agree within `atol`; on failure write render, reference and difference PNGs."""

    def check(got, want, atol, name="image"):
        got, want = np.asarray(got), np.asarray(want)
        err = np.abs(got - want)
        if not np.all(err <= atol):
            save_image(tmp_path / f"{name}_render.png", got)
            save_image(tmp_path / f"{name}_reference.png", want)
            save_image(tmp_path / f"{name}_difference.png", err / max(float(err.max()), 1e-12))
            raise AssertionError(f"{name}: max error {err.max():.3g} > {atol}; images written to {tmp_path}")

    return check
