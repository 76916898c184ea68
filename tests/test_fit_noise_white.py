"""Noise that is not white (`fit.whiteness`): the residuals read at two scales, Laplacians of taps 1
and 2 pixels apart. White noise -- Gaussian, per-channel levels, levels that follow the signal,
uniform (rounding-like), one noise in all three channels -- is not flagged (|z| <= WHITE_Z = 5; z's
spread is at most 1 for Gaussian noise, so at most 5.7e-7 of such fits are; heavy tails and a level
that changes sharply widen and shift it, as the docs state); filtered noise (a pixel filter, a box
blur) and ordered-dithered 8-bit rounding are, with k the ratio of their two levels' variances as
the filters' kernels give it. The verdict then spans the levels both scales allow: a correct
model under a Mitsuba-like pixel filter is suspected, not a mismatch; a wrong model (the image
through a power 1.03, like POV-Ray's brilliance) in a Bayer-dithered 8-bit file is not ok."""

import json
import math

import numpy as np
import pytest
from PIL import Image
from scipy.ndimage import convolve1d, uniform_filter
from test_fit_helpers import TRUTH, make_scene, perturbed, scene_dict, target_of

from difflab.cli import main
from difflab.errors import EXIT_NOT_JUDGED
from difflab.fit import fit_material
from difflab.fit.noise import _view_picks
from difflab.fit.stats import fit_statistics
from difflab.fit.whiteness import K_MAX, WHITE_Z, log_ratio_variance, sigma_range, whiteness
from difflab.io import linear_to_srgb

START = perturbed(TRUTH)
PIXEL_FILTER = np.array([0.2, 1.0, 0.2]) / 1.4  # Mitsuba's gaussian (stddev 0.5 px) as pixel taps: c(1) = 0.37
BAYER = (np.array([[0, 8, 2, 10], [12, 4, 14, 6], [3, 11, 1, 9], [15, 7, 13, 5]]) + 0.5) / 16.0 - 0.5
K1, K2 = np.array([1.0, -2.0, 1.0]), np.array([1.0, 0.0, -2.0, 0.0, 1.0])


def read_whiteness(image, used, signal=None):
    """`whiteness` (k, z) of one (H, W, 3) residual image over its used map (H, W) or (H, W, 3)."""
    return whiteness([_view_picks(used, None, signal, True)], [np.ascontiguousarray(np.moveaxis(image, -1, 0))])


def disc(size):
    yy, xx = np.mgrid[:size, :size]
    return (yy - size / 2) ** 2 + (xx - size / 2) ** 2 < (0.45 * size) ** 2


def theory_k(taps) -> float:
    """var L2 / var L1 of white noise through the separable filter `taps`: per axis the squared norms
    of k2 * f and k1 * f, squared for the two axes."""
    per_axis = np.sum(np.convolve(K2, taps) ** 2) / np.sum(np.convolve(K1, taps) ** 2)
    return float(per_axis ** 2)


def test_the_log_ratio_variance_of_independent_points_is_closed_form():
    """Points 5 or more apart share no pixel: V = var(ln Z2^2 - ln Z1^2) for unit normals of
    correlation 4 / 9 (L1 and L2 share the centre tap, 16 of 36) = pi^2 - 4 asin(4 / 9)^2; denser
    lattices add their neighbours' covariances (a = 1: 20.1)."""
    exact = math.pi ** 2 - 4.0 * math.asin(4.0 / 9.0) ** 2
    for a in (5, 6, 11):
        assert log_ratio_variance(a) == pytest.approx(exact, rel=1e-12)
    assert log_ratio_variance(1) == pytest.approx(20.147, abs=1e-3)
    assert log_ratio_variance(1) > log_ratio_variance(2) > log_ratio_variance(5)


@pytest.mark.parametrize("size", [30, 96])  # a lattice of a = 1 (784 Laplacians), of a = 4 (8836)
def test_z_is_a_unit_normal_for_one_noise_in_three_channels(size):
    """The formula's own case: one Gaussian noise in R, G and B (they count as one channel): over
    300 images z has mean 0 and standard deviation 1 (within 15 %: the spread of 300 samples' is
    4 %); with three independent channels it is narrower (1 / sqrt(3))."""
    grey, rgb = [], []
    used = np.ones((size, size), bool)
    for seed in range(300):
        rng = np.random.default_rng(seed)
        noise = rng.normal(0.0, 0.01, (size, size, 1)).astype(np.float32)
        grey.append(read_whiteness(np.repeat(noise, 3, axis=2), used)[1])
        rgb.append(read_whiteness(rng.normal(0.0, 0.01, (size, size, 3)).astype(np.float32), used)[1])
    assert abs(np.mean(grey)) < 0.2 and 0.85 < np.std(grey) < 1.15
    assert 0.45 < np.std(rgb) < 0.7


