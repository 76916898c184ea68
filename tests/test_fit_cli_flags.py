"""`difflab fit` flags through the real `difflab.cli.main`, on a fit whose answer is known in closed
form: one ambient coefficient under ambient light 1, so every pixel of the plane is ka and fitting
ka is estimating a location (see test_fit_losses.py)."""

import json

import numpy as np
import pytest

from conftest import scene_dict
from difflab.cli import main
from difflab.io import save_image

SCALE = 0.05  # the fit's default loss_scale


def huber_location(t, lo=0.0, hi=1.5):
    """The root of sum clip(t - mu, -c, c) = 0 by bisection."""
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if np.sum(np.clip(t - mid, -SCALE, SCALE)) > 0 else (lo, mid)
    return 0.5 * (lo + hi)


@pytest.fixture()
def files(tmp_path):
    """scene.json (plane filling a 16x16 orthographic view, ambient only), target.npy whose left half
    is garbage and whose right half is 0.3 / 0.5 / 0.7 + noise with a fifth of its pixels 0.4 too
    bright, and mask.png (white: the right half counts)."""
    rng = np.random.default_rng(8)
    target = np.array([0.3, 0.5, 0.7]) + rng.normal(0, 0.02, (16, 16, 3))
    target[rng.random((16, 16)) < 0.2] += 0.4
    target[:, :8] = rng.uniform(0.8, 1.0, (16, 8, 3))
    save_image(tmp_path / "target.npy", target.astype(np.float32))
    mask = np.zeros((16, 16, 3), np.float32)
    mask[:, 8:] = 1.0
    save_image(tmp_path / "mask.png", mask)
    d = scene_dict([{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1], "material": "m"}],
                   {"m": {"ka": [0.2, 0.2, 0.2], "kd": [0, 0, 0]}}, ambient=(1, 1, 1),
                   camera={"eye": [0, 0, 5], "target": [0, 0, 0], "projection": "orthographic",
                           "ortho_height": 2.0, "width": 16, "height": 16, "near": 0.1, "far": 20})
    (tmp_path / "scene.json").write_text(json.dumps(d))
    right = target.astype(np.float32).astype(np.float64)[:, 8:].reshape(-1, 3)
    return tmp_path, right


def test_mask_report_loss_solver_and_float32_flags(files):
    """--mask drops the garbage half, --loss huber ignores the outliers (the Huber location of the
    right half, not its mean), --report writes where it is told, --solver is the one used, and
    --float32 computes in float32 (every fitted value is a float32 number)."""
    tmp, right = files
    argv = ["fit", str(tmp / "scene.json"), str(tmp / "target.npy"), "--material", "m", "--params", "ka",
            "--mask", str(tmp / "mask.png"), "--loss", "huber", "--solver", "dogleg", "--float32",
            "--report", str(tmp / "report.json"), "-o", str(tmp / "fitted.json")]
    assert main(argv) in (0, 4)  # converged (4: flagged as model mismatch, which a robust fit may be)
    assert not (tmp / "fitted.fit.json").exists()
    report = json.loads((tmp / "report.json").read_text())
    assert report["converged"] and report["solver"] == "dogleg"
    ka = np.asarray(report["params"]["ka"], np.float64)
    want = [huber_location(right[:, c]) for c in range(3)]
    np.testing.assert_allclose(ka, want, atol=2e-4)  # float32 solve
    assert np.all(ka < right.mean(axis=0) - 0.04)  # not the mean: the loss was Huber
    assert np.all(ka.astype(np.float32).astype(np.float64) == ka)  # float32 values
    r = np.abs(ka - right)  # the reported loss is 0.5 sum of Huber's rho over the masked-in pixels
    rho = np.where(r <= SCALE, r * r, 2 * SCALE * r - SCALE ** 2)
    assert report["loss"] == pytest.approx(0.5 * rho.sum(), rel=1e-4)
    fitted = json.loads((tmp / "fitted.json").read_text())
    np.testing.assert_allclose(fitted["materials"]["m"]["ka"], ka, rtol=1e-7)
