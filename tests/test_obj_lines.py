"""How OBJ text is split into lines and what a line holds: CR (old Mac), LF and CR LF end a line
alike; a comment runs from a '#' anywhere on a line to its end. Each is checked on both readings --
numpy's (the plain layout) and trimesh's (here: two materials) -- against the same file written
with LF ends and no comments, and a bad line is still named by its number in the file."""

import re

import numpy as np
import pytest

from difflab.errors import MeshError
from difflab.geometry import load_mesh, loading
from difflab.geometry.obj_text import read_obj

#: A quad (two uvs a corner, so the numpy path splits nothing) and a triangle, uvs and normals.
LINES = ["v -1 -1 0", "v 1 -1 0", "v 1 1 0", "v -1 1 0", "v 0 2 0",
         "vt 0 0", "vt 1 0", "vt 1 1", "vt 0 1", "vn 0 0 1", "vn 0 0.6 0.8"]
FACES = {"numpy": ["f 1/1/1 2/2/1 3/3/1 4/4/1", "f 4/4/2 3/3/2 5/2/2"],
         "trimesh": ["usemtl a", "f 1/1/1 2/2/1 3/3/1 4/4/1", "usemtl b", "f 4/4/2 3/3/2 5/2/2"]}
ENDS = {"LF": "\n", "CR": "\r", "CRLF": "\r\n"}


def obj_bytes(lines, end="\n") -> bytes:
    return (end.join(lines) + end).encode()


def reference(tmp_path, reading):
    path = tmp_path / "reference.obj"
    path.write_bytes(obj_bytes(LINES + FACES[reading]))
    return load_mesh(path)


def assert_same_mesh(got, want):
    for a, b in [(got.vertices, want.vertices), (got.faces, want.faces), (got.normals, want.normals),
                 (got.uvs, want.uvs), (got.welds, want.welds)]:
        assert (a is None) == (b is None) and (a is None or np.array_equal(a, b))


def triangles(mesh) -> list:
    """Each triangle's corners (position, uv, normal), turned to start at its least, all sorted: the
    mesh as it renders, whatever the order and turn of its triangles."""
    corners = np.concatenate([mesh.vertices, mesh.uvs, mesh.normals], axis=1)[mesh.faces].tolist()
    return sorted(min(t[k:] + t[:k] for k in range(3)) for t in ([tuple(c) for c in tri] for tri in corners))


def who_reads(monkeypatch) -> list:
    """A list that gets an entry each time trimesh is asked to read a file."""
    asked = []
    trimesh_load = loading._trimesh_load
    monkeypatch.setattr(loading, "_trimesh_load", lambda *args, **kw: asked.append(1) or trimesh_load(*args, **kw))
    return asked


@pytest.mark.parametrize("end", sorted(ENDS))
@pytest.mark.parametrize("reading", sorted(FACES))
def test_cr_lf_and_crlf_line_ends_read_the_same_mesh(tmp_path, monkeypatch, reading, end):
    """The reference (LF) is 3 triangles over 7 vertices with the file's uvs and normals; CR and
    CR LF files give it bitwise, on the same reader. Before, a CR-only file was one line."""
    want = reference(tmp_path, reading)
    assert want.n_faces == 3 and want.n_vertices == 7  # v 3 and v 4 met with two normals
    corners = want.vertices[want.faces]  # (3, 3, 3)
    uv_at = {(-1, -1): (0, 0), (1, -1): (1, 0), (1, 1): (1, 1), (-1, 1): (0, 1), (0, 2): (1, 0)}
    np.testing.assert_array_equal(want.uvs[want.faces], [[uv_at[tuple(p[:2])] for p in t] for t in corners.tolist()])
    top = (corners[:, :, 1] == 2).any(axis=1)[:, None, None]  # the triangle at v 5 has the second normal
    np.testing.assert_array_equal(want.normals[want.faces], np.where(top, [0, 0.6, 0.8], [0.0, 0, 1]).repeat(3, 1))
    path = tmp_path / "m.obj"
    path.write_bytes(obj_bytes(LINES + FACES[reading], ENDS[end]))
    asked = who_reads(monkeypatch)
    assert_same_mesh(load_mesh(path), want)
    assert bool(asked) == (reading == "trimesh") == (read_obj(path.read_bytes()).arrays is None)


