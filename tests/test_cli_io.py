"""The command line (exit codes, outputs) and the file boundary (sRGB, atomic writes)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from conftest import scene_dict
from difflab import DifflabError, load_image, save_image
from difflab.cli import main
from difflab.files import TMP_MARK, write_json_atomic
from difflab.io import linear_to_srgb, srgb_to_linear


def tiny_scene(tmp_path, **changes):
    d = scene_dict([{"type": "sphere", "center": [0, 0, 0], "radius": 0.8, "material": "m"}],
                   {"m": {"ka": [0.1] * 3, "kd": [0.6, 0.3, 0.2], "ks": [0.3] * 3, "n": 10}},
                   lights=[{"type": "point", "position": [2, 3, 4]}], ambient=(0.2, 0.2, 0.2))
    d.update(changes)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(d))
    return path


def test_srgb_round_trip_and_known_values():
    x = np.linspace(0, 1, 1001)
    np.testing.assert_allclose(srgb_to_linear(linear_to_srgb(x)), x, atol=1e-12)
    assert linear_to_srgb(0.0031308) == pytest.approx(12.92 * 0.0031308)
    assert srgb_to_linear(1.0) == pytest.approx(1.0)
    # IEC 61966-2-1 at mid-grey both ways, and encoding clamps to [0, 1] first
    assert linear_to_srgb(0.5) == pytest.approx(1.055 * 0.5 ** (1 / 2.4) - 0.055, rel=1e-15)
    assert srgb_to_linear(0.5) == pytest.approx(((0.5 + 0.055) / 1.055) ** 2.4, rel=1e-15)
    np.testing.assert_allclose(linear_to_srgb([-0.5, 1.7, 1e30]), [0.0, 1.0, 1.0], atol=1e-15)


def test_png_and_npy_round_trip(tmp_path):
    image = np.random.default_rng(0).uniform(0, 1, (5, 7, 3)).astype(np.float32)
    save_image(tmp_path / "a.npy", image)
    assert np.array_equal(load_image(tmp_path / "a.npy"), image)
    save_image(tmp_path / "a.png", image)
    back = load_image(tmp_path / "a.png")
    assert back.shape == (5, 7, 3)
    np.testing.assert_allclose(back, image, atol=0.01)  # 8-bit sRGB quantisation
    save_image(tmp_path / "b.NPY", image)  # (numpy.save appends .npy to a name ending otherwise)
    assert np.array_equal(load_image(tmp_path / "b.NPY"), image)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npy", "a.png", "b.NPY"]


def test_non_finite_pixels_are_reported_not_hidden(tmp_path):
    image = np.zeros((2, 2, 3), np.float32)
    image[0, 0, 1] = np.nan
    with pytest.raises(DifflabError, match="1 non-finite"):
        save_image(tmp_path / "bad.png", image)
    assert not (tmp_path / "bad.png").exists()


def test_a_writer_failing_midway_leaves_the_old_file(tmp_path, monkeypatch):
    target = tmp_path / "out.png"
    save_image(target, np.full((4, 4, 3), 0.5, np.float32))
    before = target.read_bytes()

    def broken_save(self, fp, *args, **kwargs):
        with open(fp, "wb") as f:
            f.write(b"half a PNG")
        raise OSError("disk full")

    monkeypatch.setattr(Image.Image, "save", broken_save)
    with pytest.raises(OSError, match="disk full"):
        save_image(target, np.zeros((4, 4, 3), np.float32))
    assert target.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.png"]  # no temporary left behind
    assert target.stat().st_mode & 0o044  # readable by others, like a plain open() would make it
    write_json_atomic(tmp_path / "x.json", {"a": 1})
    assert json.loads((tmp_path / "x.json").read_text()) == {"a": 1}


def test_a_killed_writers_temporary_is_removed_by_the_next_write_unless_swept_already(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = tmp_path / f".x.json.{int(dead.stdout)}.k1ll{TMP_MARK}.json"  # as a writer killed by SIGKILL leaves it
    stale.write_text("{")
    write_json_atomic(tmp_path / "x.json", {"a": 1}, sweep=False)  # the caller swept the folder itself
    assert stale.exists()
    write_json_atomic(tmp_path / "x.json", {"a": 2})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.json"]
    assert json.loads((tmp_path / "x.json").read_text()) == {"a": 2}


def test_render_command_writes_png_and_linear_npy(tmp_path, capsys):
    scene = tiny_scene(tmp_path)
    out = tmp_path / "out.png"
    assert main(["render", str(scene), "-o", str(out), "--shading", "gouraud", "--width", "24", "--height", "16",
                 "--linear"]) == 0
    image = load_image(tmp_path / "out.npy")
    assert image.shape == (16, 24, 3) and image.max() > 0.1
    with Image.open(out) as png:
        assert png.size == (24, 16)
    assert "wrote" in capsys.readouterr().out


def test_render_writes_the_png_and_its_linear_copy_together(tmp_path, capsys, monkeypatch):
    """--linear: a full disk while writing the PNG leaves no .npy either (the .npy was renamed into
    place first, then the PNG failed: one output without the other), exit 2."""
    import errno

    import difflab.io as io

    scene = tiny_scene(tmp_path)
    out = tmp_path / "out.png"
    write = io.write_image

    def full_on_png(path, image, *args, **kwargs):
        if str(path).endswith(".png"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return write(path, image, *args, **kwargs)

    monkeypatch.setattr(io, "write_image", full_on_png)
    assert main(["render", str(scene), "-o", str(out), "--width", "8", "--height", "8", "--linear"]) == 2
    assert "No space left on device" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.json"]


def test_held_signals_are_delivered_even_when_the_block_fails():
    """`uninterrupted`: a SIGTERM arriving inside the block is held, and delivered to the handler
    in place before it when the block ends -- also when the block raised (it was dropped: a caller
    catching the error ran on after a SIGTERM)."""
    import signal

    import difflab.io as io

    seen = []
    old_term = signal.signal(signal.SIGTERM, lambda number, frame: seen.append(number))
    try:
        with pytest.raises(OSError), io.uninterrupted():
            signal.raise_signal(signal.SIGTERM)
            assert seen == []  # held
            raise OSError("disk full")
        assert seen == [signal.SIGTERM]  # delivered
    finally:
        signal.signal(signal.SIGTERM, old_term)


@pytest.mark.parametrize("change, message", [
    ({"objects": [{"type": "sphere", "center": [0, 0, 0], "radius": -1, "material": "m"}]}, "objects[0].radius"),
    ({"objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "nope"}]}, "undefined material"),
    ({"objects": [{"type": "mesh", "file": "missing.obj", "material": "m"}]}, "missing.obj"),
])
def test_bad_scene_exits_2_with_a_one_line_message(tmp_path, capsys, change, message):
    scene = tiny_scene(tmp_path, **change)
    assert main(["render", str(scene), "-o", str(tmp_path / "o.png")]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o.png").exists()


def test_bad_option_exits_2(tmp_path, capsys):
    assert main(["render", str(tiny_scene(tmp_path)), "-o", str(tmp_path / "o.png"), "--spp", "2"]) == 2
    assert "spp" in capsys.readouterr().err


@pytest.mark.parametrize("kind, flags", [("koch", ["--order", "3"]), ("cantor", ["--order", "3"]),
                                         ("mandelbrot", ["--max-iter", "64"]), ("terrain", ["--order", "3", "--seed", "2"])])
def test_fractal_command(tmp_path, kind, flags, capsys):
    out = tmp_path / f"{kind}.png"
    assert main(["fractal", kind, "-o", str(out), "--width", "64", "--height", "48", *flags]) == 0
    assert out.stat().st_size > 100
    assert capsys.readouterr().err == ""  # no progress bar where stderr is not a terminal


def test_demo_writes_every_figure(tmp_path):
    """The README's main job, as a subprocess (the console entry point), at the quick size."""
    result = subprocess.run([sys.executable, "-m", "difflab.cli", "demo", "--quick", "-o", str(tmp_path)],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    index = (tmp_path / "difflab-demo.txt").read_text()
    for name in ["shading_models.png", "decomposition.png", "materials.png", "materials.csv", "fractal_koch.png"]:
        assert (tmp_path / name).stat().st_size > 100, name
        assert name in result.stdout and f"\n{name}: " in index


def test_demo_runs_again_into_its_own_folder(tmp_path, capsys, monkeypatch):
    """README's quickstart `difflab demo` works a second time (it exited 2: difflab-demo exists): the
    demo's own folder -- marked by its index, difflab-demo.txt -- is written again without --force, as a
    batch's folder is resumed; a folder of other files, or an index.txt the demo did not write, is not."""
    import difflab.demos as demos

    def section(out, size):
        (out / "figure.png").write_bytes(b"figure %d" % size)
        return [(out / "figure.png", "a figure")]

    monkeypatch.setattr(demos, "sections", lambda: [section])
    folder = tmp_path / "difflab-demo"
    assert main(["demo", "--quick", "-o", str(folder)]) == 0
    (folder / "figure.png").write_bytes(b"old")
    assert main(["demo", "--quick", "-o", str(folder)]) == 0  # was exit 2: exists; use --force
    assert (folder / "figure.png").read_bytes() == b"figure 96"
    assert (folder / "difflab-demo.txt").read_text().splitlines()[1:] == ["figure.png: a figure"]
    capsys.readouterr()
    other = tmp_path / "other"
    other.mkdir()
    (other / "difflab-demo.txt").write_text("my notes")
    assert main(["demo", "--quick", "-o", str(other)]) == 2
    assert capsys.readouterr().err == f"difflab: error: {other}: exists; use --force to overwrite\n"
    assert sorted(p.name for p in other.iterdir()) == ["difflab-demo.txt"]


# ---- one overwrite rule for every command, exit codes through the real main ----------------------


def overwrite_cases(tmp_path):
    """(argv, output) of each command at a tiny size, writing to `output`."""
    scene = tiny_scene(tmp_path)
    return {
        "render": (["render", str(scene), "-o", str(tmp_path / "r.png"), "--width", "8", "--height", "8"],
                   tmp_path / "r.png"),
        "fractal": (["fractal", "koch", "-o", str(tmp_path / "k.png"), "--width", "32", "--height", "24",
                     "--order", "2"], tmp_path / "k.png"),
        "demo": (["demo", "--quick", "-o", str(tmp_path / "demo")], tmp_path / "demo"),
        "fit": (["fit", str(scene), str(tmp_path / "target.npy"), "--material", "m", "--params", "kd",
                 "-o", str(tmp_path / "fitted.json")], tmp_path / "fitted.json"),
    }


@pytest.mark.parametrize("command", ["render", "fractal", "demo", "fit"])
def test_no_command_overwrites_without_force(tmp_path, capsys, command):
    """An existing output (for demo: a folder with a file in it) is refused with exit 2, one line
    naming it and the flag, and left as it was; --force overwrites it."""
    argv, output = overwrite_cases(tmp_path)[command]
    save_image(tmp_path / "target.npy", np.full((32, 32, 3), 0.2, np.float32))
    if command == "demo":
        output.mkdir()
        (output / "mine.txt").write_text("keep")
        probe = output / "mine.txt"
    else:
        output.write_text("keep")
        probe = output
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"difflab: error: {output}: exists; use --force to overwrite"
    assert probe.read_text() == "keep"
    if command in ("render", "fractal"):  # the demo runs once, in test_demo_writes_every_figure; fits in test_fit_cli
        assert main([*argv, "--force"]) == 0
        assert output.stat().st_size > 100 and output.read_bytes() != b"keep"


def test_render_refuses_to_overwrite_the_linear_npy(tmp_path, capsys):
    scene = tiny_scene(tmp_path)
    (tmp_path / "o.npy").write_text("keep")
    assert main(["render", str(scene), "-o", str(tmp_path / "o.png"), "--linear", "--width", "8", "--height", "8"]) == 2
    assert "o.npy: exists" in capsys.readouterr().err
    assert not (tmp_path / "o.png").exists() and (tmp_path / "o.npy").read_text() == "keep"


def test_an_internal_error_exits_1_with_a_traceback(tmp_path, capsys, monkeypatch):
    """A bug (not a DifflabError) is exit 1 through the real main, with the traceback to report."""
    from difflab import commands

    def broken(args):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(commands, "run_render", broken)  # main builds its parser at each call
    assert main(["render", str(tiny_scene(tmp_path)), "-o", str(tmp_path / "o.png")]) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and "ZeroDivisionError: a bug" in err
    assert not (tmp_path / "o.png").exists()


def test_render_command_ray_traces_with_the_given_depth_and_specular(tmp_path):
    """--method raytrace --max-depth --specular reach the renderer: the written linear image equals
    difflab.render with the same overrides, and differs when the flag differs."""
    from difflab import render

    d = json.loads(tiny_scene(tmp_path).read_text())
    d["objects"].append({"type": "plane", "point": [0, -0.8, 0], "normal": [0, 1, 0], "material": "floor"})
    d["materials"]["floor"] = {"kd": [0.3] * 3, "kr": 0.5}
    d["materials"]["m"]["kr"] = 0.5
    scene = tmp_path / "mirror.json"
    scene.write_text(json.dumps(d))
    images = {}
    for depth, specular in [(1, "phong"), (3, "phong"), (3, "blinn")]:
        out = tmp_path / f"d{depth}{specular}.npy"
        assert main(["render", str(scene), "-o", str(out), "--method", "raytrace", "--max-depth", str(depth),
                     "--specular", specular, "--width", "16", "--height", "16"]) == 0
        images[depth, specular] = load_image(out)
        want = render(d, method="raytrace", max_depth=depth, specular=specular, width=16, height=16)
        np.testing.assert_array_equal(images[depth, specular], want)
    assert np.abs(images[3, "phong"] - images[1, "phong"]).max() > 0.05  # reflections appear
    assert np.abs(images[3, "blinn"] - images[3, "phong"]).max() > 0.01  # another highlight


def test_linear_8_bit_files_skip_the_srgb_curve(tmp_path):
    """srgb=False writes round(255 clip(x)) and reads back k / 255, no transfer curve either way."""
    image = np.array([[[0.0, 0.2, 0.5], [0.75, 1.0, 1.7]]], np.float32)
    save_image(tmp_path / "lin.png", image, srgb=False)
    with Image.open(tmp_path / "lin.png") as png:
        stored = np.asarray(png)[..., :3]
    np.testing.assert_array_equal(stored, np.round(np.clip(image, 0, 1) * 255).astype(np.uint8))
    np.testing.assert_allclose(load_image(tmp_path / "lin.png", srgb=False), stored / 255.0, atol=1e-7)
    save_image(tmp_path / "enc.png", image)  # the default encodes: mid-grey is stored brighter
    np.testing.assert_allclose(load_image(tmp_path / "enc.png", srgb=False)[0, 0, 2],
                               np.round(255 * linear_to_srgb(0.5)) / 255, atol=1e-7)


# ---- the render command does only the image's work; outputs that cannot be written ---------------


def glass_planes(tmp_path):
    """Two glass planes (every hit spawns a reflected and a refracted ray), 24x16 at spp 16: its
    recorded ray tree has 24576 nodes (about 3.9 MiB), the image alone needs under 2 MiB."""
    d = scene_dict([{"type": "plane", "point": [0, 0, -1], "normal": [0, 0.3, 1], "material": "glass"},
                    {"type": "plane", "point": [0, -0.8, 0], "normal": [0, 1, 0], "material": "floor"}],
                   {"glass": {"kd": [0.0] * 3, "ks": [0.3] * 3, "n": 10, "kr": 0.5, "kt": 0.8, "ior": 1.5},
                    "floor": {"kd": [0.5] * 3, "kr": 0.5}},
                   lights=[{"type": "point", "position": [2, 3, 4]}],
                   render={"method": "raytrace", "max_depth": 6, "spp": 16})
    d["camera"].update(width=24, height=16)
    path = tmp_path / "glass.json"
    path.write_text(json.dumps(d))
    return d, path


def test_render_command_renders_the_image_alone_within_a_budget_the_ray_tree_is_over(tmp_path, monkeypatch, capsys):
    """`difflab render` forms the image as `difflab.render` does (no recorded ray tree, no G-buffer):
    under a 2 MB budget that refuses recording this scene's ray tree, it writes the same pixels."""
    from difflab import RenderError, render, render_frame

    d, scene = glass_planes(tmp_path)
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "2M")
    with pytest.raises(RenderError, match="record_tree: a ray tree of 24576 nodes"):
        render_frame(d)
    out = tmp_path / "glass.npy"
    assert main(["render", str(scene), "-o", str(out)]) == 0
    np.testing.assert_array_equal(load_image(out), render(d))
    assert capsys.readouterr().out.startswith(f"wrote {out} (24x16, raytrace, ")


