"""The file boundary under hostile input: every library failure is a DifflabError naming the path,
sizes are checked before decoding, scene files are read only from bounded regular files, temporary
files do not outlive their writer, and bad output paths are refused up front with exit code 2."""

import json
import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from PIL import Image

from conftest import scene_dict
from difflab import DifflabError, Scene, SceneError, load_image, load_scene, save_image
from difflab.cli import main

SPHERE = [{"type": "sphere", "center": [0, 0, 0], "radius": 0.8, "material": "m"}]


def write_scene(tmp_path, text=None, **changes):
    d = scene_dict(SPHERE, {"m": {"kd": 0.5}}, lights=[{"type": "point", "position": [2, 3, 4]}])
    d.update(changes)
    path = tmp_path / "scene.json"
    path.write_text(text if text is not None else json.dumps(d))
    return path


# -- images -------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("array, message", [
    (np.array([[{"a": 1}]], dtype=object), r"image array must hold real numbers .* got dtype object"),
    (np.full((2, 2, 3), "x"), r"image array must hold real numbers .* got dtype <U1"),
    (np.ones((2, 2, 3), np.complex64), r"image array must hold real numbers .* got dtype complex64"),
    (np.ones((2, 2, 5), np.float32), r"expected an image array of shape .* got \(2, 2, 5\)"),
    (np.ones((0, 2, 3), np.float32), r"expected an image array of shape .* got \(0, 2, 3\)"),
])
def test_npy_images_must_be_real_numeric_images(tmp_path, array, message):
    path = tmp_path / "bad.npy"
    np.save(path, array, allow_pickle=True)
    with pytest.raises(DifflabError, match=r"bad\.npy: " + message):
        load_image(path)


def test_npy_truncated_or_garbage_is_named(tmp_path):
    path = tmp_path / "cut.npy"
    np.save(path, np.ones((64, 64, 3), np.float32))
    path.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(DifflabError, match=r"cut\.npy: \.npy file is truncated \(1000 of 49280 bytes\)"):
        load_image(path)
    path.write_bytes(b"\x93NUMPY garbage")
    with pytest.raises(DifflabError, match=r"cut\.npy: not a valid \.npy file"):
        load_image(path)


def test_npy_integer_images_are_code_values_and_bool_images_load_as_float(tmp_path):
    """An integer .npy holds a file's code values, not linear light (it was read as 0..65535)."""
    np.save(tmp_path / "i.npy", np.array([[1, 2]], np.int16))
    with pytest.raises(DifflabError, match=r"i\.npy: integer data \(int16\) are code values, not linear light; "
                                           r"give linear floats -- image / 65535\.0: "):
        load_image(tmp_path / "i.npy")
    np.save(tmp_path / "b.npy", np.array([[True, False]]))
    assert load_image(tmp_path / "b.npy")[0, :, 0].tolist() == [1.0, 0.0]


def test_png_decoding_matches_the_srgb_formula(tmp_path):
    levels = np.arange(256, dtype=np.uint8)
    Image.fromarray(np.stack([levels] * 3, axis=-1)[None]).save(tmp_path / "ramp.png")
    c = levels / 255.0
    want = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)
    np.testing.assert_array_equal(load_image(tmp_path / "ramp.png")[0, :, 1], want)
    np.testing.assert_array_equal(load_image(tmp_path / "ramp.png", srgb=False)[0, :, 2], c.astype(np.float32))


def test_image_size_is_checked_from_the_header_before_decoding(tmp_path, monkeypatch):
    big = tmp_path / "big.png"  # 120 megapixels in ~20 KB: under Pillow's bomb limit (179M), over our budget
    Image.new("1", (12000, 10000)).save(big)
    assert big.stat().st_size < 100_000
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "1G")
    with pytest.raises(DifflabError, match=r"big\.png \(12000 x 10000 pixels\): needs about 3\.35 GiB, over the "
                                           r"memory budget of 1\.00 GiB \(DIFFLAB_MEMORY_BUDGET"):
        load_image(big)
    bomb = tmp_path / "bomb.png"  # 400 megapixels: Pillow refuses it as a decompression bomb
    Image.new("1", (20000, 20000)).save(bomb)
    monkeypatch.setenv("DIFFLAB_MEMORY_BUDGET", "1T")
    with pytest.raises(DifflabError, match=r"bomb\.png: cannot read image: more pixels than Pillow opens \(Image size "
                                           r"\(400000000 pixels\) exceeds limit"):
        load_image(bomb)


