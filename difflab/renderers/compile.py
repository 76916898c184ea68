"""Scene -> device arrays, once: the mesh objects' triangle soup, and the ray-traceable geometry
(analytic spheres and planes, plus a BVH over the mesh triangles) for shadow and other rays.

The rasterizer draws the analytic objects as triangles (`tessellate.py`: Phong shading's spheres
coarser than flat and Gouraud's) appended to the meshes' soup when it first draws the compiled
scene with that shading (`CompiledScene.raster`); ray tracing never builds them: rays see the
exact spheres and planes.
"""

from __future__ import annotations

import os
import sys
import threading
from dataclasses import dataclass, field

import numpy as np
from .._warp import wp

from .. import geometry
from ..errors import MeshError, RenderError
from ..guards import check_mesh_uvs, check_world_mesh, object_errors
from ..limits import require_triangles
from ..lighting.warp_model import lights_to_warp, materials_to_warp
from ..scene import Mesh, Plane, Scene, Sphere, load_scene
from .host import ROWS, host_carved, host_empty
from .intersect import SceneGeomW
from .launch import resolve_device
from .soup import PER_FACE, SOUP_DTYPES, device_soup, host_aliased, raster_room, soup_with_room, triangle_soup
from .tessellate import AnalyticParts, plane_uv_anchor
from .texture.store import TextureStore, scene_textures
from .trace import RAY_OFFSET_ULPS

RASTER_SOUP = "raster soup"  # keys in CompiledScene.built, with `phong` (`raster`): of a tessellation and the meshes,
RASTER_COPY = "raster copy"  # ... and of its last `raster()` copy
RASTER_ROOM = "raster room"  # the key of the host arrays the mesh fields are the first rows of (`soup_with_room`),
# with their device arrays where these alias them (`host_aliased`), else None; till the first tessellation takes them
MESH_ROWS = "mesh rows"  # ... and of the compiled mesh fields and `arrays` (`meshes`)


def _unheld_refs() -> int:
    """sys.getrefcount of an object that only a dict and one local variable hold, as `reusable`
    sees an array that no frame holds (measured: the count's baseline is an interpreter detail)."""
    pool = {"x": object()}
    array = pool.get("x")
    return sys.getrefcount(array)


_UNHELD = _unheld_refs()


class HostViews:
    """What `CompiledScene.reusable_structs` tests before it hands a frame's structs out again: their
    arrays, each referred to by the structs and the pool alone, and what a caller keeps with them
    (`keep`: numpy views of the arrays, which then refer to them too), each referred to no more than
    when kept -- every array a frame hands out is one of those views or a view of one."""

    def __init__(self, arrays: list):
        self.arrays, self.watched, self.limits, self.kept = arrays, arrays, [_UNHELD + 1] * len(arrays), None

    def unheld(self) -> bool:
        return all(count <= limit for count, limit in zip(_refs(self.watched), self.limits))

    def keep(self, kept, views) -> None:
        """Keep `kept` (what the caller made of the arrays: a `GBuffer` of views of them, say) with
        the structs; `views(kept)`: the numpy arrays in it that a frame hands out and every array
        they view (a view of any of them refers to one), which nothing may refer to now but `kept`:
        their counts now are the limits."""
        self.kept = kept
        self.watched = self.arrays + views(kept)
        self.limits = _refs(self.watched)


def _refs(items: list) -> list[int]:
    """sys.getrefcount of each item (each once more than its holders': as `_UNHELD` counts)."""
    return [sys.getrefcount(item) for item in items]


