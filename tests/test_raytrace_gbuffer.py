"""A ray-traced frame's G-buffer (the primary hits of its recorded ray tree) against the rasterizer's,
closed forms, the frame's own image, and its laziness."""

import math

import numpy as np
import pytest

from conftest import scene_dict
from test_raytrace import MIXED, mixed_scene, near_edge
from test_raytrace_texture import textured_scene
from difflab import RenderError, Scene, compile_scene, render_frame
from difflab.renderers.frame import box_downsample
from difflab.renderers.raytrace import driver
from difflab.renderers.raytrace.adaptive import raytrace_adaptive

PERSPECTIVE = dict(MIXED["camera"], width=48, height=36)
ORTHOGRAPHIC = {"eye": [0.3, 0.7, 4.0], "target": [0, 0.5, 0], "projection": "orthographic", "ortho_height": 3.0,
                "width": 48, "height": 36, "far": 30}


def mixed(camera, **render_block):
    d = mixed_scene(**render_block)
    d["camera"] = camera
    return d


def off_silhouettes(gbuffer):
    """Samples whose 3x3 neighbourhood shows one object (the rasterizer's tessellated silhouettes lie
    within half a pixel of the exact ones)."""
    silhouette = np.zeros(gbuffer.mask.shape, bool)
    for k in np.unique(gbuffer.object):
        silhouette |= near_edge(gbuffer.object == k)
    return ~silhouette


@pytest.mark.parametrize("camera", [PERSPECTIVE, ORTHOGRAPHIC], ids=["perspective", "orthographic"])
def test_primary_hits_agree_with_the_rasterizers_gbuffer(camera):
    """Spheres and plane exact, a teapot mesh: ids agree with the rasterizer's off silhouettes,
    positions, normals and depths within its tessellation's error (at most 5.6e-4 / 6.4e-4 / 5.6e-4
    measured over both cameras),
    sphere hits lie on the exact sphere, mesh hits carry the rasterizer's triangle and barycentrics."""
    scene = Scene.from_dict(mixed(camera, max_depth=1))
    compiled = compile_scene(scene)
    raster = render_frame(compiled, method="raster", shading="phong").gbuffer
    gbuffer = render_frame(compiled, method="raytrace").gbuffer
    assert gbuffer.mask.shape == raster.mask.shape == (36, 48)
    keep = off_silhouettes(raster) & raster.mask
    assert keep.sum() > 0.5 * raster.mask.sum() > 0.2 * raster.mask.size
    for name in ("mask", "material", "object"):
        assert np.mean(getattr(gbuffer, name)[keep] == getattr(raster, name)[keep]) >= 0.99, name
    same = keep & (gbuffer.object == raster.object)
    for name, tol in (("position", 1.5e-3), ("normal", 2e-3), ("depth", 1.5e-3)):
        err = np.abs(getattr(gbuffer, name)[same] - getattr(raster, name)[same]).max()
        assert err < tol, (name, err)
    # empty samples as the rasterizer's: depth inf, ids -1
    empty = ~gbuffer.mask
    assert empty.any() and np.isinf(gbuffer.depth[empty]).all() and np.isfinite(gbuffer.depth[~empty]).all()
    assert (gbuffer.material[empty] == -1).all() and (gbuffer.object[empty] == -1).all()
    assert (gbuffer.face[empty] == -1).all()
    # the sphere exactly: |p - c| = r
    sphere = gbuffer.object == 0
    assert sphere.sum() > 50
    radius = np.linalg.norm(gbuffer.position[sphere].astype(np.float64) - MIXED["objects"][0]["center"], axis=-1)
    assert np.abs(radius - 0.6).max() < 1e-5
    # face: mesh triangles only (-1 on the exact sphere and plane, a tessellation triangle in the rasterizer's)
    mesh = gbuffer.object == 1
    assert mesh.sum() > 50 and (gbuffer.face[mesh] >= 0).all() and (gbuffer.face[~mesh] == -1).all()
    assert (raster.face[same & ~mesh & raster.mask] >= compiled.n_mesh_faces).all()
    on_face = same & mesh & (gbuffer.face == raster.face)
    assert on_face.sum() > 0.9 * (same & mesh).sum()
    assert np.abs(gbuffer.bary[on_face] - raster.bary[on_face]).max() < 1e-3
    # the barycentrics locate the hit on its triangle
    corners = compiled.vertices[compiled.faces[gbuffer.face[mesh]]]
    bary = gbuffer.bary[mesh]
    assert np.abs(bary.sum(-1) - 1).max() < 1e-5 and bary.min() > -1e-4
    assert np.abs(np.einsum("mk,mkc->mc", bary, corners) - gbuffer.position[mesh]).max() < 1e-5
    assert (gbuffer.bary[~mesh] == 0).all()
    # what the ray tracer does not compute: uv (no textures here), its derivatives
    assert not gbuffer.uv.any() and not gbuffer.texture.any()
    assert gbuffer.duv_dx is None and gbuffer.duv_dy is None


