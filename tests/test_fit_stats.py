"""The fit's statistics in closed form: degrees of freedom net of censored and noise-free values, the
reduced chi-square, the mismatch threshold, standard errors and optimistix result names."""

import math

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import ArpackNoConvergence
from test_fit_helpers import scene_dict

from difflab import Scene
from difflab.fit import inverse_diagonal as inverse
from difflab.fit import noise, stats
from difflab.fit.noise import chi2_spread, estimate_sigma
from difflab.fit.stats import MISMATCH_CHI2, covariance_diagonal, covariance_unscaled, fit_statistics, standard_errors
from difflab.fit.solvers import result_name
from difflab.fit.sparse_jacobian import read_graph, stats_blocks
from difflab.renderers.api import render_frame


def test_reduced_chi_square_counts_uncensored_values_less_parameters():
    jac = np.array([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0], [0.0, 0.0], [0.0, 0.0], [3.0, 0.0]])
    r = np.array([0.1, -0.2, 0.3, 0.0, 0.4, -0.1])
    sse = float(np.sum(r * r))
    st = fit_statistics(jac.T @ jac, sse, r.size, censored=1, sigma=0.5, size=2)
    assert st["s2"] == pytest.approx(sse / (6 - 1 - 2), rel=1e-15)
    assert st["chi2"] == pytest.approx(sse / 3 / 0.25, rel=1e-15)
    np.testing.assert_allclose(st["diag"], np.diag(np.linalg.inv(jac.T @ jac)), rtol=1e-12)
    gram, n = jac.T @ jac, r.size
    assert fit_statistics(gram, sse, n, censored=0, sigma=0.5, size=2)["s2"] == pytest.approx(sse / 4, rel=1e-15)
    assert fit_statistics(gram, sse, n, censored=0, sigma=0.0, size=2)["chi2"] == math.inf
    silent = fit_statistics(gram, sse, n, censored=1, sigma=0.5, size=2, silent=1)  # r[3] = 0: a noise-free zero
    assert silent["s2"] == pytest.approx(sse / (6 - 1 - 1 - 2), rel=1e-15)
    assert silent["chi2"] == pytest.approx(sse / 2 / 0.25, rel=1e-15)
    three = jac[:3].T @ jac[:3]
    sse3 = float(np.sum(r[:3] ** 2))  # three entries, two parameters: dof 1
    st3 = fit_statistics(three, sse3, 3, censored=0, sigma=1.0, size=2)
    assert st3["s2"] == pytest.approx(0.14, rel=1e-14) and not st3["underdetermined"]
    free = fit_statistics(sp.csc_matrix(gram), sse, r.size, censored=1, sigma=0.5, size=2)  # a matrix-free fit's
    assert free["s2"] == pytest.approx(sse / 3, rel=1e-15) and free["chi2"] == pytest.approx(st["chi2"], rel=1e-15)
    np.testing.assert_array_equal(free["diag"], st["diag"])  # made dense: the same numbers


@pytest.mark.parametrize("noise_values", [0, 40, 4000])
@pytest.mark.parametrize("sigma_given", [False, True])
@pytest.mark.parametrize("dof", [2, 8, 50, 5000])
def test_verdict_thresholds_are_five_spreads_of_chi_square_and_two_for_an_estimate(dof, sigma_given, noise_values):
    """chi2 of dof degrees of freedom has standard deviation sqrt(2 / dof) (reduced) with sigma
    given, sqrt(7.56 / M - 2 / dof) with sigma estimated from M Laplacians: t = 1 + 5 spread. A given
    sigma: mismatch above t. An estimated one: suspected above t, mismatch above max(2, t) -- each
    just there and not just below."""
    spread = 1.0 + 5.0 * chi2_spread(dof, 0 if sigma_given else noise_values)
    expected = math.sqrt(2.0 / dof) if sigma_given or noise_values == 0 else \
        math.sqrt(max(7.5617 / noise_values - 2.0 / dof, 2.0 / dof))
    assert spread == pytest.approx(1.0 + 5.0 * expected, rel=1e-4)
    thresholds = [(spread, "mismatch")] if sigma_given else \
        [(spread, "suspected"), (max(MISMATCH_CHI2, spread), "mismatch")]
    jac = np.zeros((dof + 1, 1))
    jac[0, 0] = 1.0
    for threshold, flag in thresholds:
        for chi2, raised in ((threshold * (1 - 1e-9), False), (threshold * (1 + 1e-9), True)):
            r = np.full(dof + 1, math.sqrt(chi2 * dof / (dof + 1)))
            st = fit_statistics(jac.T @ jac, float(np.sum(r * r)), r.size, censored=0, sigma=1.0, size=1,
                                sigma_given=sigma_given, noise_values=noise_values)
            assert st["chi2"] == pytest.approx(chi2, rel=1e-12)
            if flag == "mismatch" or spread < MISMATCH_CHI2 or not raised:  # (above 2: mismatch, not suspected)
                assert st[flag] is raised
            assert not (st["mismatch"] and st["suspected"])


