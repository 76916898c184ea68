"""The rasterizer's driver: allocate once per frame, launch the stages (see the package doc), return a Frame."""

from __future__ import annotations

import time

import numpy as np
from ..._warp import wp

from ...lighting.warp_model import fog_params, fog_struct
from ...vocabulary import FLAT, GOURAUD, PHONG_SHADING, SHADING_MODELS, SPECULAR_MODELS
from . import clip, coverage, resolve, shade
from ..camera import camera_struct
from ..frame import Frame, GBuffer, ShadingPoints, box_downsample
from ..launch import launch_rows, parallel_bands


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


def shading_points(compiled, cam, shading: int, samples):
    """Stage 5: the points where the model is evaluated (`samples` themselves under Phong shading)."""
    device, arrays = compiled.device, compiled.arrays
    n_faces, n_vertices = compiled.faces.shape[0], compiled.vertices.shape[0]
    if shading == PHONG_SHADING:
        return samples, samples.material.shape[0]
    if shading == FLAT:
        points = empty_points(n_faces, device)
        if n_faces:
            wp.launch(resolve.flat_points_kernel, dim=n_faces, inputs=[
                arrays["faces"], arrays["vertices"], arrays["face_normal"], arrays["face_material"],
                arrays["face_object"], compiled.materials, cam, compiled.n_mesh_faces, points], device=device)
        return points, n_faces
    points = empty_points(2 * n_vertices, device)
    if n_vertices:
        vertex_face = np.zeros(n_vertices, np.int64)
        vertex_face[compiled.faces.ravel()] = np.repeat(np.arange(n_faces), 3)
        per_vertex = [compiled.face_material[vertex_face], compiled.face_object[vertex_face],
                      (vertex_face >= compiled.n_mesh_faces).astype(np.int32)]
        wp.launch(resolve.gouraud_points_kernel, dim=(n_vertices, 2), inputs=[
            arrays["vertices"], arrays["normals"],
            *[wp.array(a.astype(np.int32), dtype=wp.int32, device=device) for a in per_vertex],
            compiled.materials, cam, points], device=device)
    return points, 2 * n_vertices


def light_points(compiled, settings, points, n_points: int, n_samples: int, points_are_samples: int,
                 threads: int | None = None) -> dict:
    """Stage 6: light every point (its colour, per-light direction, distance, visibility; the
    texture factor under flat / Gouraud, the texel per sample under Phong)."""
    device, n_lights = compiled.device, len(compiled.scene.lights)
    lit = {"light_dir": wp.zeros((n_points, n_lights), dtype=wp.vec3, device=device),
           "light_dist": wp.zeros((n_points, n_lights), dtype=float, device=device),
           "visibility": wp.zeros((n_points, n_lights), dtype=float, device=device),
           "color": wp.zeros(max(n_points, 1), dtype=wp.vec3, device=device),
           "factor": wp.zeros(max(n_points, 1), dtype=wp.vec3, device=device),  # textures under flat / Gouraud
           "texel": wp.zeros(n_samples, dtype=wp.vec3, device=device)}  # the texture value at each sample
    ambient = wp.vec3(*compiled.scene.ambient)

    def light_band(begin, end):
        wp.launch(shade.light_points_kernel, dim=end - begin, inputs=[
            begin, points, compiled.lights, compiled.materials, compiled.geom, SPECULAR_MODELS[settings.specular],
            ambient, int(settings.shadows), int(settings.transparent_shadows), lit["light_dir"], lit["light_dist"],
            lit["visibility"], lit["color"], compiled.textures.warp, points_are_samples, lit["factor"], lit["texel"]],
            device=device)

    parallel_bands(light_band, n_points, device, threads)
    return lit


