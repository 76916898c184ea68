"""Textures in the ray tracer: the same texels as the rasterizer, and a ray tree that re-evaluates them."""

import numpy as np
import pytest

from conftest import scene_dict
from test_raytrace import near_edge
from difflab import Scene, render, render_frame, save_image
from difflab.demos.textures import checker_texture, plane_reference, receding_plane_scene
from difflab.fit import evaluate_tree
from difflab.renderers.compile import compile_scene
from difflab.renderers.raytrace.adaptive import raytrace_adaptive


def textured_scene(tmp_path, filter="bilinear", target="kd"):
    rows, cols = np.indices((32, 32))
    texture = np.where(((rows // 4) + (cols // 4)) % 2 == 0, 0.9, 0.1)[..., None] * np.array([1.0, 0.6, 0.3])
    save_image(tmp_path / "checker.png", texture)
    return scene_dict(
        [{"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "t"},
         {"type": "sphere", "center": [0.6, 0.5, 0], "radius": 0.5, "material": "t"},
         {"type": "sphere", "center": [-0.7, 0.5, -0.3], "radius": 0.5, "material": "mirror"}],
        {"t": {"ka": [0.2] * 3, "kd": [1, 1, 1], "ks": [0.3] * 3, "n": 20, "texture": str(tmp_path / "checker.png"),
               "filter": filter, "texture_target": target},
         "mirror": {"kd": [0.05] * 3, "ks": [0.5] * 3, "n": 80, "kr": 0.8}},
        camera={"eye": [0, 1.2, 3.5], "target": [0, 0.4, 0], "fov_y": 45, "width": 48, "height": 36},
        lights=[{"type": "point", "position": [2, 4, 3]}], ambient=(0.3, 0.3, 0.3), render={"shadows": False})


def test_primary_texels_agree_with_the_rasterizer(tmp_path, compare_images):
    """Depth 1 (no mirror rays): the ray tracer's textured image equals the rasterizer's Phong image
    wherever the texel is unambiguous: off silhouettes (pixels next to a change of object) and more
    than half a texel from a checker cell edge, where bilinear filtering is the constant cell colour.
    Nearer an edge the two uv computations (interpolated on the plane's triangles, analytic in the
    ray tracer) may pick different sides."""
    scene = textured_scene(tmp_path)
    raster = render_frame(scene, shading="phong")
    traced = render(scene, method="raytrace", max_depth=1)
    gbuffer = raster.gbuffer
    silhouette = np.zeros(gbuffer.mask.shape, bool)
    for k in np.unique(gbuffer.object):
        silhouette |= near_edge(gbuffer.object == k)
    texels = gbuffer.uv * 32  # the checker's cells are 4 texels wide
    from_cell_edge = np.abs(texels - 4 * np.round(texels / 4)).min(axis=-1)
    keep = gbuffer.mask & ~silhouette & (from_cell_edge > 0.5)
    assert raster.image.std() > 0.1 and keep.sum() > 0.4 * gbuffer.mask.sum()
    # Tolerance: float32 rounding (7e-7 measured; 3e-4 while the rasterizer shaded the sphere at its
    # facets' interpolated points and normals, not at the sphere's own).
    compare_images(traced[keep], raster.image[keep], atol=1e-5, name="texels")


def test_ray_tree_reproduces_a_textured_image_with_new_materials(tmp_path, compare_images):
    d = textured_scene(tmp_path, filter="trilinear", target="kd")
    scene = Scene.from_dict(d)
    frame = render_frame(scene, method="raytrace", max_depth=3)
    tree = frame.ray_tree
    textured = tree.material == scene.material_index("t")
    assert np.abs(tree.texel[textured]).max() > 0.5  # mirror rays see textured surfaces too
    again = np.asarray(evaluate_tree(tree, scene.materials, scene.lights, scene.ambient, scene.background))
    compare_images(again, frame.image, atol=1e-5, name="textured_tree")
    d["materials"]["t"].update(ks=[0.6] * 3, ka=[0.05] * 3)
    d["materials"]["mirror"].update(kr=0.4)
    changed = Scene.from_dict(d)
    want = render(changed, method="raytrace", max_depth=3)
    got = np.asarray(evaluate_tree(tree, changed.materials, changed.lights, changed.ambient, changed.background))
    compare_images(got, want, atol=1e-5, name="textured_tree_new")


def test_supersampled_texture_filtering_converges_like_the_rasterizers(tmp_path):
    """A receding textured floor (trilinear, EWA) against its 16 x 16-ray bilinear reference: with spp
    side^2 each sample's footprint is 1/side of a pixel, on the rasterizer's sample grid as on the
    ray tracer's, so both errors fall with spp and agree within 1 % (measured 0.07 %). Footprints of
    a whole pixel per sample made the ray tracer's error grow with spp (the reviewer's grazing plane:
    trilinear 0.061 / 0.065 / 0.066 at spp 1 / 4 / 16)."""
    texture = save_image(tmp_path / "checker.png", checker_texture(64, 8))
    reference = plane_reference(receding_plane_scene(texture, "bilinear", 64, 48), 16)
    for name in ("trilinear", "ewa"):
        scene = receding_plane_scene(texture, name, 64, 48)
        errors = {}
        for spp in (1, 4, 16):
            for method in ("raster", "raytrace"):
                image = render(scene, method=method, spp=spp)
                errors[method, spp] = float(np.sqrt(np.mean((image - reference) ** 2)))
            assert errors["raytrace", spp] == pytest.approx(errors["raster", spp], rel=0.01)
        assert errors["raytrace", 16] < 0.6 * errors["raytrace", 4] < 0.6 * 0.6 * errors["raytrace", 1]


def test_adaptive_refinement_filters_textures_over_its_samples(tmp_path):
    """A refined pixel of adaptive supersampling is the mean of a refine x refine grid of sample
    centres -- the "grid" pattern of spp refine^2 -- so its textured primary and mirror hits must read
    the same footprints (1/refine of a pixel, and that sample's ray differentials) and give the same
    value. (They read a whole pixel, and a cone per refined pixel, before.)"""
    scene = Scene.from_dict(textured_scene(tmp_path, filter="trilinear", target="kd"))
    scene = scene.with_overrides(render={"max_depth": 2})
    frame = raytrace_adaptive(compile_scene(scene), scene.render, threshold=0.02, refine=4)
    refined = frame.stats["refine_mask"]
    assert refined.sum() > 200
    grid = render(scene, method="raytrace", spp=16)
    np.testing.assert_allclose(frame.image[refined], grid[refined], atol=1e-5)
