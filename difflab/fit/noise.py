"""The pixel noise of a fit's targets, from its residual images at the solution (`estimate_sigma`,
`views_noise`), the pixels that carry none (`silent_pixels`), the rounding error of their files'
codes (`quantisation`), and how far a reduced chi-square against an estimated noise spreads for a
correct model (`chi2_spread`). `fit.stats` describes what the fit reports with them."""

from __future__ import annotations

import math
import threading
from typing import NamedTuple

import numpy as np

from .._warp import wp
from ..io import code_step
from ..renderers.launch import init, load_kernels
from .targets import in_channels
from .whiteness import Lattice, lattice, sigma_range, whiteness

MIN_NOISE_PIXELS = 48  # pixel channels
NOISE_BINS = 32  # the most intensity bins of a channel (sqrt(m) / 4 of m values: 4 sqrt(m) values each)
NOISE_SAMPLE = 4096  # the most Laplacians of a channel the levels are read from (every s-th)
CAP_Z2 = 9.0  # an L^2 above 9 times its noise level (three standard deviations) counts as that level
MEDIAN_CHI2_1 = 0.454936423119572  # the median of a chi-square of 1 degree of freedom
CAP_MEAN = 0.97340891  # E[z^2 if z^2 <= 9 else 1], z ~ N(0, 1): P(chi2_3 <= 9) + P(chi2_1 > 9)
LAPLACIAN_CORRELATION = 2.0 * (70.0 / 36.0) ** 2  # 7.56: a mean of (L / 6)^2 has variance this / M

wp.set_module_options({"enable_backward": False})


def _stencil(planes: np.ndarray, middle: float) -> np.ndarray:
    """(..., h - 2, w - 2) planes (..., h, w) * k^T k, k = [1 middle 1], in their own precision (two
    passes of a + middle b + c, summed in place). middle -2: the Laplacian L; middle 4: 36 times the
    mean of L's nine pixels weighted 1, 4, 16 / 36 -- as their noise variances make up L's."""
    rows = planes[..., 1:-1, :] * middle
    rows += planes[..., :-2, :]
    rows += planes[..., 2:, :]
    out = rows[..., 1:-1] * middle
    out += rows[..., :-2]
    out += rows[..., 2:]
    return out


@wp.func_native("""
const float* p = (const float*)planes + (long long)top * cols + left;  // the box's top left, channel 0
const long long* at = (const long long*)index;
double* o = (double*)out;
float* v = (float*)scratch;  // a box row's vertical sums (width + 2), then the 3 channels' L (3 width)
float* l = v + width + 2;
long long i = 0;
for (int r = 0; r < rows && i < n; ++r, p += cols) {
    long long end = (long long)(r + 1) * width;  // the centre grid's flat index past this row
    if (at[i] >= end)
        continue;
    for (int c = 0; c < 3; ++c) {
        const float* q = p + c * size;
        float* lc = l + c * width;
        for (int x = 0; x < width + 2; ++x) {  // (one operation a statement: clang contracts none into an FMA)
            float s = q[cols + x] * -2.0f;
            s += q[x];
            v[x] = s + q[2 * cols + x];
        }
        for (int x = 0; x < width; ++x) {
            float s = v[x + 1] * -2.0f;
            s += v[x];
            lc[x] = s + v[x + 2];
        }
    }
    for (long long base = end - width; i < n && at[i] < end; ++i) {
        const float* lk = l + (at[i] - base);
        for (int c = 0; c < 3; ++c)
            o[c * n + i] = (double)lk[c * width] * (double)lk[c * width];
    }
}
""")
def _squares_native(planes: wp.uint64, size: int, cols: int, top: int, left: int, width: int, rows: int,
                    index: wp.uint64, n: int, scratch: wp.uint64, out: wp.uint64):
    ...


@wp.kernel
def _squares_kernel(planes: wp.uint64, size: int, cols: int, top: int, left: int, width: int, rows: int,
                    index: wp.uint64, n: int, scratch: wp.uint64, out: wp.uint64):
    """`_squares`' one thread (CPU memory: numpy's)."""
    _squares_native(planes, size, cols, top, left, width, rows, index, n, scratch, out)


_recorded = threading.local()  # (each thread's recorded launches, by kernel)