@pytest.mark.parametrize("end", sorted(ENDS))
@pytest.mark.parametrize("reading", sorted(FACES))
def test_a_bad_face_in_a_cr_file_is_named_by_its_line(tmp_path, reading, end):
    path = tmp_path / "bad.obj"
    lines = LINES + FACES[reading] + ["f 1 2 9"]
    path.write_bytes(obj_bytes(lines, ENDS[end]))
    with pytest.raises(MeshError, match=rf"^{re.escape(str(path))}:{len(lines)}: face index 9 out of range "
                                        r"\(file has 5 vertices\)$"):
        load_mesh(path)


def commented(lines):
    """`lines` with a comment after each, in turn a '# ...' after a blank, a '#' right after the
    last number and one after a tab, and comment lines between them."""
    tails = [" # a comment", "#tight", "\t# tab # twice"]
    return [line + tails[k % 3] for k, line in enumerate(lines)] + ["# a comment line", "   # an indented one"]


@pytest.mark.parametrize("reading", sorted(FACES))
def test_a_comment_anywhere_on_a_line_is_ignored(tmp_path, monkeypatch, reading):
    """Every `v`, `vt`, `vn`, `usemtl` and `f` line with a comment after it reads as without, on the
    same reader. Before, trimesh failed on them (`cannot read mesh: ValueError: ...`)."""
    want = reference(tmp_path, reading)
    path = tmp_path / "m.obj"
    path.write_bytes(obj_bytes(commented(LINES + FACES[reading])))
    asked = who_reads(monkeypatch)
    assert_same_mesh(load_mesh(path), want)
    assert bool(asked) == (reading == "trimesh")


@pytest.mark.parametrize("reading", sorted(FACES))
def test_a_bad_line_after_comments_is_named_by_its_line_without_the_comment(tmp_path, reading):
    path = tmp_path / "bad.obj"
    lines = commented(LINES + FACES[reading]) + ["f 1 2 9 # out of range"]
    path.write_bytes(obj_bytes(lines))
    with pytest.raises(MeshError, match=rf"^{re.escape(str(path))}:{len(lines)}: face index 9 out of range "
                                        r"\(file has 5 vertices\)$"):
        load_mesh(path)
    lines[2] = "v 1 nan 0 # not finite"
    path.write_bytes(obj_bytes(lines))
    with pytest.raises(MeshError, match=rf"^{re.escape(str(path))}:3: vertex 3 is not finite: 'v 1 nan 0'$"):
        load_mesh(path)


#: A `vn` line (line 10, normal 1) that is not 3 numbers, and its message after the file and line.
BAD_VN = {"vn 0 1": "normal 1 needs 3 numbers \\(vn x y z\\), got 2: 'vn 0 1'",
          "vn 0 0 1 5": "normal 1 needs 3 numbers \\(vn x y z\\), got 4: 'vn 0 0 1 5'",
          "vn": "normal 1 needs 3 numbers \\(vn x y z\\), got 0: 'vn'",
          "vn 0 1 0 extra": "cannot parse normal 1: 'vn 0 1 0 extra'",
          "vn 0 x 1": "cannot parse normal 1: 'vn 0 x 1'"}
#: A `vt` line (line 6, uv 1) that is not 1 to 3 finite numbers, and its message.
BAD_VT = {"vt": "uv 1 needs 1 to 3 numbers \\(vt u \\[v\\] \\[w\\]\\), got 0: 'vt'",
          "vt 0 0 0 0": "uv 1 needs 1 to 3 numbers \\(vt u \\[v\\] \\[w\\]\\), got 4: 'vt 0 0 0 0'",
          "vt 0 y": "cannot parse uv 1: 'vt 0 y'",
          "vt nan 0": "uv 1 is not finite: 'vt nan 0'", "vt 0 inf": "uv 1 is not finite: 'vt 0 inf'",
          "vt 0 0 -inf": "uv 1 is not finite: 'vt 0 0 -inf'", "vt NaN 1 # c": "uv 1 is not finite: 'vt NaN 1'"}


