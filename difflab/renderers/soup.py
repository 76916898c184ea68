"""The triangle soup: the mesh objects' (and the rasterizer's analytic) triangles in one set of
float32 / int32 arrays, on the host and on the device, with room left after the meshes' rows for
the tessellation `CompiledScene.raster` writes there first."""

from __future__ import annotations

import numpy as np

from .. import geometry
from .._warp import wp
from ..errors import RenderError
from ..limits import require_triangles
from .tessellate import AnalyticParts

PER_FACE = ("faces", "face_material", "face_object", "face_normal")  # the soup's arrays with a row per face


def chunked_face_normals(vertices: np.ndarray, faces: np.ndarray, chunk: int = 1 << 17) -> np.ndarray:
    """(F, 3) float32 unit face normals, computed in float64 `chunk` faces at a time (the same
    values as one call: each row depends only on its face; the float64 temporaries stay ~30 MB
    instead of ~200 bytes per face)."""
    vertices = vertices.astype(np.float64)
    out = np.empty(faces.shape, np.float32)
    for begin in range(0, faces.shape[0], chunk):
        out[begin:begin + chunk] = geometry.face_normals(vertices, faces[begin:begin + chunk])
    return out


def triangle_soup(parts) -> dict:
    """The parts' triangles in one set of float32 / int32 arrays (vertices, normals, uvs, faces,
    and per face its material, object and geometric normal)."""
    if not parts:
        return {"vertices": np.zeros((0, 3), np.float32), "normals": np.zeros((0, 3), np.float32),
                "uvs": np.zeros((0, 2), np.float32), "faces": np.zeros((0, 3), np.int32),
                "face_material": np.zeros(0, np.int32), "face_object": np.zeros(0, np.int32),
                "face_normal": np.zeros((0, 3), np.float32), "vertex_material": np.zeros(0, np.int32),
                "vertex_object": np.zeros(0, np.int32)}
    offsets = np.cumsum([0] + [m.vertices.shape[0] for m, _, _ in parts])
    vertices = np.concatenate([m.vertices for m, _, _ in parts]).astype(np.float32)
    faces = np.concatenate([m.faces + o for (m, _, _), o in zip(parts, offsets)]).astype(np.int32)
    return {
        "vertices": vertices, "faces": faces,
        "normals": np.concatenate([m.smooth_normals() for m, _, _ in parts]).astype(np.float32),
        "uvs": np.concatenate([m.uvs if m.uvs is not None else np.zeros((m.vertices.shape[0], 2))
                               for m, _, _ in parts]).astype(np.float32),
        "face_material": np.concatenate([np.full(m.faces.shape[0], mat, np.int32) for m, mat, _ in parts]),
        "face_object": np.concatenate([np.full(m.faces.shape[0], obj, np.int32) for m, _, obj in parts]),
        "face_normal": chunked_face_normals(vertices, faces),
        "vertex_material": np.concatenate([np.full(m.vertices.shape[0], mat, np.int32) for m, mat, _ in parts]),
        "vertex_object": np.concatenate([np.full(m.vertices.shape[0], obj, np.int32) for m, _, obj in parts]),
    }


SOUP_DTYPES = {"vertices": wp.vec3, "normals": wp.vec3, "uvs": wp.vec2, "faces": wp.int32, "face_material": wp.int32,
               "face_object": wp.int32, "face_normal": wp.vec3, "vertex_material": wp.int32, "vertex_object": wp.int32}


def host_aliased(device: str) -> bool:
    """Whether `device_soup` arrays on `device` are the host arrays' memory (the CPU's), so rows
    written on the host later are the device's too; elsewhere (a GPU) they are copies, uploaded
    whole."""
    return wp.get_device(device).is_cpu


def device_soup(soup: dict, device: str) -> dict:
    """The soup's arrays on the device, by name (on the CPU they alias the soup's: copy=False, one
    copy of the triangles in memory)."""
    return {name: wp.array(np.ascontiguousarray(soup[name]), dtype=dtype, device=device, copy=False)
            for name, dtype in SOUP_DTYPES.items()}


def soup_with_room(soup: dict, n_vertices: int, n_faces: int) -> dict:
    """The soup's arrays copied into the first rows of new ones of `n_vertices` / `n_faces` rows, the
    rest left unwritten (np.empty: memory pages nothing has written are not held)."""
    out = {}
    for name, values in soup.items():
        out[name] = np.empty((n_faces if name in PER_FACE else n_vertices,) + values.shape[1:], values.dtype)
        out[name][:len(values)] = values
    return out


def raster_room(analytic: AnalyticParts, n_faces: int) -> tuple[int, int]:
    """(vertices, faces) of the larger of the analytic objects' two tessellations (`AnalyticParts.size`),
    to leave room for after the `n_faces` mesh triangles: the first one drawn is written there;
    (0, 0) where they pass the memory budget together (then rasterizing the scene is refused, as
    `tessellate` prices them again)."""
    n_vertices, n_added = np.max([analytic.size(phong) for phong in (False, True)], axis=0).tolist()
    try:
        require_triangles(n_faces + n_added, "raster triangles of the scene", RenderError)
    except RenderError:
        return 0, 0
    return n_vertices, n_added
