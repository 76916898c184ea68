"""`interior_mask` (difflab.fit.edges) and the `--edge-margin` option of `difflab fit` / `fit-batch`:
the pixels far from every edge, which an anti-aliased target (Mitsuba, POV-Ray +A, a camera) holds
as difflab's pixel-centre samples do, and the fits that count only them."""

import json
import math

import numpy as np
import pytest

import difflab
from difflab import FitError, Scene, compile_scene, interior_mask, render_frame
from difflab.batch.manifest import parse_line
from difflab.batch.worker import fit_job
from difflab.cli import main
from difflab.fit.edges import margin_masks

SIZE = 48
RADIUS, DISTANCE, FOV = 1.0, 4.0, 40.0


def centred_sphere(method: str) -> dict:
    """A unit sphere on the optical axis: its silhouette is a circle of RHO pixels around the image centre."""
    return {"camera": {"eye": [0, 0, DISTANCE], "target": [0, 0, 0], "up": [0, 1, 0], "fov_y": FOV,
                       "width": SIZE, "height": SIZE},
            "lights": [{"type": "point", "position": [2, 3, 4], "intensity": [1, 1, 1]}],
            "materials": {"m": {"kd": [0.5, 0.5, 0.5]}},
            "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": RADIUS, "material": "m"}],
            "render": {"method": method}}


# the silhouette's radius in pixels: the tangent cone's half-angle asin(R / D), at focal length (H / 2) / tan(fov / 2)
RHO = SIZE / 2 / math.tan(math.radians(FOV / 2)) * math.tan(math.asin(RADIUS / DISTANCE))


def analytic(margin: int) -> tuple[np.ndarray, np.ndarray]:
    """(surely kept, surely left out) per pixel for the disc of radius RHO, each pixel centre's side
    known only beyond half a pixel from the circle: kept when the (2 margin + 1)^2 centres around it
    lie in the image and are all surely inside or all surely outside, left out when some are surely
    inside and some surely outside, or some lie beyond the image's border (an edge too)."""
    centres = np.arange(SIZE) + 0.5 - SIZE / 2
    r = np.hypot(*np.meshgrid(centres, centres, indexing="ij"))
    inside, outside = np.pad(r < RHO - 0.5, margin), np.pad(r > RHO + 0.5, margin)  # beyond the border: neither
    shifts = [(i, j) for i in range(2 * margin + 1) for j in range(2 * margin + 1)]
    block = lambda a, f: f([a[i:i + SIZE, j:j + SIZE] for i, j in shifts], axis=0)  # noqa: E731
    kept = block(inside, np.all) | block(outside, np.all)
    border = np.ones((SIZE, SIZE), bool)
    border[margin:-margin, margin:-margin] = False
    return kept, (block(inside, np.any) & block(outside, np.any)) | border


@pytest.mark.parametrize("method", ["raster", "raytrace"])
@pytest.mark.parametrize("margin", [1, 2, 3])
def test_a_spheres_interior_is_the_disc_eroded_by_the_margin(method, margin):
    scene = centred_sphere(method)
    mask = interior_mask(scene, margin=margin)
    kept, left_out = analytic(margin)
    assert mask.shape == (SIZE, SIZE) and mask.dtype == bool
    assert mask[kept].all() and not mask[left_out].any()
    on_sphere = render_frame(scene).gbuffer.mask
    # the sphere's kept pixels against the eroded disc's centres (all 4 block corners within RHO), within a pixel ring
    centres = np.arange(SIZE) + 0.5 - SIZE / 2
    x, y = np.meshgrid(centres, centres, indexing="ij")
    eroded = np.hypot(np.abs(x) + margin, np.abs(y) + margin) <= RHO
    ring = 2 * math.pi * (RHO - margin)
    assert abs(int(np.count_nonzero(mask & on_sphere)) - int(np.count_nonzero(eroded))) <= ring
    assert np.count_nonzero(mask & on_sphere) > 0.5 * np.count_nonzero(eroded)


