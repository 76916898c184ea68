"""The rasterizer's driver: take the frame's arrays (the last frame's where nothing holds them),
launch the stages (see the package doc), return a Frame.

`rasterize(..., gbuffer=True)` keeps every stage's output (the G-buffer `render_frame` and the fits
read; under Phong shading stages 4 and 6 in one pass, and stage 7 only when the image is asked for);
with gbuffer=False, what `render` asks for, stages 4, 6 and 7 run fused per sample
(`shade.image_kernel`) and store nothing but the image.
"""

from __future__ import annotations

import functools
import itertools
import time

import numpy as np
from ..._warp import wp

from ...errors import RenderError
from ...guards import nonfinite_pixels
from ...limits import check_raster_work
from ...scene import Sphere
from ...lighting.warp_model import fog_struct
from ...vocabulary import FLAT, GOURAUD, PHONG_SHADING, SHADING_MODELS, SPECULAR_MODELS
from . import clip, coverage, flat_gouraud, resolve, shade
from .gbuffer import filled, gbuffer_arrays, lit_fields, point_fields, to_gbuffer
from ..camera import camera_struct
from ..frame import Frame, box_downsample
from ..host import host_empty, to_host
from ..bandpool import run_bands, run_phases, start_beside
from ..launch import (band_plan, dealt_bands, halved_zbuffer, launch_band, launch_chunks, launch_dealt, launch_kept,
                      launch_parts, launch_row_loops, load_kernels, part_count, pass_threads, raster_threads, row_spans)
from ..trace import object_kinds


def raster_mesh(compiled) -> resolve.RasterMeshW:
    """The compiled triangles as the raster kernels read them (kept with the compiled scene's arrays:
    copies of it under other render settings share them)."""
    kept = compiled.built.get("raster mesh")
    if kept is not None and kept[0] is compiled.arrays:
        return kept[1]
    mesh = resolve.RasterMeshW()
    for name in ("faces", "vertices", "normals", "uvs", "face_normal", "face_material", "face_object",
                 "vertex_material", "vertex_object"):
        setattr(mesh, name, compiled.arrays[name])
    objects, device = compiled.scene.objects, compiled.device
    mesh.object_kind = wp.array(object_kinds(objects), dtype=wp.int32, device=device)
    spheres = [(obj.center, obj.radius) if isinstance(obj, Sphere) else ((0.0, 0.0, 0.0), 0.0) for obj in objects]
    mesh.sphere_center = wp.array(np.array([c for c, _ in spheres], np.float32).reshape(-1, 3), dtype=wp.vec3,
                                  device=device)
    mesh.sphere_radius = wp.array(np.array([r for _, r in spheres], np.float32), dtype=float, device=device)
    compiled.built["raster mesh"] = (compiled.arrays, mesh)
    return mesh


def lighting_struct(compiled, settings) -> shade.LightingW:
    """The `LightingW` of the compiled scene under `settings`; the last one is kept (a fit's views
    and an animation's frames ask for the same one again and again)."""
    key = (settings.specular, settings.shadows, settings.transparent_shadows, tuple(compiled.scene.ambient))
    arrays = (compiled.lights, compiled.materials, compiled.textures, compiled.geom)
    kept = compiled.built.get("lighting")
    if kept is not None and kept[0] == key and all(a is b for a, b in zip(kept[1], arrays)):
        return kept[2]
    out = shade.LightingW()
    out.lights, out.materials, out.textures = compiled.lights, compiled.materials, compiled.textures.warp
    out.geom = compiled.traceable() if settings.shadows else compiled.geom  # shadow rays need the BVH
    out.specular = SPECULAR_MODELS[settings.specular]
    out.ambient = wp.vec3(*compiled.scene.ambient)
    out.shadows, out.transparent = int(settings.shadows), int(settings.transparent_shadows)
    compiled.built["lighting"] = (key, arrays, out)
    return out


def backdrop(scene) -> tuple:
    """The background colour and fog as the image kernels read them (only where an image is formed:
    a Warp struct costs ~50 us of a fit's cold frame)."""
    return wp.vec3(*scene.background), fog_struct(scene.fog)


def band_rows(bands: list[tuple[int, int]], height: int, device: str) -> wp.array:
    """Per sample row, the index of its band (kept for later frames of the same plan)."""
    return _band_rows(tuple(bands), height, device)


