"""OBJ text read with numpy: lines classified by their key, `v` / `vt` / `vn` / `f` lines parsed by
numpy's C text readers, no Python loop per line.

`read_obj(data)` gives an `ObjText`: whether the text is in the *plain* layout that `load_mesh`
hands to a reader without first checking it line by line (only `v x y z` lines of numbers, `f`
lines of 3 or more corners of positive indices separated by single spaces, comments and `vn` /
`vt` / `o` / `g` / `s` / `usemtl` / `mtllib` lines), the number of triangles its `f` lines make,
whether its `v` lines all parse, and, for the common layouts, the mesh arrays themselves: the mesh
trimesh's OBJ loader gives (`process=False`, `maintain_order=False`). Those layouts are every
corner of every `f` line `a`, `a/t`, `a//n` or `a/t/n` as the first corner is, indices in range,
`vn` lines of 3 numbers, `vt` lines of 2 or 3, at most one `usemtl` line (before the faces), no
tabs or line continuations. A face of k corners a b c d ... is the fan of k - 2 triangles
(a, b, c), (a, c, d), ..., faces in file order (`fans`; trimesh makes the same triangles but puts
an all-quad file's second triangles, turned to (c, d, a), after all the first ones, and otherwise
a file's quads after its triangles). With `a` corners the faces index every `v` line's vertex;
with uv or normal indices, each distinct (v, t, n) a corner uses is one vertex (`unmerged`: a
vertex met with two uvs, at a uv seam, or two normals, at a crease, is split), as trimesh's
`unmerge_faces` does -- the same vertices in the same order, though trimesh may order the uvs and
normals of one `v` line's copies differently --, and where there are no normals `welds` gives each
its `v` line. Anything else (several materials, an index past its list, corners of two layouts)
gives no arrays, and trimesh reads the file. Negative (relative) indices are made absolute first
(`absolute_indices`), for every reader. `vn` lines that are not 3 finite numbers, not all 0
(`valid_normals`), and `vt` lines that are not 2 or 3 finite numbers (`valid_uvs`) give no arrays
either: the line scan refuses them, naming the line. A `vt` line of u alone is read as `vt u 0`
(the OBJ format's `vt u [v] [w]`, v and w default 0: `short_uvs_padded`).
"""

from __future__ import annotations

import dataclasses
import io
import math
import re
import warnings
from dataclasses import dataclass

import numpy as np

DIGITS = b"0123456789"
VERTEX_CHARS = DIGITS + b".eE+- \n"  # `v x y z` lines, besides their key
FACE_CHARS = DIGITS + b"/ \n"  # `f a b c ...` lines with positive indices, besides their key
KEYS = (b"v ", b"vn ", b"vt ", b"f ", b"#", b"o ", b"g ", b"s ", b"usemtl ", b"mtllib ")  # the plain layout's
V, VN, VT, F, USEMTL = 0, 1, 2, 3, 8  # their indices in KEYS
BLANK, OTHER = len(KEYS), len(KEYS) + 1  # empty lines; lines with any other start
MAX_RUNS = 100_000  # runs of consecutive lines of one key gathered one slice each; more: not plain
SLASH_TO_SPACE = bytes.maketrans(b"/", b" ")
MAX_TUPLE_KEY = 2 ** 62  # `unmerged` numbers (v, vt, vn) tuples by one int64 below this, else sorts rows
LAYOUTS = {b"#": "a", b"#/#": "a/t", b"#//#": "a//n", b"#/#/#": "a/t/n"}  # a corner's, its numbers as '#'
FAR = 10 ** 18  # `absolute_indices` counts a relative index past it as it (int64 holds it)
INLINE_COMMENT = re.compile(rb"[ \t]*#[^\n]*")  # a comment and the blanks before it (`obj_lines`)
SHORT_UV = re.compile(rb"(?m)^(vt[ \t]+[^ \t\n]+)[ \t]*$")  # a `vt` line of u alone (`short_uvs_padded`)


