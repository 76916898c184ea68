"""OBJ text read with numpy: lines classified by their key, `v` / `vt` / `vn` / `f` lines parsed by
numpy's C text reader, no Python loop per line.

`read_obj(data)` gives an `ObjText`: whether the text is in the *plain* layout that `load_mesh`
hands to trimesh without first checking it line by line (only `v x y z` lines of numbers, triangle
`f` lines of positive indices, comments and `vn` / `vt` / `o` / `g` / `s` / `usemtl` / `mtllib`
lines), its counts of `v` and `f` lines, whether its `v` lines all parse, and, for the common
layouts, the mesh arrays themselves: the mesh trimesh's OBJ loader gives (`process=False`,
`maintain_order=False`). Those layouts are every `f` line a triangle with corners `a`, `a/t`,
`a//n` or `a/t/n` as its first line has them, indices positive and in range, `vn` lines of 3
numbers, `vt` lines of 2 or 3, at most one `usemtl` line (before the faces), no line
continuations. With `a` corners the faces are kept as written over every vertex; with uv or
normal indices, each distinct (v, t, n) a corner uses is one vertex (`unmerged`: a vertex met with
two uvs, at a uv seam, or two normals, at a crease, is split), as trimesh's `unmerge_faces` does
-- the same triangles, corner by corner, though the two may order the vertices differently.
Anything else (polygons, several materials, an index past its list) gives no arrays, and trimesh
reads the file. Negative (relative) indices are made absolute first (`absolute_indices`), for
every reader.
"""

from __future__ import annotations

import dataclasses
import io
import math
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
MAX_TUPLE_KEY = 2 ** 62  # `unmerged` numbers (v, vt, vn) tuples by one int64 below this, else sorts rows


@dataclass(frozen=True)
class ObjText:
    """What `read_obj` found: `plain` (see the module doc), the numbers of `v` and `f` lines, whether
    the `v` lines parse as 3 numbers each (plain text only), and (vertices, faces, normals or None,
    uvs or None, welds or None) as trimesh reads them (welds: each vertex's `v` index, 0-based, where
    vertices were split), or None; `data`: the text read (CRLF as LF, indices made absolute:
    `absolute_indices`), which trimesh reads where these arrays are None."""

    plain: bool
    n_vertex_lines: int
    n_face_lines: int
    vertices_parse: bool = False
    arrays: tuple | None = None
    data: bytes = b""


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
    """Classify and, where it can, read OBJ text (see the module doc); relative indices are made
    absolute first (`absolute_indices`), and the text read is the result's `data`."""
    data = data.replace(b"\r\n", b"\n") if b"\r" in data else data
    if b"\r" in data:  # a carriage return inside a line: checked line by line
        return ObjText(False, 0, 0, data=data)
    keys = line_keys(data)
    if b"-" in key_lines(data, *keys, F)[0]:
        data = absolute_indices(data, *keys)
        keys = line_keys(data)
    return dataclasses.replace(_classify(data, *keys), data=data)


def _classify(data: bytes, starts, ends, code) -> ObjText:
    """`read_obj` of text without CR, split into lines (`line_keys`)."""
    if not code.size or (code == OTHER).any() or np.count_nonzero(np.diff(code)) >= MAX_RUNS:
        return ObjText(False, 0, 0)
    vertex_text, n_vertices = key_lines(data, starts, ends, code, V)
    face_text, n_faces = key_lines(data, starts, ends, code, F)
    if not (n_faces and plain_lines(vertex_text, n_vertices, KEYS[V], VERTEX_CHARS)
            and plain_lines(face_text, n_faces, KEYS[F], FACE_CHARS)):
        return ObjText(False, n_vertices, n_faces)
    vertices = table(vertex_text, KEYS[V], np.float64)
    parse = vertices is not None and vertices.shape == (n_vertices, 3)
    usemtl = np.flatnonzero(code == USEMTL)
    corners = None  # continuations, tabs or several materials: trimesh reads the file
    if not (b"\\" in data or b"\t" in data or usemtl.size > 1 or data.count(b"usemtl") != usemtl.size
            or (usemtl.size and usemtl[0] > np.argmax(code == F))):
        corners = table(face_text, KEYS[F], np.int64)
    first_corner = face_text.split(b" ", 2)[1]
    per_corner = len(first_corner.replace(b"/", b" ").split())
    if corners is None or corners.shape[1] != 3 * per_corner:
        return ObjText(not has_zero_index(face_text), n_vertices, n_faces, parse)
    if (corners[:, ::per_corner] == 0).any():  # vertex index 0: not OBJ, the line scan names it
        return ObjText(False, n_vertices, n_faces)
    sample = face_text.split(b"\n", 1)[0][2:]  # trimesh reads the corners' layout off the first face line
    arrays = mesh_arrays(data, starts, ends, code, vertices, corners, sample) if parse else None
    return ObjText(True, n_vertices, n_faces, parse, arrays)


