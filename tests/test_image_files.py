"""Image files as other programs write them: 16-bit samples (read whole, not as their high bytes) and
the colour chunks that say how samples map to light (sRGB, or a gAMA chunk: 1.0 is linear). The
files are written here byte by byte (PNG: signature, IHDR, optional sRGB / gAMA, IDAT, IEND; TIFF:
one uncompressed strip, either byte order)."""

import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from difflab import fit_material, load_image
from difflab.errors import DifflabError
from difflab.io import sample_bits, save_image, srgb_to_linear
from difflab.renderers.api import render_frame
from difflab.scene import Scene

COLOUR_TYPE = {1: 0, 2: 4, 3: 2, 4: 6}  # channels -> PNG colour type (grey, grey + alpha, RGB, RGBA)


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def write_png(path, samples: np.ndarray, *, srgb_chunk=False, gamma=None):
    """A PNG of integer samples (H, W, C), 8 or 16 bits by dtype, every row with filter 0."""
    height, width, channels = samples.shape
    bits = 16 if samples.dtype == np.uint16 else 8
    raw = samples.astype(">u2" if bits == 16 else np.uint8).reshape(height, -1).view(np.uint8)
    rows = np.concatenate([np.zeros((height, 1), np.uint8), raw], axis=1)
    data = b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, bits, COLOUR_TYPE[channels],
                                                               0, 0, 0))
    if srgb_chunk:
        data += _chunk(b"sRGB", b"\x00")
    if gamma is not None:
        data += _chunk(b"gAMA", struct.pack(">I", round(gamma * 100000)))
    data += _chunk(b"IDAT", zlib.compress(rows.tobytes())) + _chunk(b"IEND", b"")
    path.write_bytes(data)
    return path


def write_tiff(path, samples: np.ndarray, little_endian: bool):
    """An uncompressed 16-bit RGB TIFF: header, one IFD of 9 entries, BitsPerSample, one strip."""
    height, width, _ = samples.shape
    order = "<" if little_endian else ">"
    pixels = samples.astype(order + "u2").tobytes()
    bits_at = 8 + 2 + 9 * 12 + 4
    entry = lambda tag, kind, count, value: struct.pack(order + "HHI", tag, kind, count) + (  # noqa: E731
        struct.pack(order + "HH", value, 0) if kind == 3 and count == 1 else struct.pack(order + "I", value))
    entries = [entry(256, 4, 1, width), entry(257, 4, 1, height), entry(258, 3, 3, bits_at), entry(259, 3, 1, 1),
               entry(262, 3, 1, 2), entry(273, 4, 1, bits_at + 6), entry(277, 3, 1, 3), entry(278, 4, 1, height),
               entry(279, 4, 1, len(pixels))]
    path.write_bytes((b"II*\x00" if little_endian else b"MM\x00*") + struct.pack(order + "IH", 8, 9) + b"".join(entries)
                     + struct.pack(order + "I", 0) + struct.pack(order + "3H", 16, 16, 16) + pixels)
    return path


@pytest.fixture()
def ramp16():
    rng = np.random.default_rng(3)
    return rng.integers(0, 65536, size=(5, 7, 3)).astype(np.uint16)


@pytest.mark.parametrize("chunks", [{}, {"srgb_chunk": True, "gamma": 0.45455}])
def test_16_bit_rgb_is_read_whole_and_srgb_decoded(tmp_path, ramp16, chunks):
    image = load_image(write_png(tmp_path / "a.png", ramp16, **chunks))
    np.testing.assert_allclose(image, srgb_to_linear(ramp16 / 65535.0), rtol=1e-6, atol=1e-9)
    assert sample_bits(tmp_path / "a.png") == 16


