"""The item buffer's back-face culling: `geometry.closed_outward` on meshes whose answer is known; the
test that no piece passes through itself (`renderers/raytrace/selfcross.py`: the triangle pair test
on known cases, star-shaped pieces, closed meshes with and without a fold through themselves); and
frames with culling on (closed outward meshes in front of the camera, pieces crossing each other)
and off (a camera inside a solid, a solid cut by the near plane, an inside-out mesh, a piece through
itself) equal to the BVH's bit for bit."""

import numpy as np
import pytest
import trimesh

import difflab
from conftest import scene_dict
from difflab._warp import wp
from difflab.geometry import TriMesh, box, closed_outward, concatenate, cylinder, quad, uv_sphere
from difflab.geometry.closed import pieces, solid_pieces
from difflab.renderers.raytrace import itembuffer
from difflab.renderers.raytrace.selfcross import crossing_faces, passes_through_itself, star_shaped
from difflab.scene import Scene
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


def frames(objects, camera, lights=LIGHTS, **render):
    """The item buffer's frame, checked equal to the BVH's bit for bit."""
    bvh, item = both(solids_scene(objects, camera, lights, **render))
    assert_same_frames(bvh, item)
    return item


def solids_scene(objects, camera, lights=LIGHTS, **render):
    return scene_dict(objects, MATERIALS, camera=camera, lights=lights, ambient=(0.1, 0.1, 0.1),
                      render={"method": "raytrace", "max_depth": 2, "shadows": True, **render})


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



# --- pieces passing through themselves (`renderers/raytrace/selfcross.py`) ---

FLAT = [(0, 0, 0), (2, 0, 0), (0, 2, 0)]  # welded corner numbers 0, 1, 2
APART = (3, 4, 5)  # the second triangle's corner numbers when it shares none


@pytest.mark.parametrize("second, numbers, meets", [
    ([(0.5, 0.5, -1), (0.5, 0.5, 1), (3, 3, 0)], APART, True),  # crossing: the second pierces the first
    ([(0.5, 0.5, 1e-3), (3, 0.5, 1e-3), (0.5, 3, 1e-3)], APART, False),  # parallel, 1e-3 above
    ([(1, 1, 0), (3, 1, 1), (1, 3, 1)], APART, True),  # touching: a corner on the hypotenuse
    ([(0.5, 0.5, 0), (3, 0.5, 0), (0.5, 3, 0)], APART, True),  # coplanar, overlapping
    ([(0.5, 0.5, 0), (0.5, -3, 0), (-3, 0.5, 0)], APART, True),  # coplanar, overlapping, facing the other way
    ([(0.2, 0.2, 0), (0.6, 0.2, 0), (0.2, 0.6, 0)], APART, True),  # coplanar, inside the first (no edges cross)
    ([(1.2, 1.2, 0), (-0.5, 0.8, 0), (0.8, -0.5, 0)], APART, True),  # coplanar, edges crossing, no corner inside
    ([(3, 3, 0), (5, 3, 0), (3, 5, 0)], APART, False),  # coplanar, apart
    ([(1.5, 1.5, 0), (5, 1.5, 0), (1.5, 5, 0)], APART, False),  # coplanar, 0.7 beyond the hypotenuse
    ([(0, 0, 0), (-1, -2, 0), (-2, -1, 0)], (0, 4, 5), False),  # sharing the corner (0, 0, 0): coplanar, apart
    ([(0, 0, 0), (-1, 0, 1), (-1, 0, -1)], (0, 4, 5), False),  # sharing a corner, in another plane, apart
    ([(0, 0, 0), (1, 1, -1), (1, 1, 1)], (0, 4, 5), True),  # sharing a corner and crossing beyond it
    ([(0, 0, 0), (1, 0.1, 0), (0.1, 1, 0)], (0, 4, 5), True),  # sharing a corner, coplanar, inside the first
    ([(0, 0, 0), (1, 1, 0), (3, 0, 0)], (0, 4, 5), True),  # sharing a corner, coplanar, overlapping
    ([(0, 2, 0), (2, 0, 0), (2, 2, 0)], (2, 1, 5), False),  # sharing an edge (not tested: module doc)
    ([(2, 0, 0), (0, 2, 0), (1, 1, 1)], (1, 2, 5), False),  # sharing an edge, folded up
], ids=["crossing", "parallel-apart", "touching-corner-on-edge", "coplanar-overlap", "coplanar-overlap-facing-away",
        "coplanar-nested", "coplanar-edges-crossing", "coplanar-apart", "coplanar-near", "shared-vertex-apart-coplanar",
        "shared-vertex-apart", "shared-vertex-crossing", "shared-vertex-nested", "shared-vertex-overlap", "shared-edge",
        "shared-edge-folded"])