def test_chi_square_of_weighted_residuals_is_against_the_mean_weight():
    """Entries of weight w carry noise w sigma^2 in their weighted residuals sqrt(w) r: chi2 = sum w r^2
    / (dof w_mean sigma^2), so weights scaled by 4 leave chi2 (and the verdict) as it was."""
    jac = np.ones((10, 1))
    r = np.linspace(-1.0, 1.0, 10)
    plain = fit_statistics(jac.T @ jac, float(np.sum(r * r)), 10, censored=0, sigma=0.6, size=1, sigma_given=True)
    four = fit_statistics(4.0 * jac.T @ jac, float(np.sum(4.0 * r * r)), 10, censored=0, sigma=0.6, size=1,
                          sigma_given=True, mean_weight=4.0)
    assert four["chi2"] == pytest.approx(plain["chi2"], rel=1e-14)
    assert four["chi2"] == pytest.approx(np.sum(r * r) / 9 / 0.36, rel=1e-14)


def test_chi_square_spread_with_an_estimated_sigma_is_what_white_noise_gives():
    """chi2 = (mean r^2) / sigma_hat^2, sigma_hat from the same residuals' Laplacians: over 400 white
    noise images of 40 x 40 x 3 its standard deviation is `chi2_spread` within 15 % (the two means
    share the noise: 0.033 here against 0.047 were they independent), its mean 1 within 3 spreads /
    sqrt(400)."""
    rng = np.random.default_rng(11)
    used = np.ones((40, 40), bool)
    chi2 = []
    for _ in range(400):
        image = rng.normal(size=(40, 40, 3))
        sigma, count, _ = estimate_sigma([image], [used])
        chi2.append(np.mean(image * image) / sigma ** 2)
    predicted = chi2_spread(image.size, count)
    assert count == 38 * 38 * 3
    assert np.std(chi2) == pytest.approx(predicted, rel=0.15)
    assert abs(np.mean(chi2) - 1.0) < 3 * predicted / 20


def test_chi_square_spread_counts_the_values_that_weights_and_varying_noise_leave():
    """A weighted chi-square of noise that varies spreads as one of fewer values: n_eff = (sum w v)^2 /
    sum w^2 v^2 (v the entries' noise levels), `share` = n_eff / n. Pure noise, 40 x 40 x 3, 300 seeds:
    a 7 x 7 spot weighted 100 spreads 0.149 (predicted 0.155; the formula without share 0.036), noise
    rising 0.1 to 1 across the image with a signal of the same ramp 0.048 (predicted 0.047): within
    20 %."""
    rng = np.random.default_rng(5)
    used = np.ones((40, 40), bool)
    yy, xx = np.mgrid[:40, :40]
    spot = np.where((abs(yy - 20) < 4) & (abs(xx - 20) < 4), 100.0, 1.0)
    ramp = 0.1 + 0.9 * xx / 40.0
    for weight, scale, signal in ((spot, np.ones((40, 40)), None), (np.ones((40, 40)), ramp, ramp)):
        weight, scale = (np.repeat(a[..., None], 3, axis=2) for a in (weight, scale))
        chi2, predicted = [], []
        for _ in range(300):
            image = scale * rng.normal(size=scale.shape)
            sigma, count, share = estimate_sigma([image], [used], [weight], signals=None if signal is None else [scale])
            chi2.append(np.sum(weight * image ** 2) / np.sum(weight) / sigma ** 2)
            predicted.append(chi2_spread(image.size, count, share))
        assert np.std(chi2) == pytest.approx(np.mean(predicted), rel=0.2)
        assert np.std(chi2) > 1.2 * chi2_spread(image.size, count)  # (without the share: too narrow)


