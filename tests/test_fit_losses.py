"""The robust losses of the fits, through the public API: fitting one ambient coefficient to a flat
target with outliers is estimating a location, whose minimiser has a closed form condition,
sum_i psi(t_i - mu) = 0, with psi(r) = clip(r, -c, c) (Huber with scale c: quadratic within c,
linear beyond) and psi(r) = r / (1 + r^2 / c^2) (Cauchy); l2 would give the mean."""

import numpy as np
import pytest

from conftest import scene_dict
from difflab import fit_material

SCALE = 0.05
PSI = {
    "huber": lambda r: np.clip(r, -SCALE, SCALE),
    "cauchy": lambda r: r / (1 + (r / SCALE) ** 2),
}
RHO = {  # the loss of a residual r, whose half-sum is FitResult.loss
    "huber": lambda r: np.where(np.abs(r) <= SCALE, r * r, 2 * SCALE * np.abs(r) - SCALE ** 2),
    "cauchy": lambda r: SCALE ** 2 * np.log1p((r / SCALE) ** 2),
}


def location(t, psi, lo, hi):
    """The root of sum psi(t - mu) = 0 in [lo, hi] by bisection (the sum decreases through it)."""
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if np.sum(psi(t - mid)) > 0 else (lo, mid)
    return 0.5 * (lo + hi)


@pytest.mark.parametrize("loss", ["huber", "cauchy"])  # l2 (the mean) is what every other fit test checks
def test_robust_losses_fit_the_closed_form_location(loss):
    """A plane filling an orthographic 16x16 view, lit only by ambient 1, so each pixel is ka: the
    target is 0.3 / 0.5 / 0.7 per channel plus noise, with a fifth of the pixels 0.4 too bright.
    The fitted ka is the location estimate of the loss, within 1e-6, and the
    reported loss is 0.5 sum rho(r) there."""
    rng = np.random.default_rng(3)
    target = np.array([0.3, 0.5, 0.7]) + rng.normal(0, 0.02, (16, 16, 3))
    target[rng.random((16, 16)) < 0.2] += 0.4
    scene = scene_dict([{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1], "material": "m"}],
                       {"m": {"ka": [0.2, 0.2, 0.2], "kd": [0, 0, 0]}}, ambient=(1, 1, 1),
                       camera={"eye": [0, 0, 5], "target": [0, 0, 0], "projection": "orthographic",
                               "ortho_height": 2.0, "width": 16, "height": 16, "near": 0.1, "far": 20})
    result = fit_material(scene, [target.astype(np.float32)], params=("ka",), loss=loss, loss_scale=SCALE)
    assert result.converged, result.result
    t = target.astype(np.float32).astype(np.float64).reshape(-1, 3)
    want = [location(t[:, c], PSI[loss], 0.0, 1.5) for c in range(3)]
    np.testing.assert_allclose(result.params["ka"], want, atol=1e-6)
    r = np.asarray(result.params["ka"]) - t
    assert result.loss == pytest.approx(0.5 * RHO[loss](r).sum(), rel=1e-6)
    mean = t.mean(axis=0)
    assert np.all(np.asarray(result.params["ka"]) < mean - 0.04)  # the outliers pull the mean up by ~0.08