@pytest.mark.parametrize("kind", ["one level", "per channel", "follows the signal", "uniform", "grey"])
def test_white_noise_is_not_flagged(kind):
    """100 white-noise images per kind, 20 to 96 px, full, disc and per-channel masks (a channel's
    pixels missing at random), with a signal to bin the levels by: none flagged, |z| < 4."""
    zs = []
    for seed in range(100):
        rng = np.random.default_rng(seed)
        size = (20, 40, 64, 96)[seed % 4]
        signal = np.linspace(0.02, 1.0, size)[None, :, None] * rng.uniform(0.2, 1.0, 3) * np.ones((size, 1, 1))
        used = (np.ones((size, size), bool), disc(size))[seed % 2]
        if seed % 3 == 0:
            used = used[..., None] & (rng.random((size, size, 3)) > 0.03)
        level = {"one level": 0.01, "per channel": np.array([0.002, 0.01, 0.05]),
                 "follows the signal": 0.05 * signal, "uniform": 0.01, "grey": 0.01}[kind]
        if kind == "uniform":
            noise = rng.uniform(-0.5, 0.5, signal.shape) * level * math.sqrt(12.0)
        elif kind == "grey":
            noise = np.repeat(rng.normal(0.0, level, (size, size, 1)), 3, axis=2)
        else:
            noise = rng.normal(0.0, 1.0, signal.shape) * level
        k, z = read_whiteness(noise.astype(np.float32), used, signal.astype(np.float32))
        zs.append(z)
        assert sigma_range(0.01, 1e-5, (k, z)) is None
    assert np.max(np.abs(zs)) < 4.0


def test_heavy_tails_and_a_level_step_widen_and_shift_z_as_documented():
    """The limits the docs state (96 x 96, one noise in three channels): Gaussian 0.05 plus
    exponential fireflies of mean 2 on 5 % of the pixels leave z centred but spread 1.5 (1.3-1.8
    over 400 seeds), not 1; a level 10x higher on one half shifts z by ~1 (0.6-1.4 over 100)."""
    used = np.ones((96, 96), bool)
    fireflies, step = [], []
    for seed in range(400):
        rng = np.random.default_rng(seed)
        noise = rng.normal(0.0, 0.05, (96, 96)) + (rng.random((96, 96)) < 0.05) * rng.exponential(2.0, (96, 96))
        fireflies.append(read_whiteness(np.repeat(noise[..., None], 3, axis=2), used)[1])
        if seed < 100:
            level = np.where(np.arange(96) < 48, 0.01, 0.1)[None, :]
            step.append(read_whiteness(np.repeat((rng.normal(0.0, 1.0, (96, 96)) * level)[..., None], 3, axis=2),
                                       used)[1])
    assert abs(np.mean(fireflies)) < 0.25 and 1.3 < np.std(fireflies) < 1.8
    assert 0.6 < np.mean(step) < 1.4 and 0.8 < np.std(step) < 1.1


@pytest.mark.parametrize("name, taps", [("pixel filter", PIXEL_FILTER), ("box 3 x 3", np.ones(3) / 3.0),
                                        ("box 2 x 2", np.ones(2) / 2.0)])
def test_filtered_noise_is_flagged_with_the_filters_k(name, taps):
    """White noise through a separable filter, 64 x 64: flagged low-pass (z > WHITE_Z), k within
    20 % of var L2 / var L1 as the filter's taps give it (E ln(L2^2 / L1^2) is exactly its log for
    Gaussian noise): 3.36 for the pixel filter, 6.25 for a 3 x 3 box, 9 for a 2 x 2 one -- the most
    noise correlated only between neighbours can show (K_MAX)."""
    rng = np.random.default_rng(7)
    noise = rng.normal(0.0, 0.02, (64, 64, 3))
    noise = convolve1d(convolve1d(noise, taps, axis=0), taps, axis=1).astype(np.float32)
    k, z = read_whiteness(noise, np.ones((64, 64), bool))
    assert z > WHITE_Z
    assert k == pytest.approx(theory_k(taps), rel=0.2)
    assert theory_k(np.ones(2) / 2.0) == pytest.approx(K_MAX)