@dataclass(frozen=True)
class CompiledScene:
    """A scene on a device, built once by `compile_scene` and rendered any number of times by
    `render` / `render_frame` (with render-setting overrides: nothing is rebuilt). The mesh objects'
    triangles (those the BVH holds): world-space `vertices`, per-vertex `normals` (unit) and `uvs`,
    `faces`, and per face its material id, object id and geometric (winding) normal; numpy copies are
    kept beside the device arrays for the G-buffer's users. The rasterizer draws `raster(shading)`:
    the same fields with the analytic spheres' and planes' tessellation for that shading appended
    after the first `n_mesh_faces` faces (and `n_mesh_vertices` vertices), built when something
    first rasterizes the scene with it; ray tracing never builds it (and reads `meshes()`, even of a
    `raster()` copy). On the host the mesh fields are the first rows of the first-built `raster()`'s
    arrays (one copy of the mesh triangles: the rows after them are left unwritten until then,
    untouched pages hold no memory; a scene drawn with the other tessellation too copies them once
    more); so are the device arrays on the CPU, which alias them; on a GPU compiling uploads the
    mesh rows alone, and `raster()` the whole soup."""

    scene: object
    device: str
    vertices: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    faces: np.ndarray
    face_material: np.ndarray
    face_object: np.ndarray
    face_normal: np.ndarray
    vertex_material: np.ndarray  # per vertex, its object's material and index (Gouraud's vertex points)
    vertex_object: np.ndarray
    n_mesh_faces: int
    n_mesh_vertices: int
    epsilon: float
    arrays: dict  # name -> wp.array on the device
    geom: SceneGeomW  # spheres, planes and the faces' ids; no BVH (geom.mesh 0): see `traceable`
    lights: wp.array
    materials: wp.array
    textures: TextureStore | None = None  # every material's image texture; `textures.warp` for kernels
    analytic: AnalyticParts = field(default_factory=AnalyticParts)  # what `raster` tessellates
    built: dict = field(default_factory=dict, compare=False, repr=False)  # parts built on first use, shared by copies

    def raster(self, shading: str | None = None) -> CompiledScene:
        """This compiled scene with the rasterizer's triangles for `shading` ("flat", "gouraud",
        "phong"; None: its scene's `render.shading`) in `vertices`, `faces`, ... and `arrays`: the
        meshes' (the first `n_mesh_faces`), then the analytic spheres' and planes' tessellation
        (`AnalyticParts`; Phong's spheres coarser: `tessellate.sphere_segments`), each of the two
        built when first asked for (`build_once`; `with_scene` copies share them). Itself when the
        scene has no analytic objects. RenderError, when building, if the triangles pass the memory
        budget (a ray-traced scene of many spheres compiles and renders all the same). The copy for
        the last scene asked for is kept per tessellation (a copy costs ~50 us of a fit's cold frame)."""
        if not self.analytic.objects:
            return self
        phong = (shading or self.scene.render.shading) == "phong"
        kept = self.built.get((RASTER_COPY, phong))
        if kept is None or kept.scene is not self.scene:  # (every copy sharing `built` has the same soups)
            soup = self.build_once((RASTER_SOUP, phong), lambda: self._raster_soup(phong))
            kept = self.built[(RASTER_COPY, phong)] = self.copy_with(**soup)
        return kept

    def _raster_soup(self, phong: bool) -> dict:
        """The triangle fields and `arrays` of `raster()`: the analytic objects' triangles
        (`triangle_soup` of `AnalyticParts.tessellate`) written into the rows after the meshes' in
        the arrays compiling left room in (`RASTER_ROOM`, sized for the larger tessellation) -- the
        values `triangle_soup` gives all of them at once -- by the first tessellation built (the
        other one built later, or where no room was left: the tessellation passed the memory budget
        when compiled, not now, copies the mesh rows into new arrays with room). On the CPU the
        device arrays are the host's (written with them); elsewhere (a GPU) the soup is uploaded
        here: compiling uploaded the mesh rows alone."""
        added = triangle_soup(self.analytic.tessellate(self.n_mesh_faces, phong))
        added["faces"] += np.int32(self.n_mesh_vertices)
        n_vertices, n_faces = self.n_mesh_vertices + len(added["vertices"]), self.n_mesh_faces + len(added["faces"])
        host, device = self.built.pop(RASTER_ROOM, (None, None))  # (pop: one taker, whichever lock it holds)
        if host is None or len(host["faces"]) < n_faces or len(host["vertices"]) < n_vertices:
            host = soup_with_room({name: self.built[MESH_ROWS][name] for name in SOUP_DTYPES}, n_vertices, n_faces)
            device = None
        soup = {}
        for name in SOUP_DTYPES:
            first = self.n_mesh_faces if name in PER_FACE else self.n_mesh_vertices
            soup[name] = host[name][:first + len(added[name])]  # the first rows of the room
            soup[name][first:] = added[name]
        arrays = device_soup(soup, self.device) if device is None else {
            name: values if values.shape[0] == len(soup[name]) else values[:len(soup[name])]
            for name, values in device.items()}
        return dict(soup, arrays=arrays)

    def meshes(self) -> CompiledScene:
        """This compiled scene with the mesh objects' triangles alone in `vertices`, `faces`, ... and
        `arrays` (what the ray tracer reads: rays see the exact spheres and planes): itself, or, for
        a `raster()` copy, the fields and arrays as compiled (`MESH_ROWS`)."""
        if self.faces.shape[0] == self.n_mesh_faces and self.vertices.shape[0] == self.n_mesh_vertices:
            return self
        return self.copy_with(**self.built[MESH_ROWS])

    def build_once(self, name: str, build):
        """`built[name]`, made by `build()` on first use -- by one thread: others asking for it at the
        same time wait for that one (a part built twice would free the first one under its users:
        a BVH is referred to by its id) -- and kept for every later render of this compiled scene."""
        part = self.built.get(name)
        if part is None:
            with self.built.setdefault(("lock", name), threading.Lock()):  # setdefault: whoever comes first's lock
                part = self.built.get(name)
                if part is None:
                    part = self.built[name] = build()
        return part

    def with_scene(self, scene) -> CompiledScene:
        """The same device data under `scene`: the compiled scene with other render settings (itself
        for its own scene)."""
        return self if scene is self.scene else self.copy_with(scene=scene)

    def copy_with(self, **fields) -> CompiledScene:
        """This compiled scene with `fields` (of its own) replaced: `dataclasses.replace` without
        running __init__ again (24 fields: ~5 us warm, ~45 us of a fit's cold frame, where each fit's
        view scene is a new object and its frame a new copy); nothing here is computed in __init__."""
        copy = object.__new__(CompiledScene)
        copy.__dict__.update(self.__dict__, **fields)
        return copy

    def scratch(self, name: str, shape, dtype, fill=None) -> wp.array:
        """A device array `name` for one frame's intermediate results, kept for this compiled scene's
        next frame (fresh memory costs a page fault per 4 KiB on every frame). It holds whatever the
        last frame left (`fill` when new); one set per thread, so threads rendering the same
        compiled scene never share."""
        shape = (shape,) if isinstance(shape, int) else tuple(shape)
        pool = self.scratch_pool()
        array = pool.get(name)
        if array is None or array.shape != shape or array.dtype != dtype:
            array = pool[name] = host_empty(shape, dtype, self.device)
            if fill is not None:
                array.fill_(fill)
        return array

    def reusable(self, name: str, shape, dtype, zeroed: bool = False) -> wp.array:
        """A device array `name` for a frame's output, which the returned numpy arrays view (on the
        CPU): this thread's array from an earlier frame when nothing but the pool refers to it any
        more -- that frame and every view of it are gone (the reference count test of numpy's
        `resize(refcheck=True)`) -- else a new one, kept for the next frames. Fresh memory costs
        a page fault per 4 KiB (~1.5 ms of a 256^2 G-buffer). Zero when `zeroed`, else holding
        whatever the last frame left."""
        shape = (shape,) if isinstance(shape, int) else tuple(shape)
        pool = self.scratch_pool()
        key = ("reusable", name)
        array = pool.get(key)
        if array is None or array.shape != shape or array.dtype != dtype or sys.getrefcount(array) > _UNHELD:
            pool[key] = host_empty(shape, dtype, self.device, zeroed=zeroed)  # an old one stays with its frame
        elif zeroed:
            array.zero_()
        return pool[key]

    def reusable_structs(self, name: str, layout: tuple) -> tuple[list, wp.array | None, HostViews]:
        """Instances of Warp structs whose fields are a frame's output arrays, `layout` a tuple of
        (struct type, ((field, shape tuple, dtype, zero), ...)): this thread's from an earlier frame, as
        they were, when none of their arrays is held any more (as `reusable` tests it, the struct's
        own reference aside; nor any numpy view kept with them: `HostViews`) -- with the buffer the
        `zero` arrays are carved from, stale, for the caller to zero in one memset -- else new ones,
        those arrays carved from one new zero buffer (and None); and their `HostViews`. One memset: a
        pool worker zeroing the 15 arrays of a 256^2 G-buffer one by one re-took the GIL between them
        while the frame's thread waited (~0.1 ms a frame); the structs kept: filling them anew costs
        ~30 us warm, ~125 us of a fit's cold frame. A `zero` of ROWS: zero, and a column of the one
        rows block (`host_carved`)."""
        pool = self.scratch_pool()
        kept = pool.get(("structs", name))
        if kept is not None and kept[0] == layout and kept[4].unheld():
            return kept[2], kept[3], kept[4]
        buffer, carved = host_carved([(shape, dtype, zero == ROWS) for unused, fields in layout
                                      for unused, shape, dtype, zero in fields if zero], self.device)
        carved, arrays, structs = iter(carved), [], []
        for struct, fields in layout:
            structs.append(struct())
            for field, shape, dtype, zero in fields:
                arrays.append(next(carved) if zero else host_empty(shape, dtype, self.device))
                setattr(structs[-1], field, arrays[-1])
        views = HostViews(arrays)
        pool[("structs", name)] = (layout, arrays, structs, buffer, views)  # old ones stay with their frame
        return structs, None, views

    def scratch_pool(self) -> dict:
        """This thread's `scratch` arrays by name (a renderer may keep notes about them there too)."""
        return self.built.setdefault(("scratch", threading.get_ident()), {})

    def traceable(self) -> SceneGeomW:
        """`geom` with the BVH over the mesh faces, built on first use (rasterizing without shadows
        never needs it; `build_once`) and kept for every later render of this compiled scene."""
        return self.build_once("geom", self._with_bvh)

    def _with_bvh(self) -> SceneGeomW:
        if not self.n_mesh_faces:
            return self.geom
        meshes = self.meshes()  # rays see the exact spheres and planes
        indices = wp.array(meshes.faces.ravel(), dtype=wp.int32, device=self.device)
        self.built["bvh"] = wp.Mesh(points=meshes.arrays["vertices"], indices=indices)
        geom = SceneGeomW()
        for name in SceneGeomW.vars:
            setattr(geom, name, getattr(self.geom, name))
        geom.mesh = self.built["bvh"].id
        return geom


