"""The item buffer: primary rays' mesh hits from the rasterizer's z-buffer give the BVH's image, bit for
bit (the same hits, so the same ray trees), and `render` uses it without being asked."""

import numpy as np
import pytest

import difflab
from conftest import scene_dict
from difflab import RenderError, Scene
from difflab.renderers.compile import compile_scene
from difflab.renderers.raytrace.driver import raytrace
from test_raytrace import MIXED, mixed_scene

TREE_FIELDS = ("face", "object", "distance", "position", "normal", "local", "light_dir", "visibility")


def both(scene, threads=2):
    """The frame with every primary ray through the BVH, and with the item buffer (trees recorded)."""
    scene = Scene.from_dict(scene) if isinstance(scene, dict) else scene
    compiled = compile_scene(scene)
    bvh = raytrace(compiled, scene.render, threads, use_item_buffer=False)
    item = raytrace(compiled, scene.render, threads, use_item_buffer=True)
    return bvh, item


def assert_same_frames(bvh, item):
    """Images, ray counts and every recorded node equal (max abs difference 0)."""
    assert not bvh.stats["item_buffer"] and item.stats["item_buffer"]
    np.testing.assert_array_equal(item.image, bvh.image)
    assert item.stats["rays"] == bvh.stats["rays"]
    for name in TREE_FIELDS:
        np.testing.assert_array_equal(getattr(item.ray_tree, name), getattr(bvh.ray_tree, name), err_msg=name)


def random_view(seed):
    """The mixed scene (teapot mesh, sphere, checkered plane) from a seeded random eye, with a mirror floor
    (ior 1.5) and a glass sphere, depth 4, 2 x 2 supersampling."""
    rng = np.random.default_rng(seed)
    d = mixed_scene(max_depth=4, spp=4, fresnel="schlick")
    angle, height, distance = rng.uniform(0, 2 * np.pi), rng.uniform(0.3, 2.5), rng.uniform(2.0, 4.5)
    d["camera"] = dict(MIXED["camera"], eye=[distance * np.sin(angle), height, distance * np.cos(angle)],
                       width=48, height=36)
    d["materials"]["floor"] = dict(d["materials"]["floor"], kr=0.4, ior=1.5)  # (F = 0 at ior 1: no reflection)
    d["materials"]["red"] = dict(d["materials"]["red"], kt=0.8, ior=1.5)
    return d


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_item_buffer_gives_the_bvh_frame_bit_for_bit(seed):
    bvh, item = both(random_view(seed))
    assert_same_frames(bvh, item)
    assert item.stats["rays"]["reflection"] > 0 and item.stats["rays"]["refraction"] > 0


def test_ambiguous_samples_ask_the_bvh_and_still_agree():
    """A dense sphere mesh through an analytic sphere, orthographic, with shadows: the samples on
    silhouettes and where the mesh crosses the sphere are left to the BVH, the rest come from the
    z-buffer, and the frame is the BVH's."""
    objects = [{"type": "mesh", "builtin": "sphere", "resolution": 24, "material": "m",
                "transform": {"scale": 0.8}},
               {"type": "sphere", "center": [0.5, 0.3, 0.4], "radius": 0.45, "material": "m"},
               {"type": "mesh", "builtin": "teapot", "resolution": 4, "material": "m",
                "transform": {"translate": [-0.5, -0.6, 0.6], "scale": 0.25}}]
    scene = scene_dict(objects, {"m": {"kd": [0.6, 0.5, 0.4], "ks": [0.3, 0.3, 0.3], "n": 20, "kr": 0.3}},
                       lights=[{"type": "point", "position": [2, 3, 4]}], ambient=(0.1, 0.1, 0.1),
                       render={"method": "raytrace", "max_depth": 2, "shadows": True})
    scene["camera"].update(width=64, height=64)
    bvh, item = both(scene)
    assert_same_frames(bvh, item)
    asked, samples = item.stats["item_buffer_asked_bvh"], item.stats["samples"]
    assert 0 < asked < 0.1 * samples, (asked, samples)


