"""difflab.fractals: curves and their measures against closed forms, terrain statistics, escape-time
sets against known points, the Mandelbulb render, and the failure paths."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from difflab.errors import DifflabError, RenderError, SceneError
from difflab import fractals as fr
from difflab.scene import Light, Material

KOCH_DIM = math.log(4) / math.log(3)
CANTOR_DIM = math.log(2) / math.log(3)


# 1. Curves: exact counts and lengths ------------------------------------------------------------

@pytest.mark.parametrize("n", range(7))
def test_koch_vertex_count_and_length_are_exact(n):
    points = fr.koch(n)
    assert points.shape == (4**n + 1, 2)
    np.testing.assert_array_equal(points[0], [0.0, 0.0])
    np.testing.assert_allclose(points[-1], [1.0, 0.0], atol=1e-15)
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    np.testing.assert_allclose(steps, 3.0**-n, rtol=1e-12)
    assert fr.polyline_length(points) == pytest.approx((4 / 3) ** n, rel=1e-12)


@pytest.mark.parametrize("n", range(7))
def test_koch_snowflake_perimeter_is_3_times_four_thirds_to_the_n(n):
    points = fr.koch_snowflake(n)
    assert points.shape == (3 * 4**n + 1, 2)
    np.testing.assert_allclose(points[-1], points[0], atol=1e-15)  # closed
    assert fr.polyline_length(points) == pytest.approx(3 * (4 / 3) ** n, rel=1e-12)


def test_koch_snowflake_bumps_point_outwards():
    # The iteration-1 star's six tips lie outside the triangle: the outward tip on the base is below y = 0.
    points = fr.koch_snowflake(1)
    assert points[:, 1].min() == pytest.approx(-math.sqrt(3) / 6, rel=1e-12)


@pytest.mark.parametrize("curve, cells, base", [(fr.peano, fr.peano_cells, 3), (fr.hilbert, fr.hilbert_cells, 2)])
@pytest.mark.parametrize("order", range(5))
def test_space_filling_curves_visit_every_cell_once_by_unit_steps(curve, cells, base, order):
    grid = cells(order)
    side = base**order
    assert grid.shape == (side * side, 2)
    assert len(np.unique(grid[:, 0] * side + grid[:, 1])) == side * side  # each cell exactly once
    assert grid.min() == 0 and grid.max() == side - 1
    if order:
        assert np.all(np.abs(np.diff(grid, axis=0)).sum(axis=1) == 1)  # edge-adjacent steps
    points = curve(order)
    np.testing.assert_allclose(points, (grid + 0.5) / side, rtol=0, atol=1e-15)


def test_peano_and_hilbert_endpoints():
    np.testing.assert_allclose(fr.peano(3)[[0, -1]], [[1 / 54, 1 / 54], [53 / 54, 53 / 54]])
    np.testing.assert_allclose(fr.hilbert(3)[[0, -1]], [[1 / 16, 1 / 16], [15 / 16, 1 / 16]])


# 2. Box-counting dimension -----------------------------------------------------------------------

@pytest.mark.parametrize("name, points, expected", [
    ("koch", lambda: fr.koch(7), KOCH_DIM),
    ("peano", lambda: fr.peano(5), 2.0),
    ("hilbert", lambda: fr.hilbert(7), 2.0),
    ("cantor", lambda: fr.cantor_mask(12), CANTOR_DIM),
    ("segment", lambda: np.linspace([0.0, 0.0], [1.0, 0.3], 2**14 + 1), 1.0),
    ("filled square", lambda: np.ones((256, 256), dtype=bool), 2.0),
])
def test_box_counting_dimension_matches_known_values(name, points, expected):
    assert fr.box_counting_dimension(points()) == pytest.approx(expected, abs=0.03)


def test_box_counting_with_the_sets_own_scales_is_exact_for_cantor():
    sizes = 3.0 ** np.arange(10, -1, -1)
    sizes_out, counts = fr.box_counts(fr.cantor_mask(12), sizes)
    np.testing.assert_array_equal(counts, 2 ** np.arange(2, 13))
    assert fr.box_counting_dimension(fr.cantor_mask(12), sizes) == pytest.approx(CANTOR_DIM, abs=1e-12)


# 3. Cantor set and staircase ---------------------------------------------------------------------

def test_cantor_set_intervals():
    intervals = fr.cantor_set(5)
    assert intervals.shape == (32, 2)
    np.testing.assert_allclose(intervals[:, 1] - intervals[:, 0], 3.0**-5, rtol=1e-12)
    assert np.all(np.diff(intervals[:, 0]) > 0) and intervals[0, 0] == 0 and intervals[-1, 1] == pytest.approx(1)
    mask = fr.cantor_mask(5)
    np.testing.assert_array_equal(np.flatnonzero(mask), np.round(intervals[:, 0] * 3**5).astype(int))


def test_cantor_staircase_is_monotone_continuous_and_half_on_the_middle_third():
    x = np.linspace(0.0, 1.0, 100_001)
    c = fr.cantor_staircase(x)
    assert c[0] == 0.0 and c[-1] == 1.0
    assert np.all(np.diff(c) >= 0.0)  # monotone
    # Continuous: C is Hoelder with exponent log2/log3, |C(x) - C(y)| <= 2 |x - y|^(log2/log3).
    assert np.max(np.diff(c)) <= 2.0 * (x[1] - x[0]) ** CANTOR_DIM
    middle = np.linspace(1 / 3, 2 / 3, 1001)
    np.testing.assert_allclose(fr.cantor_staircase(middle), 0.5, atol=1e-9)


def test_cantor_staircase_symmetry_and_self_similarity():
    x = np.random.default_rng(0).random(10_000)
    c = fr.cantor_staircase(x)
    np.testing.assert_allclose(fr.cantor_staircase(1.0 - x), 1.0 - c, atol=1e-8)
    np.testing.assert_allclose(fr.cantor_staircase(x / 3.0), c / 2.0, atol=1e-8)
    np.testing.assert_allclose(fr.cantor_staircase([0.25, 0.75, 1 / 9, 7 / 9]), [1 / 3, 2 / 3, 0.25, 0.75], atol=1e-9)


def test_staircase_steps_lengths_and_heights():
    depth = 12
    steps = fr.staircase_steps(depth)
    assert steps.shape == (2**depth - 1, 3)
    lengths = steps[:, 1] - steps[:, 0]
    assert math.fsum(lengths) == pytest.approx(1.0 - (2 / 3) ** depth, abs=1e-12)
    np.testing.assert_allclose(fr.cantor_staircase(0.5 * (steps[:, 0] + steps[:, 1])), steps[:, 2], atol=1e-12)
    assert np.all(np.diff(steps[:, 2]) > 0)  # each step higher than the last


def test_staircase_step_lengths_sum_to_one():
    # The lecture's series 1/3 + 2/9 + 4/27 + ... = 1. After `depth` levels the steps leave exactly
    # (2/3)^depth uncovered (the intervals holding the "wet points"): at depth 30 that is 5.2e-6, so
    # steps + uncovered = 1 is the 1e-9 check there, and the steps alone reach 1 - 1e-9 from depth 52.
    steps, uncovered = fr.staircase_measure(30)
    assert steps + uncovered == pytest.approx(1.0, abs=1e-12)
    assert uncovered == pytest.approx((2 / 3) ** 30, rel=1e-12)
    assert 1.0 - fr.staircase_measure(52)[0] < 1e-9
    assert 1.0 - fr.staircase_measure(51)[0] > 1e-9


def test_x_cos_pi_over_x():
    assert fr.x_cos_pi_over_x(0.0) == 0.0
    k = np.arange(1, 50)
    np.testing.assert_allclose(fr.x_cos_pi_over_x(2.0 / (2 * k + 1)), 0.0, atol=1e-13)  # zeros
    np.testing.assert_allclose(fr.x_cos_pi_over_x(1.0 / k), (-1.0) ** k / k, rtol=1e-12)  # touches +-x
    x = np.linspace(-1e-3, 1e-3, 1001)
    assert np.all(np.abs(fr.x_cos_pi_over_x(x)) <= np.abs(x))  # continuous at 0


# 4. Terrain ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("method", [fr.diamond_square, fr.midpoint_displacement])
def test_terrain_grid_is_deterministic_and_coarser_levels_are_subsets(method):
    fine = method(7, 0.7, seed=5)
    assert fine.shape == (129, 129) and np.all(np.isfinite(fine))
    np.testing.assert_array_equal(fine, method(7, 0.7, seed=5))
    for level in range(7):
        np.testing.assert_array_equal(fine[:: 2 ** (7 - level), :: 2 ** (7 - level)], method(level, 0.7, seed=5))
    assert not np.array_equal(fine, method(7, 0.7, seed=6))


@pytest.mark.parametrize("method", [fr.diamond_square, fr.midpoint_displacement])
@pytest.mark.parametrize("hurst", [0.3, 0.5, 0.8])
def test_terrain_variogram_slope_is_two_hurst(method, hurst):
    # Mean over 8 seeds at level 9 of the log-log slope over lags 4..128 (of 512). Measured
    # deviations: diamond-square -0.007 / -0.048 / -0.054, midpoint +0.003 / -0.036 / -0.076
    # (recursive subdivision is only approximately fBm; the bias grows with H).
    slopes = [fr.variogram_slope(method(9, hurst, seed)) for seed in range(8)]
    assert np.mean(slopes) == pytest.approx(2 * hurst, abs=0.1)


def test_terrain_mesh():
    mesh = fr.terrain(level=5, seed=3, size=10.0, height=2.0)
    assert mesh.vertices.shape == (33 * 33, 3) and mesh.faces.shape == (2 * 32 * 32, 3)
    assert mesh.vertices[:, 0].min() == -5.0 and mesh.vertices[:, 2].max() == 5.0
    np.testing.assert_allclose(mesh.vertices[:, 1], 2.0 * fr.diamond_square(5, 0.8, 3).ravel())
    assert np.all(mesh.normals[:, 1] > 0)  # y up, faces counter-clockwise from above
    coarse = fr.terrain(level=3, seed=3)
    np.testing.assert_array_equal(mesh.vertices.reshape(33, 33, 3)[::4, ::4].reshape(-1, 3), coarse.vertices)
    bands = fr.terrain_bands(mesh)
    assert set(np.unique(bands)) == {0, 1, 2, 3}
    assert bands[np.argmin(mesh.vertices[:, 1])] == 0 and bands[np.argmax(mesh.vertices[:, 1])] == 3
    colours = fr.terrain_colors(mesh)
    np.testing.assert_array_equal(colours[bands == 3][0], fr.TERRAIN_COLORS["snow"])
    parts = fr.terrain_parts(mesh)
    assert sum(len(p.faces) for p in parts.values()) == len(mesh.faces)


# 5. Escape-time sets -------------------------------------------------------------------------------

@pytest.mark.parametrize("point, inside", [
    ((0.0, 0.0), True), ((-1.0, 0.0), True), ((-0.1, 0.1), True), ((0.0, 1.0), True),
    ((-1.75, 0.0), True),  # the period-3 bulb on the real axis
    ((1.0, 0.0), False), ((0.5, 0.5), False), ((-2.1, 0.0), False), ((0.3, 0.6), False),
])
def test_mandelbrot_classifies_known_points(point, inside):
    nu = fr.escape_time(1, 1, center=point, scale=1e-9, max_iter=2000)  # one pixel centred on the point
    assert (nu[0, 0] == -1.0) == inside


def _escape_reference(c, max_iter):
    """escape.py's nu in numpy complex128 (-1 inside), and the escape iteration n (-1 inside)."""
    c = np.asarray(c, dtype=complex)
    z = np.zeros_like(c)
    nu, count = np.full(c.shape, -1.0), np.full(c.shape, -1)
    for n in range(max_iter + 1):
        escaped = (count == -1) & (np.abs(z) > 2.0**20)
        nu0 = n + 1 - np.log2(np.log(np.abs(z[escaped])))
        nu[escaped], count[escaped] = np.where(nu0 >= 1.0, nu0, np.exp(nu0 - 1.0)), n
        active = count == -1
        z[active] = z[active] ** 2 + c[active]
    return nu, count