def object_mesh(obj, base_dir=None) -> geometry.TriMesh:
    """The world-space triangle mesh of a scene `Mesh` object (smooth or faceted normals)."""
    if obj.vertices is not None:
        mesh = geometry.TriMesh(obj.vertices, obj.faces, obj.normals, obj.uvs)
    elif obj.file is not None:
        mesh = geometry.load_mesh(obj.file)
    elif obj.builtin == "teapot":
        mesh = geometry.teapot(obj.resolution)
    elif obj.builtin == "sphere":
        mesh = geometry.uv_sphere(1.0, n_lat=max(2, obj.resolution), n_lon=max(3, 2 * obj.resolution))
    elif obj.builtin == "box":
        mesh = geometry.box(divisions=obj.resolution)
    elif obj.builtin == "cylinder":
        mesh = geometry.cylinder(segments=max(3, 4 * obj.resolution))
    else:
        mesh = geometry.quad(divisions=obj.resolution)
    t = obj.transform
    matrix = None if t.matrix is None else np.asarray(t.matrix, float).reshape(4, 4)
    mesh = mesh.transformed(geometry.transform_matrix(t.translate, t.rotate_deg, t.scale, matrix))
    if mesh.normals is None and obj.smooth:
        mesh = geometry.TriMesh(mesh.vertices, mesh.faces, mesh.smooth_normals(), mesh.uvs)
    if not obj.smooth:
        mesh = facet(mesh)
    return mesh


