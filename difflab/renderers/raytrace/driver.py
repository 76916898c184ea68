"""The Whitted ray tracer's driver: sample points -> ray trees (`rt_kernels`) -> Frame.

    frame = raytrace(compile_scene(scene), scene.render)

Supersampling (`spp` = side^2, a perfect square) places side x side samples in every pixel:
"grid" at the centres of a regular side x side subdivision, (j + (b + 0.5) / side, i + (a + 0.5) /
side) for sub-sample (a, b) of pixel (i, j) -- the rasterizer's sample grid; "stratified" one
sample uniformly inside each of those cells, drawn once from numpy's PCG64 seeded with
STRATIFIED_SEED (the same pattern on every render). The pixel is the mean of its samples.

The trace runs in two passes when the ray tree is recorded: the first renders the image and counts
every sample's nodes, the second (sized exactly from those counts) walks the same trees again and
writes them. The walk is a row loop (`launch.launch_row_loops`: rows dealt to bands on all cores, a
row per thread there, a sample per thread on CUDA); every output element is written by one thread
(the ray counts are integer sums), so renders are bitwise deterministic.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass

import numpy as np
from ..._warp import wp

from ...errors import RenderError
from ...guards import nonfinite_pixels
from ...lighting.warp_model import fog_struct
from ...vocabulary import FRESNEL_MODES, SPECULAR_MODELS
from ..camera import camera_struct
from ..frame import Frame, box_downsample
from ..host import host_empty
from ..launch import launch_row_loops, load_kernels, row_spans
from .gbuffer import tree_gbuffer
from .itembuffer import asked_bvh, item_buffer, item_struct
from .lightbuffer import build_light_buffer, no_light_buffer
from .medium import camera_media, transparent_objects
from .kernels import COUNT_COLUMNS, COUNT_PRIMARY, COUNT_REFLECTED, COUNT_REFRACTED, COUNT_SHADOW, COUNT_SHADOW_CUT, \
    COUNT_SHADOW_TESTS, TraceOutW, TraceParamsW, whitted_kernel
from .nesting import media_struct
from .record import empty_tree, has_textures, sized_tree, tree_to_numpy
from .surface import MeshDataW, SceneW
from .tree import RayTree

STRATIFIED_SEED = 20240917


@dataclass(frozen=True)
class Traced:
    """What one launch over an array of sample points returns (numpy, on the points' grid). `fog` and
    `node_count` live in the compiled scene's per-frame arrays: valid until its next trace on this thread."""

    color: np.ndarray  # (rows, cols, 3) float32
    fog: np.ndarray  # (rows, cols) float32
    node_count: np.ndarray  # (rows, cols) int32
    rays: dict  # primary / shadow / reflection / refraction -> count
    depth_histogram: list  # rays traced at depth 1, 2, ...
    tree: RayTree | None
    shadow_tests: int = 0  # candidates the light buffer's shadow rays tested (0 without one)
    shadow_rays_cut: int = 0  # shadow rays cut past trace.MAX_SHADOW_CROSSINGS transparent surfaces (`shadow_ray`)
    asked_bvh: int = 0  # samples whose primary mesh hit the item buffer left to the BVH (ambiguous hints)
    nonfinite_samples: int = 0  # samples whose colour is not finite


def sample_points(width: int, height: int, side: int, sampling: str = "grid") -> np.ndarray:
    """Raster positions (H*side, W*side, 2) float32 (x, y) of the supersampling pattern (see module doc)."""
    rows, cols = height * side, width * side
    if sampling == "grid":
        jx = np.full((rows, cols), 0.5)
        jy = np.full((rows, cols), 0.5)
    elif sampling == "stratified":
        rng = np.random.default_rng(STRATIFIED_SEED)
        jx, jy = rng.random((rows, cols)), rng.random((rows, cols))
    else:
        raise RenderError(f"sampling: expected 'grid' or 'stratified', got {sampling!r}")
    x = (np.arange(cols)[None, :] + jx) / side
    y = (np.arange(rows)[:, None] + jy) / side
    return np.stack([x, y], axis=-1).astype(np.float32)


def trace_params(scene, settings, record: bool, footprint: float, side: int,
                 media: tuple[tuple, bool]) -> TraceParamsW:
    params = TraceParamsW()
    params.media, params.start_check = media_struct(media[0]), int(media[1])
    params.side = int(side)
    params.max_depth = int(settings.max_depth)
    params.shadows = int(settings.shadows)
    params.transparent = int(settings.transparent_shadows)
    params.specular = SPECULAR_MODELS[settings.specular]
    params.fresnel = FRESNEL_MODES[settings.fresnel]
    params.threshold = float(settings.adaptive_threshold)
    params.ambient = wp.vec3(*scene.ambient)
    params.background = wp.vec3(*scene.background)
    params.far = float(scene.camera.far)
    params.fog = fog_struct(scene.fog)
    params.record = int(record)
    params.count_crossings = int(record and count_crossings(scene, settings))
    params.footprint = float(footprint)
    return params


def count_crossings(scene, settings) -> bool:
    """Whether shadow rays can cross transparent surfaces (their kt then enters the visibility)."""
    return bool(settings.shadows and settings.transparent_shadows and any(m.kt > 0 for m in scene.materials.values()))


def scene_struct(compiled, light_buffer=None) -> SceneW:
    """The compiled scene as the kernel's `SceneW` (with `light_buffer`'s candidate lists, if given)."""
    mesh = MeshDataW()
    mesh.vertices = compiled.arrays["vertices"]
    mesh.normals = compiled.arrays["normals"]
    mesh.uvs = compiled.arrays["uvs"]
    mesh.faces = compiled.arrays["faces"]
    out = SceneW()
    out.geom, out.mesh, out.lights, out.materials = compiled.traceable(), mesh, compiled.lights, compiled.materials
    out.textures = compiled.textures.warp
    out.probe_coincident = int(transparent_objects(compiled) >= 2)
    out.light_buffer = light_buffer.warp if light_buffer is not None else \
        read_only(compiled, "no light buffer", lambda: no_light_buffer(compiled))
    return out


def read_only(compiled, name: str, make):
    """`make()` (device arrays no kernel writes) made once per compiled scene and kept in `built`:
    a render does not pay for allocating them again."""
    if name not in compiled.built:
        compiled.built[name] = make()
    return compiled.built[name]


def trace_points(compiled, settings, points: np.ndarray | None, threads: int | None = None, *, side: int = 0,
                 footprint: float = 1.0, record: bool = False, item=None,
                 pixel_size: tuple[int, int] | None = None, light_buffer=None) -> Traced:
    """Trace one ray tree per raster point of `points` (rows, cols, 2), in pixels of the camera's
    image (or of `pixel_size` = (width, height)); with `points` None, per sample of the regular
    grid of `side` x `side` samples per pixel ("grid" `sample_points`, computed by the kernel).
    `footprint`: a sample's width in pixels, what its texture filters cover (1 / side when side x
    side samples share a pixel, as on the rasterizer's sample grid).
    `item`: an `ItemBufferW` on the same grid; `light_buffer`: a `lightbuffer.LightBuffer` for the
    shadow rays. A `raster()` copy is traced as its `meshes()`: rays see the exact spheres and planes."""
    compiled = compiled.meshes()
    scene, device = compiled.scene, compiled.device
    kernel = whitted_kernel(settings.max_depth)
    load_kernels(device, kernel)
    width, height = pixel_size or (scene.camera.width, scene.camera.height)
    if points is None:
        rows, cols = height * side, width * side
        points = np.zeros((1, 1, 2), np.float32)  # not read
    else:
        rows, cols = points.shape[:2]
        side = 0
    cam = camera_struct(scene.camera, width, height)
    n_lights = len(scene.lights)
    shape = (rows, cols)
    wp_points = wp.array(np.ascontiguousarray(points, np.float32), dtype=wp.vec2, device=device)
    item = item if item is not None else item_struct(compiled)
    scene_w = scene_struct(compiled, light_buffer)
    media = camera_media(compiled)

    def launch(params, tree) -> TraceOutW:
        out = TraceOutW()
        out.color = host_empty(shape, wp.vec3, device)  # every element written by the kernel
        out.fog = compiled.scratch("trace.fog", shape, wp.float32)  # read before this render returns
        out.node_count = compiled.scratch("trace.node_count", shape, wp.int32)
        out.rays = wp.zeros((rows, COUNT_COLUMNS), dtype=wp.int32, device=device)
        out.depth_hist = wp.zeros((rows, settings.max_depth), dtype=wp.int32, device=device)
        out.nonfinite = wp.empty(rows * row_spans(cols, device), dtype=wp.int32, device=device)
        launch_row_loops(kernel, shape, [wp_points, cam, scene_w, params, item, tree, out], device, threads)
        return out

    unrecorded = read_only(compiled, "unrecorded tree", lambda: empty_tree((1, 1), 0, 0, device))  # not read
    out = launch(trace_params(scene, settings, False, footprint, side, media), unrecorded)
    asked = asked_bvh(item)  # read before the recording pass adds its own
    counts = out.node_count.numpy()
    ray_counts = out.rays.numpy().astype(np.int64).sum(axis=0)
    stats_rays = {"primary": int(ray_counts[COUNT_PRIMARY]), "shadow": int(ray_counts[COUNT_SHADOW]),
                  "reflection": int(ray_counts[COUNT_REFLECTED]), "refraction": int(ray_counts[COUNT_REFRACTED])}
    histogram = [int(h) for h in out.depth_hist.numpy().astype(np.int64).sum(axis=0)]
    fog = out.fog.numpy()
    tree = None
    if record:
        crossings = count_crossings(scene, settings)
        wp_tree, offsets = sized_tree(counts, n_lights, len(scene.materials) if crossings else 0, device,
                                      has_textures(scene))
        launch(trace_params(scene, settings, True, footprint, side, media), wp_tree)
        tree = tree_to_numpy(wp_tree, offsets, n_lights, fog, scene, settings, shape, crossings)
    return Traced(color=out.color.numpy(), fog=fog, node_count=counts, rays=stats_rays,
                  depth_histogram=histogram, tree=tree, shadow_tests=int(ray_counts[COUNT_SHADOW_TESTS]),
                  asked_bvh=asked, nonfinite_samples=int(out.nonfinite.numpy().sum()),
                  shadow_rays_cut=int(ray_counts[COUNT_SHADOW_CUT]))


def raytrace(compiled, settings, threads: int | None = None, *, record_tree: bool = True,
             use_item_buffer: bool | None = None, use_light_buffer: bool = False,
             light_buffer_resolution: int | None = None) -> Frame:
    """Ray-trace a compiled scene under `settings` (a scene `RenderSettings`).

    Arguments:
        compiled: `compile_scene(scene, device)` (or its `raster()` copy: traced as the meshes alone).
        settings: max_depth, spp (a perfect square), sampling, fresnel, shadows, transparent_shadows,
            specular, adaptive_threshold are used.
        threads: CPU worker threads (default: all cores, or $DIFFLAB_THREADS).
        record_tree: also record the ray tree (a second pass over the same trees).
        use_item_buffer: the primary rays' mesh hits from the rasterizer's z-buffer (`itembuffer.py`:
            the BVH's own hits, the BVH asked where the z-buffer is ambiguous); needs "grid"
            sampling, whose samples are the rasterizer's. None (default): on wherever it applies
            (grid sampling and mesh triangles in the scene); False: every primary ray asks the BVH.
        use_light_buffer: shadow rays to point and spot lights test only the candidates of their
            light-buffer cell (`lightbuffer.py`), built for this render with
            `light_buffer_resolution` cells per cube-face edge (None: scaled to the mesh size);
            the image is the same.

    Returns: a `Frame` with `image` (H, W, 3) float32 linear RGB, `ray_tree` (a `RayTree` or None),
    the G-buffer of its primary hits built from the tree when `frame.gbuffer` is first read
    (`gbuffer.tree_gbuffer`; RenderError without a recorded tree) and `stats`: rays traced per
    kind, `depth_histogram` (rays per depth, from 1), `nodes`, `seconds`, `rays_per_second`,
    `nonfinite_pixels`, `shadow_rays_cut` (shadow rays that met more than
    `trace.MAX_SHADOW_CROSSINGS` transparent surfaces and would otherwise have reached the light,
    counted as blocked; one an opaque surface blocks anywhere is not cut, on either shadow path); with the light buffer also
    `light_buffer_seconds` (building it, included in `seconds`), `light_buffer_entries` and
    `shadow_tests` (candidates tested by all shadow rays).
    """
    compiled = compiled.meshes()  # a `raster()` copy's tessellation is not traced: rays see the exact spheres
    scene = compiled.scene
    side = settings.spp_side  # the scene validated spp and the sample budget
    width, height = scene.camera.width, scene.camera.height
    if use_item_buffer and settings.sampling != "grid":
        raise RenderError(f"sampling: the item buffer holds the rasterizer's regular sample grid; it needs "
                          f"sampling 'grid', got {settings.sampling!r}")
    if use_item_buffer is None:
        use_item_buffer = settings.sampling == "grid" and compiled.n_mesh_faces > 0
    start = time.perf_counter()
    points = None if settings.sampling == "grid" else sample_points(width, height, side, settings.sampling)
    item, kept, culled = (item_buffer(compiled, width * side, height * side, threads) if use_item_buffer
                          else (None, False, False))
    built = time.perf_counter()
    lights = build_light_buffer(compiled, light_buffer_resolution) if use_light_buffer else None
    built = time.perf_counter() - built
    traced = trace_points(compiled, settings, points, threads, side=side, footprint=1.0 / side,
                          record=record_tree, item=item, light_buffer=lights)
    image = box_downsample(traced.color, side)
    seconds = time.perf_counter() - start
    total_rays = sum(traced.rays.values())
    stats = {"method": "raytrace", "seconds": seconds, "samples": int(traced.color.shape[0] * traced.color.shape[1]),
             "spp": settings.spp, "sampling": settings.sampling, "max_depth": settings.max_depth,
             "rays": dict(traced.rays), "total_rays": total_rays, "rays_per_second": total_rays / max(seconds, 1e-9),
             "depth_histogram": traced.depth_histogram, "nodes": int(traced.node_count.sum()),
             "item_buffer": bool(use_item_buffer), "item_buffer_kept": kept, "item_buffer_culled": culled,
             "item_buffer_asked_bvh": traced.asked_bvh, "shadow_rays_cut": traced.shadow_rays_cut,
             "recorded_tree": bool(record_tree),
             "nonfinite_pixels": nonfinite_pixels(image) if traced.nonfinite_samples else 0}
    if lights is not None:
        stats.update(light_buffer_seconds=built, light_buffer_entries=lights.entries, shadow_tests=traced.shadow_tests)
    source = None if traced.tree is None else \
        functools.partial(tree_gbuffer, traced.tree, scene, compiled.vertices, compiled.faces)
    return Frame(image=image, buffers=None, stats=stats, ray_tree=traced.tree, gbuffer_source=source)