def test_noise_levels_follow_the_signal_on_a_high_contrast_texture():
    """difflab's sphere over a checker floor of kd 0.9 / 0.05 (48 x 48) and noise of 3 % of the
    signal, the true noise alone: the estimate is its mean variance within 12 % (0.97-1.10 over
    seeds 0-9), with the levels binned by the signal's intensity. One level for all (or 8 x 8 spatial
    blocks, whose median in a block straddling a bright and a dark square is the dark pixels') caps
    the bright pixels' real noise away: 3.6-4.2 (the blocks: 1.46 at 64 x 64), so a correct fit read
    as a mismatch."""
    d = scene_dict(size=48)
    d["materials"]["floor"] = {"kd": [0.9] * 3, "checker": {"size": 0.5, "ka2": [0, 0, 0], "kd2": [0.05] * 3}}
    d["camera"]["eye"] = [0, 3, 4]
    clean = render_frame(Scene.from_dict(d)).image.astype(np.float64)
    used = np.ones(clean.shape[:2], bool)
    for seed in range(3):
        noise = 0.03 * clean * np.random.default_rng(seed).normal(size=clean.shape)
        variance = np.mean(noise[1:-1, 1:-1] ** 2)
        assert variance / estimate_sigma([noise], [used], signals=[clean])[0] ** 2 == pytest.approx(1.0, abs=0.12)
        assert variance / estimate_sigma([noise], [used])[0] ** 2 > 3.0


@pytest.mark.parametrize("censored, silent", [(1, 0), (0, 1), (2, 0)])
def test_no_more_counted_entries_than_unknowns_is_underdetermined(censored, silent):
    """Three entries, two unknowns, one or two of them censored or noise-free: nothing is left to judge
    the model by -- chi2 nan, no flag, s2 from a known sigma (else inf), the covariance as before."""
    jac = np.array([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0]])
    st = fit_statistics(jac.T @ jac, 0.1, 3, censored=censored, sigma=0.5, size=2, silent=silent, sigma_given=True)
    assert st["underdetermined"] and math.isnan(st["chi2"]) and not st["mismatch"] and st["s2"] == 0.25
    np.testing.assert_allclose(st["diag"], np.diag(np.linalg.inv(jac.T @ jac)), rtol=1e-12)
    unknown = fit_statistics(jac.T @ jac, 0.1, 3, censored=censored, sigma=math.nan, size=2, silent=silent)
    assert unknown["underdetermined"] and unknown["s2"] == math.inf


def test_standard_errors_scale_with_sigma_and_are_infinite_where_undetermined():
    np.testing.assert_array_equal(standard_errors(np.array([4.0, np.inf, 0.25, np.nan]), 9.0),
                                  [6.0, np.inf, 1.5, np.nan])  # nan: not formed
    np.testing.assert_array_equal(standard_errors(np.array([np.inf, 1.0]), 0.0), [np.inf, 0.0])


def block_gram(rng, sizes, singular=()):
    """A J^T J (dense) of independent blocks of `sizes` entries (random J, 3 rows per entry): a
    block in `singular` has its last two columns equal (a direction no residual tells apart), a
    size-1 block in it is a zero column (an unseen texel)."""
    blocks = []
    for i, size in enumerate(sizes):
        jac = rng.normal(size=(3 * size, size)) * rng.uniform(0.5, 20.0, size)  # columns of unlike norms
        if i in singular:
            jac[:, -1] = jac[:, -2] if size > 1 else 0.0
        blocks.append(jac.T @ jac)
    gram = np.zeros((sum(sizes),) * 2)
    offset = 0
    for block in blocks:
        gram[offset:offset + len(block), offset:offset + len(block)] = block
        offset += len(block)
    return gram