def facet(mesh: geometry.TriMesh) -> geometry.TriMesh:
    """Unweld a mesh so each face has its own three vertices carrying the face normal."""
    faces = mesh.faces
    corners = faces.reshape(-1)
    normals = np.repeat(geometry.face_normals(mesh.vertices, faces), 3, axis=0)
    uvs = None if mesh.uvs is None else mesh.uvs[corners]
    return geometry.TriMesh(mesh.vertices[corners], np.arange(corners.size).reshape(-1, 3), normals, uvs)


def scene_parts(scene):
    """The mesh objects' raster triangles as (TriMesh, material id, object index), and the analytic
    spheres and planes as (object, material id, object index), each in scene order."""
    names = scene.material_names
    mesh_parts, analytic = [], []
    triangles = 0
    for index, obj in enumerate(scene.objects):
        material = names.index(obj.material)
        if isinstance(obj, Mesh):
            with object_errors(index, obj):
                mesh = object_mesh(obj)
            check_world_mesh(mesh, index, obj)
            check_mesh_uvs(mesh, index, obj, scene.materials[obj.material])
            mesh_parts.append((mesh, material, index))
            triangles += mesh.n_faces
            require_triangles(triangles, f"objects[0..{index}]: triangles of the scene's meshes", RenderError)
        elif isinstance(obj, (Sphere, Plane)):
            analytic.append((obj, material, index))
        else:  # pragma: no cover - the scene validates object types
            raise RenderError(f"objects[{index}]: cannot render {type(obj).__name__}")
    return mesh_parts, analytic