def test_escape_time_matches_a_numpy_reference():
    width, height, center, scale, max_iter = 24, 16, (-0.5, 0.1), 3.0, 64
    nu = fr.escape_time(width, height, center=center, scale=scale, max_iter=max_iter)
    step = scale / width
    re = center[0] + (np.arange(width) + 0.5 - width / 2) * step
    im = center[1] + (height / 2 - np.arange(height) - 0.5) * step
    expected, _ = _escape_reference(re[None, :] + 1j * im[:, None], max_iter)
    np.testing.assert_allclose(nu, expected, atol=1e-4)


@pytest.mark.parametrize("c, expected", [(0.26, 30.52044), (1.0, 3.29564), (-2.0001, 8.93625)])
def test_escape_time_keeps_the_classic_count_near_the_set(c, expected):
    # n + 1 - log2(log|z_n|), checked by hand in Python; the continuation below 1 leaves these alone.
    assert fr.escape_time(1, 1, center=(c, 0.0), scale=1e-9, max_iter=2000)[0, 0] == pytest.approx(expected, abs=1e-4)


def test_points_far_outside_escape_with_a_positive_count():
    # |c| >~ 7 escapes within 1-2 iterations far past the bailout: the classic count gave
    # c = 100 -> -0.205, 3000 -> -1.0011 (read as INTERIOR), 1e160 -> -inf (|z|^2 overflowed).
    cs = [20.0, 100.0, 3000.0, 1e160, 1e300]
    nu = np.array([fr.escape_time(1, 1, center=(c, 0.0), scale=1e-9)[0, 0] for c in cs])
    np.testing.assert_allclose(nu, _escape_reference(cs, 256)[0], rtol=1e-5)
    assert np.all(nu > 0) and np.all(np.diff(nu) < 0)  # positive, and decreasing outward
    wide = fr.escape_time(200, 200, center=(0.0, 0.0), scale=400.0)  # was 94 % negative
    assert np.all((wide > 0) | (wide == -1.0)) and np.count_nonzero(wide == -1.0) <= 1


