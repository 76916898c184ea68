"""A file's normal is a direction, as a mesh's `normals` inline in a scene are: an OBJ `vn` line
that is zero-length or not finite is a `MeshError` naming the file, the line and its text, on
every reading -- numpy's (a plain triangle file), trimesh's after the vectorised check (several
materials) and trimesh's after the line scan (a tab) --, used by a face or not; a PLY's zero or
non-finite normal names the file and the vertex."""

import re

import numpy as np
import pytest

import difflab
from difflab.errors import MeshError, SceneError
from difflab.geometry import load_mesh, loading
from difflab.geometry.obj_text import read_obj
from conftest import scene_dict

SQUARE = "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n"  # lines 1-4; the square [-1, 1]^2 at z = 0, facing +z
READINGS = {  # the faces after `vn {bad}` (line 5) and `vn 0 0 1` (line 6), and whether numpy reads them
    "numpy": ("f 1//2 2//2 3//1\nf 1//2 3//2 4//2\n", True),
    "several materials": ("usemtl a\nf 1//2 2//2 3//1\nusemtl b\nf 1//2 3//2 4//2\n", False),
    "a tab": ("f 1//2 2//2 3//1\nf 1//2\t3//2 4//2\n", False),
}
BAD = {"0 0 0": "zero-length \\(a normal is a direction\\)", "-0 0.0 0e5": "zero-length \\(a normal is a direction\\)",
       "nan 0 1": "not finite", "0 inf 0": "not finite", "0 0 -inf": "not finite"}


def square_obj(normal: str, reading: str, *, used: bool = True) -> str:
    """The square with `vn normal` on line 5 and `vn 0 0 1` on line 6; `used`: a corner uses line
    5's normal, else none does."""
    faces, _ = READINGS[reading]
    return SQUARE + f"vn {normal}\nvn 0 0 1\n" + (faces if used else faces.replace("3//1", "3//2"))


@pytest.mark.parametrize("reading", sorted(READINGS))
def test_valid_normals_are_the_files_on_each_reading(tmp_path, monkeypatch, reading):
    """The control: with `vn 0 0 2` the file loads (trimesh asked only where numpy cannot read it),
    its two triangles, every corner with its file normal's direction, +z."""
    path = tmp_path / "square.obj"
    path.write_text(square_obj("0 0 2", reading))
    asked = []
    trimesh_load = loading._trimesh_load
    monkeypatch.setattr(loading, "_trimesh_load", lambda *args, **kw: asked.append(1) or trimesh_load(*args, **kw))
    mesh = load_mesh(path)
    assert (read_obj(path.read_bytes()).arrays is not None) == READINGS[reading][1] == (not asked)
    triangles = {frozenset(map(tuple, corners)) for corners in mesh.vertices[mesh.faces].tolist()}
    assert mesh.n_faces == 2 and triangles == {frozenset([(-1, -1, 0), (1, -1, 0), (1, 1, 0)]),
                                               frozenset([(-1, -1, 0), (1, 1, 0), (-1, 1, 0)])}
    corner_normals = mesh.normals[mesh.faces]
    directions = corner_normals / np.linalg.norm(corner_normals, axis=-1, keepdims=True)
    np.testing.assert_allclose(directions, np.broadcast_to([0.0, 0.0, 1.0], (2, 3, 3)), atol=1e-15)


@pytest.mark.parametrize("used", [True, False], ids=["used", "unused"])
@pytest.mark.parametrize("normal", sorted(BAD))
@pytest.mark.parametrize("reading", sorted(READINGS))
def test_a_zero_or_nonfinite_vn_line_is_named_on_each_reading(tmp_path, reading, normal, used):
    path = tmp_path / "square.obj"
    path.write_text(square_obj(normal, reading, used=used))
    with pytest.raises(MeshError, match=rf"^{re.escape(str(path))}:5: normal 1 is {BAD[normal]}: 'vn {normal}'$"):
        load_mesh(path)


def test_a_zero_file_normal_fails_the_scene_as_an_inline_one_does(tmp_path):
    """The same data, from a file and inline: each refused, naming the normal; with the file's
    zero normal made (0, 0, 1), the square renders lit (kd cos 0 = 0.8) on every covered pixel."""
    path = tmp_path / "square.obj"
    light = [{"type": "directional", "direction": [0, 0, -1], "intensity": [1, 1, 1]}]

    def render(mesh):
        return difflab.render(scene_dict([{"type": "mesh", "material": "m", **mesh}], {"m": {"kd": [0.8, 0.8, 0.8]}},
                                         lights=light, render={"shading": "phong"}))

    path.write_text(square_obj("0 0 0", "numpy"))
    with pytest.raises(MeshError, match=rf"^objects\[0\] \(.*\): {re.escape(str(path))}:5: normal 1 is zero-length"):
        render({"file": str(path)})
    inline = {"vertices": [[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], "faces": [[0, 1, 2], [0, 2, 3]],
              "normals": [[0, 0, 1], [0, 0, 1], [0, 0, 0], [0, 0, 1]]}
    with pytest.raises(SceneError, match=r"^objects\[0\]\.normals\[2\]: must not be zero-length"):
        render(inline)
    path.write_text(square_obj("0 0 1", "numpy"))
    image = render({"file": str(path)})
    np.testing.assert_allclose(image[2:30, 2:30], 0.8, atol=1e-6)  # inside the square (32 px over [-1, 1])


@pytest.mark.parametrize("normal", ["0 0 0", "nan 0 1"])
def test_a_ply_normal_that_is_no_direction_names_the_file_and_vertex(tmp_path, normal):
    path = tmp_path / "tri.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 3\n" + "".join(f"property float {c}\n" for c in
                                                                         ("x", "y", "z", "nx", "ny", "nz"))
                    + "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    + f"0 0 0 0 0 1\n1 0 0 {normal}\n0 1 0 0 0 1\n3 0 1 2\n")
    with pytest.raises(MeshError, match=rf"^{re.escape(str(path))}: vertex 1's normal \[.*\] is not a direction"):
        load_mesh(path)
