"""difflab.geometry: primitives, Utah teapot, normals, transforms and mesh loading."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import POLYGONS, polygon_obj
from difflab.errors import MeshError
from difflab.geometry import (TriMesh, apply_to_normals, box, concatenate, cylinder, face_areas, face_normals,
                              load_mesh, quad, rotation_matrix, teapot, teapot_control_points,
                              teapot_patches, transform_matrix, uv_sphere, vertex_normals, weld)
from difflab.geometry.obj_text import read_obj

HYPOTHESIS = settings(derandomize=True, max_examples=40, deadline=None)


# ----------------------------------------------------------------------------- helpers

def welded(mesh: TriMesh) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces with positional duplicates merged (seams, box edges, poles)."""
    vertices, inverse = weld(mesh.vertices, 1e-9)
    return vertices, inverse[mesh.faces]


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    vertices = vertices - vertices.mean(axis=0)  # translation-invariant; about the middle, no cancellation
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def assert_closed_and_consistent(mesh: TriMesh) -> None:
    """Every (welded) edge is shared by exactly two faces, traversed once in each direction."""
    _, faces = welded(mesh)
    directed = Counter()
    for a, b, c in faces.tolist():
        for e in ((a, b), (b, c), (c, a)):
            directed[e] += 1
    assert max(directed.values()) == 1, "some directed edge is used twice: inconsistent winding"
    for (a, b) in directed:
        assert directed.get((b, a), 0) == 1, f"edge {(a, b)} is a boundary edge"


def assert_normals_match_winding(mesh: TriMesh, fraction: float = 1.0) -> None:
    fn = face_normals(mesh.vertices, mesh.faces)
    vn = mesh.normals[mesh.faces].sum(axis=1)
    agree = np.einsum("ij,ij->i", fn, vn) > 0
    assert agree.mean() >= fraction


# ----------------------------------------------------------------------------- TriMesh

def test_trimesh_converts_and_freezes():
    m = TriMesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    assert m.vertices.dtype == np.float64 and m.faces.dtype == np.int64
    assert m.normals is None and m.uvs is None
    with pytest.raises(ValueError):
        m.vertices[0, 0] = 5.0
    with pytest.raises(AttributeError):
        m.vertices = np.zeros((3, 3))


@pytest.mark.parametrize("vertices, faces, normals, uvs, match", [
    (np.zeros((3, 2)), [[0, 1, 2]], None, None, r"vertices must have shape"),
    ([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]], [[0, 1, 2]], None, None, r"vertex 2 is not finite"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3]], None, None, r"out of range"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, -1]], None, None, r"out of range"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.zeros((0, 3), int), None, None, r"no faces"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1]], None, None, r"faces must have shape"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0.5, 1, 2]], None, None, r"integers"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], np.zeros((2, 3)), None, r"normals"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], None, np.zeros((3, 3)), r"uvs"),
])
def test_trimesh_rejects_bad_input(vertices, faces, normals, uvs, match):
    with pytest.raises(MeshError, match=match):
        TriMesh(vertices, faces, normals, uvs)


def test_concatenate_reindexes_and_keeps_attributes_only_if_all_have_them():
    a, b = box(), uv_sphere(n_lat=4, n_lon=6)
    both = concatenate([a, b])
    assert both.n_vertices == a.n_vertices + b.n_vertices
    assert both.n_faces == a.n_faces + b.n_faces
    np.testing.assert_array_equal(both.faces[a.n_faces:], b.faces + a.n_vertices)
    assert both.normals is not None and both.uvs is not None
    bare = TriMesh(a.vertices, a.faces)
    mixed = concatenate([bare, b])
    assert mixed.normals is None and mixed.uvs is None
    with pytest.raises(MeshError):
        concatenate([])


# ----------------------------------------------------------------------------- primitives

@pytest.mark.parametrize("radius, center", [(1.0, (0, 0, 0)), (2.5, (1.0, -2.0, 3.0))])
def test_sphere_vertices_on_radius_and_normals_radial(radius, center):
    m = uv_sphere(radius=radius, center=center, n_lat=8, n_lon=12)
    d = m.vertices - np.asarray(center)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), radius, rtol=1e-12)
    np.testing.assert_allclose(m.normals, d / radius, atol=1e-12)
    assert np.all((m.uvs >= 0) & (m.uvs <= 1))


def test_sphere_uv_convention():
    m = uv_sphere(n_lat=4, n_lon=8)
    # v = lat / pi from the south pole: bottom v = 0, top v = 1, equator 0.5.
    lat = np.arccos(np.clip(-m.vertices[:, 1], -1, 1))
    np.testing.assert_allclose(m.uvs[:, 1], lat / np.pi, atol=1e-12)
    ring = (m.uvs[:, 1] > 0) & (m.uvs[:, 1] < 1)
    lon = np.mod(np.arctan2(-m.vertices[ring, 2], m.vertices[ring, 0]), 2 * np.pi)
    u = m.uvs[ring, 0]
    # u = lon / 2pi, with the seam duplicated at u = 1.
    diff = np.mod(u - lon / (2 * np.pi) + 0.5, 1.0) - 0.5
    np.testing.assert_allclose(diff, 0.0, atol=1e-12)
    assert set(np.round(u, 12)) == {j / 8 for j in range(9)}


def test_sphere_has_no_degenerate_triangles():
    m = uv_sphere(n_lat=6, n_lon=7)
    assert face_areas(m.vertices, m.faces).min() > 1e-3
    assert m.n_faces == 2 * 7 * (6 - 1)


@pytest.mark.parametrize("mesh", [
    uv_sphere(n_lat=6, n_lon=8), uv_sphere(radius=2, center=(1, 2, 3)), box(size=(1, 2, 3)),
    cylinder(segments=9), cylinder(radius=2.0, height=0.5, center=(0, 1, 0)),
], ids=["sphere-coarse", "sphere", "box", "cylinder-9", "cylinder-flat"])
def test_closed_primitives_are_watertight_outward_and_normals_agree(mesh):
    assert_closed_and_consistent(mesh)
    vertices, faces = welded(mesh)
    assert signed_volume(vertices, faces) > 0
    assert_normals_match_winding(mesh)
    np.testing.assert_allclose(np.linalg.norm(mesh.normals, axis=1), 1.0, atol=1e-12)


