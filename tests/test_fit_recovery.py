"""fit_material through the one engine (G-buffer model): recovery of known parameters by every solver,
calibrated standard errors, bounds, diagnostics, failures and bad input."""

import numpy as np
import pytest
from test_fit_helpers import TRUTH, make_scene, perturbed, scene_dict, target_of

from difflab.errors import FitError
from difflab.fit import FitResult, fit_batch, fit_material
from difflab.renderers.api import render_frame
from difflab.scene import Scene

START = perturbed(TRUTH)


def rel_err(result: FitResult, truth: dict) -> float:
    return max(float(np.max(np.abs(np.asarray(result.params[k]) - np.asarray(v)) / np.abs(v))) for k, v in truth.items())


@pytest.fixture(scope="module")
def scene_and_target():
    scene = make_scene(size=32)
    return scene, target_of(scene)


@pytest.mark.parametrize("solver", ["lm", "gauss_newton", "dogleg", "bfgs", "varpro", "adam"])
def test_noise_free_recovery(scene_and_target, solver):
    scene, target = scene_and_target
    result = fit_material(scene, [target], "red", init=START, solver=solver,
                          max_steps=400 if solver in ("bfgs", "adam") else 100)
    assert set(result.params) == set(TRUTH) and set(result.stderr) == set(TRUTH)
    assert result.history and np.isfinite(result.seconds) and result.steps > 0
    if solver == "adam":  # a gradient method: it may use all its steps, but must get there and say so
        assert result.converged == (result.result == "successful")
        assert result.result in ("successful", "nonlinear_max_steps_reached")
    else:
        assert result.converged, result.result
    assert rel_err(result, TRUTH) < 1e-4
    assert result.model == "raster" and not result.model_mismatch and result.at_bound == []
    if solver == "lm":
        assert result.steps <= 10
        assert result.psnr > 80 and result.poorly_determined == []


@pytest.mark.parametrize("options,tol", [({"per_channel": False, "x64": False}, 1e-3), ({"bounded": True}, 1e-4)])
def test_recovery_float32_grey_and_bounded(options, tol):
    scene = make_scene(size=32, red={"ka": 0.1, "kd": 0.5, "ks": 0.3})
    truth = {"ka": [0.1] * 3, "kd": [0.5] * 3, "ks": [0.3] * 3, "n": 24.0}
    result = fit_material(scene, [target_of(scene)], "red", init={"ka": 0.13, "kd": 0.35, "ks": 0.39, "n": 17.0},
                          **options)
    assert result.converged and rel_err(result, truth) < tol


def test_varpro_agrees_with_lm(scene_and_target):
    scene, target = scene_and_target
    noisy = target + np.random.default_rng(3).normal(0, 0.01, target.shape)
    lm = fit_material(scene, [noisy], "red", init=START)
    vp = fit_material(scene, [noisy], "red", init=START, solver="varpro")
    assert lm.converged and vp.converged
    for key in TRUTH:
        np.testing.assert_allclose(vp.params[key], lm.params[key], rtol=1e-5)
    assert vp.loss == pytest.approx(lm.loss, rel=1e-8)


def test_standard_errors_are_calibrated():
    """Over 24 seeded noisy fits (240 fitted values), the fraction of values within 1 and 2 reported
    standard errors of the truth is 68.3 % and 95.4 % within 4 binomial standard deviations: errors
    too large fail this as surely as errors too small. With the noise given, the reduced chi-square
    is 1 within its statistical spread."""
    scene = make_scene(size=20)
    target = target_of(scene)
    rng = np.random.default_rng(7)
    images = np.stack([target + rng.normal(0, 0.02, target.shape) for _ in range(24)])
    results = fit_batch(scene, images, "red", init=START, sigma=0.02)
    z = []
    for result in results:
        assert result.converged and not result.model_mismatch
        for key, truth in TRUTH.items():
            z.extend(np.ravel(np.abs(np.asarray(result.params[key]) - truth) / np.asarray(result.stderr[key])))
    z = np.asarray(z)
    for k, p in ((1, 0.6827), (2, 0.9545)):
        tolerance = 4 * np.sqrt(p * (1 - p) / z.size)
        assert abs(np.mean(z <= k) - p) < tolerance, (k, np.mean(z <= k))
    chi2 = np.array([r.chi2 for r in results])
    dof = 3 * int(results[0].residuals[0].any(axis=-1).sum()) - 10
    assert abs(chi2.mean() - 1.0) < 4 * np.sqrt(2.0 / dof / len(results))


