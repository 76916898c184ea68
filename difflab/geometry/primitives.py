"""Procedural primitives: sphere, quad, box, cylinder.

Every primitive returns a `TriMesh` with analytic unit normals and uvs, faces counter-clockwise
seen from outside (the right-hand rule gives outward face normals). Vertices are duplicated where
a normal or uv is discontinuous (the sphere's and cylinder's seam, the box's edges, cap rims), so
closed shapes are watertight by position, not by vertex index.
"""

from __future__ import annotations

import numpy as np

from difflab.errors import MeshError
from difflab.limits import require_triangles

from .mesh import TriMesh, concatenate


def _vec(value, n: int, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise MeshError(f"{what} must be {n} finite numbers, got {value!r}")
    return arr


def _positive(value, what: str) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0.0:
        raise MeshError(f"{what} must be > 0, got {value}")
    return value


def _count(value, minimum: int, what: str) -> int:
    if int(value) != value or int(value) < minimum:
        raise MeshError(f"{what} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def uv_sphere_size(n_lat: int, n_lon: int) -> tuple[int, int]:
    """(vertices, faces) of `uv_sphere(n_lat=n_lat, n_lon=n_lon)`: n_lon per pole and n_lon + 1 per
    inner ring; two triangles per cell, one per polar cell."""
    return 2 * n_lon + (n_lat - 1) * (n_lon + 1), 2 * n_lon * (n_lat - 1)


def uv_sphere(radius=1.0, center=(0.0, 0.0, 0.0), n_lat=16, n_lon=32) -> TriMesh:
    """A latitude/longitude sphere with `n_lat` bands (>= 2) and `n_lon` segments (>= 3).

    Parameterisation: longitude lon in [0, 2 pi] runs counter-clockwise seen from +y, starting at
    +x (direction (cos lon, 0, -sin lon)); latitude lat in [0, pi] is the angle from the south pole
    (-y), so uv = (lon / 2 pi, lat / pi) has v = 0 at the bottom and v = 1 at the top. The seam at
    lon = 0 / 2 pi is duplicated (u = 0 and u = 1). Each pole is one vertex per segment (same
    position, u at the segment's middle) and the polar bands are single triangles, so no triangle
    is degenerate. Normals are the exact radial directions.
    """
    r = _positive(radius, "radius")
    c = _vec(center, 3, "center")
    n_lat = _count(n_lat, 2, "n_lat")
    n_lon = _count(n_lon, 3, "n_lon")
    require_triangles(uv_sphere_size(n_lat, n_lon)[1], f"uv_sphere of {n_lat} x {n_lon}", MeshError)

    def direction(lat, lon):
        s = np.sin(lat)
        cos_lon, sin_lon = np.cos(lon), np.sin(lon)
        seam = lon == 2.0 * np.pi  # make the duplicated seam bitwise equal to lon = 0
        cos_lon, sin_lon = np.where(seam, 1.0, cos_lon), np.where(seam, 0.0, sin_lon)
        return np.stack([s * cos_lon, -np.cos(lat), -s * sin_lon], axis=-1)

    # Rings 1 .. n_lat-1 with n_lon + 1 columns (seam duplicated).
    i = np.arange(1, n_lat)
    j = np.arange(n_lon + 1)
    lat = np.pi * i / n_lat
    lon = 2.0 * np.pi * j / n_lon
    lat_g, lon_g = np.meshgrid(lat, lon, indexing="ij")
    ring_dirs = direction(lat_g, lon_g).reshape(-1, 3)
    ring_uvs = np.stack([lon_g / (2 * np.pi), lat_g / np.pi], axis=-1).reshape(-1, 2)
    # Exact poles (sin(pi) is not exactly 0).
    pole_u = (np.arange(n_lon) + 0.5) / n_lon
    south_dirs = np.tile([0.0, -1.0, 0.0], (n_lon, 1))
    north_dirs = np.tile([0.0, 1.0, 0.0], (n_lon, 1))
    south_uvs = np.stack([pole_u, np.zeros(n_lon)], axis=-1)
    north_uvs = np.stack([pole_u, np.ones(n_lon)], axis=-1)

    n_ring = n_lon + 1
    south0 = 0
    ring0 = n_lon
    north0 = ring0 + (n_lat - 1) * n_ring

    def ring(a, b):  # vertex index of ring a (1-based latitude index), column b
        return ring0 + (a - 1) * n_ring + b

    faces = []
    js = np.arange(n_lon)
    # South cap: pole, ring1[j+1], ring1[j]  -> ccw seen from outside (below).
    faces.append(np.stack([south0 + js, ring(1, js + 1), ring(1, js)], axis=1))
    for a in range(1, n_lat - 1):
        p00, p01 = ring(a, js), ring(a, js + 1)
        p10, p11 = ring(a + 1, js), ring(a + 1, js + 1)
        faces.append(np.stack([p00, p01, p11], axis=1))
        faces.append(np.stack([p00, p11, p10], axis=1))
    # North cap.
    top = n_lat - 1
    faces.append(np.stack([ring(top, js), ring(top, js + 1), north0 + js], axis=1))

    dirs = np.concatenate([south_dirs, ring_dirs, north_dirs])
    uvs = np.concatenate([south_uvs, ring_uvs, north_uvs])
    return TriMesh(c + r * dirs, np.concatenate(faces), dirs, uvs, name="uv_sphere")


def _tangent_frame(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit (t, b, n) with t x b = n (u runs along t, v along b).

    For a normal not near +-y, b is world up (+y) projected onto the plane, so walls have v
    pointing up and u pointing right as seen from the front (normal +z: t = +x, b = +y). For a
    normal near +-y, t is world +x projected onto the plane (normal +y: t = +x, b = -z).
    """
    n = normal / np.linalg.norm(normal)
    if abs(n[1]) < 0.9:
        b = np.array([0.0, 1.0, 0.0]) - n[1] * n
        b /= np.linalg.norm(b)
        t = np.cross(b, n)
    else:
        t = np.array([1.0, 0.0, 0.0]) - n[0] * n
        t /= np.linalg.norm(t)
        b = np.cross(n, t)
    return t, b, n


def _grid(divisions: int) -> tuple[np.ndarray, np.ndarray]:
    """The unit square cut into divisions x divisions cells: uvs ((d+1)^2, 2), row-major in v,
    and 2 d^2 counter-clockwise triangles (each cell split along its (0,0)-(1,1) diagonal)."""
    d = divisions
    u, v = np.meshgrid(np.arange(d + 1) / d, np.arange(d + 1) / d, indexing="xy")
    uv = np.stack([u.ravel(), v.ravel()], axis=1)
    i, j = np.meshgrid(np.arange(d), np.arange(d), indexing="xy")
    v00 = (j * (d + 1) + i).ravel()
    v10, v01, v11 = v00 + 1, v00 + d + 1, v00 + d + 2
    faces = np.concatenate([np.stack([v00, v10, v11], axis=1), np.stack([v00, v11, v01], axis=1)])
    return uv, faces


def quad(size=(1.0, 1.0), center=(0.0, 0.0, 0.0), normal=(0.0, 1.0, 0.0), divisions=1) -> TriMesh:
    """A rectangle of `size` = (extent along t, extent along b) centred at `center`, facing
    `normal`, cut into `divisions` x `divisions` cells of two triangles each ((d+1)^2 vertices,
    2 d^2 triangles; d = 1 is the plain two-triangle quad). (t, b) is the frame of
    `_tangent_frame`: for the default normal +y, t = +x and b = -z, so the default is the unit
    square in the xz plane; for a normal +z (a wall facing the default camera) t = +x and b = +y.
    uv = (0, 0) at the corner center - t*sx/2 - b*sz/2, u along t, v along b.

    Subdividing changes nothing for flat or Phong shading of a flat quad, but Gouraud shading then
    samples a point light's falloff at every grid vertex: the lecture's fix of the wall artefact by
    re-triangulation."""
    sx, sz = (_positive(s, f"size[{k}]") for k, s in enumerate(_vec(size, 2, "size")))
    c = _vec(center, 3, "center")
    n_in = _vec(normal, 3, "normal")
    if np.linalg.norm(n_in) == 0.0:
        raise MeshError("normal must not be the zero vector")
    t, b, n = _tangent_frame(n_in)
    d = _count(divisions, 1, "divisions")
    require_triangles(2 * d * d, f"quad of {d} x {d} divisions", MeshError)
    uv, faces = _grid(d)
    vertices = c + (uv[:, :1] - 0.5) * sx * t + (uv[:, 1:] - 0.5) * sz * b
    return TriMesh(vertices, faces, np.tile(n, (len(uv), 1)), uv, name="quad")


def box(size=(1.0, 1.0, 1.0), center=(0.0, 0.0, 0.0), divisions=1) -> TriMesh:
    """An axis-aligned box: 6 sides, each a `quad` grid of `divisions` x `divisions` cells
    (d = 1: 24 vertices, 12 triangles), flat outward normals per side, each side's uvs spanning
    [0, 1]^2 (u, v along the side's `_tangent_frame`)."""
    s = np.array([_positive(v, f"size[{k}]") for k, v in enumerate(_vec(size, 3, "size"))])
    c = _vec(center, 3, "center")
    d = _count(divisions, 1, "divisions")
    require_triangles(12 * d * d, f"box of {d} x {d} divisions", MeshError)
    sides = []
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            t, b, _ = _tangent_frame(n)
            # The side's extents along t and b (both are axis-aligned unit vectors).
            sides.append(quad((float(np.abs(t) @ s), float(np.abs(b) @ s)), c + n * s[axis] / 2, n, d))
    return concatenate(sides, name="box")


def cylinder(radius=0.5, height=1.0, segments=32, caps=True, center=(0.0, 0.0, 0.0)) -> TriMesh:
    """A cylinder along y, from center.y - height/2 to center.y + height/2.

    The side has `segments` quads (>= 3) with a duplicated seam, radial normals and
    uv = (angle / 2 pi, (y - bottom) / height), the angle running counter-clockwise seen from +y
    from +x (direction (cos a, 0, -sin a)). With `caps`, each cap is a fan around a centre vertex,
    with normal -y / +y and planar uvs 0.5 + 0.5 * (x, -z) / radius (bottom: (x, z)), rim vertices
    duplicated from the side so that the edge stays sharp. Without caps the side is an open tube.
    """
    r = _positive(radius, "radius")
    h = _positive(height, "height")
    n = _count(segments, 3, "segments")
    require_triangles(4 * n, f"cylinder of {n} segments", MeshError)
    c = _vec(center, 3, "center")
    a = 2.0 * np.pi * np.arange(n + 1) / n
    cos_a, sin_a = np.cos(a), np.sin(a)
    cos_a[-1], sin_a[-1] = 1.0, 0.0
    radial = np.stack([cos_a, np.zeros(n + 1), -sin_a], axis=1)
    y0, y1 = -h / 2, h / 2
    up = np.array([0.0, 1.0, 0.0])

    bottom = r * radial + y0 * up
    top = r * radial + y1 * up
    vertices = [bottom, top]
    normals = [radial, radial]
    u = a / (2 * np.pi)
    uvs = [np.stack([u, np.zeros(n + 1)], axis=1), np.stack([u, np.ones(n + 1)], axis=1)]
    js = np.arange(n)
    b0, t0 = js, js + (n + 1)
    faces = [np.stack([b0, b0 + 1, t0 + 1], axis=1), np.stack([b0, t0 + 1, t0], axis=1)]
    count = 2 * (n + 1)
    if caps:
        for y, sign in ((y0, -1.0), (y1, 1.0)):
            rim = r * radial[:n] + y * up
            centre = (y * up)[None, :]
            vertices += [centre, rim]
            normals.append(np.tile(sign * up, (n + 1, 1)))
            cap_uv = np.stack([0.5 + 0.5 * radial[:n, 0], 0.5 - 0.5 * sign * radial[:n, 2]], axis=1)
            uvs += [np.array([[0.5, 0.5]]), cap_uv]
            ring = count + 1 + js
            nxt = count + 1 + (js + 1) % n
            if sign > 0:  # top: ccw seen from +y
                faces.append(np.stack([np.full(n, count), ring, nxt], axis=1))
            else:
                faces.append(np.stack([np.full(n, count), nxt, ring], axis=1))
            count += n + 1
    return TriMesh(c + np.concatenate(vertices), np.concatenate(faces), np.concatenate(normals),
                   np.concatenate(uvs), name="cylinder")
