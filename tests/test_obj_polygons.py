"""Polygon OBJ files -- quads, pentagons, triangles mixed with larger faces -- are read by numpy
(`obj_text`), trimesh unasked, into the mesh trimesh's reading gave (what `load_mesh` returned
before): the same vertices (positions and welds bitwise), split at uv seams and creases by (v, vt,
vn), their uvs and normals up to the order of one `v` line's copies; the same triangles, up to
their order and turn (trimesh put an all-quad file's second triangles, turned to (c, d, a), after
all the first ones); each corner with the position, uv, normal and `v` line (welds) the file gives
it. numpy's triangles are the fans (a, b, c), (a, c, d), ... of the faces in file order. Relative
indices are made absolute (`absolute_indices`, vectorised) for every reader."""

import numpy as np
import pytest

from difflab.errors import MeshError
from difflab.geometry import load_mesh, loading, obj_text

SIZES = {"quads": [4] * 6, "pentagons": [5] * 4, "mixed": [3, 4, 3, 5, 4, 3, 6]}  # corners of each face
LAYOUTS = {"a": "{v}", "a/t": "{v}/{t}", "a//n": "{v}//{n}", "a/t/n": "{v}/{t}/{n}"}
N_V, N_VT, N_VN = 8, 6, 7


def polygons(sizes, seed=5):
    """8 random vertices, 6 uvs, 7 normals and faces of `sizes` corners, each face's vertices
    distinct, together using all 8 (windows over a shuffled repeat of 0..7), each corner with a random
    uv and normal index (so vertices meet several uvs -- seams -- and normals -- creases): (vertices,
    uvs, normals, [(v, vt, vn) per corner] per face), 0-based."""
    rng = np.random.default_rng(seed)
    vertices, uvs, normals = rng.normal(size=(N_V, 3)), rng.random((N_VT, 2)), rng.normal(size=(N_VN, 3))
    cycle = np.tile(rng.permutation(N_V), sum(sizes))
    starts = np.cumsum(sizes) - sizes
    faces = [np.stack([cycle[s:s + k], rng.integers(0, N_VT, k), rng.integers(0, N_VN, k)], 1)
             for s, k in zip(starts, sizes)]
    return vertices, uvs, normals, faces


def polygon_text(sizes, layout: str, *, relative: float = 0.0, seed: int = 5) -> str:
    """`polygons(sizes, seed)` as OBJ text, corners written as `layout`, a `relative` fraction of
    the indices (chosen at random, all of them at 1) relative (-1: the last line of its key, all of
    them above the faces), the others absolute."""
    vertices, uvs, normals, faces = polygons(sizes, seed)
    rng = np.random.default_rng(seed + 1)
    written = [np.where(rng.random(face.shape) < relative, face - (N_V, N_VT, N_VN), face + 1) for face in faces]
    lines = ["# polygons", *[f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in vertices],
             *[f"vt {u:.17g} {v:.17g}" for u, v in uvs], *[f"vn {x:.17g} {y:.17g} {z:.17g}" for x, y, z in normals],
             "s off", *["f " + " ".join(LAYOUTS[layout].format(v=v, t=t, n=n) for v, t, n in face) for face in written]]
    return "\n".join(lines) + "\n"


def trimesh_reading(path):
    """The mesh `load_mesh` gave before numpy read polygons: trimesh's reading of the file's text
    (indices made absolute), welded by the file's `v` lines where it has uvs but no normals."""
    data = obj_text.read_obj(path.read_bytes()).data
    mesh = loading._trimesh_load(str(path), data)
    return loading.with_file_welds(mesh, data) if mesh.uvs is not None and mesh.normals is None else mesh


def vertex_rows(mesh) -> np.ndarray:
    """(V, K): each vertex's position, normal, uv and weld, those the mesh has."""
    welds = None if mesh.welds is None else mesh.welds[:, None]
    return np.column_stack([a for a in (mesh.vertices, mesh.normals, mesh.uvs, welds) if a is not None])


