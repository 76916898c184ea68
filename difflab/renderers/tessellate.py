"""The rasterizer's triangles of the analytic spheres and planes (rays see the exact ones).

A sphere's triangles decide which samples it covers and in what depth order. Under Phong shading
that is all they decide: a covered sample takes the exact point of the sphere its eye ray meets
(`raster.resolve.sphere_sample`); flat and Gouraud shading take the triangles' own points, normals
and uv. So a compiled scene has two tessellations, each built when first drawn
(`CompiledScene.raster`), their spheres' longitudes from one rule (`sphere_segments`): the fewest
that hold the polygon's sagitta r (1 - cos(pi / N)) under SAGITTA samples, at least a floor.
- Flat and Gouraud: half a sample, at least 128 longitudes (MIN_SPHERE_SEGMENTS, for the
  interpolated normals): the 256^2 bench sphere 128 longitudes, 16,128 triangles.
- Phong: an eighth of a sample, at least 16 (PHONG_SPHERE_SEGMENTS): the bench sphere (the rule's
  radius at its nearest depth 124 sample rows) 69 longitudes, 4,554 triangles; its fit's G-buffer
  frame (`fit_frame`) 3.43 -> 2.97 ms, a first fit's render 3.5 -> 3.0 ms (A/B, load 2.7).
The silhouette is off by as much as the facets lie inside the sphere, twice the polygon's sagitta
(a quad's corners are further from its middle than an edge's ends from the edge's: 1.94x at 16
longitudes, 1.99x from 42), where a view's silhouette crosses the facets' middles: Phong's within a
quarter sample (0.225 measured), flat and Gouraud's within one (the 128 floor much closer below
~1,660 samples of radius). Inscribed, the facets never cover a sample outside the exact sphere.
A plane is a grid of quads reaching the far plane in every direction, clipped to the view by the
pipeline (its triangles lie on the plane: their points are the plane's), the same for both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import geometry
from ..errors import RenderError
from ..guards import object_errors
from ..limits import require_triangles
from ..scene import Plane, Sphere
from .camera import camera_frame, pixel_size_at

MAX_SPHERE_SEGMENTS = 1024
MIN_SPHERE_SEGMENTS = 128  # keeps Gouraud's interpolated normals within ~1e-3 of the sphere's inside the silhouette
#: Phong's floor, 8 bands of 16 (224 triangles, nothing to save): the rule asks for fewer under 6.5
#: samples of radius, where its radius at the nearest depth can miss a wide-angle view's stretch
#: off the axis (~1 / cos of the angle off it); 16 keep a 3-sample sphere's facets 0.11 deep.
PHONG_SPHERE_SEGMENTS = 16
#: The polygon's largest sagitta in samples, by `phong`: the facets twice as deep, see the module doc.
SAGITTA = {False: 0.5, True: 0.125}
PLANE_RINGS = 12  # grid lines each side of the eye's foot on a rasterized plane, spaced geometrically


def sphere_segments(centers, radii, camera, height: int, phong: bool = False) -> np.ndarray:
    """Longitude segments of each sphere (`centers` (n, 3), `radii` (n,), world units) so that the
    polygon's sagitta r (1 - cos(pi / N)) is under s = SAGITTA[phong] samples:
    N = ceil(2 pi / (2 acos(1 - s / r_px))) with r_px the radius in sample rows at the sphere's
    nearest depth, clamped to [the floor (MIN_SPHERE_SEGMENTS, Phong's PHONG_SPHERE_SEGMENTS),
    MAX_SPHERE_SEGMENTS]; the floor under half a sample. MAX where a perspective sphere reaches the
    near plane, or where the step underflows (r_px > ~4.5e15: 1 - s / r_px rounds to 1)."""
    sagitta, least = SAGITTA[phong], PHONG_SPHERE_SEGMENTS if phong else MIN_SPHERE_SEGMENTS
    _, _, forward = camera_frame(camera)
    offset = np.asarray(centers, np.float64).reshape(-1, 3) - np.asarray(camera.eye, np.float64)
    radii = np.asarray(radii, np.float64).reshape(-1)
    distance = offset[:, 0] * forward[0] + offset[:, 1] * forward[1] + offset[:, 2] * forward[2] - radii
    radius_px = radii / pixel_size_at(camera, np.maximum(distance, camera.near), height)
    step = 2.0 * np.arccos(1.0 - sagitta / np.maximum(radius_px, sagitta))
    turns = np.divide(2.0 * math.pi, step, out=np.full_like(step, np.inf), where=step > 0)  # inf: underflow, NaN
    segments = np.clip(np.ceil(turns), least, MAX_SPHERE_SEGMENTS)
    segments = np.where(radius_px <= 0.5, least, segments)
    if camera.projection == "perspective":
        segments = np.where(distance <= camera.near, MAX_SPHERE_SEGMENTS, segments)
    return segments.astype(np.int64)


def plane_grid_size() -> tuple[int, int]:
    """(vertices, faces) of every `plane_grid`: (2 PLANE_RINGS + 1)^2 grid points, two triangles per cell."""
    return (2 * PLANE_RINGS + 1) ** 2, 2 * (2 * PLANE_RINGS) ** 2


def plane_uv_anchor(plane: Plane, eye, period: float | None) -> tuple[np.ndarray, np.ndarray]:
    """(anchor, anchor_uv): the eye's foot on the plane, rounded to float32, and its `Plane.uv` in
    float64, reduced modulo `period` (the material's `uv_period`; None: not reduced). Both renderers
    take uv = ((p - anchor).t, (p - anchor).b) + anchor_uv: `Plane.uv` up to whole periods, which a
    repeating texture does not show, with every float32 term small near the eye however far `point`
    is (uv measured from `point` in float32 changed 88 of 256 pixels of a repeating texture with
    `point` 1e5 away, all of them 1e6 away). A clamped texture keeps its exact place, its uv
    measured from the anchor: precise where the eye looks, as (p - point) was."""
    normal = np.asarray(plane.normal, np.float64)
    eye = np.asarray(eye, np.float64)
    anchor = (eye - np.dot(eye - np.asarray(plane.point, np.float64), normal) * normal).astype(np.float32)
    anchor_uv = plane.uv(anchor[None].astype(np.float64))[0]
    return anchor, anchor_uv if period is None else np.mod(anchor_uv, period)


def plane_grid(plane: Plane, camera, period: float | None = None) -> geometry.TriMesh:
    """A grid of quads on the plane centred at the eye's foot, reaching 2 `far` each way, its lines
    spaced geometrically from a quarter of the eye's height: cells stay small (well-conditioned
    float32 interpolation) near the viewer and grow with distance. uv as a ray hit on the plane
    takes it (`plane_uv_anchor` with the material's texture `period`), in float64 at the vertices."""
    normal = np.asarray(plane.normal, float)
    point = np.asarray(plane.point, float)
    eye = np.asarray(camera.eye, float)
    centre = eye - np.dot(eye - point, normal) * normal
    a_axis = np.cross(normal, [0.0, 0.0, 1.0] if abs(normal[2]) < 0.9 else [1.0, 0.0, 0.0])
    a_axis /= np.linalg.norm(a_axis)
    b_axis = np.cross(a_axis, normal)
    height = abs(float(np.dot(eye - point, normal)))
    steps = np.geomspace(max(0.25 * height, 0.5 * camera.near), 2.0 * camera.far, PLANE_RINGS)
    s = np.concatenate([-steps[::-1], [0.0], steps])
    cells = s.size - 1
    aa, bb = np.meshgrid(s, s, indexing="ij")
    vertices = centre + aa[..., None] * a_axis + bb[..., None] * b_axis
    vertices = vertices.reshape(-1, 3)
    k = np.arange(cells)
    i, j = np.meshgrid(k, k, indexing="ij")
    v00 = (i * (cells + 1) + j).ravel()
    v10, v01, v11 = v00 + cells + 1, v00 + 1, v00 + cells + 2
    faces = np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)])
    if np.dot(np.cross(vertices[faces[0, 1]] - vertices[faces[0, 0]], vertices[faces[0, 2]] - vertices[faces[0, 0]]),
              normal) < 0:
        faces = faces[:, ::-1]
    normals = np.repeat(normal[None], len(vertices), axis=0)
    anchor, anchor_uv = plane_uv_anchor(plane, eye, period)
    uvs = (vertices - anchor) @ np.stack(plane.uv_frame(), axis=1) + anchor_uv
    return geometry.TriMesh(vertices, faces, normals, uvs)


