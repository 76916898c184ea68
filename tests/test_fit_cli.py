"""`difflab fit` on a tiny scene: exit codes and atomic outputs."""

import argparse
import json
import os

import numpy as np
import pytest
from test_fit_helpers import TRUTH, make_scene, perturbed, target_of

from difflab.errors import DifflabError
from difflab.fit import command
from difflab.io import save_image
from difflab.scene import Scene, load_scene, save_scene


def run_cli(argv) -> int:
    """As `difflab.cli.main` does: DifflabError -> exit 2."""
    parser = argparse.ArgumentParser(prog="difflab")
    command.add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except DifflabError:
        return 2


@pytest.fixture()
def files(tmp_path):
    truth = make_scene(size=32)
    target = tmp_path / "target.npy"
    save_image(target, target_of(truth))
    start = Scene.from_dict({**truth.to_dict(), "materials": {
        **{k: v.to_dict() for k, v in truth.materials.items()}, "red": {**truth.materials["red"].to_dict(),
                                                                          **perturbed(TRUTH)}}})
    scene = tmp_path / "scene.json"
    save_scene(start, scene)
    return scene, target, tmp_path


def test_fit_command_converges(files, capsys):
    scene, target, tmp = files
    out = tmp / "fitted.json"
    assert run_cli(["fit", str(scene), str(target), "--material", "red", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "±" in printed and "kd" in printed and "successful" in printed
    fitted = load_scene(out)
    np.testing.assert_allclose(fitted.materials["red"].kd, TRUTH["kd"], rtol=1e-4)
    report = json.loads((tmp / "fitted.fit.json").read_text())
    assert report["converged"] and report["result"] == "successful"
    # nothing is overwritten without --force
    assert run_cli(["fit", str(scene), str(target), "--material", "red", "-o", str(out)]) == 2


def test_fit_command_not_converged_exit_3(files):
    scene, target, tmp = files
    out = tmp / "fitted.json"
    assert run_cli(["fit", str(scene), str(target), "--material", "red", "--max-steps", "2", "-o", str(out)]) == 3
    report = json.loads((tmp / "fitted.fit.json").read_text())
    assert (report["converged"], report["result"]) == (False, "nonlinear_max_steps_reached")
    assert out.exists()


@pytest.mark.parametrize("extra", [["--material", "nope"], ["--material", "red", "--params", "kd,zz"],
                                   ["--material", "red", "--max-steps", "0"]])
def test_fit_command_bad_input_exit_2(files, extra):
    scene, target, tmp = files
    assert run_cli(["fit", str(scene), str(target), *extra, "-o", str(tmp / "x.json")]) == 2
    assert not (tmp / "x.json").exists()


def test_fit_command_missing_target_exit_2(files):
    scene, _, tmp = files
    assert run_cli(["fit", str(scene), str(tmp / "missing.png"), "--material", "red", "-o", str(tmp / "x.json")]) == 2


def test_output_is_atomic(files, monkeypatch):
    """A writer failing midway leaves the old file as it was and no temporary file behind."""
    scene, target, tmp = files
    out = tmp / "fitted.json"
    out.write_text("old")
    import difflab.io as io

    def failing(path, data):
        with io.atomic_path(path) as tmp_path:
            tmp_path.write_text("partial")
            raise OSError("disk full")

    monkeypatch.setattr(io, "write_json_atomic", failing)
    with pytest.raises(OSError):
        run_cli(["fit", str(scene), str(target), "--material", "red", "-o", str(out), "--force"])
    assert out.read_text() == "old"
    assert sorted(os.listdir(tmp)) == sorted(["fitted.json", "scene.json", "target.npy"])
