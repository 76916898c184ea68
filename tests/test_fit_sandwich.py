"""Standard errors under unequal noise (`fit.sandwich`): per-channel noise levels and noise that
grows with the signal get per-parameter standard errors that cover the truth as often as they
should, where the pooled s^2 (J^T J)^-1 does not; noise of one level keeps the pooled form."""

import numpy as np
import pytest
from test_fit_helpers import TRUTH, make_scene, target_of

import difflab
from difflab.fit import engine, noise, sandwich, solve
from difflab.fit.stats import covariance_diagonal, sandwich_diagonal

SEEDS = 40
KINDS = ("ka", "kd", "ks")
#: |z| <= 2 holds for 95.4 % of Gaussian estimates. Per channel 120 entries (40 seeds x ka, kd, ks):
#: a binomial standard deviation of 0.019; the three kinds of a seed are correlated, so 4 of them.
COVERAGE_MIN = 0.954 - 4 * 0.019
#: the rms of 120 z-scores spreads by 1 / sqrt(240) = 6.5 % (wider for the correlation): within 25 %.
RMS_RANGE = (0.8, 1.25)


@pytest.fixture(scope="module")
def sphere():
    scene = make_scene(size=48)
    return difflab.compile_scene(scene), target_of(scene)


def z_scores(sphere, noise, pooled=False, monkeypatch=None):
    """(seeds, 3 kinds, 3 channels) (fitted - truth) / stderr of ka, kd, ks (n fitted too) over
    SEEDS targets of the exact image plus `noise(rng)`; `pooled`: with the pooled form forced."""
    compiled, exact = sphere
    if pooled:
        monkeypatch.setattr(engine, "noise_middle", lambda *args: None)
    rng = np.random.default_rng(0)
    truth = np.array([TRUTH[k] for k in KINDS])
    out = []
    for _ in range(SEEDS):
        target = (exact + noise(rng, exact)).astype(np.float32)
        r = difflab.fit_material(compiled, [target], "red", ("ka", "kd", "ks", "n"), ceiling=False, progress=False)
        assert r.converged and not r.model_mismatch
        out.append((np.array([r.params[k] for k in KINDS]) - truth) / np.array([r.stderr[k] for k in KINDS]))
    return np.array(out)


def coverage(z):
    """Per channel: the share of |z| <= 2 and the rms of z."""
    return (np.abs(z) <= 2).mean(axis=(0, 1)), np.sqrt(np.mean(np.square(z), axis=(0, 1)))


def per_channel(rng, exact):
    return rng.standard_normal(exact.shape) * np.array([0.003, 0.003, 0.012])


def proportional(rng, exact):
    return rng.standard_normal(exact.shape) * 0.05 * exact


@pytest.mark.parametrize("noise", [per_channel, proportional])
def test_unequal_noise_gets_standard_errors_that_cover_the_truth(sphere, noise, monkeypatch):
    """Blue noise 4x red's and green's, or 5 % of each value: |fitted - truth| <= 2 stderr for
    0.91-0.96 of each channel's entries (measured), the rms z-score 0.99-1.14; the pooled form
    covers blue 0.82 (rms 1.5, red 0.5: overstated 2x) and under proportional noise red 0.67 (rms
    2.5)."""
    cover, rms = coverage(z_scores(sphere, noise))
    assert np.all(cover >= COVERAGE_MIN), cover
    assert np.all((rms > RMS_RANGE[0]) & (rms < RMS_RANGE[1])), rms
    cover, rms = coverage(z_scores(sphere, noise, pooled=True, monkeypatch=monkeypatch))
    assert np.any(cover < COVERAGE_MIN) and np.any((rms < RMS_RANGE[0]) | (rms > RMS_RANGE[1]))


def test_equal_noise_keeps_the_pooled_form_which_the_sandwich_matches(sphere, monkeypatch):
    """White noise of one level: its levels do not differ beyond their spread, so the pooled form
    stays (nothing more formed). The sandwich forced anyway (HC1) agrees with it to its own spread,
    sqrt(2 / K) for a parameter resting on K entries: ka and kd (the sphere's ~900 pixels) within
    8 % (measured over 6 seeds: <= 7 %), ks and n (its highlight's few dozen) within 35 % (<= 28 %)."""
    compiled, exact = sphere
    rng = np.random.default_rng(1)
    formed = []
    real_unequal = sandwich.unequal
    monkeypatch.setattr(sandwich, "unequal", lambda levels: formed.append(real_unequal(levels)) or True)
    for seed in range(3):
        target = (exact + rng.standard_normal(exact.shape) * 0.006).astype(np.float32)
        forced = difflab.fit_material(compiled, [target], "red", ("ka", "kd", "ks", "n"), ceiling=False,
                                      progress=False)
        with monkeypatch.context() as patch:
            patch.setattr(engine, "noise_middle", lambda *args: None)
            pooled = difflab.fit_material(compiled, [target], "red", ("ka", "kd", "ks", "n"), ceiling=False,
                                          progress=False)
        for key, rtol in (("ka", 0.08), ("kd", 0.08), ("ks", 0.35), ("n", 0.35)):
            np.testing.assert_allclose(forced.stderr[key], pooled.stderr[key], rtol=rtol)
    assert formed == [False] * 3