def test_a_mesh_through_the_near_plane_and_beyond_the_far_plane():
    """The ray starts on the near plane and ends on the far one, where the rasterizer clips: a floor
    mesh running from behind the eye to past the far plane gives the BVH's frame."""
    objects = [{"type": "mesh", "builtin": "quad", "resolution": 8, "material": "m",
                "transform": {"rotate_deg": [-90, 0, 0], "scale": 40, "translate": [0, -1, 0]}},
               {"type": "mesh", "builtin": "box", "resolution": 2, "material": "m",
                "transform": {"translate": [0.3, -0.5, 2.0], "rotate_deg": [0, 35, 0], "scale": 0.5}}]
    camera = {"eye": [0, 0, 4], "target": [0, -0.3, 0], "fov_y": 60, "width": 40, "height": 30, "near": 1.5,
              "far": 12}
    scene = scene_dict(objects, {"m": {"kd": [0.7, 0.7, 0.7], "checker": {"size": 0.5}}}, camera=camera,
                       lights=[{"type": "directional", "direction": [-1, -2, -1]}], ambient=(0.1, 0.1, 0.1),
                       render={"method": "raytrace", "max_depth": 1, "spp": 9})
    bvh, item = both(scene)
    assert_same_frames(bvh, item)
    assert (bvh.image == 0.0).all(-1).any()  # some samples see past the far plane: the (black) background


def test_render_uses_the_item_buffer_where_it_applies_and_any_thread_count_agrees():
    mesh_scene = Scene.from_dict(mixed_scene(max_depth=2))
    frame = difflab.render_frame(mesh_scene, method="raytrace", threads=1)
    assert frame.stats["item_buffer"]
    # the item buffer shares the rasterizer's per-frame arrays of a compiled scene, and is kept for the
    # next render of the same sample grid: rasterizing, other settings and other grids in between
    compiled = difflab.compile_scene(mesh_scene)
    rastered = difflab.render(compiled, method="raster")
    first = difflab.render_frame(compiled, method="raytrace", threads=1)
    np.testing.assert_array_equal(first.image, frame.image)
    np.testing.assert_array_equal(difflab.render(compiled, method="raster"), rastered)
    again = difflab.render_frame(compiled, method="raytrace", threads=1)
    assert not first.stats["item_buffer_kept"] and again.stats["item_buffer_kept"]
    np.testing.assert_array_equal(again.image, frame.image)
    fine = difflab.render_frame(compiled, method="raytrace", spp=4)
    assert not fine.stats["item_buffer_kept"]
    np.testing.assert_array_equal(fine.image, difflab.render(mesh_scene, method="raytrace", spp=4, item_buffer=False))
    shallow = difflab.render_frame(compiled, method="raytrace", max_depth=1)
    assert not shallow.stats["item_buffer_kept"]  # back to the 1-sample grid
    np.testing.assert_array_equal(shallow.image, difflab.render(mesh_scene, method="raytrace", max_depth=1,
                                                                item_buffer=False))
    assert difflab.render_frame(compiled, method="raytrace", threads=2).stats["item_buffer_kept"]
    np.testing.assert_array_equal(difflab.render(mesh_scene, method="raytrace", threads=2), frame.image)
    np.testing.assert_array_equal(difflab.render(mesh_scene, method="raytrace", item_buffer=False), frame.image)
    spheres_only = scene_dict([{"type": "sphere", "center": [0, 0, 0], "radius": 0.5, "material": "m"}], {"m": {}})
    assert not difflab.render_frame(spheres_only, method="raytrace").stats["item_buffer"]  # no triangles to hint
    stratified = Scene.from_dict(mixed_scene(spp=4, sampling="stratified"))
    assert not difflab.render_frame(stratified, method="raytrace").stats["item_buffer"]
    with pytest.raises(RenderError, match="sampling: the item buffer .* needs sampling 'grid', got 'stratified'"):
        difflab.render(stratified, method="raytrace", item_buffer=True)
    with pytest.raises(RenderError, match="item_buffer / light_buffer: speed-ups of the ray tracer"):
        difflab.render(mesh_scene, method="raster", item_buffer=True)
