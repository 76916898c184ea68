"""Texture coordinates by projection (numpy): planar, spherical and cylindrical uv for any mesh.

Each takes points (N, 3) and returns uv (N, 2); `project_uvs(mesh, kind, ...)` returns the mesh with
its uvs replaced. Axes: `axis` is the projection's up / normal direction (default +y), `center` its
origin; the two in-plane directions (t, b) are those of `uv_frame(axis)`, the frame an analytic
plane's texture lies in (`scene.Plane.uv_frame`): right-handed, upright seen from the axis's side.

- planar:      uv = ((p - center).t, (p - center).b) / scale (+ 0.5 to centre a unit square).
- spherical:   u = longitude / 2 pi in [0, 1), v = latitude from the -axis pole / pi in [0, 1]
               (for axis +y exactly `uv_sphere`'s parameterisation: lon from +x, counter-clockwise
               seen from +y).
- cylindrical: u as spherical, v = height along the axis / scale (+ 0.5).
The u seam (u jumps 1 -> 0) lies on the +t half-plane; a triangle crossing it interpolates across the
whole texture unless the mesh is split there (`uv_sphere` and `cylinder` duplicate their seams).
"""

from __future__ import annotations

import numpy as np

from .mesh import TriMesh

PROJECTIONS = ("planar", "spherical", "cylindrical")


def uv_frame(normal) -> tuple[np.ndarray, np.ndarray]:
    """(t, b): the unit directions of u and v on a plane with unit `normal`, with it a right-handed
    orthonormal frame (t x b = normal), so a texture reads unmirrored from the normal's side, v up,
    u right. b = a reference direction made orthogonal to the normal, t = b x normal. The reference
    is chosen by the normal's dominant axis: a floor or ceiling (|normal_y| strictly the largest
    component) takes -z sign(normal_y) -- a floor reads upright to a camera at +z looking toward
    -z, as the builtin quad; normal +y: t = +x, b = -z; -y: t = +x, b = +z -- anything else
    (walls, and slopes from 45 degrees up) world up +y -- normal +z: t = +x, b = +y; +x: t = -z,
    b = +y. Within each region the frame is smooth in the normal (the reference stays at least 45
    degrees off it); a continuous frame on every normal does not exist (hairy ball), so the switch
    sits at 45 degrees, far from floors and walls. The frame of `scene.Plane`'s uv and of every
    projection here."""
    normal = np.asarray(normal, np.float64)
    if abs(normal[1]) > max(abs(normal[0]), abs(normal[2])):
        reference = np.array([0.0, 0.0, -np.sign(normal[1])])
    else:
        reference = np.array([0.0, 1.0, 0.0])
    b = reference - np.dot(reference, normal) * normal
    b /= np.linalg.norm(b)
    return np.cross(b, normal), b


def frame(axis=(0.0, 1.0, 0.0)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, b, axis): `uv_frame` of the unit axis, and the unit axis. For axis +y: t = +x, b = -z, so
    longitude atan2(d.b, d.t) runs counter-clockwise seen from +y from +x, as in `uv_sphere`."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    return (*uv_frame(a), a)


def planar_uv(points, axis=(0.0, 1.0, 0.0), center=(0.0, 0.0, 0.0), scale: float = 1.0) -> np.ndarray:
    """Projection onto the plane normal to `axis`: ((p - c).t, (p - c).b) / scale + 0.5, (t, b) =
    `uv_frame(axis)` -- a plane's uv (`scene.Plane.uv`), centred: an image mapped on a wall facing
    +z reads upright from the front (u along +x, v along +y, uv (0.5, 0.5) at `center`)."""
    t, b, _ = frame(axis)
    d = np.asarray(points, float) - np.asarray(center, float)
    return np.stack([d @ t, d @ b], axis=-1) / scale + 0.5


def _longitude(d, t, b):
    lon = np.arctan2(d @ b, d @ t)
    return np.mod(lon, 2.0 * np.pi) / (2.0 * np.pi)


def spherical_uv(points, axis=(0.0, 1.0, 0.0), center=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(longitude / 2 pi, latitude from the -axis pole / pi) of the direction from `center`."""
    t, b, a = frame(axis)
    d = np.asarray(points, float) - np.asarray(center, float)
    r = np.linalg.norm(d, axis=-1)
    cos_lat = np.where(r > 0, -(d @ a) / np.where(r > 0, r, 1.0), 1.0)
    return np.stack([_longitude(d, t, b), np.arccos(np.clip(cos_lat, -1.0, 1.0)) / np.pi], axis=-1)


def cylindrical_uv(points, axis=(0.0, 1.0, 0.0), center=(0.0, 0.0, 0.0), scale: float = 1.0) -> np.ndarray:
    """(longitude / 2 pi, height along `axis` / scale + 0.5)."""
    t, b, a = frame(axis)
    d = np.asarray(points, float) - np.asarray(center, float)
    return np.stack([_longitude(d, t, b), (d @ a) / scale + 0.5], axis=-1)


def project_uvs(mesh: TriMesh, kind: str, axis=(0.0, 1.0, 0.0), center=None, scale: float | None = None) -> TriMesh:
    """The mesh with uvs from projection `kind`; center defaults to the bounding-box centre, scale
    to the bounding box's largest extent (planar, cylindrical)."""
    if kind not in PROJECTIONS:
        raise ValueError(f"uv projection: expected one of {PROJECTIONS}, got {kind!r}")
    v = mesh.vertices
    center = (v.min(0) + v.max(0)) / 2 if center is None else np.asarray(center, float)
    if scale is None:
        scale = float(np.max(v.max(0) - v.min(0))) or 1.0
    if kind == "planar":
        uv = planar_uv(v, axis, center, scale)
    elif kind == "spherical":
        uv = spherical_uv(v, axis, center)
    else:
        uv = cylindrical_uv(v, axis, center, scale)
    return TriMesh(mesh.vertices, mesh.faces, mesh.normals, uv, welds=mesh.welds)
