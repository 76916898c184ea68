"""JAX image formation against the Warp rasterizer, and gradients of the fit's residuals."""

import dataclasses
import itertools
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from test_fit_helpers import make_scene, target_of
from test_raytrace_texture import textured_scene

from difflab import Scene
from difflab.errors import FitError
from difflab.fit import Setup, shade_gbuffer
from difflab.fit.problem import ViewJ, assembled
from difflab.fit.shading import distinct_ids, own_points, pixel_arrays
from difflab.renderers.api import render_frame

LIGHTS = [
    {"type": "point", "position": [3, 4, 3], "intensity": [1, 0.9, 0.8], "attenuation": [1, 0.1, 0.01]},
    {"type": "directional", "direction": [-1, -1, -0.5], "intensity": [0.3, 0.2, 0.5]},
    {"type": "spot", "position": [0, 4, 1], "direction": [0, -1, -0.2], "cutoff_deg": 30, "exponent": 8,
     "intensity": [1, 1, 1]},
]
FOG = {"mode": "linear", "color": [0.5, 0.5, 0.5], "start": 3, "end": 20}


@pytest.mark.parametrize("shading,specular", list(itertools.product(["flat", "gouraud", "phong"],
                                                                    ["phong", "blinn", "torrance"])))
def test_parity_with_warp(shading, specular):
    """Checker floor, shadows, point / directional / spot lights, fog: the JAX image equals Warp's."""
    scene = make_scene(size=24, shading=shading, specular=specular, lights=LIGHTS, fog=FOG)
    frame = render_frame(scene)
    image = np.asarray(shade_gbuffer(frame.gbuffer, scene.materials.values(), scene.lights))
    assert frame.gbuffer.visibility.min() == 0.0  # some shadow is in view
    np.testing.assert_allclose(image, frame.image, atol=1e-5, rtol=0)


@pytest.mark.parametrize("shading,spp,clamp", [("gouraud", 4, True), ("phong", 4, False), ("flat", 4, False),
                                               ("gouraud", 1, True)])
def test_parity_supersampled_and_clamped(shading, spp, clamp):
    bright = [{"type": "point", "position": [2, 3, 3], "intensity": [3, 3, 3], "attenuation": [1, 0, 0]}]
    scene = make_scene(size=16, shading=shading, spp=spp, clamp=clamp, lights=bright)
    frame = render_frame(scene)
    image = np.asarray(shade_gbuffer(frame.gbuffer, scene.materials.values(), scene.lights))
    if clamp:
        assert frame.image.max() <= 1.0 + 1e-6 and max(frame.gbuffer.points.color.max(), 0) > 1.0
    np.testing.assert_allclose(image, frame.image, atol=1e-5, rtol=0)


def test_parity_with_other_materials_and_lights():
    """shade_gbuffer evaluates given materials / lights, not the ones the G-buffer was rendered with."""
    scene = make_scene(size=16, lights=LIGHTS)
    other = make_scene(size=16, lights=[dict(LIGHTS[0], intensity=[0.2, 0.5, 2.0])] + LIGHTS[1:],
                       red={"kd": [0.1, 0.9, 0.3], "n": 5.0})
    image = np.asarray(shade_gbuffer(render_frame(scene).gbuffer, other.materials.values(), other.lights))
    np.testing.assert_allclose(image, render_frame(other).image, atol=1e-5, rtol=0)


@pytest.mark.parametrize("method,spp,target", [("raster", 1, "kd"), ("raster", 4, "ks"), ("raytrace", 1, "ka"),
                                               ("raytrace", 4, "kd")])
def test_parity_on_a_textured_scene(tmp_path, method, spp, target):
    """A textured material: each sample's filtered texel (`GBuffer.texture`) modulates the
    coefficient its texture targets, so the JAX image equals the frame's, from the rasterizer's
    Phong G-buffer (each pixel its point at spp 1, composed at 4) and the ray tracer's at depth 1.
    It left the texture out (0.94 off), though its docstring promised the frame's image."""
    d = textured_scene(tmp_path, target=target)
    d["camera"].update(width=24, height=18)
    scene = Scene.from_dict({**d, "render": {**d["render"], "spp": spp}})
    frame = render_frame(scene, method=method, shading="phong", max_depth=1 if method == "raytrace" else None)
    image = np.asarray(shade_gbuffer(frame.gbuffer, scene.materials.values(), scene.lights))
    assert np.ptp(frame.gbuffer.texture[frame.gbuffer.material == 0]) > 0.5  # the checker is in view
    np.testing.assert_allclose(image, frame.image, atol=1e-5, rtol=0)


