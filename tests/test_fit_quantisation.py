"""The rounding of an image file's codes as the fit's noise floor: each used value's own code step in
linear units (`io.code_step`, `fit.noise.quantisation`), against a noise-free render saved as an
8-bit sRGB PNG and fitted back -- the README's teapot, a dark and a bright sphere -- and with a
given sigma added in quadrature. (One 8-bit step / sqrt(12) was taken as linear units for every
value: the README's own `difflab fit` ended "MISMATCH SUSPECTED", chi2 1.34, exit 5.)"""

import json

import numpy as np
import pytest
from test_fit_helpers import TRUTH, perturbed, scene_dict, target_of

from difflab import Scene, example_scene, render
from difflab.cli import main
from difflab.fit import fit_material
from difflab.io import code_step, load_image, save_image, srgb_to_linear
from difflab.scene import save_scene

STEP = 1.0 / 255.0
UNIFORM = STEP / np.sqrt(12.0)  # the old floor: one 8-bit step taken as linear


def test_a_code_step_is_the_decodes_slope_times_the_step():
    """At every inner 8-bit code s: sRGB's step in linear units is the central difference of
    `srgb_to_linear` over one step (1 / 12.92 of the step in the darks, 2.275 times it at white);
    a file gamma g's that of s^(1 / g); gamma 1 the step itself."""
    s = np.arange(1, 255) / 255.0
    h = 1e-6
    central = (srgb_to_linear(s + h) - srgb_to_linear(s - h)) / (2.0 * h) * STEP
    np.testing.assert_allclose(code_step(srgb_to_linear(s), STEP), central, rtol=1e-5)
    assert code_step(0.0, STEP) == pytest.approx(STEP / 12.92)
    assert code_step(1.0, STEP) == pytest.approx(2.4 / 1.055 * STEP)
    g = 1.0 / 2.2
    central = ((s + h) ** 2.2 - (s - h) ** 2.2) / (2 * h) * STEP
    np.testing.assert_allclose(code_step(s ** (1.0 / g), STEP, g), central, rtol=1e-5)
    np.testing.assert_array_equal(code_step(s, 1.0 / 65535, 1.0), np.full(s.shape, 1.0 / 65535))


def test_the_readme_fit_of_an_8_bit_srgb_render_is_ok(tmp_path, capsys):
    """The README's example at 120 x 90: the teapot's red material (seen directly and in the
    mirrors) fitted back through `difflab fit` from its noise-free ray-traced render saved as 8-bit
    sRGB: the residuals are the file's rounding, which the floor now is, so chi2 ~1, ok, exit 0.
    (It read chi2 1.39, sigma at the uniform floor 0.00113, "MISMATCH SUSPECTED", exit 5.)"""
    scene = example_scene("lecture_teapot", width=120, height=90)
    save_image(tmp_path / "target.png", render(scene))
    save_scene(scene, tmp_path / "scene.json")
    out = tmp_path / "fitted.json"
    assert main(["fit", str(tmp_path / "scene.json"), str(tmp_path / "target.png"), "--material", "red",
                 "--params", "ka,kd,ks,n", "-o", str(out)]) == 0
    assert "MISMATCH" not in capsys.readouterr().out
    report = json.loads((tmp_path / "fitted.fit.json").read_text())
    assert report["ok"] and not report["mismatch_suspected"] and abs(report["chi2"] - 1.0) < 0.1


def _sphere(red: dict, ambient: float, light: list, size: int = 32) -> Scene:
    d = scene_dict(size=size, red=red, lights=[{"type": "point", "position": light, "intensity": [1, 1, 1],
                                                "attenuation": [1, 0, 0]}])
    d["ambient"] = [ambient] * 3
    return Scene.from_dict(d)


