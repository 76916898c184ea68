"""The rasterizer's automatic back-face culling (`renderers/culling.py`): on closed solids in front of
the camera the z-buffer leaves back faces out by itself, and every array of the frame and its
G-buffer is bit for bit what drawing them gives (flat / Gouraud / Phong, spp 1 and 4, perspective and
orthographic); where culling would be wrong (a camera inside a solid, a solid cut by the near plane,
an inside-out mesh) or is not proven (an open plane grid) every triangle is drawn, as it is in a compiled scene's first
frame; the stats say which."""

import dataclasses

import numpy as np
import pytest

import difflab
from conftest import scene_dict
from difflab.geometry import uv_sphere
from difflab.renderers import culling
from difflab.renderers.raster import driver
from difflab.scene import Scene
from test_itembuffer_culling import INSIDE_OUT, MATERIALS, SOLIDS, flipped, mesh_object

LIGHTS = [{"type": "point", "position": [2, 3, 4]}]
CLOSED = SOLIDS[:4]  # sphere, cylinder and box meshes, an analytic sphere (tessellated): no plane
PERSPECTIVE = {"eye": [0.5, 1.2, 3.5], "target": [0, 0, 0], "fov_y": 45, "width": 40, "height": 30}
ORTHOGRAPHIC = {"eye": [-3, 0.5, 1], "target": [0, 0, 0], "projection": "orthographic", "ortho_height": 3.0,
                "width": 32, "height": 32}


def raster_scene(objects, camera, **render):
    return scene_dict(objects, MATERIALS, camera=camera, lights=LIGHTS, ambient=(0.1, 0.1, 0.1),
                      render={"method": "raster", "shadows": True, **render})


def frame_arrays(frame) -> dict:
    """Every array of a frame: its image and each G-buffer field (the shading points' too)."""
    out = {"image": frame.image}
    for part, prefix in [(frame.buffers, ""), (frame.buffers.points, "points.")]:
        for field in dataclasses.fields(part):
            value = getattr(part, field.name)
            if isinstance(value, np.ndarray):
                out[prefix + field.name] = value
    return out


def drawn_and_culled(scene, monkeypatch):
    """The frame with every triangle drawn (the automatic culling switched off) and the frame as
    rendered, of one compiled scene."""
    compiled = difflab.compile_scene(scene)
    with monkeypatch.context() as patch:
        patch.setattr(driver, "culls_back_faces", lambda *args, **options: False)
        drawn = difflab.render_frame(compiled, threads=2)
    return drawn, difflab.render_frame(compiled, threads=2)


@pytest.mark.parametrize("camera", [PERSPECTIVE, ORTHOGRAPHIC], ids=["perspective", "orthographic"])
@pytest.mark.parametrize("shading", ["flat", "gouraud", "phong"])
@pytest.mark.parametrize("spp", [1, 4])
def test_closed_solids_are_culled_and_every_array_is_the_same(camera, shading, spp, monkeypatch):
    drawn, culled = drawn_and_culled(raster_scene(CLOSED, camera, shading=shading, spp=spp), monkeypatch)
    assert (drawn.stats["auto_cull_backfaces"], culled.stats["auto_cull_backfaces"]) == (False, True)
    assert culled.stats["covered_samples"] > 0.1 * culled.stats["samples"]
    want, got = frame_arrays(drawn), frame_arrays(culled)
    assert want.keys() == got.keys()
    for name in want:
        assert want[name].tobytes() == got[name].tobytes(), name


def test_the_image_only_path_culls_too_and_gives_the_same_image(monkeypatch):
    compiled = difflab.compile_scene(raster_scene(CLOSED, PERSPECTIVE, spp=4))
    with monkeypatch.context() as patch:
        patch.setattr(driver, "culls_back_faces", lambda *args, **options: False)
        drawn = driver.rasterize(compiled, compiled.scene.render, 2, gbuffer=False)  # what `render` runs
    culled = driver.rasterize(compiled, compiled.scene.render, 2, gbuffer=False)
    assert (drawn.stats["auto_cull_backfaces"], culled.stats["auto_cull_backfaces"]) == (False, True)
    np.testing.assert_array_equal(culled.image, drawn.image)
    np.testing.assert_array_equal(difflab.render(compiled, threads=2), drawn.image)


