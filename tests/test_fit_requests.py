"""What a fit is asked for is done, or refused with the `difflab` error (exit 2) naming it: never
dropped or ignored. Parameters whose ray-tree rays do not exist at the start, empty names, options
of the other image model; and the command line names its own flags in those messages."""

import json
import re

import numpy as np
import pytest
from test_fit_helpers import TRUTH, make_scene, mirror_scene, target_of

from difflab import Scene, fit_material
from difflab.cli import main
from difflab.errors import FitError
from difflab.fit.params import DEFAULT_PARAMS, SCENE_PARAMS, build_layout
from difflab.io import save_image
from difflab.scene import save_scene

BLANK = np.zeros((8, 8, 3), np.float32)  # (refused before any render: its pixels do not matter)


def zero_weight_message(key: str, weight: str, rays: str) -> str:
    return (f"params: {key!r}: red.{weight} is 0 at the start, so the recorded ray tree has no {rays} rays from "
            f"it: start it above 0 (e.g. 0.05: the scene's materials.red.{weight}, or init {{'red.{weight}': "
            "0.05}), or leave it out")


@pytest.mark.parametrize("params,key,weight,rays", [
    (("kd", "kr"), "kr", "kr", "reflected"), (("kd", "red.kr"), "red.kr", "kr", "reflected"),
    (("kt",), "kt", "kt", "refracted"), (("kd", "absorption"), "absorption", "kt", "refracted"),
    (DEFAULT_PARAMS + ("kr",), "kr", "kr", "reflected"),  # a name added to the defaults is named too
])
def test_a_named_kr_kt_or_absorption_at_zero_is_refused_not_dropped(params, key, weight, rays):
    """red's kr and kt are 0: the tree holds no reflected or refracted rays from it, so a kr / kt /
    absorption the caller names cannot be fitted. It was dropped from the fit (kd alone fitted, ok
    True) when named without its material."""
    scene = make_scene(size=8)
    with pytest.raises(FitError, match=f"^{re.escape(zero_weight_message(key, weight, rays))}$"):
        fit_material(scene, [BLANK], "red", params, method="raytrace")


def test_with_several_materials_a_generic_kr_fits_where_traced_and_a_named_one_is_refused():
    """mirror_scene: red reflects (kr 0.1), the floor does not: a generic kr is the kr of the
    materials that reflect (red.kr alone); floor.kr named is refused, offering red.kr."""
    scene = mirror_scene(8)
    generic = build_layout(scene, ("red", "floor"), ("kd", "kr"), tree=True)
    assert [p.key for p in generic] == ["red.kd", "red.kr", "floor.kd"]
    want = ("params: 'floor.kr': floor.kr is 0 at the start, so the recorded ray tree has no reflected rays from "
            "it: start it above 0 (e.g. 0.05: the scene's materials.floor.kr, or init {'floor.kr': 0.05}), or name "
            "the others alone (red.kr)")
    with pytest.raises(FitError, match=f"^{re.escape(want)}$"):
        build_layout(scene, ("red", "floor"), ("kd", "floor.kr"), tree=True)


def test_the_defaults_still_skip_the_rays_the_tree_has_not():
    """fit_scene's default params (SCENE_PARAMS, also with names added) fit kr / kt / absorption only
    where the start traces them (documented)."""
    scene = mirror_scene(8)
    keys = [p.key for p in build_layout(scene, ("red", "floor"), SCENE_PARAMS + ("intensity",), tree=True)]
    assert keys == ["red.ka", "red.kd", "red.ks", "red.n", "red.kr", "floor.ka", "floor.kd", "floor.ks", "floor.n",
                    "lights[0].intensity"]


@pytest.fixture()
def ball(tmp_path):
    """A raster ball scene file (red: kr = kt = 0) and its 16 x 16 render as target.npy."""
    scene = make_scene(size=16)
    save_scene(scene, tmp_path / "ball.json")
    save_image(tmp_path / "target.npy", target_of(scene))
    return tmp_path, scene


def run_fit(folder, capsys, *options, scene="ball.json"):
    code = main(["fit", str(folder / scene), str(folder / "target.npy"), "--material", "red",
                 "-o", str(folder / "out.json"), *options])
    printed = capsys.readouterr()
    return code, printed.out, printed.err


def test_the_cli_refuses_a_kr_at_zero_and_fits_it_from_a_start_above(ball, capsys):
    """`--params kd,kr` exited 0 with kd alone fitted; now exit 2, one line, nothing written. With
    the scene's red.kr at 0.05 (what the message advises), kr is fitted: through the ray tree."""
    folder, scene = ball
    code, _, err = run_fit(folder, capsys, "--method", "raytrace", "--params", "kd,kr")
    assert code == 2 and err == f"difflab: error: {zero_weight_message('kr', 'kr', 'reflected')}\n"
    assert not (folder / "out.json").exists() and not (folder / "out.fit.json").exists()
    d = scene.to_dict()
    d["materials"]["red"]["kr"] = 0.05
    shiny = Scene.from_dict(d)
    save_scene(shiny, folder / "shiny.json")
    save_image(folder / "target.npy", target_of(shiny.with_overrides(render={"method": "raytrace"})))
    code, out, _ = run_fit(folder, capsys, "--method", "raytrace", "--params", "kd,kr", scene="shiny.json")
    report = json.loads((folder / "out.fit.json").read_text())
    assert code == 0 and sorted(report["params"]) == ["kd", "kr"] and report["model"] == "raytrace"
    assert report["params"]["kr"] == pytest.approx(0.05, rel=1e-6) and "image model: raytrace" in out


