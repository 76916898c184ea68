"""The rasterizer's driver: allocate once per frame, launch the stages (see the package doc), return a Frame.

`rasterize(..., gbuffer=True)` keeps every stage's output (the G-buffer `render_frame` and the fits
read); with gbuffer=False, what `render` asks for, stages 4, 6 and 7 run fused per sample
(`shade.image_kernel`) and store nothing but the image.
"""

from __future__ import annotations

import time

import numpy as np
from ..._warp import wp

from ...errors import RenderError
from ...guards import nonfinite_pixels
from ...limits import check_raster_work
from ...lighting.warp_model import fog_params, fog_struct
from ...vocabulary import FLAT, GOURAUD, PHONG_SHADING, SHADING_MODELS, SPECULAR_MODELS
from . import clip, coverage, resolve, shade
from ..camera import camera_struct
from ..frame import Frame, GBuffer, ShadingPoints, box_downsample
from ..launch import band_plan, launch_chunks, launch_row_loops, load_kernels, run_bands


def empty_points(count: int, device: str) -> resolve.PointsW:
    """Arrays for `count` shading points, zeroed (uncovered samples keep zeros in the G-buffer)."""
    points = resolve.PointsW()
    for name, dtype in [("position", wp.vec3), ("normal", wp.vec3), ("geo_normal", wp.vec3), ("view", wp.vec3),
                        ("material", wp.int32), ("cell", wp.int32), ("ignore", wp.int32), ("uv", wp.vec2),
                        ("duv_dx", wp.vec2), ("duv_dy", wp.vec2)]:
        setattr(points, name, wp.zeros(count, dtype=dtype, device=device))
    return points


def raster_mesh(compiled) -> resolve.RasterMeshW:
    mesh = resolve.RasterMeshW()
    for name in ("faces", "vertices", "normals", "uvs", "face_normal", "face_material", "face_object",
                 "vertex_material", "vertex_object"):
        setattr(mesh, name, compiled.arrays[name])
    mesh.n_mesh_faces, mesh.n_mesh_vertices = compiled.n_mesh_faces, compiled.n_mesh_vertices
    return mesh


def lighting_struct(compiled, settings) -> shade.LightingW:
    out = shade.LightingW()
    out.lights, out.materials, out.textures = compiled.lights, compiled.materials, compiled.textures.warp
    out.geom = compiled.traceable() if settings.shadows else compiled.geom  # shadow rays need the BVH
    out.specular = SPECULAR_MODELS[settings.specular]
    out.ambient = wp.vec3(*compiled.scene.ambient)
    out.shadows, out.transparent = int(settings.shadows), int(settings.transparent_shadows)
    return out


def bin_rows(rows: np.ndarray, bands: list[tuple[int, int]], height: int) -> list[np.ndarray]:
    """Per band of rows, the slots whose sample rows [first, last] meet it (empty slots: last < first).

    Slots are sorted by the band of their first row (a radix sort on a small key); the few that
    reach into later bands are added to those too."""
    first, last = rows[:, 0], rows[:, 1]
    drawn = np.flatnonzero((last >= first) & (last >= 0) & (first < height)).astype(np.int32)
    band_of_row = np.repeat(np.arange(len(bands), dtype=np.uint16), [b - a for a, b in bands])
    band_first = band_of_row[np.clip(first[drawn], 0, height - 1)]
    band_last = band_of_row[np.clip(last[drawn], 0, height - 1)]
    order = np.argsort(band_first, kind="stable")
    starts = np.searchsorted(band_first[order], np.arange(len(bands) + 1))
    spanning = np.flatnonzero(band_last > band_first)
    out = []
    for k in range(len(bands)):
        extra = spanning[(band_first[spanning] < k) & (band_last[spanning] >= k)]
        out.append(np.concatenate([drawn[order[starts[k]:starts[k + 1]]], drawn[extra]]))
    return out


def coverage_tests(rows: np.ndarray, width: int, height: int) -> int:
    """The sample tests the coverage stage will make: the sum over slots of their bounding boxes'
    samples on screen (the overdraw work, whatever the triangles' depth order). Summed 2^16 slots
    at a time, so the int64 temporaries stay small beside the frame's arrays."""
    def span(first, last, size):
        return np.maximum(np.minimum(last, size - 1) - np.maximum(first, 0) + 1, 0).astype(np.int64)

    return sum(int(np.dot(span(part[:, 0], part[:, 1], height), span(part[:, 2], part[:, 3], width)))
               for part in np.array_split(rows, range(1 << 16, rows.shape[0], 1 << 16)))


