"""The item buffer's back-face culling: `geometry.closed_outward` on meshes whose answer is known, and
frames with culling on (closed outward meshes in front of the camera) and off (a camera inside a
solid, a solid cut by the near plane, an inside-out mesh) equal to the BVH's bit for bit."""

import numpy as np
import pytest

import difflab
from conftest import scene_dict
from difflab.geometry import TriMesh, box, closed_outward, concatenate, cylinder, quad, uv_sphere
from difflab.geometry.closed import pieces
from test_itembuffer import assert_same_frames, both


def faceted(mesh: TriMesh) -> TriMesh:
    """Every face with its own three vertices (positions repeated bit for bit)."""
    return TriMesh(mesh.vertices[mesh.faces.ravel()], np.arange(mesh.faces.size).reshape(-1, 3))


def flipped(mesh: TriMesh) -> TriMesh:
    return TriMesh(mesh.vertices, mesh.faces[:, ::-1])


def solid(mesh: TriMesh) -> bool:
    return closed_outward(mesh.vertices, mesh.faces)


@pytest.mark.parametrize("mesh", [uv_sphere(n_lat=6, n_lon=8), box(size=(1, 2, 3)), cylinder(segments=9),
                                  faceted(uv_sphere(n_lat=5, n_lon=7)),
                                  concatenate([box(), uv_sphere(center=(3, 0, 0))]),
                                  box(size=(1, 1, 1e-5))],
                         ids=["sphere", "box", "cylinder", "faceted-sphere", "box-and-sphere", "thin-box"])
def test_closed_outward_meshes(mesh):
    assert solid(mesh)
    assert not solid(flipped(mesh))  # inside out


@pytest.mark.parametrize("mesh", [
    TriMesh(box().vertices, box().faces[2:]),  # a side left open
    cylinder(segments=9, caps=False),  # a tube
    quad(),
    concatenate([quad(), flipped(quad())]),  # a sheet drawn on both sides: closed, no volume
    concatenate([box(), flipped(uv_sphere(center=(3, 0, 0)))]),  # a second piece inside out
    concatenate([box(size=(3, 3, 3)), flipped(box())]),  # a hollow box: its cavity is a piece facing in
    TriMesh(box().vertices, np.r_[box().faces, box().faces[:1]]),  # a face twice
    TriMesh(uv_sphere(n_lat=4, n_lon=6).vertices, np.r_[uv_sphere(n_lat=4, n_lon=6).faces, [[0, 0, 1]]]),
], ids=["open-box", "tube", "quad", "two-sided-sheet", "inverted-piece", "hollow", "repeated-face",
        "degenerate-face"])
def test_meshes_that_are_not_closed_outward(mesh):
    assert not solid(mesh)


@pytest.mark.parametrize("n, edges, labels", [
    (6, [(0, 1), (2, 3), (4, 3)], [0, 0, 2, 2, 2, 5]),  # two pieces and a lone vertex
    (6, [(5, 4), (4, 3), (3, 2), (2, 1), (1, 0)], [0] * 6),  # a chain numbered backwards
    (8, [(7, 0), (6, 1), (5, 2), (4, 3), (0, 3), (5, 6)], [0, 1, 1, 0, 0, 1, 1, 0]),  # interleaved pieces
])
def test_pieces_label_each_vertex_with_the_least_vertex_of_its_piece(n, edges, labels):
    start, end = np.array(edges).T
    assert pieces(n, start, end).tolist() == labels


def test_closed_outward_of_no_faces():
    assert not closed_outward(np.zeros((3, 3)), np.zeros((0, 3), np.int64))


MATERIALS = {"m": {"kd": [0.6, 0.5, 0.4], "ks": [0.3, 0.3, 0.3], "n": 20, "kr": 0.3},
             "floor": {"kd": [0.7, 0.7, 0.7], "kr": 0.4, "checker": {"size": 0.5}}}