def test_asked_culling_is_not_reported_as_automatic():
    compiled = difflab.compile_scene(raster_scene(CLOSED, PERSPECTIVE))
    asked = difflab.render_frame(compiled, threads=2, cull_backfaces=True)
    automatic = difflab.render_frame(compiled, threads=2)
    assert (asked.stats["auto_cull_backfaces"], automatic.stats["auto_cull_backfaces"]) == (False, True)
    np.testing.assert_array_equal(asked.image, automatic.image)


@pytest.mark.parametrize("objects, camera", [
    # inside a closed box: every triangle in view is a back face
    ([{"type": "mesh", "builtin": "box", "material": "m", "transform": {"scale": 6}}, *CLOSED],
     {"eye": [0.5, 1.2, 2.5], "target": [0, 0, 0], "fov_y": 70, "width": 40, "height": 30}),
    # the near plane cuts a box the eye is outside of: its back faces show through the cut
    ([{"type": "mesh", "builtin": "box", "material": "m", "transform": {"translate": [0, 0, 2.7]}}, *CLOSED],
     {"eye": [0, 0, 4], "target": [0, 0, 0], "fov_y": 50, "near": 1.0, "width": 40, "height": 30}),
    # a sphere mesh inside out: seen from outside, its back faces
    ([mesh_object(INSIDE_OUT), *CLOSED[1:]], PERSPECTIVE),
    # an analytic sphere's tessellation around the eye
    ([{"type": "sphere", "center": [0.5, 1.2, 3.5], "radius": 0.5, "material": "m"}, *CLOSED], PERSPECTIVE),
], ids=["camera-inside", "near-plane-cuts", "inside-out", "eye-in-analytic-sphere"])
def test_back_faces_are_drawn_where_culling_them_would_change_the_frame(objects, camera):
    compiled = difflab.compile_scene(raster_scene(objects, camera))
    frame = later_frame(compiled)
    assert not frame.stats["auto_cull_backfaces"]
    wrong = difflab.render_frame(compiled, threads=2, cull_backfaces=True)
    assert np.count_nonzero(wrong.buffers.face != frame.buffers.face) > 20  # other triangles seen


@pytest.mark.parametrize("objects", [
    SOLIDS,  # a floor plane: its grid is open
    [*CLOSED, mesh_object(flipped(uv_sphere(0.3, center=(0, 0, 2.2), n_lat=6, n_lon=8)))],  # one piece inside out
], ids=["with-a-plane", "inside-out-piece-out-of-view"])
def test_back_faces_are_drawn_unless_every_triangle_is_a_solid_facing_out(objects):
    assert not later_frame(difflab.compile_scene(raster_scene(objects, PERSPECTIVE))).stats["auto_cull_backfaces"]


def later_frame(compiled):
    """A compiled scene's second frame (the first never culls by itself)."""
    difflab.render_frame(compiled, threads=2)
    return difflab.render_frame(compiled, threads=2)


def test_a_compiled_scenes_first_frame_draws_every_triangle_and_the_next_ones_cull():
    """The one-off test of the triangles (`culling.culls_back_faces`) waits for a second frame,
    of any copy of the compiled scene under other render settings."""
    compiled = difflab.compile_scene(raster_scene(CLOSED, PERSPECTIVE))
    first = difflab.render_frame(compiled, threads=2)
    assert not any(key[0] == culling.SOLIDS for key in compiled.built if isinstance(key, tuple))  # not tested yet
    later = [difflab.render_frame(compiled.with_scene(Scene.from_dict(raster_scene(CLOSED, PERSPECTIVE, spp=spp))),
                                  threads=2) for spp in (1, 1, 4)]
    assert [frame.stats["auto_cull_backfaces"] for frame in [first, *later]] == [False, True, True, True]
    for frame in later[:2]:
        np.testing.assert_array_equal(frame.image, first.image)