def test_matte_target_puts_ks_on_its_bound_in_a_few_steps():
    """No highlight (ks = 0): ks lands on its bound 0 within 25 steps, reported in at_bound; ks and n
    are flagged poorly determined (n has no effect at ks = 0), kd is recovered -- and n, switched off
    by ks = 0 rather than unseen, is not `unreached`: the matte fit is settled (ok)."""
    scene = make_scene(size=24, red={"ks": [0.0, 0.0, 0.0]})
    result = fit_material(scene, [target_of(scene)], "red", init={"ks": [0.2, 0.2, 0.2], "n": 10.0})
    assert result.converged and result.steps <= 25
    assert max(result.params["ks"]) <= 1e-8 and "ks" in result.at_bound
    assert "ks" in result.poorly_determined and "n" in result.poorly_determined
    assert "kd" not in result.poorly_determined
    assert result.unreached == [] and not result.underdetermined and result.ok
    np.testing.assert_allclose(result.params["kd"], TRUTH["kd"], rtol=1e-6)


def test_multi_view_multi_light_and_materials():
    """Two views (the second with its own camera and its own lights), two materials at once."""
    scene = make_scene(size=16)
    other = {"camera": {"eye": [3, 2, 3], "target": [0, 0.6, 0], "fov_y": 40, "width": 16, "height": 16},
             "lights": [{"type": "directional", "direction": [1, -1, -1], "intensity": [0.8, 0.8, 0.8]},
                        {"type": "point", "position": [-2, 3, 2], "intensity": [0.5, 0.5, 0.5]}]}
    views = [target_of(scene), (target_of(scene.with_overrides(**other)), other)]
    result = fit_material(scene, views, ["red", "floor"], ("red.ka", "red.kd", "red.ks", "red.n", "floor.kd"),
                          init={"red.kd": [0.5, 0.3, 0.15], "red.n": 18.0, "floor.kd": [0.6, 0.9, 0.7]})
    assert result.converged
    assert rel_err(result, {"red.kd": TRUTH["kd"], "red.n": TRUTH["n"], "floor.kd": [0.8] * 3}) < 1e-4
    fitted = result.to_scene()
    assert np.allclose(fitted.materials["red"].kd, TRUTH["kd"], rtol=1e-4)
    assert fitted.materials["floor"].checker == scene.materials["floor"].checker


def test_light_intensity():
    scene = make_scene(size=16)
    target = target_of(scene.with_overrides(lights=[{"type": "point", "position": [3, 4, 3],
                                                     "intensity": [0.9, 0.6, 0.3]}]))
    result = fit_material(scene, [target], "red", ("lights[0].intensity",))
    assert result.converged
    np.testing.assert_allclose(result.params["lights[0].intensity"], [0.9, 0.6, 0.3], rtol=1e-4)
    assert result.to_scene().lights[0].intensity == pytest.approx((0.9, 0.6, 0.3), rel=1e-4)


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_robust_loss_ignores_outliers(scene_and_target, loss):
    scene, target = scene_and_target
    spoiled = target.copy()
    spoiled[5:8, 10:20] = 5.0  # a glint that the model cannot explain
    l2 = fit_material(scene, [spoiled], "red", init=START)
    robust = fit_material(scene, [spoiled], "red", init=START, loss=loss, loss_scale=0.01)
    assert robust.converged and rel_err(robust, {"kd": TRUTH["kd"]}) < 0.2 * rel_err(l2, {"kd": TRUTH["kd"]})


