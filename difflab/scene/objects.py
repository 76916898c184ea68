"""Scene objects: analytic spheres and planes, and triangle meshes (from a file or built in)."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, fields
from typing import ClassVar, Union

import numpy as np

from ..errors import MeshError, SceneError
from ..geometry import TriMesh, uv_frame
from ._check import Vec3, choice, coordinate, fail, join, mapping, number, show
from ._record import Record
from ._spec import Spec, bounds, spec_field

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


NUMBERS = {"type": "number"}
MATRIX_JSON = {"description": "16 numbers (row-major 4x4, last row 0 0 0 1) or 4 rows of 4",
               "anyOf": [{"type": "array", "items": NUMBERS, "minItems": 16, "maxItems": 16},
                         {"type": "array", "minItems": 4, "maxItems": 4,
                          "items": {"type": "array", "items": NUMBERS, "minItems": 4, "maxItems": 4}}]}


def rows_of(width: int, items: dict, description: str) -> dict:
    """The JSON Schema of an (N, width) array given as a list of rows."""
    return {"description": description, "type": "array", "minItems": 1,
            "items": {"type": "array", "items": items, "minItems": width, "maxItems": width}}


@dataclass(frozen=True)
class Transform(Record):
    """Object-to-world transform of a mesh: scale, then rotate (about X, then Y, then Z, about the
    object origin), then translate; then `matrix` if given."""

    translate: Vec3 = spec_field(Spec("point3", "translation", "scene units"), (0.0, 0.0, 0.0))
    rotate_deg: Vec3 = spec_field(Spec("vec3", "rotation about X, then Y, then Z", "degrees"), (0.0, 0.0, 0.0))
    scale: Vec3 = spec_field(Spec("vec3", "per-axis scale factors, non-zero (one number: uniform)", grey=True),
                             (1.0, 1.0, 1.0))
    matrix: tuple[float, ...] | None = spec_field(
        Spec("custom", "an affine, invertible matrix applied after the rest", nullable=True, json=MATRIX_JSON), None)

    _PATH: ClassVar[str] = "transform"

    @classmethod
    def _check(cls, v: dict, path: str) -> dict:
        out = super()._check(v, path)
        for i, s in enumerate(out["scale"]):
            if s == 0.0:
                fail(f"{join(path, 'scale')}[{i}]", "must not be zero")
            coordinate(s, f"{join(path, 'scale')}[{i}]")
        if out["matrix"] is not None:
            out["matrix"] = _matrix(out["matrix"], join(path, "matrix"))
        return out


MATERIAL_NAME = Spec("string", "name of a material defined in `materials`")


@dataclass(frozen=True)
class Sphere(Record):
    """An analytic sphere (ray-traced exactly; the rasterizer's triangles, inscribed, place its
    silhouette within a quarter sample under Phong shading, under flat and Gouraud shading within a
    sample (at least 128 longitudes: far closer below ~1,660 samples of radius), and under Phong
    shading each sample they cover takes the sphere's exact point on its eye ray, so raster and
    ray-traced Phong spheres agree to float32 rounding where both cover a sample)."""

    center: Vec3 = spec_field(Spec("point3", "centre", "scene units"))
    radius: float = spec_field(Spec("coordinate", "radius", "scene units", bounds(gt=0)))
    material: str = spec_field(MATERIAL_NAME)

    TYPE: ClassVar[str] = "sphere"
    _PATH: ClassVar[str] = "sphere"

    def to_dict(self) -> dict:
        return {"type": self.TYPE, **super().to_dict()}


@dataclass(frozen=True)
class Plane(Record):
    """An infinite analytic plane (the rasterizer draws a large quad clipped to the view). An image
    texture lies on it with its bottom-left corner (uv = (0, 0)) at `point`, upright as seen from
    the side the normal points to, one texture per scene unit (`uv_frame`)."""

    point: Vec3 = spec_field(Spec("point3", "a point on the plane", "scene units"))
    normal: Vec3 = spec_field(Spec("unit3", "normal, the side the plane faces (stored normalised)"))
    material: str = spec_field(MATERIAL_NAME)

    TYPE: ClassVar[str] = "plane"
    _PATH: ClassVar[str] = "plane"

    def to_dict(self) -> dict:
        return {"type": self.TYPE, **super().to_dict()}

    def uv_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """(t, b): the unit directions of u and v, `geometry.uv_frame` of the normal -- right-handed
        with it (t x b = normal), upright seen from its side: a wall's v is world up (+z: t = +x,
        b = +y), a floor's -z (+y: t = +x, b = -z). `geometry.planar_uv` projects in the same frame."""
        return uv_frame(self.normal)

    def uv(self, points) -> np.ndarray:
        """Texture coordinates (N, 2) of points (N, 3) on the plane: ((p - point).t, (p - point).b),
        scene units (`uv_frame`)."""
        t, b = self.uv_frame()
        d = np.asarray(points, np.float64) - np.asarray(self.point, np.float64)
        return np.stack([d @ t, d @ b], axis=-1)