def test_nu_is_continuous_across_the_bailout_contours():
    # On the real axis the escape iteration drops by one at each c where some |z_n| = 2^20, and the
    # continuation joins the classic count where it is 1: straddle each such c by 1e-9 relative.
    def bisect(changed, lo, hi):
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if changed(lo, mid) else (mid, hi)
        return 0.5 * (lo + hi)

    grid = np.geomspace(0.3, 1e4, 400)
    count = _escape_reference(grid, 256)[1]
    edges = [bisect(lambda a, b: np.ptp(_escape_reference([a, b], 256)[1]) > 0, grid[k], grid[k + 1])
             for k in np.flatnonzero(np.diff(count))]
    join = bisect(lambda a, b: _escape_reference([b], 256)[0][0] < 1.0, 2.0, 50.0)
    assert len(edges) >= 6 and 6.5 < join < 7.5
    for c in edges + [join]:
        pair = fr.escape_time(2, 1, center=(c, 0.0), scale=2e-9 * c)[0]
        assert np.all(pair > 0) and abs(pair[0] - pair[1]) < 1e-5, (c, pair)
    assert np.ptp(_escape_reference(np.array(edges) * (1 + np.array([[-1e-9], [1e-9]])), 256)[1], axis=0).min() == 1


def test_smooth_iteration_count_has_no_band_steps():
    # Along a line outside the set nu crosses several integer bands without jumping.
    nu = fr.escape_time(2000, 1, center=(1.0, 0.8), scale=1.6, max_iter=256)[0]
    assert np.all(nu > 0) and np.ptp(nu) > 2.0
    assert np.max(np.abs(np.diff(nu))) < 0.02