@pytest.mark.parametrize("shading", ["flat", "gouraud"])
def test_a_textured_flat_or_gouraud_g_buffer_is_refused(tmp_path, shading):
    """Under flat and Gouraud shading a texel modulates the interpolated lighting of its target term
    (`GBuffer`), which shade_gbuffer does not form: a FitError naming the material, not a wrong image."""
    scene = Scene.from_dict(textured_scene(tmp_path))
    frame = render_frame(scene, shading=shading)
    want = (f"shade_gbuffer: materials[0] has an image texture, which the {shading} G-buffer's image model does not "
            "form (textures are re-formed under phong shading only)")
    with pytest.raises(FitError, match=f"^{re.escape(want)}$"):
        shade_gbuffer(frame.gbuffer, scene.materials.values(), scene.lights)


def _setup(params, size=12, **kw):
    scene = make_scene(size=size, **kw)
    return Setup(scene, [target_of(scene)], "red", params, x64=True)


@pytest.mark.parametrize("specular,params", [("phong", ("ka", "kd", "ks", "n")), ("blinn", ("ks", "n")),
                                             ("torrance", ("ks", "m", "f0")), ("phong", ("intensity",))])
def test_check_grads_every_parameter(specular, params):
    setup = _setup(params, specular=specular, lights=LIGHTS)
    with jax.enable_x64(True):
        x = jnp.asarray(setup.x0)
        values = setup.layout.values(x) * 0.9
        check_grads(lambda v: jnp.sum(setup.problem.weighted(v)), (values,), order=1, modes=("fwd", "rev"),
                    atol=1e-5, rtol=1e-5)
        check_grads(lambda x: jnp.sum(setup.problem.residuals(x)), (x,), order=1, modes=("fwd", "rev"), atol=1e-5,
                    rtol=1e-5)
        z = jnp.asarray(setup.layout.free_from_x(setup.x0))  # the unconstrained solvers' coordinates
        check_grads(lambda z: jnp.sum(setup.problem.residuals(setup.layout.x_from_free(z))), (z,), order=1,
                    modes=("fwd", "rev"), atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("specular", ["phong", "blinn"])
@pytest.mark.parametrize("n", [1e-6, 1000.0])
def test_gradient_in_n_is_finite_everywhere(specular, n):
    """Points with N.L <= 0 and with R.V <= 0 are in view; the gradient in n stays finite."""
    side = [{"type": "point", "position": [-3, 1, 4], "intensity": [1, 1, 1], "attenuation": [1, 0, 0]}]
    setup = _setup(("ks", "n"), size=16, specular=specular, lights=side)
    points = pixel_arrays(setup.views[0].record, np.flatnonzero(setup.views[0].used))[0].points()
    normal, l_dir = np.asarray(points.normal), np.asarray(points.light_dir)[:, 0]
    v_dir = np.asarray(points.view)
    n_dot_l = np.sum(normal * l_dir, axis=-1)
    r = 2 * n_dot_l[:, None] * normal - l_dir
    assert (n_dot_l <= 0).any() and ((np.sum(r * v_dir, axis=-1) <= 0) & (n_dot_l > 0)).any()
    with jax.enable_x64(True):
        values = setup.layout.values(jnp.asarray(setup.x0)).at[-1].set(n)  # layout: ks (3), n
        grad = jax.grad(lambda v: jnp.sum(setup.problem.weighted(v) ** 2))(values)
        assert np.all(np.isfinite(np.asarray(grad)))
        # and through the solver's coordinate log n, at the ends of its range and beyond
        for x_n in (-50.0, -12.0, 0.0, 12.0, 50.0):
            x = jnp.asarray(setup.x0).at[-1].set(x_n)
            g = jax.grad(lambda x: jnp.sum(setup.problem.residuals(x) ** 2))(x)
            assert np.all(np.isfinite(np.asarray(g)))


@pytest.mark.parametrize("shading", ["phong", "flat"])
def test_single_point_pixels_skip_the_composition(shading):
    """Phong and flat shading at spp 1 without fog: each pixel is one point's colour (`direct`), and
    the model's pixels still equal Warp's."""
    scene = make_scene(size=20, shading=shading, lights=LIGHTS)
    frame = render_frame(scene)
    setup = Setup(scene, [frame.image], ("red", "floor"), ("kd", "ks", "n"))
    model = setup.problem.views[0].model
    assert model.formation.direct and model.comp is None
    pixels = np.flatnonzero(setup.views[0].used)
    with jax.enable_x64(True):
        image = setup.problem.images(setup.layout.values(jnp.asarray(setup.x0)))[0]
    np.testing.assert_allclose(np.asarray(image), frame.image.reshape(-1, 3)[pixels], atol=1e-5, rtol=0)


def test_phong_points_are_the_samples():
    """`own_points` reads only the mask under Phong shading (the G-buffer's points are its samples, in
    order): the points it gives are those the point indices and weights say, and it refuses a pixel
    that nothing covers."""
    scene = make_scene(size=20, shading="phong", lights=LIGHTS)
    gbuffer = render_frame(scene).gbuffer
    covered = np.flatnonzero(gbuffer.mask)
    assert 0 < covered.size < gbuffer.mask.size and gbuffer.points.material.shape[0] == gbuffer.mask.size
    np.testing.assert_array_equal(gbuffer.point_index.reshape(-1, 3)[covered, 0], covered)
    np.testing.assert_array_equal(gbuffer.point_weight.reshape(-1, 3)[covered], np.tile([1.0, 0.0, 0.0], (covered.size, 1)))
    read_all = dataclasses.replace(gbuffer, shading="flat")  # the same buffers, every field checked
    np.testing.assert_array_equal(own_points(gbuffer, covered), own_points(read_all, covered))
    np.testing.assert_array_equal(own_points(gbuffer, covered), covered)
    empty = np.flatnonzero(~gbuffer.mask)[:1]
    assert own_points(gbuffer, np.concatenate([covered, empty])) is None


def test_own_points_refuses_mixed_weights():
    """Flat shading: pixels whose points' weights are not (1, 0, 0) are composed, not taken as one point."""
    scene = make_scene(size=20, shading="flat", lights=LIGHTS)
    gbuffer = render_frame(scene).gbuffer
    covered = np.flatnonzero(gbuffer.mask)
    np.testing.assert_array_equal(own_points(gbuffer, covered), gbuffer.point_index.reshape(-1, 3)[covered, 0])
    for weight in ([0.5, 0.5, 0.0], [1.0, 0.0, 1e-7], [1.0, -0.0, np.nan]):
        changed = gbuffer.point_weight.copy()
        changed.reshape(-1, 3)[covered[3]] = weight
        assert own_points(dataclasses.replace(gbuffer, point_weight=changed), covered) is None, weight
    changed = gbuffer.point_weight.copy()
    changed.reshape(-1, 3)[covered[3]] = [1.0, -0.0, 0.0]  # -0 is 0
    assert own_points(dataclasses.replace(gbuffer, point_weight=changed), covered) is not None


@pytest.mark.parametrize("ids,expected", [([3, 3, 3], (3,)), ([-1], (-1,)), ([2, -1, 0, 2, 5], (-1, 0, 2, 5)),
                                          ([], ()), ([0, 1], (0, 1))])
def test_distinct_ids(ids, expected):
    assert distinct_ids(np.asarray(ids, np.int32)) == expected


def test_assembled_modules_are_the_constructors():
    """`problem.assembled` makes the problem's modules as their constructors do (every field, the
    defaults filled in): the same pytree structure and leaves; a missing or unknown field is a TypeError."""
    problem = _setup(("kd", "ks", "n"), size=8).problem
    for module in (problem, problem.views[0], problem.views[0].model):
        fields = {f.name: getattr(module, f.name) for f in dataclasses.fields(module) if f.name != "smoothness"}
        built, made = type(module)(**fields), assembled(type(module), **fields)
        structure = jax.tree_util.tree_structure
        assert structure(made) == structure(built) == structure(module)
        assert all(a is b for a, b in zip(jax.tree_util.tree_leaves(made), jax.tree_util.tree_leaves(built)))
        assert all(getattr(made, f.name) is getattr(built, f.name) for f in dataclasses.fields(module))
    with pytest.raises(TypeError, match="no model given"):
        assembled(ViewJ, **{f.name: None for f in dataclasses.fields(ViewJ) if f.name != "model"})
    with pytest.raises(TypeError, match="has no field size"):
        assembled(ViewJ, **{f.name: None for f in dataclasses.fields(ViewJ)}, size=1)
