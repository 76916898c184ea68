"""OBJ text read with numpy: lines classified by their key, `v` / `vt` / `vn` / `f` lines parsed by
numpy's C text reader, no Python loop per line.

`read_obj(data)` gives an `ObjText`: whether the text is in the *plain* layout that `load_mesh`
hands to trimesh without first checking it line by line (only `v x y z` lines of numbers, triangle
`f` lines of positive indices, comments and `vn` / `vt` / `o` / `g` / `s` / `usemtl` / `mtllib`
lines), its counts of `v` and `f` lines, and, for the common layouts, the mesh arrays themselves:
what trimesh's OBJ loader gives (`process=False, maintain_order=True`), computed as it computes
them. Those layouts are every `f` line a triangle with corners `a`, `a/t`, `a//n` or `a/t/n` as
its first line has them, indices positive and in range, `vn` lines of 3 numbers, `vt` lines of 2
or 3, at most one `usemtl` line (before the faces), no line continuations. There trimesh keeps the
faces as written and the vertices up to the largest one used; a corner's `t` / `n` indices give
each vertex one uv / normal: per corner column the last face using the vertex, and the median of
the (up to three) columns, rounded down (`trimesh.visual.texture.unmerge_faces`). Anything else
(quads, negative indices, several materials, a vertex that no face uses before the last used one,
an index past its list) gives no arrays, and trimesh reads the file.
"""

from __future__ import annotations

import io
import re
import warnings
from dataclasses import dataclass

import numpy as np

VERTEX_CHARS = b"0123456789.eE+- \n"  # `v x y z` lines, besides their key
FACE_CHARS = b"0123456789/ \n"  # `f a b c` lines with positive indices, besides their key
KEYS = (b"v ", b"vn ", b"vt ", b"f ", b"#", b"o ", b"g ", b"s ", b"usemtl ", b"mtllib ")  # the plain layout's
V, VN, VT, F, USEMTL = 0, 1, 2, 3, 8  # their indices in KEYS
BLANK, OTHER = len(KEYS), len(KEYS) + 1  # empty lines; lines with any other start
MAX_RUNS = 100_000  # runs of consecutive lines of one key gathered one slice each; more: not plain
SLASH_TO_SPACE = bytes.maketrans(b"/", b" ")


@dataclass(frozen=True)
class ObjText:
    """What `read_obj` found: `plain` (see the module doc), the numbers of `v` and `f` lines, and
    (vertices, faces, normals or None, uvs or None) as trimesh reads them, or None."""

    plain: bool
    n_vertex_lines: int
    n_face_lines: int
    arrays: tuple | None = None


