"""Views kept with a compiled scene (`fit.records`): a view fitted again renders nothing and cuts
nothing again, and gives exactly what a fresh fit gives -- for another start, target, mask, weights,
precision or fitted set; another camera, light placement or tree shape is rendered anew."""

import jax
import numpy as np
import pytest
from test_fit_helpers import TRUTH, make_scene, mirror_scene, perturbed, target_of

from difflab import compile_scene
from difflab.fit import Setup, fit_material
from difflab.fit.records import KEPT_ARRAYS, KEPT_VIEWS, STORE, DeviceCopies, take_pixels, used_rows

SCENE = make_scene(size=16)
TARGET = target_of(SCENE)
START, OTHER_START = perturbed(TRUTH), perturbed(TRUTH, factor=0.2, seed=5)
CAMERA = SCENE.camera.to_dict()


def fit(scene, targets, **kwargs):
    return fit_material(scene, targets, "red", history=False, **kwargs)


def assert_same(result, expected):
    """Bitwise the fresh fit's result: steps, values, loss, noise and flags."""
    assert (result.result, result.steps, result.at_bound) == (expected.result, expected.steps, expected.at_bound)
    for key in expected.params:
        np.testing.assert_array_equal(result.params[key], expected.params[key])
        np.testing.assert_array_equal(result.stderr[key], expected.stderr[key])
    assert (result.loss, result.sigma, result.chi2) == (expected.loss, expected.sigma, expected.chi2)
    np.testing.assert_array_equal(result.residuals[0], expected.residuals[0])


def kept_views(compiled) -> int:
    return len(compiled.built[STORE])


def test_a_view_fitted_again_with_another_start_renders_nothing():
    compiled = compile_scene(SCENE)
    first = fit(compiled, [TARGET], init=START)
    again = fit(compiled, [TARGET], init=OTHER_START)
    assert first.timings["render"] > 0 and again.timings["render"] == 0.0 and kept_views(compiled) == 1
    assert_same(first, fit(SCENE, [TARGET], init=START))
    assert_same(again, fit(SCENE, [TARGET], init=OTHER_START))


def test_another_target_mask_weights_or_precision_on_a_kept_view_is_the_fresh_fit():
    compiled = compile_scene(SCENE)
    fit(compiled, [TARGET], init=START)
    noisy = TARGET + np.random.default_rng(1).normal(0.0, 0.01, TARGET.shape)
    half = np.zeros(TARGET.shape[:2], bool)
    half[:, 4:12] = True
    ramp = np.linspace(0.5, 2.0, TARGET.shape[1])[None, :].repeat(TARGET.shape[0], axis=0)
    for kwargs in ({"targets": [noisy]}, {"masks": [half]}, {"weights": [ramp]}, {"x64": False},
                   {"targets": [noisy], "masks": [half]}):
        targets = kwargs.pop("targets", [TARGET])
        again = fit(compiled, targets, init=START, **kwargs)
        assert again.timings["render"] == 0.0
        assert_same(again, fit(SCENE, targets, init=START, **kwargs))
    assert kept_views(compiled) == 1


def test_light_intensities_fitted_again_start_from_their_new_values():
    compiled = compile_scene(SCENE)
    params = ("kd", "intensity")
    fit(compiled, [TARGET], params=params, init={"kd": TRUTH["kd"]})
    start = {"kd": START["kd"], "lights[0].intensity": [0.7, 0.8, 0.9]}
    again = fit(compiled, [TARGET], params=params, init=start)
    assert again.timings["render"] == 0.0
    assert_same(again, fit(SCENE, [TARGET], params=params, init=start))


def test_views_kept_side_by_side_stay_intact():
    """Views A, B, A: the second fit of A reads its own record, untouched by B's render (a record
    that shared the renderer's scratch memory would now hold B)."""
    compiled = compile_scene(SCENE)
    other = CAMERA | {"eye": [0.6, 1.5, 3.8]}
    moved = target_of(SCENE.with_overrides(camera=other))
    first = fit(compiled, [TARGET], init=START)
    fit(compiled, [(moved, {"camera": other})], init=START)
    again = fit(compiled, [TARGET], init=START)
    assert again.timings["render"] == 0.0 and kept_views(compiled) == 2
    assert_same(again, first)


def test_another_camera_or_light_placement_is_rendered_and_at_most_kept_views_are_kept():
    compiled = compile_scene(SCENE)
    fit(compiled, [TARGET], init=START)
    lights = [light.to_dict() for light in SCENE.lights]
    lights[0]["position"] = [2.5, 4.0, 3.5]
    moved_light = target_of(SCENE.with_overrides(lights=lights))
    result = fit(compiled, [(moved_light, {"lights": lights})], init=START)
    assert result.timings["render"] > 0
    assert_same(result, fit(SCENE, [(moved_light, {"lights": lights})], init=START))
    cameras = [CAMERA | {"eye": [0.2 * i, 1.2, 4.0]} for i in range(1, KEPT_VIEWS + 1)]
    for camera in cameras:
        assert fit(compiled, [(TARGET, {"camera": camera})], init=START).timings["render"] > 0
    assert kept_views(compiled) == KEPT_VIEWS
    assert fit(compiled, [(TARGET, {"camera": cameras[-1]})], init=START).timings["render"] == 0.0
    assert fit(compiled, [TARGET], init=START).timings["render"] > 0  # the oldest view was let go