def rasterize(compiled, settings, threads: int | None = None) -> Frame:
    """Render a compiled scene with the rasterizer under `settings` (a scene RenderSettings)."""
    scene, device = compiled.scene, compiled.device
    side = settings.spp_side  # the scene validated spp and the sample budget
    width, height = scene.camera.width * side, scene.camera.height * side
    shading = SHADING_MODELS[settings.shading]
    clamp_colors = bool(settings.clamp_vertex_colors and shading == GOURAUD)
    start = time.perf_counter()
    cam = camera_struct(scene.camera, width, height)
    arrays = compiled.arrays
    n_samples = width * height

    # Stages 1-3: clip space, clipping, z-buffer.
    screen, weight, facing, key = zbuffer(compiled, cam, int(settings.cull_backfaces), threads)

    # Stage 4: the per-sample G-buffer.
    samples = empty_points(n_samples, device)
    out = {name: wp.empty(n_samples, dtype=dtype, device=device) for name, dtype in
           [("face", wp.int32), ("bary", wp.vec3), ("depth", float), ("uv", wp.vec2), ("object", wp.int32),
            ("point_weight", wp.vec3)]}
    out["point_index"] = wp.empty((n_samples, 3), dtype=wp.int32, device=device)
    launch_rows(resolve.resolve_kernel, (height, width), [
        key, screen, weight, facing, arrays["faces"], arrays["vertices"], arrays["normals"], arrays["uvs"],
        arrays["face_normal"], arrays["face_material"], arrays["face_object"], compiled.materials, cam,
        int(settings.interpolation == "perspective"), shading, compiled.n_mesh_faces, compiled.vertices.shape[0],
        out["face"], out["bary"], out["depth"], out["uv"], out["object"], samples, out["point_index"],
        out["point_weight"],
    ], device, threads)

    # Stages 5-6: shading points, lit.
    points, n_points = shading_points(compiled, cam, shading, samples)
    points_are_samples = int(shading == PHONG_SHADING)
    lit = light_points(compiled, settings, points, n_points, n_samples, points_are_samples, threads)

    # Stage 7: compose samples, then filter to pixels.
    image = wp.empty(n_samples, dtype=wp.vec3, device=device)
    launch_rows(shade.compose_kernel, (height, width), [
        width, samples.material, out["depth"], out["point_index"], out["point_weight"], lit["color"],
        int(clamp_colors), wp.vec3(*scene.background), fog_struct(scene.fog), image, compiled.materials,
        compiled.textures.warp, samples, 1 - points_are_samples, lit["factor"], lit["texel"]], device, threads)
    pixels = box_downsample(image.numpy().reshape(height, width, 3), side)
    seconds = time.perf_counter() - start

    gbuffer = to_gbuffer(scene, settings, side, (height, width), samples, out, points, n_points, lit, clamp_colors)
    stats = {"method": "raster", "seconds": seconds, "triangles": compiled.faces.shape[0], "samples": n_samples,
             "shading_points": n_points, "covered_samples": int(gbuffer.mask.sum()),
             "nonfinite_pixels": int(np.count_nonzero(~np.isfinite(pixels).all(axis=-1)))}
    return Frame(image=pixels, buffers=gbuffer, stats=stats)


def to_gbuffer(scene, settings, side: int, grid: tuple[int, int], samples, out: dict, points, n_points: int,
               lit: dict, clamp_colors: bool) -> GBuffer:
    """The device buffers of stages 4-6 as a numpy `GBuffer` on the sample grid."""
    def on_grid(array, *channels):
        return array.numpy().reshape(*grid, *channels)

    material = on_grid(samples.material)
    return GBuffer(
        mask=material >= 0, depth=on_grid(out["depth"]), position=on_grid(samples.position, 3),
        normal=on_grid(samples.normal, 3), uv=on_grid(out["uv"], 2), material=material,
        object=on_grid(out["object"]), face=on_grid(out["face"]), bary=on_grid(out["bary"], 3),
        point_index=on_grid(out["point_index"], 3), point_weight=on_grid(out["point_weight"], 3),
        points=ShadingPoints(
            position=points.position.numpy(), normal=points.normal.numpy(), view=points.view.numpy(),
            material=points.material.numpy(), cell=points.cell.numpy(), light_dir=lit["light_dir"].numpy(),
            light_dist=lit["light_dist"].numpy(), visibility=lit["visibility"].numpy(),
            color=lit["color"].numpy()[:n_points], texture_factor=lit["factor"].numpy()[:n_points]),
        shading=settings.shading, specular=settings.specular, spp_side=side,
        ambient=np.asarray(scene.ambient, np.float32), background=np.asarray(scene.background, np.float32),
        clamp_vertex_colors=clamp_colors, fog=fog_params(scene.fog),
        duv_dx=on_grid(samples.duv_dx, 2), duv_dy=on_grid(samples.duv_dy, 2), texture=on_grid(lit["texel"], 3),
    )