def test_a_given_sigma_keeps_the_pooled_form(sphere, monkeypatch):
    """sigma given (one number declares one level): the standard errors are s^2 (J^T J)^-1's even
    where the noise differs by channel."""
    compiled, exact = sphere
    target = (exact + per_channel(np.random.default_rng(2), exact)).astype(np.float32)
    fit = lambda: difflab.fit_material(compiled, [target], "red", ("ka", "kd", "ks"), ceiling=False,  # noqa: E731
                                       progress=False, sigma=0.007)
    given = fit()
    monkeypatch.setattr(engine, "noise_middle", lambda *args: None)
    for key in KINDS:
        np.testing.assert_array_equal(given.stderr[key], fit().stderr[key])


def test_the_middle_starts_once_the_levels_are_read_and_gives_what_it_gives_waited_for(sphere, monkeypatch):
    """Unequal noise: the report starts the sandwich's middle (`noise_middle`) with the levels the
    noise estimate returns as soon as it has read them -- before its sums and its whiteness test, which
    run while JAX forms the middle -- and the standard errors are those of a middle waited for at
    once (nothing run beside it), bit for bit."""
    compiled, exact = sphere
    target = (exact + per_channel(np.random.default_rng(3), exact)).astype(np.float32)
    events, levels = [], []
    real_middle, real_sums, real_whiteness, real_noise = (sandwich.noise_middle, noise._sums, noise.whiteness,
                                                          noise.views_noise)

    def middle(setup, at, r, read, *rest):
        events.append("middle")
        levels.append(read)
        return real_middle(setup, at, r, read, *rest)

    def views_noise(*args):
        out = real_noise(*args)
        levels.append(out[4])
        return out

    monkeypatch.setattr(engine, "noise_middle", middle)
    monkeypatch.setattr(engine, "views_noise", views_noise)
    monkeypatch.setattr(noise, "_sums", lambda channels: events.append("sums") or real_sums(channels))
    monkeypatch.setattr(noise, "whiteness", lambda *args: events.append("whiteness") or real_whiteness(*args))
    fit = lambda: difflab.fit_material(compiled, [target], "red", ("ka", "kd", "ks", "n"), ceiling=False,  # noqa: E731
                                       progress=False)
    started = fit()
    assert events == ["middle", "sums", "whiteness"] and levels[0] is levels[1]
    monkeypatch.setattr(engine, "views_noise", real_noise)

    def waited_for(*args):
        matrix = real_middle(*args)()
        return lambda: matrix

    monkeypatch.setattr(engine, "noise_middle", waited_for)
    waited = fit()
    for key in KINDS + ("n",):
        np.testing.assert_array_equal(started.stderr[key], waited.stderr[key])


def test_texture_fits_keep_the_pooled_form_dense_and_matrix_free_alike(tmp_path, monkeypatch):
    """Even with the levels read as unequal, a texture fit's standard errors stay pooled: the dense
    solve's equal the matrix-free one's (rtol 1e-8, as test_fit_texels has them)."""
    from test_fit_texels import assert_same_stderr, noisy_texel_setup

    monkeypatch.setattr(sandwich, "unequal", lambda levels: True)
    setup, _ = noisy_texel_setup(tmp_path, (8, 8), "nearest", ("texture", "ks"))
    dense, free = solve(setup, linear_solver="dense"), solve(setup, linear_solver="cg")
    assert dense.converged and free.converged
    assert_same_stderr(dense, free, rtol=1e-8)


def test_sandwich_diagonal_is_the_pooled_one_for_one_level_and_keeps_singular_directions():
    rng = np.random.default_rng(3)
    jac = rng.standard_normal((50, 4))
    gram = jac.T @ jac
    np.testing.assert_allclose(sandwich_diagonal(gram, gram), covariance_diagonal(gram), rtol=1e-10)
    weights = rng.uniform(0.5, 2.0, 50)  # v_i: diag(inv J^T V J inv) by hand
    inverse = np.linalg.inv(gram)
    want = np.diag(inverse @ (jac.T * weights) @ jac @ inverse)
    np.testing.assert_allclose(sandwich_diagonal(gram, (jac.T * weights) @ jac), want, rtol=1e-10)
    jac[:, 3] = 2 * jac[:, 2]  # entries 2 and 3 trade off exactly: inf, the others finite
    gram = jac.T @ jac
    got = sandwich_diagonal(gram, gram)
    assert np.all(np.isinf(got[2:])) and np.all(np.isfinite(got[:2]))


def test_levels_differ_beyond_their_spread():
    """`unequal`: per channel (x, levels, n values each); a level of 1000 values spreads by
    3.2 / sqrt(1000) = 10 % (times 3, plus 10 %: within 40 % of the mean is one level)."""
    x = np.linspace(0, 30, 8)
    flat = [[(x, np.full(8, 1.0), 1000)] * 3]
    assert not sandwich.unequal(flat)
    assert not sandwich.unequal([[(x, np.full(8, 1.0), 1000), (x, np.full(8, 1.2), 1000), (x, np.full(8, 0.9), 1000)]])
    assert sandwich.unequal([[(x, np.full(8, 1.0), 1000), (x, np.full(8, 1.0), 1000), (x, np.full(8, 16.0), 1000)]])
    rising = [[(x, 0.2 + x / 10, 1000)] * 3]  # noise growing with the signal
    assert sandwich.unequal(rising)