@dataclass(frozen=True)
class ObjText:
    """What `read_obj` found: `plain` (see the module doc), the number of triangles its `f` lines
    make (a face of k corners: k - 2), whether the `v` lines parse as 3 numbers each and whether the
    `vn` and `vt` lines are valid (`valid_normals`, `valid_uvs`; plain text only), and (vertices,
    faces, normals or None, uvs or None, welds or None) as trimesh reads them
    (welds: each vertex's `v` index, 0-based, where vertices were split and there are no normals), or
    None; `data`: the text read (LF-ended: `obj_lines`; indices made absolute: `absolute_indices`; `vt u`
    lines made `vt u 0`: `short_uvs_padded`), which trimesh
    reads where these arrays are None."""

    plain: bool
    n_triangles: int = 0
    vertices_parse: bool = False
    attributes_valid: bool = False
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


def plain_vertices(text: bytes, count: int) -> bool:
    """Whether `count` `v` lines `text` (joined by newlines) are each the key and three numbers of
    VERTEX_CHARS separated by single spaces."""
    return (not text.translate(None, VERTEX_CHARS + b"v") and text.count(b"v") == count and b"  " not in text
            and text.count(b" ") == 3 * count)


def face_sizes(text: bytes, count: int) -> np.ndarray | None:
    """The number of corners of each of `count` `f` lines `text` (joined by newlines), where each is
    the key and 3 or more corners of FACE_CHARS separated by single spaces, none starting with '/'
    (a `v` index missing); else None."""
    if (text.translate(None, FACE_CHARS + b"f") or text.count(b"f") != count or b"  " in text or b" \n" in text
            or b" /" in text or text.endswith(b" ")):
        return None
    spaces = np.frombuffer(text.translate(None, DIGITS + b"/") + b"\n", np.uint8)  # per line "f", a space a corner
    sizes = np.diff(np.flatnonzero(spaces == ord("\n")), prepend=-1) - 2
    return sizes if sizes.min() >= 3 else None


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


def valid_normals(normals: np.ndarray | None) -> bool:
    """Whether a `vn` table (`table`: None where a line does not parse) is rows of 3 finite numbers,
    none all 0 -- a normal is a direction: a zero one would shade its corners as facing nowhere."""
    return (normals is not None and normals.shape[1] == 3 and bool(np.isfinite(normals).all())
            and bool(np.any(normals != 0.0, axis=1).all()))


def valid_uvs(uvs: np.ndarray | None) -> bool:
    """Whether a `vt` table (`table`: None where a line does not parse) is rows of 2 or 3 finite
    numbers (u v [w])."""
    return uvs is not None and uvs.shape[1] in (2, 3) and bool(np.isfinite(uvs).all())


def corner_table(face_text: bytes, n_corners: int) -> tuple[np.ndarray, str] | None:
    """Plain `f` lines' (`face_sizes`) `n_corners` corners as an (n_corners, k) int64 table, a row
    per corner in file order, and their layout (`a`, `a/t`, `a//n` or `a/t/n`: LAYOUTS), where every
    corner is laid out as the first; else None. Counts tell: each corner has the first's slashes (a
    corner's slashes follow its space), together where its are (`//`), and its numbers (none missing)."""
    first = face_text[2:].split(b" ", 1)[0]
    layout = LAYOUTS.get(re.sub(rb"\d+", b"#", first))
    slashes = first.count(b"/")
    marks = face_text.translate(None, DIGITS)  # per line "f", then a space and the slashes of each corner
    if (layout is None or marks.count(b"/") != slashes * n_corners
            or (slashes and marks.count(b" " + b"/" * slashes) != n_corners)
            or (slashes == 2 and face_text.count(b"//") != (n_corners if layout == "a//n" else 0))):
        return None
    numbers = np.fromstring(face_text.translate(SLASH_TO_SPACE, b"f"), dtype=np.int64, sep=" ")  # past int64: its max
    if numbers.size != n_corners * len(layout.replace("//", "/").split("/")):
        return None
    return numbers.reshape(n_corners, -1), layout