def test_sphere_volume_converges_to_analytic():
    r = 1.7
    exact = 4.0 / 3.0 * math.pi * r ** 3
    errors = []
    for n in (8, 16, 32, 64):
        m = uv_sphere(radius=r, n_lat=n, n_lon=2 * n)
        errors.append(abs(signed_volume(*welded(m)) - exact) / exact)
    assert all(b < a for a, b in zip(errors, errors[1:]))
    assert errors[-1] < 2e-3
    # Second order: doubling n divides the error by about 4.
    assert 3.0 < errors[-2] / errors[-1] < 5.0


def test_box_exact_volume_counts_and_flat_normals():
    m = box(size=(1.0, 2.0, 3.0), center=(1, 1, 1))
    assert m.n_vertices == 24 and m.n_faces == 12
    assert signed_volume(*welded(m)) == pytest.approx(6.0, rel=1e-12)
    np.testing.assert_allclose(m.bounds(), [[0.5, 0, -0.5], [1.5, 2, 2.5]])
    fn = face_normals(m.vertices, m.faces)
    np.testing.assert_allclose(m.normals[m.faces[:, 0]], fn, atol=1e-15)
    np.testing.assert_allclose(np.abs(fn).sum(axis=1), 1.0)
    assert np.all((m.uvs == 0) | (m.uvs == 1))


def test_cylinder_volume_and_open_tube():
    r, h, n = 0.5, 2.0, 64
    m = cylinder(radius=r, height=h, segments=n)
    polygon_area = 0.5 * n * r * r * math.sin(2 * math.pi / n)
    assert signed_volume(*welded(m)) == pytest.approx(polygon_area * h, rel=1e-12)
    np.testing.assert_allclose(m.bounds()[:, 1], [-1.0, 1.0])
    tube = cylinder(radius=r, height=h, segments=n, caps=False)
    assert tube.n_faces == 2 * n
    np.testing.assert_allclose(tube.normals[:, 1], 0.0)
    np.testing.assert_allclose(np.linalg.norm(tube.vertices[:, [0, 2]], axis=1), r)


@pytest.mark.parametrize("normal", [(0, 1, 0), (0, 0, 1), (0, 0, -1), (1, 0, 0), (-1, 0, 0),
                                    (0, -1, 0), (1, 2, 3)])
def test_quad_faces_its_normal(normal):
    center = np.array([0.5, -1.0, 2.0])
    m = quad(size=(2.0, 3.0), center=center, normal=normal)
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    np.testing.assert_allclose(face_normals(m.vertices, m.faces), [n, n], atol=1e-12)
    np.testing.assert_allclose(m.normals, np.tile(n, (4, 1)), atol=1e-12)
    np.testing.assert_allclose((m.vertices - center) @ n, 0.0, atol=1e-12)
    np.testing.assert_allclose(m.vertices.mean(axis=0), center, atol=1e-12)
    assert face_areas(m.vertices, m.faces).sum() == pytest.approx(6.0)


def test_quad_default_is_unit_square_in_xz_and_walls_have_v_up():
    m = quad()
    np.testing.assert_allclose(m.bounds(), [[-0.5, 0, -0.5], [0.5, 0, 0.5]])
    wall = quad(normal=(0, 0, 1))
    top = wall.uvs[:, 1] == 1
    assert np.all(wall.vertices[top, 1] > 0)
    right = wall.uvs[:, 0] == 1
    assert np.all(wall.vertices[right, 0] > 0)


@pytest.mark.parametrize("d", [1, 2, 5])
def test_subdivided_quad_and_box_keep_shape_area_volume_and_uv_map(d):
    q = quad(size=(2.0, 3.0), center=(0.5, -1.0, 2.0), normal=(0, 0, 1), divisions=d)
    assert q.n_vertices == (d + 1) ** 2 and q.n_faces == 2 * d * d
    np.testing.assert_allclose(face_normals(q.vertices, q.faces), np.tile([0, 0, 1.0], (2 * d * d, 1)), atol=1e-12)
    np.testing.assert_allclose(face_areas(q.vertices, q.faces), 6.0 / (2 * d * d), rtol=1e-12)
    np.testing.assert_allclose(q.bounds(), [[-0.5, -2.5, 2.0], [1.5, 0.5, 2.0]], atol=1e-12)
    # uv is the affine map of position (u along +x, v along +y for a wall facing +z).
    np.testing.assert_allclose(q.uvs, (q.vertices[:, :2] - [-0.5, -2.5]) / [2.0, 3.0], atol=1e-12)
    assert set(np.round(q.uvs[:, 0] * d, 9)) == set(range(d + 1))
    b = box(size=(1.0, 2.0, 3.0), center=(1, 1, 1), divisions=d)
    assert b.n_vertices == 6 * (d + 1) ** 2 and b.n_faces == 12 * d * d
    assert signed_volume(*welded(b)) == pytest.approx(6.0, rel=1e-12)
    np.testing.assert_allclose(b.normals[b.faces[:, 0]], face_normals(b.vertices, b.faces), atol=1e-12)


def test_scene_resolution_subdivides_builtin_quads_and_boxes():
    from difflab.renderers.compile import object_mesh
    from difflab.scene import Mesh

    assert object_mesh(Mesh("m", builtin="quad", resolution=1)).n_faces == 2
    assert object_mesh(Mesh("m", builtin="quad", resolution=4)).n_faces == 32
    assert object_mesh(Mesh("m", builtin="box", resolution=3, smooth=False)).n_faces == 12 * 9


@pytest.mark.parametrize("call", [
    lambda: quad(divisions=0), lambda: box(divisions=1.5),
    lambda: uv_sphere(radius=-1), lambda: uv_sphere(n_lat=1), lambda: uv_sphere(n_lon=2),
    lambda: box(size=(1, 0, 1)), lambda: cylinder(segments=2), lambda: cylinder(height=0),
    lambda: quad(normal=(0, 0, 0)), lambda: quad(size=(1, float("nan"))),
])
def test_primitive_bad_arguments_raise(call):
    with pytest.raises(MeshError):
        call()


# ----------------------------------------------------------------------------- normals

def test_face_normal_and_area_of_known_triangle():
    v = np.array([[0, 0, 0], [2, 0, 0], [0, 3, 0], [0, 0, 1]], float)
    f = np.array([[0, 1, 2], [0, 2, 1], [0, 3, 1]])
    np.testing.assert_allclose(face_normals(v, f), [[0, 0, 1], [0, 0, -1], [0, 1, 0]])
    np.testing.assert_allclose(face_areas(v, f), [3.0, 3.0, 1.0])