@pytest.fixture(scope="module")
def mirror():
    scene = mirror_scene(12)
    return scene, target_of(scene)


def test_a_kept_ray_tree_serves_new_coefficient_starts_but_not_a_new_tree_shape(mirror):
    """The tree's shape follows kr (a reflected child exists where kr > 0): another kr start is
    recorded anew; another ka / kd / ks / n start reads the kept tree."""
    scene, target = mirror
    compiled = compile_scene(scene)
    params = ("ka", "kd", "ks", "n", "kr")
    fit(compiled, [target], params=params, init=START)
    again = fit(compiled, [target], params=params, init=OTHER_START)
    assert again.model == "raytrace" and again.timings["render"] == 0.0
    assert_same(again, fit(scene, [target], params=params, init=OTHER_START))
    new_kr = fit(compiled, [target], params=params, init={**START, "kr": 0.3})
    assert new_kr.timings["render"] > 0 and kept_views(compiled) == 2
    assert_same(new_kr, fit(scene, [target], params=params, init={**START, "kr": 0.3}))


@pytest.mark.parametrize("compiled", [False, True])
def test_a_setup_reweighted_keeps_its_pixels_and_fits_as_a_setup_built_afresh(compiled):
    """The refit without clipped pixels (`engine.fit`) reweights its setup instead of preparing the
    targets again: its pixels stay (weight 0 where left out), so the problem keeps its shapes and
    every refit of the view runs one compiled solve; its fit is the one a `Setup` built afresh with
    those weights makes (the left-out pixels dropped)."""
    from difflab.fit.engine import solve
    from difflab.fit.lm import solve_box
    from difflab.fit.setup import Setup

    scene = compile_scene(SCENE) if compiled else SCENE
    noisy = np.maximum(TARGET + np.random.default_rng(2).normal(0.0, 0.02, TARGET.shape), 0.0)
    first = Setup(scene, [noisy], "red", init=START)

    def some_left_out(seed):
        return [first.views[0].weight * (np.random.default_rng(seed).random(TARGET.shape[:2]) > 0.3)[..., None]]

    assert first.weight_total == 3 * first.used_pixels  # (its statistics formed: the reweighted copy forms its own)
    again = first.reweighted(some_left_out(0), OTHER_START)
    fresh = Setup(scene, [noisy], "red", weights=some_left_out(0), init=OTHER_START)
    np.testing.assert_array_equal(again.views[0].pixels, first.views[0].pixels)
    assert again.views[0].pixels.size > fresh.views[0].pixels.size
    np.testing.assert_array_equal(again.x0, fresh.x0)
    assert (again.censored, again.weight_total, again.views[0].ceiling, again.render_seconds) == \
        (fresh.censored, fresh.weight_total, fresh.views[0].ceiling, 0.0)
    a, b = solve(again), solve(fresh)
    assert (a.result, a.steps, a.at_bound, a.censored) == (b.result, b.steps, b.at_bound, b.censored)
    for key in b.params:  # (to the solver's rtol 1e-8: the steps' J^T J is summed over other rows)
        np.testing.assert_allclose(a.params[key], b.params[key], rtol=1e-7)
        np.testing.assert_allclose(a.stderr[key], b.stderr[key], rtol=1e-6)
    np.testing.assert_allclose([a.loss, a.sigma, a.chi2, a.psnr], [b.loss, b.sigma, b.chi2, b.psnr], rtol=1e-7)
    np.testing.assert_allclose(a.residuals[0], b.residuals[0], atol=1e-6)
    compiled_solves = solve_box._cache_size()
    other = solve(first.reweighted(some_left_out(1), START))  # other pixels left out: the same compiled solve
    assert other.converged and solve_box._cache_size() == compiled_solves


def test_device_copies_are_reused_only_for_an_equal_key():
    """`DeviceCopies.kept`: for a key equal to one kept, the device copies made before (its arrays not
    formed again); for another key, the arrays formed and moved afresh with their values."""
    store = DeviceCopies()
    formed = []

    def host(lights):
        formed.append(lights)
        return {"lights": np.array(lights), "index": np.array([0, -1], np.int32)}

    with jax.enable_x64(True):
        first = store.kept(("lights", [0.5, 0.25, 1.0]), lambda: host([0.5, 0.25, 1.0]))
        again = store.kept(("lights", [0.5, 0.25, 1.0]), lambda: host([0.5, 0.25, 1.0]))
        assert again is first and len(formed) == 1
        other = store.kept(("lights", [0.5, 0.25, 1.5]), lambda: host([0.5, 0.25, 1.5]))
        assert other["lights"] is not first["lights"] and len(formed) == 2
        np.testing.assert_array_equal(other["lights"], [0.5, 0.25, 1.5])
        assert other["lights"].dtype == np.float64 and other["index"].dtype == np.int32