def test_julia_of_zero_is_the_unit_disk():
    nu = fr.escape_time(64, 64, center=(0.0, 0.0), scale=2.5, max_iter=500, c=(0.0, 0.0))
    step = 2.5 / 64
    r = np.hypot(*np.meshgrid((np.arange(64) + 0.5 - 32) * step, (np.arange(64) + 0.5 - 32) * step))
    np.testing.assert_array_equal(nu == -1.0, r < 1.0)


def test_mandelbrot_and_julia_images():
    image = fr.mandelbrot(48, 32, max_iter=128)
    assert image.shape == (32, 48, 3) and image.dtype == np.float32 and np.all(np.isfinite(image))
    nu = fr.escape_time(48, 32, max_iter=128)
    assert np.all(image[nu == -1.0] == 0.0) and np.all(image[nu > 0].max(axis=-1) > 0.0)
    j = fr.julia(48, 32, max_iter=128)
    assert j.shape == (32, 48, 3) and np.all(np.isfinite(j)) and np.any(j.max(axis=-1) == 0.0)


def test_escape_time_is_identical_on_one_thread_and_many():
    a = fr.escape_time(40, 30, max_iter=100, threads=1)
    b = fr.escape_time(40, 30, max_iter=100, threads=4)
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("threads", [1, 2])
def test_a_long_escape_run_reports_every_row_and_keeps_its_image(threads):
    # A view far outside the set (every point escapes within two iterations) at max_iter 10^6: a row's
    # 64 x (10^6 + 1) iterations at most exceed launch.BAND_WORK (2^25), so each row is a band of its
    # own and is reported as it finishes, in order whichever thread ran it.
    calls = []
    view = {"center": (3.0, 3.0), "scale": 0.5, "max_iter": 1_000_000}
    nu = fr.escape_time(64, 6, **view, threads=threads, progress=lambda done, total: calls.append((done, total)))
    assert calls == [(k, 6) for k in range(1, 7)]
    np.testing.assert_array_equal(nu, fr.escape_time(64, 6, **view, threads=threads))
    assert np.all((nu > 0) & (nu < 3))



