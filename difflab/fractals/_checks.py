"""Argument checks shared by the fractal generators: every bad input becomes a `FractalError`
(or, for image sizes and devices, a `RenderError`) whose message names the argument."""

from __future__ import annotations

import math
import numbers

from ..errors import DifflabError, RenderError
from ..limits import FRACTAL_PIXEL_BYTES, require_image

# Largest image a fractal renderer allocates (pixels): 64 Mpx of float32 RGB is 768 MiB.
MAX_PIXELS = 64 * 1024 * 1024


class FractalError(DifflabError, ValueError):
    """A fractal generator was given an invalid argument; the message names it."""


def check_int(name: str, value, lo: int, hi: int | None = None) -> int:
    """`value` as an int in [lo, hi], or a FractalError naming `name`."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise FractalError(f"{name}: expected an integer, got {value!r}")
    value = int(value)
    if value < lo or (hi is not None and value > hi):
        bounds = f">= {lo}" if hi is None else f"in [{lo}, {hi}]"
        raise FractalError(f"{name}: must be {bounds}, got {value}")
    return value


def check_float(name: str, value, lo: float = -math.inf, hi: float = math.inf,
                lo_open: bool = False, hi_open: bool = False) -> float:
    """`value` as a finite float in the interval (lo, hi) with the given open/closed ends."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise FractalError(f"{name}: expected a number, got {value!r}")
    value = float(value)
    below = value <= lo if lo_open else value < lo
    above = value >= hi if hi_open else value > hi
    if not math.isfinite(value) or below or above:
        left, right = "(" if lo_open else "[", ")" if hi_open else "]"
        raise FractalError(f"{name}: must be a finite number in {left}{lo}, {hi}{right}, got {value!r}")
    return value


def check_vec(name: str, value, size: int) -> tuple[float, ...]:
    """`value` as a tuple of `size` finite floats."""
    try:
        items = tuple(value)
    except TypeError:
        raise FractalError(f"{name}: expected {size} numbers, got {value!r}") from None
    if len(items) != size:
        raise FractalError(f"{name}: expected {size} numbers, got {len(items)}")
    return tuple(check_float(f"{name}[{k}]", x) for k, x in enumerate(items))


def check_image_size(width, height) -> tuple[int, int]:
    """(width, height) as positive ints within the pixel budget, checked before anything is allocated."""
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value <= 0:
            raise RenderError(f"{name}: must be a positive integer, got {value!r}")
    if int(width) * int(height) > MAX_PIXELS:
        raise RenderError(f"width x height: {width} x {height} exceeds the budget of {MAX_PIXELS} pixels")
    require_image(int(width), int(height), "width x height", FRACTAL_PIXEL_BYTES, RenderError)
    return int(width), int(height)