def load_noise_kernels() -> None:
    """Load this module's Warp kernels (`renderers.launch.load_kernels`), beside the solve
    (`engine.noise_ahead`): a fit's report launches them."""
    init()
    load_kernels("cpu", _squares_kernel, _scatter_kernel)


def _launch(kernel, inputs: list) -> None:
    """Launch a one-thread CPU `kernel` of `inputs` (pointers and sizes): a recorded launch per thread,
    its arguments set anew (wp.launch packs them: ~13 us more)."""
    launch = _recorded.__dict__.get(kernel.key)
    if launch is None:
        load_noise_kernels()
        launch = _recorded.__dict__[kernel.key] = wp.launch(kernel, dim=1, inputs=inputs, device="cpu",
                                                           record_cmd=True)
    else:
        for k, value in enumerate(inputs):
            launch.set_param_at_index_from_ctype(k, value)
    launch.launch()


@wp.func_native("""
const long long* at = (const long long*)pixels;
const double* r = (const double*)part;
float* p = (float*)planes;
for (long long u = 0; u < n; ++u) {
    long long k = at[u];
    p[k] = (float)r[u];
    p[size + k] = (float)r[n + u];
    p[2 * size + k] = (float)r[2 * n + u];
}
""")
def _scatter_native(planes: wp.uint64, size: int, pixels: wp.uint64, n: int, part: wp.uint64):
    ...


@wp.kernel
def _scatter_kernel(planes: wp.uint64, size: int, pixels: wp.uint64, n: int, part: wp.uint64):
    """`scatter`'s one thread."""
    _scatter_native(planes, size, pixels, n, part)


def scatter(planes: np.ndarray, used: np.ndarray, pixels: np.ndarray, part: np.ndarray) -> None:
    """planes[c][used] = part[c] (rounded to float32) for the 3 channels of C-contiguous (3, H W)
    float32 planes, `pixels` (U,) the flat positions of `used` (H, W) in order and part (3, U): in a
    Warp CPU kernel (`_scatter_kernel`) where part is float64 and pixels int64, both C-contiguous as
    the planes -- the bench's 24729 pixels hot 24 us, numpy's 3 boolean-mask passes 48 --, else by
    numpy."""
    contiguous = all(a.flags.c_contiguous for a in (part, pixels, planes))  # (the kernel reads them flat)
    if part.dtype == np.float64 and pixels.dtype == np.int64 and contiguous:
        _launch(_scatter_kernel, [planes.ctypes.data, planes.shape[1], pixels.ctypes.data, pixels.size,
                                  part.ctypes.data])
        return
    used = used.reshape(-1)
    for c in range(3):
        planes[c][used] = part[c]  # (a boolean mask: ~3x the speed of the pixels' indices)


def _squares(planes: np.ndarray, box: tuple, index: np.ndarray) -> np.ndarray:
    """(3, M) float64 squared Laplacians of C-contiguous (3, H, W) float32 planes over the `box`
    (`ViewPicks.box`) at the sorted flat positions `index` (M,) int64 of its centre grid: the bits of
    np.square(np.take(`_stencil`(planes[:, box], -2.0), index), dtype=float64) -- the same float32
    operations in the same order (x -2 exact; no FMA: one operation a C statement) -- in one Warp
    CPU kernel (a C snippet: Warp's own array indexing, with its negative-index checks, compiled to
    scalar code that took 190-240 us here; its floor division per pick, 80 us more), a box row at a
    time: the row's 3 channels' L vectorised into a scratch row, then its picks. The bench's
    (3, 166, 164) box, 23960 picks, hot: 53 us, numpy's 6 passes, take and square 133; it reads the
    planes once and writes nothing but the result (numpy: two 320 kB temporaries and the taken
    float32 values). With `scatter`, processes alternating ABBA with the bench's fits (results kept, as
    tools/mfirst.py keeps them; 5 runs of 10 rounds, load 1.1-1.6), paired medians: first fit of the
    view -0.115 ms (faster in 33 of 50), fitted again -0.095, in a row -0.105; the report -0.08 to
    -0.095 (40 of 50). (Warp compiles this module once, ~1.5 s, then cached on disk.)"""
    index = np.ascontiguousarray(index, np.int64)  # (what the kernel reads: as a rule the picks' own)
    out = np.empty((3, index.size))
    width, rows = box[1].stop - box[1].start - 2, box[0].stop - box[0].start - 2
    scratch = np.empty(4 * width + 2, np.float32)
    inputs = [planes.ctypes.data, planes.shape[1] * planes.shape[2], planes.shape[2], box[0].start, box[1].start,
              width, rows, index.ctypes.data, index.size, scratch.ctypes.data, out.ctypes.data]
    _launch(_squares_kernel, inputs)
    return out