def test_scene_compiled_scene_and_frame_give_one_mask_and_margin_0_every_pixel():
    scene = Scene.from_dict(centred_sphere("raster"))
    mask = interior_mask(scene)  # margin 2
    assert np.array_equal(mask, interior_mask(compile_scene(scene), margin=2))
    assert np.array_equal(mask, interior_mask(render_frame(scene), margin=2))
    assert interior_mask(scene, margin=0).all()
    fine = interior_mask(render_frame(scene, spp=9), margin=2)  # a pixel's 9 samples must agree too
    assert np.count_nonzero(fine != mask) <= 2 * math.pi * RHO and not fine[analytic(2)[1]].any()


def test_checker_cell_edges_are_edges():
    """A checker floor seen straight from above: its cell edges are the lines x = k and z = k, at
    columns / rows SIZE / 2 + f k / h (focal length f, height h); the interior keeps the pixels more
    than `margin` rows and columns from every edge's pixel, and none within."""
    height = 4.0
    d = {"camera": {"eye": [0, height, 0], "target": [0, 0, 0], "up": [0, 0, -1], "fov_y": 60, "width": SIZE,
                    "height": SIZE},
         "lights": [{"type": "directional", "direction": [0, -1, 0], "intensity": [1, 1, 1]}],
         "materials": {"floor": {"kd": [0.8, 0.8, 0.8], "checker": {"size": 1.0, "kd2": [0.1, 0.1, 0.1]}}},
         "objects": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"}],
         "render": {"method": "raytrace"}}
    mask = interior_mask(d, margin=1)
    focal = SIZE / 2 / math.tan(math.radians(30))
    edges = SIZE / 2 + focal * np.arange(-3, 4) / height  # the lines' raster coordinates
    centres = np.arange(SIZE) + 0.5
    near = np.min(np.abs(centres[:, None] - edges[None, :]), axis=1)  # each column's (row's) distance to an edge
    far, close = near > 1.5 + 0.5, near < 1.5 - 0.5  # beyond margin + half a pixel, or within it
    far[[0, -1]], close[[0, -1]] = False, True  # the image's border is an edge too
    assert far.sum() > SIZE / 2 and mask[np.ix_(far, far)].all()
    assert not mask[close, :].any() and not mask[:, close].any()


@pytest.mark.parametrize("bad", [-1, 1.5, True, "2", None])
def test_a_margin_that_is_no_whole_number_of_pixels_is_refused(bad):
    with pytest.raises(FitError, match=rf"^margin: expected an integer number of pixels >= 0, got {bad!r}"):
        interior_mask(centred_sphere("raster"), margin=bad)


def anti_aliased_target(folder, noise=0.005):
    """difflab's own 16-spp render of a diffuse sphere under a 1 / d^2 light (a stand-in for a foreign
    anti-aliased render: its silhouette pixels are coverage means), with seeded noise, as .npy, and
    the start scene (spp 1, kd, ks, n off the truth) as a file; returns (scene file, target, kd)."""
    kd = (np.array([0.2, 0.5, 0.8]) / np.pi).tolist()
    d = {"camera": {"eye": [0, 1.2, 4], "target": [0, 0.6, 0], "up": [0, 1, 0], "fov_y": 40, "width": SIZE,
                    "height": SIZE},
         "ambient": [0, 0, 0], "lights": [{"type": "point", "position": [3, 4, 3], "intensity": [40] * 3,
                                           "attenuation": [0, 0, 1]}],
         "materials": {"red": {"kd": kd}},
         "objects": [{"type": "sphere", "center": [0, 1, 0], "radius": 1, "material": "red"}],
         "render": {"method": "raster", "shadows": False}}
    image = difflab.render(d, spp=16)
    image = image + np.random.default_rng(3).normal(0, noise, image.shape).astype(np.float32)
    np.save(folder / "target.npy", image)
    d["materials"]["red"] = {"kd": [0.1] * 3, "ks": [0.2] * 3, "n": 10.0}
    difflab.save_scene(Scene.from_dict(d), folder / "scene.json")
    return folder / "scene.json", folder / "target.npy", kd