def mesh_arrays(data: bytes, starts, ends, code, vertices: np.ndarray, corners: np.ndarray, sample: bytes):
    """(vertices, faces, normals or None, uvs or None, welds or None) of plain OBJ text as trimesh
    reads it (welds: `unmerged`'s, each vertex's `v` index, None where no vertex is split), or
    None outside the layouts of the module doc. `vertices`: the `v` lines' (N, 3) numbers;
    `corners`: the `f` lines' numbers, a row each."""
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
    uv_table = None if uv_table is None else uv_table[:, :2]
    used = {name: (index, values) for name, index, values in (("normals", norm, normal_table), ("uvs", tex, uv_table))
            if index is not None and values is not None}
    if not used:
        return vertices, faces, None, None, None  # every vertex, no normals or uvs
    if any(index.max() >= len(values) for index, values in used.values()):
        return None  # trimesh drops that attribute: let it read the file
    welds, faces, *values = unmerged(vertices, faces, list(used.values()))
    found = dict(zip(used, values))
    normals, uvs = (found.get(name) for name in ("normals", "uvs"))
    finite = [None if a is None or not np.all(np.isfinite(a)) else a for a in (normals, uvs)]  # else dropped
    return (vertices[welds], faces, *finite, welds)


def absolute_indices(data: bytes, starts, ends, code) -> bytes:
    """OBJ text (split into lines by `line_keys`) with every negative (relative) index of its `f`
    lines made the absolute one it names -- a corner's `v`, `vt` and `vn` index alike: -1 is the
    last line of that key above the face --, so that every reader (numpy's, trimesh's,
    `fan_corners`) sees the faces of the same file with positive indices (trimesh counts relative
    indices from the end of the file). Only the `f` lines holding a '-' change (their comments kept,
    line breaks kept: line numbers still name the file's lines); an index before the first line
    stays <= 0, for the line scan to name. (A Python loop over those lines: ~8 us a face.)"""
    above = np.stack([np.cumsum(code == key) for key in (V, VT, VN)], axis=1) + 1  # per line: 1 + lines of each key
    pieces, done = [], 0
    for line in np.flatnonzero(code == F):
        body, hash_, comment = data[starts[line]:ends[line]].partition(b"#")
        if b"-" not in body:
            continue
        base = above[line].tolist()
        corners = [corner if b"-" not in corner else b"/".join(
            b"%d" % (base[k] + int(part)) if k < 3 and part[:1] == b"-" and part[1:].isdigit() else part
            for k, part in enumerate(corner.split(b"/"))) for corner in body[2:].split()]
        pieces += [data[done:starts[line]], b"f " + b" ".join(corners) + (b" " + hash_ + comment if hash_ else b"")]
        done = ends[line]
    return b"".join(pieces) + data[done:]


def fan_corners(data: bytes) -> np.ndarray | None:
    """(T, 3) int64: each corner's `v` index (0-based) of the triangles OBJ text's `f` lines make, in
    file order, a polygon a b c d ... as the fan (a, b, c), (a, c, d), ... (trimesh's triangulation);
    indices absolute (`absolute_indices`). None where a corner does not parse, is not positive, or a
    face has fewer than 3 corners."""
    data = data.replace(b"\r\n", b"\n")
    starts, ends, code = line_keys(data)
    face_text, n_faces = key_lines(data, starts, ends, code, F)
    if not n_faces:
        return None
    tokens = np.array(re.sub(rb"/\S*|#[^\n]*", b"", face_text).split())  # keys and vertex indices
    is_key = tokens == b"f"
    try:
        index = tokens[~is_key].astype(np.int64) - 1
    except ValueError:
        return None
    face = np.cumsum(is_key)[~is_key] - 1  # each corner's face line
    counts = np.bincount(face, minlength=n_faces)
    if counts.min() < 3 or index.min() < 0:
        return None
    first = np.cumsum(counts) - counts  # each face's first corner
    fans = counts - 2
    owner = np.repeat(np.arange(n_faces), fans)
    step = np.arange(owner.size) - np.repeat(np.cumsum(fans) - fans, fans) + 1  # 1 .. k-2 within a face
    return np.stack([index[first[owner]], index[first[owner] + step], index[first[owner] + step + 1]], axis=1)


def unmerged(vertices: np.ndarray, faces: np.ndarray, attributes: list) -> list:
    """[welds, faces, *values]: one vertex per distinct (vertex, attribute indices...) tuple the
    faces' corners use, rows in the order of those tuples (vertices in file order, a split vertex's
    copies side by side), a vertex no face uses dropped; `welds` is each one's index in `vertices`
    (its positions: `vertices[welds]`). `attributes`: (index per corner (F, 3),
    values) pairs, e.g. the corners' `vt` indices and the uv table. The tuples are told apart by
    one int64 each, their index in the grid of all tuples (sorting one column is ~3x faster than
    sorting rows), or by rows where that grid is too big for int64."""
    columns = [faces.ravel()] + [index.ravel() for index, _ in attributes]
    sizes = [len(vertices)] + [len(values) for _, values in attributes]
    if math.prod(sizes) < MAX_TUPLE_KEY:
        keys, inverse = np.unique(np.ravel_multi_index(columns, sizes), return_inverse=True)
        rows = np.unravel_index(keys, sizes)
    else:
        keys, inverse = np.unique(np.column_stack(columns), axis=0, return_inverse=True)
        rows = keys.T
    return [rows[0], inverse.reshape(faces.shape)] + [values[rows[k]]
                                                                for k, (_, values) in enumerate(attributes, 1)]