def test_ordered_dithering_is_flagged_high_pass():
    """A smooth image rounded to 8-bit codes with a Bayer 4 x 4 threshold (ordered dither), 64 x
    64: its error flagged high-pass (z < -WHITE_Z, the 2-apart level a fraction of the 1-apart
    one); rounded plainly, it is not (its level is the rounding's)."""
    yy, xx = np.mgrid[:64, :64] / 64.0
    image = (0.2 + 0.5 * np.sin(2.0 * xx + yy) ** 2)[..., None] * np.array([1.0, 0.7, 0.4])
    codes = image * 255.0
    dithered = np.floor(codes + 0.5 + np.tile(BAYER, (16, 16))[..., None]) / 255.0 - image
    k, z = read_whiteness(dithered.astype(np.float32), np.ones((64, 64), bool))
    assert z < -WHITE_Z and k < 0.3


def test_the_levels_a_non_white_noise_allows():
    """sigma_range from the 1-apart estimate raw, the floor and (k, z): the 2-apart level raw
    sqrt(k), both floored; white (|z| <= 5), a low-pass reading at the rounding's level (raw under
    twice the floor) or beyond K_MAX, and two levels both at the floor: None."""
    assert sigma_range(0.01, 0.001, (4.0, 5.0)) is None
    assert sigma_range(0.01, 0.001, (4.0, 10.0)) == pytest.approx((0.01, 0.02))
    assert sigma_range(0.003, 0.001, (0.09, -20.0)) == pytest.approx((0.001, 0.003))
    assert sigma_range(0.003, 0.0005, (0.09, -20.0)) == pytest.approx((0.0009, 0.003))
    assert sigma_range(0.0015, 0.001, (3.0, 9.0)) is None
    assert sigma_range(0.0015, 0.001, (0.25, -9.0)) == pytest.approx((0.001, 0.0015))
    assert sigma_range(0.01, 0.001, (9.5, 30.0)) is None
    assert sigma_range(0.0005, 0.001, (0.1, -20.0)) is None
    assert sigma_range(0.01, 0.001, (3.0, 9.0)) == pytest.approx((0.01, 0.01 * math.sqrt(3.0)))
    assert sigma_range(0.01, 0.001, None) is None


@pytest.mark.parametrize("chi2, spread, verdict", [
    (5.0, (1.0, 2.0), "suspected"),  # low-pass: 1.25 at the high level
    (5.0, (1.0, 1.2), "mismatch"),  # 3.47 even there
    (1.0, (0.5, 1.0), "suspected"),  # high-pass: 4 at the low level
    (0.2, (0.5, 1.0), "ok"),  # 0.8 even there
    (1.0, None, "ok"),
])
def test_the_verdict_spans_the_levels(chi2, spread, verdict):
    """fit_statistics with sigma 1 (relative) and a sigma_range: a mismatch only when chi2 at the
    range's high level is above max(t, 2), ok only when chi2 at its low level is within t."""
    dof, sigma = 10000, 0.01
    st = fit_statistics(np.eye(2), chi2 * sigma ** 2 * dof, dof + 2, 0, sigma, 2, noise_values=30000,
                        sigma_range=None if spread is None else tuple(sigma * s for s in spread))
    assert st["chi2"] == pytest.approx(chi2)
    assert (st["mismatch"], st["suspected"]) == {"mismatch": (True, False), "suspected": (False, True),
                                                  "ok": (False, False)}[verdict]


@pytest.fixture(scope="module")
def sphere():
    scene = make_scene(size=64)
    return scene, target_of(scene)


def test_a_correct_model_under_a_pixel_filter_is_suspected_not_a_mismatch(sphere):
    """The sphere's render plus noise through the pixel filter (rms 0.026): its 1-apart level reads
    low (chi2 > 2: a MODEL MISMATCH before), the 2-apart one about its rms, so the fit is
    mismatch_suspected with noise_not_white, not ok, not a mismatch; the values within 4 standard
    errors. The same rms of white noise: ok, white."""
    scene, clean = sphere
    rng = np.random.default_rng(0)
    filtered = convolve1d(convolve1d(rng.normal(0.0, 0.04, clean.shape), PIXEL_FILTER, axis=0), PIXEL_FILTER, axis=1)
    result = fit_material(scene, [clean + filtered], "red", init=START)
    assert result.converged and result.noise_not_white and result.mismatch_suspected
    assert not result.model_mismatch and not result.ok and result.chi2 > 2.0
    low, high = result.sigma_range
    assert low == pytest.approx(result.sigma) and high == pytest.approx(np.std(filtered), rel=0.15)
    for key in ("ka", "kd"):
        z = np.abs(np.asarray(result.params[key]) - TRUTH[key]) / np.asarray(result.stderr[key])
        assert np.all(z < 4.0)
    assert "NOISE NOT WHITE" in result.table() and "pixel filter" in result.table()
    report = result.to_dict()
    assert report["noise_not_white"] is True and report["sigma_range"] == pytest.approx([low, high])
    white = fit_material(scene, [clean + rng.normal(0.0, np.std(filtered), clean.shape)], "red", init=START)
    assert white.ok and not white.noise_not_white and white.sigma_range is None
    assert white.to_dict()["sigma_range"] is None


