"""One vocabulary: the names a scene file may use are exactly those the models and the CLI know,
and each table's ids are 0..n-1 (what the kernels switch on)."""

import pytest

from difflab import vocabulary as voc
from difflab.cli import build_parser
from difflab.errors import SceneError
from difflab.lighting import jax_model, warp_model
from difflab.scene import Material, RenderSettings
from difflab.scene.view import Fog, Light

TABLES = {"SHADING_MODELS": voc.SHADING_MODELS, "SPECULAR_MODELS": voc.SPECULAR_MODELS,
          "LIGHT_TYPES": voc.LIGHT_TYPES, "FRESNEL_MODES": voc.FRESNEL_MODES,
          "TEXTURE_FILTER_IDS": voc.TEXTURE_FILTER_IDS, "TEXTURE_WRAP_IDS": voc.TEXTURE_WRAP_IDS,
          "TEXTURE_TARGET_IDS": voc.TEXTURE_TARGET_IDS}


@pytest.mark.parametrize("name", TABLES)
def test_ids_are_distinct_and_dense(name):
    assert sorted(TABLES[name].values()) == list(range(len(TABLES[name])))


def test_fog_ids_leave_zero_for_no_fog():
    assert voc.FOG_NONE == 0 and sorted(voc.FOG_MODES.values()) == [1, 2, 3]


# record, field, the vocabulary's names, a valid record to vary
FIELDS = [
    (RenderSettings, "method", voc.METHODS, {}),
    (RenderSettings, "shading", tuple(voc.SHADING_MODELS), {}),
    (RenderSettings, "specular", tuple(voc.SPECULAR_MODELS), {}),
    (RenderSettings, "fresnel", tuple(voc.FRESNEL_MODES), {}),
    (RenderSettings, "interpolation", voc.INTERPOLATIONS, {}),
    (RenderSettings, "sampling", voc.SAMPLINGS, {}),
    (Material, "filter", tuple(voc.TEXTURE_FILTER_IDS), {}),
    (Material, "wrap", tuple(voc.TEXTURE_WRAP_IDS), {}),
    (Material, "texture_target", tuple(voc.TEXTURE_TARGET_IDS), {}),
    (Fog, "mode", tuple(voc.FOG_MODES), {"mode": "exp"}),
    (Light, "type", tuple(voc.LIGHT_TYPES), {"type": "spot", "position": [0, 1, 0], "direction": [0, -1, 0],
                                              "cutoff_deg": 30}),
]


@pytest.mark.parametrize("record, field, names, base", FIELDS, ids=[f"{r.__name__}.{f}" for r, f, _, _ in FIELDS])
def test_scene_accepts_exactly_the_vocabulary(record, field, names, base):
    """Every name in the table validates; the error for any other lists exactly the table."""
    for name in names:
        values = {**base, field: name}
        if record is Light and name == "point":
            values = {"type": "point", "position": [0, 1, 0]}
        if record is Light and name == "directional":
            values = {"type": "directional", "direction": [0, -1, 0]}
        assert getattr(record.parse(values, record._PATH), field) == name
    listed = ", ".join(repr(n) for n in names)
    with pytest.raises(SceneError, match=f"must be one of {listed}, got 'nonsense'"):
        record.parse({**base, field: "nonsense"}, record._PATH)


@pytest.mark.parametrize("flag, names", [("--method", voc.METHODS), ("--shading", tuple(voc.SHADING_MODELS)),
                                         ("--specular", tuple(voc.SPECULAR_MODELS))])
def test_render_command_offers_the_vocabulary(flag, names, capsys):
    parser = build_parser()
    base = ["render", "scene.json", "-o", "out.png", flag]
    for name in names:
        assert getattr(parser.parse_args(base + [name]), flag[2:]) == name
    with pytest.raises(SystemExit) as exit_info:
        parser.parse_args(base + ["nonsense"])
    listed = ", ".join(repr(n) for n in names)
    assert exit_info.value.code == 2 and f"(choose from {listed})" in capsys.readouterr().err


def test_both_halves_of_the_model_switch_on_the_same_ids():
    for name in ("PHONG", "BLINN", "DIRECTIONAL", "SPOT", "FOG_LINEAR", "FOG_EXP", "FOG_EXP2", "TARGET_KA",
                 "TARGET_KD", "BECKMANN_MIN_COS"):
        assert getattr(jax_model, name) == getattr(warp_model, name) == getattr(voc, name), name
    assert warp_model.SPECULAR_MODELS is voc.SPECULAR_MODELS and warp_model.FOG_MODES is voc.FOG_MODES
