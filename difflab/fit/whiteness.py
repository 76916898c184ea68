"""Whether a fit's residual noise is white, and the noise levels it allows when it is not
(`sigma_range`): the Laplacian noise estimate (`fit.noise.estimate_sigma`) reads the noise between
neighbours 1 pixel apart, which is the pixels' noise only when it is white. A pixel filter or a blur
makes neighbours alike (low-pass: the estimate reads low -- Mitsuba's default gaussian filter, 4
spp: sigma 4x too low, a correct fit chi2 5.2, flagged a mismatch); dithering makes them differ
(high-pass: it reads high -- an 8-bit file with Bayer ordered dither: 1.8x too high, a wrong model
chi2 1.1, reported ok). So the noise is read at a second scale too, neighbours 2 apart, and the two
compared.

At each point p of a lattice over the picked Laplacians (every a-th row and column of the box's
centre grid, where the 5 x 5 pixels around p are all used),

    L1 = R * k1 (x) k1,  k1 = [1 -2 1]          (today's Laplacian: taps 1 apart)
    L2 = R * k2 (x) k2,  k2 = [1 0 -2 0 1]      (the same taps 2 apart)

both of variance 36 sigma^2 for white noise, and l = ln(L2^2 / L1^2), clipped to +-LOG_CLIP. For
i.i.d. noise of any distribution and level, L1 and L2 are exchangeable (the same weights on i.i.d.
pixels, sharing the centre), so l has mean 0; for Gaussian noise of any correlation, its mean is
exactly ln(var L2 / var L1) (E ln Z^2 is the same for both). A level that varies across the image
breaks the exchange: L2 reads pixels 2 away that L1 does not, so l has mean 0 only where the level
is alike over 5 x 5 pixels (a 96 x 96 noise whose level steps 10x at the middle column: mean z
0.97, k 1.15; 2x: 0.23). The test:

    k = exp(mean l),   z = mean l / sqrt(V(a) / m),   not white when |z| > WHITE_Z

V(a) = sum over the lattice's lags d of g(r11(d)) + g(r22(d)) - 2 g(r12(d)), g(r) = 2 arcsin(r)^2
the covariance of ln X^2 and ln Y^2 for unit normals of correlation r, r11 / r22 / r12 the
correlations of L1 / L2 / L1 with L2 at lag d (products of the 1-D kernels' normalised
correlations): 20.1 for a = 1, 9.02 for a >= 5 (points 5 apart share no pixel). m counts per view
the points of its fullest channel: the channels' noise can be one (a renderer's paths are shared by
R, G and B), so three channels count as one. For white Gaussian noise z is then within N(0, 1) or
narrower (measured: `tests/test_fit_noise_white.py`: standard deviation 1.0 for one noise in three
channels, 0.55-0.6 for three), and WHITE_Z = 5 flags at most 5.7e-7 of white Gaussian noise fits.
V(a) is Gaussian's, not any distribution's: heavy tails widen z (its mean stays 0). White noise
with sparse outliers, as a Monte Carlo render's fireflies (96 x 96, one noise in three channels,
Gaussian 0.05 plus exponential outliers of mean 2 at a rate of 1 % / 5 %, 3000 seeds): standard
deviation 1.12 / 1.49, |z| > 5 in 0 / 2.3e-3 of the fits (a review's outliers: 1.20 / 1.72).

Cost: only the lattice's points: a = floor(sqrt(M / WHITE_SAMPLE)) for M picked Laplacians of the
fullest channel, so every one up to 4 WHITE_SAMPLE (2048), else WHITE_SAMPLE to 2.25 WHITE_SAMPLE
a channel: ~0.09 ms for a 256 x 256 view (load 6 on 2 cores; the noise estimate itself ~1 ms)."""

from __future__ import annotations

import math
from functools import lru_cache
from typing import NamedTuple

import numpy as np

WHITE_SAMPLE = 512  # a channel's lattice holds about this many points or more (its step a)
WHITE_Z = 5.0  # |z| above this: not white
LOG_CLIP = 6.0  # ln(L2^2 / L1^2) clipped to +-6 (a ratio of 400): a model's sharp error in one of the two counts at most that
K_MAX = 9.0  # the most k noise correlated only between neighbours shows (`sigma_range`)
ROUNDING_MARGIN = 2.0  # a low-pass reading counts where the noise 1 apart is above twice the rounding's (`sigma_range`)
MIN_WHITE_POINTS = 64  # fewer lattice points (the fullest channels', summed over views): not tested
_R11 = {0: 1.0, 1: -4.0 / 6.0, 2: 1.0 / 6.0}  # k1's correlation at lag d: [1 -4 6 -4 1] / 6
_R22 = {0: 1.0, 2: -4.0 / 6.0, 4: 1.0 / 6.0}  # k2's: the same, 2 apart
_R12 = {0: 4.0 / 6.0, 1: -1.0 / 6.0, 2: -2.0 / 6.0, 3: 1.0 / 6.0}  # k1 against k2: [1 -2 -1 4 -1 -2 1] / 6