def test_a_sparse_gram_gives_the_dense_diagonal_through_blocks_and_lu(monkeypatch):
    """Above PACKED_MAX, a sparse J^T J is inverted per connected block -- small ones dense
    (packed), larger ones by sparse LU, or dense where LU finds them singular -- with the same
    diagonal as `covariance_unscaled` of the whole (rtol 1e-10; measured ~1e-13): inf for a zero
    column and the entries of singular blocks, nan for a singular block beyond DENSE_STATS_MAX and
    for a block beyond SPARSE_STATS_MAX."""
    rng = np.random.default_rng(4)
    sizes = [1, 6, 1, 30, 4, 40, 2, 12]  # PACKED_MAX 8: blocks of 12, 30 and 40 by LU (12, singular: dense)
    gram = block_gram(rng, sizes, singular=(2, 4, 7))
    perm = rng.permutation(gram.shape[0])  # the blocks' entries interleaved
    gram = gram[perm][:, perm]
    want = np.diag(covariance_unscaled(gram))
    monkeypatch.setattr(stats, "DENSE_STATS_MAX", 20)
    monkeypatch.setattr(stats, "PACKED_MAX", 8)
    got = covariance_diagonal(sp.csr_matrix(gram))
    assert np.isinf(want).sum() == 1 + 2 + 2 and (np.isinf(got) == np.isinf(want)).all()
    np.testing.assert_allclose(got[np.isfinite(want)], want[np.isfinite(want)], rtol=1e-10)

    lu_block = np.flatnonzero(np.isin(perm, np.arange(8, 38)))  # the entries of the block of 30
    monkeypatch.setattr(stats, "SPARSE_STATS_MAX", 35)  # the block of 40: too large
    got = covariance_diagonal(sp.csr_matrix(gram))
    too_large = np.isin(perm, np.arange(42, 82))
    assert np.isnan(got[too_large]).all() and not np.isnan(got[~too_large]).any()
    np.testing.assert_allclose(got[lu_block], want[lu_block], rtol=1e-10)

    singular = block_gram(rng, [30, 5], singular=(0,))  # a singular block above DENSE_STATS_MAX: nan
    got = covariance_diagonal(sp.csr_matrix(singular))
    assert np.isnan(got[:30]).all() and np.allclose(got[30:], np.diag(covariance_unscaled(singular))[30:],
                                                    rtol=1e-10)


def test_the_diagonal_without_arpack_and_with_blocks_skipped(monkeypatch):
    """Where ARPACK does not converge on the largest eigenvalue, Gershgorin's bound stands in for
    it: the same diagonal (rtol 1e-10), the same singular blocks inf. Entries `skip` (whole blocks)
    are nan, the others' the full matrix's."""
    rng = np.random.default_rng(5)
    sizes = [1, 6, 1, 30, 4, 12]
    gram = block_gram(rng, sizes, singular=(2, 4))
    want = np.diag(covariance_unscaled(gram))
    monkeypatch.setattr(stats, "PACKED_MAX", 8)
    calls = []

    def no_convergence(*args, **kwargs):
        calls.append(1)
        raise ArpackNoConvergence("ARPACK error -1: No convergence", np.zeros(0), np.zeros((0, 0)))

    monkeypatch.setattr(stats, "eigsh", no_convergence)
    got = covariance_diagonal(sp.csr_matrix(gram))
    assert calls and np.isinf(want).sum() == 1 + 2 and (np.isinf(got) == np.isinf(want)).all()
    np.testing.assert_allclose(got[np.isfinite(want)], want[np.isfinite(want)], rtol=1e-10)
    skip = np.zeros(gram.shape[0], bool)
    skip[8:38] = True  # the block of 30
    got = covariance_diagonal(sp.csr_matrix(gram), skip)
    assert np.isnan(got[skip]).all() and (np.isinf(got[~skip]) == np.isinf(want[~skip])).all()
    finite = ~skip & np.isfinite(want)
    np.testing.assert_allclose(got[finite], want[finite], rtol=1e-10)


def test_predicted_blocks_of_texels_and_scalars():
    """Texels {0, 1} read by one pixel, {2, 3, 4} chained by two, texel 5 by none: without scalars
    blocks of 2 and 3 (and 1); RGB scalars (one per channel) join a channel's 5 read texels, 6
    entries a block; a scalar of every channel joins all, 3 * 5 + 1."""
    together = read_graph(np.array([0, 0, 1, 1, 2, 2]), np.array([0, 1, 2, 3, 3, 4]), 6)
    keep, scalars = stats_blocks(together, np.zeros(0, np.int64), 2)
    assert keep.tolist() == [True, True, False, False, False, True] and not scalars
    assert stats_blocks(together, np.zeros(0, np.int64), 3)[0].all()
    for channels, size in (([0, 1, 2], 6), ([-1], 16), ([0, 1, 2, -1], 19)):
        keep, scalars = stats_blocks(together, np.array(channels), size)
        assert keep.all() and scalars
        keep, scalars = stats_blocks(together, np.array(channels), size - 1)
        assert keep.tolist() == [False] * 5 + [True] and not scalars


