"""The lecture's line with infinitely many maxima and minima on (0, 1): f(x) = x cos(pi / x), f(0) = 0.

f is continuous at 0 (|f(x)| <= |x|) but oscillates ever faster towards it: its zeros lie at
x = 2 / (2k + 1) and it touches the lines y = +-x at x = 1 / k. Its graph has infinite length on
every interval [0, a]: the k-th swing alone is at least of height ~ 2 / k.
"""

from __future__ import annotations

import numpy as np

from ._checks import FractalError


def x_cos_pi_over_x(x) -> np.ndarray:
    """f(x) = x cos(pi / x) with f(0) = 0, elementwise on an array of finite floats."""
    x = np.asarray(x, dtype=np.float64)
    if not np.all(np.isfinite(x)):
        raise FractalError("x: contains non-finite values")
    safe = np.where(x == 0.0, 1.0, x)  # catch the removable singularity at 0 before dividing
    return np.where(x == 0.0, 0.0, x * np.cos(np.pi / safe))