@pytest.mark.parametrize("threads", [1, 2])
def test_an_interrupt_between_bands_starts_no_further_band(threads):
    # Ctrl-C lands between the bands the calling thread launches (Python runs its handler there): here
    # the second report raises it. No band starts after it; one already running on another thread ends.
    calls = []

    def interrupt_at_the_second(done, total):
        calls.append(done)
        if len(calls) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        fr.escape_time(64, 6, center=(3.0, 3.0), scale=0.5, max_iter=1_000_000, threads=threads,
                       progress=interrupt_at_the_second)
    assert 2 <= len(calls) <= 1 + threads and calls[-1] < 6

@pytest.mark.parametrize("render", [lambda progress: fr.mandelbrot(48, 32, max_iter=128, threads=2, progress=progress),
                                    lambda progress: fr.julia(48, 32, max_iter=128, threads=2, progress=progress),
                                    lambda progress: fr.mandelbulb(48, 32, threads=2, progress=progress)])
def test_progress_counts_rows_up_to_the_height(render):
    calls = []
    render(lambda done, total: calls.append((done, total)))
    done = [d for d, total in calls]
    assert {total for d, total in calls} == {32} and done[-1] == 32
    assert all(a < b for a, b in zip(done, done[1:])) and len(done) == 8  # the short run's bands: 4 a thread


def test_terrain_progress_counts_its_three_steps():
    from difflab.demos.fractals import render_set

    calls = []
    image = render_set("terrain", 32, 24, order=3, progress=lambda done, total: calls.append((done, total)))
    assert calls == [(1, 3), (2, 3), (3, 3)] and image.shape == (24, 32, 3)


# 6. The Mandelbulb ---------------------------------------------------------------------------------

def test_mandelbulb_renders_a_lit_shadowed_bulb():
    image = fr.mandelbulb(48, 36)
    assert image.shape == (36, 48, 3) and image.dtype == np.float32
    assert np.all(np.isfinite(image)) and np.all(image >= 0.0)
    hit = image.max(axis=-1) > 0.0
    assert 0.2 < hit.mean() < 0.9  # the bulb and background both in view
    unshadowed = fr.mandelbulb(48, 36, shadows=False)
    assert np.all(unshadowed >= image - 1e-6) and np.any(unshadowed > image + 0.05)  # shadows only darken
    np.testing.assert_array_equal(image, fr.mandelbulb(48, 36, threads=1))


def test_mandelbulb_uses_the_illumination_model():
    # With kd = ks = 0 the bulb shows exactly ka * Ia, whatever the lights do.
    mat = Material(ka=(0.5, 0.25, 1.0), kd=(0, 0, 0), ks=(0, 0, 0))
    image = fr.mandelbulb(32, 24, material=mat, ambient=(0.4, 0.4, 0.4), background=(0, 0, 0))
    hit = image.max(axis=-1) > 0.0
    assert hit.any()
    np.testing.assert_allclose(image[hit], np.broadcast_to([0.2, 0.1, 0.4], image[hit].shape), atol=1e-6)


# 7. Failure paths -----------------------------------------------------------------------------------