def test_area_weighted_vertex_normal_at_cube_corner():
    # Corner at the origin of a box with sides 1 x 2 x 3, outward normals -x, -y, -z. The corner
    # touches one triangle of each side (the diagonal choice below), so area weighting gives
    # weights equal to those triangles' areas: (2*3/2, 1*3/2, 1*2/2) for (-x, -y, -z).
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3]], float)
    f = np.array([[0, 3, 2],   # x = 0 side, normal -x, area 3
                  [0, 1, 3],   # y = 0 side, normal -y, area 1.5
                  [0, 2, 1]])  # z = 0 side, normal -z, area 1
    np.testing.assert_allclose(face_normals(v, f), [[-1, 0, 0], [0, -1, 0], [0, 0, -1]])
    expected = -np.array([3.0, 1.5, 1.0]) / np.linalg.norm([3.0, 1.5, 1.0])
    np.testing.assert_allclose(vertex_normals(v, f)[0], expected, atol=1e-15)
    np.testing.assert_allclose(vertex_normals(v, f, weighting="area")[0], expected, atol=1e-15)
    np.testing.assert_allclose(vertex_normals(v, f, weighting="uniform")[0],
                               -np.ones(3) / math.sqrt(3), atol=1e-15)
    # Each corner angle at the origin is 90 degrees: angle weighting is uniform here too.
    np.testing.assert_allclose(vertex_normals(v, f, weighting="angle")[0],
                               -np.ones(3) / math.sqrt(3), atol=1e-15)


def test_angle_weighting_ignores_triangulation_of_a_flat_region():
    # A flat fan (+z) and a slanted face: splitting a flat triangle in two changes area and
    # uniform weights but not angle weights.
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.5, 0.5, 0], [-1, 0, 1]], float)
    one = np.array([[0, 1, 2], [0, 2, 4]])
    two = np.array([[0, 1, 3], [0, 3, 2], [0, 2, 4]])
    a = vertex_normals(v, one, weighting="angle")[0]
    b = vertex_normals(v, two, weighting="angle")[0]
    np.testing.assert_allclose(a, b, atol=1e-14)
    u1 = vertex_normals(v, one, weighting="uniform")[0]
    u2 = vertex_normals(v, two, weighting="uniform")[0]
    assert np.abs(u1 - u2).max() > 1e-3


def test_degenerate_faces_are_skipped_and_never_nan():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [5, 5, 5]], float)
    f = np.array([[0, 1, 2],     # good, +z
                  [0, 1, 3],     # collinear: zero area
                  [1, 1, 2],     # repeated vertex
                  [4, 4, 4]])    # a point
    fn = face_normals(v, f)
    assert np.all(np.isfinite(fn))
    np.testing.assert_array_equal(fn[1:], 0.0)
    for weighting in ("area", "angle", "uniform"):
        vn = vertex_normals(v, f, weighting=weighting)
        assert np.all(np.isfinite(vn))
        np.testing.assert_allclose(vn[:3], np.tile([0, 0, 1.0], (3, 1)))
        # Vertices touched only by degenerate faces get the zero vector (documented).
        np.testing.assert_array_equal(vn[3], 0.0)
        np.testing.assert_array_equal(vn[4], 0.0)


def test_relatively_tiny_face_counts_as_degenerate():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0], [1e-7, 0, 0], [0, 0, 1e-7]], float)
    f = np.array([[0, 1, 2], [3, 4, 5]])
    np.testing.assert_array_equal(face_normals(v, f)[1], 0.0)
    # Alone, the tiny face is a perfectly good face.
    np.testing.assert_allclose(face_normals(v, f[1:])[0], [0, -1, 0])


def test_vertex_normals_rejects_unknown_weighting():
    m = box()
    with pytest.raises(ValueError, match="weighting"):
        vertex_normals(m.vertices, m.faces, weighting="max")


def test_vertex_normals_of_fine_sphere_are_radial():
    m = uv_sphere(n_lat=32, n_lon=64)
    v, f = welded(m)
    for weighting in ("area", "angle", "uniform"):
        vn = vertex_normals(v, f, weighting=weighting)
        assert np.min(np.einsum("ij,ij->i", vn, v)) > 0.999


# ----------------------------------------------------------------------------- transforms

def test_rotation_of_x_by_90_about_z_gives_y():
    m = rotation_matrix((0, 0, 1), 90)
    np.testing.assert_allclose(m @ [1, 0, 0, 1], [0, 1, 0, 1], atol=1e-15)
    np.testing.assert_allclose(transform_matrix(rotate_deg=(0, 0, 90)) @ [1, 0, 0, 1],
                               [0, 1, 0, 1], atol=1e-15)
    # Right-handed about x and y too.
    np.testing.assert_allclose(rotation_matrix((1, 0, 0), 90) @ [0, 1, 0, 1], [0, 0, 1, 1])
    np.testing.assert_allclose(rotation_matrix((0, 1, 0), 90) @ [0, 0, 1, 1], [1, 0, 0, 1])


def test_transform_matrix_composition_order():
    t, r, s = (1.0, 2.0, 3.0), (30.0, 45.0, 60.0), (2.0, 3.0, 4.0)
    extra = np.array([[0, -1, 0, 5], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], float)
    expected = (extra
                @ np.array([[1, 0, 0, t[0]], [0, 1, 0, t[1]], [0, 0, 1, t[2]], [0, 0, 0, 1]])
                @ rotation_matrix((0, 0, 1), r[2]) @ rotation_matrix((0, 1, 0), r[1])
                @ rotation_matrix((1, 0, 0), r[0]) @ np.diag([*s, 1.0]))
    np.testing.assert_allclose(transform_matrix(t, r, s, matrix=extra), expected, atol=1e-14)
    # Order check on a point: scale first, then rotate x (90), then y (90), then translate.
    m = transform_matrix(translate=(10, 0, 0), rotate_deg=(90, 90, 0), scale=(2, 1, 1))
    # (1,0,0) -S-> (2,0,0) -Rx-> (2,0,0) -Ry-> (0,0,-2) -T-> (10,0,-2)
    np.testing.assert_allclose(m @ [1, 0, 0, 1], [10, 0, -2, 1], atol=1e-14)
    # (0,1,0) -S-> (0,1,0) -Rx-> (0,0,1) -Ry-> (1,0,0) -T-> (11,0,0)
    np.testing.assert_allclose(m @ [0, 1, 0, 1], [11, 0, 0, 1], atol=1e-14)
    # A scalar scale is uniform.
    np.testing.assert_allclose(transform_matrix(scale=0.5), np.diag([0.5, 0.5, 0.5, 1]))