def test_failures_are_values(scene_and_target):
    scene, target = scene_and_target
    empty = fit_material(scene, [target], "red", masks=[np.zeros(target.shape[:2], bool)])
    assert (empty.converged, empty.result) == (False, "empty_mask")
    nan = target.copy()
    nan[16, 16, 0] = np.nan
    bad = fit_material(scene, [nan], "red")
    assert (bad.converged, bad.result) == (False, "nonfinite_target")
    # a NaN where the mask excludes it is not looked at
    nan = target.copy()
    nan[0, 0] = np.nan
    mask = np.ones(target.shape[:2], bool)
    mask[0, 0] = False
    assert fit_material(scene, [nan], "red", init=START, masks=[mask]).converged
    short = fit_material(scene, [target], "red", init=START, max_steps=2)
    assert (short.converged, short.result, short.steps) == (False, "nonlinear_max_steps_reached", 2)
    for kwargs in ({"masks": [np.zeros(target.shape[:2], bool)]}, {"max_steps": 2}):
        with pytest.raises(FitError):
            fit_material(scene, [target], "red", init=START, throw=True, **kwargs)


@pytest.mark.parametrize("kwargs,message", [
    ({"material": "nope"}, "undefined material"), ({"params": ("kd", "q")}, "unknown parameter"),
    ({"solver": "newton"}, "unknown solver"), ({"loss": "l1"}, "unknown loss"),
    ({"init": {"n": -1.0}}, r"init\['n'\]"), ({"targets": [np.zeros((4, 4, 5))]}, r"expected an \(H, W, 3\) image"),
    ({"targets": [np.zeros((4, 4))]}, r"targets\[0\]: an array of shape \(4, 4\) has 1 colour channel \(grey\)"),
    ({"targets": [(np.zeros((4, 4, 3)), {"fog": {}})]}, "unknown override"),
    ({"params": 5}, "params: expected a name"), ({"params": ["kd", 3]}, "params: expected a name"),
    ({"material": 5}, "material: expected a name"), ({"init": {"kd": "abc"}}, r"init\['kd'\]"),
    ({"init": 3}, "init: expected a dict"), ({"params": ("kr",)}, "needs the ray-traced image model"),
    ({"targets": [np.zeros((32, 32, 3), np.uint8)]}, r"targets\[0\]: integer data \(uint8\) are code values"),
    ({"targets": [np.zeros((32, 32, 3), np.int64)]}, r"targets\[0\]: integer data \(int64\) are code values"),
    ({"targets": [np.zeros((32, 32, 3), complex)]}, r"targets\[0\]: an image of dtype complex128"),
    ({"targets": [np.zeros((20, 30, 3))]}, r"targets\[0\]: the image is 30x20 .* camera renders 32x32"),
    ({"weights": [-np.ones((32, 32))]}, r"weights\[0\]: weights must be finite and >= 0"),
    ({"masks": [np.ones((8, 8), bool)]}, r"masks\[0\]: expected shape"),
    ({"masks": 0}, "masks: expected an array, an image path or a list"),
    ({"masks": ("kd",)}, r"masks\[0\]: .*kd"),
    ({"sigma": -1.0}, "sigma: must be a finite number > 0"), ({"max_steps": 0}, "max_steps"),
    ({"x64": "yes"}, "x64: must be True or False"), ({"tolerance": 1e-3}, r"unknown argument\(s\) \['tolerance'\]"),
    ({"method": "pathtrace"}, "method: expected one of raster, raytrace"),
])
def test_bad_input_raises(scene_and_target, kwargs, message):
    scene, target = scene_and_target
    args = {"targets": [target], "material": "red", **kwargs}
    with pytest.raises(FitError, match=message):
        fit_material(scene, **args)