def triangle_set(mesh) -> list:
    """Each triangle as its corners' `vertex_rows`, turned to its least turn, sorted: the same
    triangles in any order and turn give the same list."""
    corners = vertex_rows(mesh)[mesh.faces]  # (T, 3, K)
    turns = np.stack([np.roll(corners, -k, axis=1).reshape(len(corners), -1) for k in range(3)], 1)
    return sorted(min(map(tuple, triangle)) for triangle in turns)


def check_read_as_trimesh_read(path, monkeypatch, sizes, layout, seed=5) -> None:
    """`load_mesh(path)` of `polygons(sizes, seed)` written with `layout` corners: read by numpy,
    as trimesh read it (up to the orders of the module doc), its triangles the file's fans."""
    reference = trimesh_reading(path)
    with monkeypatch.context() as patch:
        patch.setattr(loading, "_trimesh_load", lambda *args, **kwargs: pytest.fail("trimesh was asked"))
        mesh = load_mesh(path)
    for field in ("normals", "uvs", "welds"):
        assert (getattr(mesh, field) is None) == (getattr(reference, field) is None), field
    assert (mesh.normals is None) == ("n" not in layout) and (mesh.uvs is None) == ("t" not in layout)
    assert (mesh.welds is None) == (layout != "a/t")  # split vertices, no normals: welded by `v` line
    assert mesh.n_vertices == reference.n_vertices and mesh.n_faces == reference.n_faces == sum(sizes) - 2 * len(sizes)
    np.testing.assert_array_equal(mesh.vertices, reference.vertices)  # the `v` lines' copies in file order, in both
    if mesh.welds is not None:
        np.testing.assert_array_equal(mesh.welds, reference.welds)
    np.testing.assert_array_equal(np.unique(vertex_rows(mesh), axis=0), np.unique(vertex_rows(reference), axis=0))
    assert triangle_set(mesh) == triangle_set(reference)
    vertices, uvs, normals, faces = polygons(sizes, seed)
    fans = np.array([[face[0], face[k], face[k + 1]] for face in faces for k in range(1, len(face) - 1)])  # (T, 3, 3)
    np.testing.assert_array_equal(mesh.vertices[mesh.faces], vertices[fans[..., 0]])
    if mesh.uvs is not None:
        np.testing.assert_array_equal(mesh.uvs[mesh.faces], uvs[fans[..., 1]])
    if mesh.normals is not None:
        np.testing.assert_array_equal(mesh.normals[mesh.faces], normals[fans[..., 2]])
    if mesh.welds is not None:
        np.testing.assert_array_equal(mesh.welds[mesh.faces], fans[..., 0])


@pytest.mark.parametrize("relative", [False, True], ids=["absolute", "relative"])
@pytest.mark.parametrize("layout", sorted(LAYOUTS))
@pytest.mark.parametrize("shape", sorted(SIZES))
def test_polygon_files_are_read_by_numpy_as_trimesh_read_them(tmp_path, monkeypatch, shape, layout, relative):
    path = tmp_path / "polygons.obj"
    path.write_text(polygon_text(SIZES[shape], layout, relative=float(relative)))
    check_read_as_trimesh_read(path, monkeypatch, SIZES[shape], layout)


@pytest.mark.parametrize("seed", range(12))
def test_random_polygon_files_are_read_by_numpy_as_trimesh_read_them(tmp_path, monkeypatch, seed):
    """3 to 8 faces of 3 to 8 corners at random, each layout in turn, half the indices relative."""
    rng = np.random.default_rng(seed)
    sizes, layout = rng.integers(3, 9, rng.integers(3, 9)).tolist(), sorted(LAYOUTS)[seed % 4]  # 9+ corners: all 8 `v`s
    path = tmp_path / "polygons.obj"
    path.write_text(polygon_text(sizes, layout, relative=0.5, seed=seed))
    check_read_as_trimesh_read(path, monkeypatch, sizes, layout, seed)


