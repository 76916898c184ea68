"""A fitted texture written by `difflab fit` and by a batch: a texture file beside the fitted scene,
written with it, which the scene names and renders (they used to fail: `to_scene` wants a folder)."""

import json

import numpy as np
import pytest
from test_texture_fit import quad_scene

from difflab import render
from difflab.batch.manifest import load_manifest
from difflab.batch.store import Store
from difflab.batch.worker import outcome_of
from difflab.cli import main
from difflab.fit.result import texture_file_name
from difflab.io import save_image
from difflab.scene import load_scene, save_scene

SHAPE = (6, 6)  # 108 texels: a dense solve, seconds


@pytest.fixture(scope="module")
def texel_fit(tmp_path_factory):
    """(folder, scene file starting from grey texels, target file, true texels, target image)."""
    folder = tmp_path_factory.mktemp("texture_outputs")
    texels = np.random.default_rng(5).uniform(0.1, 0.9, SHAPE + (3,)).astype(np.float32)
    np.save(folder / "truth.npy", texels)
    np.save(folder / "grey.npy", np.full(SHAPE + (3,), 0.5, np.float32))
    target = render(quad_scene(folder / "truth.npy", size=24))
    save_image(folder / "target.npy", target)
    save_scene(quad_scene(folder / "grey.npy", size=24), folder / "scene.json")
    return folder, folder / "scene.json", folder / "target.npy", texels, target


def assert_renders_the_fit(scene_file, texture_file, texels, target):
    """The written scene names `texture_file`, which holds the fit's texels (float32), and renders
    the target."""
    scene = load_scene(scene_file)
    assert scene.materials["m"].texture == str(texture_file)
    written = np.load(texture_file)
    assert written.dtype == np.float32 and written.shape == SHAPE + (3,)
    assert np.abs(written - texels).max() < 1e-4  # recovered from a noise-free render
    np.testing.assert_allclose(render(scene), target, atol=1e-5)


def assert_reports_the_file(report, file, texture_file):
    """The report names the texture's file (`file`, as the report gives it) and gives its statistics,
    its stderr's and its start's (grey 0.5), not texel by texel: before, each was nested lists, a 256 x
    256 texture ~1.5 MB of JSON."""
    written = np.load(texture_file).astype(np.float64)
    entry = report["params"]["texture"]
    assert entry.pop("mean") == pytest.approx(written.mean(axis=(0, 1)).tolist(), rel=1e-12)
    assert entry == {"file": file, "size": [SHAPE[1], SHAPE[0]], "min": written.min(axis=(0, 1)).tolist(),
                     "max": written.max(axis=(0, 1)).tolist(), "nonfinite": 0, "seen": 1.0}
    assert report["initial"]["texture"] == {"size": [SHAPE[1], SHAPE[0]], "min": [0.5] * 3, "max": [0.5] * 3,
                                            "mean": [0.5] * 3, "nonfinite": 0}
    stderr = report["stderr"]["texture"]
    assert sorted(stderr) == ["max", "mean", "min", "nonfinite", "size"] and stderr["nonfinite"] == 0
    assert all(0 < low <= mid <= high < 1 for low, mid, high in zip(stderr["min"], stderr["mean"], stderr["max"]))


def test_a_report_gives_a_texture_by_its_statistics():
    """`FitResult.to_dict`: a texture's size, per-channel min / max / mean over its finite entries
    (null for a channel with none), and how many entries are not finite; other values as before."""
    from difflab.fit.result import FitResult

    texels = np.arange(24.0).reshape(2, 4, 3) / 32  # (binary fractions: exact sums)
    stderr = np.full((2, 4, 3), 0.25)
    stderr[0, 1] = [np.inf, 0.5, np.inf]
    stderr[..., 2] = np.inf
    result = FitResult({"texture": texels, "kd": [0.5, 0.25, 0.125]}, {"texture": stderr, "kd": [0.1, np.inf, 0.1]},
                       0.0, 99.0, 3, 1.0, True, "successful", initial={"texture": np.zeros((2, 4, 3)), "kd": [0.4] * 3})
    report = result.to_dict()
    texture = {"size": [4, 2], "min": [0.0, 1 / 32, 2 / 32], "max": [21 / 32, 22 / 32, 23 / 32],
               "mean": [10.5 / 32, 11.5 / 32, 12.5 / 32], "nonfinite": 0}
    assert report["params"] == {"texture": texture, "kd": [0.5, 0.25, 0.125]}
    assert report["stderr"] == {"texture": {"size": [4, 2], "min": [0.25, 0.25, None], "max": [0.25, 0.5, None],
                                            "mean": [0.25, 2.25 / 8, None], "nonfinite": 9}, "kd": [0.1, None, 0.1]}
    assert report["initial"]["texture"] == {"size": [4, 2], "min": [0.0] * 3, "max": [0.0] * 3, "mean": [0.0] * 3,
                                            "nonfinite": 0}


