"""What a fit says about its inputs beyond the verdict (review of foreign targets, defects 6-9): a
given ceiling that used values exceed is an input error; non-finite values outside the pixels used
are left out (and counted), inside them refused with a hint to mask them; a mismatch beside a lobe
pushed to a degenerate value hints at a local minimum (and `difflab fit --init` gives another
start); coefficients far above 1 suggest code values; `difflab fit --spp / --max-depth`."""

import dataclasses
import json

import numpy as np
import pytest
from test_fit_helpers import TRUTH, make_scene, target_of

from difflab import FitError, fit_material, interior_mask
from difflab.fit import fit_batch
from difflab.cli import main
from difflab.fit.hints import SCALE_HINT
from difflab.io import save_image
from difflab.renderers.api import render_frame
from difflab.scene import save_scene

BRIGHT = [{"type": "point", "position": [3, 4, 3], "intensity": [2, 2, 2], "attenuation": [1, 0, 0]}]


def cli(argv) -> int:
    try:
        return main(argv)
    except SystemExit as exc:  # argparse's errors
        return exc.code


def files(tmp_path, scene, target, name="t.npy"):
    save_image(tmp_path / name, target)
    return [str(save_scene(scene, tmp_path / "scene.json")), str(tmp_path / name)]


def red_pixels(scene) -> np.ndarray:
    return render_frame(scene).gbuffer.material == scene.material_names.index("red")


def test_a_given_ceiling_below_used_values_is_an_input_error(tmp_path, capsys):
    """Unclipped floats with ceiling=1 were fitted (exact values) and reported MODEL MISMATCH, chi2 7e5."""
    scene = make_scene(size=16, lights=BRIGHT)
    target = target_of(scene)
    used = target[red_pixels(scene)]
    above = int(np.count_nonzero(used > 1.0))
    assert above > 3
    message = (f"ceiling: 1 is below {above} used values of targets[0] (largest {used.max():.3g}); a ceiling is the "
               "value the target saturates at -- give that value, or ceiling=False where the target does not clip")
    with pytest.raises(FitError) as info:
        fit_material(scene, [target], "red", ceiling=1.0)
    assert str(info.value) == message
    argv = files(tmp_path, scene, target)
    assert cli(["fit", *argv, "--material", "red", "--ceiling", "1", "-o", str(tmp_path / "o.json")]) == 2
    assert capsys.readouterr().err.strip() == "difflab: error: --" + message.replace(
        "targets[0]", f"targets[0] ({argv[1]})").replace("ceiling=False", "--ceiling none")
    assert not (tmp_path / "o.json").exists()
    with pytest.raises(FitError, match=rf"^ceiling: 1 is below {above} used values of images\[1\] \(largest"):
        fit_batch(scene, [np.minimum(target, 1.0), target], "red", ceiling=1.0)  # (a batch's ceiling is every image's)
    # a float32 clip at the ceiling given (0.8 rounds to 0.80000001) is at it: censored, not refused
    clipped = np.minimum(target, np.float32(0.8))
    fitted = fit_material(scene, [clipped], "red", ceiling=0.8)
    assert fitted.censored == np.count_nonzero(clipped[red_pixels(scene)] == np.float32(0.8)) > 3
    np.testing.assert_allclose(fitted.params["ks"], TRUTH["ks"], rtol=1e-2)  # (issue 10's 1 % for clipped highlights)
    np.testing.assert_allclose(fitted.params["n"], TRUTH["n"], rtol=1e-2)


def test_nonfinite_values_outside_the_used_pixels_are_left_out(tmp_path, capsys):
    """A NaN background (a masked EXR's) refused the fit: nonfinite_target, exit 2. (inf beside -inf
    there: the noise estimate's stencils must not read them -- a RuntimeWarning, an error here.)"""
    scene = make_scene(size=16)
    red = red_pixels(scene)
    background = np.resize(np.array([np.nan, np.inf, -np.inf], np.float32), red.shape)[..., None]  # pixel by pixel
    target = np.where(red[..., None], target_of(scene), background)
    result = fit_material(scene, [target], "red")
    left_out = 3 * int(np.count_nonzero(~red))
    assert result.ok and result.nonfinite_left_out == left_out and result.to_dict()["nonfinite_left_out"] == left_out
    for key, value in TRUTH.items():
        np.testing.assert_allclose(result.params[key], value, rtol=1e-4)
    line = f"non-finite target values left out: {left_out} (none at a pixel the fit uses)"
    assert result.notes == [line] and result.to_dict()["notes"] == [line]
    assert cli(["fit", *files(tmp_path, scene, target), "--material", "red", "-o", str(tmp_path / "o.json")]) == 0
    assert line in capsys.readouterr().out.splitlines()
    assert json.loads((tmp_path / "o.fit.json").read_text())["nonfinite_left_out"] == left_out