def test_two_triangles_of_a_piece_meet_where_they_share_no_vertex(second, numbers, meets):
    """The pair test on known cases, both ways round (which face comes later must not matter);
    two triangles of different pieces are never paired."""
    for faces, corners in [((FLAT, second), [0, 1, 2, *numbers]), ((second, FLAT), [*numbers, 0, 1, 2])]:
        points = np.array([*faces[0], *faces[1]], np.float32)
        bvh = wp.Mesh(points=wp.array(points, dtype=wp.vec3), indices=wp.array(np.arange(6, dtype=np.int32),
                                                                                 dtype=wp.int32))
        corners = np.array(corners).reshape(2, 3)
        assert crossing_faces(bvh, corners, np.zeros(2, np.int64)).tolist() == [meets, False]
        assert not crossing_faces(bvh, corners, np.array([0, 5])).any()


def dented_box(depth: float) -> TriMesh:
    """A unit box whose top side (y = 0.5) is a pyramid pushed `depth` down from its centre: a
    fan of four triangles to an apex at y = 0.5 - depth, wound as the side was. Closed and facing
    out for any depth below 3 (volume 1 - depth / 3); past 1 its tip pokes out through the bottom,
    a region of winding number -1 that is seen first through back faces from below."""
    base = box()
    top = np.all(base.vertices[base.faces][:, :, 1] == 0.5, axis=1)
    edges = {(a, b) for f in base.faces[top] for a, b in zip(f, np.roll(f, -1))}
    rim = [(a, b) for a, b in edges if (b, a) not in edges]  # the side's border, counter-clockwise from above
    apex = len(base.vertices)
    fan = np.array([(a, b, apex) for a, b in rim])
    return TriMesh(np.r_[base.vertices, [[0.0, 0.5 - depth, 0.0]]], np.r_[base.faces[~top], fan])


def star_prism(step: int) -> TriMesh:
    """A prism (0 <= y <= 1, capped by fans from the axis) on the pentagon (step 1) or the pentagram
    {5/2} (step 2): closed, facing out, every face turning counter-clockwise seen from the axis --
    the pentagram's sides cross each other, winding twice around it."""
    angle = 2 * step * np.pi * np.arange(5) / 5
    ring = np.stack([np.cos(angle), np.zeros(5), -np.sin(angle)], axis=1)  # counter-clockwise seen from +y
    vertices = np.r_[ring, ring + [0, 1, 0], [[0, 0, 0], [0, 1, 0]]]
    k, n = np.arange(5), (np.arange(5) + 1) % 5
    faces = np.r_[np.stack([k, n, n + 5], 1), np.stack([k, n + 5, k + 5], 1),  # sides
                  np.stack([np.full(5, 11), k + 5, n + 5], 1), np.stack([np.full(5, 10), n, k], 1)]  # caps
    return TriMesh(vertices, faces)


def icosphere(subdivisions: int) -> TriMesh:
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    return TriMesh(sphere.vertices, sphere.faces)


def crossing(mesh: TriMesh) -> tuple[bool, bool]:
    """Whether the pieces of a closed mesh facing out are proven star-shaped, and whether one passes
    through itself (the item buffer's test, and the pair test alone on every face)."""
    corners, piece, centre = solid_pieces(mesh.vertices, mesh.faces)
    bvh = wp.Mesh(points=wp.array(mesh.vertices.astype(np.float32), dtype=wp.vec3),
                  indices=wp.array(mesh.faces.ravel().astype(np.int32), dtype=wp.int32))
    passes = passes_through_itself(bvh, corners, piece, centre)
    assert crossing_faces(bvh, corners, piece).any() == passes
    return bool(star_shaped(bvh, piece, centre).all()), passes


@pytest.mark.parametrize("mesh, star, passes", [
    (icosphere(3), True, False),
    (box(size=(1, 2, 3)), True, False),
    (cylinder(segments=9), True, False),
    (dented_box(0.4), True, False),  # a shallow dent: still star-shaped from the centre
    (dented_box(0.9), False, False),  # a deep one: not star-shaped from the centre, not crossing either
    (dented_box(1.4), False, True),  # the dent poked through the bottom
    (star_prism(1), True, False),
    (star_prism(2), False, True),
    (concatenate([box(), uv_sphere(0.7, center=(0.5, 0.2, 0.1))]), True, False),  # two pieces crossing each other
    (concatenate([box(center=(3, 0, 0)), dented_box(1.4)]), False, True),  # one piece fine, the other not
], ids=["icosphere", "box", "cylinder", "dent", "deep-dent", "dent-through", "pentagon-prism", "pentagram-prism",
        "box-through-sphere", "box-beside-dent-through"])