@pytest.mark.parametrize("kwargs", [dict(translate=(1, 2)), dict(rotate_deg=(0, float("nan"), 0)),
                                    dict(matrix=np.eye(3))])
def test_transform_matrix_bad_arguments(kwargs):
    with pytest.raises(ValueError):
        transform_matrix(**kwargs)


def test_normals_transform_by_inverse_transpose_under_nonuniform_scale():
    m = uv_sphere(n_lat=12, n_lon=24)
    M = transform_matrix(translate=(1, 2, 3), rotate_deg=(10, 20, 30), scale=(3.0, 1.0, 0.25))
    out = m.transformed(M)
    np.testing.assert_allclose(np.linalg.norm(out.normals, axis=1), 1.0, atol=1e-12)
    # The transformed surface is the ellipsoid |S^-1 R^-1 (p - t)| = 1; its gradient is the normal.
    A = np.linalg.inv(M[:3, :3])
    q = (out.vertices - M[:3, 3]) @ A.T
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    grad = q @ A
    grad /= np.linalg.norm(grad, axis=1, keepdims=True)
    np.testing.assert_allclose(out.normals, grad, atol=1e-12)
    # Normals stay perpendicular to the transformed surface: to every edge at a vertex, roughly
    # (exactly for the tangent plane; edges of a coarse mesh are chords, so compare with faces).
    fn = face_normals(out.vertices, out.faces)
    vn = out.normals[out.faces].sum(axis=1)
    assert np.all(np.einsum("ij,ij->i", fn, vn) > 0)
    # Transforming the points alone (normals not inverse-transposed) would be wrong:
    naive = m.normals @ M[:3, :3].T
    naive /= np.linalg.norm(naive, axis=1, keepdims=True)
    assert np.abs(naive - grad).max() > 0.1


def test_transformed_mirror_keeps_outward_winding_and_rejects_singular():
    m = box()
    mirrored = m.transformed(transform_matrix(scale=(-1, 1, 1)))
    assert signed_volume(*welded(mirrored)) == pytest.approx(1.0)
    assert_normals_match_winding(mirrored)
    with pytest.raises(MeshError, match="singular"):
        m.transformed(transform_matrix(scale=(0, 1, 1)))
    with pytest.raises(MeshError):
        m.transformed(np.eye(3))


@pytest.mark.parametrize("scale", [(1, 1, 1e-160), (1e-150, 1, 1), (1, 1e160, 1), (-1e-160, 1e140, 1)])
def test_transformed_normals_survive_tiny_and_huge_scales(scale):
    # A box's face normals are the axes under any axis scale (sign flipped by a mirror). The old
    # |A^-T n| squared 1e160 to inf, so those normals came out zero with an overflow warning.
    m = box()
    out = m.transformed(transform_matrix(scale=scale))
    np.testing.assert_array_equal(out.normals, m.normals * np.sign(scale))


def test_apply_to_normals_keeps_tiny_rows_and_refuses_a_singular_matrix():
    np.testing.assert_array_equal(apply_to_normals(np.eye(4), [[1e-320, 0, 0], [0, 3e300, 4e300], [0, 0, 0]]),
                                  [[1, 0, 0], [0, 0.6, 0.8], [0, 0, 0]])
    with pytest.raises(ValueError, match="singular"):
        apply_to_normals(np.diag([1.0, 0.0, 1.0, 1.0]), [[1, 0, 0]])


#: A general 3x3 map with a mirror (det < 0) and its exact inverse-transpose normals.
SHEAR_MIRROR = np.array([[1, 0.3, 0], [0, 2, 0.5], [0.2, 0, -0.7]])


@pytest.mark.parametrize("scale", [1e-300, 1e-160, 1e-108, 1e110, 1e160, 1e300])
def test_apply_to_normals_does_not_see_a_uniform_scale(scale):
    """Normals are scale-free: s A maps them as A does. The old det-based check called 1e-108 A and
    1e-160 A singular (det underflowed to -0.0) and 1e110 A, 1e160 A too (det -inf, with numpy's
    overflow warning, an error in this suite)."""
    normals = np.random.default_rng(0).normal(size=(5, 3))
    want = normals @ np.linalg.inv(SHEAR_MIRROR)
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    np.testing.assert_allclose(apply_to_normals(scale * SHEAR_MIRROR, normals), want, atol=1e-15)


@pytest.mark.parametrize("scale", [1e-300, 1e300, -1e300])
def test_a_uniformly_scaled_mesh_keeps_its_lighting(scale):
    """A mesh scaled by 1e-300 or 1e300 (a mirror too) keeps scale 1's normals (to 1e-15), so it
    shades alike; its points are scaled and a mirror's winding flipped. The old TriMesh.transformed
    refused both (|det| 1e-900 < 1e-300; det inf) as singular."""
    m = box()
    matrix = np.diag([scale, scale, scale, 1.0]) @ transform_matrix(rotate_deg=(10, 20, 30))
    out, one = m.transformed(matrix), m.transformed(transform_matrix(rotate_deg=(10, 20, 30)) @ np.diag(
        [np.sign(scale)] * 3 + [1.0]))
    np.testing.assert_allclose(out.normals, one.normals, atol=1e-15)
    np.testing.assert_allclose(out.vertices, abs(scale) * one.vertices, rtol=1e-14)
    np.testing.assert_array_equal(out.faces, one.faces)


@pytest.mark.parametrize("size", [1e200, 1e300])
def test_a_mesh_scaled_down_by_its_transform_renders_as_at_scale_one(size):
    """A sphere given 1e300 (1e200) times too large and scaled by 1 / size in its transform renders
    bit for bit as the unit sphere: lit alike, the smooth normals through a uniform scale of 1e-300.
    The old check (|det| < 1e-300) refused it: "transform is singular (det of 3x3 part = 0.0)"."""
    from conftest import scene_dict
    from difflab import render

    sphere = uv_sphere(1.0, n_lat=8, n_lon=16)
    light = [{"type": "directional", "direction": [-0.3, -0.5, -1], "intensity": [1, 1, 1]}]

    def image(scale):
        obj = {"type": "mesh", "vertices": (sphere.vertices / scale).tolist(), "faces": sphere.faces.tolist(),
               "normals": sphere.normals.tolist(), "material": "m", "transform": {"scale": scale}}
        return render(scene_dict([obj], {"m": {"kd": [0.8] * 3, "ks": [0.3] * 3, "n": 10}}, lights=light,
                                 render={"shading": "phong"}), method="raster")

    np.testing.assert_array_equal(image(1 / size), image(1.0))