SOLIDS = [{"type": "mesh", "builtin": "sphere", "resolution": 20, "material": "m",
           "transform": {"translate": [-0.6, 0.1, 0], "scale": 0.6}},
          {"type": "mesh", "builtin": "cylinder", "resolution": 18, "material": "m",
           "transform": {"translate": [0.7, 0.0, -0.3], "rotate_deg": [20, 0, 10], "scale": 0.5}},
          {"type": "mesh", "builtin": "box", "material": "m",
           "transform": {"translate": [0.2, -0.5, 0.8], "rotate_deg": [0, 35, 15], "scale": 0.4}},
          {"type": "sphere", "center": [0.1, 0.6, -0.8], "radius": 0.4, "material": "m"},
          {"type": "plane", "point": [0, -0.8, 0], "normal": [0, 1, 0], "material": "floor"}]
LIGHTS = [{"type": "point", "position": [2, 3, 4]}]
INSIDE_OUT = flipped(uv_sphere(radius=0.6, center=(-0.6, 0.1, 0), n_lat=12, n_lon=20))


def frames(objects, camera, **render):
    scene = scene_dict(objects, MATERIALS, camera=camera, lights=LIGHTS, ambient=(0.1, 0.1, 0.1),
                       render={"method": "raytrace", "max_depth": 2, "shadows": True, **render})
    bvh, item = both(scene)
    assert_same_frames(bvh, item)
    return item


@pytest.mark.parametrize("camera", [
    {"eye": [0.5, 1.2, 3.5], "target": [0, 0, 0], "fov_y": 45, "width": 64, "height": 48},
    {"eye": [-3, 0.5, 1], "target": [0, 0, 0], "projection": "orthographic", "ortho_height": 3.0, "width": 48,
     "height": 48},
], ids=["perspective", "orthographic"])
def test_closed_meshes_in_front_of_the_camera_are_culled_and_the_frame_is_the_bvhs(camera):
    item = frames(SOLIDS, camera, spp=4)
    assert item.stats["item_buffer_culled"]
    assert 0 < item.stats["item_buffer_asked_bvh"] < 0.1 * item.stats["samples"]


@pytest.mark.parametrize("objects, camera", [
    # inside a closed box: every triangle in view is a back face
    ([{"type": "mesh", "builtin": "box", "material": "m", "transform": {"scale": 6}}, *SOLIDS],
     {"eye": [0.5, 1.2, 2.5], "target": [0, 0, 0], "fov_y": 70, "width": 48, "height": 36}),
    # the near plane cuts a box the eye is outside of: the rays start inside it and meet its back faces first
    ([{"type": "mesh", "builtin": "box", "material": "m", "transform": {"translate": [0, 0, 2.7]}}, *SOLIDS],
     {"eye": [0, 0, 4], "target": [0, 0, 0], "fov_y": 50, "near": 1.0, "width": 48, "height": 36}),
    # a sphere mesh inside out: seen from outside, its back faces
    ([{"type": "mesh", "vertices": INSIDE_OUT.vertices.tolist(), "faces": INSIDE_OUT.faces.tolist(), "material": "m"},
      *SOLIDS[1:]],
     {"eye": [0.5, 1.2, 3.5], "target": [0, 0, 0], "fov_y": 45, "width": 48, "height": 36}),
], ids=["camera-inside", "near-plane-cuts", "inside-out"])
def test_back_faces_are_drawn_when_culling_would_be_wrong(objects, camera):
    item = frames(objects, camera)
    assert not item.stats["item_buffer_culled"]


def test_a_kept_culled_item_buffer_says_so_and_gives_the_same_frame():
    scene = scene_dict(SOLIDS, MATERIALS, lights=LIGHTS, ambient=(0.1, 0.1, 0.1),
                       camera={"eye": [0.5, 1.2, 3.5], "target": [0, 0, 0], "fov_y": 45, "width": 40, "height": 30},
                       render={"method": "raytrace", "max_depth": 2})
    compiled = difflab.compile_scene(scene)
    first, again = (difflab.render_frame(compiled, threads=2) for _ in range(2))
    assert (first.stats["item_buffer_kept"], first.stats["item_buffer_culled"]) == (False, True)
    assert (again.stats["item_buffer_kept"], again.stats["item_buffer_culled"]) == (True, True)
    np.testing.assert_array_equal(again.image, first.image)
    np.testing.assert_array_equal(difflab.render(compiled, threads=2, item_buffer=False), first.image)