def test_a_view_without_a_full_3x3_interior_adds_nothing_to_the_test():
    """A view whose used pixels hold no full 3 x 3 (a 2-px-wide strip) has no Laplacian: beside a
    40 x 40 view the test reads the big view's (k, z) exactly; alone it is not tested (None), as
    when the noise is unknown."""
    rng = np.random.default_rng(3)
    used = np.ones((40, 40), bool)
    strip = np.zeros((40, 40), bool)
    strip[10:12, 5:30] = True
    big, thin = rng.normal(0.0, 0.01, (2, 3, 40, 40))
    views = [_view_picks(used, None, None, True), _view_picks(strip, None, None, True)]
    alone = whiteness(views[:1], [big])
    assert alone is not None and abs(alone[1]) < WHITE_Z
    assert whiteness(views, [big, thin]) == alone
    assert whiteness(views[1:], [thin]) is None


def test_a_two_view_fit_with_a_strip_view_reports_the_big_views_verdict(sphere):
    """The pixel-filtered sphere fit (above) with a second view masked to a 2-px strip across the
    sphere: it runs and reports what the big view alone does -- not white, suspected, not a
    mismatch, its sigma_range within 1 % of the one view's."""
    scene, clean = sphere
    rng = np.random.default_rng(0)
    noisy = [clean + convolve1d(convolve1d(rng.normal(0.0, 0.04, clean.shape), PIXEL_FILTER, axis=0),
                                PIXEL_FILTER, axis=1) for _ in range(2)]
    strip = np.zeros(clean.shape[:2], bool)
    strip[31:33, 12:52] = True
    one = fit_material(scene, noisy[:1], "red", init=START)
    two = fit_material(scene, noisy, "red", init=START, masks=[None, strip])
    for result in (one, two):
        assert result.converged and result.noise_not_white and result.mismatch_suspected
        assert not result.model_mismatch and not result.ok
    assert two.sigma_range == pytest.approx(one.sigma_range, rel=0.01)


def write_codes(path, linear, dither: bool):
    """An 8-bit sRGB PNG of a linear image, rounded, or with the Bayer 4 x 4 ordered dither."""
    codes = linear_to_srgb(np.clip(linear, 0.0, 1.0)) * 255.0
    h, w = codes.shape[:2]
    offset = np.tile(BAYER, (h // 4 + 1, w // 4 + 1))[:h, :w, None] if dither else 0.0
    Image.fromarray(np.clip(np.floor(codes + 0.5 + offset), 0, 255).astype(np.uint8)).save(path)


def test_a_wrong_model_in_a_dithered_8_bit_file_is_not_ok(sphere, tmp_path, capsys):
    """The render through a power 1.03 (an effect outside the model, like POV-Ray's brilliance 1.03)
    in an 8-bit file: rounded, a MODEL MISMATCH; ordered-dithered, the dither reads as noise 1 apart
    (chi2 under 2 there: reported ok before), but the noise is flagged high-pass and chi2 at the
    rounding floor is far above its threshold: mismatch_suspected, not ok -- and `difflab fit`
    exits 5 naming the dithering and --sigma."""
    scene, clean = sphere
    plain, dithered = tmp_path / "plain.png", tmp_path / "dithered.png"
    write_codes(plain, clean ** 1.03, dither=False)
    write_codes(dithered, clean ** 1.03, dither=True)
    assert fit_material(scene, [str(plain)], "red", init=START).model_mismatch
    result = fit_material(scene, [str(dithered)], "red", init=START)
    assert result.converged and result.chi2 < 2.0 and result.noise_not_white
    assert result.mismatch_suspected and not result.ok
    low, high = result.sigma_range
    assert high == pytest.approx(result.sigma) and result.chi2 * (result.sigma / low) ** 2 > 3.0
    (tmp_path / "scene.json").write_text(json.dumps(scene_dict(size=64)))
    code = main(["fit", str(tmp_path / "scene.json"), str(dithered), "--material", "red", "-o",
                 str(tmp_path / "fitted.json")])
    out = capsys.readouterr().out
    assert code == EXIT_NOT_JUDGED and "NOISE NOT WHITE" in out and "dithering" in out and "--sigma" in out
    assert json.loads((tmp_path / "fitted.fit.json").read_text())["noise_not_white"] is True