def test_optimistix_results_are_named():
    import optimistix as optx

    assert result_name(optx.RESULTS.successful) == "successful"
    assert result_name(optx.RESULTS.nonlinear_max_steps_reached) == "nonlinear_max_steps_reached"
    assert result_name(optx.RESULTS.nonfinite) == "nonfinite"


@pytest.mark.parametrize("per_channel", [False, True])
@pytest.mark.parametrize("interior", [True, False])
def test_noise_estimate_is_the_robust_laplacian_over_the_used_pixels(interior, per_channel):
    """sqrt(sum w L^2 / (36 CAP_MEAN sum w)) with L the 3 x 3 Laplacian [1 -2 1; -2 4 -2; 1 -2 1], over
    the used pixels whose neighbourhood is used (interior) or that are not on the image border; with
    an (H, W, 3) map, over the used entries of each channel whose neighbourhood is used in that
    channel; w: the weight at the centre entry (1 without weights); and the count of L values. (A
    checkerboard of magnitudes 0.5-1: every L^2 within 16x of any other, under the 19.8x its block's
    median above which a value counts as that level.)"""
    rng = np.random.default_rng(4)
    kernel = np.outer([1.0, -2.0, 1.0], [1.0, -2.0, 1.0])
    checker = np.where((np.arange(23)[:, None] + np.arange(31)[None, :]) % 2, 1.0, -1.0)[..., None]
    image = checker * rng.uniform(0.5, 1.0, size=(23, 31, 3))
    weights = rng.uniform(0.1, 3.0, size=(23, 31, 3))
    used = rng.random((23, 31)) < 0.8
    used[:, :3] = False  # the used box does not reach the left side
    if per_channel:
        used = used[..., None] & (rng.random((23, 31, 3)) < 0.9)
    h, w = used.shape[:2]
    centre = np.zeros_like(used)
    centre[1:-1, 1:-1] = used[1:-1, 1:-1]
    if interior:
        centre[1:-1, 1:-1] = np.logical_and.reduce([used[i:h - 2 + i, j:w - 2 + j] for i in range(3) for j in range(3)])
    if not per_channel:
        centre = np.repeat(centre[..., None], 3, axis=2)
    lap = np.zeros_like(image)
    lap[1:-1, 1:-1] = sum(kernel[i, j] * image[i:h - 2 + i, j:w - 2 + j] for i in range(3) for j in range(3))
    assert lap[centre].min() ** 2 * 16 > lap[centre].max() ** 2
    plain = math.sqrt(np.mean(lap[centre] ** 2) / 36.0 / noise.CAP_MEAN)
    weighted = math.sqrt(np.sum(weights[centre] * lap[centre] ** 2) / np.sum(weights[centre]) / 36.0 / noise.CAP_MEAN)
    got, count, _ = estimate_sigma([image], [used], interior=interior)
    assert got == pytest.approx(plain, rel=1e-12) and count == np.count_nonzero(centre)
    assert estimate_sigma([image], [used], [weights], interior=interior)[0] == pytest.approx(weighted, rel=1e-12)
    assert estimate_sigma([image], [np.zeros_like(used)], interior=interior) is None  # too few pixels


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noise_estimate_caps_a_models_sharp_errors(seed):
    """White noise of sigma 0.01 (96 x 96) plus what a wrong model leaves sharply: a step of 0.2 along
    a column and a ring of 0.1 one pixel wide. The estimate is sigma within 10 % (their Laplacians,
    above 9 times their blocks' noise level, count as that level); a plain mean square of L read
    them as noise: sigma 33 % too high, the model's chi2 1.8x too low. (7.6 % high at seed 0:
    the blocks the ring crosses read a higher median.) A wholly noise-free
    residual with the same errors estimates 0 (a noise-free target's mismatch is seen in full)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:96, :96]
    error = np.where(xx >= 40, 0.2, 0.0) + np.where(np.abs(np.hypot(yy - 60, xx - 60) - 20) < 0.5, 0.1, 0.0)
    image = error[..., None] + 0.01 * rng.normal(size=(96, 96, 3))
    used = np.ones((96, 96), bool)
    assert estimate_sigma([image], [used])[0] == pytest.approx(0.01, rel=0.1)
    r2 = image[:-2] - 2 * image[1:-1] + image[2:]
    lap = r2[:, :-2] - 2 * r2[:, 1:-1] + r2[:, 2:]
    assert math.sqrt(np.mean(lap ** 2) / 36) > 1.25 * 0.01
    assert estimate_sigma([np.repeat(error[..., None], 3, axis=2)], [used])[0] == 0.0


def test_noise_estimate_leaves_out_zero_weight_channels():
    """A weighted residual image is 0 where a channel's weight is 0: not noise. White noise (sigma
    0.02, 64 x 64) with 30 % of its entries zeroed so: over the (H, W, 3) map of the weighted entries
    the estimate is sigma within 5 % (~470 Laplacians); over the pixels' (H, W) map the zeros entered
    the Laplacians and it came out low -- a correct fit's chi-square read high: a model mismatch."""
    rng = np.random.default_rng(7)
    weighted = rng.random((64, 64, 3)) > 0.3
    image = np.where(weighted, rng.normal(0.0, 0.02, (64, 64, 3)), 0.0)
    pixels = np.ones((64, 64), bool)
    assert estimate_sigma([image], [weighted])[0] == pytest.approx(0.02, rel=0.05)
    assert estimate_sigma([image], [pixels])[0] < 0.9 * 0.02


