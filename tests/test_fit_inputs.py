"""A fit's inputs as other programs hand them over: integer .npy targets (code values), float
targets with a flat-lit surface at their maximum (not a clip), mask files and arrays (colour,
alpha, stray values), the messages of a fit that cannot be made, parameters of another specular
model, and the fitted scene's file name."""

import json
import re

import numpy as np
import pytest
from PIL import Image
from test_fit_helpers import make_scene, scene_dict, target_of

from difflab import FitError, Scene, fit_material, load_image, render
from difflab.cli import main
from difflab.errors import DifflabError
from difflab.fit.targets import view_mask
from difflab.io import save_image
from difflab.renderers.api import render_frame
from difflab.scene import save_scene

FLOOR = [0.5, 0.4, 0.3]


def cli(argv) -> int:
    """`difflab` run as from a shell: its exit code (argparse's errors exit through SystemExit)."""
    try:
        return main(argv)
    except SystemExit as exc:
        return exc.code


def flat_scene(floor_kd=FLOOR, size=(24, 18)) -> Scene:
    """A floor under a directional light straight down (every lit floor pixel holds the same value,
    the image's maximum, in most of the floor's pixels) and a darker ball; ray traced, no ambient."""
    return Scene.from_dict({
        "camera": {"eye": [0, 3, 6], "target": [0, 0.3, 0], "fov_y": 40, "width": size[0], "height": size[1]},
        "ambient": [0, 0, 0], "lights": [{"type": "directional", "direction": [0, -1, 0]}],
        "materials": {"ball": {"kd": [0.3, 0.2, 0.1]}, "floor": {"kd": floor_kd}},
        "objects": [{"type": "sphere", "center": [0, 0.6, 0], "radius": 0.6, "material": "ball"},
                    {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"}],
        "render": {"method": "raytrace", "shadows": True}})


# ---- integer .npy targets: code values, refused the same way as integer arrays, advice per dtype


@pytest.mark.parametrize("dtype, advice", [(np.uint8, r"image / 255\.0, then difflab\.io\.srgb_to_linear\(\)"),
                                           (np.uint16, r"image / 65535\.0: linear if the source wrote linear")])
def test_an_integer_npy_target_is_refused_like_an_integer_array(tmp_path, dtype, advice):
    """POV-Ray's 16-bit linear PNG read by another reader and saved with np.save was read as linear
    light up to 65535: kd ~ 39320, reported successful (a uint8 one: kd ~ 185)."""
    scene = make_scene(size=12)
    codes = np.round(np.clip(target_of(scene), 0, 1) * np.iinfo(dtype).max).astype(dtype)
    np.save(tmp_path / "codes.npy", codes)
    with pytest.raises(FitError, match=r"^targets\[0\]: .*codes\.npy: integer data \(" + np.dtype(dtype).name
                       + r"\) are code values, not linear light; .*" + advice):
        fit_material(scene, [tmp_path / "codes.npy"], "red", ("kd",))
    with pytest.raises(FitError, match=r"^targets\[0\]: integer data \(" + np.dtype(dtype).name + r"\) .*" + advice):
        fit_material(scene, [codes], "red", ("kd",))
    with pytest.raises(DifflabError, match=r"codes\.npy: integer data .*" + advice):
        load_image(tmp_path / "codes.npy")
    assert main(["fit", str(save_scene(scene, tmp_path / "s.json")), str(tmp_path / "codes.npy"), "--material",
                 "red", "-o", str(tmp_path / "out.json")]) == 2
    assert not (tmp_path / "out.json").exists()
    decoded = codes / np.float32(np.iinfo(dtype).max)  # the advice, followed (the codes are linear here)
    np.save(tmp_path / "linear.npy", decoded)
    np.testing.assert_array_equal(load_image(tmp_path / "linear.npy"), decoded)


# ---- float targets: a flat-lit surface at the maximum is not a clip; ceiling=inf / --ceiling none


def test_a_flat_lit_floor_at_the_maximum_is_not_taken_for_a_clip():
    """The floor's lit pixels all hold kd (0.5 in red, the image maximum): counted over all three
    channels those ties were under half the values, so they were taken for a clipped ceiling --
    every lit pixel censored, kd left at its start 0.9 +- inf. Counted per channel they are most of
    the red channel's values: no ceiling, kd recovered exactly. Under a mask that keeps a few floor
    pixels beside the ball, the ties are under half of each channel's values, yet all of the
    floor's: no clip either (a highlight clips a minority of its surface's pixels)."""
    target = render(flat_scene())
    used = target[..., 0] > 0
    assert np.count_nonzero(target[..., 0] == 0.5) > 0.5 * np.count_nonzero(used)  # most of the floor ties
    start = flat_scene(floor_kd=0.9)
    result = fit_material(start, [target], "floor", ("kd",))
    assert result.ok and result.censored == 0
    np.testing.assert_allclose(result.params["kd"], FLOOR, rtol=1e-5)
    for none in (np.inf, float("inf"), False):  # inf is "no ceiling", as False (it was refused)
        same = fit_material(start, [target], "floor", ("kd",), ceiling=none)
        assert same.censored == 0 and same.params["kd"] == pytest.approx(result.params["kd"], rel=1e-9)
    floor = np.flatnonzero(target[..., 0] == 0.5)[:5]  # a few floor pixels beside the ball's: the floor's ties
    mask = (target[..., 0] > 0) & (target[..., 0] < 0.5)  # are under half of each channel's values, all of
    assert np.count_nonzero(mask) > 2 * floor.size  # the floor's: still no clip
    mask.reshape(-1)[floor] = True
    both = fit_material(start, [target], ["floor", "ball"], ("kd",), masks=[mask], init={"ball.kd": 0.5})
    assert both.converged and both.censored == 0  # (noise unknown: too few pixels to tell)
    np.testing.assert_allclose(both.params["floor.kd"] + both.params["ball.kd"], FLOOR + [0.3, 0.2, 0.1], rtol=1e-5)
    given = fit_material(start, [target], "floor", ("kd",), ceiling=0.5)  # told it clips there: censored
    assert given.censored > 0 and given.params["kd"][0] >= 0.5
    with pytest.raises(FitError, match=r"ceiling: must be a finite number > 0, got -inf"):
        fit_material(start, [target], "floor", ("kd",), ceiling=-np.inf)


def test_a_surface_wholly_at_the_clip_does_not_hide_a_clipped_highlight():
    """A small white bulb (ka 3: every pixel of it clipped) beside the red ball, whose highlight is
    clipped at the same value: the ball's ties are a minority of its pixels -- a clip, censored, ks
    and n recovered. (Any surface with ties at most of its pixels called the whole view unclipped:
    ks 0.045 for 0.5, n 23.6 for 24, chi2 1.7e6.)"""
    from test_fit_helpers import TRUTH, perturbed, scene_dict

    from difflab import Scene

    d = scene_dict(size=32)
    d["materials"]["bulb"] = {"ka": [3.0, 3.0, 3.0], "kd": [0.5, 0.5, 0.5]}
    d["objects"].append({"type": "sphere", "center": [-1.3, 1.6, 0.5], "radius": 0.12, "material": "bulb"})
    scene = Scene.from_dict(d)
    target = render(scene)
    top = float(np.quantile(target[..., 0][target[..., 0] < 0.6], 0.99))  # under the ball's highlight
    clipped = np.minimum(target, top)
    start = {f"red.{k}": v for k, v in perturbed(TRUTH).items() if k != "ka"}
    result = fit_material(scene, [clipped], ["red", "bulb"], ("kd", "ks", "n"), init=start)
    assert result.censored > 0  # the bulb's values and the ball's highlight
    np.testing.assert_allclose(result.params["red.ks"], TRUTH["ks"], rtol=1e-4)
    assert result.params["red.n"] == pytest.approx(TRUTH["n"], rel=1e-4)


def test_a_clipped_highlight_is_still_a_ceiling_and_the_cli_can_say_none(tmp_path, capsys):
    scene = make_scene(size=20, red={"ks": [1.5, 1.5, 1.5], "n": 20.0})
    image = target_of(scene)
    clipped = np.minimum(image, 1.0)
    save_image(tmp_path / "clipped.npy", clipped)
    path = save_scene(scene, tmp_path / "scene.json")
    reports = {}
    for name, extra in (("default", []), ("none", ["--ceiling", "none"]), ("value", ["--ceiling", "1"])):
        out = tmp_path / f"{name}.json"
        code = main(["fit", str(path), str(tmp_path / "clipped.npy"), "--material", "red", "--params", "kd,ks",
                     *extra, "-o", str(out)])
        reports[name] = json.loads(out.with_name(f"{name}.fit.json").read_text())
        assert code in (0, 4), capsys.readouterr()
    censored = int(np.count_nonzero(image >= 1.0))
    assert censored >= 3 and reports["default"]["censored"] == censored == reports["value"]["censored"]
    assert reports["none"]["censored"] == 0
    for bad in ("-1", "0", "nan", "x"):
        assert cli(["fit", str(path), str(tmp_path / "clipped.npy"), "--material", "red", "--ceiling", bad,
                     "-o", str(tmp_path / "bad.json")]) == 2
        assert "--ceiling" in capsys.readouterr().err and not (tmp_path / "bad.json").exists()


# ---- masks: colour (any channel) and alpha; arrays of 0 / 1 only


def test_mask_files_read_colour_and_alpha(tmp_path):
    """In: the brightest colour channel > 0.5 and alpha (if any) > 0.5. Only the red channel was read
    (cyan counted out) and alpha was ignored (transparent white counted in)."""
    rgba = np.zeros((4, 6, 4), np.uint8)
    rgba[..., 3] = 255
    rgba[0] = (0, 255, 255, 255)  # cyan, opaque: in (was out)
    rgba[1] = (255, 255, 255, 0)  # white, transparent: out (was in)
    rgba[2] = (255, 255, 255, 200)  # white, mostly opaque: in
    rgba[3, :3] = (0, 0, 120, 255)  # dark blue: out
    Image.fromarray(rgba).save(tmp_path / "m.png")
    np.testing.assert_array_equal(view_mask(tmp_path / "m.png", (4, 6), "masks[0]"),
                                  np.array([[1] * 6, [0] * 6, [1] * 6, [0] * 6], bool))
    Image.fromarray(rgba[..., :3]).save(tmp_path / "rgb.png")  # without alpha: white is in
    assert view_mask(tmp_path / "rgb.png", (4, 6), "m")[:, 0].tolist() == [True, True, True, False]
    np.save(tmp_path / "m.npy", (rgba > 127).astype(np.uint8))  # a .npy of 0 / 1 (H, W, 4): the same rule
    np.testing.assert_array_equal(view_mask(tmp_path / "m.npy", (4, 6), "m"),
                                  view_mask(tmp_path / "m.png", (4, 6), "m"))


@pytest.mark.parametrize("bad, shown", [(np.nan, "nan"), (-1.0, "-1"), (255.0, "255"), (0.5, "0.5")])
def test_mask_arrays_hold_only_0_and_1(tmp_path, bad, shown):
    """NaN and -1 went through astype(bool) and counted as in."""
    mask = np.ones((4, 6))
    mask[1, 2] = bad
    with pytest.raises(FitError, match=rf"^masks\[0\]: a mask holds bools or only 0 and 1; 1 value is not: {shown}$"):
        view_mask(mask, (4, 6), "masks[0]")
    np.save(tmp_path / "m.npy", mask)
    with pytest.raises(FitError, match=rf"^masks\[1\] \(.*m\.npy\): a mask .* 1 value is not: {shown}$"):
        view_mask(tmp_path / "m.npy", (4, 6), "masks[1]")
    assert view_mask(mask == 1, (4, 6), "m").sum() == 23  # bools as they are


# ---- a fit that cannot be made names the target, the mask and the counts


def test_no_fit_messages_name_the_target_mask_and_counts(tmp_path, capsys):
    scene = make_scene(size=16)
    path = save_scene(scene, tmp_path / "scene.json")
    target = target_of(scene)
    target[2, 3, 1], target[5, 5] = np.nan, np.inf
    save_image(tmp_path / "bad.npy", target)
    assert main(["fit", str(path), str(tmp_path / "bad.npy"), "--material", "red", "-o", str(tmp_path / "o.json")]) == 2
    assert capsys.readouterr().err.strip() == (
        f"difflab: error: no fit made: nonfinite_target: targets[0] ({tmp_path / 'bad.npy'}) holds 4 non-finite "
        "values (1 NaN, 3 inf) in 2 pixels the fit uses")
    background = render_frame(scene).gbuffer.material != scene.material_names.index("red")
    mask = np.zeros((16, 16, 3), np.float32)
    mask[background] = 1.0  # every pixel but the sphere's
    save_image(tmp_path / "mask.png", mask, srgb=False)
    save_image(tmp_path / "good.npy", target_of(scene))
    assert main(["fit", str(path), str(tmp_path / "good.npy"), "--material", "red", "--mask",
                 str(tmp_path / "mask.png"), "-o", str(tmp_path / "o.json")]) == 2
    count = int(np.count_nonzero(background))
    assert capsys.readouterr().err.strip() == (
        f"difflab: error: no fit made: empty_mask: targets[0] ({tmp_path / 'good.npy'}): the mask masks[0] "
        f"({tmp_path / 'mask.png'}) holds {count} pixels, none showing material red")
    result = fit_material(scene, [target_of(scene)], "red", masks=[background])  # the API: the code, and why
    assert result.result == "empty_mask" and result.to_dict()["result"] == "empty_mask"
    assert result.no_fit() == f"empty_mask: targets[0]: the mask masks[0] holds {count} pixels, none showing " \
                              "material red"


# ---- parameters of another specular model; the fitted scene's name


def test_a_parameter_the_specular_model_does_not_read_is_refused(tmp_path, capsys):
    """One rule, both ways: m / f0 on a Phong or Blinn scene came back "0.3 +- inf"; n on a torrance
    scene was fitted though the model never reads it (the image does not depend on it: n moved
    nowhere from its start, +- inf). The defaults (ka, kd, ks, n) read n as the model's lobe width:
    m under torrance, recovered from a perturbed start."""
    for specular in ("phong", "blinn"):
        scene = make_scene(size=8, specular=specular)
        for param in ("m", "f0", "red.m"):
            with pytest.raises(FitError, match=rf"^params: '{param}' applies only to the torrance specular model; the "
                                               rf"scene's is '{specular}' \(its render.specular\), which does not "
                                               "read it"):
                fit_material(scene, [target_of(scene)], "red", ("kd", param))
    scene = make_scene(size=16, specular="torrance", red={"m": 0.3, "f0": 0.2})
    target = target_of(scene)
    for param in ("n", "red.n"):
        with pytest.raises(FitError, match=rf"^params: '{param}' applies only to the phong and blinn specular models; "
                                           r"the scene's is 'torrance' \(its render.specular\), which does not read it"):
            fit_material(scene, [target], "red", ("kd", param))
    path = save_scene(scene, tmp_path / "s.json")
    np.save(tmp_path / "t.npy", target)
    assert cli(["fit", str(path), str(tmp_path / "t.npy"), "--material", "red", "--params", "ks,n",
                "-o", str(tmp_path / "o.json")]) == 2
    assert "params: 'n' applies only to the phong and blinn specular models" in capsys.readouterr().err
    result = fit_material(scene, [target], "red", init={"m": 0.4, "kd": 0.5})
    assert result.converged and set(result.params) == {"ka", "kd", "ks", "m"}
    np.testing.assert_allclose(result.params["m"], 0.3, rtol=1e-4)
    np.testing.assert_allclose(result.params["kd"], [0.7, 0.2, 0.1], rtol=1e-4)
    assert cli(["fit", str(path), str(tmp_path / "t.npy"), "--material", "red", "-o", str(tmp_path / "o.json")]) == 0
    assert json.loads((tmp_path / "o.json").read_text())["materials"]["red"]["m"] == pytest.approx(0.3, rel=1e-4)


def test_the_defaults_with_more_names_keep_reading_n_as_the_lobe_width():
    """DEFAULT_PARAMS + ("intensity",) (either order) is still the defaults: under torrance its "n" is
    m. The old tuple subclass lost that on +: the sum was a plain tuple, its "n" refused under
    torrance ("params: 'n' applies only to the phong and blinn specular models"). A list built
    otherwise is taken as written."""
    from difflab.fit import DEFAULT_PARAMS
    from difflab.fit.params import build_layout

    scene = make_scene(size=8, specular="torrance", red={"m": 0.3})
    for params in (DEFAULT_PARAMS + ("intensity",), ("intensity",) + DEFAULT_PARAMS):
        layout = build_layout(scene, ["red"], params, tree=False)
        assert {p.kind for p in layout} == {"ka", "kd", "ks", "m", "intensity"}
    assert [p.kind for p in build_layout(make_scene(size=8), ["red"], DEFAULT_PARAMS + ("intensity",),
                                         tree=False)][:4] == ["ka", "kd", "ks", "n"]
    with pytest.raises(FitError, match=r"^params: 'n' applies only to the phong and blinn specular models"):
        build_layout(scene, ["red"], [*DEFAULT_PARAMS, "intensity"], tree=False)
    with pytest.raises(TypeError):  # a bare string is not split into letters, as with any tuple
        DEFAULT_PARAMS + "intensity"


def test_fit_output_must_be_json(tmp_path, capsys):
    scene = make_scene(size=8)
    path = save_scene(scene, tmp_path / "scene.json")
    save_image(tmp_path / "t.npy", target_of(scene))
    for flags in (["-o", str(tmp_path / "out.png")],
                  ["-o", str(tmp_path / "o.json"), "--report", str(tmp_path / "r.txt")]):
        assert cli(["fit", str(path), str(tmp_path / "t.npy"), "--material", "red", *flags]) == 2
        err = capsys.readouterr().err
        assert "give a file name ending in .json" in err and ("out.png" in err or "r.txt" in err)
    assert not any(p.name.startswith(("out", "o.", "r.")) for p in tmp_path.iterdir())


def test_one_tied_value_on_a_second_surface_is_no_clip():
    """float_ceiling on a flat-lit floor (100 pixels at 0.8 in red) beside a ball (50 pixels) that
    reaches 0.8 at one pixel: no clip (a single value at the maximum is a peak, not a plateau); with
    CENSOR_MIN_TIES of the ball's pixels there (a minority of it), a clip at 0.8."""
    from difflab.fit.ceiling import CENSOR_MIN_TIES, float_ceiling

    floor = np.tile([0.8, 0.6, 0.4], (100, 1))
    ball = np.tile([0.5, 0.2, 0.1], (50, 1))
    surfaces = np.r_[np.zeros(100, int), np.ones(50, int)]
    ball[0, 0] = 0.8
    assert float_ceiling(np.r_[floor, ball], lambda: surfaces) == np.inf  # (it censored 96 values, 95 the floor's)
    ball[:CENSOR_MIN_TIES, 0] = 0.8
    assert float_ceiling(np.r_[floor, ball], lambda: surfaces) == pytest.approx(0.8)


# ---- grey targets: refused, not fitted as equal R, G, B


def grey_scene() -> Scene:
    """make_scene with a grey ball and background: its image has R = G = B."""
    d = scene_dict(size=12, red={"ka": [0.1] * 3, "kd": [0.5] * 3, "ks": [0.3] * 3})
    d["background"] = [0.05] * 3
    return Scene.from_dict(d)


def test_a_grey_target_is_refused_naming_it_and_the_channel_counts(tmp_path, capsys):
    """A luminance camera's image (Y of the RGB target, a 16-bit grey PNG) was read as equal R, G, B
    and fitted: kd [0.016, 0.038, 0.054] for the truth [0.7, 0.2, 0.1], reported successful. Grey files
    (8-bit L and LA, 16-bit grey, 1-bit, .npy of shape (H, W), (H, W, 1), (H, W, 2)) and grey arrays
    are refused alike, by the API and `difflab fit`; the advice, followed where equal RGB is meant,
    fits. (The message called 16-bit and 1-bit files "PNG L / LA", and a .npy of shape (H, W, 1) or
    (H, W, 2) got a shape error without the advice.)"""
    scene = make_scene(size=12)
    luminance = np.clip(target_of(scene) @ np.array([0.2126, 0.7152, 0.0722], np.float32), 0, 1)
    codes = np.round(luminance * 255).astype(np.uint8)
    Image.fromarray(codes, "L").save(tmp_path / "l.png")
    Image.fromarray(np.stack([codes, np.full_like(codes, 255)], axis=-1), "LA").save(tmp_path / "la.png")
    Image.fromarray(np.round(luminance * 65535).astype(np.uint16)).save(tmp_path / "i16.png")
    Image.fromarray(codes > 127).save(tmp_path / "bits.png")  # 1-bit
    np.save(tmp_path / "y.npy", luminance)
    np.save(tmp_path / "y1.npy", luminance[..., None])
    np.save(tmp_path / "y2.npy", np.stack([luminance, np.ones_like(luminance)], axis=-1))
    advice = (r" has 1 colour channel \(grey\) but the scene renders 3 \(linear RGB\); a grey target is not fitted as "
              r"equal R, G, B: give an RGB image -- if equal RGB is meant, np\.repeat\(grey\[\.\.\., None\], 3, "
              r"axis=-1\) of the \(H, W\) grey values, or the file saved as RGB$")
    for name in ("l.png", "la.png", "i16.png", "bits.png", "y.npy", "y1.npy", "y2.npy"):
        with pytest.raises(FitError, match=rf"^targets\[0\] \(.*{name}\): a grey image file" + advice):
            fit_material(scene, [tmp_path / name], "red", ("kd",))
    for array in (luminance, luminance[..., None], np.stack([luminance, np.ones_like(luminance)], axis=-1)):
        with pytest.raises(FitError, match=rf"^targets\[1\]: an array of shape {re.escape(str(array.shape))}" + advice):
            fit_material(scene, [target_of(scene), array], "red", ("kd",))
    path = save_scene(scene, tmp_path / "s.json")
    assert cli(["fit", str(path), str(tmp_path / "l.png"), "--material", "red", "-o", str(tmp_path / "o.json")]) == 2
    assert re.search(r"targets\[0\] \(.*l\.png\): a grey image file" + advice[:-1], capsys.readouterr().err)
    assert not (tmp_path / "o.json").exists()
    grey = grey_scene()
    equal = np.repeat(target_of(grey)[..., 0][..., None], 3, axis=-1)  # the advice, where R = G = B is meant
    result = fit_material(grey, [equal], "red", ("kd",), init={"kd": 0.3})
    assert result.converged
    np.testing.assert_allclose(result.params["kd"], [0.5] * 3, rtol=1e-4)