def empty_screen(device: str) -> resolve.ScreenW:
    tris = resolve.ScreenW()
    tris.screen = wp.empty((0, 3), dtype=wp.vec4d, device=device)
    tris.weight = wp.empty((0, 3), dtype=wp.vec3, device=device)
    tris.facing = wp.empty(0, dtype=wp.int32, device=device)
    tris.face = wp.empty(0, dtype=wp.int32, device=device)
    return tris


def zbuffer(compiled, cam, cull: int, threads: int | None = None):
    """Stages 1-3 on the sample grid of `cam`: clip space, near-plane clipping, and the z-buffer.

    Returns the clipped screen triangles (a `ScreenW`: a slot per face, and one more per face clipped
    to a quad) and the visibility key per sample (NO_HIT, or depth << 32 | slot of the nearest
    triangle). Vertices and faces are transformed in bands on all cores; each band of rows
    rasterizes only the triangles binned to it (those whose sample-centre rows meet the band)."""
    device, arrays = compiled.device, compiled.arrays
    n_faces, n_vertices = compiled.faces.shape[0], compiled.vertices.shape[0]
    width, height = cam.width, cam.height
    scratch = compiled.scratch  # arrays kept between frames: no fresh pages to fault in
    key = scratch("key", width * height, wp.int64)
    key.fill_(coverage.NO_HIT)
    if not n_faces:
        return empty_screen(device), key
    p_clip, p_screen = scratch("clip", n_vertices, wp.vec4), scratch("screen", n_vertices, wp.vec4d)
    inside = scratch("inside", n_vertices, wp.int32)
    launch_chunks(clip.clip_vertices_kernel, n_vertices, [arrays["vertices"], cam.view_proj, width, height, p_clip,
                                                          p_screen, inside], device, threads)
    split_faces = np.empty(0, np.int32)  # faces clipped to a quad: a second slot each
    if not inside.numpy().all():  # only a vertex behind the near plane can split a face
        split = scratch("split", n_faces, wp.int32)
        launch_chunks(clip.split_kernel, n_faces, [arrays["faces"], p_clip, split], device, threads)
        split_faces = np.flatnonzero(split.numpy()).astype(np.int32)
    extra_slot = np.full(n_faces, -1, np.int32)
    extra_slot[split_faces] = n_faces + np.arange(split_faces.size, dtype=np.int32)
    n_slots = n_faces + split_faces.size
    tris = resolve.ScreenW()
    tris.screen = scratch("tris.screen", (n_slots, 3), wp.vec4d)
    tris.weight = scratch("tris.weight", (n_slots, 3), wp.vec3)
    tris.facing = scratch("tris.facing", n_slots, wp.int32)
    tris.face = wp.array(np.concatenate([np.arange(n_faces, dtype=np.int32), split_faces]), dtype=wp.int32,
                         device=device, copy=False)  # copy=False: on the CPU no second copy of the index
    rows = scratch("rows", (n_slots, 4), wp.int32)  # each slot's box: first / last sample row and column
    extra = wp.array(extra_slot, dtype=wp.int32, device=device, copy=False)
    launch_chunks(clip.assemble_kernel, n_faces, [arrays["faces"], p_clip, p_screen, cull, width, height, extra,
                                                  tris.screen, tris.weight, tris.facing, rows], device, threads)
    rows_np = rows.numpy()
    check_raster_work(coverage_tests(rows_np, width, height), n_slots, "render", RenderError)
    bands = band_plan(height, device, threads)
    binned = dict(zip(bands, bin_rows(rows_np, bands, height)))

    def raster_band(begin, end):
        slots = binned[(begin, end)]
        if slots.size:
            chunk = slots.size if device == "cpu" else 1  # a band is one thread's work on the CPU
            wp.launch(coverage.raster_kernel, dim=(slots.size + chunk - 1) // chunk, inputs=[
                chunk, begin, end, wp.array(slots, dtype=wp.int32, device=device), tris.screen, width, key],
                device=device)

    run_bands(raster_band, bands, threads)
    return tris, key


