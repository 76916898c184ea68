"""The frame a fit renders (`renderers.api.fit_frame`): render_frame(..., image=False) without what
the fit never reads -- under Phong shading no point is lit (the fit shades the recorded light
geometry itself), no texel is sampled, uv is formed only where a texture is sampled and only in a
scene with one, depth only with fog, and neither positions, point indices and weights (each Phong
sample is its own point), uv derivatives nor faces and barycentrics are formed. Every field it
keeps is render_frame's; the fields it skips are None, not zeros passed off as values, and uv is 0
where no texture is sampled, as in a ray-traced G-buffer. A fit through it is bitwise the fit
through render_frame's G-buffer."""

import dataclasses

import numpy as np
import pytest

from test_fit_helpers import TRUTH, make_scene, perturbed, target_of
from test_raster_spheres import RED, sphere_scene, textured
from test_texture_fit import quad_scene
from difflab import compile_scene, render_frame
from difflab.fit import Setup, fit_material
from difflab.renderers.api import fit_frame
from difflab.renderers.frame import POINT_ROWS
from difflab.scene import Scene

# what every fit frame under rasterized Phong shading skips (`raster.gbuffer.fit_skips`); "position" is
# both the samples' and the points'
SKIPPED = {"duv_dx", "duv_dy", "color", "texture_factor", "texture", "face", "bary", "position", "point_index",
           "point_weight"}
FOG = {"mode": "linear", "color": [0.5, 0.5, 0.5], "start": 3, "end": 20}


def arrays(gbuffer) -> dict:
    """Every array (or None) of a G-buffer and of its points, by name."""
    out = {f.name: getattr(gbuffer, f.name) for f in dataclasses.fields(gbuffer) if f.name != "points"}
    out.update({f.name: getattr(gbuffer.points, f.name) for f in dataclasses.fields(gbuffer.points)})
    return {k: v for k, v in out.items() if v is None or isinstance(v, np.ndarray)}


@pytest.mark.parametrize("shading, method", [("phong", "raster"), ("gouraud", "raster"), ("phong", "raytrace")])
@pytest.mark.parametrize("texture, fog, spp", [(False, False, 1), (True, False, 1), (False, True, 4),
                                               (True, True, 1)])
def test_a_fits_frame_is_render_frames_less_what_the_fit_does_not_read(tmp_path, shading, method, texture, fog, spp):
    """A sphere (and a mesh quad beside it) with shadows: under rasterized Phong shading the fit's
    G-buffer equals render_frame's in every field but SKIPPED, and depth without fog and uv without
    a texture, which are None; uv with a texture is there only on the textured material (the texels
    are sampled with uv and its derivatives, which the fit frame then does not keep); Gouraud frames
    and ray-traced ones are render_frame's in full."""
    quad = {"type": "mesh", "builtin": "quad", "material": "plain",
            "transform": {"rotate_deg": [-90, 0, 0], "translate": [0, -0.01, 0], "scale": 3}}
    d = sphere_scene("outside", size=24, material=textured(tmp_path) if texture else RED,
                     objects=[{"type": "sphere", "center": [0, 1, 0], "radius": 1, "material": "red"}, quad])
    d["materials"]["plain"] = RED
    d["render"].update(shading=shading, method=method, spp=spp)
    if fog:
        d["fog"] = FOG
    full, fitted = render_frame(d, image=False), fit_frame(d)
    assert fitted.image is None and fitted.stats["method"] == method
    skipped = set()
    if (shading, method) == ("phong", "raster"):
        skipped = SKIPPED | ({"uv"} if not texture else set()) | ({"depth"} if not fog else set())
    want, got = arrays(full.gbuffer), arrays(fitted.gbuffer)
    if skipped and texture:  # uv only where the texture is sampled
        plain = full.gbuffer.material == 1
        assert plain.any() and np.abs(want["uv"][plain]).max() > 0.5
        want["uv"] = np.where(plain[..., None], 0.0, want["uv"]).astype(np.float32)
    assert want.keys() == got.keys()
    for name, value in want.items():
        if name in skipped:
            assert got[name] is None and value is not None, name
        elif name == "rows" and skipped:  # the fit's points side by side (`ShadingPoints.rows`)
            side_by_side = [want[k].reshape(len(want[k]), -1).view(np.float32) for k in POINT_ROWS]
            np.testing.assert_array_equal(got[name].view(np.int32), np.concatenate(side_by_side, 1).view(np.int32))
        elif value is None:
            assert got[name] is None, name
        else:
            np.testing.assert_array_equal(got[name], value, err_msg=name)
    if texture:
        assert np.abs(want["texture"]).max() > 0.1
    assert np.abs(want["visibility"]).min() == 0.0 and want["visibility"].max() == 1.0  # the sphere's shadow