@pytest.mark.parametrize("call, error", [
    (lambda: fr.koch(-1), "iterations"),
    (lambda: fr.koch(1.5), "iterations"),
    (lambda: fr.koch(99), "iterations"),
    (lambda: fr.koch_snowflake(True), "iterations"),
    (lambda: fr.peano(-2), "order"),
    (lambda: fr.hilbert("3"), "order"),
    (lambda: fr.cantor_set(-1), "depth"),
    (lambda: fr.cantor_staircase([0.5, np.nan]), "x"),
    (lambda: fr.cantor_staircase(0.5, depth=0), "depth"),
    (lambda: fr.staircase_steps(40), "depth"),
    (lambda: fr.x_cos_pi_over_x([np.inf]), "x"),
    (lambda: fr.polyline_length(np.zeros((3, 2, 2))), "points"),
    (lambda: fr.box_counting_dimension(np.zeros((4, 4), dtype=bool)), "image"),
    (lambda: fr.box_counting_dimension(fr.koch(2), sizes=[0.1]), "sizes"),
    (lambda: fr.diamond_square(4, hurst=0.0, seed=0), "hurst"),
    (lambda: fr.diamond_square(4, hurst=0.5, seed=-1), "seed"),
    (lambda: fr.midpoint_displacement(13, 0.5, 0), "level"),
    (lambda: fr.terrain(level=0), "level"),
    (lambda: fr.terrain(method="perlin"), "method"),
    (lambda: fr.terrain(size=-1.0), "size"),
    (lambda: fr.variogram(np.zeros((5, 5))), "heights"),
    (lambda: fr.mandelbrot(16, 16, max_iter=0), "max_iter"),
    (lambda: fr.mandelbrot(16, 16, scale=-1.0), "scale"),
    (lambda: fr.mandelbrot(16, 16, center=(0.0,)), "center"),
    (lambda: fr.julia(16, 16, c=(0.0, np.nan)), "c[1]"),
    (lambda: fr.mandelbulb(16, 16, power=1.0), "power"),
    (lambda: fr.mandelbulb(16, 16, lights=[{"type": "point"}]), "lights[0]"),
    (lambda: fr.mandelbulb(16, 16, material="gold"), "material"),
    (lambda: fr.mandelbulb(16, 16, specular="cook"), "specular"),
])
def test_bad_arguments_raise_fractal_errors_naming_them(call, error):
    with pytest.raises(fr.FractalError, match=error.replace("[", r"\[").replace("]", r"\]")) as info:
        call()
    assert isinstance(info.value, DifflabError) and isinstance(info.value, ValueError)


@pytest.mark.parametrize("call, message", [
    (lambda: fr.variogram(fr.diamond_square(5), lags=[0, 4]),  # was numpy's broadcast ValueError
     r"lags: expected a list of whole grid steps in [1, 32] (a 33 x 33 grid), got [0, 4]"),
    (lambda: fr.variogram(fr.diamond_square(5), lags=[4, 40]),  # was nan and RuntimeWarnings
     r"lags: expected a list of whole grid steps in [1, 32] (a 33 x 33 grid), got [4, 40]"),
    (lambda: fr.variogram(fr.diamond_square(5), lags=[2.5, 4]),  # was truncated to 2 silently
     r"lags: expected a list of whole grid steps in [1, 32] (a 33 x 33 grid), got [2.5, 4.0]"),
    (lambda: fr.variogram_slope(np.full((33, 33), np.nan)),  # was nan, silently
     "heights: 1089 of 1089 values are not finite (NaN or inf)"),
    (lambda: fr.variogram_slope(np.zeros((33, 33))),  # was nan and a divide-by-zero warning
     "heights: no height differences at lag 4 (gamma = 0, e.g. a flat grid): log gamma has no slope"),
    (lambda: fr.variogram_slope(fr.diamond_square(4)),  # one default lag: was a polyfit of one point
     "lags: a slope needs at least 2 different lags, got [4] (the default below 33 x 33: give lags, e.g. [1, 2, 4])"),
    (lambda: fr.variogram(np.eye(33) * 1e200),  # was inf and an overflow warning
     "heights: height differences too large to square in float64 (beyond ~1e154)"),
    (lambda: fr.box_counting_dimension(fr.cantor_mask(5).astype(int)),  # was "points: expected shape (N, D)"
     "points_or_image: got shape (243,) of dtype int64, neither a polyline (N, D) of vertices with D in [1, 3] "
     "nor a boolean image: for a mask of 0/1 cells pass mask.astype(bool)"),
    (lambda: fr.box_counting_dimension(np.eye(64, dtype=np.uint8)),  # was read as 64 points in 64-D
     "points_or_image: got shape (64, 64) of dtype uint8, neither a polyline"),
])
def test_bad_measure_inputs_raise_one_fractal_error(call, message):
    with pytest.raises(fr.FractalError, match="^" + re.escape(message)):
        call()