@pytest.mark.parametrize("vmap", [True, False])
def test_batch(vmap):
    """Per-target results from one compiled solve; a target with NaN under the mask fails alone."""
    scene = make_scene(size=16)
    kds = [[0.6, 0.3, 0.2], [0.3, 0.5, 0.7], [0.9, 0.1, 0.4]]
    images = np.stack([target_of(make_scene(size=16, red={"kd": kd})) for kd in kds])
    images = np.concatenate([images[:1], np.full_like(images[:1], np.nan), images[1:]])
    results = fit_batch(scene, images, "red", ("kd", "n"), vmap=vmap, init={"kd": [0.5, 0.5, 0.5], "n": 18.0})
    assert [r.result for r in results] == ["successful", "nonfinite_target", "successful", "successful"]
    for r, kd in zip(results[:1] + results[2:], kds):
        np.testing.assert_allclose(r.params["kd"], kd, rtol=1e-4)


def test_batch_targets_are_decoded_once_and_kept():
    """A batch element's target is decoded by `load_target` (a private copy, in its own precision) and
    kept by `Setup.retarget` as it is -- not copied again to float64 -- and checked against the view's
    size without forming the first view's whole float64 `target`, which a fit does not read. The
    loop's results are the single fits' exactly."""
    from difflab.fit.batch import _decoded
    from difflab.fit.setup import Setup

    scene, start = make_scene(size=16), {"kd": [0.5, 0.5, 0.5]}
    images = np.stack([target_of(make_scene(size=16, red={"kd": kd})) for kd in ([0.6, 0.3, 0.2], [0.3, 0.5, 0.7])])
    images = images.astype(np.float32)
    setup = Setup(scene, [images[0]], "red", ("kd",), init=start)
    decoded = _decoded(images[1], setup, 1)
    assert decoded.dtype == np.float32 and not np.shares_memory(decoded, images[1])
    assert setup.retarget([decoded]).views[0].image is decoded and "target" not in setup.views[0].__dict__
    batch = fit_batch(scene, images, "red", ("kd",), vmap=False, init=start)
    for image, result in zip(images, batch):
        single = fit_material(scene, [image], "red", ("kd",), init=start)
        assert result.params == single.params and result.stderr == single.stderr and result.chi2 == single.chi2


def test_a_textured_material_goes_through_the_ray_tree(tmp_path):
    """The G-buffer model carries no texture: the scene's choice is the ray tree (which does), and
    forcing the G-buffer is refused with a pointer to what can fit it."""
    from test_fit_helpers import scene_dict

    from difflab import Scene, render, save_image

    save_image(tmp_path / "t.png", np.random.default_rng(0).uniform(0.3, 1.0, (4, 4, 3)))
    d = scene_dict(16)
    d["materials"]["red"].update(texture=str(tmp_path / "t.png"))
    scene = Scene.from_dict(d)
    target = render(scene, method="raytrace")
    result = fit_material(scene, [target], "red", ("kd",), init={"kd": [0.5, 0.3, 0.2]})
    assert result.model == "raytrace" and result.converged
    np.testing.assert_allclose(result.params["kd"], TRUTH["kd"], rtol=1e-4)
    with pytest.raises(FitError, match="add .texture. to params"):
        fit_material(scene, [target], "red", method="raster")