def test_the_fit_command_writes_the_texels_beside_the_scene(texel_fit, tmp_path, capsys):
    _, scene, target, texels, image = texel_fit
    out, report, texture = tmp_path / "fitted.json", tmp_path / "fitted.fit.json", tmp_path / "fitted.m.texture.npy"
    code = main(["fit", str(scene), str(target), "--material", "m", "--params", "texture", "-o", str(out)])
    written = json.loads(report.read_text())
    assert (code, written["ok"]) == (0, True), capsys.readouterr()
    assert written["converged"] and written["result"] == "successful"
    assert capsys.readouterr().out.endswith(f"wrote {texture}, {out} and {report}\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fitted.fit.json", "fitted.json", "fitted.m.texture.npy"]
    assert_renders_the_fit(out, texture, texels, image)
    assert_reports_the_file(written, str(texture), texture)
    # the texture file falls under the overwrite rule, before any work
    out.unlink()
    report.unlink()
    assert main(["fit", str(scene), str(target), "--material", "m", "--params", "texture", "-o", str(out)]) == 2
    assert capsys.readouterr().err == f"difflab: error: {texture}: exists; use --force to overwrite\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fitted.m.texture.npy"]


def test_a_batch_writes_the_texels_beside_the_scene_and_drops_them_with_it(texel_fit, tmp_path):
    folder, scene, target, texels, image = texel_fit
    (job,), _ = load_manifest([{"name": "tex", "scene": str(scene), "targets": str(target), "material": "m",
                                "params": "texture"}])
    outcome = outcome_of(job.spec)
    assert outcome["ok"], outcome
    store = Store(tmp_path)
    store.record(job, {**outcome, "seconds": 1.0})
    report = json.loads((tmp_path / "reports" / "tex.json").read_text())
    assert report["converged"] and store.done(job) and store.row(job)["status"] == "converged"
    texture = tmp_path / "scenes" / "tex.m.texture.npy"
    assert_renders_the_fit(tmp_path / "scenes" / "tex.json", texture, texels, image)
    assert_reports_the_file(report, "scenes/tex.m.texture.npy", texture)
    store.record(job, {"ok": False, "error": "boom", "seconds": 1.0})  # a failed rerun leaves no result behind
    assert not texture.exists() and list((tmp_path / "scenes").iterdir()) == []


def test_fit_force_leaves_no_texture_file_of_an_earlier_run(texel_fit, tmp_path, capsys):
    """`difflab fit --force` over an earlier run's outputs removes that run's texture files that the
    new fit does not write (as a batch does), and nothing else: the old command left them, so
    fitted.other.texture.npy and fitted.texture3.npy stayed beside a scene that does not name them."""
    _, scene, target, _, _ = texel_fit
    out = tmp_path / "fitted.json"
    for name in ("fitted.m.texture.npy", "fitted.other.texture.npy", "fitted.texture3.npy", "fitted.notes.npy",
                 "other.m.texture.npy"):
        np.save(tmp_path / name, np.zeros((1, 1, 3), np.float32))
    assert main(["fit", str(scene), str(target), "--material", "m", "--params", "kd", "-o", str(out),
                 "--force"]) in (0, 3, 4, 5), capsys.readouterr()  # written whatever the verdict
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fitted.fit.json", "fitted.json", "fitted.notes.npy",
                                                         "other.m.texture.npy"]


def test_a_job_whose_texture_file_is_gone_is_not_done(texel_fit, tmp_path):
    """Resuming, a job counts as done only with every texture file its scene names: the old check
    (report and scene) skipped a job whose texture had been deleted, leaving a scene that cannot load."""
    folder, scene, target, _, _ = texel_fit
    (job,), _ = load_manifest([{"name": "tex", "scene": str(scene), "targets": str(target), "material": "m",
                                "params": "texture"}])
    store = Store(tmp_path)
    store.record(job, {**outcome_of(job.spec), "seconds": 1.0})
    assert store.done(job)
    (tmp_path / "scenes" / "tex.m.texture.npy").unlink()
    assert not store.done(job)


@pytest.mark.parametrize("material, index, name", [
    ("m", 0, "out.m.texture.npy"), ("brick_2-a", 3, "out.brick_2-a.texture.npy"),
    ("a.b", 1, "out.texture1.npy"), ("../x", 2, "out.texture2.npy"), ("", 4, "out.texture4.npy")])
def test_texture_file_names_are_plain_and_distinct(material, index, name):
    """A material named as a path, or with dots (which could make two (stem, material) pairs meet:
    "a" + "b.c" and "a.b" + "c"), is named by its index instead."""
    assert texture_file_name("out", material, index) == name
