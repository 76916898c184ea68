"""The Mandelbrot and Julia sets by escape time, as Warp kernels, with smooth colouring.

Both iterate z <- z^2 + c: the Mandelbrot set starts at z = 0 with c the pixel, a Julia set starts
at z = the pixel with a fixed c. A point whose orbit leaves the disk |z| <= R escapes; with a large
bailout R the normalised iteration count

    nu0 = n + 1 - log2(log |z_n|)

(n the first iteration with |z_n| > R) varies continuously across the iteration bands: it is
1 - log2(log|z_n| / 2^n), and log|z_n| / 2^n tends to the set's escape potential. Far outside the
set the potential grows without bound (~ log|c|), so nu0 goes negative (points with |c| >~ 7, which
escape in one or two iterations) and -> -inf as |c| -> inf. escape_time therefore returns

    nu = nu0 if nu0 >= 1 else exp(nu0 - 1),

which keeps the classic count wherever it is >= 1 (all of the Mandelbrot view |c| <= 6.9) and
continues it below 1 with the same value and slope at the join: nu is > 0 for every escaping point,
continuous, and decreasing outward, while INTERIOR = -1 stays the one negative value. Points that
stay bounded for `max_iter` iterations are taken to be inside the set. The arithmetic is float64, so
views down to a width of ~1e-12 stay sharp.
"""

from __future__ import annotations

import numpy as np
from .._warp import wp

from ..renderers.launch import launch_rows, resolve_device
from ._checks import check_float, check_image_size, check_int, check_vec

wp.set_module_options({"enable_backward": False})

# Escape radius R. z_{n+1} = z_n^2 + c rather than z_n^2 makes nu0 jump by about
# |c| / (R^2 ln(R^2) ln 2) across each contour |z_n| = R (2e-5 at c = 15 for R = 256); at R = 2^20
# that is < 1e-12, far below float32, for 2 more iterations per escaping point.
BAILOUT = 2.0**20
INTERIOR = -1.0  # escape_time's value for points that never escaped
MAX_ITERATIONS = 1_000_000
MANDELBROT, JULIA = 0, 1


@wp.func
def smooth_escape(z0: wp.vec2d, c: wp.vec2d, max_iter: int):
    """nu (module docstring) for the first |z_n| > BAILOUT, n <= max_iter, or INTERIOR if none."""
    x = z0[0]
    y = z0[1]
    r2_max = wp.float64(BAILOUT * BAILOUT)
    for n in range(max_iter + 1):
        x2 = x * x
        y2 = y * y
        if x2 + y2 > r2_max:
            # log|z| from the larger component, as x2 + y2 overflows for |z| > 1e154 (|c| that large)
            big = wp.max(wp.abs(x), wp.abs(y))
            ratio = wp.min(wp.abs(x), wp.abs(y)) / big
            log_abs = wp.log(big) + wp.float64(0.5) * wp.log(wp.float64(1.0) + ratio * ratio)
            nu0 = wp.float64(n) + wp.float64(1.0) - wp.log2(log_abs)
            if nu0 < wp.float64(1.0):
                nu0 = wp.exp(nu0 - wp.float64(1.0))  # far outside: positive, C1 at the join
            return float(nu0)
        y = wp.float64(2.0) * x * y + c[1]
        x = x2 - y2 + c[0]
    return INTERIOR


@wp.kernel
def escape_kernel(row0: int, kind: int, corner: wp.vec2d, step: wp.float64, c_julia: wp.vec2d,
                  max_iter: int, nu: wp.array2d(dtype=float)):
    """One pixel: its complex point (centre of pixel (row0 + i, j), imaginary axis up) and its nu."""
    i, j = wp.tid()
    row = row0 + i
    point = wp.vec2d(corner[0] + (wp.float64(j) + wp.float64(0.5)) * step,
                     corner[1] - (wp.float64(row) + wp.float64(0.5)) * step)
    if kind == MANDELBROT:
        nu[row, j] = smooth_escape(wp.vec2d(wp.float64(0.0), wp.float64(0.0)), point, max_iter)
    else:
        nu[row, j] = smooth_escape(point, c_julia, max_iter)


@wp.func
def palette(t: float):
    """A smooth cyclic colour ramp (cosine palette), linear RGB in [0, 1]."""
    phase = wp.vec3(0.0, 0.10, 0.20)
    return wp.vec3(0.5 + 0.5 * wp.cos(6.2831853 * (t + phase[0])),
                   0.5 + 0.5 * wp.cos(6.2831853 * (t + phase[1])),
                   0.5 + 0.5 * wp.cos(6.2831853 * (t + phase[2])))