@pytest.mark.parametrize("used", [True, False], ids=["used", "unused"])
@pytest.mark.parametrize("bad", sorted(BAD_VN) + sorted(BAD_VT))
@pytest.mark.parametrize("reading", sorted(FACES))
def test_a_vn_or_vt_line_that_is_no_normal_or_uv_is_named(tmp_path, reading, bad, used):
    """As a `v` line that is not 3 numbers or not finite is refused with its line, so is a `vn` line
    that is not exactly 3 numbers and a `vt` line that is not 1 to 3 finite numbers, used by a face or
    not. Before, trimesh failed on some (`cannot read mesh`), and the others read as a mesh without
    normals or uvs -- a textured object without its texture, a smooth one with its creases lost."""
    line, message = (10, BAD_VN[bad]) if bad.startswith("vn") else (6, BAD_VT[bad])
    lines = LINES.copy()
    lines[line - 1] = bad
    faces = [face if used else re.sub(r"/1\b", "/2", face) for face in FACES[reading]]  # unused: uv 2, normal 2
    assert bool(re.search(r"/1\b", " ".join(faces))) == used
    path = tmp_path / "bad.obj"
    path.write_bytes(obj_bytes(lines + faces))
    with pytest.raises(MeshError, match=rf"^{re.escape(str(path))}:{line}: {message}$"):
        load_mesh(path)


@pytest.mark.parametrize("short", [(6, 7, 8, 9), (7,)], ids=["all", "one"])
@pytest.mark.parametrize("reading", sorted(FACES))
def test_a_vt_line_of_u_alone_reads_with_v_0(tmp_path, reading, short):
    """The OBJ format's `vt u [v] [w]`: a `vt` line of u alone (all of them, or one among `vt u v`
    lines; blanks or a comment after it) reads as `vt u 0`, on both readings. Before, it was refused
    (`uv 1 needs 2 or 3 numbers`); before that, trimesh read the file without its uvs."""
    lines = LINES.copy()
    for line in short:
        lines[line - 1] = lines[line - 1].rsplit(" ", 1)[0] + " 0"
    want = reference_of(tmp_path, lines + FACES[reading])
    assert want.uvs is not None and (want.uvs[:, 1] == 0).any()
    for line in short:
        lines[line - 1] = lines[line - 1][:-2] + (" \t# u alone" if line == 7 else "")
    path = tmp_path / "short.obj"
    path.write_bytes(obj_bytes(lines + FACES[reading]))
    assert_same_mesh(load_mesh(path), want)


def reference_of(tmp_path, lines):
    path = tmp_path / "want.obj"
    path.write_bytes(obj_bytes(lines))
    return load_mesh(path)


@pytest.mark.parametrize("uv", ["nan 0", "0 inf"])
def test_a_ply_uv_that_is_not_finite_names_the_file_and_vertex(tmp_path, uv):
    path = tmp_path / "tri.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 3\n" + "".join(f"property float {c}\n" for c in "xyzst")
                    + "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    + f"0 0 0 0 0\n1 0 0 {uv}\n0 1 0 0 1\n3 0 1 2\n")
    with pytest.raises(MeshError, match=rf"^{re.escape(str(path))}: vertex 1's uv \[.*\] is not finite$"):
        load_mesh(path)


@pytest.mark.parametrize("reading", sorted(FACES))
def test_a_v_line_with_a_word_after_its_numbers_is_named(tmp_path, reading):
    """A `v` line is 3 numbers, then optionally a weight or a colour (numbers too): a word after
    them is named with its line, as a word among them is. Before, it reached trimesh, which failed
    without a line (`cannot read mesh: ValueError: ...`). With a weight, or a colour, the mesh has
    the reference's triangles (trimesh reads it: their order and turn may differ)."""
    want = triangles(reference(tmp_path, reading))
    path = tmp_path / "m.obj"
    for extra in (" 1", " 0.5 0.25 1"):
        lines = LINES.copy()
        lines[1] += extra
        path.write_bytes(obj_bytes(lines + FACES[reading]))
        assert triangles(load_mesh(path)) == want
    lines[1] = "v 1 -1 0 x"
    path.write_bytes(obj_bytes(lines + FACES[reading]))
    with pytest.raises(MeshError, match=rf"^{re.escape(str(path))}:2: cannot parse vertex 'v 1 -1 0 x'$"):
        load_mesh(path)
