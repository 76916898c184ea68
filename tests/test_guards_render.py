"""The renderers' guards: a render over the memory or ray budget is refused before anything is
allocated, meshes that cannot be rendered name their object and file, and no NaN or inf pixel is
ever returned."""

import re

import numpy as np
import pytest

from conftest import scene_dict
from difflab import MeshError, RenderError, Scene, TextureError, compile_scene, limits, render, render_frame
from difflab.geometry import load_mesh
from difflab.guards import check_image, check_render, likely_causes, nonfinite_pixels, tree_shape
from difflab.renderers.bandpool import cpu_threads
from difflab.renderers.launch import (BANDS_PER_THREAD, PASS_POOL_MIN_SAMPLES, RASTER_POOL_MIN_SAMPLES, pass_threads,
                                     raster_threads)
from difflab.renderers.raytrace.record import sized_tree
from difflab.renderers.texture.store import TextureStore

LIGHT = [{"type": "point", "position": [2, 3, 4]}]
SPHERE = {"type": "sphere", "center": [0, 0, 0], "radius": 0.8, "material": "m"}


def scene(objects=(SPHERE,), materials=None, camera=None, **render_settings):
    return Scene.from_dict(scene_dict(list(objects), materials or {"m": {"kd": 0.6}}, lights=LIGHT, camera=camera,
                                      render=render_settings))


BIG = {"eye": [0, 0, 5], "target": [0, 0, 0], "width": 8192, "height": 8192}


@pytest.mark.parametrize("method, gib", [("raster", "15.25"), ("raytrace", "15.00")])
def test_an_8192_squared_frame_is_refused_before_compiling(monkeypatch, method, gib):
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "5G")
    with pytest.raises(RenderError, match=rf"^render: 8192 x 8192 pixels at spp 1 \({method}\): needs about {gib} GiB, "
                                          r"over the memory budget of 5\.00 GiB"):
        render(scene(camera=BIG, method=method))
    monkeypatch.setattr("difflab.renderers.api.compile_scene", None)  # nothing was compiled: it is not even reached
    with pytest.raises(RenderError, match="over the memory budget"):
        render(scene(camera=BIG, method=method))


def test_the_raster_estimate_counts_lights_per_shading_point():
    """220 bytes per sample plus 24 per sample and light (Phong: one shading point per sample)."""
    assert limits.raster_frame_bytes(1000, 1000, 3, 0) == 1000 * 220 + 1000 * 3 * 24


GLASS = {"g": {"kd": 0.1, "kr": 1, "kt": 1, "ior": 1.5}}
GLASS_SCENE = [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "g"},
               {"type": "sphere", "center": [1.5, 0, -1], "radius": 0.7, "material": "g"}]
CAMERA_32x24 = {"eye": [0, 1, 5], "target": [0, 0, 0], "width": 32, "height": 24}


def test_an_exponential_glass_tree_is_refused_up_front():
    glass = scene(GLASS_SCENE, GLASS, CAMERA_32x24, method="raytrace", max_depth=64)
    assert tree_shape(glass) == (2, 2.0, 2.0)  # kr + kt = 2 without Fresnel
    with pytest.raises(RenderError, match=r"^render: 32 x 24 pixels at spp 1 \(raytrace\) at max_depth 64: up to "
                                          r"7\.08e\+21 rays \(768 samples x 4\.61e\+18 ray-tree nodes x 2 rays per "
                                          r"node\) is over the budget of 1\.07e\+09 rays \(set DIFFLAB_MAX_RAYS to "
                                          r"raise it\); lower max_depth, kr / kt or the image size$"):
        render(glass)
    # the weights double at every bounce: no adaptive threshold (<= 1) bounds the tree, nor is one advised
    with pytest.raises(RenderError, match=r"lower max_depth, kr / kt or the image size$"):
        render(glass.with_overrides(render={"adaptive_threshold": 0.5}))


@pytest.mark.parametrize("fresnel, kr, kt, shape", [("none", 0.1, 0.9, (2, 1.0, 1.0)), ("none", 0.5, 0.4, (2, 0.9, 0.9)),
                                                    ("exact", 1.0, 1.0, (2, 1.0, 1.0)), ("none", 0.5, 0.0, (1, 0.5, 0.5))])
