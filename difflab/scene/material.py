"""Materials: the coefficients of the illumination model, plus checker and image textures."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ..vocabulary import TEXTURE_FILTER_IDS, TEXTURE_TARGET_IDS, TEXTURE_WRAP_IDS
from ._check import Vec3
from ._record import Record
from ._spec import Spec, bounds, colour, spec_field

TEXTURE_FILTERS = tuple(TEXTURE_FILTER_IDS)
TEXTURE_WRAPS = tuple(TEXTURE_WRAP_IDS)
TEXTURE_TARGETS = tuple(TEXTURE_TARGET_IDS)
#: The uv shift (per axis) that leaves a texture's image unchanged, by wrap mode: 1 with "repeat", 2
#: with "mirror" (every other tile reflected); None with "clamp" (the image has one place).
WRAP_PERIODS = {"repeat": 1.0, "mirror": 2.0, "clamp": None}
#: Accepted indices of refraction: the ray tracer's float32 optics square eta = n1 / n2 (Snell's
#: eta^2 sin_i^2; Fresnel's r_s, r_p hold eta cos_i), which overflows past ior ~2e19 (and 1 / ior
#: past ior ~5e-20) and went wrong silently (a head-on slab of ior 1e30 rendered 0.49995 for 0.566);
#: within [1e-3, 1e3] every product stays below ~1e6 and F keeps float32 precision
#: (tests/test_closed_forms.py checks both ends).
IOR_RANGE = (1e-3, 1e3)



@dataclass(frozen=True)
class Checker(Record):
    """A procedural checkerboard of world position: cell = (floor(a/size) + floor(b/size)) mod 2 over
    the two world coordinates other than the dominant axis of the surface's normal (x and z for a
    floor), whatever the surface's uv; cell 0 uses the material's ka / kd, cell 1 ka2 / kd2."""

    size: float = spec_field(Spec("number", "edge of a cell", "scene units", bounds(gt=0)), 1.0)
    ka2: Vec3 = spec_field(colour("ambient reflectance of the odd cells"), (0.0, 0.0, 0.0))
    kd2: Vec3 = spec_field(colour("diffuse reflectance of the odd cells"), (0.1, 0.1, 0.1))

    _PATH: ClassVar[str] = "checker"


@dataclass(frozen=True)
class Material(Record):
    """Surface coefficients of I = ka Ia + sum_p s att spot Ip (kd max(N.L,0) + ks S) + kr F Ir + kt (1-F) It.

    An image `texture` modulates (multiplies, per channel) its `texture_target` coefficient; give
    that coefficient 1 for the texture's own colours.
    """

    ka: Vec3 = spec_field(colour("ambient reflectance"), (0.0, 0.0, 0.0))
    kd: Vec3 = spec_field(colour("diffuse (Lambert) reflectance"), (0.8, 0.8, 0.8))
    ks: Vec3 = spec_field(colour("specular reflectance"), (0.0, 0.0, 0.0))
    n: float = spec_field(Spec("number", "specular exponent of the phong and blinn models", "", bounds(ge=0)), 1.0)
    kr: float = spec_field(Spec("number", "weight of the reflected ray (ray tracer)", "", bounds(ge=0, le=1)), 0.0)
    kt: float = spec_field(Spec("number", "weight of the transmitted ray (ray tracer)", "", bounds(ge=0, le=1)), 0.0)
    ior: float = spec_field(Spec("number", "index of refraction (docs/limits.md: float32 optics)", "",
                                 bounds(ge=IOR_RANGE[0], le=IOR_RANGE[1])), 1.0)
    absorption: Vec3 = spec_field(Spec("vec3", "Beer absorption coefficient inside the object", "per scene unit",
                                       bounds(ge=0), grey=True), (0.0, 0.0, 0.0))
    m: float = spec_field(Spec("number", "Beckmann roughness (torrance model)", "", bounds(gt=0)), 0.3)
    f0: float = spec_field(Spec("number", "Schlick reflectance at normal incidence (torrance model)", "",
                                bounds(ge=0, le=1)), 0.04)
    checker: Checker | None = spec_field(Spec("record", "procedural checkerboard", record=Checker, nullable=True), None)
    texture: str | None = spec_field(Spec("file", "image texture: a PNG / TIFF (8- or 16-bit, sRGB-decoded unless a "
                                          "PNG declares another gamma) or .npy (linear floats, >= 0)", nullable=True), None)
    filter: str = spec_field(Spec("choice", "texture filter", options=TEXTURE_FILTERS), "bilinear")
    wrap: str = spec_field(Spec("choice", "texture coordinates outside [0, 1]", options=TEXTURE_WRAPS), "repeat")
    texture_target: str = spec_field(Spec("choice", "the coefficient the texture modulates", options=TEXTURE_TARGETS),
                                     "kd")

    _PATH: ClassVar[str] = "material"

    @property
    def uv_period(self) -> float | None:
        """`WRAP_PERIODS` of the texture's wrap mode; None without a texture (uv then shows nowhere
        but the G-buffer, which keeps it unshifted)."""
        return None if self.texture is None else WRAP_PERIODS[self.wrap]
