"""`render` and `render_frame`: a scene (object, dict, file, or `CompiledScene`) in, numpy out."""

from __future__ import annotations

from dataclasses import replace

from ..errors import RenderError
from ..guards import check_image, check_render, check_threads
from ..scene import Scene
from .compile import CompiledScene, as_scene, compile_scene
from .frame import Frame
from .launch import resolve_device

RENDER_OVERRIDES = ("method", "shading", "specular", "shadows", "max_depth", "spp", "fresnel",
                    "transparent_shadows", "clamp_vertex_colors", "interpolation", "cull_backfaces",
                    "adaptive_threshold", "sampling")
# Per renderer, the settings it does not use, each with the one value that describes what it does
# anyway; given as an argument with any other value, such a setting is an error rather than ignored.
NOT_USED = {
    "raster": ({"max_depth": 1, "fresnel": "none", "adaptive_threshold": 0.0, "sampling": "grid"},
               "the rasterizer draws primary visibility on a regular sample grid; use method='raytrace'"),
    "raytrace": ({"shading": "phong", "clamp_vertex_colors": False, "interpolation": "perspective",
                  "cull_backfaces": False},
                 "the ray tracer shades every hit with interpolated normals; use method='raster'"),
}


def prepare(scene, width=None, height=None, **overrides) -> Scene:
    """The scene with the given render settings and image size applied (None leaves a setting as is)."""
    scene = as_scene(scene)
    unknown = set(overrides) - set(RENDER_OVERRIDES)
    if unknown:
        raise RenderError(f"render: unknown option(s) {sorted(unknown)}; known: {', '.join(RENDER_OVERRIDES)}")
    render = {k: v for k, v in overrides.items() if v is not None}
    camera = None
    if width is not None or height is not None:
        camera = scene.camera.to_dict()
        camera["width"] = camera["width"] if width is None else width
        camera["height"] = camera["height"] if height is None else height
    if render or camera:
        scene = scene.with_overrides(camera=camera, render=render or None)
    return scene


def check_applies(method: str, given: dict) -> None:
    """Raise RenderError for an argument the renderer of `method` would ignore (see NOT_USED)."""
    unused, why = NOT_USED[method]
    for name, value in given.items():
        if name in unused and value is not None and value != unused[name]:
            raise RenderError(f"{name}: {value!r} does not apply to method={method!r} ({why})")


def render_frame(scene, *, method=None, shading=None, specular=None, max_depth=None, spp=None, device=None,
                 width=None, height=None, threads=None, item_buffer=None, light_buffer=False, image=True,
                 **options) -> Frame:
    """Render a scene and return the `Frame` (image and G-buffer; the ray tree for ray tracing).

    Arguments:
        scene: a Scene, a dict in the file format, a scene file, or a `CompiledScene` (from
            `compile_scene`: its device arrays, BVH and textures are reused, nothing is rebuilt).
        method, shading, specular, max_depth, spp, **options: override the scene's `render` block.
            One the chosen method does not use (`shading` for the ray tracer, `max_depth` for the
            rasterizer, ...) raises RenderError rather than being ignored.
        device: "cpu" (default) or "cuda[:N]"; a CompiledScene renders on its own device.
        width, height: override the camera's image size (not with a CompiledScene, which is
            tessellated for its camera: compile the resized scene instead).
        threads: CPU worker threads (default: $DIFFLAB_THREADS, else all cores; a rasterized
            frame of up to 256^2 samples on one, but from 128^2 samples its G-buffer passes on all:
            `launch.raster_threads`, `launch.pass_threads`).
        item_buffer, light_buffer: ray-tracer speed-ups that leave the image unchanged: the primary
            rays' mesh hits from the rasterizer's z-buffer (needs "grid" sampling; None, the
            default: on wherever it applies, False: every primary ray through the BVH), and shadow
            rays that test only the candidates of their light-buffer cell (Haines and Greenberg).
            Their costs are in `frame.stats`. True with the rasterizer: RenderError.
        image: False for the G-buffer (or ray tree) alone: `frame.image` is then None, and a
            Phong-shaded rasterized frame skips forming it (stage 7; its samples' colours are in
            the G-buffer's points). The G-buffer and the ray tree are the same either way.

    Raises RenderError before allocating a render over the memory or ray budget (`difflab.limits`),
    and instead of returning non-finite pixels (naming the scene's largest numbers).

    Returns: a `Frame`. A ray-traced frame always records its `ray_tree`; its `gbuffer` is the
    G-buffer of the tree's root nodes (the primary hits), built on first read and kept
    (`raytrace.gbuffer.tree_gbuffer`: two-sided shading normals facing the incoming ray, `face`
    -1 on exact spheres and planes, no uv derivatives).
    """
    if not isinstance(image, bool):
        raise RenderError(f"image: expected True or False, got {image!r}")
    overrides = dict(options, method=method, shading=shading, specular=specular, max_depth=max_depth, spp=spp)
    return draw(scene, overrides, device, width, height, threads, keep=True, speedups=(item_buffer, light_buffer),
                image=image)