@pytest.mark.parametrize("seed", [0, 1])
def test_noise_estimate_is_the_mean_variance_of_noise_that_varies(seed):
    """Noise whose standard deviation varies over the image (a renderer's, with the signal: here 0.002
    to 0.05 along a smooth ramp, 96 x 96, proportional to a signal of the same ramp): sigma^2 is the
    mean of the variances over the interior pixels within 5 % (0.968-1.004 over seeds 0-3) -- what
    a chi-square's mean of r^2 compares with (a median of |L| read 0.48-0.50 of it: a correct fit's
    chi2 2.0). With weights, the weighted mean of the variances. Without the signal one level per
    channel caps the noisiest pixels' real noise away: 0.61-0.63 of it (the levels follow the signal)."""
    rng = np.random.default_rng(seed)
    scale = np.linspace(0.002, 0.05, 96)[None, :, None] * np.ones((96, 96, 3))
    image = scale * rng.normal(size=scale.shape)
    used = np.ones((96, 96), bool)
    inner = scale[1:-1, 1:-1]
    got = estimate_sigma([image], [used], signals=[scale])[0] ** 2
    assert got == pytest.approx(np.mean(inner ** 2), rel=0.05)
    assert estimate_sigma([image], [used])[0] ** 2 < 0.7 * got
    weights = np.where(np.arange(96)[None, :, None] < 48, 1.0, 0.1) * np.ones((96, 96, 3))
    want = np.sum(weights[1:-1, 1:-1] * inner ** 2) / np.sum(weights[1:-1, 1:-1])
    assert estimate_sigma([image], [used], [weights], signals=[scale])[0] ** 2 == pytest.approx(want, rel=0.05)


def texture_jacobian(rng, side=12, scalars=2):
    """J of a side x side texel grid read bilinearly by (side - 1)^2 pixels, 3 rows each, with
    `scalars` dense columns beside (ks-like: every pixel)."""
    rows, cols, vals = [], [], []
    for i in range(side - 1):
        for j in range(side - 1):
            for r in range(3):
                row = 3 * (i * (side - 1) + j) + r
                for t in (i * side + j, i * side + j + 1, (i + 1) * side + j, (i + 1) * side + j + 1):
                    rows.append(row), cols.append(t), vals.append(rng.uniform(0.1, 1.0))
    jac = sp.csr_matrix((vals, (rows, cols)), shape=(3 * (side - 1) ** 2, side * side)).toarray()
    return np.hstack([jac, rng.uniform(0.1, 1.0, (jac.shape[0], scalars))])


