"""solver="varpro" (variable projection, fit/varpro.py) against "lm": fits with only linear params
(no outer search), targets with a ceiling (8-bit files), several views with weights and masks."""

import numpy as np
import pytest
from test_fit_helpers import TRUTH, make_scene, perturbed, scene_dict, target_of

from difflab.errors import FitError
from difflab.fit import fit_material
from difflab.io import save_image
from difflab.scene import Scene

RTOL = 1e-6
#: Standard errors under unequal noise (an 8-bit file's rounding grows with the value: `fit.sandwich`)
#: weigh J^T J by the squared residuals, which -- unlike their sum at the minimum -- move to first order
#: with the solution: the 8-bit sphere's lm and varpro solutions 1e-7 to 8e-7 apart gave standard errors
#: 3e-6 (kd) to 3.6e-5 (ks, resting on the highlight's few pixels) apart.
STDERR_RTOL = 1e-4


def start(params) -> dict:
    """The fitted params' 30 % perturbed start."""
    return {key: value for key, value in perturbed(TRUTH).items() if key in params}


def assert_same_fit(vp, lm, keys):
    assert vp.converged and lm.converged, (vp.result, lm.result)
    for key in keys:
        np.testing.assert_allclose(vp.params[key], lm.params[key], rtol=RTOL, atol=1e-12)
        np.testing.assert_allclose(vp.stderr[key], lm.stderr[key], rtol=STDERR_RTOL)
    assert vp.loss == pytest.approx(lm.loss, rel=RTOL)
    # chi2 divides by the estimated sigma, whose Laplacians are capped at a local level: a step function of
    # the residuals, so solutions equal to 1e-12 can estimate sigma ~1e-6 apart (measured: 7e-7)
    assert vp.chi2 == pytest.approx(lm.chi2, rel=1e-4)
    assert vp.at_bound == lm.at_bound


@pytest.fixture(scope="module")
def scene_and_noisy():
    scene = make_scene(size=24)
    target = target_of(scene)
    return scene, target + np.random.default_rng(5).normal(0, 0.01, target.shape)


@pytest.mark.parametrize("params", [("kd",), ("ka", "kd")])
def test_linear_params_only_is_the_linear_solve(scene_and_noisy, params):
    """No nonlinear parameter, no outer search: k* is the fit, 0 steps, with the statistics of any
    fit -- lm's solution (float64) to 1e-6."""
    scene, noisy = scene_and_noisy
    lm = fit_material(scene, [noisy], "red", params, init=start(params), x64=True)
    vp = fit_material(scene, [noisy], "red", params, init=start(params), x64=True, solver="varpro")
    assert_same_fit(vp, lm, params)
    assert vp.steps == 0 and vp.result == "successful" and vp.history == []
    assert vp.sigma == pytest.approx(0.01, rel=0.1) and not vp.model_mismatch


def test_a_coefficient_no_pixel_sees_keeps_its_start():
    """Under no ambient light ka reaches no pixel: varpro leaves it at its start, as lm does, both
    listing it poorly determined; kd is fitted."""
    d = scene_dict(size=24)
    d["ambient"] = [0, 0, 0]
    scene = Scene.from_dict(d)
    target = target_of(scene)
    init = {"ka": 0.3, "kd": 0.4}
    lm = fit_material(scene, [target], "red", ("ka", "kd"), init=init, x64=True)
    vp = fit_material(scene, [target], "red", ("ka", "kd"), init=init, x64=True, solver="varpro")
    np.testing.assert_allclose(vp.params["ka"], [0.3] * 3, rtol=1e-12)
    np.testing.assert_allclose(lm.params["ka"], [0.3] * 3, rtol=1e-12)
    np.testing.assert_allclose(vp.params["kd"], TRUTH["kd"], rtol=1e-6)
    np.testing.assert_allclose(vp.params["kd"], lm.params["kd"], rtol=RTOL)
    assert "ka" in vp.poorly_determined and "ka" in lm.poorly_determined


