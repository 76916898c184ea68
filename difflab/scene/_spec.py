"""Field specs: one declaration per scene field that validates it, describes it in the docs and
gives its JSON Schema, so the three cannot drift apart.

A record declares `name: type = spec_field(Spec(...), default)`; `Record` checks each field with
`Spec.check`, `Record.schema()` assembles `Spec.schema()`, and `docs/scene-format.md` is generated
from `Spec.describe()` (see `difflab.scene.reference`). Rules that tie fields together (a spot light
needs a direction, fog needs start < end) stay in each record's `_check`, by hand, and are written
in its docstring.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from ._check import MAX_COORD, boolean, choice, coordinate, existing_file, integer, number, point3, string, unit3, vec3

BOUND_KEYWORDS = {"gt": "exclusiveMinimum", "ge": "minimum", "lt": "exclusiveMaximum", "le": "maximum"}
BOUND_SIGNS = {"gt": ">", "ge": ">=", "lt": "<", "le": "<="}


@dataclass(frozen=True)
class Spec:
    """What one field holds.

    kind: "number" | "coordinate" (a number within +-MAX_COORD scene units) | "integer" | "boolean" |
    "string" | "choice" | "vec3" | "point3" (3 coordinates) | "unit3" | "file" | "record" |
    "custom" (validated by the record's own `_check`; `json` gives its schema).
    doc: one sentence for the reference. unit: scene units, degrees, pixels... ("" if none).
    bounds: gt / ge / lt / le for numbers (each element of a vec3). options: a choice's names.
    grey: a vec3 that may be one number x meaning (x, x, x). nullable: null (None) is allowed.
    record: the nested Record class (kind "record"). json: the schema of a "custom" field.
    """

    kind: str
    doc: str
    unit: str = ""
    bounds: tuple[tuple[str, float], ...] = ()
    options: tuple[str, ...] = ()
    grey: bool = False
    nullable: bool = False
    record: Any = None
    json: Any = None

    def check(self, value, path: str):
        """The validated value (SceneError naming `path` otherwise); "custom" and "record" pass through."""
        if value is None and self.nullable:
            return None
        bounds = dict(self.bounds)
        if self.kind == "number":
            return number(value, path, **bounds)
        if self.kind == "coordinate":
            return coordinate(value, path, **bounds)
        if self.kind == "point3":
            return point3(value, path)
        if self.kind == "integer":
            return integer(value, path, **bounds)
        if self.kind == "boolean":
            return boolean(value, path)
        if self.kind == "string":
            return string(value, path)
        if self.kind == "choice":
            return choice(value, path, self.options)
        if self.kind == "vec3":
            return vec3(value, path, grey=self.grey, **bounds)
        if self.kind == "unit3":
            return unit3(value, path)
        if self.kind == "file":
            return existing_file(value, path)
        return value

    def schema(self) -> dict:
        """The JSON Schema of the field's value in a scene file."""
        return nullable(self.bare_schema()) if self.nullable else self.bare_schema()

    def bare_schema(self) -> dict:
        limits = {BOUND_KEYWORDS[k]: v for k, v in self.bounds}
        if self.kind in ("coordinate", "point3"):
            limits = {"minimum": -MAX_COORD, "maximum": MAX_COORD, **limits}
        number_schema = {"type": "number", **limits}
        if self.kind in ("number", "integer"):
            return {"type": self.kind, **limits}
        if self.kind == "coordinate":
            return number_schema
        if self.kind == "boolean":
            return {"type": "boolean"}
        if self.kind in ("string", "file"):
            return {"type": "string", "minLength": 1}
        if self.kind == "choice":
            return {"enum": list(self.options)}
        if self.kind in ("vec3", "point3", "unit3"):
            triple = {"type": "array", "items": number_schema, "minItems": 3, "maxItems": 3}
            if self.kind == "unit3":
                triple["not"] = {"const": [0, 0, 0]}
            return {"anyOf": [number_schema, triple]} if self.grey else triple
        if self.kind == "record":
            return {"$ref": f"#/$defs/{self.record.__name__}"}
        return self.json

    def describe(self) -> str:
        """The type column of the reference: "number > 0", "one of 'a', 'b'", "3 numbers >= 0"..."""
        limits = ", ".join(f"{BOUND_SIGNS[k]} {v:g}" for k, v in self.bounds)
        names = {
            "number": "number", "coordinate": "number within +-1e12", "point3": "3 numbers within +-1e12",
            "integer": "integer", "boolean": "true / false", "string": "string",
            "file": "file path (relative to the scene file)", "unit3": "3 numbers, not all 0 (normalised)",
            "vec3": "3 numbers" + (" or 1 (grey)" if self.grey else ""),
            "choice": "one of " + ", ".join(f'"{o}"' for o in self.options),
        }
        if self.kind == "record":
            text = f"object ({self.record.__name__})"
        elif self.kind == "custom":
            text = self.json["description"]
        else:
            text = names[self.kind]
        text = f"{text} {limits}".strip() if limits else text
        return f"{text} or null" if self.nullable else text


def colour(doc: str) -> Spec:
    """A linear RGB colour or reflectance: 3 numbers >= 0, or one number meaning grey."""
    return Spec("vec3", doc, "linear RGB", bounds(ge=0), grey=True)


def nullable(schema: dict) -> dict:
    return {"anyOf": [schema, {"type": "null"}]}


def spec_field(spec: Spec, default: Any = dataclasses.MISSING, **kwargs) -> Any:
    """A dataclass field carrying `spec` (required when no default is given)."""
    return dataclasses.field(default=default, metadata={"spec": spec}, **kwargs)


def spec_of(field: dataclasses.Field) -> Spec | None:
    return field.metadata.get("spec")


def bounds(**limits: float) -> tuple[tuple[str, float], ...]:
    """`bounds(ge=0, le=1)` for `Spec(bounds=...)`."""
    return tuple(limits.items())
