"""`load_mesh`: OBJ / PLY (and whatever else trimesh reads) into a validated `TriMesh`; `save_mesh`
writes a `TriMesh` as OBJ.

trimesh is lenient: it may drop faces that index past the vertex list or read a garbage file as an
empty scene. For OBJ files we therefore check the raw text (vertex values, every `f` index, at least
one face) so each problem is reported, with the path and line, instead of silently repaired: a
file in the plain layout (`v x y z`, `f a b c ...`, see `obj_text`) is vouched for by vectorised
byte checks, by its `v` lines parsing as numbers and by its reading giving exactly the triangles its
`f` lines make (k - 2 a face of k corners); anything else is scanned line by line. The common plain
layouts, triangles and polygons, are read by numpy (`obj_text.read_obj`) to what trimesh gives for
them; trimesh reads the rest.
"""

from __future__ import annotations

import io
import math
import os
import warnings
from pathlib import Path

import numpy as np

from difflab.errors import MeshError
from difflab.files import write_text_atomic
from difflab.limits import MAX_COORD, MESH_FILE_BYTES, require_memory

from .mesh import TriMesh, concatenate
from .obj_text import KEYS, V, fan_corners, key_lines, line_keys, obj_lines, read_obj, table


def _read_obj(path: str) -> bytes:
    try:
        with open(path, "rb") as handle:
            return handle.read()
    except OSError as exc:
        raise MeshError(f"{path}: cannot read mesh file: {exc}") from None