def test_the_refusal_names_the_adaptive_threshold_that_brings_the_tree_within_the_budget(monkeypatch, fresnel, kr, kt,
                                                                                         shape):
    """Glass at depth 40 over a budget of 10^6 rays: with kr + kt <= 1 (a ray's weight never grows:
    total internal reflection without Fresnel gives kr + kt, Fresnel's kr F + kt (1 - F) <= 1) a
    threshold t bounds each level's rays by 1 / t, and the message names the smallest t of
    1, 2, 5 x 10^-k that fits (the next smaller does not); a mirror chain (one child, weight 0.5)
    at spp 4 over 10^5 rays names spp too."""
    monkeypatch.setenv("DIFFLAB_MAX_RAYS", str(10 ** 5 if kt == 0 else 10 ** 6))
    glass = scene(GLASS_SCENE, {"g": {"kd": 0.1, "kr": kr, "kt": kt, "ior": 1.5}}, CAMERA_32x24, method="raytrace",
                  max_depth=40, fresnel=fresnel, spp=4 if kt == 0 else 1)
    assert tree_shape(glass) == shape
    with pytest.raises(RenderError) as refused:
        check_render(glass)
    levers = "max_depth, kr / kt, spp or the image size" if kt == 0 else "max_depth, kr / kt or the image size"
    advice = re.search(rf"; lower {re.escape(levers)}, or raise render\.adaptive_threshold \(Hall's control\) to "
                       r"([0-9.e-]+)$", str(refused.value))
    assert advice, str(refused.value)
    threshold = float(advice.group(1))
    digit = f"{threshold:.0e}"[0]
    assert float(f"{threshold:.0e}") == threshold and digit in "125"
    check_render(glass.with_overrides(render={"adaptive_threshold": threshold}))  # fits
    smaller = threshold / (2.5 if digit == "5" else 2.0)  # the grid's value below
    with pytest.raises(RenderError):
        check_render(glass.with_overrides(render={"adaptive_threshold": smaller}))


def test_fresnel_glass_at_depth_20_renders_within_the_bound():
    """The reviewer's case: glass (kr = kt = 1, exact Fresnel) at max_depth 20, adaptive_threshold
    0.01, was refused (bound 2^20 - 1 nodes a sample): each level's weights sum to <= 1, so it holds
    at most 100 rays -- the bound is 1427 nodes a sample, and the render stays within it."""
    glass = scene(GLASS_SCENE, GLASS, {**CAMERA_32x24, "width": 16, "height": 12}, method="raytrace", max_depth=20,
                  fresnel="exact", adaptive_threshold=0.01)
    check_render(glass)
    frame = render_frame(glass)
    assert frame.stats["nodes"] <= 16 * 12 * limits.ray_tree_nodes(20, 2, 1.0, 0.01, 1.0) == 16 * 12 * 1427
    assert all(n <= 16 * 12 * min(2 ** k, 100) for k, n in enumerate(frame.stats["depth_histogram"]))


def test_hall_adaptive_control_bounds_the_tree():
    """With kr = kt = 0.5 a ray at level k weighs at most 0.5^(k-1); a threshold of 0.01 stops it at level 8."""
    half = {"g": {"kd": 0.1, "kr": 0.5, "kt": 0.5, "ior": 1.5}}
    adaptive = scene(GLASS_SCENE, half, CAMERA_32x24, method="raytrace", max_depth=64, adaptive_threshold=0.01)
    check_render(adaptive)  # 768 x 255 nodes x 2: well within the ray budget
    frame = render_frame(adaptive)
    assert max(i + 1 for i, n in enumerate(frame.stats["depth_histogram"]) if n) <= 8
    assert np.isfinite(frame.image).all()


def test_a_recorded_tree_over_the_budget_is_refused_after_counting(monkeypatch):
    """The first pass counts each sample's nodes; the tree is sized from the counts, or refused."""
    counts = np.full((4, 4), 1000, np.int32)  # 16000 nodes of 150 bytes (one light): 2.3 MiB
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "1M")
    with pytest.raises(RenderError, match=r"^record_tree: a ray tree of 16000 nodes: needs about 2\.3 MiB, over the "
                                          r"memory budget of 1\.0 MiB .*; lower the image size, spp, max_depth or "
                                          r"kr / kt; difflab\.render \(and `difflab render`\) forms the image alone, "
                                          r"recording no tree$") as refused:
        sized_tree(counts, 1, 0, "cpu")
    assert "record_tree=False" not in str(refused.value)  # an option no public function has
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "3M")
    tree, offsets = sized_tree(counts, 1, 0, "cpu")
    assert offsets[-1] == 16000 and tree.sample.shape == (16000,)
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "2.5M")
    sized_tree(counts, 1, 0, "cpu")
    with pytest.raises(RenderError, match=r"^record_tree: a ray tree of 16000 nodes: needs about 2\.9 MiB"):
        sized_tree(counts, 1, 0, "cpu", textured=True)  # 190 bytes a node: texel and uv recorded too