@dataclass(frozen=True)
class AnalyticParts:
    """The analytic spheres and planes of a compiled scene as the rasterizer tessellates them, fixed
    when it is compiled (so its copies under other render settings tessellate alike): the objects as
    (Sphere | Plane, material id, object index) in scene order, the camera, and the sample rows
    (image height x spp side) a sphere's silhouette is made fine enough for (`sphere_segments`),
    and per object its material's `uv_period` (a plane's uv is reduced by whole periods of it).
    `phong` below: the spheres' triangles for Phong shading, else for flat and Gouraud's."""

    objects: tuple = ()
    camera: object = None
    sample_height: int = 0
    uv_periods: tuple = ()

    def sphere_grids(self, phong: bool) -> np.ndarray:
        """(n_lat, n_lon) per object of its uv sphere, (0, 0) for a plane: `sphere_segments`
        longitudes (all the spheres' at once), half as many bands."""
        is_sphere = np.array([isinstance(obj, Sphere) for obj, _, _ in self.objects], bool)
        spheres = [obj for obj, _, _ in self.objects if isinstance(obj, Sphere)]
        n_lon = sphere_segments(np.reshape([s.center for s in spheres], (-1, 3)), [s.radius for s in spheres],
                                self.camera, self.sample_height, phong)
        grids = np.zeros((len(self.objects), 2), np.int64)
        grids[is_sphere] = np.stack([np.maximum(2, n_lon // 2), n_lon], 1)
        return grids

    def size(self, phong: bool) -> tuple[int, int]:
        """(vertices, faces) that `tessellate` builds, counted without building them."""
        grids = self.sphere_grids(phong)
        n_lat, n_lon = grids[grids[:, 1] > 0].T
        vertices, faces = geometry.uv_sphere_size(n_lat, n_lon)
        planes = int((grids[:, 1] == 0).sum())
        plane_vertices, plane_faces = plane_grid_size()
        return int(vertices.sum()) + planes * plane_vertices, int(faces.sum()) + planes * plane_faces

    def tessellate(self, n_before: int, phong: bool) -> list:
        """Per object its raster triangles as (TriMesh, material id, object index). RenderError once
        the scene's triangles -- `n_before` (the meshes') and these so far -- pass the memory budget."""
        parts, triangles = [], n_before
        for (obj, material, index), (n_lat, n_lon), period in zip(self.objects, self.sphere_grids(phong),
                                                                   self.uv_periods):
            if isinstance(obj, Sphere):
                with object_errors(index, obj):
                    mesh = geometry.uv_sphere(obj.radius, obj.center, int(n_lat), int(n_lon))
            else:
                mesh = plane_grid(obj, self.camera, period)
            parts.append((mesh, material, index))
            triangles += mesh.n_faces
            require_triangles(triangles, f"objects[0..{index}]: raster triangles of the scene", RenderError)
        return parts