def test_a_correct_model_of_a_high_contrast_texture_with_noise_that_grows_with_the_signal_is_ok():
    """The sphere over a checker floor of kd 0.9 / 0.05 (48 x 48), noise 3 % of the signal, fitted
    with the right model (kd, ks, n of both): ok, chi2 0.97-1.02 over seeds 0-2 (the noise levels
    by the target's intensity). With 8 x 8 spatial blocks' levels it read 1.15-1.26: 2 of 3
    `mismatch_suspected` (64 x 64: 20 of 20 at chi2 1.38)."""
    d = scene_dict(size=48)
    d["materials"]["floor"] = {"kd": [0.9] * 3, "checker": {"size": 0.5, "ka2": [0, 0, 0], "kd2": [0.05] * 3}}
    d["camera"]["eye"] = [0, 3, 4]
    scene = Scene.from_dict(d)
    clean = render_frame(scene).image.astype(np.float64)
    for seed in range(3):
        noisy = clean * (1.0 + 0.03 * np.random.default_rng(seed).normal(size=clean.shape))
        result = fit_material(scene, [noisy.astype(np.float32)], ["red", "floor"], ("kd", "ks", "n"))
        assert result.ok and not result.mismatch_suspected and abs(result.chi2 - 1.0) < 0.05, (seed, result.chi2)


def test_unlit_pixels_leave_the_noise_estimate_and_the_chi_square():
    """A sphere lit from the side without ambient light: 52 % of its pixels are exactly 0 in the
    target and in the fitted model. A renderer's noise scales with its signal, so they carry none:
    Gaussian noise of sigma 0.01 on the lit pixels only. The noise estimate reads the lit pixels (over
    every used pixel the unlit half's zero Laplacians pull the mean square down: sigma ~0.7x, the
    correct fit's chi2 ~2) and the chi-square counts only the lit entries: its sum of squares over
    dof estimates 0.01^2 within 5 standard deviations (counting the unlit entries too gives ~0.48).
    With noise proportional to the signal (5 %), sigma is the lit pixels' rms noise within 20 % and the
    fit is not flagged: the estimate reads only the pixels with lit neighbours, not the brightest
    (noisiest) limb, so it runs up to 17 % low on these 443 pixels (0.83-1.05 of it, chi2 0.95-1.52
    over 6 seeds: ok, the threshold of so few values being wide). (The noise levels binned by the
    target's intensity: 5 bins a channel here; in one, the limb's noise was capped away: chi2 1.9-2.4,
    5 of 6 flagged model_mismatch.)"""
    from difflab.fit.noise import estimate_sigma

    side = {"type": "point", "position": [-4, 1.5, 1], "intensity": [1, 1, 1], "attenuation": [1, 0, 0]}
    d = scene_dict(size=48, red={"ka": [0.0] * 3, "ks": [0.0] * 3}, lights=[side])
    d["ambient"], d["background"], d["objects"] = [0, 0, 0], [0, 0, 0], d["objects"][:1]
    scene = Scene.from_dict(d)
    frame = render_frame(scene)
    clean, mask = frame.image.astype(np.float64), frame.gbuffer.material == 0
    lit = mask & (clean > 0).any(axis=-1)
    assert (mask & ~lit).sum() > 0.5 * mask.sum()
    rng = np.random.default_rng(0)
    fit = lambda noisy: fit_material(scene, [noisy], "red", ("kd",), masks=[mask], init={"kd": [0.5] * 3})  # noqa: E731
    result = fit(clean + 0.01 * (clean > 0) * rng.normal(size=clean.shape))
    assert result.converged and not result.model_mismatch
    assert abs(result.sigma - 0.01) < 0.0015
    assert estimate_sigma(result.residuals, [mask])[0] < 0.75 * result.sigma  # the unlit pixels counted: too low
    dof = 3 * int(lit.sum()) - 3
    assert abs(result.chi2 * result.sigma ** 2 / 0.01 ** 2 - 1.0) < 5 * np.sqrt(2.0 / dof)
    proportional = fit(clean * (1.0 + 0.05 * rng.normal(size=clean.shape)))
    rms_noise = float(np.sqrt(np.mean(np.square(0.05 * clean[lit]))))
    assert proportional.converged and abs(proportional.sigma / rms_noise - 1.0) < 0.2
    assert not proportional.model_mismatch and proportional.chi2 < 2.0