def output_cases(tmp_path, folder):
    """(argv, output) of each command that writes a file, writing into `folder` (inputs in tmp_path)."""
    scene = tiny_scene(tmp_path)
    save_image(tmp_path / "target.npy", np.full((32, 32, 3), 0.2, np.float32))
    return {
        "render": (["render", str(scene), "-o", str(folder / "r.png"), "--width", "8", "--height", "8"], folder / "r.png"),
        "fractal": (["fractal", "koch", "-o", str(folder / "k.png"), "--width", "64", "--height", "48", "--order", "2"],
                    folder / "k.png"),
        "fit": (["fit", str(scene), str(tmp_path / "target.npy"), "--material", "m", "--params", "kd",
                 "-o", str(folder / "fitted.json")], folder / "fitted.json"),
    }


@pytest.mark.parametrize("where", ["read-only folder", "/sys"])
@pytest.mark.parametrize("command", ["render", "fractal", "fit"])
def test_an_output_folder_that_takes_no_files_is_refused_before_the_work(tmp_path, capsys, monkeypatch, command, where):
    """Exit 2, one line naming the folder, and the command's work never starts: a folder without
    write permission, and /sys, where even root cannot create a file (os.access says yes to root:
    the folder is probed by creating a file). Root may write in a folder without write permission,
    so there the probe's file creation is refused as the kernel refuses it to anyone else (EACCES)."""
    from difflab import commands
    from difflab.fit import command as fit_command

    if where == "/sys":
        folder = Path("/sys")
        if not folder.is_dir():
            pytest.skip("no /sys on this system")
    else:
        folder = tmp_path / "locked"
        folder.mkdir()
        folder.chmod(0o500)
        if os.geteuid() == 0:
            import errno
            import tempfile

            mkstemp = tempfile.mkstemp

            def refused(*args, dir=None, **kwargs):
                if dir is not None and Path(dir) == folder:
                    raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(folder))
                return mkstemp(*args, dir=dir, **kwargs)

            monkeypatch.setattr(tempfile, "mkstemp", refused)
    argv, _ = output_cases(tmp_path, folder)[command]

    def work(args):
        raise AssertionError("the work started")

    monkeypatch.setattr(*{"render": (commands, "run_render"), "fractal": (commands, "run_fractal"),
                          "fit": (fit_command, "run")}[command], work)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"difflab: error: -o/--output: ") and str(folder) in err[0]
    assert "not writable" in err[0] or "cannot write in folder" in err[0]