def test_a_singular_or_non_finite_matrix_is_still_refused():
    with pytest.raises(MeshError, match="singular"):
        box().transformed(np.diag([1e300, 1e300, 0.0, 1.0]))
    with pytest.raises(ValueError, match="singular"):
        apply_to_normals(np.zeros((3, 3)), [[1, 0, 0]])
    with pytest.raises(ValueError, match="not finite"):
        apply_to_normals(np.diag([np.inf, 1, 1]), [[1, 0, 0]])


@HYPOTHESIS
@given(angles=st.tuples(*[st.floats(-360, 360)] * 3),
       scale=st.tuples(*[st.floats(0.1, 10)] * 3),
       translate=st.tuples(*[st.floats(-100, 100)] * 3))
def test_transformed_normals_stay_perpendicular_to_flat_faces(angles, scale, translate):
    m = box(size=(1, 2, 3))
    out = m.transformed(transform_matrix(translate, angles, scale))
    fn = face_normals(out.vertices, out.faces)
    np.testing.assert_allclose(out.normals[out.faces[:, 0]], fn, atol=1e-9)
    assert signed_volume(*welded(out)) == pytest.approx(6.0 * np.prod(scale), rel=1e-9)


# ----------------------------------------------------------------------------- teapot

def test_teapot_data_counts():
    cp = teapot_control_points()
    patches = teapot_patches()
    assert cp.shape == (306, 3) and cp.dtype == np.float64
    assert patches.shape == (32, 16) and patches.dtype == np.int64
    assert patches.min() == 0 and patches.max() == 305
    # Classic data is z up: bottom at z = 0, knob top at z = 3.15, spout tip at x = 3.525.
    assert cp[:, 2].min() == 0.0 and cp[:, 2].max() == 3.15
    assert cp[:, 0].min() == -3.0 and cp[:, 0].max() == 3.525
    # The first patch is the classic first rim patch; the whole set is symmetric about y = 0.
    np.testing.assert_array_equal(patches[0], np.arange(16))
    mirrored = {tuple(p) for p in np.round(cp * [1, -1, 1], 6)}
    assert mirrored == {tuple(p) for p in np.round(cp, 6)}


@pytest.mark.parametrize("resolution", [2, 4, 8])
def test_teapot_mesh_is_sane(resolution):
    m = teapot(resolution)
    assert np.all(np.isfinite(m.vertices)) and np.all(np.isfinite(m.normals))
    np.testing.assert_allclose(np.linalg.norm(m.normals, axis=1), 1.0, atol=1e-12)
    # Welded: no duplicate positions; degenerate triangles dropped.
    assert len(weld(m.vertices, 1e-9)[0]) == m.n_vertices
    assert face_areas(m.vertices, m.faces).min() > 0
    # 32 patches x 2 r^2 triangles, minus r collapsed triangles in each of the 8 lid-top and
    # bottom-centre patches.
    assert m.n_faces == 32 * 2 * resolution ** 2 - 8 * resolution
    # Y up, standing on y = 0, spout toward +x, symmetric about z = 0.
    lo, hi = m.bounds()
    assert lo[1] == pytest.approx(0.0, abs=1e-12) and hi[1] == pytest.approx(3.15)
    assert lo[0] == pytest.approx(-3.0)           # handle
    assert 3.3 < hi[0] < 3.525                     # spout tip
    assert lo[2] == pytest.approx(-2.0) and hi[2] == pytest.approx(2.0)
    height, width = hi[1] - lo[1], hi[0] - lo[0]
    assert 0.45 < height / width < 0.5             # the classic (squat) proportions
    # Consistent winding: every directed edge at most once, every edge in at most two faces.
    directed = Counter()
    for a, b, c in m.faces.tolist():
        for e in ((a, b), (b, c), (c, a)):
            directed[e] += 1
    assert max(directed.values()) == 1
    # Shading normals (analytic) and averaged vertex normals agree with the winding.
    assert_normals_match_winding(m, fraction=0.99)
    fn = face_normals(m.vertices, m.faces)
    vn = vertex_normals(m.vertices, m.faces)[m.faces]
    assert np.mean(np.einsum("ij,ij->i", vn.sum(axis=1), fn) > 0) > 0.99
    if resolution >= 4:  # finer meshes: every corner's normal, not just their sum
        assert np.mean(np.einsum("ikj,ij->ik", vn, fn).min(axis=1) > 0) > 0.99
        assert np.mean(np.einsum("ikj,ij->ik", m.normals[m.faces], fn).min(axis=1) > 0) > 0.99


def test_teapot_normals_point_outward():
    m = teapot(8)
    v, n = m.vertices, m.normals
    # Body (between the bottom rim and the rim, away from handle and spout): normals point away
    # from the y axis.
    body = (v[:, 1] > 0.3) & (v[:, 1] < 2.3) & (np.hypot(v[:, 0], v[:, 2]) > 1.45) \
        & (np.abs(v[:, 0]) < 1.0)
    assert body.sum() > 50
    radial = v[body][:, [0, 2]] / np.hypot(v[body, 0], v[body, 2])[:, None]
    assert np.all(np.einsum("ij,ij->i", n[body][:, [0, 2]], radial) > 0.5)
    # Knob top points up; bottom centre points down (the collapsed points: face-averaged).
    top = np.argmax(v[:, 1])
    np.testing.assert_allclose(v[top], [0, 3.15, 0], atol=1e-12)
    np.testing.assert_allclose(n[top], [0, 1, 0], atol=1e-9)
    bottom = np.flatnonzero(np.all(np.abs(v) < 1e-12, axis=1))
    assert len(bottom) == 1
    np.testing.assert_allclose(n[bottom[0]], [0, -1, 0], atol=1e-9)