@lru_cache(maxsize=16)
def log_ratio_variance(a: int) -> float:
    """V(a): the variance of a mean of l over m lattice points a apart, times m, for white Gaussian
    noise (the module's formula): the sum over lags d = (a i, a j) within the 9 x 9 the kernels
    reach of g(r11(d)) + g(r22(d)) - 2 g(r12(d)), r the separable products of the 1-D correlations."""
    lags = [d for d in range(-4, 5) if d % a == 0]
    total = 0.0
    for dy in lags:
        for dx in lags:
            r11 = _R11.get(abs(dy), 0.0) * _R11.get(abs(dx), 0.0)
            r22 = _R22.get(abs(dy), 0.0) * _R22.get(abs(dx), 0.0)
            r12 = _R12.get(abs(dy), 0.0) * _R12.get(abs(dx), 0.0)
            total += 2.0 * (math.asin(r11) ** 2 + math.asin(r22) ** 2 - 2.0 * math.asin(r12) ** 2)
    return total


def _lattice(start: int, count: int, a: int) -> slice:
    """The `count` indices start, start + a, ... as a slice."""
    return slice(start, start + a * (count - 1) + 1, a)


class Lattice(NamedTuple):
    """A view's lattice (module doc), from its picked Laplacians alone (`lattice`): its step a, the
    18 pixels L1 and L2 read at each valid point, as flat positions in the residual planes --
    (3, 2, 3, n) in each (H W) plane, every channel's, or (3, 2, 3, N) in the (3 H W) planes, per
    channel, in order: the k(s) of the rows above, below and through the point (s 1 for L1, 2 for
    L2) and each one's taps left, right and centre (`_view_log_ratios`) --, and per channel where
    each one's valid points end among them (None: every channel's)."""

    a: int
    taps: np.ndarray
    ends: np.ndarray | None


_TAPS = np.array([[[(side * s, tap * s) for tap in (-1, 1, 0)] for s in (1, 2)] for side in (-1, 1, 0)])  # (row,
# column) offsets of a point's taps: (3 rows, 2 scales, 3 taps, 2)