def test_broken_or_missing_picture_files_are_named(tmp_path):
    save_image(tmp_path / "ok.png", np.random.default_rng(0).random((64, 64, 3)))
    (tmp_path / "cut.png").write_bytes((tmp_path / "ok.png").read_bytes()[:2000])
    with pytest.raises(DifflabError, match=r"cut\.png: cannot read image: the file is damaged or cut short \(image file "
                                           r"is truncated\)$"):
        load_image(tmp_path / "cut.png")
    with pytest.raises(DifflabError, match=r"nothing\.png: image file not found"):
        load_image(tmp_path / "nothing.png")
    (tmp_path / "dir.png").mkdir()
    with pytest.raises(DifflabError, match=r"dir\.png: a folder, not an image file$"):
        load_image(tmp_path / "dir.png")


def test_save_image_refuses_non_real_arrays(tmp_path):
    with pytest.raises(DifflabError, match=r"image: must hold real numbers .* got dtype complex128"):
        save_image(tmp_path / "c.npy", np.ones((2, 2, 3), complex))
    assert list(tmp_path.iterdir()) == []


# -- scene files --------------------------------------------------------------------------------------------

def test_scene_files_must_be_bounded_regular_files(tmp_path, monkeypatch):
    with pytest.raises(SceneError, match=r"^/dev/zero: scene file is not a regular file$"):
        load_scene("/dev/zero")
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    with pytest.raises(SceneError, match=r"pipe\.json: scene file is not a regular file"):  # at once, no writer needed
        load_scene(fifo)
    (tmp_path / "folder.json").mkdir()
    with pytest.raises(SceneError, match=r"folder\.json: scene file is not a regular file"):
        load_scene(tmp_path / "folder.json")
    path = write_scene(tmp_path)
    monkeypatch.setattr("difflab.scene.scene.MAX_SCENE_BYTES", 100)
    with pytest.raises(SceneError, match=rf"scene\.json: file is {path.stat().st_size} bytes, over the limit of 100"):
        load_scene(path)
    path.write_bytes(b'{"\xff": 1}')
    with pytest.raises(SceneError, match=r"scene\.json: not UTF-8 text \(invalid start byte at byte 2\)"):
        load_scene(path)


def test_huge_integer_literals_name_their_field(tmp_path):
    huge = "1" * 5000
    text = json.dumps(scene_dict(SPHERE, {"m": {}})).replace('"radius": 0.8', f'"radius": {huge}')
    with pytest.raises(SceneError, match=r"^objects\[0\]\.radius: must be finite, got inf \(in .*scene\.json\)$"):
        load_scene(write_scene(tmp_path, text))
    text = json.dumps(scene_dict(SPHERE, {"m": {}})).replace('"width": 32', f'"width": {huge}')
    with pytest.raises(SceneError, match=r"^camera\.width: expected an integer, got inf"):
        load_scene(write_scene(tmp_path, text))


def test_long_user_strings_do_not_make_long_messages():
    d = scene_dict(SPHERE, {"m": {}})
    d["k" * 10000] = 1
    with pytest.raises(SceneError) as info:
        Scene.from_dict(d)
    message = str(info.value)
    assert len(message) <= 400 and message.startswith("scene: unknown key 'kkk") and "[...]" in message


# -- temporary files ----------------------------------------------------------------------------------------

SLOW_WRITER = textwrap.dedent("""
    import sys, time
    import numpy as np
    from PIL import Image
    from difflab import save_image

    def slow_save(self, fp, *args, **kwargs):
        with open(fp, "wb") as f:
            f.write(b"half a PNG")
        print("writing", flush=True)
        time.sleep(60)

    Image.Image.save = slow_save
    save_image(sys.argv[1], np.zeros((4, 4, 3), np.float32))
""")


def killed_writer(tmp_path, sig):
    """Start a writer of tmp_path/out.png that hangs midway, kill it with `sig`, return the folder's names."""
    out = tmp_path / "out.png"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    with subprocess.Popen([sys.executable, "-c", SLOW_WRITER, str(out)], stdout=subprocess.PIPE, env=env,
                          text=True) as child:
        assert child.stdout.readline() == "writing\n"
        child.send_signal(sig)
        assert child.wait(timeout=30) == -sig
    return sorted(p.name for p in tmp_path.iterdir())