def test_teapot_is_connected_and_unwelded_variant_has_uvs():
    m = teapot(4)
    # Union-find over faces: the body, rim, bottom and handle patches join; the lid is a
    # separate piece (it sits in the rim with a gap) and so is the spout (it pierces the body).
    parent = list(range(m.n_vertices))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b, c in m.faces.tolist():
        for x, y in ((a, b), (b, c)):
            parent[find(x)] = find(y)
    roots = {find(i) for i in range(m.n_vertices)}
    # body + rim + bottom + handle (its ends are welded to the body), the spout, the lid.
    assert len(roots) == 3
    assert m.uvs is None
    loose = teapot(4, weld_vertices=False)
    assert loose.uvs is not None and np.all((loose.uvs >= 0) & (loose.uvs <= 1))
    assert loose.n_faces == m.n_faces
    assert_normals_match_winding(loose, fraction=0.99)


def test_teapot_bad_resolution():
    with pytest.raises(MeshError):
        teapot(0)
    with pytest.raises(MeshError):
        teapot(2.5)


# ----------------------------------------------------------------------------- loading

def test_load_mesh_round_trip_obj_with_uvs_and_normals(tmp_path):
    m = box(size=(1, 2, 3), center=(0.5, 0, 0))
    lines = [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in m.vertices]
    lines += [f"vt {float(u)!r} {float(v)!r}" for u, v in m.uvs]
    lines += [f"vn {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in m.normals]
    lines += ["f " + " ".join(f"{i + 1}/{i + 1}/{i + 1}" for i in face) for face in m.faces]
    path = tmp_path / "box.obj"
    path.write_text("# a box\n" + "\n".join(lines) + "\n")
    loaded = load_mesh(path)
    np.testing.assert_array_equal(loaded.vertices, m.vertices)
    np.testing.assert_array_equal(loaded.faces, m.faces)
    np.testing.assert_allclose(loaded.uvs, m.uvs)
    np.testing.assert_allclose(loaded.normals, m.normals)
    assert loaded.name == str(path)


def test_load_mesh_round_trip_via_trimesh_export(tmp_path):
    import trimesh

    m = uv_sphere(n_lat=5, n_lon=7)
    for ext in ("obj", "ply"):
        path = tmp_path / f"sphere.{ext}"
        trimesh.Trimesh(m.vertices, m.faces, process=False).export(path)
        loaded = load_mesh(str(path))
        np.testing.assert_allclose(loaded.vertices, m.vertices, atol=1e-6)
        np.testing.assert_array_equal(loaded.faces, m.faces)


def test_load_mesh_plain_obj_has_no_normals_or_uvs_and_triangulates_quads(tmp_path):
    path = tmp_path / "quad.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    loaded = load_mesh(path)
    assert loaded.n_faces == 2 and loaded.normals is None and loaded.uvs is None
    np.testing.assert_allclose(face_normals(loaded.vertices, loaded.faces), [[0, 0, 1]] * 2)
    # Negative (relative) indices are valid OBJ.
    rel = tmp_path / "rel.obj"
    rel.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n")
    assert load_mesh(rel).n_faces == 1


def test_load_mesh_concatenates_several_objects(tmp_path):
    path = tmp_path / "two.obj"
    path.write_text("o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
                    "o b\nv 0 0 1\nv 1 0 1\nv 0 1 1\nf 4 5 6\n")
    loaded = load_mesh(path)
    assert loaded.n_faces == 2 and loaded.n_vertices == 6


BAD_FILES = {
    "garbage.obj": "hello, this is not a mesh {}\n",
    "nan.obj": "v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n",
    "inf.obj": "v 0 0 0\nv 1 0 inf\nv 0 1 0\nf 1 2 3\n",
    "range.obj": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 3 9\n",
    "negrange.obj": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n",
    "zero.obj": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n",
    "zeros.obj": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 00\r\n",
    "zero_slash.obj": "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 00//1 3//1\n",
    "nofaces.obj": "v 0 0 0\nv 1 0 0\nv 0 1 0\n",
    "empty.obj": "",
    "badnum.obj": "v 0 0 zero\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    "badface.obj": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n",
    "garbage.ply": "ply\nthis is not a ply header\n",
    "nofaces.ply": ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                    "property float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n"),
}


def test_load_mesh_reads_leading_zeros_and_crlf_lines(tmp_path):
    path = tmp_path / "padded.obj"
    path.write_bytes(b"v 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nf 01 002 3\r\n")
    loaded = load_mesh(path)
    assert loaded.faces.tolist() == [[0, 1, 2]] and loaded.vertices[1].tolist() == [1, 0, 0]


def obj_data(*, vt_columns=2, unused=None, quads=False, seed=3):
    """8 random vertices, 6 uvs, 7 normals, 10 triangles (or quads) with random uv / normal indices
    (so a vertex meets several: it must be split), vertex `unused` used by no face: (vertices, uvs,
    normals, faces, uv indices, normal indices), 0-based."""
    rng = np.random.default_rng(seed)
    vertices, uvs, normals = rng.normal(size=(8, 3)), rng.random((6, vt_columns)), rng.normal(size=(7, 3))
    used = [k for k in range(8) if k != unused]
    faces = rng.choice(used, size=(10, 4 if quads else 3))
    faces[:2, :3] = np.reshape(used[:6], (2, 3))
    faces[2, :len(used) - 6] = used[6:]
    return vertices, uvs, normals, faces, rng.integers(0, 6, faces.shape), rng.integers(0, 7, faces.shape)


def obj_file(layout: str, *, vt_columns=2, unused=None, extra_lines=(), quads=False, seed=3) -> str:
    """`obj_data` as OBJ text with `layout` corners (a, a/t, a//n, a/t/n), comment, o / g / s /
    mtllib / usemtl lines."""
    vertices, uvs, normals, faces, tex, norm = obj_data(vt_columns=vt_columns, unused=unused, quads=quads, seed=seed)
    corner = {"a": "{0}", "a/t": "{0}/{1}", "a//n": "{0}//{2}", "a/t/n": "{0}/{1}/{2}"}[layout]
    lines = ["# a test", "mtllib none.mtl", "o thing", *[f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in vertices],
             *["vt " + " ".join(f"{u:.17g}" for u in uv) for uv in uvs],
             *[f"vn {x:.17g} {y:.17g} {z:.17g}" for x, y, z in normals], "s off", "g part", "usemtl none", "",
             *["f " + " ".join(corner.format(a + 1, b + 1, c + 1) for a, b, c in zip(*row))
               for row in zip(faces, tex, norm)], *extra_lines]
    return "\n".join(lines) + "\n"


