"""Materials: the coefficients of the illumination model, plus checker and image textures."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ..vocabulary import TEXTURE_FILTER_IDS, TEXTURE_TARGET_IDS, TEXTURE_WRAP_IDS
from ._check import Vec3, choice, existing_file, fail, join, number, vec3
from ._record import Record

TEXTURE_FILTERS = tuple(TEXTURE_FILTER_IDS)
TEXTURE_WRAPS = tuple(TEXTURE_WRAP_IDS)
TEXTURE_TARGETS = tuple(TEXTURE_TARGET_IDS)


@dataclass(frozen=True)
class Checker(Record):
    """A procedural checkerboard: cell = (floor(a/size) + floor(b/size)) mod 2 over the surface's two
    in-plane axes; cell 0 uses the material's ka/kd, cell 1 uses ka2/kd2 (linear RGB, >= 0).
    size: cell edge in scene units (> 0)."""

    size: float = 1.0
    ka2: Vec3 = (0.0, 0.0, 0.0)
    kd2: Vec3 = (0.1, 0.1, 0.1)

    _PATH: ClassVar[str] = "checker"

    @classmethod
    def _check(cls, v: dict, path: str) -> dict:
        return dict(
            size=number(v["size"], join(path, "size"), gt=0),
            ka2=vec3(v["ka2"], join(path, "ka2"), grey=True, ge=0),
            kd2=vec3(v["kd2"], join(path, "kd2"), grey=True, ge=0),
        )


@dataclass(frozen=True)
class Material(Record):
    """Surface coefficients of I = ka Ia + sum_p s att spot Ip (kd max(N.L,0) + ks S) + kr F Ir + kt (1-F) It.

    ka, kd, ks: ambient, diffuse, specular reflectances (linear RGB triples, >= 0; one number means
    grey). n: specular exponent (>= 0). kr, kt: reflected / transmitted weights in [0, 1].
    ior: index of refraction (> 0). absorption: Beer absorption coefficient per scene unit (RGB, >= 0).
    m: Beckmann roughness (> 0) and f0: Schlick reflectance at normal incidence ([0, 1]), used by
    the "torrance" specular model. checker: optional Checker. texture: optional image file (absolute
    path once loaded) that modulates (multiplies, per channel) the `texture_target` coefficient
    ("ka" | "kd" | "ks"; give that coefficient 1 for the texture's own colours), sampled
    with `filter` ("nearest" | "bilinear" | "mipmap" | "trilinear" | "ewa") and `wrap`
    ("repeat" | "clamp" | "mirror").
    """

    ka: Vec3 = (0.0, 0.0, 0.0)
    kd: Vec3 = (0.8, 0.8, 0.8)
    ks: Vec3 = (0.0, 0.0, 0.0)
    n: float = 1.0
    kr: float = 0.0
    kt: float = 0.0
    ior: float = 1.0
    absorption: Vec3 = (0.0, 0.0, 0.0)
    m: float = 0.3
    f0: float = 0.04
    checker: Checker | None = None
    texture: str | None = None
    filter: str = "bilinear"
    wrap: str = "repeat"
    texture_target: str = "kd"

    _PATH: ClassVar[str] = "material"
    _NESTED: ClassVar[dict] = {"checker": Checker}
    _FILES: ClassVar[tuple] = ("texture",)

    @classmethod
    def _check(cls, v: dict, path: str) -> dict:
        p = lambda name: join(path, name)  # noqa: E731
        checker = v["checker"]
        if checker is not None and not isinstance(checker, Checker):
            fail(p("checker"), f"expected a Checker or None, got {checker!r:.60}")
        texture = v["texture"]
        if texture is not None:
            texture = existing_file(texture, p("texture"))
        out = {k: vec3(v[k], p(k), grey=True, ge=0) for k in ("ka", "kd", "ks")}
        out.update(
            n=number(v["n"], p("n"), ge=0),
            kr=number(v["kr"], p("kr"), ge=0, le=1),
            kt=number(v["kt"], p("kt"), ge=0, le=1),
            ior=number(v["ior"], p("ior"), gt=0),
            absorption=vec3(v["absorption"], p("absorption"), grey=True, ge=0),
            m=number(v["m"], p("m"), gt=0),
            f0=number(v["f0"], p("f0"), ge=0, le=1),
            checker=checker,
            texture=texture,
            filter=choice(v["filter"], p("filter"), TEXTURE_FILTERS),
            wrap=choice(v["wrap"], p("wrap"), TEXTURE_WRAPS),
            texture_target=choice(v["texture_target"], p("texture_target"), TEXTURE_TARGETS),
        )
        return out
