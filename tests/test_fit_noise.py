"""The noise estimate's arithmetic (`fit.noise.estimate_sigma`) against a plain implementation kept
here as the reference, for one level per channel (no signal: the median of its picked L^2 values,
read from all of them below NOISE_SAMPLE): the same sigma to 1e-12 and the same number of
Laplacians on random residual images -- masks per pixel and per channel, weights, infinite and NaN
residuals, boxes cut by the mask, images too small for a Laplacian, several views at once. (The
levels by intensity: `test_fit_stats`.)"""

import math

import numpy as np
import pytest

from difflab.fit import noise
from difflab.fit.noise import estimate_sigma


def sample(values):
    """The levels' sample of a channel's picked values, in row-major order: every s-th, s = max(M //
    NOISE_SAMPLE, 1)."""
    return values[::max(values.size // noise.NOISE_SAMPLE, 1)]


def reference_levels(square, centre):
    """(h, w, 3) each L^2 value's level: its channel's median sampled picked value / MEDIAN_CHI2_1."""
    median = [np.median(sample(square[..., c][centre[..., c]])) if centre[..., c].any() else 0.0 for c in range(3)]
    return np.broadcast_to(np.asarray(median), square.shape) / noise.MEDIAN_CHI2_1


def reference_sigma(images, used_maps, weight_maps=None, interior=True):
    """`estimate_sigma` without a signal, plainly: full-size arrays, boolean selections: (sigma, M,
    share), share = (sum_c w v)^2 / (M sum_c w^2 v^2) over each channel's sample scaled to its M."""
    num = den = spread = square_spread = 0.0
    count = 0
    for k, (image, used) in enumerate(zip(images, used_maps)):
        pixels = used if used.ndim == 2 else used[..., 0] | used[..., 1] | used[..., 2]
        rows, cols = np.flatnonzero(pixels.any(axis=1)), np.flatnonzero(pixels.any(axis=0))
        if rows.size == 0 or used.shape[0] < 3 or used.shape[1] < 3:
            continue
        top, left = max(rows[0] - 1, 0), max(cols[0] - 1, 0)
        box = (slice(top, min(rows[-1] + 2, used.shape[0])), slice(left, min(cols[-1] + 2, used.shape[1])))
        used, image = used[box], np.asarray(image)[box]
        if used.shape[0] < 3 or used.shape[1] < 3:
            continue
        centre = used[1:-1, 1:-1]
        if interior:
            across = used[:, :-2] & used[:, 1:-1] & used[:, 2:]
            centre = across[:-2] & across[1:-1] & across[2:]
        rows2 = image[1:-1] * -2.0
        rows2 += image[:-2]
        rows2 += image[2:]
        lap = rows2[:, 1:-1] * -2.0
        lap += rows2[:, :-2]
        lap += rows2[:, 2:]
        square = np.square(lap, dtype=np.float64)
        centre = (np.broadcast_to(centre[..., None], lap.shape) if centre.ndim == 2 else centre) & np.isfinite(square)
        level = reference_levels(square, centre)
        capped = np.where(square > noise.CAP_Z2 * level, level, square)[centre]
        weight = None if weight_maps is None or weight_maps[k] is None else weight_maps[k][box][1:-1, 1:-1][centre]
        num += float(np.sum(capped) if weight is None else np.dot(weight, capped))
        den += float(capped.size if weight is None else np.sum(weight))
        count += capped.size
        full = np.ones(centre.shape) if weight is None else weight_maps[k][box][1:-1, 1:-1]
        for c in range(3):
            weighted = sample(level[..., c][centre[..., c]] * full[..., c][centre[..., c]])
            if weighted.size:
                scale = np.count_nonzero(centre[..., c]) / weighted.size
                spread += float(np.sum(weighted)) * scale
                square_spread += float(np.sum(weighted * weighted)) * scale
    if count < noise.MIN_NOISE_PIXELS or den <= 0:
        return None
    share = spread * spread / (count * square_spread) if square_spread > 0 else 1.0
    return math.sqrt(num / (36.0 * noise.CAP_MEAN * den)), count, share


def residual(rng, h, w, dtype, spikes, bad):
    """(h, w, 3) noise whose level varies by region, `spikes` of its entries 30x (a model's sharp
    errors: capped), `bad` of them inf, -inf or NaN, one channel 0 where h is odd (level 0)."""
    scale = np.exp(rng.uniform(-3.0, 0.0, (h // 5 + 1, w // 7 + 1, 3))).repeat(5, 0).repeat(7, 1)[:h, :w]
    image = scale * rng.normal(0.0, 0.01, (h, w, 3))
    image = np.where(rng.random((h, w, 3)) < spikes, 30.0 * image + 0.3, image)
    image = np.where(rng.random((h, w, 3)) < bad, rng.choice([np.inf, -np.inf, np.nan], (h, w, 3)), image)
    if h % 2:
        image[..., 1] = 0.0
    return image.astype(dtype)


def mask(rng, h, w, kind):
    """A used map: a disc (its box smaller than the image), random holes, a sparse scatter, per
    channel, all or none."""
    yy, xx = np.mgrid[:h, :w]
    if kind == "disc":
        return np.hypot(yy - 0.55 * h, xx - 0.45 * w) < 0.4 * min(h, w)
    if kind == "holes":
        return rng.random((h, w)) < 0.93
    if kind == "sparse":
        return rng.random((h, w)) < 0.6
    if kind == "channels":
        return (rng.random((h, w))[..., None] < 0.95) & (rng.random((h, w, 3)) < 0.97)
    return np.full((h, w), kind == "all")


SIZES = [(3, 3), (4, 5), (6, 11), (9, 9), (13, 30), (23, 31), (40, 17), (64, 64), (71, 90),
         (130, 130)]  # (the last: > 2 NOISE_SAMPLE Laplacians a channel: sampled)
KINDS = ["disc", "holes", "sparse", "channels", "all", "none"]


@pytest.mark.parametrize("seed", range(6))
def test_the_estimate_matches_the_reference_implementation(seed):
    """Per seed: 20 random single views (a size, mask kind, dtype, weights or none, interior or not,
    spikes and non-finite entries) and 5 sets of 2-3 views, each equal to the reference: both None
    (too few values, no weight), or sigma within 1e-12 and the same count. The cases cover every
    branch: capped values, non-finite ones left out, channels with none picked."""
    rng = np.random.default_rng(seed)

    def view():
        h, w = SIZES[rng.integers(len(SIZES))]
        kind = KINDS[rng.integers(len(KINDS))]
        image = residual(rng, h, w, [np.float32, np.float64][rng.integers(2)], rng.choice([0.0, 0.03]),
                         rng.choice([0.0, 0.01]))
        weights = None if rng.random() < 0.4 else np.where(rng.random((h, w, 3)) < 0.1, 0.0,
                                                            rng.uniform(0.1, 3.0, (h, w, 3)))
        return image, mask(rng, h, w, kind), weights

    seen = set()
    for n in [1] * 20 + [2, 3, 2, 3, 3]:
        images, used, weights = zip(*[view() for _ in range(n)])
        interior = bool(rng.random() < 0.7)
        weights = list(weights) if any(w is not None for w in weights) else None
        with np.errstate(invalid="ignore"):  # (inf - inf in the reference's Laplacian)
            want = reference_sigma(images, used, weights, interior)
        got = estimate_sigma(list(images), list(used), weights, interior=interior)
        if want is None:
            assert got is None
            seen.add("none")
            continue
        assert got[0] == pytest.approx(want[0], rel=1e-12, abs=0.0) and got[1] == want[1]
        assert got[2] == pytest.approx(want[2], rel=1e-12)
        seen.add("zero" if want[0] == 0.0 else "sigma")
    assert seen >= {"sigma", "none"}


def test_a_large_channel_reads_its_levels_from_a_sample():
    """130 x 130 of white noise: 16384 Laplacians a channel, the levels' median read from every 4th
    (NOISE_SAMPLE 4096) -- sigma, M and share as the reference's, to 1e-12."""
    image = np.random.default_rng(4).normal(size=(130, 130, 3))
    used = np.ones((130, 130), bool)
    got, want = estimate_sigma([image], [used]), reference_sigma([image], [used])
    assert want[1] == 128 * 128 * 3 and got[1] == want[1]
    assert got[0] == pytest.approx(want[0], rel=1e-12) and got[2] == pytest.approx(want[2], rel=1e-12)


def test_the_cases_reach_every_branch():
    """The random cases above exercise what they claim: spikes are capped, non-finite values are
    left out of the count."""
    rng = np.random.default_rng(0)
    image = residual(rng, 71, 90, np.float64, 0.03, 0.01)
    used = mask(rng, 71, 90, "disc")
    centre = np.repeat(used[1:-1, 1:-1, None], 3, axis=2)
    r2 = image[:-2] - 2 * image[1:-1] + image[2:]
    with np.errstate(invalid="ignore"):
        square = np.square(r2[:, :-2] - 2 * r2[:, 1:-1] + r2[:, 2:])
    picked = centre & np.isfinite(square)
    level = reference_levels(square, picked)
    assert np.any(picked & (square > noise.CAP_Z2 * level))  # capped
    assert 0 < estimate_sigma([image], [used], interior=False)[1] == np.count_nonzero(picked) < np.count_nonzero(centre)


def test_the_sample_is_ordered_as_argsort_with_ties_by_position():
    """`noise._order`, the levels' sample in order of intensity: np.argsort's order for distinct
    float32 values (negative, subnormal and 0 among them), and equal values in order of position
    where they are >= 0 (np.argsort(kind="stable")'s; np.argsort's own quicksort sets no order)."""
    rng = np.random.default_rng(5)
    distinct = rng.permutation(np.concatenate([np.unique(rng.normal(0.0, 3.0, 6000).astype(np.float32)),
                                               np.float32([0.0, 1e-44, -1e-44, 3e38])]))
    assert np.array_equal(noise._order(distinct), np.argsort(distinct))
    ties = (rng.integers(0, 40, 8191) * 0.125).astype(np.float32)  # (the largest sample: 2 NOISE_SAMPLE - 1)
    assert np.array_equal(noise._order(ties), np.argsort(ties, kind="stable"))


def test_the_kernels_squared_laplacians_are_numpys_bit_for_bit():
    """`noise._squares` (a Warp CPU kernel: C-contiguous float32 planes, the index shared by the
    channels) against np.square(np.take(`_stencil`(...))) on random float32 planes with NaN, +-inf,
    values whose double overflows (2^127: an FMA would keep a finite sum where numpy's is inf) and
    neighbours that cancel it, over non-square boxes inside and at the image's edges, every centre
    Laplacian, a sparse pick of them, one or none: the same bits, NaN at the same places. And a noise
    estimate over such planes (the non-finite ones left out per channel) is the one numpy's planes
    give, a non-contiguous copy of them."""
    rng = np.random.default_rng(11)
    for h, w, box in [(64, 80, (slice(5, 47), slice(9, 70))), (40, 70, (slice(0, 40), slice(3, 70))),
                      (9, 5, (slice(2, 7), slice(0, 5))), (3, 12, (slice(0, 3), slice(0, 12)))]:
        planes = rng.normal(0.0, 1.0, (3, h, w)).astype(np.float32)
        for value in (np.nan, np.inf, -np.inf, 2.0 ** 127, 3e38, -3e38):
            planes[rng.random(planes.shape) < 0.01] = value
        grid = (box[0].stop - box[0].start - 2) * (box[1].stop - box[1].start - 2)
        for index in (np.arange(grid), np.flatnonzero(rng.random(grid) < 0.3), np.array([grid - 1]),
                      np.zeros(0, np.int64)):
            with np.errstate(invalid="ignore", over="ignore"):
                want = np.square(np.take(noise._stencil(planes[:, box[0], box[1]], -2.0).reshape(3, -1), index,
                                         axis=1), dtype=np.float64)
            got = noise._squares(planes, box, index)
            assert got.dtype == np.float64 and np.array_equal(np.isnan(got), np.isnan(want))
            assert np.array_equal(got, want, equal_nan=True)
    image = residual(rng, 71, 90, np.float32, 0.03, 0.01)
    used = mask(rng, 71, 90, "disc")
    planes = np.ascontiguousarray(np.moveaxis(image, -1, 0))
    views = [noise._view_picks(used, None, None, True)]
    got, want = noise._estimate(views, [planes]), noise._estimate(views, [np.moveaxis(image, -1, 0)])
    assert planes.flags.c_contiguous and not np.moveaxis(image, -1, 0).flags.c_contiguous
    assert got[:3] == want[:3] and np.isfinite(got[0])
    assert all(np.array_equal(a[1], b[1]) for a, b in zip(got[3][0], want[3][0]))