def test_the_cli_names_its_method_flag_in_the_ray_tree_refusal(ball, capsys):
    """kr with the scene's raster model: the message names `--method raytrace`, the flag to give
    (it said method='raytrace', the Python keyword); Python keeps its keyword."""
    folder, scene = ball
    code, _, err = run_fit(folder, capsys, "--params", "kd,kr")
    assert code == 2
    assert err == "difflab: error: params: 'kr' needs the ray-traced image model (--method raytrace)\n"
    with pytest.raises(FitError, match=re.escape("params: 'kr' needs the ray-traced image model (method='raytrace')")):
        fit_material(scene, [BLANK], "red", ("kd", "kr"))


def test_max_depth_is_refused_with_the_g_buffer_and_spp_applies_to_it():
    """max_depth shapes only the ray tree: with the G-buffer it is a FitError (it was ignored),
    whether method="raster" is given or the scene's. spp supersamples either image model: a raster
    fit with spp=4 is the fit of the scene whose render.spp is 4 (it was ignored: the spp-1 fit)."""
    scene = make_scene(size=16)
    want = "max_depth: 2 does not apply to method='raster' (the G-buffer has no secondary rays; use method='raytrace')"
    for method in ("raster", None):
        with pytest.raises(FitError, match=f"^{re.escape(want)}$"):
            fit_material(scene, [BLANK], "red", ("kd",), method=method, max_depth=2)
    supersampled = make_scene(size=16, spp=4)
    target = target_of(supersampled)
    given = fit_material(scene, [target], "red", ("kd", "ks"), method="raster", spp=4)
    scenes = fit_material(supersampled, [target], "red", ("kd", "ks"), method="raster")
    for key in ("kd", "ks"):
        np.testing.assert_allclose(given.params[key], scenes.params[key], rtol=1e-12)
    np.testing.assert_allclose(given.params["kd"], TRUTH["kd"], rtol=1e-5)


@pytest.mark.parametrize("keywords, want", [
    ({"spp": True}, "spp: expected an integer, got True"),
    ({"spp": "4"}, "spp: expected an integer, got '4'"),
    ({"spp": 0}, "spp: must be >= 1, got 0"),
    ({"spp": 3, "method": "raytrace"}, "spp: must be a perfect square (1, 4, 9, 16, ...): both renderers take a side x "
                                       "side pattern of samples per pixel, got 3"),
    ({"max_depth": 0, "method": "raytrace"}, "max_depth: must be >= 1, got 0"),
    ({"max_depth": True, "method": "raytrace"}, "max_depth: expected an integer, got True"),
])
def test_a_bad_spp_or_max_depth_is_refused_naming_its_keyword(keywords, want):
    """spp and max_depth are checked as the scene's render block checks them, and the message names
    the keyword. spp=True was taken for 1 (True == the scene's spp, so nothing was checked); the
    others read 'targets[0]: render.spp: ...', as if the first target's file were wrong."""
    with pytest.raises(FitError, match=f"^{re.escape(want)}$"):
        fit_material(make_scene(size=8), [BLANK], "red", ("kd",), **keywords)


@pytest.mark.parametrize("params,material,flag,given", [
    ("ka,,kd", "red", "--params", "ka,,kd"), ("kd,", "red", "--params", "kd,"),
    ("kd", "red,,floor", "--material", "red,,floor"),
])
def test_an_empty_name_is_refused(ball, capsys, params, material, flag, given):
    """`--params ka,,kd` fitted ka and kd, the empty name dropped: now exit 2 naming the flag; from
    Python the keyword."""
    folder, scene = ball
    code = main(["fit", str(folder / "ball.json"), str(folder / "target.npy"), "--material", material,
                 "--params", params, "-o", str(folder / "out.json")])
    err = capsys.readouterr().err
    assert code == 2 and err == f"difflab: error: {flag}: an empty name in {given!r}; separate names by single commas\n"
    assert not (folder / "out.json").exists()
    with pytest.raises(FitError, match=f"^params: an empty name in {re.escape(repr(['ka', '', 'kd']))}"):
        fit_material(scene, [BLANK], "red", ["ka", "", "kd"])


def test_fit_help_lists_texture_among_the_params(capsys):
    with pytest.raises(SystemExit):
        main(["fit", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "kr, kt, absorption, texture, intensity" in help_text