def obj_lines(data: bytes) -> bytes:
    """OBJ text with every line ended by LF alone -- CR LF (DOS) and a lone CR (old Mac) end a line
    as LF does -- and no comment after a line's content: a comment runs from a '#' anywhere on a
    line to its end (`f 1 2 3 # tri`), and goes with the blanks before it (a comment line stays:
    every reader skips it). So each reader, and each line number in a message, sees the file's
    lines as the OBJ format means them. Text with neither is returned as it is."""
    if b"\r" in data:
        data = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    if inline_comment(data):
        data = INLINE_COMMENT.sub(b"", data)
    return data


def inline_comment(data: bytes) -> bool:
    """Whether a '#' of LF-ended text lies after a line's start. From '#' to '#', skipping the rest
    of a comment line: a search a comment line, ~1 ms for a file of 11 MB with its comments on top
    (counting the '\n#' pairs took 10)."""
    at = data.find(b"#")
    while at >= 0:
        if at and data[at - 1] != ord("\n"):
            return True
        at = data.find(b"\n", at)
        at = data.find(b"#", at) if at >= 0 else -1
    return False


def read_obj(data: bytes) -> ObjText:
    """Classify and, where it can, read OBJ text (see the module doc); its lines are made LF-ended
    (`obj_lines`) and relative indices absolute (`absolute_indices`) first, and the text read is
    the result's `data`."""
    data = obj_lines(data)
    keys = line_keys(data)
    if b"-" in key_lines(data, *keys, F)[0]:
        data = absolute_indices(data, *keys)
        keys = line_keys(data)
    text = _classify(data, *keys)
    if not text.attributes_valid and SHORT_UV.search(data):
        data = short_uvs_padded(data)
        text = _classify(data, *line_keys(data))
    return dataclasses.replace(text, data=data)


def short_uvs_padded(data: bytes) -> bytes:
    """LF-ended OBJ text (`obj_lines`) with each `vt u` line written `vt u 0`: the OBJ format's `vt
    u [v] [w]` gives an omitted v the value 0 (trimesh drops such lines' uvs, numpy's table needs
    rows of one length). Only within lines: line numbers still name the file's lines. `read_obj`
    looks for such lines only in text that is not plain or whose `vn` / `vt` lines are not valid:
    a regex over a file of 10 MB takes ~0.1 s."""
    return SHORT_UV.sub(rb"\1 0", data)


def _classify(data: bytes, starts, ends, code) -> ObjText:
    """`read_obj` of LF-ended text (`obj_lines`), split into lines (`line_keys`)."""
    if not code.size or (code == OTHER).any() or np.count_nonzero(np.diff(code)) >= MAX_RUNS:
        return ObjText(False)
    vertex_text, n_vertices = key_lines(data, starts, ends, code, V)
    face_text, n_faces = key_lines(data, starts, ends, code, F)
    sizes = face_sizes(face_text, n_faces) if n_faces else None
    if sizes is None or not plain_vertices(vertex_text, n_vertices):
        return ObjText(False)
    vertices = table(vertex_text, KEYS[V], np.float64)
    vn_text, n_normals = key_lines(data, starts, ends, code, VN)
    normals = table(vn_text, KEYS[VN], np.float64) if n_normals else None
    vt_text, n_uvs = key_lines(data, starts, ends, code, VT)
    uvs = table(vt_text, KEYS[VT], np.float64) if n_uvs else None
    text = ObjText(True, int((sizes - 2).sum()), vertices is not None and vertices.shape == (n_vertices, 3),
                   (not n_normals or valid_normals(normals)) and (not n_uvs or valid_uvs(uvs)))
    usemtl = np.flatnonzero(code == USEMTL)
    corners = None  # continuations, tabs or several materials: trimesh reads the file
    if text.vertices_parse and not (b"\\" in data or b"\t" in data or usemtl.size > 1 or data.count(b"usemtl")
                                    != usemtl.size or (usemtl.size and usemtl[0] > np.argmax(code == F))):
        corners = corner_table(face_text, int(sizes.sum()))
    if has_zero_index(face_text) if corners is None else (corners[0][:, 0] == 0).any():
        return ObjText(False)  # a vertex index 0 is not OBJ: the line scan names it
    if corners is None or not text.attributes_valid:  # invalid normals or uvs: the line scan names the line
        return text
    return dataclasses.replace(text, arrays=mesh_arrays(vertices, normals, uvs, *corners, sizes))


