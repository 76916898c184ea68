"""Scene objects: analytic spheres and planes, and triangle meshes (from a file or built in)."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, fields
from typing import ClassVar, Union

import numpy as np

from ..errors import MeshError, SceneError
from ..geometry import TriMesh
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


#: The fields of a mesh given as arrays (`vertices` and `faces` required together).
ARRAY_FIELDS = ("vertices", "faces", "normals", "uvs")


def _arrays(v: dict, path: str) -> dict:
    """vertices (V, 3), faces (F, 3) and optional normals (V, 3), uvs (V, 2), validated as a file's
    mesh is (`geometry.TriMesh`: finite, indices in range, at least one face), read-only arrays."""
    if v["faces"] is None:
        fail(join(path, "faces"), "required with 'vertices'")
    try:
        mesh = TriMesh(v["vertices"], v["faces"], v["normals"], v["uvs"], name=path)
    except MeshError as exc:
        raise SceneError(str(exc)) from None
    return {"vertices": mesh.vertices, "faces": mesh.faces, "normals": mesh.normals, "uvs": mesh.uvs}


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape == b.shape and np.array_equal(a, b)
    return a == b


@dataclass(frozen=True, eq=False)
class Mesh(Record):
    """A triangle mesh from exactly one source: `file` (OBJ/PLY..., absolute path once loaded),
    `builtin` ("teapot" | "sphere" | "box" | "cylinder" | "quad", tessellated at `resolution`,
    1..1024: the teapot's steps per patch side, the sphere's latitude bands (2x as many segments),
    the cylinder's segments / 4, the quad's and each box side's cells per edge), or arrays given from
    Python or inline in the file: `vertices` (V, 3) and `faces` (F, 3) vertex indices,
    counter-clockwise seen from the front, with optional per-vertex `normals` (V, 3) and `uvs`
    (V, 2) -- validated as a file's mesh is, stored as read-only numpy arrays.
    smooth: interpolate vertex normals (else faceted). transform: object-to-world Transform.
    Meshes compare equal when every field (and every array element) is equal."""

    material: str
    file: str | None = None
    builtin: str | None = None
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None
    normals: np.ndarray | None = None
    uvs: np.ndarray | None = None
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
        file, builtin, vertices = v["file"], v["builtin"], v["vertices"]
        given = [key for key, value in (("file", file), ("builtin", builtin), ("vertices", vertices)) if value is not None]
        if not given:
            fail(path, "needs one of 'file', 'builtin' or 'vertices' (with 'faces')")
        if len(given) > 1:
            fail(p(given[1]), f"give one of 'file', 'builtin' or 'vertices', not {' and '.join(repr(g) for g in given)}")
        if vertices is None:
            for key in ARRAY_FIELDS[1:]:
                if v[key] is not None:
                    fail(p(key), "only used with 'vertices'")
        if file is not None:
            file = existing_file(file, p("file"))
        if builtin is not None:
            builtin = choice(builtin, p("builtin"), BUILTIN_MESHES)
        arrays = dict.fromkeys(ARRAY_FIELDS) if vertices is None else _arrays(v, path)
        transform = v["transform"]
        if not isinstance(transform, Transform):
            fail(p("transform"), f"expected a Transform, got {show(transform)}")
        return dict(
            material=material, file=file, builtin=builtin, **arrays,
            resolution=integer(v["resolution"], p("resolution"), ge=1, le=MAX_RESOLUTION),
            smooth=boolean(v["smooth"], p("smooth")), transform=transform,
        )

    def to_dict(self) -> dict:
        """The JSON form: only the fields of the mesh's source (arrays as nested lists)."""
        d = super().to_dict()
        for key in ("file", "builtin", *ARRAY_FIELDS):
            if d[key] is None:
                del d[key]
        return {"type": self.TYPE, **d}

    def __eq__(self, other) -> bool:
        if type(other) is not Mesh:
            return NotImplemented
        return all(_same(getattr(self, f.name), getattr(other, f.name)) for f in fields(self))

    def __hash__(self) -> int:
        def key(value):
            return hashlib.sha1(value.tobytes()).hexdigest() if isinstance(value, np.ndarray) else value

        return hash(tuple(key(getattr(self, f.name)) for f in fields(self)))


SceneObject = Union[Sphere, Plane, Mesh]
OBJECT_TYPES: dict[str, type] = {"sphere": Sphere, "plane": Plane, "mesh": Mesh}


def parse_object(data, path: str, base_dir: str | None = None) -> SceneObject:
    """An object from its JSON form, dispatched on its "type" key."""
    d = mapping(data, path)
    if "type" not in d:
        fail(join(path, "type"), f"required (one of {', '.join(repr(t) for t in OBJECT_TYPES)})")
    kind = choice(d["type"], join(path, "type"), tuple(OBJECT_TYPES))
    return OBJECT_TYPES[kind].parse(d, path, base_dir, extra_keys=("type",))
