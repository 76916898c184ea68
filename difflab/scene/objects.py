"""Scene objects: analytic spheres and planes, and triangle meshes (from a file or built in)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Union

from ._check import (Vec3, boolean, choice, coordinate, existing_file, fail, integer, join, mapping,
                     number, point3, show, string, unit3, vec3)
from ._record import Record

BUILTIN_MESHES = ("teapot", "sphere", "box", "cylinder", "quad")
#: Largest tessellation resolution of a mesh (keeps the triangle count within memory).
MAX_RESOLUTION = 1024


def _matrix(value, path: str) -> tuple[float, ...]:
    """16 numbers, row-major, given flat or as 4 rows of 4; the last row must be [0, 0, 0, 1]."""
    rows = None
    if isinstance(value, (list, tuple)) and len(value) == 4 and all(isinstance(r, (list, tuple)) for r in value):
        rows = value
        if any(len(r) != 4 for r in rows):
            fail(path, f"expected 16 numbers (row-major 4x4), got {show(value)}")
        value = [x for r in rows for x in r]
    if not isinstance(value, (list, tuple)) or len(value) != 16:
        fail(path, f"expected 16 numbers (row-major 4x4), got {show(value)}")
    m = tuple(number(x, f"{path}[{i}]") for i, x in enumerate(value))
    if m[12:] != (0.0, 0.0, 0.0, 1.0):
        fail(path, f"must be affine: the last row must be [0, 0, 0, 1], got {list(m[12:])}")
    a, b, c, d, e, f, g, h, i = m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]
    if a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) == 0.0:
        fail(path, "must be invertible (its 3x3 part is singular)")
    return m


@dataclass(frozen=True)
class Transform(Record):
    """Object-to-world transform of a mesh: scale, then rotate (degrees, about X then Y then Z, about
    the object origin), then translate (scene units); then `matrix` (16 floats, row-major 4x4, affine)
    if given. scale: per-axis factors, non-zero (one number means uniform)."""

    translate: Vec3 = (0.0, 0.0, 0.0)
    rotate_deg: Vec3 = (0.0, 0.0, 0.0)
    scale: Vec3 = (1.0, 1.0, 1.0)
    matrix: tuple[float, ...] | None = None

    _PATH: ClassVar[str] = "transform"

    @classmethod
    def _check(cls, v: dict, path: str) -> dict:
        scale = vec3(v["scale"], join(path, "scale"), grey=True)
        for i, s in enumerate(scale):
            if s == 0.0:
                fail(f"{join(path, 'scale')}[{i}]", "must not be zero")
            coordinate(s, f"{join(path, 'scale')}[{i}]")
        return dict(
            translate=point3(v["translate"], join(path, "translate")),
            rotate_deg=vec3(v["rotate_deg"], join(path, "rotate_deg")),
            scale=scale,
            matrix=None if v["matrix"] is None else _matrix(v["matrix"], join(path, "matrix")),
        )


@dataclass(frozen=True)
class Sphere(Record):
    """An analytic sphere: center (scene units), radius (> 0), material name."""

    center: Vec3
    radius: float
    material: str

    TYPE: ClassVar[str] = "sphere"
    _PATH: ClassVar[str] = "sphere"

    @classmethod
    def _check(cls, v: dict, path: str) -> dict:
        return dict(
            center=point3(v["center"], join(path, "center")),
            radius=coordinate(v["radius"], join(path, "radius"), gt=0),
            material=string(v["material"], join(path, "material")),
        )

    def to_dict(self) -> dict:
        return {"type": self.TYPE, **super().to_dict()}


@dataclass(frozen=True)
class Plane(Record):
    """An infinite analytic plane through `point` with unit `normal` (stored normalised); material name."""

    point: Vec3
    normal: Vec3
    material: str

    TYPE: ClassVar[str] = "plane"
    _PATH: ClassVar[str] = "plane"

    @classmethod
    def _check(cls, v: dict, path: str) -> dict:
        return dict(
            point=point3(v["point"], join(path, "point")),
            normal=unit3(v["normal"], join(path, "normal")),
            material=string(v["material"], join(path, "material")),
        )

    def to_dict(self) -> dict:
        return {"type": self.TYPE, **super().to_dict()}


@dataclass(frozen=True)
class Mesh(Record):
    """A triangle mesh: exactly one of `file` (OBJ/PLY..., absolute path once loaded) or `builtin`
    ("teapot" | "sphere" | "box" | "cylinder" | "quad", tessellated at `resolution`, 1..1024: the
    teapot's steps per patch side, the sphere's latitude bands (2x as many segments), the cylinder's
    segments / 4, the quad's and each box side's cells per edge).
    smooth: interpolate vertex normals (else faceted). transform: object-to-world Transform."""

    material: str
    file: str | None = None
    builtin: str | None = None
    resolution: int = 8
    smooth: bool = True
    transform: Transform = Transform()

    TYPE: ClassVar[str] = "mesh"
    _PATH: ClassVar[str] = "mesh"
    _NESTED: ClassVar[dict] = {"transform": Transform}
    _FILES: ClassVar[tuple] = ("file",)

    @classmethod
    def _check(cls, v: dict, path: str) -> dict:
        p = lambda name: join(path, name)  # noqa: E731
        material = string(v["material"], p("material"))
        file, builtin = v["file"], v["builtin"]
        if file is None and builtin is None:
            fail(path, "needs one of 'file' or 'builtin'")
        if file is not None and builtin is not None:
            fail(p("builtin"), "give either 'file' or 'builtin', not both")
        if file is not None:
            file = existing_file(file, p("file"))
        if builtin is not None:
            builtin = choice(builtin, p("builtin"), BUILTIN_MESHES)
        transform = v["transform"]
        if not isinstance(transform, Transform):
            fail(p("transform"), f"expected a Transform, got {show(transform)}")
        return dict(
            material=material, file=file, builtin=builtin,
            resolution=integer(v["resolution"], p("resolution"), ge=1, le=MAX_RESOLUTION),
            smooth=boolean(v["smooth"], p("smooth")), transform=transform,
        )

    def to_dict(self) -> dict:
        return {"type": self.TYPE, **super().to_dict()}


SceneObject = Union[Sphere, Plane, Mesh]
OBJECT_TYPES: dict[str, type] = {"sphere": Sphere, "plane": Plane, "mesh": Mesh}


def parse_object(data, path: str, base_dir: str | None = None) -> SceneObject:
    """An object from its JSON form, dispatched on its "type" key."""
    d = mapping(data, path)
    if "type" not in d:
        fail(join(path, "type"), f"required (one of {', '.join(repr(t) for t in OBJECT_TYPES)})")
    kind = choice(d["type"], join(path, "type"), tuple(OBJECT_TYPES))
    return OBJECT_TYPES[kind].parse(d, path, base_dir, extra_keys=("type",))
