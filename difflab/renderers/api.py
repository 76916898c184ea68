"""`render` and `render_frame`: a scene (object, dict or file) in, numpy out."""

from __future__ import annotations

import os

from ..errors import RenderError
from ..scene import Scene, load_scene
from .compile import compile_scene
from .frame import Frame

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


def as_scene(scene) -> Scene:
    """A Scene from a Scene, a dict in the file format, or a path to a scene file."""
    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, dict):
        return Scene.from_dict(scene)
    if isinstance(scene, (str, os.PathLike)):
        return load_scene(scene)
    raise RenderError(f"scene: expected a Scene, a dict or a path, got {type(scene).__name__}")


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


def render_frame(scene, method=None, shading=None, specular=None, max_depth=None, spp=None, device="cpu", *,
                 width=None, height=None, threads=None, compiled=None, **options) -> Frame:
    """Render a scene and return the `Frame` (image and G-buffer; the ray tree for ray tracing).

    Arguments given override the scene's `render` block (and `width` / `height` its camera); one
    the chosen method does not use (`shading` for the ray tracer, `max_depth` for the rasterizer, ...)
    raises RenderError. A ray-traced frame has no G-buffer (`frame.gbuffer` raises) but its
    recorded `ray_tree`, whose root nodes are the primary hits.
    `compiled` reuses device arrays from `compile_scene` for the same scene and device.
    """
    scene = prepare(scene, width, height, method=method, shading=shading, specular=specular,
                    max_depth=max_depth, spp=spp, **options)
    settings = scene.render
    check_applies(settings.method, dict(options, shading=shading, max_depth=max_depth))
    from .raster.driver import rasterize

    if compiled is None or compiled.scene != scene:
        side = settings.spp_side if settings.method == "raster" else 1
        compiled = compile_scene(scene, device, sample_height=scene.camera.height * side)
    if settings.method == "raster":
        return rasterize(compiled, settings, threads)
    from .raytrace.driver import raytrace

    return raytrace(compiled, settings, threads)


def render(scene, method=None, shading=None, specular=None, max_depth=None, spp=None, device="cpu", **kwargs):
    """Render a scene to a numpy (H, W, 3) float32 linear RGB image (see `render_frame`)."""
    return render_frame(scene, method, shading, specular, max_depth, spp, device, **kwargs).image