def corner_values(mesh) -> list:
    """Per triangle corner its position, normal and uv (None where the mesh has none): what a mesh
    renders as, however its vertices are ordered or split."""
    return [None if values is None else values[mesh.faces] for values in (mesh.vertices, mesh.normals, mesh.uvs)]


def same_corners(a, b) -> bool:
    return all((x is None and y is None) or (x is not None and y is not None and np.array_equal(x, y))
               for x, y in zip(corner_values(a), corner_values(b)))


def same_mesh(a, b) -> bool:
    return all((x is None and y is None) or (x is not None and y is not None and x.shape == y.shape
                                              and np.array_equal(x, y))
               for x, y in [(a.vertices, b.vertices), (a.faces, b.faces), (a.normals, b.normals), (a.uvs, b.uvs)])


@pytest.mark.parametrize("layout", ["a", "a/t", "a//n", "a/t/n"])
@pytest.mark.parametrize("variant", ["plain", "uvw", "crlf", "unused last vertex", "unused vertex"])
def test_common_obj_layouts_are_read_by_numpy_as_trimesh_reads_them(tmp_path, monkeypatch, layout, variant):
    """Triangles with a, a/t, a//n or a/t/n corners (with comment, o / g / s / mtllib / one usemtl
    lines, 3-number `vt` lines, CRLF line ends, a vertex no face uses, the last or not): numpy's reading
    (`obj_text`) gives trimesh's triangles corner by corner, trimesh unasked, and each corner has
    the position, uv and normal the file gives it: a vertex met with several uvs / normals is split
    into one vertex per (v, vt, vn) used (a vertex no face uses is dropped unless corners are bare)."""
    from difflab.geometry import loading

    unused = {"unused last vertex": 7, "unused vertex": 2}.get(variant)
    vt_columns = 3 if variant == "uvw" else 2
    text = obj_file(layout, vt_columns=vt_columns, unused=unused)
    path = tmp_path / "m.obj"
    path.write_bytes(text.replace("\n", "\r\n").encode() if variant == "crlf" else text.encode())
    reference = loading._trimesh_load(str(path), None)
    monkeypatch.setattr(loading, "_trimesh_load", lambda *args, **kwargs: pytest.fail("trimesh was asked"))
    loaded = load_mesh(path)
    assert same_corners(loaded, reference)
    vertices, uvs, normals, faces, tex, norm = obj_data(vt_columns=vt_columns, unused=unused)
    position, normal, uv = corner_values(loaded)
    np.testing.assert_array_equal(position, vertices[faces])
    assert (normal is None) == ("n" not in layout) and (uv is None) == ("t" not in layout)
    if "n" in layout:
        np.testing.assert_array_equal(normal, normals[norm])
    if "t" in layout:
        np.testing.assert_array_equal(uv, uvs[tex][..., :2])
    columns = [faces] + [index for index, key in ((tex, "t"), (norm, "n")) if key in layout]
    distinct = len(np.unique(np.stack(columns, -1).reshape(-1, len(columns)), axis=0))  # (v, vt, vn) used
    assert loaded.n_vertices == (8 if layout == "a" else distinct) and (layout == "a" or distinct > 8)


def test_unmerged_gives_the_same_vertices_by_rows_as_by_one_key(monkeypatch):
    """`unmerged` tells (v, vt, vn) tuples apart by one int64 key where their grid fits, else by
    sorting rows: both give the same split vertices (by their `v` index), in (v, vt, vn) order."""
    from difflab.geometry import obj_text

    vertices, uvs, normals, faces, tex, norm = obj_data()
    attributes = [(tex, uvs), (norm, normals)]
    by_key = obj_text.unmerged(vertices, faces, attributes)
    monkeypatch.setattr(obj_text, "MAX_TUPLE_KEY", 0)
    by_rows = obj_text.unmerged(vertices, faces, attributes)
    assert all(np.array_equal(a, b) for a, b in zip(by_key, by_rows))
    np.testing.assert_array_equal(by_key[0][by_key[1]], faces)  # each split vertex's `v` index
    np.testing.assert_array_equal(by_key[2][by_key[1]], uvs[tex])
    np.testing.assert_array_equal(by_key[3][by_key[1]], normals[norm])


@pytest.mark.parametrize("name", sorted(POLYGONS))
def test_polygon_faces_keep_their_corners_uvs_and_normals(tmp_path, name):
    """A quad / pentagon face with `vt` and `vn` per corner: a fan of triangles covering the polygon
    (areas sum to the shoelace area), each corner with the file's uv and normal (trimesh read
    polygons' uvs as none at all: the face rendered one texel's colour)."""
    path = tmp_path / f"{name}.obj"
    path.write_text(polygon_obj(POLYGONS[name]))
    loaded = load_mesh(path)
    position, normal, uv = corner_values(loaded)
    assert loaded.n_faces == len(POLYGONS[name]) - 2 and uv is not None and normal is not None
    np.testing.assert_array_equal(uv, (position[..., :2] + 1) / 2)
    np.testing.assert_array_equal(normal, np.broadcast_to([0.0, 0.0, 1.0], position.shape))
    x, y = np.array(POLYGONS[name], float).T
    shoelace = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    edges = np.cross(position[:, 1] - position[:, 0], position[:, 2] - position[:, 0])
    assert np.all(edges[:, 2] > 0) and np.isclose(0.5 * edges[:, 2].sum(), shoelace)