def test_linear_params_only_lands_on_bound():
    """A target whose best green kd is -0.05 (the model's image there: affine in kd) -- the
    unconstrained solve's value -- is fitted with kd green on its bound 0, reported at_bound, as lm
    does; the other channels keep their truth."""
    kd0, kd1 = [0.7, 0.0, 0.1], [0.7, 0.05, 0.1]
    image0, image1 = (target_of(make_scene(size=24, red={"kd": kd})) for kd in (kd0, kd1))
    target = 2.0 * image0 - image1  # the image at kd = [0.7, -0.05, 0.1]
    scene = make_scene(size=24)
    lm = fit_material(scene, [target], "red", ("kd",), init={"kd": 0.3}, x64=True)
    vp = fit_material(scene, [target], "red", ("kd",), init={"kd": 0.3}, x64=True, solver="varpro")
    assert_same_fit(vp, lm, ("kd",))
    assert vp.params["kd"][1] == 0.0 and vp.at_bound == ["kd"]
    np.testing.assert_allclose(np.asarray(vp.params["kd"])[[0, 2]], [0.7, 0.1], rtol=1e-6)


@pytest.mark.parametrize("params", [("kd", "ks", "n"), ("kd",)])
def test_8bit_png_below_its_ceiling_fits_as_lm(tmp_path, params):
    """An 8-bit file has ceiling 1.0; a target none of whose values reaches it (half the render:
    max ~0.6) is solved unclipped, to lm's values."""
    scene = make_scene(size=24)
    image = 0.5 * target_of(scene)
    assert image.max() < 0.7
    path = save_image(tmp_path / "target.png", image)
    lm = fit_material(scene, [path], "red", params, init=start(params), x64=True)
    vp = fit_material(scene, [path], "red", params, init=start(params), x64=True, solver="varpro")
    assert_same_fit(vp, lm, params)
    assert vp.censored == 0


def test_clipped_8bit_png_is_refused_naming_the_clip(tmp_path):
    """A target value at the ceiling (a clipped highlight) is censored, not linear: FitError naming
    the clip and lm, which fits it."""
    scene = make_scene(size=24)
    image = 2.0 * target_of(scene)
    path = save_image(tmp_path / "target.png", image)
    with pytest.raises(FitError, match=r"(\d+) target values reach their ceiling.*solver='lm'") as caught:
        fit_material(scene, [path], "red", ("kd", "ks", "n"), init=start(("kd", "ks", "n")), solver="varpro")
    counted = int(str(caught.value).split(" target values")[0].split()[-1])  # the sphere's (the fitted) pixels
    assert 0 < counted <= np.count_nonzero(image >= 1.0)
    assert fit_material(scene, [path], "red", ("kd", "ks", "n"), init=start(("kd", "ks", "n"))).converged


def test_model_above_an_unreached_ceiling_is_refused():
    """No target value reaches the ceiling, but the fitted model does at a counted pixel (the
    highlight, lowered in the target below the ceiling; kd fitted from the rest): FitError."""
    scene = make_scene(size=24)
    target = target_of(scene)
    ceiling = 0.8 * float(target.max())
    lowered = np.minimum(target, ceiling - 0.01)
    with pytest.raises(FitError, match="model at or above a target's ceiling.*solver='lm'"):
        fit_material(scene, [lowered], "red", ("kd",), ceiling=ceiling, solver="varpro")


def test_views_weights_and_masks_as_lm():
    """Two views (the second from another camera), per-pixel weights on the first and a mask on the
    second: varpro's fit is lm's, for the full params and for the linear ones."""
    scene = Scene.from_dict(scene_dict(size=24))
    other = {"camera": {**scene_dict(size=24)["camera"], "eye": [2.5, 1.5, 3]}}
    rng = np.random.default_rng(9)
    first = target_of(scene)
    second = target_of(Scene.from_dict({**scene_dict(size=24), **other}))
    targets = [first + rng.normal(0, 0.01, first.shape), (second + rng.normal(0, 0.01, second.shape), other)]
    weights = [rng.uniform(0.5, 2.0, (24, 24)), np.ones((24, 24))]
    mask = np.zeros((24, 24), bool)
    mask[:, :14] = True
    masks = [np.ones((24, 24), bool), mask]
    for params in (("ka", "kd", "ks", "n"), ("kd",)):
        kw = dict(init=start(params), weights=weights, masks=masks, x64=True)
        lm = fit_material(scene, targets, "red", params, **kw)
        vp = fit_material(scene, targets, "red", params, solver="varpro", **kw)
        assert_same_fit(vp, lm, params)
