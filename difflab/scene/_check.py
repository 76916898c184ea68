"""Field validators for scene data: each takes a raw value and its field path, returns a clean value.

Every failure raises `SceneError` with a message that starts with the field path, e.g.
`objects[2].radius: must be > 0, got -1`. Numbers must be real, finite and within the float32 range
(bool is not a number); vectors are 3 numbers; colours may also be one number meaning grey.
"""

from __future__ import annotations

import difflib
import math
import numbers
import os
from collections.abc import Mapping

from ..errors import SceneError
from ..limits import MAX_COORD

#: Largest magnitude accepted for any number: the float32 range that the renderers compute in.
FLOAT32_MAX = 3.4028234663852886e38

Vec3 = tuple[float, float, float]


def join(path: str, key: str) -> str:
    """`path.key`, or just `key` at the top level."""
    return f"{path}.{key}" if path else str(key)


def fail(path: str, message: str):
    """Raise `SceneError("path: message")`."""
    raise SceneError(f"{path}: {message}" if path else message)


def show(value) -> str:
    """A short repr of a bad value for messages."""
    try:
        text = repr(value)
    except RecursionError:
        return "<a deeply nested value>"
    return text if len(text) <= 60 else text[:57] + "..."


def _fmt(x: float) -> str:
    return repr(int(x)) if float(x).is_integer() else repr(x)


def _is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and type(value).__name__ != "bool_"


def suggestion(word, options) -> str:
    """` (did you mean 'x'?)` for the closest of `options`, or ''."""
    if not isinstance(word, str):
        return ""
    close = difflib.get_close_matches(word, [str(o) for o in options], n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def number(value, path: str, *, gt=None, ge=None, lt=None, le=None) -> float:
    """A finite real number (as float) within the given bounds."""
    if not _is_number(value):
        fail(path, f"expected a number, got {show(value)}")
    try:
        x = float(value)
    except (OverflowError, ValueError):
        fail(path, f"must be finite, got {show(value)}")
    if not math.isfinite(x):
        fail(path, f"must be finite, got {x}")
    if abs(x) > FLOAT32_MAX:
        fail(path, f"must be within the float32 range (|x| <= 3.4e38), got {show(value)}")
    if gt is not None and not x > gt:
        fail(path, f"must be > {_fmt(gt)}, got {show(value)}")
    if ge is not None and not x >= ge:
        fail(path, f"must be >= {_fmt(ge)}, got {show(value)}")
    if lt is not None and not x < lt:
        fail(path, f"must be < {_fmt(lt)}, got {show(value)}")
    if le is not None and not x <= le:
        fail(path, f"must be <= {_fmt(le)}, got {show(value)}")
    return x


def integer(value, path: str, *, gt=None, ge=None, le=None) -> int:
    """An integer (an integral float such as 320.0 is accepted) within the given bounds."""
    if isinstance(value, numbers.Integral) and _is_number(value):
        n = int(value)
    elif _is_number(value) and math.isfinite(float(value)) and float(value).is_integer():
        n = int(value)
    else:
        fail(path, f"expected an integer, got {show(value)}")
    if gt is not None and not n > gt:
        fail(path, f"must be > {gt}, got {show(value)}")
    if ge is not None and n < ge:
        fail(path, f"must be >= {ge}, got {show(value)}")
    if le is not None and n > le:
        fail(path, f"must be <= {le}, got {show(value)}")
    return n


def boolean(value, path: str) -> bool:
    """true or false (numbers are not accepted)."""
    if isinstance(value, bool) or type(value).__name__ == "bool_":
        return bool(value)
    fail(path, f"expected true or false, got {show(value)}")


def string(value, path: str) -> str:
    """A non-empty string."""
    if not isinstance(value, str):
        fail(path, f"expected a string, got {show(value)}")
    if not value:
        fail(path, "must not be empty")
    return value


def choice(value, path: str, options) -> str:
    """One of `options` (names, or a vocabulary table name -> id), exactly."""
    options = tuple(options)
    if not isinstance(value, str) or value not in options:
        allowed = ", ".join(repr(o) for o in options)
        fail(path, f"must be one of {allowed}, got {show(value)}{suggestion(value, options)}")
    return value


def vec3(value, path: str, *, grey: bool = False, ge=None) -> Vec3:
    """Three numbers as a tuple; with `grey`, one number x means (x, x, x)."""
    if grey and _is_number(value):
        value = (value, value, value)
    items = None
    if not isinstance(value, (str, bytes, Mapping)):
        try:
            items = list(value)
        except TypeError:
            items = None
    if items is None or len(items) != 3:
        fail(path, f"expected 3 numbers, got {show(value)}")
    return tuple(number(x, f"{path}[{i}]", ge=ge) for i, x in enumerate(items))


def coordinate(value, path: str, **bounds) -> float:
    """A number that is a world-space coordinate or size: |x| <= MAX_COORD (see there)."""
    x = number(value, path, **bounds)
    if abs(x) > MAX_COORD:
        fail(path, f"must be within +-1e12 scene units (float32 rendering overflows beyond), got {show(value)}")
    return x


def point3(value, path: str) -> Vec3:
    """Three coordinates (a world-space point or offset), each within +-MAX_COORD."""
    return tuple(coordinate(x, f"{path}[{i}]") for i, x in enumerate(vec3(value, path)))


def normalised(v: Vec3, path: str) -> Vec3:
    """v / |v|; an error when v is zero. Idempotent: a vector already of unit length is kept as is."""
    length = math.hypot(*v)
    if length == 0.0:
        fail(path, "must not be zero-length")
    if abs(length - 1.0) <= 1e-15:
        return v
    return tuple(x / length for x in v)


def unit3(value, path: str) -> Vec3:
    """Three numbers, not all zero, normalised to unit length."""
    return normalised(vec3(value, path), path)


def mapping(value, path: str) -> dict:
    """A JSON object (dict with string keys)."""
    if not isinstance(value, Mapping):
        fail(path, f"expected an object, got {show(value)}")
    for key in value:
        if not isinstance(key, str):
            fail(path, f"keys must be strings, got {show(key)}")
    return dict(value)


def sequence(value, path: str) -> list:
    """A JSON array (list or tuple)."""
    if not isinstance(value, (list, tuple)):
        fail(path, f"expected a list, got {show(value)}")
    return list(value)


def check_keys(d: Mapping, path: str, allowed, required=()) -> None:
    """Unknown keys (with a close-match suggestion) and missing required keys are errors."""
    allowed = tuple(allowed)
    for key in d:
        if key not in allowed:
            fail(path or "scene", f"unknown key {key!r}{suggestion(key, allowed)}")
    for key in required:
        if key not in d:
            fail(join(path, key), "required")


def existing_file(value, path: str, base_dir: str | None = None) -> str:
    """A path to an existing file, made absolute (relative paths resolve against `base_dir`, else cwd)."""
    value = string(os.fspath(value) if isinstance(value, os.PathLike) else value, path)
    if "\x00" in value:
        fail(path, f"invalid path {show(value)}")
    if not os.path.isabs(value) and base_dir is not None:
        value = os.path.join(base_dir, value)
    value = os.path.abspath(value)
    if not os.path.isfile(value):
        why = "a folder, not a file" if os.path.isdir(value) else "not a regular file" if os.path.exists(value) \
            else "file not found"
        fail(path, f"{why}: {value}")
    return value