def test_a_triangle_file_is_unchanged_by_the_fans(tmp_path):
    """Triangles are their own fans: faces as written, over every `v` line's vertex."""
    path = tmp_path / "t.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\nf 4 3 2\n")
    np.testing.assert_array_equal(load_mesh(path).faces, [[0, 1, 2], [0, 2, 3], [3, 2, 1]])


def test_corners_of_two_layouts_are_left_to_trimesh(tmp_path, monkeypatch):
    """Faces whose corners are not all laid out as the first (`a/t` then `a`): trimesh reads the
    file, as before."""
    path = tmp_path / "two.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1 4/1\nf 1 3 4\n")
    asked = []
    trimesh_load = loading._trimesh_load
    monkeypatch.setattr(loading, "_trimesh_load", lambda *args, **kwargs: asked.append(1) or trimesh_load(*args, **kwargs))
    assert load_mesh(path).n_faces == 3 and asked


def test_absolute_indices_rewrites_each_relative_index_in_place():
    """Each relative `v` / `vt` / `vn` index of an `f` line (a '-' and digits, one of a corner's
    first three numbers, before any '#') becomes the absolute one: 1 + lines of its key above, minus
    k; nothing else changes (`--1`, `-1-`, `1-1`, a fourth number, a comment's, a `v` line's), nor
    any line break. -4 over 3 vertices is 0 and a number past 10^18 counts as 10^18 (both before
    the first line, for the line scan to name)."""
    data = (b"v 0 0 -1\nv 1 0 0\nvt 0 0\nv 1 1 0\nvn 0 0 1\nf -3/-1/-1 -2/1/-1 -1 # -1 stays\nf 1 -1#x\n"
            b"f -0001 --1 -1- 1-1 1/2/3/-1 x/-1\tx -4 -99999999999999999999\nv 2 2 2\nf -1//-1 -2 -3")
    want = (b"v 0 0 -1\nv 1 0 0\nvt 0 0\nv 1 1 0\nvn 0 0 1\nf 1/1/1 2/1/1 3 # -1 stays\nf 1 3#x\n"
            b"f 3 --1 -1- 1-1 1/2/3/-1 x/1\tx 0 -999999999999999996\nv 2 2 2\nf 4//1 3 2")
    assert obj_text.absolute_indices(data, *obj_text.line_keys(data)) == want


def test_a_carriage_return_leaves_relative_indices_relative_to_the_lines_above(tmp_path):
    """A lone CR (here in a comment) ends a line, as in an old Mac file, and the `b` after it is no
    plain line: the file goes to the line scan and trimesh; its relative indices are still made
    absolute first. Before, they were not, and trimesh counted them from the
    end of the file: the first triangle landed on the second's vertices."""
    path = tmp_path / "cr.obj"
    path.write_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 5 5 5\nv 6 5 5\nv 5 6 5\nf 4 5 6\n# a\rb\n")
    mesh = load_mesh(path)
    np.testing.assert_array_equal(mesh.vertices[mesh.faces], [[[0, 0, 0], [1, 0, 0], [0, 1, 0]],
                                                              [[5, 5, 5], [6, 5, 5], [5, 6, 5]]])


@pytest.mark.parametrize("face, message", [
    ("f 1 2 3 9", "face index 9 out of range \\(file has 4 vertices\\)"),
    ("f 1 2 -5 3", "face index -5 out of range \\(file has 4 vertices\\)"),
    ("f 1 2 3 0", "face index 0 is invalid \\(OBJ is 1-based\\)"),
    ("f 1 2 3 4x", "cannot parse face index '4x'"),
    ("f 1 2 3 /4", "cannot parse face index '/4'"),
    ("f 1 2", "face needs at least 3 vertices: 'f 1 2'"),
])
def test_a_bad_polygon_face_is_named_with_its_line(tmp_path, face, message):
    """After a good quad, a bad face names the file, its line and the index as written."""
    path = tmp_path / "bad.obj"
    path.write_text(f"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n{face}\n")
    with pytest.raises(MeshError, match=rf"^{path}:6: {message}"):
        load_mesh(path)