def line_keys(data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per line of `data` (split at newlines), its first and past-last byte and its key's index
    in KEYS (BLANK, OTHER). A key is told by the line's first four bytes (the longer two are
    checked whole)."""
    buf = np.frombuffer(data, np.uint8)
    newlines = np.flatnonzero(buf == ord("\n"))
    starts = np.concatenate([[0], newlines + 1])
    ends = np.concatenate([newlines, [len(data)]])
    if starts[-1] == len(data):  # a final newline ends the last line, it does not start one
        starts, ends = starts[:-1], ends[:-1]
    padded = np.frombuffer(data + b"\n" * 4, np.uint8)
    head = np.zeros(starts.size, np.uint32)  # the first four bytes, little-endian
    for k in range(4):
        head |= padded[starts + k].astype(np.uint32) << np.uint32(8 * k)
    code = np.full(starts.size, OTHER, np.int8)
    for index, key in enumerate(KEYS):  # no key is the start of another
        prefix = key[:4]
        code[(head & np.uint32((1 << 8 * len(prefix)) - 1)) == int.from_bytes(prefix, "little")] = index
        if len(key) > 4:
            for line in np.flatnonzero(code == index):
                if data[starts[line]:starts[line] + len(key)] != key:
                    code[line] = OTHER
    code[starts == ends] = BLANK
    return starts, ends, code


def key_lines(data: bytes, starts, ends, code, key: int) -> tuple[bytes, int]:
    """The lines with key KEYS[key], joined by newlines, and their count."""
    lines = np.flatnonzero(code == key)
    if not lines.size:
        return b"", 0
    breaks = np.flatnonzero(np.diff(lines) > 1)  # runs of consecutive lines: a slice each
    first = lines[np.concatenate([[0], breaks + 1])]
    last = lines[np.concatenate([breaks, [lines.size - 1]])]
    view = memoryview(data)
    return b"\n".join(view[starts[a]:ends[b]] for a, b in zip(first, last)), int(lines.size)


def plain_lines(text: bytes, count: int, key: bytes, chars: bytes) -> bool:
    """Whether `count` lines of `text` with key `key` are that key and three numbers (or corners)
    of `chars` separated by single spaces."""
    return (not text.translate(None, chars + key[:1]) and text.count(key[:1]) == count and b"  " not in text
            and text.count(b" ") == 3 * count)


def has_zero_index(face_text: bytes) -> bool:
    """Whether a vertex index (a corner's first number) of these plain face lines is 0."""
    text = b" " + face_text.replace(b"\n", b" ") + b" "
    if b" 00" in text:  # leading zeros: the regex (rare; slower)
        return re.search(rb" 0+[ /]", text) is not None
    return b" 0 " in text or b" 0/" in text


def table(text: bytes, key: bytes, dtype) -> np.ndarray | None:
    """Lines of `key` and whitespace-separated numbers ('/' counts as a space) as a 2-D array, a
    row per line; None where there are none, a number does not parse or the rows differ in length."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # "input contained no data", for lines of keys alone
            return np.loadtxt(io.BytesIO(text.translate(SLASH_TO_SPACE, key.strip())), dtype=dtype, comments=None,
                              ndmin=2)
    except (ValueError, UserWarning):
        return None


def read_obj(data: bytes) -> ObjText:
    """Classify and, where it can, read OBJ text (see the module doc)."""
    data = data.replace(b"\r\n", b"\n") if b"\r" in data else data
    if b"\r" in data:  # a carriage return inside a line: checked line by line
        return ObjText(False, 0, 0)
    starts, ends, code = line_keys(data)
    if not code.size or (code == OTHER).any() or np.count_nonzero(np.diff(code)) >= MAX_RUNS:
        return ObjText(False, 0, 0)
    vertex_text, n_vertices = key_lines(data, starts, ends, code, V)
    face_text, n_faces = key_lines(data, starts, ends, code, F)
    if not (n_faces and plain_lines(vertex_text, n_vertices, KEYS[V], VERTEX_CHARS)
            and plain_lines(face_text, n_faces, KEYS[F], FACE_CHARS)):
        return ObjText(False, n_vertices, n_faces)
    usemtl = np.flatnonzero(code == USEMTL)
    corners = None  # continuations, tabs or several materials: trimesh reads the file
    if not (b"\\" in data or b"\t" in data or usemtl.size > 1 or data.count(b"usemtl") != usemtl.size
            or (usemtl.size and usemtl[0] > np.argmax(code == F))):
        corners = table(face_text, KEYS[F], np.int64)
    first_corner = face_text.split(b" ", 2)[1]
    per_corner = len(first_corner.replace(b"/", b" ").split())
    if corners is None or corners.shape[1] != 3 * per_corner:
        return ObjText(not has_zero_index(face_text), n_vertices, n_faces)
    if (corners[:, ::per_corner] == 0).any():  # vertex index 0: not OBJ, the line scan names it
        return ObjText(False, n_vertices, n_faces)
    sample = face_text.split(b"\n", 1)[0][2:]  # trimesh reads the corners' layout off the first face line
    return ObjText(True, n_vertices, n_faces, mesh_arrays(data, starts, ends, code, vertex_text, corners, sample))


def mesh_arrays(data: bytes, starts, ends, code, vertex_text: bytes, corners: np.ndarray, sample: bytes):
    """(vertices, faces, normals or None, uvs or None) of plain OBJ text as trimesh reads it, or
    None outside the layouts of the module doc. `corners`: the `f` lines' numbers, a row each."""
    vertices = table(vertex_text, KEYS[V], np.float64)
    if vertices is None or vertices.shape[1] != 3:
        return None
    per_corner = corners.shape[1] // 3
    corners = np.where(corners > 0, corners - 1, corners)  # 1-based (a 0 tex / normal index stays 0, as in trimesh)
    faces = corners[:, ::per_corner]
    if faces.max() >= len(vertices):
        return None
    tex = norm = None
    if per_corner == 3:
        tex, norm = corners[:, 1::3], corners[:, 2::3]
    elif per_corner == 2:  # `a//n` or `a/t`: trimesh counts the inner slashes of the first line
        inner = b"".join(corner.strip(b"/") for corner in sample.split()).count(b"/")
        if inner == 6:
            norm = corners[:, 1::2]
        elif inner == 3:
            tex = corners[:, 1::2]
        else:
            return None
    vn_text, n_vn = key_lines(data, starts, ends, code, VN)
    vt_text, n_vt = key_lines(data, starts, ends, code, VT)
    normal_table = table(vn_text, KEYS[VN], np.float64)
    uv_table = table(vt_text, KEYS[VT], np.float64)
    if (n_vn and (normal_table is None or normal_table.shape[1] != 3)) \
            or (n_vt and (uv_table is None or uv_table.shape[1] not in (2, 3))):
        return None
    if tex is None and (norm is None or normal_table is None):
        return vertices, faces, None, None  # every vertex, no normals or uvs
    n_used = int(faces.max()) + 1
    normals = uvs = None
    if norm is not None and normal_table is not None:
        normals = per_vertex(faces, norm, n_used, normal_table)
        if normals is None:
            return None
    if tex is not None and uv_table is not None:
        uvs = per_vertex(faces, tex, n_used, uv_table[:, :2])
        if uvs is None:
            return None
    finite = [None if a is None or not np.all(np.isfinite(a)) else a for a in (normals, uvs)]  # else dropped
    return (vertices[:n_used], faces, *finite)


def per_vertex(faces: np.ndarray, index: np.ndarray, n_vertices: int, values: np.ndarray) -> np.ndarray | None:
    """values[k] for each vertex, k from the corners that use it as trimesh's `unmerge_faces`
    (maintain_faces=True) picks it: per corner column the last face's index, then the median of
    the columns that have one (two: their mean, rounded down). None where a vertex has none or an
    index is past `values` (trimesh then drops the attribute: let it read the file)."""
    masks = np.full((3, n_vertices), -1, np.int64)
    for column in range(3):
        masks[column][faces[:, column]] = index[:, column]
    count = (masks >= 0).sum(axis=0)
    ordered = np.sort(np.where(masks >= 0, masks, np.iinfo(np.int64).max), axis=0)
    pick = np.where(count == 3, ordered[1], np.where(count == 2, (ordered[0] + ordered[1]) // 2, ordered[0]))
    if (count == 0).any() or pick.max() >= len(values):
        return None
    return values[pick]
