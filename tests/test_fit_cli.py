"""`difflab fit` through the real command line (`difflab.cli.main`): exit codes, summary, outputs."""

import json
import os

import numpy as np
import pytest
from test_fit_helpers import TRUTH, make_scene, mirror_scene, perturbed, target_of

from difflab import Scene, render
from difflab.cli import main
from difflab.io import save_image
from difflab.scene import load_scene, save_scene


@pytest.fixture()
def files(tmp_path):
    truth = make_scene(size=24)
    target = tmp_path / "target.npy"
    save_image(target, target_of(truth))
    start = Scene.from_dict({**truth.to_dict(), "materials": {
        **{k: v.to_dict() for k, v in truth.materials.items()}, "red": {**truth.materials["red"].to_dict(),
                                                                          **perturbed(TRUTH)}}})
    scene = tmp_path / "scene.json"
    save_scene(start, scene)
    return scene, target, tmp_path


def test_fit_command_converges_exit_0(files, capsys):
    scene, target, tmp = files
    out = tmp / "fitted.json"
    assert main(["fit", str(scene), str(target), "--material", "red", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "±" in printed and "kd" in printed and "successful" in printed and "reduced chi-square" in printed
    assert "image model: raster" in printed
    fitted = load_scene(out)
    np.testing.assert_allclose(fitted.materials["red"].kd, TRUTH["kd"], rtol=1e-4)
    report = json.loads((tmp / "fitted.fit.json").read_text())
    assert report["converged"] and report["result"] == "successful" and not report["model_mismatch"] and report["ok"]
    # nothing is overwritten without --force
    assert main(["fit", str(scene), str(target), "--material", "red", "-o", str(out)]) == 2


def test_fit_command_not_converged_exit_3(files):
    scene, target, tmp = files
    out = tmp / "fitted.json"
    assert main(["fit", str(scene), str(target), "--material", "red", "--max-steps", "2", "-o", str(out)]) == 3
    report = json.loads((tmp / "fitted.fit.json").read_text())
    assert (report["converged"], report["result"], report["ok"]) == (False, "nonlinear_max_steps_reached", False)
    assert out.exists()


def test_fit_command_model_mismatch_exit_4(tmp_path, capsys):
    """A ray-traced mirror fitted with --method raster: converged, flagged, exit 4, files written;
    the scene's own model (the ray tree) exits 0. Two materials given as one comma-separated list."""
    scene = mirror_scene(16)
    target = tmp_path / "target.npy"
    save_image(target, render(scene))
    path = tmp_path / "scene.json"
    save_scene(scene, path)
    out = tmp_path / "fitted.json"
    args = ["fit", str(path), str(target), "--material", "red,floor", "--params", "red.kd,floor.kd", "-o", str(out)]
    assert main(args + ["--method", "raster"]) == 4
    assert "MODEL MISMATCH" in capsys.readouterr().out and out.exists()
    report = json.loads((tmp_path / "fitted.fit.json").read_text())
    assert report["model_mismatch"] and report["converged"] and not report["ok"]
    assert main(args + ["--force"]) == 0
    assert "image model: raytrace" in capsys.readouterr().out


def test_fit_command_noise_unknown_exit_5(files, capsys):
    """A mask of 6 scattered pixels: converged, but the noise cannot be estimated -- exit 5, files
    written, the report's noise_unknown true and sigma null; with --sigma, exit 0."""
    scene, target, tmp = files
    mask = np.zeros((24, 24), bool)
    mask[[9, 9, 12, 12, 15, 15], [9, 14, 11, 16, 9, 14]] = True
    mask_file = tmp / "mask.npy"
    np.save(mask_file, mask)
    out = tmp / "fitted.json"
    args = ["fit", str(scene), str(target), "--material", "red", "--params", "kd", "--mask", str(mask_file), "-o", str(out)]
    assert main(args) == 5
    assert "NOISE UNKNOWN" in capsys.readouterr().out and out.exists()
    report = json.loads((tmp / "fitted.fit.json").read_text())
    assert report["converged"] and report["noise_unknown"] and report["sigma"] is None and report["chi2"] is None
    assert not report["ok"]
    assert main(args + ["--sigma", "0.01", "--force"]) == 0


def test_fit_command_report_on_the_output_is_refused(files, capsys):
    """-o X --report X: the report would replace the fitted scene -- exit 2 before any work, nothing
    written (it printed "wrote X and X" and kept only the report)."""
    scene, target, tmp = files
    out = tmp / "fitted.json"
    assert main(["fit", str(scene), str(target), "--material", "red", "-o", str(out), "--report", str(out)]) == 2
    assert "--report: the same file as -o/--output" in capsys.readouterr().err and not out.exists()


def test_fit_command_ctrl_c_while_writing_leaves_the_whole_pair(files, monkeypatch):
    """Ctrl-C arriving while the fitted scene and report are written is held until both are renamed
    into place, then ends the command (exit 130): never one new file beside an old one."""
    import contextlib
    import signal

    import difflab.files as writers

    scene, target, tmp = files
    out, report = tmp / "fitted.json", tmp / "fitted.fit.json"
    atomic_path = writers.atomic_path

    @contextlib.contextmanager
    def interrupted_path(path, **kwargs):
        with atomic_path(path, **kwargs) as tmp_path:
            if path.name == out.name:
                signal.raise_signal(signal.SIGINT)  # the user's Ctrl-C, between the two files
            yield tmp_path

    monkeypatch.setattr(writers, "atomic_path", interrupted_path)
    assert main(["fit", str(scene), str(target), "--material", "red", "-o", str(out)]) == 130
    assert json.loads(report.read_text())["converged"] and "materials" in json.loads(out.read_text())


@pytest.mark.parametrize("extra", [["--material", "nope"], ["--material", "red", "--params", "kd,zz"],
                                   ["--material", "red", "--max-steps", "0"],
                                   ["--material", "red", "--sigma", "-1"]])
def test_fit_command_bad_input_exit_2(files, extra, capsys):
    scene, target, tmp = files
    assert main(["fit", str(scene), str(target), *extra, "-o", str(tmp / "x.json")]) == 2
    assert not (tmp / "x.json").exists()
    assert capsys.readouterr().err.startswith("difflab: error:")


def test_fit_command_wrong_size_and_missing_target_exit_2(files, capsys):
    scene, _, tmp = files
    small = tmp / "small.npy"
    save_image(small, np.zeros((8, 8, 3), np.float32))
    assert main(["fit", str(scene), str(small), "--material", "red", "-o", str(tmp / "x.json")]) == 2
    assert "8x8" in capsys.readouterr().err
    assert main(["fit", str(scene), str(tmp / "missing.png"), "--material", "red", "-o", str(tmp / "x.json")]) == 2


@pytest.mark.parametrize("failing", ["fitted.json", "fitted.fit.json"])
def test_output_is_atomic(files, monkeypatch, capsys, failing):
    """The fitted scene and the report are written as a pair: a write failing midway -- of either --
    leaves both old files as they were and no temporary file behind; exit 2 with one line naming the
    file and the reason (docs/cli.md: an output that cannot be written). (The scene was written
    before the report: a full disk on the report left a new scene beside the old report.)"""
    scene, target, tmp = files
    out, report = tmp / "fitted.json", tmp / "fitted.fit.json"
    out.write_text("old")
    report.write_text("old report")
    import contextlib

    import difflab.files as writers

    atomic_path = writers.atomic_path

    class Full(type(tmp)):  # a temporary whose writing runs out of space midway
        def write_text(self, text, *args, **kwargs):
            super().write_text(text[:10], *args, **kwargs)
            raise OSError("disk full")

    @contextlib.contextmanager
    def failing_path(path, **kwargs):
        with atomic_path(path, **kwargs) as tmp_path:
            yield Full(tmp_path) if path.name == failing else tmp_path

    monkeypatch.setattr(writers, "atomic_path", failing_path)
    assert main(["fit", str(scene), str(target), "--material", "red", "-o", str(out), "--force"]) == 2
    assert capsys.readouterr().err == f"difflab: error: {tmp / failing}: cannot write (disk full); not written\n"
    assert out.read_text() == "old" and report.read_text() == "old report"
    assert sorted(os.listdir(tmp)) == sorted(["fitted.json", "fitted.fit.json", "scene.json", "target.npy"])


@pytest.mark.parametrize("case, message", [
    ("nan", r"no fit made: nonfinite_target: targets\[0\] \(.*bad\.npy\) holds 1 non-finite value \(0 NaN, 1 inf\) "
            r"in 1 pixel the fit uses"),  # (the NaN at the corner is the background's: left out)
    ("mask", r"no fit made: empty_mask: targets\[0\] \(.*target\.npy\): the mask masks\[0\] \(.*mask\.npy\) holds 4 "
             r"pixels, none showing material red"),
])
def test_fit_command_that_makes_no_fit_prints_one_error_line_only(files, capsys, case, message):
    """docs/cli.md: exit 2 is one `difflab: error:` line; a fit that could not be made (a non-finite
    target, a mask showing none of the material) printed the whole parameter table before it (start
    values '± nan (poorly determined)') and a result line, on stdout."""
    import re

    scene, target, tmp = files
    extra = []
    if case == "nan":
        image = np.load(target)
        image[0, 0, 0], image[3, 5, 1] = np.nan, np.inf
        np.save(tmp / "bad.npy", image)
        target = tmp / "bad.npy"
    else:
        mask = np.zeros(np.load(target).shape[:2], dtype=bool)
        mask[:2, :2] = True  # a corner: the background, no red sphere
        np.save(tmp / "mask.npy", mask)
        extra = ["--mask", str(tmp / "mask.npy")]
    out = tmp / "fitted.json"
    assert main(["fit", str(scene), str(target), "--material", "red", "-o", str(out), *extra]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert re.fullmatch(f"difflab: error: {message}\n", captured.err), captured.err
    assert not out.exists() and not (tmp / "fitted.fit.json").exists()
