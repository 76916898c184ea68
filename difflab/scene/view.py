"""Camera, lights, fog and render settings: the scene's non-object records."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from ..vocabulary import (FOG_MODES, FRESNEL_MODES, INTERPOLATIONS, LIGHT_TYPES, MAX_DEPTH_LIMIT, MAX_SPP, METHODS,
                          PROJECTIONS, SAMPLINGS, SHADING_MODELS, SPECULAR_MODELS)
from ._check import (Vec3, boolean, choice, coordinate, fail, integer, join, normalised, number, point3,
                     show, unit3, vec3)
from ._record import Record

#: Largest image (width * height) a scene may ask for: 64 megapixels, the memory budget of a frame
#: and its G-buffer. A supersampled render's sample grid (width * height * spp) is held to it too.
MAX_PIXELS = 64 * 1024 * 1024
#: Largest far / near ratio: beyond ~1e7 float32 unprojection of primary rays collapses (measured:
#: far / near = 1e8 gives a black ray-traced image of a visible sphere).
MAX_FAR_NEAR = 1e6
#: Smallest field of view (degrees) and orthographic height (scene units) the camera matrices and
#: the sphere tessellation stay finite for.
MIN_FOV_Y = 1e-6
MIN_ORTHO_HEIGHT = 1e-9


def at_least(x: float, smallest: float, path: str) -> float:
    """x, if x >= smallest (a positive number too small for float32 rendering is an error)."""
    if x < smallest:
        fail(path, f"must be >= {smallest:g} (the camera's float32 matrices degenerate below), got {x:g}")
    return x


@dataclass(frozen=True)
class Camera(Record):
    """A pinhole (or orthographic) camera looking from `eye` at `target`, camera space looking down -z.

    eye, target, up: world-space points / direction (scene units). fov_y: vertical field of view in
    degrees, 0 < fov_y < 180 (perspective). width, height: image size in pixels, each > 0 and
    width * height <= MAX_PIXELS (64 megapixels). projection: "perspective" | "orthographic".
    near, far: clip distances, 0 < near < far. ortho_height: full height of the orthographic view
    volume in scene units (> 0).
    """

    eye: Vec3
    target: Vec3
    up: Vec3 = (0.0, 1.0, 0.0)
    fov_y: float = 40.0
    width: int = 320
    height: int = 240
    projection: str = "perspective"
    near: float = 0.1
    far: float = 100.0
    ortho_height: float = 2.0

    _PATH: ClassVar[str] = "camera"

    @classmethod
    def _check(cls, v: dict, path: str) -> dict:
        p = lambda name: join(path, name)  # noqa: E731
        eye, target, up = point3(v["eye"], p("eye")), point3(v["target"], p("target")), vec3(v["up"], p("up"))
        view = tuple(t - e for t, e in zip(target, eye))
        if math.hypot(*view) == 0.0:
            fail(p("target"), f"must differ from eye, got {list(target)}")
        u, w = normalised(up, p("up")), normalised(view, p("target"))
        cross = (u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0])
        if not math.hypot(*cross) > 1e-6:
            fail(p("up"), f"must not be parallel to the view direction (target - eye), got {list(up)}")
        width = integer(v["width"], p("width"), gt=0)
        height = integer(v["height"], p("height"), gt=0)
        if width * height > MAX_PIXELS:
            fail(p("width"), f"{width} x {height} = {width * height} pixels exceeds the memory budget "
                 f"of 64 megapixels ({MAX_PIXELS} pixels)")
        near = coordinate(v["near"], p("near"), gt=0)
        far = coordinate(v["far"], p("far"))
        if not far > near:
            fail(p("far"), f"must be > near ({near}), got {show(v['far'])}")
        if far / near > MAX_FAR_NEAR:
            fail(p("near"), f"far / near = {far / near:.3g} is over {MAX_FAR_NEAR:.0e} (float32 depth and primary "
                 f"rays lose all precision); raise near or lower far")
        return dict(
            eye=eye, target=target, up=up,
            fov_y=at_least(number(v["fov_y"], p("fov_y"), gt=0, lt=180), MIN_FOV_Y, p("fov_y")),
            width=width, height=height,
            projection=choice(v["projection"], p("projection"), PROJECTIONS),
            near=near, far=far,
            ortho_height=at_least(coordinate(v["ortho_height"], p("ortho_height"), gt=0), MIN_ORTHO_HEIGHT,
                                  p("ortho_height")),
        )


@dataclass(frozen=True)
class Light(Record):
    """A light source (OpenGL conventions).

    type: "point" (needs position), "directional" (needs direction: the direction the light
    travels; attenuation is ignored, att = 1) or "spot" (needs both). direction is stored normalised.
    intensity: linear RGB, >= 0. attenuation: (kc, kl, kq) of att = 1 / (kc + kl d + kq d^2),
    non-negative and not all zero. cutoff_deg: half-angle of a spot's cone in degrees, 0 < c <= 90;
    180 (no cone) for point and directional lights. exponent: spot falloff max(-L.D, 0)^exponent, >= 0.
    """

    type: str
    position: Vec3 | None = None
    direction: Vec3 | None = None
    intensity: Vec3 = (1.0, 1.0, 1.0)
    attenuation: Vec3 = (1.0, 0.0, 0.0)
    cutoff_deg: float = 180.0
    exponent: float = 0.0

    _PATH: ClassVar[str] = "light"

    @classmethod
    def _check(cls, v: dict, path: str) -> dict:
        p = lambda name: join(path, name)  # noqa: E731
        kind = choice(v["type"], p("type"), LIGHT_TYPES)
        position = None if v["position"] is None else point3(v["position"], p("position"))
        direction = None if v["direction"] is None else unit3(v["direction"], p("direction"))
        if kind in ("point", "spot") and position is None:
            fail(p("position"), f"required for a {kind} light")
        if kind == "directional" and position is not None:
            fail(p("position"), "not used by a directional light (it is infinitely far); remove it")
        if kind in ("directional", "spot") and direction is None:
            fail(p("direction"), f"required for a {kind} light")
        if kind == "point" and direction is not None:
            fail(p("direction"), "not used by a point light (use a spot light for a cone); remove it")
        attenuation = vec3(v["attenuation"], p("attenuation"), ge=0)
        if not any(attenuation):
            fail(p("attenuation"), "must not be all zero (kc + kl*d + kq*d^2 would be 0)")
        cutoff = number(v["cutoff_deg"], p("cutoff_deg"))
        if kind == "spot":
            if cutoff == 180.0:
                fail(p("cutoff_deg"), "a spot light needs 0 < cutoff_deg <= 90 (180, the default, means "
                     f"no cone), got {show(v['cutoff_deg'])}")
            cutoff = number(v["cutoff_deg"], p("cutoff_deg"), gt=0, le=90)
        elif cutoff != 180.0:
            fail(p("cutoff_deg"), f"only spot lights have a cone; must be 180 (no cone) for a {kind} "
                 f"light, got {show(v['cutoff_deg'])}")
        return dict(
            type=kind, position=position, direction=direction,
            intensity=vec3(v["intensity"], p("intensity"), grey=True, ge=0),
            attenuation=attenuation, cutoff_deg=cutoff,
            exponent=number(v["exponent"], p("exponent"), ge=0),
        )


@dataclass(frozen=True)
class Fog(Record):
    """Depth cueing / fog blended toward `color` (linear RGB, >= 0) by eye distance (scene units).

    mode "linear": f = (end - d) / (end - start), needs start < end. "exp": f = exp(-density d).
    "exp2": f = exp(-(density d)^2). density >= 0. (OpenGL GL_FOG conventions.)
    """

    mode: str
    color: Vec3 = (0.5, 0.5, 0.5)
    start: float = 0.0
    end: float = 1.0
    density: float = 1.0

    _PATH: ClassVar[str] = "fog"

    @classmethod
    def _check(cls, v: dict, path: str) -> dict:
        p = lambda name: join(path, name)  # noqa: E731
        mode = choice(v["mode"], p("mode"), FOG_MODES)
        start, end = coordinate(v["start"], p("start")), coordinate(v["end"], p("end"))
        if mode == "linear" and not start < end:
            fail(p("end"), f"must be > start ({start}) for linear fog, got {show(v['end'])}")
        return dict(
            mode=mode, color=vec3(v["color"], p("color"), grey=True, ge=0), start=start, end=end,
            density=number(v["density"], p("density"), ge=0),
        )


def _spp(value, path: str) -> int:
    """Samples per pixel: a perfect square side^2 in 1..MAX_SPP (both renderers sample side x side)."""
    spp = integer(value, path, ge=1, le=MAX_SPP)
    if math.isqrt(spp) ** 2 != spp:
        fail(path, f"must be a perfect square (1, 4, 9, 16, ...): both renderers take a side x side pattern of "
             f"samples per pixel, got {spp}")
    return spp


@dataclass(frozen=True)
class RenderSettings(Record):
    """How to render: the scene file's "render" block; `difflab.render(...)` arguments override it.

    method "raster" | "raytrace"; shading "flat" | "gouraud" | "phong" (raster); specular "phong" |
    "blinn" | "torrance"; shadows: cast shadow rays; max_depth: ray-tree depth, the primary ray counts
    as 1 (1..64); spp: samples per pixel, a perfect square side^2 (1, 4, 9, ..., 4096) taken as a
    side x side pattern in each pixel, "grid" (regular) or "stratified" (`sampling`);
    fresnel "none" | "schlick" | "exact"; transparent_shadows: shadow rays are multiplied by kt at
    each transparent surface; clamp_vertex_colors: clamp Gouraud vertex colours to [0, 1];
    interpolation "perspective" | "affine"; cull_backfaces (raster); adaptive_threshold: Hall's
    adaptive depth control, stop a ray whose weight falls below it (>= 0; 0 = off).
    """

    method: str = "raster"
    shading: str = "phong"
    specular: str = "phong"
    shadows: bool = True
    max_depth: int = 5
    spp: int = 1
    fresnel: str = "none"
    transparent_shadows: bool = True
    clamp_vertex_colors: bool = False
    interpolation: str = "perspective"
    cull_backfaces: bool = False
    adaptive_threshold: float = 0.0
    sampling: str = "grid"

    _PATH: ClassVar[str] = "render"

    @classmethod
    def _check(cls, v: dict, path: str) -> dict:
        p = lambda name: join(path, name)  # noqa: E731
        return dict(
            method=choice(v["method"], p("method"), METHODS),
            shading=choice(v["shading"], p("shading"), SHADING_MODELS),
            specular=choice(v["specular"], p("specular"), SPECULAR_MODELS),
            shadows=boolean(v["shadows"], p("shadows")),
            max_depth=integer(v["max_depth"], p("max_depth"), ge=1, le=MAX_DEPTH_LIMIT),
            spp=_spp(v["spp"], p("spp")),
            fresnel=choice(v["fresnel"], p("fresnel"), FRESNEL_MODES),
            transparent_shadows=boolean(v["transparent_shadows"], p("transparent_shadows")),
            clamp_vertex_colors=boolean(v["clamp_vertex_colors"], p("clamp_vertex_colors")),
            interpolation=choice(v["interpolation"], p("interpolation"), INTERPOLATIONS),
            cull_backfaces=boolean(v["cull_backfaces"], p("cull_backfaces")),
            adaptive_threshold=number(v["adaptive_threshold"], p("adaptive_threshold"), ge=0),
            sampling=choice(v["sampling"], p("sampling"), SAMPLINGS),
        )

    @property
    def spp_side(self) -> int:
        """The side of the side x side pattern of samples in each pixel (spp = side^2)."""
        return math.isqrt(self.spp)
