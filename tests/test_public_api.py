"""The public surface: `difflab.__all__` names resolve, re-exports are the real objects, fitting
names load lazily."""

import subprocess
import sys

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
            "print(before, fit_material is fit.fit_material, FitResult is fit.FitResult, 'optimistix' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "True", "True", "True"], out.stderr


def test_unknown_names_raise_attribute_error():
    with pytest.raises(AttributeError, match="module 'difflab' has no attribute 'fit_materials'"):
        difflab.fit_materials  # noqa: B018
