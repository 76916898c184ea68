"""The rasterizer's driver: allocate once per frame, launch the stages (see the package doc), return a Frame."""

from __future__ import annotations

import math
import time

import numpy as np
from ..._warp import wp

from ...errors import RenderError
from ...lighting.warp_model import SPECULAR_MODELS, fog_params, fog_struct
from ...scene import MAX_PIXELS
from . import clip, coverage, resolve, shade
from ..camera import camera_struct
from ..frame import Frame, GBuffer, ShadingPoints, box_downsample
from ..launch import launch_rows, parallel_bands


def spp_side(spp: int) -> int:
    """The side of the regular spp = side^2 supersampling grid; spp must be a perfect square."""
    side = math.isqrt(spp)
    if spp < 1 or side * side != spp:
        raise RenderError(f"spp: the rasterizer samples a regular grid, so spp must be a perfect square "
                          f"(1, 4, 9, 16, ...), got {spp}")
    return side


def empty_points(count: int, device: str) -> resolve.PointsW:
    points = resolve.PointsW()
    for name, dtype in [("position", wp.vec3), ("normal", wp.vec3), ("geo_normal", wp.vec3), ("view", wp.vec3),
                        ("material", wp.int32), ("cell", wp.int32), ("ignore", wp.int32), ("uv", wp.vec2),
                        ("duv_dx", wp.vec2), ("duv_dy", wp.vec2)]:
        setattr(points, name, wp.zeros(count, dtype=dtype, device=device))
    return points


def zbuffer(compiled, cam, cull: int, threads: int | None = None):
    """Stages 1-3 on the sample grid of `cam`: clip space, near-plane clipping, and the z-buffer.

    Returns the clipped screen triangles (screen, weight, facing: two slots per face) and the
    visibility key per sample (NO_HIT, or depth << 32 | slot of the nearest triangle). Vertices
    and faces are transformed in bands on all cores; each band of rows rasterizes only the
    triangles binned to it (those whose sample-centre rows meet the band)."""
    device, arrays = compiled.device, compiled.arrays
    n_faces, n_vertices = compiled.faces.shape[0], compiled.vertices.shape[0]
    width, height = cam.width, cam.height
    screen = wp.empty((2 * n_faces, 3), dtype=wp.vec4d, device=device)
    weight = wp.empty((2 * n_faces, 3), dtype=wp.vec3, device=device)
    facing = wp.empty(2 * n_faces, dtype=wp.int32, device=device)
    key = wp.full(width * height, value=coverage.NO_HIT, dtype=wp.int64, device=device)
    if not n_faces:
        return screen, weight, facing, key
    p_clip = wp.empty(n_vertices, dtype=wp.vec4, device=device)
    rows = wp.empty((2 * n_faces, 2), dtype=wp.int32, device=device)

    def clip_band(begin, end):
        wp.launch(clip.clip_vertices_kernel, dim=end - begin, inputs=[begin, arrays["vertices"], cam.view_proj, p_clip],
                  device=device)

    def assemble_band(begin, end):
        wp.launch(clip.assemble_kernel, dim=end - begin, inputs=[begin, arrays["faces"], p_clip, cull, width, height,
                                                               screen, weight, facing, rows], device=device)

    parallel_bands(clip_band, n_vertices, device, threads)
    parallel_bands(assemble_band, n_faces, device, threads)
    row_range = rows.numpy()
    first, last = row_range[:, 0], row_range[:, 1]

    def raster_band(begin, end):
        slots = np.flatnonzero((last >= begin) & (first < end) & (last >= first)).astype(np.int32)
        if slots.size:
            wp.launch(coverage.raster_kernel, dim=slots.size, inputs=[
                begin, end, wp.array(slots, dtype=wp.int32, device=device), screen, width, key], device=device)

    parallel_bands(raster_band, height, device, threads)
    return screen, weight, facing, key