class Picks(NamedTuple):
    """What a noise estimate reads of one channel's Laplacians, none of it from the residuals:
    index (M,) the picked ones' flat positions in the box's centre grid; step: the levels' sample
    is every step-th of them, index[::step] (step = max(M // NOISE_SAMPLE, 1)); binned (bins,
    count): the sample's positions in index in order of intensity, the runs `_levels` takes
    medians of (None: one level); x (bins,) each bin's median intensity (one level: 0); bright:
    the intensities over the centre grid, flat (None: one level); ordered: the sample's positions
    in order of intensity and its intensities in that order (None: one level; `_sums` interpolates
    the levels there); weight: the entries' weights at index and at the sample (None: 1), and den,
    their sum."""

    index: np.ndarray
    step: int
    binned: np.ndarray | None
    x: np.ndarray
    bright: np.ndarray | None
    ordered: tuple | None
    weight: np.ndarray | None
    weight_sample: np.ndarray | None
    den: float


class ViewPicks(NamedTuple):
    """What a noise estimate reads of one view, none of it from the residuals: box (the used
    pixels' bounding box one pixel wider: its rows' and columns' slices), centre (h - 2, w - 2) bool
    over the box's centre grid, every channel's, or (3, h - 2, w - 2) per channel (the Laplacians
    picked, non-finite ones aside), the Laplacians' intensities ((h - 2) (w - 2), 3) and weights
    (3, h - 2, w - 2) or None, per channel its `Picks` (None: none), and the whiteness test's
    `Lattice` over them (None: no point)."""

    box: tuple
    centre: np.ndarray
    bright: np.ndarray | None
    weights: np.ndarray | None
    picks: list
    lattice: Lattice | None