def test_the_device_copies_used_last_are_kept():
    """`DeviceCopies` lets go of the set used longest ago: one set used between every other keeps
    its copies (it was let go as the oldest moved, KEPT_ARRAYS new sets after it was first moved)."""
    store = DeviceCopies()
    with jax.enable_x64(True):
        often = store.kept("often", lambda: np.array([0.5, 0.25, 1.0]))
        for k in range(2 * KEPT_ARRAYS):
            store.kept(k, lambda: np.array([float(k), 0.0, 0.0]))
            assert store.kept("often", lambda: np.array([0.5, 0.25, 1.0])) is often


def test_small_device_arrays_are_kept_process_wide():
    """The first fit of a view, of a compiled or a plain scene, takes the device copies of the small
    arrays (material table, lights, ambient) that an earlier fit with the same values moved; other
    values are moved afresh."""
    compiled = compile_scene(SCENE)
    first = Setup(compiled, [TARGET], "red", x64=True).problem
    compiled.built.pop(STORE)  # no view kept
    for scene in (compiled, SCENE):
        again = Setup(scene, [TARGET], "red", x64=True).problem
        assert again.table.kd is first.table.kd and again.ambient is first.ambient
        assert again.views[0].lights.position is first.views[0].lights.position
    other = Setup(SCENE, [TARGET], "red", init={"kd": [0.25, 0.5, 0.75]}, x64=True).problem
    assert other.table.kd is not first.table.kd
    single = Setup(SCENE, [TARGET], "red", x64=False).problem  # the same values in float32: moved afresh
    assert single.table.kd.dtype == np.float32 and single.ambient.dtype == np.float32
    np.testing.assert_array_equal(single.table.kd, np.asarray(first.table.kd, np.float32))
    red = SCENE.material_index("red")
    expected = np.array(first.table.kd)
    expected[red] = [0.25, 0.5, 0.75]
    np.testing.assert_array_equal(other.table.kd, expected)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_used_rows_are_the_pixels_rows_on_a_64_byte_boundary(dtype):
    """`records.used_rows` (a boolean selection of whole pixels) gives `take_pixels`' rows at the
    used pixels, of a strided image too, in the dtype asked for, each on a 64-byte boundary (moved
    to the device in place)."""
    rng = np.random.default_rng(4)
    image = rng.normal(size=(9, 14, 4)).astype(dtype)[:, 1::2, :3]  # (9, 7, 3), not contiguous
    for used in (rng.random((9, 7)) > 0.4, np.zeros((9, 7), bool), np.ones((9, 7), bool)):
        for out_dtype in (None, np.float64):
            rows = used_rows(image, used, out_dtype)
            expected = take_pixels(np.ascontiguousarray(image), np.flatnonzero(used), out_dtype)
            assert rows.dtype == expected.dtype and rows.shape == (np.count_nonzero(used), 3)
            np.testing.assert_array_equal(rows, expected)
            assert rows.size == 0 or rows.ctypes.data % 64 == 0


@pytest.mark.parametrize("size", [16, 112])  # 12 x 16^2 bytes of planes from the heap, 12 x 112^2 in a map
def test_residual_images_are_each_results_own_memory(size):
    """A result's residual images (`Setup.zero_planes`: from the heap, or from a memory map of their
    own once MAPPED_PLANES or more) are model - target at the used pixels, 0 elsewhere, writable,
    shared with no other result, and survive a pickle round trip."""
    import mmap
    import pickle

    from difflab.fit.setup import MAPPED_PLANES

    scene = make_scene(size=size)
    target = target_of(scene)
    noisy = target + np.random.default_rng(1).normal(0, 0.01, target.shape).astype(np.float32)
    first, second = (fit(scene, [image], init=START) for image in (noisy, target))
    planes = memory = first.residuals[0]
    while isinstance(memory, np.ndarray):
        memory = memory.base
    assert (12 * size * size >= MAPPED_PLANES) == isinstance(getattr(memory, "obj", None), mmap.mmap)
    model = Setup(scene, [noisy], "red", init=first.params).render()[0]
    used = planes.any(axis=-1)
    assert used.sum() > 0.3 * size * size and not np.shares_memory(planes, second.residuals[0])
    np.testing.assert_allclose(planes[used], (model - noisy)[used], atol=1e-5)
    assert not planes[~used].any() and planes.flags.writeable
    np.testing.assert_array_equal(pickle.loads(pickle.dumps(planes)), planes)
    planes[:] = 7.0
    assert not (second.residuals[0] == 7.0).any()