def test_nonfinite_values_at_used_pixels_are_refused_with_a_mask_hint_where_the_material_is_not_shown():
    scene = make_scene(size=16)
    target = target_of(scene)
    red = red_pixels(scene)
    one = target.copy()
    one[np.argwhere(red)[0][0], np.argwhere(red)[0][1], 1] = np.inf
    refused = fit_material(scene, [one], "red")
    assert refused.no_fit() == ("nonfinite_target: targets[0] holds 1 non-finite value (0 NaN, 1 inf) in 1 pixel the "
                                "fit uses")
    # fitting the light's intensity reads every lit surface: NaN on the floor is used, but shows no red
    target[~red] = np.nan
    on_floor = int(np.count_nonzero(render_frame(scene).gbuffer.material == scene.material_names.index("floor")))
    refused = fit_material(scene, [target], "red", ("kd", "intensity"))
    assert refused.no_fit() == (f"nonfinite_target: targets[0] holds {3 * on_floor} non-finite values ({3 * on_floor} "
                                f"NaN, 0 inf) in {on_floor} pixels the fit uses -- none of them shows material red: "
                                "leave them out with a mask (masks= / --mask)")
    masked = fit_material(scene, [target], "red", ("kd", "intensity"), masks=[red])
    assert masked.converged and masked.nonfinite_left_out == 3 * int(np.count_nonzero(~red))


HINT = (" -- or the fit may sit in a local minimum (ks, n at a degenerate value: the highlight gone, its width "
        "undetermined or at its bound): retry from another start (init= / --init)")
MISMATCH = "MODEL MISMATCH: the image model does not explain the targets; the standard errors assume it does"


def test_a_mismatch_beside_a_vanished_highlight_hints_at_a_local_minimum(tmp_path, capsys):
    """A tight highlight (n = 200) started at n = 1000: ks -> 0, n at its bound +- inf, and the text
    said only that the image model cannot explain the targets (it can: from n = 3000 it is exact)."""
    truth = make_scene(size=32, red={"ks": [0.6] * 3, "n": 200.0})
    target = target_of(truth)
    start = {"ka": 0.05, "kd": 0.5, "ks": 0.1}
    stuck = fit_material(truth, [target], "red", init={**start, "n": 1000.0})
    assert stuck.model_mismatch and np.max(stuck.params["ks"]) < 1e-6 and not np.isfinite(stuck.stderr["n"])
    assert MISMATCH + HINT in stuck.table().splitlines()
    good = fit_material(truth, [target], "red", init={**start, "n": 3000.0})
    np.testing.assert_allclose(good.params["n"], 200.0, rtol=1e-4)
    assert MISMATCH in dataclasses.replace(good, model_mismatch=True).table().splitlines()  # n determined: no hint
    assert HINT not in dataclasses.replace(stuck, model_mismatch=False).table()  # no mismatch: no hint
    unformed = {key: np.full(np.shape(value), np.nan).tolist() for key, value in stuck.stderr.items()}  # a nonfinite fit
    assert MISMATCH in dataclasses.replace(stuck, stderr=unformed, degenerate=[], at_bound=[]).table().splitlines()
    inits = [arg for key, value in {**start, "n": 1000}.items() for arg in ("--init", f"{key}={value}")]
    argv = [*files(tmp_path, truth, target), "--material", "red", "-o", str(tmp_path / "o.json")]
    assert cli(["fit", *argv, *inits]) == 4
    assert MISMATCH + HINT in capsys.readouterr().out.splitlines()
    assert json.loads((tmp_path / "o.fit.json").read_text())["initial"]["n"] == 1000.0
    assert cli(["fit", *argv, "--force", "--init", "q=1"]) == 2
    assert capsys.readouterr().err.strip() == ("difflab: error: --init q: expected 'kind' (one fitted material), "
                                               "'material.kind' or 'lights[i].intensity'; fitted materials: red")
    assert cli(["fit", *argv, "--force", "--init", "n"]) == 2
    assert "'n': give NAME=VALUE" in capsys.readouterr().err