def mesh_arrays(vertices: np.ndarray, normal_table: np.ndarray | None, uv_table: np.ndarray | None,
                corners: np.ndarray, layout: str, sizes: np.ndarray):
    """(vertices, faces, normals or None, uvs or None, welds or None) of plain OBJ text as trimesh
    reads it, up to the order of the module doc (welds: `unmerged`'s, each vertex's `v` index, where
    vertices are split and the file gives no normals), or None outside the layouts of the module doc.
    `vertices`: the `v` lines' (N, 3) numbers; `normal_table` / `uv_table`: the `vn` / `vt` lines'
    numbers (valid: `valid_normals`, `valid_uvs`), or None where there are none; `corners`: the `f`
    lines' corners' numbers (`corner_table`), a row each, laid out as `layout`; `sizes`: each face's
    number of corners."""
    corners = np.where(corners > 0, corners - 1, corners)  # 1-based (a 0 tex / normal index stays 0, as in trimesh)
    triangles = corners.reshape(-1, 3, corners.shape[1]) if (sizes == 3).all() else corners[fans(sizes)]
    columns = dict(zip(layout.replace("//", "/").split("/"), triangles.transpose(2, 0, 1)))
    faces = columns["a"]
    if faces.max() >= len(vertices):
        return None
    if ("n" in columns and normal_table is None) or ("t" in columns and uv_table is None):
        return None  # indices into no lines: trimesh reads the file
    uv_table = None if uv_table is None else uv_table[:, :2]
    used = {name: (columns[key], values) for name, key, values in (("normals", "n", normal_table), ("uvs", "t", uv_table))
            if key in columns and values is not None}
    if not used:
        return vertices, faces, None, None, None  # every vertex, no normals or uvs
    if any(index.max() >= len(values) for index, values in used.values()):
        return None  # trimesh drops that attribute: let it read the file
    welds, faces, *values = unmerged(vertices, faces, list(used.values()))
    found = dict(zip(used, values))
    normals = found.get("normals")
    return vertices[welds], faces, normals, found.get("uvs"), welds if normals is None else None


def fans(sizes: np.ndarray) -> np.ndarray:
    """(T, 3) int64: the triangles that faces of `sizes` corners make, each a row of three corners
    numbered in file order over all the faces, a face a b c d ... the fan (a, b, c), (a, c, d), ...,
    in file order."""
    count = sizes - 2  # triangles a face
    start = np.repeat(np.cumsum(sizes) - sizes, count)  # each triangle's face's first corner
    step = start + np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count) + 1  # its second corner
    return np.stack([start, step, step + 1], axis=1)