def relative_obj(corners: int, layout: str, relative: bool, materials: bool = False) -> str:
    """Two `corners`-gons, each after its own `v`, `vt` and `vn` lines (the second face's corners
    with the second block's uv / normal), the corners written `a`, `a/t`, `a//n` or `a/t/n` with
    indices absolute or `relative` (-1: the last line of its key above the face); `materials`: each
    face with its own (trimesh reads the file)."""
    angles = 2 * np.pi * np.arange(corners) / corners
    lines = []
    for block in range(2):
        lines += [f"usemtl m{block}"] if materials else []
        lines += [f"v {np.cos(a) + 3 * block:.6f} {np.sin(a):.6f} {block}" for a in angles]
        lines += [f"vt {(np.cos(a) + 1) / 2:.6f} {(np.sin(a) + 1) / 2:.6f}" for a in angles]
        lines += [f"vn 0 {0.6 * block:.1f} {1 - 0.2 * block:.1f}"]
        index = [k - corners if relative else block * corners + k + 1 for k in range(corners)]
        normal = -1 if relative else block + 1
        forms = {"a": "{v}", "a/t": "{v}/{v}", "a//n": "{v}//{n}", "a/t/n": "{v}/{v}/{n}"}
        lines.append("f " + " ".join(forms[layout].format(v=i, n=normal) for i in index))
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("materials", [False, True], ids=["numpy", "trimesh"])
@pytest.mark.parametrize("layout", ["a", "a/t", "a//n", "a/t/n"])
@pytest.mark.parametrize("corners", [3, 4, 5])
def test_relative_indices_read_as_the_absolute_ones(tmp_path, corners, layout, materials):
    """Negative (relative) `v` / `vt` / `vn` indices name the lines above their face: the file reads
    as the same one with positive indices -- the same vertices, faces, normals, uvs and welds --,
    numpy's reader or (two materials) trimesh's alike. trimesh counted them from the end of the file: the first face landed on the second's vertices (4 vertices for 8 in a quad file, its
    faces [[0, 1, 2], [0, 1, 2], [2, 3, 0], [2, 3, 0]] for [[0, 1, 2], [4, 5, 6], [2, 3, 0], [6, 7, 4]])."""
    meshes = []
    for relative in (False, True):
        path = tmp_path / f"{relative}.obj"
        path.write_text(relative_obj(corners, layout, relative, materials))
        assert (read_obj(path.read_bytes()).arrays is None) == materials  # who reads it
        meshes.append(load_mesh(path))
    absolute, relative = meshes
    assert absolute.n_faces == 2 * (corners - 2) and absolute.n_vertices == 2 * corners
    for field in ("vertices", "faces", "normals", "uvs", "welds"):
        a, b = getattr(absolute, field), getattr(relative, field)
        assert (a is None) == (b is None), field
        if a is not None:
            np.testing.assert_array_equal(a, b, err_msg=field)
    assert (absolute.normals is None) == (layout not in ("a//n", "a/t/n"))
    assert (absolute.uvs is None) == (layout not in ("a/t", "a/t/n"))


def test_a_relative_index_before_the_first_line_is_named(tmp_path):
    path = tmp_path / "far.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf -5 -3 -2 -1\n")
    with pytest.raises(MeshError, match=r"far\.obj:5: face index -5 out of range \(file has 4 vertices\)"):
        load_mesh(path)


@pytest.mark.parametrize("case", ["quads, two materials", "two materials", "a tab"])
def test_other_obj_layouts_are_left_to_trimesh(tmp_path, monkeypatch, case):
    """Several materials, a tab: trimesh reads these, and load_mesh gives its mesh."""
    from difflab.geometry import loading

    text = {"quads, two materials": obj_file("a//n", quads=True, extra_lines=["usemtl b", "f 1//1 2//2 3//3 4//4"]),
            "two materials": obj_file("a", extra_lines=["usemtl b", "f 1 2 3"]),
            "a tab": obj_file("a", extra_lines=["f 1\t2 3"])}[case]
    path = tmp_path / "m.obj"
    path.write_text(text)
    asked = []
    trimesh_load = loading._trimesh_load
    monkeypatch.setattr(loading, "_trimesh_load", lambda *args, **kwargs: asked.append(1) or trimesh_load(*args, **kwargs))
    loaded = load_mesh(path)
    assert asked and same_mesh(loaded, trimesh_load(str(path), None))


@pytest.mark.parametrize("name", sorted(BAD_FILES))
def test_load_mesh_bad_files_raise_mesh_error_naming_path(tmp_path, name):
    path = tmp_path / name
    path.write_text(BAD_FILES[name])
    with pytest.raises(MeshError) as info:
        load_mesh(path)
    assert str(path) in str(info.value)


def test_load_mesh_binary_garbage_and_missing_file(tmp_path):
    path = tmp_path / "noise.ply"
    path.write_bytes(bytes(range(256)) * 8)
    with pytest.raises(MeshError) as info:
        load_mesh(path)
    assert str(path) in str(info.value)
    missing = tmp_path / "does_not_exist.obj"
    with pytest.raises(MeshError, match="not found") as info:
        load_mesh(missing)
    assert str(missing) in str(info.value)
    with pytest.raises(MeshError, match="not a file"):
        load_mesh(tmp_path)


# ----------------------------------------------------------------------------- viewing

def test_look_at_perspective_and_viewport_map_known_points():
    from difflab.geometry import apply_to_points, look_at, ndc_to_raster, orthographic, perspective

    view = look_at((0, 0, 5), (0, 0, 0))
    np.testing.assert_allclose(apply_to_points(view, [[0, 0, 0], [1, 2, 0]]), [[0, 0, -5], [1, 2, -5]], atol=1e-12)
    proj = perspective(90.0, 2.0, 1.0, 11.0)
    # near plane -> z_ndc -1, far -> +1; at z = -d a point at height d tan(45) = d is on the top edge
    # (and d * aspect on the right edge); z_ndc(-3) = (11 + 1) / 10 + 2 * 11 / (10 * -3) = 7 / 15.
    ndc = apply_to_points(proj, [[0, 0, -1], [0, 0, -11], [0, 3, -3], [6, 0, -3]])
    np.testing.assert_allclose(ndc, [[0, 0, -1], [0, 0, 1], [0, 1, 7 / 15], [1, 0, 7 / 15]], atol=1e-12)
    np.testing.assert_allclose(ndc_to_raster([[-1, 1], [1, -1], [0, 0]], 40, 20), [[0, 0], [40, 20], [20, 10]])
    ortho = orthographic(4.0, 1.5, 0.5, 10.5)
    np.testing.assert_allclose(apply_to_points(ortho, [[3, 2, -0.5], [0, -2, -10.5]]), [[1, 1, -1], [0, -1, 1]], atol=1e-12)
    for bad in (lambda: perspective(40, 1, 0, 1), lambda: orthographic(1, 1, 2, 1), lambda: look_at((0, 0, 0), (0, 0, 0)),
                lambda: look_at((0, 0, 0), (0, 1, 0))):
        with pytest.raises(ValueError):
            bad()


def test_save_mesh_round_trips_through_load_mesh(tmp_path):
    from difflab.geometry import save_mesh

    m = uv_sphere(n_lat=4, n_lon=6)
    back = load_mesh(save_mesh(tmp_path / "s.obj", m))
    np.testing.assert_allclose(back.vertices[back.faces], m.vertices[m.faces], atol=1e-8)
    np.testing.assert_allclose(back.normals[back.faces], m.normals[m.faces], atol=1e-8)