def _picks(index, bright, weight) -> Picks:
    """A channel's `Picks` for its picked Laplacians `index`, its intensities and weights over the
    centre grid, flat (None: one level; 1). The levels' bins (`_levels`): the sample (m values) in
    order of intensity cut into runs of equal count, sqrt(m) / 4 bins of 4 sqrt(m) values, at most
    NOISE_BINS, the middle bins * count values kept."""
    step = max(index.size // NOISE_SAMPLE, 1)
    sample = index[::step]
    bright_sample = None if bright is None else bright[sample]
    bins = 1 if bright is None else min(max(int(math.sqrt(sample.size)) // 4, 1), NOISE_BINS)
    binned, x, ordered = None, np.zeros(1), None
    if bins > 1:
        count = sample.size // bins
        trim = (sample.size - bins * count) // 2
        everyone = _order(bright_sample)
        order = everyone[trim:trim + bins * count].reshape(bins, count)
        binned, x, ordered = order * step, bright_sample[order[:, count // 2]], (everyone, bright_sample[everyone])
    at_index = None if weight is None else weight[index]
    return Picks(index, step, binned, x, bright, ordered, at_index,
                 None if weight is None else weight[sample],
                 float(index.size if weight is None else np.sum(at_index)))


def _order(values: np.ndarray) -> np.ndarray:
    """np.argsort of (n,) finite float32 values, n < 2^29, equal ones in order of position (negative
    ones in reverse): widened to float64, each carries its position in the 29 low mantissa bits the
    widening leaves 0, and one float64 sort orders them -- 19 us for 4773 values, np.argsort 38 (its
    quicksort leaves equal ones in no set order). (An infinity with position bits turns NaN: last.)"""
    keys = values.astype(np.float64).view(np.int64) | np.arange(values.size)
    return np.sort(keys.view(np.float64)).view(np.int64) & (2 ** 29 - 1)


def _levels(values: np.ndarray, picks: Picks) -> np.ndarray:
    """The noise level -- the variance of L where it is Gaussian -- of a channel's L^2 values (at
    its `Picks`' index) as a function of their intensity (the mean signal of each L's pixels,
    weighted as their variances are: `_stencil`), read from their sample: v (bins,), the level at
    intensity i being np.interp(i, x, v). Each bin of the sample in order of intensity is a point
    (its median intensity x, its median L^2 / MEDIAN_CHI2_1): the bins narrow enough to follow the
    level (a side-lit sphere's 400 values a channel, one bin: its bright limb's noise capped away,
    a correct fit read chi2 2.0-2.4, flagged; 5 bins: 0.95-1.52, ok), wide enough that a median is
    a level (bins of 64 values: a flat signal's chi2 spread 1.5x the formula's; of 4 sqrt(m):
    1.2x). Where the noise grows with the signal (a camera's, a renderer's, 8-bit code steps), the
    level follows it, and a model's sharp errors -- an edge, a penumbra, a rim: few values among
    those of their intensity -- stay outliers of their bin. (Spatial blocks did not: in a block
    straddling bright and dark pixels the median was the dark pixels', the bright ones' real noise
    was capped away, and a correct model of a checker floor with noise of 3 % of the signal read
    chi2 1.38: `mismatch_suspected` 20 times of 20.)"""
    if picks.binned is None:
        return np.array([np.median(values[::picks.step]) / MEDIAN_CHI2_1])
    count = picks.binned.shape[1]
    ordered = np.sort(values[picks.binned], axis=1)  # (each bin's median, as np.median's: a sort of the rows
    # took 12 us a channel of 17 x 280, np.partition at the two middles 28)
    return (ordered[:, (count - 1) // 2] + ordered[:, count // 2]) / 2.0 / MEDIAN_CHI2_1


def _count_per_level(picks: Picks) -> int:
    """How many sampled values each of a channel's levels is the median of (`_levels`)."""
    return -(-picks.index.size // picks.step) if picks.binned is None else picks.binned.shape[1]


def _view_picks(used, weights, signal, interior: bool) -> ViewPicks | None:
    """A view's `ViewPicks` from its used map, weights and signal (`estimate_sigma`'s), or None
    when it has no Laplacian (no used pixel, or a box under 3 x 3)."""
    pixels = used if used.ndim == 2 else used[..., 0] | used[..., 1] | used[..., 2]
    rows, cols = np.flatnonzero(pixels.any(axis=1)), np.flatnonzero(pixels.any(axis=0))
    if rows.size == 0 or used.shape[0] < 3 or used.shape[1] < 3:
        return None
    top, left = max(rows[0] - 1, 0), max(cols[0] - 1, 0)  # the box, one pixel wider (non-interior case)
    box = (slice(top, min(rows[-1] + 2, used.shape[0])), slice(left, min(cols[-1] + 2, used.shape[1])))
    shape, used = used.shape[:2], used[box]
    if used.shape[0] < 3 or used.shape[1] < 3:
        return None
    centre = used[1:-1, 1:-1]
    if interior:
        across = used[:, :-2] & used[:, 1:-1] & used[:, 2:]
        centre = across[:-2] & across[1:-1] & across[2:]
    shared = np.flatnonzero(centre) if centre.ndim == 2 else None  # (every channel's)
    centre = centre if shared is not None else _planes(centre)
    bright = None if signal is None else _stencil(np.asarray(signal)[box].astype(np.float32, copy=False).transpose(
        2, 0, 1), 4.0).transpose(1, 2, 0).reshape(-1, 3)  # (binned: float32 is plenty; the signal's channel-last
    # memory kept, channel-major planes a copy more: 0.113 -> 0.104 ms for 180 x 180)
    weights = None if weights is None else _planes(weights[box][1:-1, 1:-1])
    picks = [_channel(np.flatnonzero(centre[c]) if shared is None else shared, bright, weights, c) for c in range(3)]
    return ViewPicks(box, centre, bright, weights, picks, lattice(centre, picks, (top, left), shape))


def _channel(index, bright, weights, c: int) -> Picks | None:
    """Channel c's `Picks` at `index` (None where it is empty)."""
    if not index.size:
        return None
    return _picks(index, None if bright is None else bright[:, c],
                  None if weights is None else weights[c].reshape(-1))


def _planes(image, dtype=None) -> np.ndarray:
    """(3, ...) contiguous channel planes of an (..., 3) image."""
    return np.ascontiguousarray(np.moveaxis(image, -1, 0), dtype)


def _read(views: list, planes) -> list:
    """Per view (None: none) per channel (None: no Laplacian picked) what `estimate_sigma` reads of
    its residuals, as (picks, values, level): the channel's `Picks` (without a non-finite value), its
    squared Laplacians there in float64 -- from the view's residuals as (3, H, W) planes, in their
    own precision (float32 residual images), over the box: `_squares` where every channel's are at
    one index and the planes are C-contiguous float32 (a fit's), else, and for the picks without a
    non-finite value, numpy's `_stencil` (the reference: `estimate_sigma`'s planes of (H, W, 3)
    images are neither; per-channel picks are rare) -- and their levels (`_levels`). (The
    Laplacian by XLA on the one-thread client, dispatched after `Setup.residual_planes` and taken
    here -- the same bits: a b + c with b times -2 exact --: the bench's fits alternating in one
    process, results dropped, the report -59 us first, -35 again (medians of 80); but processes
    alternating ABBA with the results kept, 3 runs of 10-12 rounds, the report +0.1-0.3 ms in fits
    again and in a row: its dispatch 0.04 ms, and in fits again XLA's run not done when read in 21
    of 40, a median wait of 0.1 ms. Not taken.)"""
    read = []
    for view, image in zip(views, planes):
        read.append(None if view is None else [None, None, None])
        if view is None:
            continue
        shared = view.centre.ndim == 2 and view.picks[0] is not None  # (every channel's at one index: one take)
        laplacian = None if shared and image.dtype == np.float32 and image.flags.c_contiguous else \
            _laplacian(image, view.box)
        squared = None if not shared else _squares(image, view.box, view.picks[0].index) if laplacian is None else \
            np.square(np.take(laplacian, view.picks[0].index, axis=1), dtype=np.float64)
        finite = shared and np.isfinite(squared.max())  # (as a rule, every channel's at once: no check per channel)
        for c, picks in enumerate(view.picks):
            values = None if picks is None else squared[c] if shared else \
                np.square(np.take(laplacian[c], picks.index), dtype=np.float64)
            if values is not None and not finite and not np.isfinite(values.max()):  # (rare: a NaN or inf) the
                laplacian = _laplacian(image, view.box) if laplacian is None else laplacian
                centre = (view.centre if view.centre.ndim == 2 else view.centre[c]).reshape(-1)  # picks without them
                picks = _channel(np.flatnonzero(centre & np.isfinite(laplacian[c])), view.bright, view.weights, c)
                values = None if picks is None else np.square(np.take(laplacian[c], picks.index), dtype=np.float64)
            if picks is not None:
                read[-1][c] = (picks, values, _levels(values, picks))
    return read


def _laplacian(image: np.ndarray, box: tuple) -> np.ndarray:
    """(3, (h - 2) (w - 2)) Laplacians of (3, H, W) planes over the box (`_stencil`)."""
    with np.errstate(invalid="ignore", over="ignore"):  # (inf - inf: NaN; either is left out)
        return _stencil(image[:, box[0], box[1]], -2.0).reshape(3, -1)


def _sums(channels: list) -> tuple[float, float, float]:
    """(num, spread, square_spread) of `estimate_sigma` from what it read of its channels (`_read`'s
    (picks, values, level); the values capped in place)."""
    num = spread = square_spread = 0.0
    for picks, values, level in channels:
        over = np.flatnonzero(values > CAP_Z2 * level.min())  # (only these can be above 9 times their level)
        if over.size:
            high = level[0] if picks.bright is None else np.interp(picks.bright[picks.index[over]], picks.x, level)
            capped = values[over]
            values[over] = np.where(capped > CAP_Z2 * high, high, capped)
        num += float(np.sum(values if picks.weight is None else values * picks.weight))  # (no BLAS dot: slow threads)
        sampled = -(-picks.index.size // picks.step)  # m
        if picks.ordered is None:  # the share, from the sample: one level
            weighted = np.full(sampled, level[0])
        else:  # the levels at the sample's intensities, interpolated in order of intensity and put back (np.interp
            # finds each one's bin at its first guess: a fit's 3 x 4773 values 19 us a channel, in the sample's
            # order 24 -- 45 where a noisy target's neighbours' bins differ; bench fits alternating, medians of 60)
            weighted = np.empty(sampled)
            weighted[picks.ordered[0]] = np.interp(picks.ordered[1], picks.x, level)
        if picks.weight_sample is not None:
            weighted *= picks.weight_sample
        scale = picks.index.size / sampled  # M / m
        spread += float(np.sum(weighted)) * scale
        square_spread += float(np.sum(np.square(weighted))) * scale
    return num, spread, square_spread


def estimate_sigma(images, used_maps, weight_maps=None, *, interior=True, signals=None):
    """The Laplacian noise estimate of (H, W, 3) residual images over their used entries -- only
    those whose 3 x 3 neighbourhood is used, when `interior` --: (sigma, M, share), or None with
    fewer than MIN_NOISE_PIXELS, with

        sigma^2 = sum_c w_c q_c / (36 CAP_MEAN sum_c w_c),   q_c = L_c^2, or v_c where L_c^2 > 9 v_c

    share = (sum_c w_c v_c)^2 / (M sum_c w_c^2 v_c^2)

    over the M entries c picked (w_c: the entry's weight from `weight_maps`, (H, W, 3) or None for
    1). L = R * [1 -2 1; -2 4 -2; 1 -2 1] has variance 36 times the mean of its nine pixels' noise
    variances (weighted 1, 4, 16 by position, summing to 36), so sigma^2 is the weighted mean noise
    variance -- what a chi-square's mean of w r^2 over the same weights compares with, noise that
    varies over the image (a renderer's, with the signal) included (a median level reads the median
    pixel's: a correct fit of noise proportional to the signal gave chi2 2.6-15). A model's sharp
    errors (an edge, a shadow's penumbra, a rim) are kept out: an L^2 above CAP_Z2 = 9 (three
    standard deviations) times its noise level v_c counts as v_c; Gaussian noise keeps CAP_MEAN =
    0.973 of its mean square so, corrected for. v_c is the level of the values of similar signal
    (`_levels`): each L's intensity is the mean of `signals` (per image (H, W, 3): the target;
    None: one level per channel) over its nine pixels weighted as their variances are. share:
    how many of M equally weighted values of equal noise the weighted values of unequal noise count
    as, per value (`chi2_spread`; its sums from the levels' sample). A used map is (H, W) bool (every
    channel of a used pixel) or (H, W, 3) (per channel: where some channels have weight 0, their
    residuals are 0, not noise, and must not enter a neighbourhood). (Over the used pixels'
    bounding box: what depends on no residual, `ViewPicks`, first.)"""
    views = [_view_picks(used, None if weight_maps is None else weight_maps[k],
                         None if signals is None else signals[k], interior) for k, used in enumerate(used_maps)]
    estimate = _estimate(views, [np.moveaxis(np.asarray(image), -1, 0) for image in images])
    return None if estimate is None else estimate[:3]


def _estimate(views: list, planes, on_levels=None):
    """`estimate_sigma` from the views' `ViewPicks` and residual planes (3, H, W), with the levels it
    read after it: per view (None: none) per channel (None: none) (x, v, n), v the levels at
    intensities x (in units of 36 times the signal; one level: x = [0]) and n `_count_per_level`.
    `on_levels(levels)` is called as soon as they are read, before the sums, when there is an
    estimate (what depends on them can start: `engine.report` dispatches the sandwich's middle)."""
    read = _read(views, planes)
    channels = [channel for view in read if view is not None for channel in view if channel]
    count, den = 0, 0.0
    for picks, _, _ in channels:
        count, den = count + picks.index.size, den + picks.den
    if count < MIN_NOISE_PIXELS or den <= 0:
        return None
    levels = [None if view is None else [None if channel is None else (
        channel[0].x, channel[2], _count_per_level(channel[0])) for channel in view] for view in read]
    if on_levels is not None:
        on_levels(levels)
    num, spread, square_spread = _sums(channels)
    share = spread * spread / (count * square_spread) if square_spread > 0 else 1.0
    return math.sqrt(num / (36.0 * CAP_MEAN * den)), count, share, levels


def at_ceiling(image, ceiling) -> np.ndarray:
    """(...) bool: the pixels of an image (..., 3) with a channel at or above `ceiling` (three
    comparisons or'ed: numpy's `any` over a last axis of 3 costs ~10x as much)."""
    top = image >= ceiling
    return top[..., 0] | top[..., 1] | top[..., 2]


def silent_pixels(views, r) -> tuple[list[np.ndarray], int]:
    """The used pixels of a fit's views (`records.View`) that carry no noise: target and model both
    exactly 0 in every channel (an unlit side; a renderer's noise scales with its signal), from the
    weighted residuals r, per view (3, U) (`Problem.view_residuals`). Returns per view (U,) bool
    over its used pixels -- `View.black` itself where every black pixel is silent (`views_noise` knows
    it so, no compare) --, and how many of their entries have weight > 0 (left out of the
    chi-square's dof)."""
    out, count = [], 0
    for view, part in zip(views, r):
        rows = view.black  # black in the target, and the model 0 there too
        black = silent = int(np.count_nonzero(rows))
        if black:  # (none black, as in noisy targets: nothing to compare)
            quiet = rows & (part[0] == 0)
            quiet &= part[1] == 0
            quiet &= part[2] == 0
            silent = int(np.count_nonzero(quiet))
            rows = rows if silent == black else quiet
        count += 3 * silent if view.weighting is None else \
            int(np.count_nonzero(np.take(view.entries, np.flatnonzero(rows), axis=0)))
        out.append(rows)
    return out, count


def views_noise(views, residual_planes, silent, given: float | None, floor: float, fallback=None,
                quantisation: float = 0.0, on_levels=None,
                picks=None) -> tuple[float | None, int, float, tuple | None, list | None]:
    """The pixel noise sigma of a fit's views, in the targets' units, the number of Laplacian values M
    it was estimated from (0 when given or taken from `fallback`), their `estimate_sigma` share (1
    for none), the range (low, high) of noise levels the residuals allow when their noise is not
    white (`whiteness.sigma_range`; None when it reads white, is given or not estimated) and the
    levels by view, channel and intensity that the estimate read (`_estimate`; None when it is given or
    not estimated: `fit.sandwich` reads them): `given` -- the noise before quantisation, to which
    the targets' `quantisation` (the rms rounding error of their used values, 0 for float data: one
    sigma serves every view) is added in quadrature: a correct fit of an 8-bit file with its true
    noise 0.002 given came out at chi2 1.2, flagged; its share is the weights' (`weight_share`) --
    or estimated (`estimate_sigma`, each entry weighted by its view's weight) from the plain
    residuals at the solution, per view (3, H, W) planes, their levels by the targets' intensities
    (the data's: two fits a hair apart bin alike), over the used pixels but the `silent` (per view
    (U,) bool, `silent_pixels`) and the censored ones -- per channel where a weight of 0 leaves a
    used pixel's channel out -- and at least `floor` (the quantisation's, `Setup.sigma_floor`).
    Where too few pixels allow that: `fallback` when given (a refit's, the first fit's sigma), else
    None (unknown). `on_levels(levels)`: called with the levels as soon as they are read, when they
    are returned (`_estimate`). `picks`: `noise_picks(views, [view.black ...])` when formed already
    (`engine.run_fit`: beside the solve), taken where the silent pixels are the black ones."""
    if given is not None:
        return (math.hypot(given, quantisation) if quantisation else given), 0, weight_share(views), None, None
    if picks is None or not all(quiet is view.black or np.array_equal(quiet, view.black)
                                for view, quiet in zip(views, silent)):
        picks = noise_picks(views, silent)
    estimate = _estimate(picks, residual_planes, on_levels)
    if estimate is None:
        return fallback, 0, 1.0, None, None
    spread = sigma_range(estimate[0], floor, whiteness(picks, residual_planes))
    return max(estimate[0], floor), estimate[1], estimate[2], spread, estimate[3]


def noise_picks(views, silent) -> list:
    """Per view (`records.View`) the `ViewPicks` of `views_noise`'s estimate, over its used pixels but
    the `silent` (per view (U,) bool) and the censored ones -- per channel where a weight of 0 leaves
    a used pixel's channel out --, binned by the targets' intensities: what it reads of the targets
    alone (formed beside the solve, for silent pixels all black ones: `engine.run_fit`)."""
    picks = []
    for view, quiet in zip(views, silent):
        left_out = quiet | at_ceiling(view.values, view.ceiling) if np.isfinite(view.ceiling) else quiet
        clean = view.used
        if left_out.any():
            clean = view.used.copy()
            clean.reshape(-1)[view.pixels[left_out]] = False
        if view.weighting is not None and not np.all(view.weights > 0):
            clean = in_channels(clean) & (view.weighting > 0)
        signal = view.target if view.left_out else view.image  # (non-finite values outside the pixels used: 0)
        picks.append(_view_picks(clean, view.weighting, signal, interior=True))
    return picks


def weight_share(views) -> float:
    """n_eff / n of the entries a fit counts (`View.counted`) under their weights w, for noise of one
    level: (sum w)^2 / (n sum w^2) -- 1 for equal weights. A chi-square sum w r^2 / (sigma^2 sum w)
    of white noise has variance 2 sum w^2 / (sum w)^2 = 2 / (n share) (`chi2_spread`)."""
    total = square = 0.0
    count = 0
    for view in views:
        if view.weighting is None:  # w = 1
            n = int(np.count_nonzero(view.counted))
            count, total, square = count + n, total + n, square + n
            continue
        weight = view.weights[view.counted]
        count += weight.size
        total += float(np.sum(weight))
        square += float(np.dot(weight, weight))
    return total * total / (count * square) if square > 0 else 1.0


def quantisation(views) -> float:
    """The rms error that rounding to their files' codes adds to the targets' values, over the used
    entries a fit counts (`View.counted`: weight > 0, below the ceiling) but those of black pixels
    (0 in every channel, as silent pixels are: `silent_pixels`):

        sqrt(sum_c w_c q_c^2 / sum_c w_c),   q_c = `io.code_step`(value_c, step, gamma) / sqrt(12)

    (w_c: the entry's weight), 0 for float data (step 0). q is one code step in linear units at
    the entry's value -- an sRGB file's step is 1 / 12.92 of the sample step in the darks, 2.275
    times it at white --, so the mean is what a chi-square's mean of w r^2 over the same entries
    compares with when the residuals are the rounding: the README's teapot, rendered and saved as
    8-bit sRGB, has residual rms 0.00133 over its 1649 used pixels, this 0.00134, the uniform
    (1 / 255) / sqrt(12) = 0.00113 it was taken for (chi2 1.34, mismatch suspected)."""
    if not any(view.step for view in views):  # float data: nothing rounded (and no pass over the values)
        return 0.0
    num = den = 0.0
    for view in views:
        keep = view.counted & in_channels(~view.black)  # (`in_channels`: 0.02 ms, broadcasting [:, None] 0.07)
        weight = None if view.weighting is None else view.weights[keep]
        den += float(np.count_nonzero(keep) if weight is None else np.sum(weight))
        if view.step:
            q2 = np.square(code_step(view.values[keep], view.step, view.gamma))
            num += float(np.sum(q2) if weight is None else np.dot(weight, q2))
    return math.sqrt(num / (12.0 * den)) if den > 0 else 0.0


def chi2_spread(dof: int, noise_values: int = 0, share: float = 1.0) -> float:
    """The standard deviation of a reduced chi-square over dof degrees of freedom for a correct model
    (white noise): sqrt(2 / (dof share)) with sigma known (share: `weight_share`); with sigma estimated from M = `noise_values`
    Laplacians of the same residuals (`estimate_sigma`: a mean of squares of L / 6, whose nine
    taps make neighbouring values correlated, sum of squared correlations (70 / 36)^2 = 3.78), the
    ratio of the two means of squares has variance 2 (3.78) / M + 2 / dof - 2 (2 / dof) (the two
    share the noise: covariance 2 / dof), sqrt(7.56 / M - 2 / dof): 0.015 for the ~24k values of a
    96 x 96 image (Monte Carlo over 20 seeds on fitted scenes' masks: 0.014-0.027, within its own
    16 % spread of this). Weights and noise that vary over the image (w_c, v_c: `estimate_sigma`)
    make fewer values count: a weighted mean of squares over n values has the variance of an equal
    one over n_eff = (sum w v)^2 / sum w^2 v^2 = n `share`; so dof and M count as dof share and M
    share (pure noise, 40 x 40 x 3, 300 seeds: a 7 x 7 spot weighted 100 spreads 0.149, this 0.155,
    the formula without share 0.036; noise rising 0.1 to 1 across, 0.048, this 0.047; the
    reviewer's sphere with 3 % proportional noise, fitted: 0.085 over 40 seeds, all ok)."""
    dof_eff = dof * share
    if noise_values <= 0:  # sigma given: sqrt(2 / n_eff) (`weight_share`)
        return math.sqrt(2.0 / dof_eff)
    values_eff = noise_values * share
    return math.sqrt(max(LAPLACIAN_CORRELATION / values_eff - 2.0 / dof_eff, 2.0 / dof_eff))