@pytest.mark.parametrize("materials, cause", [
    ({"m": {"kd": 3e38, "ks": 3e38}}, r"materials\.m\.kd\[0\] = 3e\+38"),
    ({"m": {"kd": 0.5, "ka": 3e38}}, r"materials\.m\.ka\[0\] = 3e\+38"),  # times an ambient of 3: inf
])
@pytest.mark.parametrize("method", ["raster", "raytrace"])
def test_non_finite_pixels_are_refused_with_the_likely_cause(materials, cause, method):
    with pytest.raises(RenderError, match=r"^render: \d+ of 1024 pixels are not finite \(float32 overflow\); the "
                                          r"largest numbers in the scene: " + cause):
        render(Scene.from_dict(scene_dict([SPHERE], materials, lights=LIGHT, ambient=(3, 3, 3),
                                          render={"method": method})))


def test_check_image_counts_pixels_and_accepts_finite_images():
    image = np.zeros((2, 3, 3), np.float32)
    check_image(image, scene())
    image[0, 1, 2], image[1, 1] = np.inf, np.nan
    with pytest.raises(RenderError, match=r"^render: 2 of 6 pixels are not finite"):
        check_image(image, scene())


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nonfinite_pixels_counts_each_kind_and_no_large_finite_value(bad):
    image = np.full((3, 4, 3), 3e38, np.float32)  # a float64 sum of these is finite, a float32 one is not
    assert nonfinite_pixels(image) == 0 and nonfinite_pixels(image[:0]) == 0
    image[0, 1, 2], image[2, 3] = bad, bad
    assert nonfinite_pixels(image) == 2


def test_likely_causes_name_the_largest_numbers_and_a_vanishing_attenuation():
    d = scene_dict([SPHERE], {"m": {"kd": 0.5, "ks": 7e30}}, lights=[
        {"type": "point", "position": [2, 3, 4], "intensity": 2e20, "attenuation": [1e-30, 0, 0]}])
    assert likely_causes(Scene.from_dict(d), count=2) == ("materials.m.ks[0] = 7e+30, materials.m.ks[1] = 7e+30, "
                                                          "lights[0].attenuation[0] = 1e-30")


def test_mesh_errors_name_object_and_file(tmp_path):
    obj = tmp_path / "far.obj"
    obj.write_text("v 0 0 0\nv 1e11 0 0\nv 0 1 0\nf 1 2 3\n")
    mesh = {"type": "mesh", "file": str(obj), "material": "m", "transform": {"scale": 20}}
    with pytest.raises(MeshError, match=rf"^objects\[1\] \({obj}\)\.transform: vertices reach 2e\+12 after the "
                                        r"transform, beyond \+-1e\+12 \(float32 rendering overflows\)$"):
        compile_scene(scene([SPHERE, mesh]))
    obj.write_text("v 0 0 0\nv 1e39 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(MeshError, match=rf"^objects\[1\] \({obj}\): {obj}:2: vertex 2 is beyond \+-1e\+12"):
        render(scene([SPHERE, mesh]))


def test_tessellation_errors_name_the_object(monkeypatch):
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "64M")
    teapot = {"type": "mesh", "builtin": "teapot", "resolution": 1024, "material": "m"}
    with pytest.raises(MeshError, match=r"^objects\[1\]: teapot at resolution 1024 \(67108864 triangles\): needs about "
                                        r"33\.75 GiB, over the memory budget of 64\.0 MiB"):
        render(scene([SPHERE, teapot]))
    close = {"type": "sphere", "center": [0, 0, 4.95], "radius": 0.5, "material": "m"}  # around the eye: 1024 segments
    compiled = compile_scene(scene([close], camera={"eye": [0, 0, 5], "target": [0, 0, 0], "width": 8, "height": 8}))
    with pytest.raises(MeshError, match=r"^objects\[0\]: uv_sphere of 512 x 1024 \(1046528 triangles\)"):
        render(compiled, method="raster")  # tessellated when first rasterized