@pytest.mark.parametrize("band_max", [256, 4])  # 4: the texels' band is too wide, SuperLU solves
def test_the_inverse_diagonal_of_a_texel_block_with_wide_scalars(monkeypatch, band_max):
    """`inverse_diagonal` of a unit-diagonal J^T J of 144 texels (shuffled) and 2 scalars coupled to
    all of them: the band (reverse Cuthill-McKee) with the scalars by Schur complement, or SuperLU,
    equal the dense inverse's diagonal (rtol 1e-10); two equal columns (a direction no residual
    tells apart) make it singular: nan."""
    monkeypatch.setattr(inverse, "BAND_MAX", band_max)
    monkeypatch.setattr(inverse, "WIDE", 40)  # texel rows: <= 3 * 9 entries, the scalars' all 146
    rng = np.random.default_rng(6)
    jac = texture_jacobian(rng)[:, rng.permutation(146)]
    gram = jac.T @ jac
    unit = gram / np.sqrt(np.outer(np.diag(gram), np.diag(gram)))
    top = float(np.linalg.eigvalsh(unit).max())
    want = np.diag(np.linalg.inv(unit))
    np.testing.assert_allclose(inverse.inverse_diagonal(sp.csr_matrix(unit), top, 1e-12), want, rtol=1e-10)
    jac[:, 1] = jac[:, 0]  # one direction no residual tells apart
    gram = jac.T @ jac
    unit = gram / np.sqrt(np.outer(np.diag(gram), np.diag(gram)))
    assert np.isnan(inverse.inverse_diagonal(sp.csr_matrix(unit), top, 1e-12)).all()


def test_a_singular_normal_matrix_names_the_degenerate_parameters():
    """J^T J of a texture (2 x 1 texels, 6 entries) and a scalar kd: rank-deficient directions over
    the entries the data reach are `degenerate`, whatever the count; a zero column (a texel no
    pixel reads) is no unknown of the data's. A direction within the texels alone is the prior's to
    fill (smoothness > 0): not counted; one that trades texels against kd is, prior or not."""
    from difflab.fit.params import Layout, Param
    from difflab.fit.stats import degenerate

    layout = Layout((Param("texture", "texture", 0, 6, 0.0, np.inf, (2, 1)), Param("kd", "kd", 0, 1, 0.0, np.inf)))
    rng = np.random.default_rng(3)

    def gram_of(jac):
        gram = jac.T @ jac
        return gram, np.diag(covariance_unscaled(gram))

    jac = rng.normal(size=(40, 7))
    jac[:, 5] = 0.0  # texel (1, 0) blue: seen by no pixel
    full, diag = gram_of(jac)
    assert np.isinf(diag[5]) and degenerate(layout, diag, full, prior=False) == []
    within = jac.copy()
    within[:, 1] = within[:, 0]  # two texels seen only as their sum
    gram, diag = gram_of(within)
    assert degenerate(layout, diag, gram, prior=False) == ["texture"]
    assert degenerate(layout, diag, gram, prior=True) == []
    assert degenerate(layout, diag, sp.csc_matrix(gram), prior=False) == ["texture"]  # a matrix-free fit's
    across = jac.copy()
    across[:, 6] = 2.0 * across[:, 0]  # kd against a texel
    gram, diag = gram_of(across)
    assert degenerate(layout, diag, gram, prior=True) == ["texture", "kd"]


def test_prior_pull_is_the_data_only_step_in_standard_errors():
    """delta = (J^T J)^-1 g over the entries the data determine, / sqrt(diag (J^T J)^-1 s2): for a
    linear least-squares problem plus a quadratic prior, the regularised solution moved by delta is
    the data-only solution exactly. Dense and sparse J^T J give the same numbers; an entry no row
    reads (inf in diag) gets 0."""
    from difflab.fit.stats import prior_pull

    rng = np.random.default_rng(5)
    jac = rng.normal(size=(30, 4))
    jac[:, 3] = 0.0  # no data on entry 3
    y = rng.normal(size=30)
    prior = np.diag([0.5, 0.2, 0.1, 1.0])  # 0.5 x^T P x
    gram = jac.T @ jac
    x_prior = np.linalg.solve(gram + prior, jac.T @ y)
    x_data = np.linalg.lstsq(jac[:, :3], y, rcond=None)[0]
    diag = np.diag(covariance_unscaled(gram))
    s2 = 0.04
    want = (x_data - x_prior[:3]) / np.sqrt(diag[:3] * s2)
    for matrix in (gram, sp.csr_matrix(gram)):
        got = prior_pull(matrix, diag, s2, prior @ x_prior)
        np.testing.assert_allclose(got[:3], want, rtol=1e-10)
        assert got[3] == 0.0 and np.isinf(diag[3])


