"""The demos package: example scenes found through the package, figure helpers."""

import json

import numpy as np
import pytest

import difflab
from difflab.demos import example_names, image_grid, scene_path
from difflab.errors import SceneError


def test_example_scenes_ship_inside_the_package():
    assert example_names() == ("glass_sphere", "lecture_teapot")
    for name in example_names():
        path = scene_path(name)
        assert path.is_file() and path.parent.parent.name == "demos"
        scene = difflab.example_scene(name)
        assert scene == difflab.load_scene(path)
        assert scene.camera.width == json.loads(path.read_text())["camera"]["width"]


def test_example_scene_at_another_size_keeps_the_rest():
    full = difflab.example_scene("glass_sphere")
    small = difflab.example_scene("glass_sphere", width=40, height=30)
    assert (small.camera.width, small.camera.height) == (40, 30)
    assert small.camera.eye == full.camera.eye and small.materials == full.materials
    assert difflab.example_scene("glass_sphere", height=30).camera.width == full.camera.width


def test_unknown_example_names_the_closest():
    with pytest.raises(SceneError, match=r"unknown name 'lecture_teapo' \(did you mean 'lecture_teapot'\?\)"):
        scene_path("lecture_teapo")


def test_image_grid_writes_a_png(tmp_path):
    images = [np.full((8, 8, 3), v, np.float32) for v in (0.0, 0.5, 1.0)]
    path = image_grid(images, ["a", "b", "c"], tmp_path / "grid.png", columns=2)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in tmp_path.iterdir()] == ["grid.png"]  # written atomically, no temporary left