def test_textures_are_priced_before_their_pyramids(monkeypatch):
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "1M")
    with pytest.raises(TextureError, match=r"^textures: 16384 texels: needs about 1\.2 MiB, over the memory budget "
                                           r"of 1\.0 MiB"):
        TextureStore.from_images([np.zeros((128, 128, 3), np.float32)])


def test_difflab_threads_must_be_a_positive_integer(monkeypatch):
    monkeypatch.setenv("DIFFLAB_THREADS", "3")
    assert cpu_threads() == 3
    for bad in ("abc", "0", "-2", "1.5"):
        monkeypatch.setenv("DIFFLAB_THREADS", bad)
        with pytest.raises(limits.DifflabError, match=rf"^DIFFLAB_THREADS: expected a positive integer, got '{bad}'$"):
            render(scene())


def test_a_small_rasterized_frame_runs_on_one_thread_unless_told(monkeypatch):
    """The default for a frame under RASTER_POOL_MIN_SAMPLES samples is one thread; larger frames,
    an explicit `threads` and $DIFFLAB_THREADS keep their own count; the image is the same."""
    monkeypatch.delenv("DIFFLAB_THREADS", raising=False)
    assert raster_threads(None, RASTER_POOL_MIN_SAMPLES - 1) == 1
    assert raster_threads(None, RASTER_POOL_MIN_SAMPLES) is None
    assert raster_threads(2, 64) == 2
    assert pass_threads(None, PASS_POOL_MIN_SAMPLES - 1) == (1, BANDS_PER_THREAD)
    assert pass_threads(None, PASS_POOL_MIN_SAMPLES) == (None, 1)  # the per-sample passes: a band per core
    assert pass_threads(None, RASTER_POOL_MIN_SAMPLES) == (None, BANDS_PER_THREAD)
    assert pass_threads(1, RASTER_POOL_MIN_SAMPLES) == (1, BANDS_PER_THREAD)
    monkeypatch.setenv("DIFFLAB_THREADS", "2")
    assert raster_threads(None, 64) is None  # cpu_threads() then reads the variable
    assert pass_threads(None, PASS_POOL_MIN_SAMPLES) == (None, BANDS_PER_THREAD)
    small = scene(camera={"eye": [0, 0, 5], "target": [0, 0, 0], "width": 48, "height": 32})
    image = render(small)
    assert (image > 0).any(axis=-1).sum() > 100  # the sphere is drawn
    assert np.array_equal(image, render(small, threads=3))


def test_the_triangles_of_a_whole_scene_are_priced_as_they_are_built(monkeypatch):
    """Each of 40 spheres is small (16 128 triangles each, as a mesh or as the rasterizer's
    tessellation for flat and Gouraud shading); together they pass a 64 MiB budget at the 8th.
    Meshes are priced when compiled, the analytic spheres' tessellation when first rasterized: ray
    tracing them needs none, and Phong shading's (18,400 triangles in all) passes."""
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "64M")
    over = r" \(129024 triangles\): needs about 66\.4 MiB, over the memory budget of 64\.0 MiB"
    meshes = [{"type": "mesh", "builtin": "sphere", "resolution": 64, "material": "m",
               "transform": {"translate": [0, 0, -k]}} for k in range(40)]
    with pytest.raises(RenderError, match=r"^objects\[0\.\.7\]: triangles of the scene's meshes" + over):
        compile_scene(scene(meshes))
    compiled = compile_scene(scene([{**SPHERE, "center": [0, 0, -k]} for k in range(40)]))
    traced = render(compiled, method="raytrace")
    assert compiled.faces.shape[0] == 0 and traced[16, 16].max() > 0.1 and traced[0, 0].max() == 0
    for _ in range(2):  # refused again: nothing half built is kept
        with pytest.raises(RenderError, match=r"^objects\[0\.\.7\]: raster triangles of the scene" + over):
            render(compiled, method="raster", shading="gouraud")
    assert render(compiled, method="raster", shading="phong")[16, 16].max() > 0.1


def test_mesh_files_are_priced_by_their_size_before_reading(tmp_path, monkeypatch):
    path = tmp_path / "big.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n" + "# padding\n" * 100_000)  # 1,000,032 bytes
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "10M")
    with pytest.raises(MeshError, match=rf"^{path}: loading a mesh file of 1000032 bytes: needs about 13\.4 MiB"):
        load_mesh(path)
