"""The command line's options as docs/cli.md states them, each through `difflab.cli.main`: output
kinds, flags of the other renderer, sizes and ranges, --help's defaults, messages naming the problem."""

import json

import numpy as np
import pytest

from difflab import load_image
from difflab.cli import main
from test_cli_io import tiny_scene


@pytest.mark.parametrize("render, flags, message", [
    ({}, ["--method", "raytrace", "--shading", "phong"],
     "--shading: does not apply to this render's method 'raytrace' (the ray tracer shades every hit with "
     "interpolated normals; use --method 'raster')"),
    ({"method": "raytrace"}, ["--shading", "gouraud"], "--shading: does not apply to this render's method 'raytrace'"),
    ({}, ["--max-depth", "1"],
     "--max-depth: does not apply to this render's method 'raster' (the rasterizer draws primary visibility on a "
     "regular sample grid; use --method 'raytrace')"),
])
def test_a_flag_of_the_other_renderer_is_an_error(tmp_path, capsys, render, flags, message):
    """docs/cli.md: --shading is the rasterizer's (an error with the ray tracer, even `phong`, the value
    that says what it does), --max-depth the ray tracer's; the method is the flag's or the scene's."""
    out = tmp_path / "o.png"
    assert main(["render", str(tiny_scene(tmp_path, render=render)), "-o", str(out), *flags]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"difflab: error: {message}") and len(err.splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize("command, name, accepted", [
    ("render", "a.jpg", ".png or .npy"), ("render", "a.tiff", ".png or .npy"), ("render", "noext", ".png or .npy"),
    ("fractal", "k.npy", ".png"), ("fractal", "k.svg", ".png"),
])
def test_an_output_image_of_another_kind_is_refused_naming_the_accepted_ones(tmp_path, capsys, command, name, accepted):
    """-o takes .png (8-bit sRGB) or .npy for render, .png for fractal: Pillow / matplotlib would write
    a lossy JPEG, a TIFF or an SVG from the suffix silently; exit 2, one line, nothing written."""
    out = tmp_path / name
    first = ["render", str(tiny_scene(tmp_path))] if command == "render" else ["fractal", "koch"]
    with pytest.raises(SystemExit) as exit_:  # (argparse's error: Parser.error exits)
        main([*first, "-o", str(out), "--width", "8", "--height", "8"])
    assert exit_.value.code == 2
    assert capsys.readouterr().err == (f"difflab: error: {command}: argument -o/--output: {str(out)!r}: give a file "
                                       f"name ending in {accepted}\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == (["scene.json"] if command == "render" else [])


def test_render_to_npy_with_linear_writes_and_names_the_file_once(tmp_path, capsys):
    """An .npy output is the linear image already: written once, named once (any case of the suffix:
    numpy.save given a name not ending in lower-case .npy appends one, so the data went elsewhere)."""
    scene = tiny_scene(tmp_path)
    out = tmp_path / "b.NPY"
    assert main(["render", str(scene), "-o", str(out), "--linear", "--width", "8", "--height", "6"]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith(f"wrote {out} (8x6, raster, ") and " and " not in printed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.NPY", "scene.json"]
    assert load_image(out).shape == (6, 8, 3)


@pytest.mark.parametrize("kind", ["koch", "peano", "hilbert", "cantor"])
def test_fractal_curves_are_drawn_at_the_given_size(tmp_path, kind):
    """--width / --height are the image's size for the curves too (the curve fit into it, equal axes)."""
    for width, height in [(128, 96), (57, 133)]:
        out = tmp_path / f"{kind}{width}.png"
        assert main(["fractal", kind, "-o", str(out), "--width", str(width), "--height", str(height), "--order", "2"]) == 0
        image = load_image(out)
        assert image.shape == (height, width, 3)
        ink = np.argwhere(image.min(axis=-1) < 0.5)  # the curve's pixels: inside, reaching across one axis
        assert ink.size and max(np.ptp(ink[:, 0]) / height, np.ptp(ink[:, 1]) / width) > 0.9


def test_fractal_refuses_hurst_one_and_sizes_below_one(tmp_path, capsys):
    out = tmp_path / "t.png"
    assert main(["fractal", "terrain", "-o", str(out), "--hurst", "1.0", "--width", "32", "--height", "24"]) == 2
    assert capsys.readouterr().err == "difflab: error: hurst: must be a finite number in (0.0, 1.0), got 1.0\n"
    assert main(["fractal", "koch", "-o", str(out), "--width", "0", "--height", "24"]) == 2
    assert capsys.readouterr().err == "difflab: error: width: must be >= 1, got 0\n"
    assert not out.exists()


@pytest.mark.parametrize("kind, flags, reads", [
    ("mandelbrot", ["--hurst", "0.5"], "--max-iter, --device"),  # these three were ignored silently
    ("mandelbrot", ["--seed", "3"], "--max-iter, --device"),
    ("mandelbulb", ["--order", "3"], "--device"),
    ("julia", ["--order", "3"], "--max-iter, --device"),
    ("mandelbulb", ["--max-iter", "64"], "--device"),
    ("terrain", ["--max-iter", "64"], "--order, --seed, --hurst, --device"),
    ("koch", ["--device", "cpu"], "--order"),  # refused whatever the value, as render's --shading
])
def test_a_fractal_option_the_kind_does_not_read_is_an_error(tmp_path, capsys, kind, flags, reads):
    """docs/cli.md: `difflab fractal` refuses an option its KIND does not read, as `difflab render`
    refuses the other renderer's flags: exit 2, one line naming the option and the fractal, nothing written."""
    out = tmp_path / "f.png"
    assert main(["fractal", kind, "-o", str(out), "--width", "16", "--height", "12", *flags]) == 2
    assert capsys.readouterr().err == f"difflab: error: {flags[0]}: does not apply to the {kind} fractal (it reads {reads})\n"
    assert not out.exists()


@pytest.mark.parametrize("command, shown", [
    ("render", ["--device DEVICE       cpu or cuda (default: cpu)", "(default: the scene's)"]),
    ("fractal", ["(default: 640)", "(default: 480)", "(default: 0.8)", "(default: 256)", "--seed SEED           terrain seed (default: 0)"]),
    ("fit", ["default: lm", "default: l2", "default: 256"]),
    ("demo", ["(default: difflab-demo)"]),
])
def test_help_shows_the_defaults(capsys, command, shown):
    """docs/cli.md: `difflab COMMAND --help` lists the options with their defaults."""
    with pytest.raises(SystemExit) as exit_:
        main([command, "--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    for line in shown:
        assert line in text, line


def test_a_texture_path_that_is_a_folder_is_named_as_such(tmp_path, capsys):
    from difflab import TextureError
    from difflab.renderers.texture.store import load_texture

    (tmp_path / "bricks").mkdir()
    scene = tiny_scene(tmp_path)
    d = json.loads(scene.read_text())
    d["materials"]["m"]["texture"] = "bricks"
    scene.write_text(json.dumps(d))
    assert main(["render", str(scene), "-o", str(tmp_path / "o.png")]) == 2
    assert capsys.readouterr().err == (f"difflab: error: materials.m.texture: a folder, not a file: {tmp_path / 'bricks'} "
                                       f"(in {scene})\n")
    with pytest.raises(TextureError, match=r"^.*bricks: a folder, not a texture file$"):
        load_texture(tmp_path / "bricks")



@pytest.mark.parametrize("kind, order, accepted", [
    ("koch", "10", "0..9 (orders up to 9: at most 1048576 curve vertices, drawn and box-counted in seconds)"),
    ("koch", "11", "0..9 (orders up to 9"), ("koch", "-1", "0..9 (orders up to 9"),
    ("peano", "7", "0..6 (orders up to 6: at most 1048576 curve vertices"),
    ("hilbert", "11", "0..10 (orders up to 10: at most 1048576 curve vertices"),
    ("cantor", "0", "1..60 (the staircase's ternary digits)"), ("cantor", "61", "1..60"),
    ("terrain", "11", "1..10 (levels up to 10: at most 2097152 triangles, rendered in seconds)"),
])
def test_fractal_order_outside_its_work_budget_is_refused_naming_the_option(tmp_path, capsys, kind, order, accepted):
    """docs/cli.md: --order's range per kind is bounded by work (2^20 curve vertices, 2^21 terrain
    triangles: seconds each); beyond it the command ran for minutes (koch 11: over 10 minutes, 1.5 GB).
    The message names the CLI option, not the library's argument (was `iterations: must be in [0, 11]`)."""
    out = tmp_path / "f.png"
    assert main(["fractal", kind, "-o", str(out), "--width", "16", "--height", "12", "--order", order]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"difflab: error: --order: the {kind} fractal takes {accepted}")
    assert err.endswith(f", got {order}\n") and len(err.splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize("kind, order, what", [
    ("koch", "9", "--order 9: the koch curve (786433 vertices)"),
    ("hilbert", "10", "--order 10: the hilbert curve (1048576 vertices)"),
    ("terrain", "10", "--order 10: the terrain (2097152 triangles)"),
])
def test_fractal_order_within_range_is_priced_against_the_memory_budget(tmp_path, capsys, monkeypatch, kind, order,
                                                                         what):
    """docs/limits.md: an accepted order's curve (190 B a vertex, measured 158-172) or terrain (540 B a
    triangle) is priced before anything is built; under DIFFLAB_MEMORY_BUDGET=50M these ran on (koch 11
    and peano 7 still running at 25 s)."""
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "50M")
    out = tmp_path / "f.png"
    assert main(["fractal", kind, "-o", str(out), "--width", "16", "--height", "12", "--order", order]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"difflab: error: {what}: needs about ") and "over the memory budget of 50.0 MiB" in err
    assert not out.exists()


def test_fractal_figure_from_python_names_its_own_argument(tmp_path):
    """The Python API (difflab.demos.fractals.fractal_figure) names its argument `order`, not the option."""
    from difflab.demos.fractals import fractal_figure
    from difflab.errors import DifflabError

    with pytest.raises(DifflabError, match=r"^order: the koch fractal takes 0\.\.9 .*, got 12$"):
        fractal_figure("koch", tmp_path / "k.png", 16, 12, titled=False, order=12)
    assert not (tmp_path / "k.png").exists()