def test_sigterm_during_a_write_removes_the_temporary(tmp_path):
    assert killed_writer(tmp_path, signal.SIGTERM) == []


def test_sigkill_leaves_a_temporary_that_the_next_write_removes(tmp_path):
    left = killed_writer(tmp_path, signal.SIGKILL)
    assert len(left) == 1 and left[0].startswith(".out.png.") and left[0].endswith(".tmp.png")
    save_image(tmp_path / "out.png", np.zeros((2, 2, 3), np.float32))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.png"]


def test_a_live_writers_temporary_is_kept(tmp_path):
    live = tmp_path / f".out.png.{os.getppid()}.abcd.tmp.png"  # our parent is alive
    live.write_bytes(b"in progress")
    save_image(tmp_path / "out.png", np.zeros((2, 2, 3), np.float32))
    assert live.exists()


# -- the command line ---------------------------------------------------------------------------------------

def one_line_error(capsys, argv, match):
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("difflab: error: "), err
    assert match in err, err


@pytest.mark.parametrize("output, match", [
    ("{dir}", "-o/--output: {dir} is a folder; give a file name"),
    ("{dir}/missing/out.png", "-o/--output: folder {dir}/missing does not exist"),
    ("{dir}/file.json/out.png", "-o/--output: {dir}/file.json is a file, not a folder"),
])
def test_render_output_paths_are_checked_before_rendering(tmp_path, capsys, output, match):
    scene = write_scene(tmp_path)
    (tmp_path / "file.json").write_text("{}")
    one_line_error(capsys, ["render", str(scene), "-o", output.format(dir=tmp_path)], match.format(dir=tmp_path))


def test_argument_errors_are_one_line_with_exit_2(tmp_path, capsys):
    scene = write_scene(tmp_path)
    with pytest.raises(SystemExit) as info:
        main(["render", str(scene), "-o", str(tmp_path / "x.png"), "--width", "abc"])
    err = capsys.readouterr().err
    assert info.value.code == 2 and err == "difflab: error: render: argument --width: invalid int value: 'abc'\n"
    with pytest.raises(SystemExit) as info:
        main(["render", str(scene), "-o", str(tmp_path / "x.png"), "--bogus"])
    assert info.value.code == 2 and capsys.readouterr().err == "difflab: error: unrecognized arguments: --bogus\n"
    with pytest.raises(SystemExit) as info:
        main([])
    assert info.value.code == 2 and capsys.readouterr().err.count("\n") == 1


def test_cli_scene_errors_are_one_line(tmp_path, capsys):
    one_line_error(capsys, ["render", "/dev/zero", "-o", str(tmp_path / "x.png")],
                   "/dev/zero: scene file is not a regular file")
    multi = write_scene(tmp_path, json.dumps(scene_dict(SPHERE, {"m": {}}))[:-1] + ', "bad\\nkey": 1}')
    one_line_error(capsys, ["render", str(multi), "-o", str(tmp_path / "x.png")], "scene: unknown key 'bad\\nkey'")


def test_devices_and_fifos_are_never_replaced(tmp_path):
    fifo = tmp_path / "pipe.png"
    os.mkfifo(fifo)
    for target in ("/dev/null", fifo):
        with pytest.raises(DifflabError, match=rf"^output: {target} exists and is not a regular file$"):
            save_image(target, np.zeros((2, 2, 3), np.float32))
    assert os.path.exists("/dev/null") and not os.path.isfile("/dev/null")


@pytest.mark.parametrize("bad", [None, 5, b"x.png", "", "a\x00b.png", ["x.png"]])
def test_paths_must_be_strings_or_path_likes(tmp_path, bad):
    with pytest.raises(DifflabError, match=r"^image: expected a file path, got "):
        load_image(bad)
    with pytest.raises(DifflabError, match=r"^image: expected a file path, got "):
        save_image(bad, np.zeros((2, 2, 3), np.float32))
    with pytest.raises(SceneError, match=r"^scene: expected a file path, got "):
        load_scene(bad)


def test_running_out_of_memory_is_one_line_with_exit_2(tmp_path, capsys, monkeypatch):
    def exhausted(*args, **kwargs):
        raise MemoryError

    monkeypatch.setattr("difflab.renderers.api.compile_scene", exhausted)
    one_line_error(capsys, ["render", str(write_scene(tmp_path)), "-o", str(tmp_path / "x.png")],
                   "difflab: error: out of memory: the request is too big for this machine")