def _scan_obj_lines(data: bytes, path: str) -> None:
    """The line-by-line check of LF-ended OBJ text (`obj_lines`), naming the first problem's line."""
    n_vertices = 0
    n_normals = 0
    n_uvs = 0
    n_faces = 0
    indices: list[tuple[int, int, int]] = []  # (line, index as written, absolute 1-based index)
    for number, raw in enumerate(data.decode("utf-8", errors="replace").split("\n"), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        key = parts[0]
        if key == "v":
            try:
                values = [float(x) for x in parts[1:]][:3]  # (then a weight or a colour: numbers too)
            except ValueError:
                raise MeshError(f"{path}:{number}: cannot parse vertex {line!r}") from None
            if len(values) < 3:
                raise MeshError(f"{path}:{number}: vertex needs 3 coordinates: {line!r}")
            if not all(math.isfinite(x) for x in values):
                raise MeshError(f"{path}:{number}: vertex {n_vertices + 1} is not finite: {line[:80]!r}")
            if not all(abs(x) <= MAX_COORD for x in values):
                raise MeshError(f"{path}:{number}: vertex {n_vertices + 1} is beyond +-{MAX_COORD:g} (float32 "
                                f"rendering overflows): {line[:80]!r}")
            n_vertices += 1
        elif key == "vn":
            n_normals += 1
            values = _numbers(parts, (3,), f"{path}:{number}: ", f"normal {n_normals}", "vn x y z", line)
            if not any(values):
                raise MeshError(f"{path}:{number}: normal {n_normals} is zero-length (a normal is a direction): "
                                f"{line[:80]!r}")
        elif key == "vt":
            n_uvs += 1
            _numbers(parts, (1, 2, 3), f"{path}:{number}: ", f"uv {n_uvs}", "vt u [v] [w]", line)
        elif key == "f":
            corners = parts[1:]
            if len(corners) < 3:
                raise MeshError(f"{path}:{number}: face needs at least 3 vertices: {line!r}")
            for corner in corners:
                token = corner.split("/", 1)[0]
                try:
                    index = int(token)
                except ValueError:
                    raise MeshError(
                        f"{path}:{number}: cannot parse face index {corner!r}") from None
                if index == 0:
                    raise MeshError(f"{path}:{number}: face index 0 is invalid (OBJ is 1-based)")
                indices.append((number, index, index if index > 0 else n_vertices + index + 1))
            n_faces += 1
    for number, written, index in indices:
        if index < 1 or index > n_vertices:
            raise MeshError(f"{path}:{number}: face index {written} out of range "
                            f"(file has {n_vertices} vertices)")
    if n_faces == 0:
        what = "no vertices and no faces (not an OBJ mesh?)" if n_vertices == 0 else "no faces"
        raise MeshError(f"{path}: mesh has {what}")


def _numbers(parts: list[str], counts: tuple[int, ...], where: str, what: str, form: str, line: str) -> list[float]:
    """The numbers after a `vn` / `vt` line's key (`parts`: the line split), which must be finite
    and `counts` many (consecutive; `form`: the line's form, for the message); else `MeshError` naming `what`
    (e.g. 'normal 3'), prefixed by `where` (the file and line), and the line's text."""
    try:
        values = [float(x) for x in parts[1:]]
    except ValueError:
        raise MeshError(f"{where}cannot parse {what}: {line[:80]!r}") from None
    if len(values) not in counts:
        needs = str(counts[0]) if len(counts) == 1 else f"{counts[0]} to {counts[-1]}"
        raise MeshError(f"{where}{what} needs {needs} numbers ({form}), got {len(values)}: {line[:80]!r}")
    if not all(math.isfinite(x) for x in values):
        raise MeshError(f"{where}{what} is not finite: {line[:80]!r}")
    return values


def _to_trimesh_list(loaded, path: str) -> list:
    import trimesh

    if isinstance(loaded, trimesh.Scene):
        meshes = []
        for node in loaded.graph.nodes_geometry:
            transform, geometry_name = loaded.graph[node]
            geometry = loaded.geometry[geometry_name]
            meshes.append((geometry, np.asarray(transform, dtype=np.float64)))
        return meshes
    return [(loaded, None)]


def _convert(geometry, transform, path: str) -> TriMesh:
    import trimesh

    if not isinstance(geometry, trimesh.Trimesh):
        raise MeshError(f"{path}: contains a {type(geometry).__name__}, not a triangle mesh "
                        "(no faces)")
    vertices = np.asarray(geometry.vertices, dtype=np.float64)
    faces = np.asarray(geometry.faces)
    normals = None
    cache = getattr(geometry, "_cache", None)
    try:
        has_file_normals = cache is not None and "vertex_normals" in cache
    except TypeError:
        has_file_normals = False
    if has_file_normals:
        normals = np.asarray(geometry.vertex_normals, dtype=np.float64)
        if normals.shape != vertices.shape:
            normals = None
        else:
            bad = np.flatnonzero(~np.isfinite(normals).all(axis=1) | ~np.any(normals != 0.0, axis=1))
            if bad.size:  # an OBJ's were refused by its line already
                raise MeshError(f"{path}: vertex {bad[0]}'s normal {normals[bad[0]].tolist()} is not a direction "
                                "(zero-length or not finite)")
    uvs = None
    visual = getattr(geometry, "visual", None)
    uv = getattr(visual, "uv", None) if getattr(visual, "kind", None) == "texture" else None
    if uv is not None:
        uv = np.asarray(uv, dtype=np.float64)
        if uv.shape == (len(vertices), 2):
            bad = np.flatnonzero(~np.isfinite(uv).all(axis=1))
            if bad.size:  # an OBJ's were refused by its line already
                raise MeshError(f"{path}: vertex {bad[0]}'s uv {uv[bad[0]].tolist()} is not finite")
            uvs = uv
    mesh = TriMesh(vertices, faces, normals, uvs, name=path)  # no welds: equal positions may be a hard edge
    if transform is not None and not np.allclose(transform, np.eye(4)):
        mesh = mesh.transformed(transform)
    return mesh


def load_mesh(path) -> TriMesh:
    """Read a triangle mesh file (OBJ, PLY, or another format trimesh reads) into a `TriMesh`.

    trimesh loads it with `process=False` (and `maintain_order=False`): each corner keeps the uv
    and normal the file gives it -- an OBJ vertex used with several uvs (a uv seam) or normals (a
    crease) is split into one vertex per (v, vt, vn) its corners use, as any renderer must, and
    vertices no face uses are dropped; vertices otherwise keep their file order. uvs are kept when
    the file has them; normals when the file has them (OBJ `vn`, PLY nx/ny/nz), else None -- then
    `welds` numbers each vertex of an OBJ by the `v` line it copies (where trimesh reads
    the file, from its `f` lines: `with_file_welds`; never by equal positions, which may be a hard
    edge; a PLY's vertices are not welded), so smooth normals (`TriMesh.smooth_normals`) average
    over all a position's faces and a uv seam shades as the unsplit surface.
    A polygon a b c d ... is the fan of triangles (a, b, c), (a, c, d), ..., with its corners' uvs
    and normals (faces in file order where numpy reads the file, `obj_text`). A scene with several
    geometries is concatenated with its node transforms applied. An OBJ's lines end at CR, LF or
    CR LF alike (`obj_lines`). Every failure raises `MeshError`
    naming the path: missing file, unreadable or unparsable file, non-finite vertex, a file normal
    (OBJ `vn`, with its line) that is zero-length or not finite -- a normal is a direction, as for a
    mesh's `normals` inline in a scene --, an OBJ `vt` line that is not 1 to 3 finite numbers (`vt
    u` is `vt u 0`, as the OBJ format says: `short_uvs_padded`), face index out of range, no faces.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise MeshError(f"{path}: mesh file not found")
    if not os.path.isfile(path):
        raise MeshError(f"{path}: not a file")
    require_memory(os.path.getsize(path) * MESH_FILE_BYTES, f"{path}: loading a mesh file of "
                   f"{os.path.getsize(path)} bytes", MeshError)
    text = None  # an OBJ file's text, as `read_obj` finds it (its `data`: indices made absolute)
    if path.lower().endswith(".obj"):
        data = obj_lines(_read_obj(path))
        text = read_obj(data)
        if not text.plain or not text.attributes_valid:  # a bad `vn` / `vt` line: the scan names it
            _scan_obj_lines(data, path)
    if text is not None and text.arrays is not None:
        vertices, faces, normals, uvs, welds = text.arrays
        mesh = TriMesh(vertices, faces, normals, uvs, name=path, welds=welds)
    else:
        mesh = _trimesh_load(path, None if text is None else text.data, plain=text is not None and text.plain)
        if text is not None and mesh.uvs is not None and mesh.normals is None:  # trimesh split `v`s per uv
            mesh = with_file_welds(mesh, text.data)
    if text is not None and text.plain and (
            not text.vertices_parse or mesh.n_faces != text.n_triangles  # a garbled vertex, a dropped face
            or not np.all(np.abs(mesh.vertices) <= MAX_COORD)):  # or a value is out of range
        _scan_obj_lines(data, path)  # names the line
    if not np.all(np.isfinite(mesh.vertices)):
        raise MeshError(f"{path}: vertex coordinates are not finite")
    if not np.all(np.abs(mesh.vertices) <= MAX_COORD):
        raise MeshError(f"{path}: vertex coordinates reach {np.abs(mesh.vertices).max():.3g}, beyond +-{MAX_COORD:g} "
                        "(float32 rendering overflows)")
    return mesh


def with_file_welds(mesh: TriMesh, data: bytes) -> TriMesh:
    """`mesh` (trimesh's reading of the OBJ text `data`, as `obj_lines` gives it) with `welds`: each
    vertex numbered by the `v` line its corners name in the `f` lines (`fan_corners`) -- only the
    file says which copies of a position are one vertex (an OBJ without normals marks a hard edge by repeating a position in
    another `v` line). trimesh reorders the triangles (a polygon's fans after the triangles, a fan
    started at another corner), so each of its triangles is matched to the file's with the same
    corner positions (`by_positions`); triangles at the same positions pair in any order where they
    name the same `v` lines (a repeated face). Unchanged (no welds) where they do not match one to
    one, or two triangles at the same positions name different `v` lines (which is which is unknown)."""
    corners = fan_corners(data)
    starts, ends, code = line_keys(data)
    positions = table(key_lines(data, starts, ends, code, V)[0], KEYS[V], np.float64)
    if corners is None or positions is None or corners.shape != mesh.faces.shape or positions.shape[1] < 3 \
            or corners.min() < 0 or corners.max() >= len(positions):
        return mesh
    ours, file_keys = by_positions(mesh.vertices[mesh.faces], mesh.faces)
    theirs, their_keys = by_positions(positions[corners, :3], corners)
    if not np.array_equal(file_keys, their_keys):
        return mesh  # other triangles
    if ((their_keys[1:] == their_keys[:-1]).all(axis=1) & (theirs[1:] != theirs[:-1]).any(axis=1)).any():
        return mesh  # two at the same positions from other `v` lines: which is which is unknown
    welds = len(positions) + np.arange(mesh.n_vertices)  # a vertex no face uses: its own
    welds[ours.ravel()] = theirs.ravel()
    if not np.array_equal(welds[ours], theirs):  # a vertex at two `v` lines' corners
        return mesh
    return TriMesh(mesh.vertices, mesh.faces, None, mesh.uvs, name=mesh.name, welds=welds)


def by_positions(points: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangles' `corners` (T, 3) and their (T, 9) corner `points` (T, 3, 3), each triangle's
    corners turned to start at its lexicographically least point and the triangles sorted by
    those points: the same triangles in any order and turn give the same keys."""
    rows = np.arange(len(points))
    first = np.zeros(len(points), np.int64)
    for k in (1, 2):
        a, b = points[:, k], points[rows, first]
        less = (a[:, 0] < b[:, 0]) | ((a[:, 0] == b[:, 0])
                                      & ((a[:, 1] < b[:, 1]) | ((a[:, 1] == b[:, 1]) & (a[:, 2] < b[:, 2]))))
        first = np.where(less, k, first)
    turn = (first[:, None] + np.arange(3)) % 3
    keys = points[rows[:, None], turn].reshape(-1, 9)
    order = np.lexsort(keys.T[::-1])
    return corners[rows[:, None], turn][order], keys[order]


def _trimesh_load(path: str, obj: bytes | None = None, plain: bool = False) -> TriMesh:
    """The file read by trimesh (several geometries concatenated, node transforms applied); `obj`:
    an OBJ file's text to read instead (its indices made absolute: `absolute_indices`; `mtllib`
    files still found beside `path`). `plain`: `obj` is plain text, which the line scan checks when
    trimesh fails on it."""
    try:
        import trimesh

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if obj is None:
                loaded = trimesh.load(path, process=False, maintain_order=False)
            else:
                loaded = trimesh.load(io.BytesIO(obj), file_type="obj", resolver=trimesh.resolvers.FilePathResolver(path),
                                      process=False, maintain_order=False)
    except MeshError:
        raise
    except Exception as exc:  # trimesh raises many kinds on bad input
        if plain:  # the line scan names the problem better where it finds one
            _scan_obj_lines(obj, path)
        raise MeshError(f"{path}: cannot read mesh: {type(exc).__name__}: {exc}") from None
    parts = _to_trimesh_list(loaded, path)
    if not parts:
        raise MeshError(f"{path}: no mesh geometry found (empty or unparsable file)")
    try:
        meshes = [_convert(geometry, transform, path) for geometry, transform in parts]
    except MeshError as exc:
        message = str(exc)
        raise MeshError(message if path in message else f"{path}: {message}") from None
    return meshes[0] if len(meshes) == 1 else concatenate(meshes, name=path)


def obj_text(mesh: TriMesh) -> str:
    """Wavefront OBJ text of the mesh's used vertices (v), its normals (vn) if any, and faces."""
    used, faces = np.unique(mesh.faces, return_inverse=True)
    faces = faces.reshape(-1, 3) + 1  # OBJ indices start at 1
    parts = [_lines("v %.9g %.9g %.9g", mesh.vertices[used])]
    if mesh.normals is not None:
        parts += [_lines("vn %.9g %.9g %.9g", mesh.normals[used]),
                  _lines("f %d//%d %d//%d %d//%d", np.repeat(faces, 2, axis=1))]
    else:
        parts.append(_lines("f %d %d %d", faces))
    return "".join(parts)


def _lines(fmt: str, rows: np.ndarray) -> str:
    """`fmt` of each row, one line each: np.savetxt's text, formatted by one % over every value
    (np.savetxt formats row by row in Python: 2.75x slower on a 300k-vertex mesh)."""
    return ((fmt + "\n") * len(rows)) % tuple(rows.ravel().tolist())


def save_mesh(path, mesh: TriMesh) -> Path:
    """Write `mesh` as a Wavefront OBJ file (positions, normals if any, faces; no uvs), atomically.
    `load_mesh` reads it back. Returns the path."""
    path = Path(path)
    write_text_atomic(path, obj_text(mesh))
    return path
