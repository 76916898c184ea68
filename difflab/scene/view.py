"""Camera, lights, fog and render settings: the scene's non-object records."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from ..vocabulary import (FOG_MODES, FRESNEL_MODES, INTERPOLATIONS, LIGHT_TYPES, MAX_DEPTH_LIMIT, MAX_SPP, METHODS,
                          PROJECTIONS, SAMPLINGS, SHADING_MODELS, SPECULAR_MODELS)
from ._check import Vec3, fail, integer, join, normalised, number, show
from ._record import Record
from ._spec import Spec, bounds, colour, spec_field

#: Largest image (width * height) a scene may ask for: 64 megapixels, a fixed cap on a frame and its
#: G-buffer (below it the memory budget, `difflab.limits`, applies). A supersampled render's sample grid (width * height * spp) is held to it too.
MAX_PIXELS = 64 * 1024 * 1024
#: Largest far / near ratio: the rasterizer's float32 depth z_ndc ~ 1 - 2 near / z (far >> near) is
#: within one float32 ulp (6e-8) of 1 for every z beyond ~1e7 near, so its z-buffer cannot order them.
#: (The ray tracer builds its rays from the camera basis and has no such limit.)
MAX_FAR_NEAR = 1e6
#: Smallest field of view (degrees) and orthographic height (scene units) the camera's float32
#: matrices and the sphere tessellation stay finite for (the fields' lower bounds, in the schema too).
MIN_FOV_Y = 1e-6
MIN_ORTHO_HEIGHT = 1e-9
#: Shortest `up` vector, and shortest eye -> target distance per unit of |eye| (squares of shorter
#: ones underflow, or their float32 difference is noise).
MIN_VECTOR = 1e-9


@dataclass(frozen=True)
class Camera(Record):
    """A pinhole (or orthographic) camera looking from `eye` at `target`; camera space looks down -z.
    width * height is at most MAX_PIXELS (64 megapixels); `up` must not be parallel to target - eye."""

    eye: Vec3 = spec_field(Spec("point3", "position of the eye", "scene units"))
    target: Vec3 = spec_field(Spec("point3", "point looked at (differs from eye)", "scene units"))
    up: Vec3 = spec_field(Spec("vec3", "up direction (not parallel to target - eye)"), (0.0, 1.0, 0.0))
    fov_y: float = spec_field(Spec("number", "vertical field of view (perspective)", "degrees", bounds(ge=MIN_FOV_Y, lt=180)), 40.0)
    width: int = spec_field(Spec("integer", "image width", "pixels", bounds(gt=0)), 320)
    height: int = spec_field(Spec("integer", "image height", "pixels", bounds(gt=0)), 240)
    projection: str = spec_field(Spec("choice", "projection", options=PROJECTIONS), "perspective")
    near: float = spec_field(Spec("coordinate", "near clip distance", "scene units", bounds(gt=0)), 0.1)
    far: float = spec_field(Spec("coordinate", "far clip distance (> near, far / near <= 1e6)", "scene units"), 100.0)
    ortho_height: float = spec_field(Spec("coordinate", "full height of the orthographic view volume", "scene units",
                                          bounds(ge=MIN_ORTHO_HEIGHT)), 2.0)

    _PATH: ClassVar[str] = "camera"
    JSON_RULES: ClassVar[tuple[dict, ...]] = ({"properties": {"up": {"not": {"const": [0, 0, 0]}}}},)

    @classmethod
    def _check(cls, v: dict, path: str) -> dict:
        p = lambda name: join(path, name)  # noqa: E731
        out = super()._check(v, path)
        eye, target, up = out["eye"], out["target"], out["up"]
        view = tuple(t - e for t, e in zip(target, eye))
        if math.hypot(*view) == 0.0:
            fail(p("target"), f"must differ from eye, got {list(target)}")
        if math.hypot(*view) < MIN_VECTOR * max(1.0, math.hypot(*eye)):
            fail(p("target"), f"is {math.hypot(*view):.3g} from eye, too close to give a view direction in float32")
        if 0.0 < math.hypot(*up) < MIN_VECTOR:
            fail(p("up"), f"is {math.hypot(*up):.3g} long, too short to give a direction (must be >= {MIN_VECTOR:g})")
        u, w = normalised(up, p("up")), normalised(view, p("target"))
        cross = (u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0])
        if not math.hypot(*cross) > 1e-6:
            fail(p("up"), f"must not be parallel to the view direction (target - eye), got {list(up)}")
        width, height = out["width"], out["height"]
        if width * height > MAX_PIXELS:
            fail(p("width"), f"{width} x {height} = {width * height} pixels is over the limit of 64 megapixels "
                 f"({MAX_PIXELS} pixels; below it the memory budget applies)")
        near, far = out["near"], out["far"]
        if not far > near:
            fail(p("far"), f"must be > near ({near}), got {show(v['far'])}")
        if far / near > MAX_FAR_NEAR:
            fail(f"{p('far')} / {p('near')}", f"{far / near:.3g} is over {MAX_FAR_NEAR:.0e} (the rasterizer's "
                 f"float32 depth loses all precision); raise near or lower far")
        return out


@dataclass(frozen=True)
class Light(Record):
    """A light source (OpenGL conventions): "point" needs `position`; "directional" needs `direction`
    (the way the light travels; no attenuation, att = 1); "spot" needs both and 0 < cutoff_deg <= 90.
    att = 1 / (kc + kl d + kq d^2) with (kc, kl, kq) = attenuation, not all zero; a spot's falloff is
    max(-L.D, 0)^exponent inside its cone."""

    type: str = spec_field(Spec("choice", "kind of light", options=tuple(LIGHT_TYPES)))
    position: Vec3 | None = spec_field(Spec("point3", "position (point, spot)", "scene units", nullable=True), None)
    direction: Vec3 | None = spec_field(Spec("unit3", "direction the light travels (directional, spot; stored "
                                             "normalised)", nullable=True), None)
    intensity: Vec3 = spec_field(colour("intensity Ip"), (1.0, 1.0, 1.0))
    attenuation: Vec3 = spec_field(Spec("vec3", "(kc, kl, kq) of att = 1 / (kc + kl d + kq d^2), not all zero",
                                        bounds=bounds(ge=0)), (1.0, 0.0, 0.0))
    cutoff_deg: float = spec_field(Spec("number", "half-angle of a spot's cone, 0 < c <= 90 (180: no cone, the "
                                        "only value for other lights)", "degrees"), 180.0)
    exponent: float = spec_field(Spec("number", "spot falloff exponent", "", bounds(ge=0)), 0.0)

    _PATH: ClassVar[str] = "light"
    JSON_RULES: ClassVar[tuple[dict, ...]] = (
        {"if": {"properties": {"type": {"const": "point"}}},
         "then": {"required": ["position"], "not": {"required": ["direction"]}}},
        {"if": {"properties": {"type": {"const": "directional"}}},
         "then": {"required": ["direction"], "not": {"required": ["position"]}}},
        {"if": {"properties": {"type": {"const": "spot"}}},
         "then": {"required": ["position", "direction", "cutoff_deg"],
                  "properties": {"cutoff_deg": {"exclusiveMinimum": 0, "maximum": 90}}},
         "else": {"properties": {"cutoff_deg": {"const": 180}}}},
        {"properties": {"attenuation": {"not": {"const": [0, 0, 0]}}}},
    )

    @classmethod
    def _check(cls, v: dict, path: str) -> dict:
        p = lambda name: join(path, name)  # noqa: E731
        out = super()._check(v, path)
        kind, position, direction = out["type"], out["position"], out["direction"]
        if kind in ("point", "spot") and position is None:
            fail(p("position"), f"required for a {kind} light")
        if kind == "directional" and position is not None:
            fail(p("position"), "not used by a directional light (it is infinitely far); remove it")
        if kind in ("directional", "spot") and direction is None:
            fail(p("direction"), f"required for a {kind} light")
        if kind == "point" and direction is not None:
            fail(p("direction"), "not used by a point light (use a spot light for a cone); remove it")
        if not any(out["attenuation"]):
            fail(p("attenuation"), "must not be all zero (kc + kl*d + kq*d^2 would be 0)")
        cutoff = out["cutoff_deg"]
        if kind == "spot":
            if cutoff == 180.0:
                fail(p("cutoff_deg"), "a spot light needs 0 < cutoff_deg <= 90 (180, the default, means "
                     f"no cone), got {show(v['cutoff_deg'])}")
            number(v["cutoff_deg"], p("cutoff_deg"), gt=0, le=90)
        elif cutoff != 180.0:
            fail(p("cutoff_deg"), f"only spot lights have a cone; must be 180 (no cone) for a {kind} "
                 f"light, got {show(v['cutoff_deg'])}")
        return out


@dataclass(frozen=True)
class Fog(Record):
    """Depth cueing / fog blended toward `color` by eye distance d (OpenGL GL_FOG): "linear"
    f = (end - d) / (end - start), needs start < end; "exp" f = exp(-density d); "exp2"
    f = exp(-(density d)^2)."""

    mode: str = spec_field(Spec("choice", "fog formula", options=tuple(FOG_MODES)))
    color: Vec3 = spec_field(colour("fog colour"), (0.5, 0.5, 0.5))
    start: float = spec_field(Spec("coordinate", "where linear fog begins", "scene units"), 0.0)
    end: float = spec_field(Spec("coordinate", "where linear fog is complete (> start)", "scene units"), 1.0)
    density: float = spec_field(Spec("number", "density of exp / exp2 fog", "per scene unit", bounds(ge=0)), 1.0)

    _PATH: ClassVar[str] = "fog"

    @classmethod
    def _check(cls, v: dict, path: str) -> dict:
        out = super()._check(v, path)
        if out["mode"] == "linear" and not out["start"] < out["end"]:
            fail(join(path, "end"), f"must be > start ({out['start']}) for linear fog, got {show(v['end'])}")
        return out


def _spp(value, path: str) -> int:
    """Samples per pixel: a perfect square side^2 in 1..MAX_SPP (both renderers sample side x side)."""
    spp = integer(value, path, ge=1, le=MAX_SPP)
    if math.isqrt(spp) ** 2 != spp:
        fail(path, f"must be a perfect square (1, 4, 9, 16, ...): both renderers take a side x side pattern of "
             f"samples per pixel, got {spp}")
    return spp


@dataclass(frozen=True)
class RenderSettings(Record):
    """How to render: the scene file's "render" block; `difflab.render(...)` arguments override it."""

    method: str = spec_field(Spec("choice", "renderer", options=METHODS), "raster")
    shading: str = spec_field(Spec("choice", "shading model (rasterizer)", options=tuple(SHADING_MODELS)), "phong")
    specular: str = spec_field(Spec("choice", "specular model", options=tuple(SPECULAR_MODELS)), "phong")
    shadows: bool = spec_field(Spec("boolean", "cast shadow rays"), True)
    max_depth: int = spec_field(Spec("integer", "ray-tree depth, the primary ray counting as 1 (ray tracer)",
                                     bounds=bounds(ge=1, le=MAX_DEPTH_LIMIT)), 5)
    spp: int = spec_field(Spec("custom", f"samples per pixel, a perfect square side^2 (1, 4, 9, ..., {MAX_SPP}) taken "
                               "as a side x side pattern in each pixel; width * height * spp <= 64 M",
                               json={"description": f"perfect square integer 1..{MAX_SPP}",
                                     "enum": [k * k for k in range(1, math.isqrt(MAX_SPP) + 1)]}), 1)
    fresnel: str = spec_field(Spec("choice", "Fresnel weighting of kr / kt (none: the plain weights)",
                                   options=tuple(FRESNEL_MODES)), "none")
    transparent_shadows: bool = spec_field(Spec("boolean", "shadow rays are multiplied by kt at each transparent "
                                                "surface (not blocked), up to 255 of them: a shadow ray meeting "
                                                "more counts as blocked (frame.stats['shadow_rays_cut'])"), True)
    clamp_vertex_colors: bool = spec_field(Spec("boolean", "clamp Gouraud vertex colours to [0, 1] (OpenGL)"), False)
    interpolation: str = spec_field(Spec("choice", "attribute interpolation", options=INTERPOLATIONS), "perspective")
    cull_backfaces: bool = spec_field(Spec("boolean", "skip triangles facing away (rasterizer)"), False)
    adaptive_threshold: float = spec_field(Spec("number", "Hall's adaptive depth control: stop a ray whose weight "
                                                "falls below it (0: off)", "", bounds(ge=0)), 0.0)
    sampling: str = spec_field(Spec("choice", "sample pattern in a pixel", options=SAMPLINGS), "grid")

    _PATH: ClassVar[str] = "render"

    @classmethod
    def _check(cls, v: dict, path: str) -> dict:
        return {**super()._check(v, path), "spp": _spp(v["spp"], join(path, "spp"))}

    @property
    def spp_side(self) -> int:
        """The side of the side x side pattern of samples in each pixel (spp = side^2)."""
        return math.isqrt(self.spp)