def test_measures_accept_the_edges_of_their_ranges():
    h = fr.diamond_square(5)
    lags, gamma = fr.variogram(h, lags=[1, 32])
    assert gamma[1] == pytest.approx(0.5 * (np.mean((h[32] - h[0]) ** 2) + np.mean((h[:, 32] - h[:, 0]) ** 2)))
    assert 0.5 < fr.variogram_slope(fr.diamond_square(4), lags=[1, 2, 4]) < 2.5
    mask = fr.cantor_mask(8)
    assert fr.box_counting_dimension(mask.astype(int).astype(bool), 3 ** np.arange(6, -1, -1)) == pytest.approx(CANTOR_DIM)


@pytest.mark.parametrize("call", [
    lambda: fr.mandelbrot(0, 16),
    lambda: fr.julia(16, -3),
    lambda: fr.escape_time(100_000, 100_000),  # beyond the pixel budget, refused before allocating
    lambda: fr.mandelbulb(16, 16, device="tpu"),
])
def test_bad_image_sizes_and_devices_raise_render_errors(call):
    with pytest.raises(RenderError):
        call()


def test_bad_camera_raises_scene_error():
    with pytest.raises(SceneError, match="target"):
        fr.mandelbulb(16, 16, eye=(0, 0, 0), target=(0, 0, 0))


def test_mandelbulb_is_lit_only_by_the_lights_it_is_given():
    """No ambient and one light of zero intensity: the bulb is exactly black, misses show the background."""
    background = np.array([0.25, 0.5, 0.75], np.float32)
    image = fr.mandelbulb(24, 24, lights=[Light(type="point", position=(3, 3, 3), intensity=(0, 0, 0))],
                          ambient=(0, 0, 0), background=tuple(background), max_steps=64)
    black = np.all(image == 0.0, axis=-1)
    assert 0.1 < black.mean() < 0.9
    assert np.all(image[~black] == background)


def test_terrain_scene_writes_loadable_band_meshes(tmp_path):
    from difflab.geometry import load_mesh
    from difflab.scene import Scene

    mesh = fr.terrain(level=4, seed=2)
    scene = Scene.from_dict(fr.terrain_scene(mesh, tmp_path, width=32, height=24))
    assert scene.render.shadows and len(scene.objects) == len(fr.terrain_parts(mesh))
    total = 0
    for obj in scene.objects:
        part = load_mesh(obj.file)
        assert np.all(np.isin(np.round(part.vertices, 6), np.round(mesh.vertices, 6)).all(axis=1))
        assert part.normals is not None and np.all(part.normals[:, 1] > 0)
        total += len(part.faces)
    assert total == len(mesh.faces)


def test_hurst_one_is_refused_because_its_displacements_vanish():
    """At H = 1 (the linear fBm t Z) the variance of every symmetric configuration of parents is 0:
    edge and diagonal midpoints, diamond and square centres -- subdivision would add no detail, so H
    is in (0, 1) and 1.0 is a FractalError naming the open interval (just below, detail remains)."""
    from difflab.fractals.heightfield import _std

    d = 0.25
    for parents in ([(-d, 0), (d, 0)], [(-d, -d), (d, d)], [(-d, -d), (-d, d), (d, -d), (d, d)],
                    [(-d, 0), (d, 0), (0, -d), (0, d)]):
        assert _std(1.0, 1.0, parents) == pytest.approx(0.0, abs=1e-7)
        assert _std(1.0, 0.9, parents) > 0.05
    for generate in (fr.diamond_square, fr.midpoint_displacement):
        with pytest.raises(fr.FractalError, match=r"^hurst: must be a finite number in \(0\.0, 1\.0\), got 1\.0$"):
            generate(4, hurst=1.0)
        assert np.isfinite(generate(4, hurst=0.999)).all()