def test_pieces_passing_through_themselves(mesh, star, passes):
    assert solid(mesh)
    assert crossing(mesh) == (star, passes)


@pytest.mark.parametrize("step, star", [(1, True), (2, False)], ids=["pentagon", "pentagram"])
def test_star_shaped_needs_every_face_turning_and_one_cover(step, star):
    """Both prisms' faces all turn counter-clockwise seen from their centroid; the pentagram's
    central projection covers the sphere twice (a ray from the centre crosses two sides), so it is
    not proven star-shaped -- rightly: its sides cross."""
    prism = star_prism(step)
    corners, piece, centre = solid_pieces(prism.vertices, prism.faces)
    np.testing.assert_allclose(centre[piece], np.tile([0, 0.5, 0], (len(piece), 1)), atol=1e-12)
    assert np.all(np.linalg.det(prism.vertices[prism.faces] - centre[piece][:, None]) > 0.1)
    assert crossing(prism) == (star, not star)


def mesh_object(mesh: TriMesh, **extra) -> dict:
    return {"type": "mesh", "vertices": mesh.vertices.tolist(), "faces": mesh.faces.tolist(), "material": "m", **extra}


FROM_ABOVE = {"eye": [0.5, 1.2, 3.5], "target": [0, 0, 0], "fov_y": 45, "width": 48, "height": 36}
FROM_BELOW = {"eye": [0.6, -2.5, 1.4], "target": [0, -0.4, 0], "fov_y": 40, "width": 48, "height": 40}
LIT_FROM_BELOW = [{"type": "point", "position": [1.5, -4, 3]}]


def test_a_piece_through_itself_is_drawn_whole_and_culling_it_would_be_wrong(monkeypatch):
    """The dent poked through the bottom, seen from below: its tip's back faces are what the BVH
    meets first. Culled only if `passes_through_itself` is bypassed -- then the z-buffer leaves the
    tip out and the frame shows the bottom side behind it instead."""
    objects = [mesh_object(dented_box(1.4))]
    assert not frames(objects, FROM_BELOW, LIT_FROM_BELOW).stats["item_buffer_culled"]
    monkeypatch.setattr(itembuffer, "passes_through_itself", lambda *args, **options: False)
    bvh, item = both(solids_scene(objects, FROM_BELOW, LIT_FROM_BELOW))
    assert item.stats["item_buffer_culled"]
    wrong = np.any(item.image != bvh.image, axis=2)
    assert wrong.sum() > 20  # the tip's footprint: ~40 of the 48 x 40 samples


@pytest.mark.parametrize("objects", [
    [mesh_object(icosphere(3).transformed(np.diag([0.6, 0.6, 0.6, 1.0]))), mesh_object(box(center=(0.9, -0.2, 0)))],
    [mesh_object(concatenate([box(), uv_sphere(0.6, center=(0.5, 0.3, 0.2), n_lat=10, n_lon=16)]))],
    [mesh_object(dented_box(0.9))],
], ids=["icosphere-and-box", "box-through-sphere-one-mesh", "deep-dent"])
def test_solids_not_through_themselves_are_culled_and_the_frame_is_the_bvhs(objects):
    for camera, lights in [(FROM_ABOVE, LIGHTS), (FROM_BELOW, LIT_FROM_BELOW)]:
        assert frames(objects, camera, lights).stats["item_buffer_culled"]


def test_the_culling_test_follows_the_camera_of_a_compiled_scene_and_keeps_nothing_per_camera():
    """One compiled scene seen from cameras outside its solids (culled) and from inside the sphere
    mesh (drawn whole), in turn: each frame the BVH's, and what the compiled scene keeps does not
    grow with the cameras seen (the meshes' answer is kept; the camera's is asked each frame)."""
    outside = {"eye": [0.5, 1.2, 3.5], "target": [0, 0, 0], "fov_y": 45, "width": 32, "height": 24}
    inside = {**outside, "eye": [-0.6, 0.1, 0.05], "target": [1, 0, 0]}
    compiled = difflab.compile_scene(solids_scene(SOLIDS, outside))
    kept = None
    for k, (camera, culled) in enumerate([(outside, True), (inside, False), ({**outside, "eye": [0.4, 1.3, 3.4]}, True),
                                          (inside, False), ({**outside, "eye": [0.6, 1.1, 3.6]}, True)]):
        view = compiled.with_scene(Scene.from_dict(solids_scene(SOLIDS, camera)))
        frame = difflab.render_frame(view, threads=2)
        assert frame.stats["item_buffer_culled"] == culled
        np.testing.assert_array_equal(difflab.render(view, threads=2, item_buffer=False), frame.image)
        if k == 1:
            kept = set(compiled.built)
        elif k > 1:
            assert set(compiled.built) == kept