def test_an_anti_aliased_target_is_flagged_unless_its_edges_are_left_out(tmp_path):
    scene, target, kd = anti_aliased_target(tmp_path)
    args = ["fit", str(scene), str(target), "--material", "red", "--params", "kd,ks,n", "--force"]
    assert main([*args, "-o", str(tmp_path / "all.json")]) == 4  # model_mismatch: the rim's mixed pixels
    mask = np.ones((SIZE, SIZE), bool)
    mask[:, :SIZE // 2] = False  # with a mask too: the interior inside it
    np.save(tmp_path / "half.npy", mask)
    assert main([*args, "-o", str(tmp_path / "edge.json"), "--edge-margin", "2"]) == 0
    assert main([*args, "-o", str(tmp_path / "half.json"), "--edge-margin", "2", "--mask", str(tmp_path / "half.npy")]) == 0
    for name, used in (("edge", interior_mask(scene)), ("half", interior_mask(scene) & mask)):
        report = json.loads((tmp_path / f"{name}.fit.json").read_text())
        np.testing.assert_allclose(report["params"]["kd"], kd, atol=1e-3)
        assert report["model_mismatch"] is False
    unmasked = json.loads((tmp_path / "all.fit.json").read_text())
    assert np.max(np.abs(np.subtract(unmasked["params"]["kd"], kd))) > 5e-3


def test_a_batch_line_edge_margin_gives_the_fit_the_interior(tmp_path):
    scene, target, kd = anti_aliased_target(tmp_path)
    spec = parse_line({"name": "a", "scene": str(scene), "targets": [str(target)], "material": "red",
                       "params": "kd,ks,n", "edge_margin": 2}, tmp_path)
    assert spec["edge_margin"] == 2
    batch = fit_job(spec)
    alone = difflab.fit_material(scene, [target], "red", ("kd", "ks", "n"), masks=[interior_mask(scene)], progress=False)
    assert batch.params["kd"] == pytest.approx(alone.params["kd"], abs=1e-12) and batch.ok
    np.testing.assert_allclose(batch.params["kd"], kd, atol=1e-3)
    assert margin_masks(scene, [target], None, 0) is None
    with pytest.raises(FitError, match=r"^scene: .*nope\.json: scene file not found$"):
        margin_masks(tmp_path / "nope.json", [target], None, 2)  # as the fit says it


def test_fit_many_gives_its_edge_margin_to_the_lines_without_one(tmp_path):
    """A batch's --edge-margin (fit_many's edge_margin) applies to a line without its own, not to one
    that says 0, and is part of the job: the report records it, and a rerun with another margin
    fits that line again."""
    scene, target, kd = anti_aliased_target(tmp_path)
    line = {"scene": str(scene), "targets": [str(target)], "material": "red", "params": "kd,ks,n"}
    manifest = [{"name": "inherits", **line}, {"name": "own0", **line, "edge_margin": 0}]
    out = tmp_path / "out"
    summary = difflab.fit_many(manifest, out, workers=1, edge_margin=2, quiet=True, progress=False)
    assert summary.mismatched == ["own0"] and summary.all_converged
    inherits = json.loads((out / "reports" / "inherits.json").read_text())
    assert inherits["job"]["edge_margin"] == 2 and inherits["model_mismatch"] is False
    np.testing.assert_allclose(inherits["params"]["kd"], kd, atol=1e-3)
    assert json.loads((out / "reports" / "own0.json").read_text())["job"]["edge_margin"] == 0
    again = difflab.fit_many(manifest, out, workers=1, edge_margin=1, quiet=True, progress=False)
    assert (again.ran, again.skipped) == (1, 1)  # "inherits" fitted again (margin 1), "own0" as it was


@pytest.mark.parametrize("command", ["fit", "fit-batch"])
@pytest.mark.parametrize("bad", ["-1", "1.5", "two"])
def test_a_bad_edge_margin_exits_2_naming_the_option(tmp_path, capsys, command, bad):
    scene, target, _ = anti_aliased_target(tmp_path)
    if command == "fit":
        args = ["fit", str(scene), str(target), "--material", "red", "-o", str(tmp_path / "o.json")]
    else:
        (tmp_path / "m.jsonl").write_text(json.dumps({"name": "a", "scene": str(scene), "targets": [str(target)]}))
        args = ["fit-batch", str(tmp_path / "m.jsonl"), "-o", str(tmp_path / "out")]
    assert main([*args, "--edge-margin", bad]) == 2
    err = capsys.readouterr().err
    assert err == f"difflab: error: --edge-margin: expected an integer number of pixels >= 0, got {bad!r}\n"
    assert not (tmp_path / "o.json").exists() and not (tmp_path / "out" / "summary.csv").exists()


def test_the_edge_margin_mask_is_of_the_fits_record_and_its_errors_name_the_options(tmp_path, capsys):
    """`margin_masks` reads the interior of the record the fit makes (its spp and method, as
    `--spp` / `--method` give them): at spp 4 the 48 x 48 sphere's interior is 1412 pixels, not spp
    1's 1468 (ray traced 1472: the raster Phong sphere's silhouette is up to a quarter sample
    inside). `difflab fit --edge-margin` names what the user gave: --mask[0] for a mask of the wrong
    shape, --spp for an spp that is no square (exit 2, no file written)."""
    scene, target, _ = anti_aliased_target(tmp_path)
    for spp, count in ((None, 1468), (4, 1412)):
        mask = margin_masks(scene, [target], None, 2, spp=spp)[0]
        assert np.count_nonzero(mask) == count and np.array_equal(mask, interior_mask(scene, margin=2, spp=spp))
    traced = margin_masks(scene, [target], None, 2, method="raytrace")[0]
    assert np.array_equal(traced, interior_mask(scene, method="raytrace")) and np.count_nonzero(traced) == 1472
    np.save(tmp_path / "small.npy", np.ones((5, 5), bool))
    args = ["fit", str(scene), str(target), "--material", "red", "-o", str(tmp_path / "o.json"),
            "--edge-margin", "2"]
    assert main([*args, "--mask", str(tmp_path / "small.npy")]) == 2
    assert capsys.readouterr().err == "difflab: error: --mask[0]: expected shape (48, 48), got (5, 5)\n"
    assert main([*args, "--spp", "2"]) == 2
    assert capsys.readouterr().err.startswith("difflab: error: --spp: must be a perfect square")
    assert not (tmp_path / "o.json").exists()


def test_fit_many_refuses_a_bad_edge_margin(tmp_path):
    with pytest.raises(FitError, match=r"^edge_margin: expected an integer number of pixels >= 0, got True$"):
        difflab.fit_many([{"name": "a", "scene": "s.json", "targets": ["t.npy"]}], tmp_path / "out", edge_margin=True)


def test_cast_shadows_are_edges_and_the_terminator_is_not():
    """A sphere resting on a floor under a light straight down, seen obliquely and ray traced. Each
    pixel centre's region, computed here from the geometry: the sphere, the floor in its shadow
    (x^2 + z^2 < R^2) or the floor in the light. The mask must be the pixels whose (2 margin + 1)^2
    centres share one region: the shadow's outline is an edge, the sphere's equator -- where its
    surface turns from the light, the part below it unlit but not shadowed -- is not."""
    eye, target, fov, margin = np.array([0.0, 6.0, 4.0]), np.array([0.0, 0.5, 0.0]), 40.0, 1
    d = {"camera": {"eye": eye.tolist(), "target": target.tolist(), "up": [0, 1, 0], "fov_y": fov, "width": SIZE,
                    "height": SIZE},
         "lights": [{"type": "directional", "direction": [0, -1, 0], "intensity": [1, 1, 1]}],
         "materials": {"m": {"kd": [0.5, 0.5, 0.5]}, "floor": {"kd": [0.8, 0.8, 0.8]}},
         "objects": [{"type": "sphere", "center": [0, 1, 0], "radius": 1, "material": "m"},
                     {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"}],
         "render": {"method": "raytrace", "shadows": True}}
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, [0, 1, 0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    half = math.tan(math.radians(fov) / 2)
    centres = (np.arange(SIZE) + 0.5) / SIZE * 2 - 1
    rays = forward + centres[None, :, None] * half * right - centres[:, None, None] * half * up  # (row, column, 3)
    to_centre = np.array([0.0, 1.0, 0.0]) - eye
    along = rays @ to_centre
    square = (rays * rays).sum(-1)
    discriminant = along ** 2 - square * (to_centre @ to_centre - 1.0)
    on_sphere = discriminant > 0  # the ray meets the sphere
    hit_y = eye[1] + (along - np.sqrt(np.maximum(discriminant, 0))) / square * rays[..., 1]
    floor = eye - (eye[1] / rays[..., 1])[..., None] * rays  # where each ray meets y = 0
    region = np.where(on_sphere, 0, np.where(floor[..., 0] ** 2 + floor[..., 2] ** 2 < 1.0, 1, 2))
    padded = np.pad(region, margin, mode="edge")
    shifts = [(i, j) for i in range(2 * margin + 1) for j in range(2 * margin + 1)]
    window = np.stack([padded[i:i + SIZE, j:j + SIZE] for i, j in shifts])
    expected = (window.min(axis=0) == window.max(axis=0))
    expected[[0, -1], :] = expected[:, [0, -1]] = False  # the image's border
    shadow_edge = (window.min(axis=0) >= 1) & (window.min(axis=0) != window.max(axis=0))
    assert np.count_nonzero(shadow_edge) > 20  # the shadow's outline is in view
    assert np.count_nonzero(on_sphere & (hit_y < 0.9)) >= 5  # and so is the sphere below its equator (y = 1)
    mask = interior_mask(d, margin=margin)
    assert np.count_nonzero(mask != expected) <= 2


def test_the_edge_margin_mask_is_of_the_image_model_the_fit_chooses():
    """A Gouraud-rasterized checker floor with kr > 0: the fit re-forms it from the ray tree
    (`arguments.choose_method`), whose Phong record keeps the checker cells, so without --method the
    edge-margin mask is the ray tree's interior (cell edges left out) and not the raster record's
    (no cell edges: every pixel but the border ring)."""
    d = {"camera": {"eye": [0, 4, 0], "target": [0, 0, 0], "up": [0, 0, -1], "fov_y": 60, "width": SIZE, "height": SIZE},
         "lights": [{"type": "directional", "direction": [0, -1, 0], "intensity": [1, 1, 1]}],
         "materials": {"floor": {"kd": [0.8, 0.8, 0.8], "kr": 0.2, "checker": {"size": 1.0, "kd2": [0.1, 0.1, 0.1]}}},
         "objects": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "material": "floor"}],
         "render": {"method": "raster", "shading": "gouraud"}}
    target = np.zeros((SIZE, SIZE, 3))
    traced, rastered = (interior_mask(d, margin=1, method=m) for m in ("raytrace", "raster"))
    assert np.count_nonzero(rastered) == (SIZE - 2) ** 2  # the border ring only
    assert np.count_nonzero(traced) < 0.8 * (SIZE - 2) ** 2  # 7 cell lines each way, 3 pixels wide
    for materials in (None, ["floor"]):
        assert np.array_equal(margin_masks(d, [target], None, 1, materials=materials)[0], traced)
    assert np.array_equal(margin_masks(d, [target], None, 1, method="raster")[0], rastered)  # as told
    d["materials"]["floor"]["kr"] = 0.0  # now the fit keeps the G-buffer
    assert np.array_equal(margin_masks(d, [target], None, 1)[0], rastered)