@pytest.mark.parametrize("command", ["render", "fractal", "fit"])
def test_a_full_disk_while_writing_is_one_line_exit_2_and_leaves_nothing(tmp_path, capsys, monkeypatch, command):
    """OSError(ENOSPC) from the writer, after the work: `difflab: error: OUTPUT: cannot write (...)`,
    exit 2, no output and no temporary left in the folder."""
    import errno
    import pathlib

    import matplotlib.figure

    folder = tmp_path / "out"
    folder.mkdir()
    argv, output = output_cases(tmp_path, folder)[command]

    def full_disk(self, fp, *args, **kwargs):  # (Path.write_text(self, data) writes to self)
        with open(self if isinstance(self, pathlib.Path) else fp, "wb") as f:
            f.write(b"the start of a file")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(*{"render": (Image.Image, "save"), "fractal": (matplotlib.figure.Figure, "savefig"),
                          "fit": (pathlib.Path, "write_text")}[command], full_disk)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"difflab: error: {output}: cannot write ({os.strerror(errno.ENOSPC)}); not written"
    assert list(folder.iterdir()) == []


def test_an_interrupted_command_exits_130(tmp_path, capsys, monkeypatch):
    """Ctrl-C (KeyboardInterrupt) is exit 130 (128 + SIGINT, as shells report it), not 1 (a bug),
    with one line and no traceback; a write it interrupts leaves nothing."""
    folder = tmp_path / "out"
    folder.mkdir()

    def interrupted(self, fp, *args, **kwargs):
        with open(fp, "wb") as f:
            f.write(b"half")
        raise KeyboardInterrupt

    monkeypatch.setattr(Image.Image, "save", interrupted)
    argv, _ = output_cases(tmp_path, folder)["render"]
    assert main(argv) == 130
    assert capsys.readouterr().err == "difflab: interrupted\n"
    assert list(folder.iterdir()) == []