BRIGHT = {"ka": [0.8, 0.78, 0.76], "kd": [0.17, 0.17, 0.17], "ks": [0.0, 0.0, 0.0], "n": 10.0}  # linear 0.76-0.97
CASES = {  # (scene, params fitted, start): a sphere lit from the camera (every visible point lit: no flat
    # region, whose one rounding error is not a spread of them) in linear 0.76-0.97; the helpers' sphere
    # in linear 0.002-0.1 (light 0.08, ambient 0.05)
    "bright": (lambda: _sphere(BRIGHT, 1.0, [0, 1.2, 4]), ("ka", "kd"), {"ka": [0.7] * 3, "kd": [0.2] * 3}),
    "dark": (lambda: Scene.from_dict({**scene_dict(size=48, lights=[
        {"type": "point", "position": [3, 4, 3], "intensity": [0.08] * 3, "attenuation": [1, 0, 0]}]),
        "ambient": [0.05] * 3}), ("ka", "kd", "ks", "n"), perturbed(TRUTH)),
}


def _rounding_rms(result, path) -> float:
    """The rms rounding error, width / sqrt(12), of the codes the fit's values decode from (over the
    pixels with a residual), each code's interval of samples mapped through `srgb_to_linear`: the
    test's own computation, not `io.code_step`'s slope."""
    used = np.abs(result.residuals[0]).max(axis=-1) > 0
    decoded = load_image(path)[used].reshape(-1, 1)
    codes = np.argmin(np.abs(decoded - srgb_to_linear(np.arange(256) / 255.0)), axis=1)  # the code each decodes from
    h = 0.5 / 255.0  # each code's interval of samples, in linear units
    width = srgb_to_linear(np.minimum(codes / 255.0 + h, 1.0)) - srgb_to_linear(np.maximum(codes / 255.0 - h, 0.0))
    return float(np.sqrt(np.mean(width ** 2) / 12.0))


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_noise_free_8_bit_render_is_at_its_rounding(tmp_path, case):
    """A noise-free render saved as 8-bit sRGB and fitted back with the right model: sigma is the
    rounding's rms at the values used -- over 2x the uniform floor for the bright sphere, under half
    of it for the dark one -- and chi2 ~1 (the mean of r^2 over the mean of q^2; uniform rounding
    errors spread it sqrt(0.8 / N), 0.026 over the bright sphere's ~1200 entries). (The uniform
    floor gave the bright sphere sigma 0.00230, chi2 1.09, the dark one 0.00113, chi2 0.04.)"""
    make, params, start = CASES[case]
    scene = make()
    path = save_image(tmp_path / "t.png", target_of(scene))
    result = fit_material(scene, [path], "red", params, init=start)
    expected = _rounding_rms(result, path)
    assert result.ok and result.sigma == pytest.approx(expected, rel=0.03)
    assert (expected > 2.0 * UNIFORM) if case == "bright" else (expected < 0.5 * UNIFORM)
    assert abs(result.chi2 - 1.0) < 0.05


def test_a_given_sigma_adds_to_the_rounding_at_each_value(tmp_path):
    """The bright sphere with noise 0.002 saved as 8-bit sRGB, sigma = 0.002 given: the rounding
    there (~0.0024, 2.1 uniform steps) adds in quadrature, so chi2 ~1 and ok. (With the uniform
    0.00113 added the noise read 0.0023: chi2 ~1.8, a false model mismatch.)"""
    scene = _sphere(BRIGHT, 1.0, [0, 1.2, 4])
    noisy = target_of(scene) + np.random.default_rng(4).normal(0.0, 0.002, (32, 32, 3))
    path = save_image(tmp_path / "t.png", noisy.astype(np.float32))
    result = fit_material(scene, [path], "red", ("ka", "kd"), init={"ka": [0.7] * 3, "kd": [0.2] * 3}, sigma=0.002)
    assert result.ok and abs(result.chi2 - 1.0) < 5.0 * np.sqrt(2.0 / 1200)
    assert 2.0 * UNIFORM < np.sqrt(result.sigma ** 2 - 0.002 ** 2) < 2.3 * UNIFORM