def test_16_bit_linear_rgba_and_grey(tmp_path, ramp16):
    """gAMA 1.0 without an sRGB chunk: the samples are linear (POV-Ray's File_Gamma=1.0); alpha is
    dropped; 16-bit grey fills the three channels."""
    rgba = np.concatenate([ramp16, np.full(ramp16.shape[:2] + (1,), 65535, np.uint16)], axis=-1)
    np.testing.assert_allclose(load_image(write_png(tmp_path / "l.png", rgba, gamma=1.0)), ramp16 / 65535.0,
                               rtol=1e-6, atol=1e-9)
    grey = load_image(write_png(tmp_path / "g.png", ramp16[..., :1]))
    np.testing.assert_allclose(grey, np.repeat(srgb_to_linear(ramp16[..., :1] / 65535.0), 3, axis=-1), rtol=1e-6)
    # srgb=False reads every file's samples as linear values (masks)
    np.testing.assert_allclose(load_image(tmp_path / "g.png", srgb=False)[..., 1], ramp16[..., 0] / 65535.0, rtol=1e-6)


@pytest.mark.parametrize("channels", [1, 2, 3, 4])
def test_every_16_bit_png_colour_type_is_read_whole(tmp_path, ramp16, channels):
    """Grey, grey + alpha, RGB and RGBA at 16 bits: all 16 bits of each sample, alpha dropped from
    the image and kept for masks (`fit.targets.view_mask`: out where alpha <= 0.5). Grey + alpha
    (PNG colour type 4) was read as its high bytes: sample_bits 8, errors up to 1 / 255."""
    from difflab.fit.targets import view_mask

    grey = channels < 3
    samples = np.concatenate([ramp16[..., :1] if grey else ramp16, ramp16[..., 1:2]], axis=-1)[..., :channels]
    path = write_png(tmp_path / "a.png", samples, gamma=1.0)
    colour = np.repeat(samples[..., :1], 3, axis=-1) if grey else samples[..., :3]
    assert sample_bits(path) == 16
    np.testing.assert_allclose(load_image(path), colour / 65535.0, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(load_image(path, srgb=False), colour / 65535.0, rtol=1e-6, atol=1e-9)
    inside = colour.max(axis=-1) > 32767.5
    if channels in (2, 4):
        inside &= samples[..., -1] > 32767.5
    np.testing.assert_array_equal(view_mask(path, samples.shape[:2], "masks[0]"), inside)


@pytest.mark.parametrize("little_endian", [True, False])
def test_16_bit_tiff_is_read_whole(tmp_path, ramp16, little_endian):
    path = write_tiff(tmp_path / "a.tif", ramp16, little_endian)
    np.testing.assert_allclose(load_image(path, srgb=False), ramp16 / 65535.0, rtol=1e-6, atol=1e-9)
    assert sample_bits(path) == 16


def test_8_bit_gamma_chunks(tmp_path):
    codes = np.arange(0, 256, 5, dtype=np.uint8).reshape(1, -1, 1).repeat(3, axis=-1)
    np.testing.assert_allclose(load_image(write_png(tmp_path / "lin.png", codes, gamma=1.0)), codes / 255.0,
                               rtol=1e-6)
    np.testing.assert_allclose(load_image(write_png(tmp_path / "g22.png", codes, gamma=0.45455)),
                               (codes / 255.0) ** (1 / 0.45455), rtol=1e-6)  # linear^g stored: s^(1/g) read
    np.testing.assert_allclose(load_image(write_png(tmp_path / "s.png", codes, srgb_chunk=True, gamma=0.45455)),
                               srgb_to_linear(codes / 255.0), rtol=1e-6)
    assert sample_bits(tmp_path / "s.png") == 8 and sample_bits(save_image(tmp_path / "x.npy", codes / 255.0)) is None


def test_a_16_bit_target_fits_at_its_own_noise_floor(tmp_path):
    """A 16-bit sRGB PNG of a difflab render: ka/kd/ks/n recovered to 1e-4 with the noise floored at
    one 16-bit step / sqrt(12) (not the 8-bit step: that floor hid mismatches 257^2 times smaller
    in chi-square than the data show)."""
    d = {"camera": {"eye": [0, 0, 3], "target": [0, 0, 0], "fov_y": 40, "width": 24, "height": 24},
         "ambient": [0.2, 0.2, 0.2], "lights": [{"type": "point", "position": [2, 2, 3]}],
         "materials": {"red": {"ka": [0.1, 0.05, 0.02], "kd": [0.6, 0.2, 0.1], "ks": [0.3] * 3, "n": 20.0}},
         "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "red"}]}
    image = np.clip(render_frame(Scene.from_dict(d)).image, 0.0, 1.0)
    codes = np.round(np.where(image <= 0.0031308, 12.92 * image, 1.055 * image ** (1 / 2.4) - 0.055) * 65535)
    target = write_png(tmp_path / "t.png", codes.astype(np.uint16), srgb_chunk=True)
    start = {"ka": [0.12, 0.04, 0.025], "kd": [0.5, 0.25, 0.08], "ks": [0.35] * 3, "n": 15.0}
    result = fit_material(Scene.from_dict(d), [target], "red", init=start, progress=False)
    assert result.ok and result.sigma < 1e-4
    for key, truth in d["materials"]["red"].items():
        np.testing.assert_allclose(result.params[key], truth, rtol=1e-3, atol=1e-4)


def test_a_float_exr_is_refused_with_what_to_do(tmp_path):
    exr = tmp_path / "target.exr"
    exr.write_bytes(b"\x76\x2f\x31\x01" + bytes(60))  # OpenEXR's magic number, then nothing Pillow reads
    with pytest.raises(DifflabError) as info:
        load_image(exr)
    assert str(info.value) == (f"{exr}: cannot read image: not a picture file Pillow can read (its header is no PNG, "
                               "JPEG, TIFF, BMP, ... header); float images (EXR, HDR) are read from .npy: save the "
                               "linear array with numpy.save")


@pytest.mark.parametrize("name, kind", [("t.png", "PNG"), ("t.JPG", "JPEG"), ("t.tiff", "TIFF")])
def test_a_file_that_is_no_picture_is_named_in_plain_words(tmp_path, name, kind):
    """Not Pillow's class (it was "(UnidentifiedImageError: cannot identify image file ...)"): what
    is wrong, the format its ending promises. The header is checked too (`sample_bits`)."""
    path = tmp_path / name
    path.write_text("just some text, no picture")
    message = (f"cannot read image: not a {kind} file Pillow can read (its header is not a valid {kind} header), "
               "nor a picture in another format Pillow reads")
    for read in (load_image, sample_bits):
        with pytest.raises(DifflabError) as info:
            read(path)
        assert str(info.value).endswith(f"{name}: {message}") and "Error" not in str(info.value)


@pytest.mark.parametrize("mode, values", [("I", np.full((4, 4), 100000, np.int32)),
                                          ("F", np.full((4, 4), 0.5, np.float32))])
def test_32_bit_integer_and_float_tiffs_are_refused(tmp_path, mode, values):
    """Pillow opens them as mode "I" / "F": neither 8- nor 16-bit samples (a 32-bit integer TIFF was
    read as 16-bit, its values wrapped: 100000 -> 0.526)."""
    from PIL import Image

    path = tmp_path / f"deep_{mode}.tif"
    Image.fromarray(values, mode=mode).save(path)
    with pytest.raises(DifflabError, match=rf"deep_{mode}\.tif: 32-bit integer or float samples .*\.npy"):
        load_image(path)


@pytest.mark.parametrize("dtype, bits, opens", [(np.uint8, 8, 1), (np.uint16, 16, 2)])
def test_a_target_file_is_opened_once(tmp_path, monkeypatch, dtype, bits, opens):
    """`fit.targets.load_target` read a file's header twice (`load_image`, then `sample_bits`): an
    8-bit PNG was opened 2 times, a 16-bit colour one 3 (its second decode, of the low bytes, is the
    one more open: `picture._samples16`). Now `io.read_image` reads image, bits and channels at once."""
    from PIL import Image

    from difflab.fit.targets import load_target

    samples = np.arange(5 * 7 * 3).reshape(5, 7, 3).astype(dtype)
    path = write_png(tmp_path / "t.png", samples, gamma=1.0)
    real_open, opened = Image.open, []
    monkeypatch.setattr(Image, "open", lambda *a, **k: opened.append(a[0]) or real_open(*a, **k))
    image, step, gamma = load_target(path, "targets[0]")
    assert len(opened) == opens
    assert step == 1.0 / (2 ** bits - 1) and gamma == 1.0
    np.testing.assert_allclose(image, samples / float(np.iinfo(dtype).max), rtol=1e-6)


@pytest.mark.parametrize("shape", [(5, 7), (5, 7, 1), (5, 7, 2)])
def test_a_grey_npy_reads_as_a_grey_picture_does(tmp_path, shape):
    """A .npy of shape (H, W, 1) or (H, W, 2) (grey, grey + alpha) is grey as (H, W) is and as a PNG's
    L / LA are: its values in the three channels, 1 colour channel reported (the old reader refused
    those two shapes with a shape error, so a fit target of them missed the grey-target advice)."""
    from difflab.io import read_image

    grey = np.random.default_rng(4).random((5, 7)).astype(np.float32)
    array = grey if len(shape) == 2 else np.stack([grey, np.ones_like(grey)][:shape[-1]], axis=-1)
    np.save(tmp_path / "g.npy", array)
    loaded = read_image(tmp_path / "g.npy")
    assert loaded.channels == 1 and loaded.bits is None
    np.testing.assert_array_equal(loaded.image, np.repeat(grey[..., None], 3, axis=-1))


#: Palettes of 3 entries (R, G, B each): all grey, or with colours.
PALETTES = {"grey": [0, 0, 0, 128, 128, 128, 255, 255, 255], "colour": [0, 0, 0, 255, 0, 0, 30, 200, 90]}
#: A palette PNG's transparency: none, one transparent entry, or an alpha per entry (both tRNS chunks).
TRANSPARENCY = {"opaque": None, "tRNS index": 1, "tRNS alphas": b"\x00\xff\x80"}


@pytest.mark.parametrize("transparency", sorted(TRANSPARENCY))
@pytest.mark.parametrize("palette", sorted(PALETTES))
def test_a_palette_png_is_grey_exactly_when_its_palette_is(tmp_path, palette, transparency):
    """A palette (mode "P") PNG reads as its entries' colours, sRGB-decoded, alpha dropped; it holds
    1 colour channel when every palette entry is grey (R = G = B) -- a fit target of it is refused
    as an L PNG is --, else 3. Before, a grey palette passed as an RGB target, and a palette with an
    alpha per entry failed to load under warnings as errors (Pillow warns converting it to RGB)."""
    from difflab.errors import FitError
    from difflab.fit.targets import load_target
    from difflab.io import read_image

    codes = np.array([[0, 1, 2], [2, 1, 0]], np.uint8)
    picture = Image.fromarray(codes, "P")
    picture.putpalette(PALETTES[palette])
    path = tmp_path / "p.png"
    extra = {} if TRANSPARENCY[transparency] is None else {"transparency": TRANSPARENCY[transparency]}
    picture.save(path, **extra)
    with Image.open(path) as opened:
        assert opened.mode == "P" and ("transparency" in opened.info) == bool(extra)
    loaded = read_image(path)
    colours = np.reshape(PALETTES[palette], (-1, 3))[codes]
    np.testing.assert_array_equal(loaded.image, srgb_to_linear(colours / 255.0).astype(np.float32))
    assert loaded.bits == 8 and loaded.channels == (1 if palette == "grey" else 3)
    if palette == "grey":
        with pytest.raises(FitError, match=r"^targets\[0\] \(.*p\.png\): a grey image file has 1 colour channel "):
            load_target(path, "targets[0]")
    else:
        image, step, gamma = load_target(path, "targets[0]")
        assert step == 1 / 255 and gamma is None
        np.testing.assert_array_equal(image, loaded.image)


@pytest.mark.parametrize("palette", sorted(PALETTES))
def test_a_palette_with_alpha_counts_its_palette_colours(palette):
    """Mode "PA" (palette + alpha, which Pillow makes, though PNG stores it as "P" + tRNS) is grey as
    "P" is: by its palette."""
    from difflab.picture import colour_channels

    picture = Image.fromarray(np.array([[0, 1, 2]], np.uint8), "P")
    picture.putpalette(PALETTES[palette])
    with_alpha = picture.convert("PA")
    assert with_alpha.mode == "PA"
    assert colour_channels(picture) == colour_channels(with_alpha) == (1 if palette == "grey" else 3)