def absolute_indices(data: bytes, starts, ends, code) -> bytes:
    """OBJ text (split into lines by `line_keys`) with every negative (relative) index of its `f`
    lines made the absolute one it names -- a corner's `v`, `vt` and `vn` index alike: -1 is the
    last line of that key above the face --, so that every reader (numpy's, trimesh's,
    `fan_corners`) sees the faces of the same file with positive indices (trimesh counts relative
    indices from the end of the file). A relative index is a '-' and digits making one of a corner's
    first three numbers (between whitespace or '/' and '/', whitespace or '#'), before any '#' of an
    `f` line; -k there becomes (1 + the lines of its key above) - k, in place: the rest of the text
    stays as it is (line numbers still name the file's lines). An index before the first line
    stays <= 0, for the line scan to name (k past FAR counts as FAR). numpy over the text's '-'
    signs, no loop over lines or corners."""
    padded = np.frombuffer(data + b"\n", np.uint8)  # the byte past the end reads as a line end
    minus = np.flatnonzero(padded == ord("-"))
    line = np.searchsorted(starts, minus, "right") - 1
    minus, line = minus[code[line] == F], line[code[line] == F]
    blank = np.flatnonzero(is_blank(padded))
    slash, hashes = (np.flatnonzero(padded == ord(c)) for c in "/#")
    field = np.searchsorted(slash, minus) - np.searchsorted(slash, blank[np.searchsorted(blank, minus) - 1])
    value, digits, going = np.zeros(minus.size, np.int64), np.zeros(minus.size, np.int64), np.ones(minus.size, bool)
    while going.any():  # the digits after each '-', a digit a round (a non-digit byte minus '0' is >= 10 as uint8)
        digit = padded[minus + digits + going] - np.uint8(ord("0"))
        going &= digit < 10
        value = np.where(going, np.minimum(10 * np.minimum(value, FAR // 10) + digit, FAR), value)
        digits += going
    before, after = padded[minus - 1], padded[minus + 1 + digits]
    relative = ((field < 3) & ((before == ord("/")) | is_blank(before)) & (digits > 0)
                & ((after == ord("/")) | (after == ord("#")) | is_blank(after))
                & (np.searchsorted(hashes, minus) == np.searchsorted(hashes, starts[line])))  # no '#' before
    above = np.stack([np.cumsum(code == key) for key in (V, VT, VN)], axis=1) + 1  # per line: 1 + lines of each key
    minus, span = minus[relative], 1 + digits[relative]
    text, width = decimal(above[line[relative], field[relative]] - value[relative])
    kept = np.diff(minus, prepend=0) - np.concatenate([[0], span[:-1]])  # the bytes before each, after the last
    odd = np.arange(2 * minus.size) % 2 == 1  # runs of kept bytes, then of replaced ones
    keep = np.repeat(~odd, np.stack([kept, span], axis=1).ravel())
    new = np.repeat(odd, np.stack([kept, width], axis=1).ravel())
    out = np.empty(len(data) - span.sum() + width.sum(), np.uint8)
    out[:new.size][new] = text
    out[:new.size][~new] = padded[:keep.size][keep]
    out[new.size:] = padded[keep.size:len(data)]
    return out.tobytes()


def is_blank(chars: np.ndarray) -> np.ndarray:
    """Whether each byte (uint8) is whitespace as `bytes.split` sees it: space, or \\t to \\r."""
    return (chars == ord(" ")) | (chars - np.uint8(ord("\t")) <= ord("\r") - ord("\t"))


def decimal(numbers: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The decimal digits (uint8 ASCII, '-' before a negative number's) of int64 `numbers` (of
    magnitude below 10^19), all concatenated, and each number's count of them."""
    size = 1 + np.searchsorted(10 ** np.arange(1, 19), np.abs(numbers), "right")  # digits
    width = size + (numbers < 0)
    columns = np.empty((numbers.size, int(width.max(initial=1))), np.uint8)  # right-aligned
    rest = np.abs(numbers)
    for k in range(1, columns.shape[1] + 1):
        rest, columns[:, -k] = np.divmod(rest, 10)
    columns += ord("0")
    columns[numbers < 0, -1 - size[numbers < 0]] = ord("-")
    return columns[np.arange(columns.shape[1]) >= columns.shape[1] - width[:, None]], width


def fan_corners(data: bytes) -> np.ndarray | None:
    """(T, 3) int64: each corner's `v` index (0-based) of the triangles OBJ text's `f` lines make
    (`fans`); lines LF-ended and comments removed (`obj_lines`), indices absolute
    (`absolute_indices`). None where a corner does not parse, is not positive, or a face has fewer
    than 3 corners."""
    starts, ends, code = line_keys(data)
    face_text, n_faces = key_lines(data, starts, ends, code, F)
    if not n_faces:
        return None
    tokens = np.array(re.sub(rb"/\S*", b"", face_text).split())  # keys and vertex indices
    is_key = tokens == b"f"
    try:
        index = tokens[~is_key].astype(np.int64) - 1
    except ValueError:
        return None
    sizes = np.bincount(np.cumsum(is_key)[~is_key] - 1, minlength=n_faces)  # each face line's corners
    if sizes.min() < 3 or index.min() < 0:
        return None
    return index[fans(sizes)]


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