def lattice(centre: np.ndarray, picks: list, origin: tuple, shape: tuple) -> Lattice | None:
    """The `Lattice` of a view's centre grid (`noise.ViewPicks`' centre: (h - 2, w - 2) bool, or (3,
    h - 2, w - 2) per channel, of the box at pixel `origin` (row, column) of the (H, W) = `shape`
    images) and its channels' `Picks` (None: none); None without a point. Its points are the
    centre grid's rows and columns i = 1, 1 + a, ... (box pixel i + 1), a point valid where the
    centre grid is set at i - 1 .. i + 1 (each of those has its 3 x 3 used: the 5 x 5 around the
    point is). Formed with the picks, beside the solve (`noise.noise_picks`): the bench's Mitsuba
    sphere, first fits interleaved with the test's lattice formed in the report (one process,
    medians of 100, load 3): the report's whiteness test 149-153 -> 123-124 us of CPU."""
    count = max((p.index.size for p in picks if p is not None), default=0)
    if not count:  # (used pixels but no 3 x 3 interior: a thin strip, a scattered mask)
        return None
    hc, wc = centre.shape[-2:]
    a = max(1, math.isqrt(count // WHITE_SAMPLE))
    rows, cols = len(range(1, hc - 1, a)), len(range(1, wc - 1, a))
    if rows < 1 or cols < 1:
        return None
    ok = centre[..., _lattice(0, rows, a), :] & centre[..., _lattice(1, rows, a), :] & centre[..., _lattice(2, rows, a), :]
    ok = ok[..., _lattice(0, cols, a)] & ok[..., _lattice(1, cols, a)] & ok[..., _lattice(2, cols, a)]
    ends = None if ok.ndim == 2 else np.cumsum(np.count_nonzero(ok.reshape(3, -1), axis=1))[:-1]
    channel, point = np.divmod(np.flatnonzero(ok), rows * cols)  # (channel 0: every channel's)
    row, col = np.divmod(point, cols)
    at = channel * (shape[0] * shape[1]) + (origin[0] + 2 + a * row) * shape[1] + origin[1] + 2 + a * col
    return Lattice(a, at + (_TAPS[..., 0] * shape[1] + _TAPS[..., 1])[..., None], ends)


def _view_log_ratios(view, image) -> tuple[float, int, int, float] | None:
    """(sum of l, n, m, n^2 V(a) / m) over one view's lattice (`ViewPicks` view, with its `Lattice`;
    residual planes (3, H, W)): n its valid points, m those of its fullest channel (its mean's
    variance is V(a) / m if its channels carry one noise); None without a point. The valid points'
    taps are gathered at once and L1, L2 formed from them by the stencils' operations in their order
    (each row's k(s), then the three rows'): the bench's sphere 110 -> 99 us in a fit, 62 -> 53
    alone, against six k(s) of the lattice's row and column slices, every point's, then the valid."""
    grid = view.lattice
    if grid is None:
        return None
    shared = grid.ends is None
    taps = np.take(image.reshape(3, -1) if shared else image.reshape(-1), grid.taps, axis=-1)  # (3,) 3, 2, 3, n
    across = taps[..., 0, :] + taps[..., 1, :] - 2.0 * taps[..., 2, :]  # k(s) along the rows above, below, through
    stencils = across[..., 0, :, :] + across[..., 1, :, :] - 2.0 * across[..., 2, :, :]  # L1, L2
    with np.errstate(divide="ignore", invalid="ignore"):
        log = np.log(np.abs(stencils[..., 1, :] / stencils[..., 0, :]))  # ln |L2 / L1| = l / 2 (a tie of zeros,
        # or a non-finite residual: nan)
    np.minimum(log, LOG_CLIP / 2.0, out=log)
    np.maximum(log, -LOG_CLIP / 2.0, out=log)
    finite = np.isfinite(log)  # (left out: a tie carries no sign, a non-finite residual no noise)
    every = bool(finite.all())  # (as a rule: n and m then the lattice's, no counts: ~25 us in a fit)
    if not every:
        log = np.where(finite, log, 0.0)
    if shared:  # (3, n): every channel's points alike
        m = log.shape[1] if every else int(np.count_nonzero(finite, axis=1).max())
    else:  # channel by channel, in order
        m = max(int(np.count_nonzero(part)) for part in np.split(finite, grid.ends))
    n = log.size if every else int(np.count_nonzero(finite))
    return (2.0 * float(np.sum(log, dtype=np.float64)), n, m, n * n * log_ratio_variance(grid.a) / m) if m else None


def whiteness(views, planes) -> tuple[float, float] | None:
    """(k, z) of the fit's residuals (module doc) from each view's `ViewPicks` (None: none) and
    residual planes (3, H, W): k the variance the noise shows 2 pixels apart over what it shows 1
    apart (1 for white noise), z its departure from 1 in standard deviations; None with fewer than
    MIN_WHITE_POINTS points."""
    total = variance = 0.0
    count = fullest = 0
    for view, image in zip(views, planes):
        part = None if view is None else _view_log_ratios(view, image)
        if part is not None:
            total, count, fullest, variance = total + part[0], count + part[1], fullest + part[2], variance + part[3]
    if fullest < MIN_WHITE_POINTS:
        return None
    mean = total / count
    return math.exp(mean), mean / math.sqrt(variance / (count * count))


def sigma_range(raw: float, floor: float, test) -> tuple[float, float] | None:
    """The noise levels (low, high) a non-white noise allows, from the estimate `raw` (before the
    floor: `fit.noise.estimate_sigma`'s, 1 pixel apart) and `whiteness`'s (k, z) `test`: raw
    sqrt(k) is the level 2 apart, each floored at `floor` (the targets' quantisation); None when
    the noise reads white (|z| <= WHITE_Z, or not tested) or both levels sit at the floor. An image
    file's rounding of smooth shading is itself not white, but low-pass: a plain 8-bit POV-Ray
    sphere reads its rounding's rms (raw 0.98 of the floor) 1 apart and 1.7x that 2 apart (k 3.0,
    z 6.9); its rms is known (the floor), so the low-pass side is taken only where the noise at
    1 apart is above ROUNDING_MARGIN times the floor (the rounding then at most a quarter of it:
    its k of 3 moves k by at most 1.5). Nor where k > K_MAX = 9: noise correlated only between
    neighbours (C(d) = 0 beyond 1 pixel: a pixel filter of radius up to 1, Mitsuba's gaussian,
    k 3.6-3.9) has var L2 = 36 C(0), and var L1 at least 4 C(0) (per axis, k1's 6 - 8 c(1) with
    c(1) <= 1/2: the [1 1] / 2 filter's 2), so k <= 9; more is a model's error with sharp structure
    (a noise-free 24 x 24 ray-traced mirror fitted without its reflection: k 9.9, 11 at 48 x 48)
    or a blur wider than that, whose level neither scale reads: judged white."""
    if test is None or abs(test[1]) <= WHITE_Z or (test[0] > 1.0 and (raw < ROUNDING_MARGIN * floor or test[0] > K_MAX)):
        return None
    other = raw * math.sqrt(test[0])
    low, high = max(min(raw, other), floor), max(raw, other, floor)
    return (low, high) if high > low else None


def not_white_line(sigma: float, chi2: float, levels: tuple) -> str:
    """The fit table's line on noise that is not white: its two levels -- `sigma`, read between
    neighbours, and the other of `levels` (`sigma_range`) --, which way they differ, and chi2 (at
    sigma) over the range."""
    low, high = levels
    alike = sigma <= low  # (the neighbours' level the lower: neighbours alike)
    over = [chi2 * (sigma / level) ** 2 for level in (high, low)]
    return (f"NOISE NOT WHITE: its level reads {sigma:.3g} between neighbouring pixels and "
            f"{high if alike else low:.3g} between pixels 2 apart (each at least the targets' rounding; "
            + ("neighbours alike: a pixel filter or a blur" if alike else "neighbours differ: dithering")
            + f"); chi2 {over[0]:.3g} to {over[1]:.3g} over that range, and the model is judged against both "
            "(give sigma, --sigma, to judge it against the true noise)")