@wp.kernel
def colour_kernel(row0: int, nu: wp.array2d(dtype=float), image: wp.array3d(dtype=float)):
    """Interior black; outside, the palette at sqrt(nu) (nu > 0: colour bands widen gently away from
    the set), squared per channel for contrast."""
    i, j = wp.tid()
    row = row0 + i
    value = nu[row, j]
    rgb = wp.vec3(0.0, 0.0, 0.0)
    if value != INTERIOR:
        base = palette(0.15 * wp.sqrt(value) + 0.55)
        rgb = wp.cw_mul(base, base)
    image[row, j, 0] = rgb[0]
    image[row, j, 1] = rgb[1]
    image[row, j, 2] = rgb[2]


def _view(width, height, center, scale, max_iter, device):
    width, height = check_image_size(width, height)
    center = check_vec("center", center, 2)
    scale = check_float("scale", scale, 0.0, lo_open=True)
    max_iter = check_int("max_iter", max_iter, 1, MAX_ITERATIONS)
    device = resolve_device(device)
    step = scale / width  # square pixels: `scale` is the view's width in the complex plane
    corner = wp.vec2d(center[0] - 0.5 * width * step, center[1] + 0.5 * height * step)
    return width, height, corner, step, max_iter, device


def _escape(kind, width, height, center, scale, max_iter, c, device, threads, progress) -> wp.array:
    width, height, corner, step, max_iter, device = _view(width, height, center, scale, max_iter, device)
    c = check_vec("c", c, 2)
    nu = wp.empty((height, width), dtype=float, device=device)
    launch_rows(escape_kernel, (height, width), [kind, corner, wp.float64(step), wp.vec2d(*c), max_iter, nu], device,
                threads, row_work=width * (max_iter + 1), progress=progress)  # (a row's iterations at most)
    return nu


def _colour(nu: wp.array, device: str, threads) -> np.ndarray:
    height, width = nu.shape
    image = wp.empty((height, width, 3), dtype=float, device=nu.device)
    launch_rows(colour_kernel, (height, width), [nu, image], str(nu.device), threads)
    return image.numpy()


def escape_time(width: int, height: int, center=(-0.5, 0.0), scale: float = 3.0, max_iter: int = 256,
                c=None, device: str = "cpu", threads: int | None = None, progress=None) -> np.ndarray:
    """Smooth escape times nu over a view of the Mandelbrot set, or of the Julia set of `c`.

    Arguments:
        width, height: pixels (> 0). Pixel (i, j) samples the complex point at its centre:
            re = center[0] + (j + 0.5 - width/2) * scale / width,
            im = center[1] + (height/2 - i - 0.5) * scale / width   (row 0 at the top).
        center: (re, im) at the middle of the image.
        scale: width of the view in the complex plane (pixels are square).
        max_iter: iterations before a point counts as inside (1..10^6).
        c: None for the Mandelbrot set, or (re, im) of a Julia set.
        device: "cpu" or "cuda[:N]"; threads: CPU worker threads (default all cores).
        progress: None, or called as progress(rows_done, height) while the rows are computed, rows_done
            increasing to height (`launch.launch_rows`: a long run in bands of ~0.1 s).

    Returns:
        (height, width) float32: nu > 0 for escaping points, nu = n + 1 - log2(log|z_n|) where that
        is >= 1, else exp(n - log2(log|z_n|)) (module docstring), and INTERIOR = -1 for points still
        bounded after max_iter iterations.
    """
    kind, c = (MANDELBROT, (0.0, 0.0)) if c is None else (JULIA, c)
    return _escape(kind, width, height, center, scale, max_iter, c, device, threads, progress).numpy()


def mandelbrot(width: int, height: int, center=(-0.5, 0.0), scale: float = 3.0, max_iter: int = 256,
               device: str = "cpu", threads: int | None = None, progress=None) -> np.ndarray:
    """The Mandelbrot set, smoothly coloured: (height, width, 3) float32 linear RGB, interior black.

    Arguments as for `escape_time` (center default -0.5 + 0i, a view 3 wide).
    """
    nu = _escape(MANDELBROT, width, height, center, scale, max_iter, (0.0, 0.0), device, threads, progress)
    return _colour(nu, device, threads)


def julia(width: int, height: int, c=(-0.8, 0.156), center=(0.0, 0.0), scale: float = 3.2,
          max_iter: int = 256, device: str = "cpu", threads: int | None = None, progress=None) -> np.ndarray:
    """The filled Julia set of z^2 + c, smoothly coloured: (height, width, 3) float32 linear RGB.

    Arguments as for `escape_time`; c: (re, im), default -0.8 + 0.156i (a connected "dendrite").
    """
    nu = _escape(JULIA, width, height, center, scale, max_iter, c, device, threads, progress)
    return _colour(nu, device, threads)
