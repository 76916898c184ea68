"""CUDA's thread per sample for the row loops (`launch.row_span`), run on the CPU (`launch.PER_SAMPLE`):
every frame -- images, G-buffers, ray trees, statistics -- bitwise the CPU's row per thread."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from conftest import scene_dict
from golden_scenes import SCENES
from test_raster_gbuffer import textured_scene
from difflab import RenderError, compile_scene, render, render_frame
from difflab.renderers import launch
from difflab.renderers.api import fit_frame
from difflab.renderers.raytrace.driver import trace_points

DEMOS = Path(__file__).resolve().parents[1] / "difflab" / "demos" / "scenes"


def assert_same(a, b, where="frame"):
    """a and b equal bit for bit (NaNs where the other has them), through dataclasses, dicts and
    sequences; timings left out."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            assert_same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, dict):
        keys = {k for k in a if "second" not in str(k)}
        assert keys == {k for k in b if "second" not in str(k)}, where
        for k in keys:
            assert_same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape, where
        assert np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"), where
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{where}[{k}]")
    else:
        assert a == b, where


def both(monkeypatch, draw):
    """draw() under the CPU's mapping, then under CUDA's (a thread per sample)."""
    monkeypatch.setattr(launch, "PER_SAMPLE", False)
    rows = draw()
    monkeypatch.setattr(launch, "PER_SAMPLE", True)
    return rows, draw()


def assert_same_frames(monkeypatch, scene, **options):
    rows, samples = both(monkeypatch, lambda: render_frame(scene, **options))
    assert_same(rows.image, samples.image, "image")
    assert_same(rows.gbuffer, samples.gbuffer, "gbuffer")
    assert_same(rows.ray_tree, samples.ray_tree, "ray_tree")
    assert_same(rows.stats, samples.stats, "stats")
    return rows


def demo(name: str, width: int, height: int) -> dict:
    scene = json.loads((DEMOS / name).read_text())
    scene.pop("$schema", None)
    scene["camera"].update(width=width, height=height)
    return scene


@pytest.mark.parametrize("spp", [1, 4])
@pytest.mark.parametrize("name", ["glass_sphere.json", "lecture_teapot.json"])
def test_demo_scenes_ray_traced_and_rasterized(monkeypatch, name, spp):
    """The demos (glass and mirrors, transparent shadows, a teapot through the item buffer), ray
    traced with their trees recorded and with the light buffer, and rasterized."""
    scene = demo(name, 37, 29)  # (an odd width: spans end mid-block)
    frame = assert_same_frames(monkeypatch, scene, method="raytrace", spp=spp)
    assert frame.stats["rays"]["reflection"] + frame.stats["rays"]["refraction"] > 0
    # (one thread: the light buffer's count of tests is one element every band adds to, and Warp's
    # CPU atomics are plain adds, so with bands on two threads the count varies from run to run)
    assert_same_frames(monkeypatch, scene, method="raytrace", spp=spp, light_buffer=True, threads=1)
    if spp > 1:
        assert_same_frames(monkeypatch, scene, method="raytrace", spp=spp, sampling="stratified")
    assert_same_frames(monkeypatch, scene, method="raster", spp=spp)


@pytest.mark.parametrize("method", ["raster", "raytrace"])
@pytest.mark.parametrize("name", sorted(SCENES))
def test_golden_scenes(monkeypatch, name, method):
    """Spheres and a checkered floor under shadows and a spot; a Gouraud teapot in fog at spp 4."""
    scene = dict(SCENES[name], render={k: v for k, v in SCENES[name]["render"].items()
                                       if method == "raster" or k not in ("shading",)})
    assert_same_frames(monkeypatch, scene, method=method)
    rows, samples = both(monkeypatch, lambda: render(scene, method=method))  # raster: the fused image pass
    assert_same(rows, samples, "render")


@pytest.mark.parametrize("shading", ["phong", "flat", "gouraud"])
@pytest.mark.parametrize("spp", [1, 4])
def test_textured_frames_image_less_frames_and_fit_frames(tmp_path, monkeypatch, shading, spp):
    """A textured floor under a sphere: the full frame, the G-buffer alone, `render`'s fused pass,
    a fit's frame, and the ray tracer's."""
    compiled = compile_scene(textured_scene(tmp_path, shading, spp))
    assert_same_frames(monkeypatch, compiled)
    assert_same_frames(monkeypatch, compiled, image=False)
    assert_same(*both(monkeypatch, lambda: render(compiled)), "render")
    rows, samples = both(monkeypatch, lambda: fit_frame(compiled))
    assert_same(rows.gbuffer, samples.gbuffer, "fit gbuffer")
    assert_same_frames(monkeypatch, compiled.scene, method="raytrace", max_depth=3)


def test_nonfinite_samples_are_counted_alike(monkeypatch):
    """Overflowing materials: each thread's count of non-finite samples (`dealt_span`'s slot) sums to
    the row per thread's -- the ray tracer's, and the Phong G-buffer pass's (a frame without its image)."""
    objects = [{"type": "sphere", "center": [0, 0, 0], "radius": 1.0, "material": "m"}]
    lights = [{"type": "point", "position": [2, 3, 4], "intensity": [1, 1, 1]}]
    scene = scene_dict(objects, {"m": {"kd": 3e38, "ks": 3e38}}, lights=lights, ambient=(3, 3, 3), camera={
        "eye": [0, 0, 4], "target": [0, 0, 0], "fov_y": 40, "width": 13, "height": 11})
    compiled = compile_scene(scene)
    counts = both(monkeypatch, lambda: trace_points(compiled, compiled.scene.render, None, side=2).nonfinite_samples)
    assert counts[0] == counts[1] > 0
    for image in (True, False):
        messages = []
        for per_sample in (False, True):
            monkeypatch.setattr(launch, "PER_SAMPLE", per_sample)
            with pytest.raises(RenderError, match="not finite") as caught:
                render_frame(scene, spp=4, image=image)
            messages.append(str(caught.value))
        assert messages[0] == messages[1]