def point_count(compiled, shading: int, n_samples: int) -> int:
    """How many points stage 5 has: a sample each (phong), a face each (flat), two per vertex (gouraud)."""
    if shading == PHONG_SHADING:
        return n_samples
    return compiled.faces.shape[0] if shading == FLAT else 2 * compiled.vertices.shape[0]


def shading_points(compiled, mesh, cam, shading: int, samples, threads: int | None = None):
    """Stage 5: the points where the model is evaluated (`samples` themselves under Phong shading)."""
    if shading == PHONG_SHADING:
        return samples, samples.material.shape[0]
    n_points = point_count(compiled, shading, 0)
    points = empty_points(n_points, compiled.device)
    launch_chunks(resolve.mesh_points_kernel, n_points, [mesh, compiled.materials, cam, shading, points],
                  compiled.device, threads)
    return points, n_points


def empty_lit(device: str, n_points: int, n_lights: int, n_samples: int, record: bool) -> shade.LitW:
    """Stage 6's outputs; the per-light records and per-sample texels only when `record` (else 1 element)."""
    rows = n_points if record else 1
    lit = shade.LitW()
    lit.light_dir = wp.zeros((rows, n_lights), dtype=wp.vec3, device=device)  # zero where nothing is lit
    lit.light_dist = wp.zeros((rows, n_lights), dtype=float, device=device)
    lit.visibility = wp.zeros((rows, n_lights), dtype=float, device=device)
    lit.color = wp.empty(max(n_points, 1), dtype=wp.vec3, device=device)
    lit.factor = wp.empty(max(n_points, 1), dtype=wp.vec3, device=device)
    lit.texel = wp.zeros(n_samples if record else 1, dtype=wp.vec3, device=device)
    return lit


def light_points(compiled, lighting, points, n_points: int, n_samples: int, points_are_samples: int,
                 threads: int | None = None) -> shade.LitW:
    """Stage 6 for the G-buffer: light every point, recording per light its direction, distance
    and visibility (and the texture factor under flat / Gouraud, the texel per sample under Phong)."""
    lit = empty_lit(compiled.device, n_points, max(len(compiled.scene.lights), 1), n_samples, True)
    launch_chunks(shade.light_points_kernel, n_points, [points, lighting, points_are_samples, 1, lit],
                  compiled.device, threads)
    return lit


