"""The shared machinery of scene records: validate on construction, parse from and write to JSON dicts."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from ._check import check_keys, existing_file, fail, join, mapping, show
from ._spec import spec_of


def plain(value) -> Any:
    """A JSON-able copy: records become dicts, tuples become lists."""
    if isinstance(value, Record):
        return value.to_dict()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (tuple, list)):
        return [plain(v) for v in value]
    if isinstance(value, Mapping):
        return {k: plain(v) for k, v in value.items()}
    return value


class Record:
    """Base of the frozen scene dataclasses.

    Each field declares a `Spec` (`_spec.spec_field`) that validates it, documents it and gives its
    JSON Schema. `_check(values, path) -> values` validates and normalises every field
    (idempotently) and raises `SceneError` naming `path.field`: by default field by field through the
    specs; records with rules across fields extend it. It runs on direct construction (with the
    class's `_PATH` as prefix) and in `parse` (with the position in the file as prefix).
    """

    _PATH: ClassVar[str] = ""
    #: The value of the JSON object's "type" key that selects this record (scene objects), or None.
    TYPE: ClassVar[str | None] = None
    #: JSON Schema fragments for the rules across fields that `_check` enforces by hand and a schema
    #: can state (added to the record's schema as "allOf"; see `reference.record_schema`).
    JSON_RULES: ClassVar[tuple[dict, ...]] = ()

    def __post_init__(self) -> None:
        values = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        for name, value in self._check(values, self._PATH).items():
            object.__setattr__(self, name, value)

    @classmethod
    def _check(cls, values: dict, path: str) -> dict:
        """Validated (and normalised) field values: each field checked by its spec."""
        out = dict(values)
        for f in cls.spec_fields():
            spec, value, where = spec_of(f), values[f.name], join(path, f.name)
            if spec.kind == "record" and not (isinstance(value, spec.record) or (value is None and spec.nullable)):
                fail(where, f"expected a {spec.record.__name__}, got {show(value)}")
            out[f.name] = spec.check(value, where)
        return out

    @classmethod
    def spec_fields(cls) -> tuple[dataclasses.Field, ...]:
        """The fields of the JSON form, in order (those that carry a Spec)."""
        return tuple(f for f in dataclasses.fields(cls) if spec_of(f) is not None)

    @classmethod
    def _defaults(cls) -> tuple[dict, tuple[str, ...]]:
        defaults, required = {}, []
        for f in dataclasses.fields(cls):
            if not f.init:
                continue
            if f.default is not dataclasses.MISSING:
                defaults[f.name] = f.default
            elif f.default_factory is not dataclasses.MISSING:
                defaults[f.name] = f.default_factory()
            else:
                required.append(f.name)
        return defaults, tuple(required)

    @classmethod
    def parse(cls, data, path: str, base_dir: str | None = None, *, extra_keys: tuple[str, ...] = ()):
        """Build a validated record from its JSON object; errors name `path.field`.

        `extra_keys` are allowed (and ignored) keys, such as the "type" of an object.
        """
        d = mapping(data, path)
        defaults, required = cls._defaults()
        check_keys(d, path, (*extra_keys, *defaults, *required), required)
        for key in extra_keys:
            d.pop(key, None)
        values = {**defaults, **d}
        for f in cls.spec_fields():
            spec, name = spec_of(f), f.name
            if spec.kind == "record" and name in d and not (d[name] is None and spec.nullable):
                values[name] = spec.record.parse(d[name], join(path, name), base_dir)
            if spec.kind == "file" and values.get(name) is not None:
                values[name] = existing_file(values[name], join(path, name), base_dir)
        return cls(**cls._check(values, path))

    def to_dict(self) -> dict:
        """A plain JSON-able dict with every field written explicitly."""
        return {f.name: plain(getattr(self, f.name)) for f in dataclasses.fields(self) if f.init}


class FrozenDict(dict):
    """A read-only dict (keeps insertion order; picklable, hashable when its values are)."""

    def _readonly(self, *args, **kwargs):
        raise TypeError("scene data is read-only; use dataclasses.replace or Scene.with_overrides")

    __setitem__ = __delitem__ = clear = pop = popitem = setdefault = update = _readonly
    __ior__ = _readonly

    def __hash__(self):
        return hash(tuple(self.items()))

    def __reduce__(self):
        return (FrozenDict, (dict(self),))

    def __repr__(self):
        return f"FrozenDict({dict.__repr__(self)})"