def object_offset(mesh_vertices: np.ndarray, spheres, planes=()) -> float:
    """The least offset (scene units) of a rasterized point's shadow rays (`trace.point_offset`):
    RAY_OFFSET_ULPS x 2^-23 x the largest coordinate (max-norm) of the scene's objects -- the mesh
    vertices, the spheres' |c_i| + r, the planes' points -- whose rounding reaches a point
    interpolated on their triangles. Neither the eye nor the far plane counts."""
    extent = [0.0, float(np.abs(mesh_vertices).max(initial=0.0))]
    extent += [float(np.abs(sphere.center).max()) + sphere.radius for sphere, _, _ in spheres]
    extent += [float(np.abs(plane.point).max()) for plane, _, _ in planes]
    return RAY_OFFSET_ULPS * 2.0 ** -23 * max(extent)


def ray_geometry(arrays: dict, mesh_vertices: np.ndarray, spheres, planes, anchors, epsilon: float, device: str):
    """The ray-traceable scene's spheres and planes, and its mesh faces' ids; the BVH over the faces
    is built when a ray first needs it (`CompiledScene.traceable`), geom.mesh is 0 until then.
    `mesh_vertices`: the vertices the mesh faces use (MeshError unless finite); `anchors`: each
    plane's `plane_uv_anchor`."""
    def arr(values, dtype):
        return wp.array(np.ascontiguousarray(values), dtype=dtype, device=device)

    geom = SceneGeomW()
    geom.mesh = wp.uint64(0)
    if not np.all(np.isfinite(mesh_vertices)):
        raise MeshError("mesh vertices are not finite after transforming")
    geom.face_material, geom.face_object = arrays["face_material"], arrays["face_object"]
    geom.sphere_center = arr(np.array([s.center for s, _, _ in spheres], np.float32).reshape(-1, 3), wp.vec3)
    geom.sphere_radius = arr(np.array([s.radius for s, _, _ in spheres], np.float32), float)
    geom.sphere_material = arr(np.array([m for _, m, _ in spheres], np.int32), wp.int32)
    geom.sphere_object = arr(np.array([o for _, _, o in spheres], np.int32), wp.int32)
    geom.plane_point = arr(np.array([p.point for p, _, _ in planes], np.float32).reshape(-1, 3), wp.vec3)
    geom.plane_normal = arr(np.array([p.normal for p, _, _ in planes], np.float32).reshape(-1, 3), wp.vec3)
    frames = np.array([p.uv_frame() for p, _, _ in planes], np.float32).reshape(-1, 2, 3)
    geom.plane_tangent = arr(frames[:, 0], wp.vec3)
    geom.plane_bitangent = arr(frames[:, 1], wp.vec3)
    geom.plane_anchor = arr(np.array([anchor for anchor, _ in anchors], np.float32).reshape(-1, 3), wp.vec3)
    geom.plane_anchor_uv = arr(np.array([uv for _, uv in anchors], np.float32).reshape(-1, 2), wp.vec2)
    geom.plane_material = arr(np.array([m for _, m, _ in planes], np.int32), wp.int32)
    geom.plane_object = arr(np.array([o for _, _, o in planes], np.int32), wp.int32)
    geom.epsilon = float(epsilon)
    return geom