@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
def test_depth_of_a_plane_is_the_closed_form(projection):
    """The floor y = 0 seen from (0, 3, 4) looking at the origin: forward (0, -0.6, -0.8), up
    (0, 0.8, -0.6). Sample row i has b = 1 - 2 (i + 0.5) / H; its ray meets the floor at view depth
    3 / (0.6 - 0.8 b tan(fov_y / 2)) (perspective: the ray eye + s (forward + b h up + ...)) or
    (3 + 0.8 b h) / 0.6 (orthographic, h = ortho_height / 2), the same along a row."""
    camera = {"eye": [0, 3, 4], "target": [0, 0, 0], "projection": projection, "fov_y": 40, "ortho_height": 2.0,
              "width": 16, "height": 20, "far": 100}
    d = scene_dict([{"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "m"}], {"m": {}},
                   camera=camera)
    b = 1 - 2 * (np.arange(20) + 0.5) / 20
    if projection == "perspective":
        want = 3 / (0.6 - 0.8 * b * math.tan(math.radians(20)))
    else:
        want = (3 + 0.8 * b) / 0.6
    for method in ("raytrace", "raster"):
        depth = render_frame(d, method=method).gbuffer.depth
        assert np.abs(depth / want[:, None] - 1).max() < 2e-6, method


def test_shading_points_are_the_image_samples():
    """max_depth 1, no fog: each sample's colour is its root node's local colour, so the points'
    colours on the grid are the image (spp 1) and box-filter to it (spp 4: a 2x2 grid per pixel);
    every sample is its own point."""
    d = mixed(dict(PERSPECTIVE, width=24, height=18), max_depth=1)
    frame = render_frame(d, method="raytrace")
    gbuffer = frame.gbuffer
    assert np.abs(gbuffer.points.color.reshape(frame.image.shape) - frame.image).max() <= 1e-6
    assert (frame.image[~gbuffer.mask] == np.float32([0.1, 0.2, 0.3])).all()  # misses see the background
    frame = render_frame(d, method="raytrace", spp=4)
    gbuffer, tree = frame.gbuffer, frame.ray_tree
    assert gbuffer.spp_side == 2 and gbuffer.mask.shape == gbuffer.depth.shape == (36, 48)
    assert gbuffer.position.shape == (36, 48, 3) and gbuffer.points.color.shape == (36 * 48, 3)
    samples = np.arange(36 * 48).reshape(36, 48)
    assert (gbuffer.point_index == samples[..., None]).all() and (gbuffer.point_weight == [1, 0, 0]).all()
    pixels = box_downsample(gbuffer.points.color.reshape(36, 48, 3), 2)
    assert np.abs(pixels - frame.image).max() <= 1e-6
    roots = tree.primary().ravel()
    for name in ("position", "normal", "view", "material", "cell", "light_dir", "light_dist", "visibility"):
        assert np.array_equal(getattr(gbuffer.points, name), getattr(tree, name)[roots]), name
    assert gbuffer.points.light_dir.shape == (36 * 48, 2, 3)
    assert not gbuffer.points.texture_factor.any()
    assert (gbuffer.shading, gbuffer.specular, gbuffer.clamp_vertex_colors) == ("phong", "phong", False)
    assert np.array_equal(gbuffer.background, np.float32([0.1, 0.2, 0.3])) and np.allclose(gbuffer.ambient, 0.2)


def test_textured_samples_carry_their_uv_and_texel(tmp_path):
    """uv and the texel are recorded where a textured material was hit (0 on the untextured mirror
    sphere); off silhouettes, the textured plane's and sphere's uv are the rasterizer's (interpolated
    on the tessellated sphere: 9e-5 measured), and so are their texels away from the checker's cell
    edges (where the two uv may pick different sides)."""
    d = textured_scene(tmp_path)
    d["camera"].update(width=32, height=24)
    raster = render_frame(d, shading="phong").gbuffer
    gbuffer = render_frame(d, method="raytrace", max_depth=1).gbuffer
    textured = gbuffer.material == 0
    assert textured.sum() > 200 and (gbuffer.material == 1).sum() > 20
    assert not gbuffer.uv[~textured].any() and not gbuffer.texture[~textured].any()
    both = textured & (raster.material == 0) & off_silhouettes(raster)
    assert both.sum() > 0.6 * textured.sum()
    assert np.abs(gbuffer.uv[both] - raster.uv[both]).max() < 3e-4
    texels = raster.uv * 32  # the checker's cells are 4 texels wide
    from_cell_edge = np.abs(texels - 4 * np.round(texels / 4)).min(axis=-1)
    keep = both & (from_cell_edge > 0.5)
    assert keep.sum() > 100
    assert np.abs(gbuffer.texture[keep] - raster.texture[keep]).max() < 1e-5


def test_the_gbuffer_is_built_on_first_read_only(monkeypatch):
    """A frame whose G-buffer is never read never builds it; the first read builds it once and keeps it
    (also for an image=False frame, whose ray tree render_frame records all the same)."""
    built = []

    def counting(*args):
        built.append(1)
        return tree_gbuffer(*args)

    tree_gbuffer = driver.tree_gbuffer
    monkeypatch.setattr(driver, "tree_gbuffer", counting)
    d = mixed(dict(PERSPECTIVE, width=8, height=6))
    frame = render_frame(d, method="raytrace")
    assert frame.image.shape == (6, 8, 3) and frame.ray_tree.n_nodes > 0 and frame.stats["recorded_tree"]
    assert not built
    first = frame.gbuffer
    assert frame.gbuffer is first and len(built) == 1
    blind = render_frame(d, method="raytrace", image=False)
    assert blind.image is None and len(built) == 1
    assert np.array_equal(blind.gbuffer.depth, first.depth) and len(built) == 2


def test_a_frame_without_its_ray_tree_says_how_to_get_the_gbuffer():
    scene = Scene.from_dict(mixed(dict(PERSPECTIVE, width=8, height=6)))
    compiled = compile_scene(scene)
    for frame in (driver.raytrace(compiled, scene.render, record_tree=False),
                  raytrace_adaptive(compiled, scene.render, threshold=0.1, refine=2)):
        assert frame.ray_tree is None
        with pytest.raises(RenderError, match=r"^gbuffer: this raytrace frame kept no G-buffer .*render_frame"):
            frame.gbuffer


def test_the_jax_model_reforms_the_depth_one_image_from_the_gbuffer():
    """`fit.shade_gbuffer` (the rasterizer's Phong image model) on the ray-traced G-buffer -- shadows,
    a checker floor, linear fog from its depth, spp 4 -- gives the ray-traced image (1.8e-7 measured)."""
    from difflab.fit import shade_gbuffer

    d = mixed(dict(PERSPECTIVE, width=24, height=18), max_depth=1, spp=4)
    d["fog"] = {"mode": "linear", "color": [0.5, 0.5, 0.5], "start": 2, "end": 8}
    scene = Scene.from_dict(d)
    frame = render_frame(scene, method="raytrace")
    image = np.asarray(shade_gbuffer(frame.gbuffer, scene.materials.values(), scene.lights))
    assert frame.image.std() > 0.05 and np.abs(image - frame.image).max() < 1e-5