def test_a_given_sigma_spreads_chi_square_over_the_weights_effective_count():
    """With sigma given, chi2 = sum w r^2 / (sigma^2 sum w) of white noise has standard deviation
    sqrt(2 / n_eff), n_eff = (sum w)^2 / sum w^2 = n `weight_share`: a 6 x 6 spot weighted 100 on
    40 x 40 x 3 entries, 400 draws, within 15 % (sqrt(2 / n) alone is 4.6x too narrow); equal weights
    share 1."""
    from types import SimpleNamespace

    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[:40, :40]
    weight = np.repeat(np.where((abs(yy - 20) < 3) & (abs(xx - 20) < 3), 100.0, 1.0)[..., None], 3, axis=2)
    rows = weight.reshape(-1, 3)
    view = SimpleNamespace(weighting=weight, weights=rows, counted=np.ones(rows.shape, bool))
    share = noise.weight_share([view])
    assert share == pytest.approx(np.sum(rows) ** 2 / (rows.size * np.sum(rows ** 2)), rel=1e-12)
    chi2 = [np.sum(weight * rng.normal(size=weight.shape) ** 2) / np.sum(weight) for _ in range(400)]
    assert np.std(chi2) == pytest.approx(chi2_spread(rows.size, 0, share), rel=0.15)
    assert chi2_spread(rows.size, 0, share) > 4 * chi2_spread(rows.size)
    plain = SimpleNamespace(weighting=None, counted=np.ones(rows.shape, bool))
    assert noise.weight_share([plain, plain]) == 1.0


def test_a_correct_fit_with_sigma_given_and_a_heavily_weighted_spot_is_not_a_mismatch():
    """The sphere's kd fitted to its own render with noise 0.01, sigma=0.01 given and a 5 x 5 spot
    weighted 100: seed 9 reads chi2 1.26, above sqrt(2 / dof)'s threshold 1.14 (flagged, as 2 of 12
    seeds were before the weights' n_eff counted), below the weighted one; the observed spread over
    12 seeds is 0.17."""
    from test_fit_helpers import make_scene, target_of

    from difflab import fit_material

    scene = make_scene(size=48)
    clean = target_of(scene)
    yy, xx = np.mgrid[:48, :48]
    weight = np.repeat(np.where((abs(yy - 20) < 3) & (abs(xx - 24) < 3), 100.0, 1.0)[..., None], 3, axis=2)
    target = clean + 0.01 * np.random.default_rng(9).normal(size=clean.shape)
    out = fit_material(scene, [target], "red", ("kd",), weights=[weight], sigma=0.01, progress=False)
    assert out.chi2 == pytest.approx(1.26, abs=0.01)
    assert out.converged and not out.model_mismatch and out.ok


def test_share_is_one_for_equal_weights_and_one_noise_level():
    """White noise, no weights, no signals (one level a channel): share (sum_c v_c)^2 / (3 sum_c v_c^2),
    within 1 % of 1 for three channels of equal noise -- every value counts (it was ~1 / m, 7e-4
    here: the one level summed once instead of once per sampled value)."""
    image = np.random.default_rng(2).normal(size=(40, 40, 3))
    sigma, count, share = estimate_sigma([image], [np.ones((40, 40), bool)])
    assert share == pytest.approx(1.0, abs=0.01) and count == 38 * 38 * 3
    assert sigma == pytest.approx(1.0, rel=0.05)


def test_parameters_no_counted_value_depends_on_are_unreached_and_the_fit_not_ok():
    """The light straight behind the sphere (32 x 32): no used pixel is lit, so kd, ks and n reach
    no value the fit counts -- zero columns of J^T J, their stderr inf, their values the start's.
    The fit is `underdetermined` with them in `unreached`, `ok` False (it was ok: a zero column
    is no singular direction of the columns the data reach); ka, which the ambient term shows,
    is determined."""
    from test_fit_helpers import make_scene

    from difflab import fit_material, render

    behind = make_scene(size=32).with_overrides(lights=[{"type": "point", "position": [0, 3, -3]}])
    out = fit_material(behind, [render(behind)], "red", ("ka", "kd", "ks", "n"), progress=False)
    assert out.unreached == ["kd", "ks", "n"] and out.degenerate == []
    assert out.underdetermined and out.converged and not out.ok
    assert not np.isfinite(out.stderr["n"]) and np.all(np.isfinite(out.stderr["ka"]))
    assert "UNDERDETERMINED: kd, ks, n reach no value the fit counts" in out.table()
    assert out.to_dict()["unreached"] == ["kd", "ks", "n"]