def as_scene(scene) -> Scene:
    """A Scene from a Scene, a dict in the file format, or a path to a scene file."""
    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, dict):
        return Scene.from_dict(scene)
    if isinstance(scene, (str, os.PathLike)):
        return load_scene(scene)
    raise RenderError(f"scene: expected a Scene, a dict or a path, got {type(scene).__name__}")


def compile_scene(scene, device: str = "cpu") -> CompiledScene:
    """Build the device arrays, BVH and textures of `scene` (a Scene, dict or path) once.

    The mesh objects' triangles are built here; the rasterizer's tessellation of the analytic
    spheres (finely enough for the scene's camera and spp, one for Phong shading and one for flat
    and Gouraud's: `tessellate.sphere_segments`) and planes (grids around the camera's eye) when
    something first rasterizes it with that shading (`CompiledScene.raster`).
    """
    scene = as_scene(scene)
    device = resolve_device(device)
    mesh_parts, analytic = scene_parts(scene)
    soup = triangle_soup(mesh_parts)
    n_mesh_faces = soup["faces"].shape[0]
    n_mesh_vertices = soup["vertices"].shape[0]
    ordered = [scene.materials[name] for name in scene.material_names]
    parts = AnalyticParts(tuple(analytic), scene.camera, scene.camera.height * scene.render.spp_side,
                          tuple(ordered[material].uv_period for _, material, _ in analytic))
    room_vertices, room_faces = raster_room(parts, n_mesh_faces) if analytic else (0, 0)
    room = soup_with_room(soup, n_mesh_vertices + room_vertices, n_mesh_faces + room_faces) if analytic else soup
    soup = {name: values[:n_mesh_faces if name in PER_FACE else n_mesh_vertices] for name, values in room.items()}
    room_arrays = device_soup(room, device) if host_aliased(device) else None  # a GPU's: uploaded when rasterized
    arrays = device_soup(soup, device) if room_arrays is None else {  # the mesh rows
        name: values if values.shape[0] == len(soup[name]) else values[:len(soup[name])]  # warp: no [:0] of an
        for name, values in room_arrays.items()}  # empty array
    used = np.zeros(n_mesh_vertices, bool)  # the vertices of the mesh faces, each once
    used[soup["faces"].ravel()] = True
    mesh_vertices = soup["vertices"][used]
    spheres = [part for part in analytic if isinstance(part[0], Sphere)]
    planes = [part for part in analytic if isinstance(part[0], Plane)]
    epsilon = object_offset(mesh_vertices, spheres, planes)
    anchors = [plane_uv_anchor(plane, scene.camera.eye, ordered[material].uv_period) for plane, material, _ in planes]
    geom = ray_geometry(arrays, mesh_vertices, spheres, planes, anchors, epsilon, device)
    textures, texture_ids = scene_textures(ordered, device)
    return CompiledScene(
        scene=scene, device=device, **soup, n_mesh_faces=n_mesh_faces, n_mesh_vertices=n_mesh_vertices,
        epsilon=epsilon, arrays=arrays, geom=geom,
        lights=lights_to_warp(scene.lights, device), materials=materials_to_warp(ordered, device, texture_ids),
        textures=textures, analytic=parts,
        built={RASTER_ROOM: (room, room_arrays), MESH_ROWS: dict(soup, arrays=arrays)},
    )
