"""The public surface: `difflab.__all__` names resolve, re-exports are the real objects, fitting
names load lazily."""

import subprocess
import sys
from pathlib import Path

import pytest

import difflab


def test_every_public_name_resolves():
    for name in difflab.__all__:
        assert getattr(difflab, name) is not None, name
    assert len(set(difflab.__all__)) == len(difflab.__all__)
    assert set(difflab.__all__) <= set(dir(difflab))


def test_reexports_are_the_defining_objects():
    from difflab.errors import SceneError
    from difflab.scene import Mesh, Scene

    assert difflab.Scene is Scene and difflab.Mesh is Mesh and difflab.SceneError is SceneError
    assert callable(difflab.render) and callable(difflab.compile_scene)


def test_fit_names_load_on_first_use_in_a_fresh_interpreter():
    code = ("import sys, difflab\n"
            "before = 'jax' in sys.modules or 'optimistix' in sys.modules\n"
            "from difflab import fit_material, FitResult\n"
            "import difflab.fit as fit\n"
            "print(before, fit_material is fit.fit_material, FitResult is fit.FitResult, 'jax' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "True", "True", "True"], out.stderr


def test_unknown_names_raise_attribute_error():
    with pytest.raises(AttributeError, match="module 'difflab' has no attribute 'fit_materials'"):
        difflab.fit_materials  # noqa: B018


def test_knobs_are_keyword_only():
    """One entry per problem with keyword-only knobs (optimistix style): `render(scene, "raytrace")`
    is a TypeError, not a silently misread argument."""
    import inspect

    for fn in (difflab.render_frame, difflab.example_scene):
        params = list(inspect.signature(fn).parameters.values())[1:]
        assert params and all(p.kind in (p.KEYWORD_ONLY, p.VAR_KEYWORD) for p in params), fn.__name__
    with pytest.raises(TypeError):
        difflab.render(difflab.example_scene("glass_sphere", width=8, height=6), "raytrace")


def test_render_is_the_function_after_every_renderer_module_is_imported():
    """No subpackage is named like a public function (importing it would rebind the name)."""
    import importlib
    import inspect

    for module in ("difflab.renderers.api", "difflab.renderers.raster.driver", "difflab.renderers.raytrace.driver"):
        importlib.import_module(module)
    assert inspect.isfunction(difflab.render) and inspect.isfunction(difflab.render_frame)
    functions = {n for n in difflab.__all__ if inspect.isfunction(getattr(difflab, n))}
    packages = {p.name for p in Path(difflab.__file__).parent.iterdir() if (p / "__init__.py").is_file()}
    assert not functions & packages


def test_lazy_fit_names_are_not_rebound_by_their_modules():
    """`difflab.fit` loads its names on first use: a module named like one of them would replace it
    once imported (`from difflab.fit import identify` would then give the module)."""
    import importlib
    import pkgutil

    import difflab.fit as fit

    modules = {m.name for m in pkgutil.iter_modules(fit.__path__)}
    assert not modules & set(fit.__all__)
    for name in modules - {"command"}:
        importlib.import_module(f"difflab.fit.{name}")
    assert callable(fit.identify) and callable(fit.fit) and not isinstance(fit.identify, type(fit))


@pytest.mark.parametrize("module", ["scene", "geometry", "fractals", "fit", "demos", "vocabulary", "errors", "io"])
def test_public_modules_declare_their_names(module):
    """docs/architecture.md: these modules' own `__all__` is public API -- each has one, every name
    in it resolves, none twice; the package's names are the same objects."""
    import importlib

    mod = importlib.import_module(f"difflab.{module}")
    names = mod.__all__
    assert names and len(set(names)) == len(names)
    for name in names:
        assert getattr(mod, name) is not None, name
    for name in set(names) & set(difflab.__all__):
        assert getattr(difflab, name) is getattr(mod, name), name