def render(scene, *, method=None, shading=None, specular=None, max_depth=None, spp=None, device=None,
           width=None, height=None, threads=None, item_buffer=None, light_buffer=False, **options):
    """Render a scene (or a `CompiledScene`) to a numpy (H, W, 3) float32 linear RGB image; the
    keyword-only options are those of `render_frame`. Only the image is formed (no G-buffer, no
    recorded ray tree)."""
    overrides = dict(options, method=method, shading=shading, specular=specular, max_depth=max_depth, spp=spp)
    return draw(scene, overrides, device, width, height, threads, keep=False,
                speedups=(item_buffer, light_buffer)).image


def fit_frame(scene, *, device=None, threads=None) -> Frame:
    """`render_frame(scene, image=False, device=..., threads=...)` as a fit reads it (`fit.setup`;
    the frame stays inside the fit): a rasterized Phong G-buffer records its points' light
    directions, distances and visibilities but lights none of them, and forms only what the fit
    reads -- the mask, material, object, the points' normal, view, cell and light geometry, uv
    where a texture is sampled (0 elsewhere, as in a ray-traced G-buffer) and depth under fog;
    every other field is None (`raster.gbuffer.fit_skips`: colours, texture factors, texels, uv
    derivatives, faces, barycentrics, positions, and the point indices and weights, which each
    Phong sample's own point makes plain) -- and no overflow is checked (no colour is formed). The
    256^2 bench sphere's frame (one light): 3.7 MB of arrays instead of 7.7, none cleared instead of
    6.0 MB (`raster.gbuffer.gbuffer_arrays`); 1.63 -> 1.58 ms (1.70 -> 1.65 after a 32 MB sweep), its
    Phong pass 628 -> 586 us a half (731 -> 667): interleaved medians of 150-200 at load 1.1. Its
    arrays are read-only: the compiled scene's next fit frame reuses their memory once dropped,
    uncleared.
    Other frames are render_frame's."""
    return draw(scene, {}, device, None, None, threads, keep=True, image=False, geometry_only=True)


def draw(scene, overrides: dict, device, width, height, threads, keep: bool, speedups=(False, False),
         image: bool = True, geometry_only: bool = False) -> Frame:
    """The frame of `scene` under `overrides`; `keep`: also its G-buffer or recorded ray tree;
    `speedups`: (item buffer, light buffer) for the ray tracer; `image`: False to return none;
    `geometry_only`: a fit's G-buffer (`fit_frame`)."""
    threads = check_threads(threads)
    if isinstance(scene, CompiledScene):
        compiled = scene
        if width is not None or height is not None:
            raise RenderError(f"width / height: a CompiledScene is built for its camera "
                              f"({compiled.scene.camera.width}x{compiled.scene.camera.height}); compile the "
                              f"scene at the new size instead")
        if device is not None and resolve_device(device) != compiled.device:
            raise RenderError(f"device: this CompiledScene lives on {compiled.device!r}, not {device!r}")
        if overrides:  # (a fit frame has none: its compiled scene as it is, ~7 us of its cold frame)
            compiled = compiled.with_scene(prepare(compiled.scene, None, None, **overrides))
        check_render(compiled.scene)
    else:
        scene = prepare(scene, width, height, **overrides)
        check_render(scene)  # memory and ray budgets, before anything is allocated
        compiled = compile_scene(scene, "cpu" if device is None else device)
    settings = compiled.scene.render
    check_applies(settings.method, overrides)
    if settings.method == "raster":
        if any(speedups):
            raise RenderError("item_buffer / light_buffer: speed-ups of the ray tracer; use method='raytrace'")
        from .raster.driver import rasterize

        frame = rasterize(compiled, settings, threads, gbuffer=keep, image=image, geometry_only=geometry_only)
    else:
        from .raytrace.driver import raytrace

        frame = raytrace(compiled, settings, threads, record_tree=keep, use_item_buffer=speedups[0],
                         use_light_buffer=speedups[1])
    check_image(frame.image, compiled.scene, frame.stats["nonfinite_pixels"], compiled.textures)  # no NaN / inf
    return frame if image or frame.image is None else replace(frame, image=None)