#: The fields of a mesh given as arrays (`vertices` and `faces` required together).
ARRAY_FIELDS = ("vertices", "faces", "normals", "uvs")


def _arrays(v: dict, path: str) -> dict:
    """vertices (V, 3), faces (F, 3) and optional normals (V, 3), uvs (V, 2), validated as a file's
    mesh is (`geometry.TriMesh`: finite, indices in range, at least one face), read-only arrays.
    A normal is a direction, so a zero row is an error, as any zero-length direction in a scene."""
    if v["faces"] is None:
        fail(join(path, "faces"), "required with 'vertices'")
    try:
        mesh = TriMesh(v["vertices"], v["faces"], v["normals"], v["uvs"], name=path)
    except MeshError as exc:
        raise SceneError(str(exc)) from None
    zero = [] if mesh.normals is None else np.flatnonzero(~np.any(mesh.normals != 0.0, axis=1))
    if len(zero):
        fail(f"{join(path, 'normals')}[{zero[0]}]", "must not be zero-length (a normal is a direction)")
    return {"vertices": mesh.vertices, "faces": mesh.faces, "normals": mesh.normals, "uvs": mesh.uvs}


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape == b.shape and np.array_equal(a, b)
    return a == b


def _array_field(width: int, items: dict, doc: str):
    return spec_field(Spec("custom", doc, nullable=True, json=rows_of(width, items, f"list of rows of {width} numbers")),
                      None)


@dataclass(frozen=True, eq=False)
class Mesh(Record):
    """A triangle mesh from exactly one source: `file`, `builtin`, or `vertices` + `faces` arrays
    (from Python, or inline in the file; validated as a file's mesh is and stored as read-only numpy
    arrays, with optional per-vertex `normals` and `uvs`). Meshes compare equal when every field
    (and every array element) is equal."""

    material: str = spec_field(MATERIAL_NAME)
    file: str | None = spec_field(Spec("file", "mesh file (OBJ, PLY, ... read by trimesh)", nullable=True), None)
    builtin: str | None = spec_field(
        Spec("choice", "a built-in shape (the Utah teapot, or a unit sphere, box, cylinder or quad)",
             options=BUILTIN_MESHES, nullable=True), None)
    vertices: np.ndarray | None = _array_field(3, NUMBERS, "(V, 3) vertex positions")
    faces: np.ndarray | None = _array_field(3, {"type": "integer", "minimum": 0},
                                            "(F, 3) vertex indices, counter-clockwise seen from the front")
    normals: np.ndarray | None = _array_field(3, NUMBERS, "(V, 3) per-vertex normals, none of zero length (with vertices)")
    uvs: np.ndarray | None = _array_field(2, NUMBERS, "(V, 2) per-vertex texture coordinates (with vertices)")
    resolution: int = spec_field(
        Spec("integer", "tessellation of a builtin: the teapot's steps per patch side, the sphere's latitude "
             "bands (2x as many segments), the cylinder's segments / 4, the quad's and each box side's cells "
             "per edge", bounds=bounds(ge=1, le=MAX_RESOLUTION)), 8)
    smooth: bool = spec_field(Spec("boolean", "interpolate vertex normals (false: faceted)"), True)
    transform: Transform = spec_field(Spec("record", "object-to-world transform", record=Transform), Transform())

    TYPE: ClassVar[str] = "mesh"
    _PATH: ClassVar[str] = "mesh"
    JSON_RULES: ClassVar[tuple[dict, ...]] = (
        {"oneOf": [{"required": [source]} for source in ("file", "builtin", "vertices")]},
        {"dependentRequired": {"vertices": ["faces"], "faces": ["vertices"], "normals": ["vertices"],
                               "uvs": ["vertices"]}},
    )

    @classmethod
    def _check(cls, v: dict, path: str) -> dict:
        p = lambda name: join(path, name)  # noqa: E731
        out = super()._check(v, path)
        given = [key for key in ("file", "builtin", "vertices") if out[key] is not None]
        if not given:
            fail(path, "needs one of 'file', 'builtin' or 'vertices' (with 'faces')")
        if len(given) > 1:
            fail(p(given[1]), f"give one of 'file', 'builtin' or 'vertices', not {' and '.join(repr(g) for g in given)}")
        if out["vertices"] is None:
            for key in ARRAY_FIELDS[1:]:
                if out[key] is not None:
                    fail(p(key), "only used with 'vertices'")
            return out
        return {**out, **_arrays(out, path)}

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

    def __setstate__(self, state: dict) -> None:
        """Unpickling and deep copies keep the arrays read-only (numpy restores them writeable)."""
        for name, value in state.items():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            object.__setattr__(self, name, value)

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