def test_coefficients_far_above_1_suggest_code_values(tmp_path, capsys):
    """A target read in code values (x 255) gave kd = 178 without a word."""
    scene = make_scene(size=16)
    target = target_of(scene)
    codes = fit_material(scene, [target * 255], "red")
    largest = {k: max(codes.params[k]) for k in ("ka", "kd", "ks")}
    assert [round(v, 2) for v in largest.values()] == [25.5, 178.5, 127.5]  # 255 x the truth's
    assert codes.notes == [", ".join(f"{k} = {v:.5g}" for k, v in largest.items()) + ": coefficients far above 1 -- "
                           "is the target in code values (0-255 / 0-65535) rather than linear floats in [0, 1]?"]
    np.testing.assert_allclose(codes.params["kd"], np.multiply(TRUTH["kd"], 255), rtol=1e-4)
    scaled = fit_material(scene, [target * 16], "red")  # ka 1.6, kd 11.2, ks 8: only kd above SCALE_HINT
    assert scaled.notes == [f"kd = {max(scaled.params['kd']):.5g}: coefficients far above 1 -- is the target in code "
                            "values (0-255 / 0-65535) rather than linear floats in [0, 1]?"]
    assert max(scaled.params["ks"]) < SCALE_HINT < max(scaled.params["kd"])
    assert fit_material(scene, [target], "red").notes == []
    assert cli(["fit", *files(tmp_path, scene, target * 255), "--material", "red", "-o", str(tmp_path / "o.json")]) == 0
    assert codes.notes[0] in capsys.readouterr().out.splitlines()


def test_fit_command_spp_and_max_depth_as_the_api(tmp_path, capsys):
    """`difflab fit` had no --spp: the scene file had to be edited to emulate an anti-aliased target."""
    scene = make_scene(size=16)
    target = target_of(make_scene(size=16, spp=4))
    argv = [*files(tmp_path, scene, target), "--material", "red", "-o", str(tmp_path / "o.json")]
    assert cli(["fit", *argv, "--spp", "4"]) == 0
    report = json.loads((tmp_path / "o.fit.json").read_text())
    api = fit_material(scene, [target], "red", spp=4)
    for key, value in api.params.items():
        np.testing.assert_allclose(report["params"][key], value, rtol=1e-9)
    np.testing.assert_allclose(api.params["kd"], TRUTH["kd"], rtol=1e-4)
    for extra, error in ((["--spp", "3"], "--spp: must be a perfect square (1, 4, 9, 16, ...): both renderers take a "
                                          "side x side pattern of samples per pixel, got 3"),
                         (["--spp", "0"], "--spp: must be >= 1, got 0"),
                         (["--max-depth", "3"], "--max-depth: 3 does not apply to --method raster (the G-buffer has "
                                                "no secondary rays; use --method raytrace)"),
                         (["--method", "raytrace", "--max-depth", "0"], "--max-depth: must be >= 1, got 0")):
        assert cli(["fit", *argv, "--force", *extra]) == 2
        assert capsys.readouterr().err.strip() == "difflab: error: " + error
    # The rasterizer's sphere samples are the ray tracer's exact points and normals: a raster-made
    # target fits as well ray-traced (exit 0, ok), with the API's chi2, inside the silhouettes (the
    # raster Phong sphere's is up to a quarter sample inside the exact one: chi2 1510 with them).
    inside = interior_mask(scene, margin=1, method="raytrace", spp=4)
    traced = fit_material(scene, [target], "red", method="raytrace", max_depth=2, spp=4, masks=[inside])
    assert traced.ok and not traced.model_mismatch
    assert cli(["fit", *argv, "--force", "--method", "raytrace", "--max-depth", "2", "--spp", "4",
                "--edge-margin", "1"]) == 0
    report = json.loads((tmp_path / "o.fit.json").read_text())
    assert report["model"] == "raytrace" and report["chi2"] == pytest.approx(traced.chi2, rel=1e-9)