@pytest.mark.parametrize("threads", [None, 1])
def test_a_fits_frame_in_the_buffer_another_view_left_is_one_in_new_memory(tmp_path, threads):
    """A fit's G-buffer is not cleared (`gbuffer.gbuffer_arrays`): its pass zeroes what the last
    frame left where this one has no point. Each view's frame, rendered in the buffer the other
    view's frame left (one compiled scene, other cameras; a textured sphere and a plain quad under
    two lights with shadows), is bitwise the frame rendered in new memory."""
    quad = {"type": "mesh", "builtin": "quad", "material": "plain",
            "transform": {"rotate_deg": [-90, 0, 0], "translate": [0, -0.01, 0], "scale": 3}}
    d = sphere_scene("outside", size=24, material=textured(tmp_path),
                     objects=[{"type": "sphere", "center": [0, 1, 0], "radius": 1, "material": "red"}, quad])
    d["materials"]["plain"] = RED
    d["lights"].append({"type": "directional", "direction": [-1, -1, -0.5], "intensity": [0.3, 0.2, 0.5]})
    compiled = compile_scene(Scene.from_dict(d))
    last = None
    for eye in ([0, 1.2, 4], [2.5, 3, 1.5], [-1, 0.4, 2.5], [0, 1.2, 4]):
        view = compiled.with_scene(Scene.from_dict(dict(d, camera=dict(d["camera"], eye=eye))))
        got = fit_frame(view, threads=threads).gbuffer  # in the last view's buffer
        fresh = fit_frame(view, threads=threads).gbuffer  # in new memory (that buffer is held)
        assert last in (None, got.points.rows.ctypes.data) and fresh.points.rows.ctypes.data != last
        last = fresh.points.rows.ctypes.data
        assert_bitwise(arrays(got), arrays(fresh))
        with pytest.raises(ValueError, match="read-only"):  # (what is written there would reach the next frame)
            got.points.normal[0] = 1.0
        del fresh, got  # (their memory free for the next frame)


@pytest.mark.parametrize("hold", ["normal rows", "points", "rows", "material"])
def test_a_fits_frame_held_through_any_array_of_it_keeps_its_memory(hold):
    """A fit frame's GBuffer is views kept with its structs (`gbuffer.to_gbuffer`, `compile.HostViews`):
    while anything derived from it is held (a slice, its points, a reshape), the next frame takes
    other memory; once let go, the next frame takes its memory again."""
    compiled = compile_scene(Scene.from_dict(sphere_scene("outside", size=16)))
    take = {"normal rows": lambda g: g.normal[:3], "points": lambda g: g.points, "rows": lambda g: g.points.rows[1:],
            "material": lambda g: g.material.reshape(-1)}[hold]
    address = lambda frame: frame.gbuffer.points.rows.ctypes.data  # noqa: E731
    first = fit_frame(compiled, threads=1)
    where, held = address(first), take(first.gbuffer)
    del first
    second = fit_frame(compiled, threads=1)
    assert address(second) != where
    where = address(second)
    del second, held
    assert address(fit_frame(compiled, threads=1)) == where


def full_frame(scene, *, device=None, threads=None):
    """render_frame's whole G-buffer, where a fit renders `fit_frame`."""
    return render_frame(scene, image=False, device=device, threads=threads)


def assert_bitwise(a, b, where=""):
    """a and b equal value for value, floats and arrays bit for bit (nan included)."""
    if isinstance(a, dict):
        assert list(a) == list(b), where
        for key in a:
            assert_bitwise(a[key], b[key], f"{where}[{key!r}]")
    elif isinstance(a, (list, tuple)) and not isinstance(a, str):
        assert type(a) is type(b) and len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b)):
            assert_bitwise(x, y, f"{where}[{k}]")
    elif isinstance(a, (float, np.ndarray, np.floating)):
        x, y = np.asarray(a), np.asarray(b)
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), where
    else:
        assert a == b, where


def random_texture(tmp_path, shape=(8, 8)):
    texels = np.random.default_rng(5).uniform(0.1, 0.9, shape + (3,)).astype(np.float32)
    np.save(tmp_path / "truth.npy", texels)
    return tmp_path / "truth.npy"


@pytest.mark.parametrize("case", ["plain", "spp 4", "fog", "two lights", "blinn", "texture", "texture spp 4"])
def test_a_fit_through_its_frame_is_the_fit_through_render_frames_gbuffer(monkeypatch, tmp_path, case):
    """Phong shading: the sphere and checker floor with shadows (kd, ks, n fitted; with two lights a
    light's intensity too) at spp 1 and 4, with fog, Blinn's highlight, and a textured quad's texels
    at spp 1 and 4: every field of the fit's result but its timings, and the image model's whole
    image (every pixel, the background included: composed even at spp 1), are bitwise those of the
    fit through render_frame's full G-buffer."""
    spp = 4 if case.endswith("spp 4") else 1
    if case.startswith("texture"):
        scene = quad_scene(random_texture(tmp_path), size=24).with_overrides(render={"spp": spp})
        material, params, start = "m", ("texture", "ks"), {"texture": 0.5, "ks": [0.2] * 3}
    else:
        lights = [{"type": "point", "position": [3, 4, 3], "intensity": [1, 1, 1], "attenuation": [1, 0, 0]},
                  {"type": "directional", "direction": [-1, -1, -0.5], "intensity": [0.3, 0.2, 0.5]}]
        scene = make_scene(size=24, spp=spp, fog=FOG if case == "fog" else None, lights=lights[:1 + (
            case == "two lights")], specular="blinn" if case == "blinn" else "phong")
        material, params = "red", ("kd", "ks", "n") + (("lights[1].intensity",) if case == "two lights" else ())
        start = {k: v for k, v in perturbed(TRUTH, 0.2).items() if k in params}
    target = target_of(scene)
    results = []
    for frames in (fit_frame, full_frame):
        monkeypatch.setattr("difflab.fit.setup.fit_frame", frames)
        result = fit_material(scene, [target], material, params, init=start, history=True, progress=False)
        results.append((result, Setup(scene, [target], material, params, init=start).render()[0]))
    (slim, slim_image), (full, full_image) = results
    assert slim.steps > 2 and slim.converged
    for field in dataclasses.fields(slim):
        if field.name not in ("timings", "seconds", "scene", "layout"):
            assert_bitwise(getattr(slim, field.name), getattr(full, field.name), field.name)
    assert slim.scene == full.scene
    np.testing.assert_array_equal(slim_image, full_image)