@functools.lru_cache(maxsize=32)
def _band_rows(bands: tuple, height: int, device: str) -> wp.array:
    band_of_row = np.repeat(np.arange(len(bands), dtype=np.int32), [b - a for a, b in bands])
    return wp.array(band_of_row[:height], dtype=wp.int32, device=device)


def bin_starts(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """From counts[part, band] (slots of each launch part meeting each band): where each band's list
    starts in the binned array (B + 1 entries, the last the total), and where each part writes its
    slots of each band (cursor[part, band]: the band's start plus the earlier parts' counts)."""
    starts = np.concatenate([[0], np.cumsum(counts.sum(axis=0))])
    cursor = starts[None, :-1] + np.cumsum(counts, axis=0) - counts
    return starts, cursor.astype(np.int32)


def cleared_key(compiled, n_samples: int, name: str = "key") -> wp.array:
    """The visibility key per sample, all NO_HIT (`name`: "key", or the second of a z-buffer drawn
    in two, `zbuffer`). The array is kept between frames; the kernel that reads a frame's keys last
    resets each to NO_HIT (and `mark_key_cleared` notes it), so the array is filled here only when
    the last frame's reader did not (a first frame, a new size, a frame stopped midway, the ray
    tracer's item buffer)."""
    key = compiled.scratch(name, n_samples, wp.int64)
    if compiled.scratch_pool().pop(("cleared", name), None) is not key:
        key.fill_(coverage.NO_HIT)
    return key


def host_view(compiled, name: str, array: wp.array) -> np.ndarray:
    """`to_host(array)` of the scratch array `name`: on the CPU its numpy view, kept with it (Warp's
    array interface: ~10 us of a fit's cold frame for a one-int flag)."""
    if compiled.device != "cpu":
        return to_host(array)
    pool = compiled.scratch_pool()
    kept = pool.get(("view", name))
    if kept is None or kept[0] is not array:
        kept = pool[("view", name)] = (array, to_host(array))
    return kept[1]


def zeroed_scratch(compiled, name: str, shape, dtype) -> wp.array:
    """`compiled.scratch(name, shape, dtype)` set to zero, on the CPU through its `host_view` (Warp's
    `zero_`: ~20 us of a fit's cold frame for a one-int flag)."""
    array = compiled.scratch(name, shape, dtype)
    if compiled.device == "cpu":
        host_view(compiled, name, array).fill(0)
    else:
        array.zero_()
    return array


def mark_key_cleared(compiled, key: wp.array, name: str = "key") -> None:
    compiled.scratch_pool()[("cleared", name)] = key


def empty_screen(device: str) -> resolve.ScreenW:
    tris = resolve.ScreenW()
    tris.screen = wp.empty((0, 3), dtype=wp.vec4d, device=device)
    tris.weight = wp.empty((0, 3), dtype=wp.vec3, device=device)
    tris.facing = wp.empty(0, dtype=wp.int32, device=device)
    tris.face = wp.empty(0, dtype=wp.int32, device=device)
    return tris


def screen_slots(compiled, n_slots: int) -> resolve.ScreenW:
    """Stage 2's `n_slots` screen triangles (scratch arrays), in a struct kept with them: the kernels'
    launches that read it are then the same and replayed (`launch.launch_kept`)."""
    scratch = compiled.scratch
    arrays = (scratch("tris.screen", (n_slots, 3), wp.vec4d), scratch("tris.weight", (n_slots, 3), wp.vec3),
              scratch("tris.facing", n_slots, wp.int32), scratch("tris.face", n_slots, wp.int32))
    pool = compiled.scratch_pool()
    kept = pool.get(("struct", "tris"))
    if kept is None or any(a is not b for a, b in zip(kept[0], arrays)):
        tris = resolve.ScreenW()
        tris.screen, tris.weight, tris.facing, tris.face = arrays
        kept = pool[("struct", "tris")] = (arrays, tris)
    return kept[1]


def split_slots(compiled, p_clip: wp.array, threads: int | None) -> tuple[wp.array, int]:
    """Per face, its extra slot (-1: none) for the faces with one vertex behind the near plane
    (clipped to a quad), numbered after the F faces' own slots; and how many there are."""
    n_faces, device = compiled.faces.shape[0], compiled.device
    split = compiled.scratch("split", n_faces, wp.int32)
    launch_chunks(clip.split_kernel, n_faces, [compiled.arrays["faces"], p_clip, split], device, threads)
    split_faces = np.flatnonzero(to_host(split))
    extra_slot = np.full(n_faces, -1, np.int32)
    extra_slot[split_faces] = n_faces + np.arange(split_faces.size, dtype=np.int32)
    return wp.array(extra_slot, dtype=wp.int32, device=device), split_faces.size


def zbuffer(compiled, cam, cull: int, threads: int | None = None, then=None, halves: tuple | None = None,
            beside=None):
    """Stages 1-3 on the sample grid of `cam`: clip space, near-plane clipping, and the z-buffer.

    Returns the clipped screen triangles (a `ScreenW`: a slot per face, and one more per face clipped
    to a quad) and the visibility key per sample (NO_HIT, or depth << 32 | slot of the nearest
    triangle). Vertices and faces are transformed in parts on all cores; assembling counts the slots
    meeting each band of rows, `bin_kernel` lists them (with a single band, every slot is its), and
    each band rasterizes only its list, then calls `then(tris, key, begin, end)` when given: the
    band's keys are final there, and its rows need no other band's.

    `halves` (partial, pass): a second key array, all NO_HIT (one band of rows to bin into), and the
    (threads, bands per thread) of a per-sample pass (`launch.pass_threads`). The slots are dealt in
    turn to the returned key and to `partial`, the two drawn side by side on two threads (no binning:
    a 256^2 frame's z-buffer on one thread); a sample's key is then the lesser of its two, which its
    reader takes (`resolve.resolve_into`), the same as one z-buffer's (min is order-free). Then the
    same threads call `then(tris, key, k, n)` for the pass's bands of rows dealt in blocks (band k
    of n, `launch.dealt_bands`) as soon as both halves are drawn (`bandpool.run_phases`).

    `beside`: called right before the assembly's launch, the longest on this thread before the
    z-buffer (it starts the G-buffer's clearing on a pool worker: `bandpool.start_beside`). A fit
    frame's (nothing to clear) with the worker writing NO_HIT over `partial` there instead (already
    NO_HIT), to draw its half from its cache: that half 317 -> 245 us and its Phong pass 684 -> 658,
    but the assembly beside it +7 us and the first fit's wall +0.1-0.2 ms (the 256^2 bench sphere,
    medians of 60, 8 alternating pairs of processes; ABBA of first fits -0.25 to +0.41 ms): dropped."""
    device, arrays = compiled.device, compiled.arrays
    load_kernels(device, clip.assemble_kernel, coverage.raster_kernel)  # before two threads launch them
    n_faces, n_vertices = compiled.faces.shape[0], compiled.vertices.shape[0]
    width, height = cam.width, cam.height
    scratch = compiled.scratch  # arrays kept between frames: no fresh pages to fault in
    key = cleared_key(compiled, width * height)
    if halves:
        partial, (pass_pool, per_thread) = halves
        then_plan = dealt_bands(height, device, pass_pool, per_thread), pass_pool
    if not n_faces:  # nothing to draw; `then` still sees every band
        tris = empty_screen(device)
        if then is not None:
            run_bands(lambda a, b: then(tris, key, a, b), *(then_plan if halves else
                                                           (band_plan(height, device, threads), threads)))
        return tris, key
    p_clip, p_screen = scratch("clip", n_vertices, wp.vec4), scratch("screen", n_vertices, wp.vec4d)
    behind = zeroed_scratch(compiled, "behind", 1, wp.int32)
    kept = compiled.scratch_pool()  # the launches of scratch arrays, recorded (`launch_kept`)
    launch_chunks(clip.clip_vertices_kernel, n_vertices, [arrays["vertices"], cam.view_proj, width, height, p_clip,
                                                          p_screen, behind], device, threads, kept)
    extra = none = scratch("no slots", 0, wp.int32)  # only a vertex behind the near plane can split a face
    n_split = 0
    near = scratch("no vertices", 0, wp.vec4)  # (`clip.assemble_face`: no face is clipped)
    if host_view(compiled, "behind", behind)[0]:
        extra, n_split = split_slots(compiled, p_clip, threads)
        near = p_clip
    n_slots = n_faces + n_split
    tris = screen_slots(compiled, n_slots)
    rows = scratch("rows", (n_slots, 4), wp.int32)  # each slot's box: first / last sample row and column
    bands = band_plan(height, device, threads)
    band_of_row = band_rows(bands, height, device)
    parts = part_count(n_faces, device, threads)
    counts = zeroed_scratch(compiled, "bin counts", (parts, len(bands)) if len(bands) > 1 else (0, 1),  # (1 band:
                            wp.int32)  # no bins)
    tests = zeroed_scratch(compiled, "bin tests", parts, wp.int64)
    if beside is not None:
        beside()
    launch_parts(clip.assemble_kernel, n_faces, [
        arrays["faces"], near, p_screen, cull, width, height, extra, tris.screen, tris.weight, tris.facing, rows,
        tris.face, band_of_row, counts, tests], device, threads, kept)
    check_raster_work(int(host_view(compiled, "bin tests", tests).sum()), n_slots, "render", RenderError)
    band_index = {band: k for k, band in enumerate(bands)}
    binned = none  # one band: it draws every slot, nothing is binned
    starts = np.array([0, n_slots])
    if len(bands) > 1:
        starts, cursor = bin_starts(host_view(compiled, "bin counts", counts))
        binned = scratch("binned", 1 << int(starts[-1]).bit_length(), wp.int32)  # a power of two: kept between frames
        launch_parts(coverage.bin_kernel, n_faces, [
            extra, rows, width, height, band_of_row, wp.array(cursor, dtype=wp.int32, device=device), binned], device,
            threads)

    def raster_band(begin, end):
        first, last = int(starts[band_index[(begin, end)]]), int(starts[band_index[(begin, end)] + 1])
        if last > first:
            count, step = (1, 1) if device == "cpu" else (last - first,) * 2  # on the CPU one thread takes a band
            wp.launch(coverage.raster_kernel, dim=count, inputs=[
                0, step, begin, end, binned[first:last] if binned.shape[0] else binned, n_slots, rows, tris.screen,
                width, height, key], device=device)
        if then is not None:
            then(tris, key, begin, end)

    if halves:  # every other slot into each of two z-buffers, side by side (one band, on the CPU), then `then`
        keys = (key, partial)
        run_phases([(lambda part, parts: launch_kept(kept, coverage.raster_kernel, parts, 1, [
            part, parts, 0, height, binned, n_slots, rows, tris.screen, width, height, keys[part]], device),
            [(0, 2), (1, 2)]), (lambda k, n: then(tris, key, k, n), then_plan[0])], then_plan[1])
        return tris, key

    # the bands with most triangles first: the threads finish on the small ones (bands write disjoint rows,
    # so the order changes no result)
    run_bands(raster_band, sorted(bands, key=lambda band: starts[band_index[band]] - starts[band_index[band] + 1]),
              threads)
    return tris, key


def point_count(compiled, shading: int) -> int:
    """How many points stage 5 has under flat or Gouraud shading: a face each (flat), two per vertex
    (gouraud). (Phong's points are its samples.)"""
    return compiled.faces.shape[0] if shading == FLAT else 2 * compiled.vertices.shape[0]


def mesh_points(compiled, mesh, cam, shading: int, threads: int | None = None):
    """Stage 5 under flat or Gouraud shading: the points where the model is evaluated (Phong's are
    its samples, see `rasterize`), and how many."""
    n_points = point_count(compiled, shading)
    points = filled(resolve.PointsW(), "points", point_fields(n_points, False),  # every point written
                    lambda name, shape, dtype, zero: compiled.reusable(name, shape, dtype))  # (`flat_gouraud`)
    launch_chunks(flat_gouraud.mesh_points_kernel, n_points, [mesh, compiled.materials, cam, shading, points],
                  compiled.device, threads)
    return points, n_points


def point_cache(compiled, n_points: int, frame: int) -> shade.PointCacheW:
    """The calling thread's cache of lit flat / Gouraud points (`shade.PointCacheW`) for `frame`:
    arrays kept between frames, stamps zeroed when allocated (frame numbers start at 1)."""
    cache = shade.PointCacheW()
    cache.color = compiled.scratch("cache.color", max(n_points, 1), wp.vec3)
    cache.factor = compiled.scratch("cache.factor", max(n_points, 1), wp.vec3)
    cache.stamp = compiled.scratch("cache.stamp", max(n_points, 1), wp.int32, fill=0)
    cache.frame = frame
    return cache


def light_mesh_points(compiled, lighting, points, n_points: int, n_samples: int,
                      threads: int | None = None) -> shade.LitW:
    """Stage 6 for the G-buffer under flat or Gouraud shading: light every point, recording per
    light its direction, distance and visibility, and the texture factor."""
    lit = filled(shade.LitW(), "lit", lit_fields(len(compiled.scene.lights), n_points, n_samples), compiled.reusable)
    launch_chunks(shade.light_points_kernel, n_points, [points, lighting, lit], compiled.device, threads)
    return lit


def rasterize(compiled, settings, threads: int | None = None, *, gbuffer: bool = True, image: bool = True,
              geometry_only: bool = False) -> Frame:
    """Render a compiled scene with the rasterizer under `settings` (a scene RenderSettings); keep
    the G-buffer in the Frame when `gbuffer` (see the module doc). With `image` False (G-buffer
    only) the frame's image is None and, under Phong shading, stage 7 is not run: a sample's colour
    is its point's, so the non-finite count comes from the points' colours. Flat / Gouraud frames
    still compose (that pass also samples their textures into the G-buffer). `geometry_only` (with
    `image` False; a fit's record, `api.fit_frame`): under Phong shading the points are not lit,
    only their light geometry recorded, uv is formed only where a texture is sampled (uv 0
    elsewhere, as in a ray-traced G-buffer), and what the fit never reads is not formed: those
    fields of the G-buffer are None (`gbuffer.fit_skips`), and no overflow is counted. `threads`:
    as given to `render_frame` (None: the default of `launch.raster_threads`, and
    `launch.pass_threads` for the G-buffer's per-sample passes)."""
    compiled = compiled.raster(settings.shading)  # the meshes' and the analytic objects' triangles (built on first use)
    scene, device = compiled.scene, compiled.device
    side = settings.spp_side  # the scene validated spp and the sample budget
    width, height = scene.camera.width * side, scene.camera.height * side
    row_pass = pass_threads(threads, width * height)  # (threads, bands per thread) of the per-sample passes
    threads = raster_threads(threads, width * height)
    halved = halved_zbuffer(threads, row_pass, device)  # the G-buffer's z-buffer in two halves (`zbuffer`)
    shading = SHADING_MODELS[settings.shading]
    clamp_colors = bool(settings.clamp_vertex_colors and shading == GOURAUD)
    perspective_correct = int(settings.interpolation == "perspective")
    load_kernels(device, resolve.resolve_kernel, shade.image_kernel)  # (stages 1-3's in `zbuffer`)
    start = time.perf_counter()
    cam = camera_struct(scene.camera, width, height)
    mesh, lighting = raster_mesh(compiled), lighting_struct(compiled, settings)
    black = not any(scene.background)  # a zeroed image needs no background written (`render`)

    if not gbuffer:  # stages 1-3, then 4-7 fused (flat / Gouraud points lit on first use)
        n_points = 0 if shading == PHONG_SHADING else point_count(compiled, shading)
        frame = next(compiled.built.setdefault("frames", itertools.count(1)))  # this frame's cache stamp
        if device != "cpu":  # one cache for the GPU's threads: lit before any is read
            launch_chunks(shade.light_mesh_points_kernel, n_points, [
                mesh, cam, shading, lighting, point_cache(compiled, n_points, frame)], device, threads)
        bad = compiled.scratch("nonfinite rows", height * row_spans(width, device), wp.int32)  # (`launch.dealt_span`)
        canvas = host_empty(width * height, wp.vec3, device, zeroed=black)  # fresh every frame
        background, fog = backdrop(scene)

        def image_band(tris, key, begin: int, end: int) -> None:  # right after the band's z-buffer, its thread's cache
            launch_band(shade.image_kernel, begin, end, width, [
                key, tris, mesh, cam, lighting, point_cache(compiled, n_points, frame), perspective_correct, shading,
                int(clamp_colors), int(not black), background, fog, canvas, bad], device)

        tris, key = zbuffer(compiled, cam, int(settings.cull_backfaces), threads, image_band)
        mark_key_cleared(compiled, key)  # image_kernel reset every key it read
        pixels = box_downsample(to_host(canvas).reshape(height, width, 3), side)
        nonfinite = int(to_host(bad).sum())  # non-finite samples; with spp > 1 count the pixels they reach
        if nonfinite and side > 1:
            nonfinite = nonfinite_pixels(pixels)
        return Frame(image=pixels, buffers=None, stats=frame_stats(compiled, start, nonfinite, width * height,
                                                                   n_points))

    # The per-sample G-buffer's arrays (stage 4; Phong's stage 6 too): what must start zero is
    # cleared beside stages 1-3 when a core is free (a memset of memory other work has pushed out of
    # the cache, ~0.4-0.9 ms of a 256^2 frame); nothing of a fit's (`gbuffer.gbuffer_arrays`).
    points_are_samples = int(shading == PHONG_SHADING)
    geometry_only = bool(geometry_only and points_are_samples and not image)
    record = shade.GEOMETRY_ONLY if geometry_only else 1
    samples, out, lit, found, stale, views = gbuffer_arrays(compiled, width * height, points_are_samples,
                                                           geometry_only)
    partial = cleared_key(compiled, width * height, "partial key") if halved else compiled.scratch("no key", 0,
                                                                                                    wp.int64)
    bad = compiled.scratch("nonfinite rows", height * row_spans(width, device), wp.int32)  # (`launch.dealt_span`)
    clearing = start_beside(stale.zero_ if stale is not None else None, device, row_pass[0], start=False)

    kept = compiled.scratch_pool()  # the pass's launches, recorded with the structs kept (`launch_kept`)

    def sample_pass(tris, key, k: int, n: int) -> None:  # stage 4 on band k of n of the dealt rows, once cleared
        clearing.join()
        if points_are_samples:  # stages 4-6 in one pass: each sample resolved, then lit as its own point
            launch_dealt(shade.phong_gbuffer_kernel, k, n, (height, width), [
                key, partial, tris, mesh, cam, perspective_correct, out, samples, found, lighting, lit, record, bad],
                device, kept)
        else:
            launch_dealt(resolve.resolve_kernel, k, n, (height, width), [
                key, partial, tris, mesh, compiled.materials, cam, perspective_correct, shading,
                compiled.vertices.shape[0], out, samples], device, kept)

    try:
        tris, key = zbuffer(compiled, cam, int(settings.cull_backfaces), threads,  # stages 1-3 (and 4 when halved)
                            then=sample_pass if halved else None, halves=(partial, row_pass) if halved else None,
                            beside=clearing.start)
    finally:
        clearing.join()
    if not halved:
        run_bands(lambda k, n: sample_pass(tris, key, k, n), dealt_bands(height, device, *row_pass), row_pass[0])
    points, n_points = samples, width * height
    if not points_are_samples:  # stages 5-6
        points, n_points = mesh_points(compiled, mesh, cam, shading, threads)
        lit = light_mesh_points(compiled, lighting, points, n_points, width * height, threads)
    mark_key_cleared(compiled, key)  # stage 4 reset every key it read
    if halved:
        mark_key_cleared(compiled, partial, "partial key")

    composed = image or not points_are_samples
    if composed:  # Stage 7: compose samples (on the CUDA device before the G-buffer is copied out)
        canvas = compiled.reusable("canvas", width * height, wp.vec3)  # every sample written
        launch_row_loops(shade.compose_kernel, (height, width), [
            width, samples, out.uv, out.depth, out.point_index, out.point_weight, lit, lighting, int(clamp_colors),
            1 - points_are_samples, *backdrop(scene), canvas], device, *row_pass)
    gbuffer = to_gbuffer(scene, settings, side, (height, width), samples, out, points, n_points, lit, clamp_colors,
                         geometry_only, views if geometry_only and device.startswith("cpu") else None)
    # then filter to pixels (Phong without stage 7: a sample's colour is its point's, fogged, so the
    # pixels are not finite exactly where these are not: the pass counted those samples)
    pixels, nonfinite = None, 0  # (geometry only: no colours)
    if not geometry_only:
        samples_rgb = (to_host(canvas) if composed else gbuffer.points.color).reshape(height, width, 3)
        pixels = box_downsample(samples_rgb, side) if image else None
        nonfinite = nonfinite_pixels(samples_rgb if pixels is None else pixels) if composed else int(to_host(bad).sum())
        if pixels is None and nonfinite and side > 1:  # count the pixels the non-finite samples reach
            nonfinite = nonfinite_pixels(box_downsample(samples_rgb, side))
    stats = frame_stats(compiled, start, nonfinite, width * height, n_points)
    if not geometry_only:  # (a fit frame's stats stay inside the fit, which reads none of them)
        stats["covered_samples"] = int(np.count_nonzero(gbuffer.mask))
    return Frame(image=pixels, buffers=gbuffer, stats=stats)


def frame_stats(compiled, start: float, nonfinite: int, n_samples: int, n_points: int) -> dict:
    return {"method": "raster", "seconds": time.perf_counter() - start, "triangles": compiled.faces.shape[0],
            "samples": n_samples, "shading_points": n_points, "nonfinite_pixels": nonfinite}