def rasterize(compiled, settings, threads: int | None = None) -> Frame:
    """Render a compiled scene with the rasterizer under `settings` (a scene RenderSettings)."""
    scene, device = compiled.scene, compiled.device
    side = spp_side(settings.spp)
    width, height = scene.camera.width * side, scene.camera.height * side
    if width * height > MAX_PIXELS:
        raise RenderError(f"spp: {scene.camera.width}x{scene.camera.height} pixels at spp={settings.spp} is "
                          f"{width * height} samples, over the budget of {MAX_PIXELS}")
    shading = resolve.SHADING_MODELS[settings.shading]
    start = time.perf_counter()
    cam = camera_struct(scene.camera, width, height)
    arrays = compiled.arrays
    n_faces, n_vertices = compiled.faces.shape[0], compiled.vertices.shape[0]
    n_samples, n_lights = width * height, len(scene.lights)

    # Stages 1-3: clip space, clipping, z-buffer.
    screen, weight, facing, key = zbuffer(compiled, cam, int(settings.cull_backfaces), threads)

    # Stage 4: the per-sample G-buffer.
    samples = empty_points(n_samples, device)
    out = {name: wp.empty(n_samples, dtype=dtype, device=device) for name, dtype in
           [("face", wp.int32), ("bary", wp.vec3), ("depth", float), ("uv", wp.vec2), ("object", wp.int32),
            ("point_weight", wp.vec3)]}
    point_index = wp.empty((n_samples, 3), dtype=wp.int32, device=device)
    launch_rows(resolve.resolve_kernel, (height, width), [
        key, screen, weight, facing, arrays["faces"], arrays["vertices"], arrays["normals"], arrays["uvs"],
        arrays["face_normal"], arrays["face_material"], arrays["face_object"], compiled.materials, cam,
        int(settings.interpolation == "perspective"), shading, compiled.n_mesh_faces, n_vertices,
        out["face"], out["bary"], out["depth"], out["uv"], out["object"], samples, point_index, out["point_weight"],
    ], device, threads)

    # Stage 5: shading points.
    if shading == resolve.PHONG_SHADING:
        points, n_points = samples, n_samples
    elif shading == resolve.FLAT:
        n_points = n_faces
        points = empty_points(n_points, device)
        if n_faces:
            wp.launch(resolve.flat_points_kernel, dim=n_faces, inputs=[
                arrays["faces"], arrays["vertices"], arrays["face_normal"], arrays["face_material"],
                arrays["face_object"], compiled.materials, cam, compiled.n_mesh_faces, points], device=device)
    else:
        n_points = 2 * n_vertices
        points = empty_points(n_points, device)
        if n_vertices:
            vertex_face = np.zeros(n_vertices, np.int64)
            vertex_face[compiled.faces.ravel()] = np.repeat(np.arange(n_faces), 3)
            per_vertex = [compiled.face_material[vertex_face], compiled.face_object[vertex_face],
                          (vertex_face >= compiled.n_mesh_faces).astype(np.int32)]
            wp.launch(resolve.gouraud_points_kernel, dim=(n_vertices, 2), inputs=[
                arrays["vertices"], arrays["normals"],
                *[wp.array(a.astype(np.int32), dtype=wp.int32, device=device) for a in per_vertex],
                compiled.materials, cam, points], device=device)

    # Stage 6: light the points.
    light_dir = wp.zeros((n_points, n_lights), dtype=wp.vec3, device=device)
    light_dist = wp.zeros((n_points, n_lights), dtype=float, device=device)
    visibility = wp.zeros((n_points, n_lights), dtype=float, device=device)
    color = wp.zeros(max(n_points, 1), dtype=wp.vec3, device=device)
    factor = wp.zeros(max(n_points, 1), dtype=wp.vec3, device=device)  # textures under flat / Gouraud
    texel = wp.zeros(n_samples, dtype=wp.vec3, device=device)  # the texture value at each sample
    points_are_samples = int(shading == resolve.PHONG_SHADING)
    ambient = wp.vec3(*scene.ambient)

    def light_band(begin, end):
        wp.launch(shade.light_points_kernel, dim=end - begin, inputs=[
            begin, points, compiled.lights, compiled.materials, compiled.geom, SPECULAR_MODELS[settings.specular],
            ambient, int(settings.shadows), int(settings.transparent_shadows), light_dir, light_dist, visibility,
            color, compiled.textures.warp, points_are_samples, factor, texel], device=device)

    parallel_bands(light_band, n_points, device, threads)

    # Stage 7: compose samples, then filter to pixels.
    fog = fog_params(scene.fog)
    image = wp.empty(n_samples, dtype=wp.vec3, device=device)
    launch_rows(shade.compose_kernel, (height, width), [
        width, samples.material, out["depth"], point_index, out["point_weight"], color,
        int(settings.clamp_vertex_colors and shading == resolve.GOURAUD), wp.vec3(*scene.background),
        fog_struct(scene.fog), image, compiled.materials, compiled.textures.warp, samples,
        1 - points_are_samples, factor, texel], device, threads)
    sample_image = image.numpy().reshape(height, width, 3)
    pixels = box_downsample(sample_image, side)
    seconds = time.perf_counter() - start

    grid = (height, width)
    material = samples.material.numpy().reshape(grid)
    gbuffer = GBuffer(
        mask=material >= 0, depth=out["depth"].numpy().reshape(grid), position=samples.position.numpy().reshape(*grid, 3),
        normal=samples.normal.numpy().reshape(*grid, 3), uv=out["uv"].numpy().reshape(*grid, 2), material=material,
        object=out["object"].numpy().reshape(grid), face=out["face"].numpy().reshape(grid),
        bary=out["bary"].numpy().reshape(*grid, 3), point_index=point_index.numpy().reshape(*grid, 3),
        point_weight=out["point_weight"].numpy().reshape(*grid, 3),
        points=ShadingPoints(
            position=points.position.numpy(), normal=points.normal.numpy(), view=points.view.numpy(),
            material=points.material.numpy(), cell=points.cell.numpy(), light_dir=light_dir.numpy(),
            light_dist=light_dist.numpy(), visibility=visibility.numpy(), color=color.numpy()[:n_points],
            texture_factor=factor.numpy()[:n_points]),
        shading=settings.shading, specular=settings.specular, spp_side=side,
        ambient=np.asarray(scene.ambient, np.float32), background=np.asarray(scene.background, np.float32),
        clamp_vertex_colors=bool(settings.clamp_vertex_colors and shading == resolve.GOURAUD), fog=fog,
        duv_dx=samples.duv_dx.numpy().reshape(*grid, 2), duv_dy=samples.duv_dy.numpy().reshape(*grid, 2),
        texture=texel.numpy().reshape(*grid, 3),
    )
    stats = {"method": "raster", "seconds": seconds, "triangles": n_faces, "samples": n_samples,
             "shading_points": n_points, "covered_samples": int(gbuffer.mask.sum()),
             "nonfinite_pixels": int(np.count_nonzero(~np.isfinite(pixels).all(axis=-1)))}
    return Frame(image=pixels, buffers=gbuffer, stats=stats)