def rasterize(compiled, settings, threads: int | None = None, *, gbuffer: bool = True) -> Frame:
    """Render a compiled scene with the rasterizer under `settings` (a scene RenderSettings); keep
    the G-buffer in the Frame when `gbuffer` (see the module doc)."""
    scene, device = compiled.scene, compiled.device
    side = settings.spp_side  # the scene validated spp and the sample budget
    width, height = scene.camera.width * side, scene.camera.height * side
    shading = SHADING_MODELS[settings.shading]
    clamp_colors = bool(settings.clamp_vertex_colors and shading == GOURAUD)
    perspective_correct = int(settings.interpolation == "perspective")
    load_kernels(device, clip.assemble_kernel, coverage.raster_kernel, resolve.resolve_kernel, shade.image_kernel)
    start = time.perf_counter()
    cam = camera_struct(scene.camera, width, height)
    mesh, lighting = raster_mesh(compiled), lighting_struct(compiled, settings)
    image = wp.empty(width * height, dtype=wp.vec3, device=device)
    background, fog = wp.vec3(*scene.background), fog_struct(scene.fog)

    # Stages 1-3: clip space, clipping, z-buffer (`zbuffer`).
    tris, key = zbuffer(compiled, cam, int(settings.cull_backfaces), threads)
    if not gbuffer:  # stages 5-6 for the flat / Gouraud points visible samples read, then 4, 6 (Phong), 7 fused
        n_points = 0 if shading == PHONG_SHADING else point_count(compiled, shading, 0)
        needed = compiled.scratch("needed", n_points, wp.int32)
        needed.zero_()
        if n_points:
            launch_row_loops(shade.seen_points_kernel, height, [
                width, key, tris, compiled.arrays["faces"], compiled.vertices.shape[0], shading, needed], device,
                threads)
        lit = empty_lit(device, n_points, max(len(scene.lights), 1), 0, False)
        launch_chunks(shade.light_mesh_points_kernel, n_points, [mesh, cam, shading, lighting, needed, lit], device,
                      threads)
        launch_row_loops(shade.image_kernel, height, [
            key, tris, mesh, cam, lighting, lit, perspective_correct, shading, int(clamp_colors), background, fog,
            image], device, threads)
        pixels = box_downsample(image.numpy().reshape(height, width, 3), side)
        return Frame(image=pixels, buffers=None, stats=frame_stats(compiled, start, pixels, width * height, n_points))

    # Stage 4: the per-sample G-buffer.
    samples = empty_points(width * height, device)
    out = resolve.GBufferW()
    for name, dtype in [("face", wp.int32), ("bary", wp.vec3), ("depth", float), ("uv", wp.vec2),
                        ("object", wp.int32), ("point_index", wp.vec3i), ("point_weight", wp.vec3)]:
        setattr(out, name, wp.empty(width * height, dtype=dtype, device=device))
    launch_row_loops(resolve.resolve_kernel, height, [
        key, tris, mesh, compiled.materials, cam, perspective_correct, shading, compiled.vertices.shape[0], out,
        samples], device, threads)

    # Stages 5-6: shading points, lit.
    points, n_points = shading_points(compiled, mesh, cam, shading, samples, threads)
    points_are_samples = int(shading == PHONG_SHADING)
    lit = light_points(compiled, lighting, points, n_points, width * height, points_are_samples, threads)

    # Stage 7: compose samples, then filter to pixels.
    launch_row_loops(shade.compose_kernel, height, [
        width, samples, out.depth, out.point_index, out.point_weight, lit, lighting, int(clamp_colors),
        1 - points_are_samples, background, fog, image], device, threads)
    pixels = box_downsample(image.numpy().reshape(height, width, 3), side)
    gbuffer = to_gbuffer(scene, settings, side, (height, width), samples, out, points, n_points, lit, clamp_colors)
    stats = frame_stats(compiled, start, pixels, width * height, n_points)
    stats["covered_samples"] = int(gbuffer.mask.sum())
    return Frame(image=pixels, buffers=gbuffer, stats=stats)


def frame_stats(compiled, start: float, pixels: np.ndarray, n_samples: int, n_points: int) -> dict:
    return {"method": "raster", "seconds": time.perf_counter() - start, "triangles": compiled.faces.shape[0],
            "samples": n_samples, "shading_points": n_points, "nonfinite_pixels": nonfinite_pixels(pixels)}



def to_gbuffer(scene, settings, side: int, grid: tuple[int, int], samples, out, points, n_points: int,
               lit, clamp_colors: bool) -> GBuffer:
    """The device buffers of stages 4-6 as a numpy `GBuffer` on the sample grid."""
    def on_grid(array, *channels):
        return array.numpy().reshape(*grid, *channels)

    material = on_grid(samples.material)
    return GBuffer(
        mask=material >= 0, depth=on_grid(out.depth), position=on_grid(samples.position, 3),
        normal=on_grid(samples.normal, 3), uv=on_grid(out.uv, 2), material=material,
        object=on_grid(out.object), face=on_grid(out.face), bary=on_grid(out.bary, 3),
        point_index=on_grid(out.point_index, 3), point_weight=on_grid(out.point_weight, 3),
        points=ShadingPoints(
            position=points.position.numpy(), normal=points.normal.numpy(), view=points.view.numpy(),
            material=points.material.numpy(), cell=points.cell.numpy(), light_dir=lit.light_dir.numpy(),
            light_dist=lit.light_dist.numpy(), visibility=lit.visibility.numpy(),
            color=lit.color.numpy()[:n_points], texture_factor=lit.factor.numpy()[:n_points]),
        shading=settings.shading, specular=settings.specular, spp_side=side,
        ambient=np.asarray(scene.ambient, np.float32), background=np.asarray(scene.background, np.float32),
        clamp_vertex_colors=clamp_colors, fog=fog_params(scene.fog),
        duv_dx=on_grid(samples.duv_dx, 2), duv_dy=on_grid(samples.duv_dy, 2), texture=on_grid(lit.texel, 3),
    )
