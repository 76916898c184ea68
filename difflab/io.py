"""Image files at the boundary: sRGB <-> linear, PNG/NPY load and save.

Images inside difflab are numpy float32 arrays (H, W, 3) of linear RGB, row 0 at the top.
sRGB encoding happens only here, when an 8-bit file is written or read. Files are written
atomically (`difflab.files`, whose writers this module re-exports: they are public here).
"""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
from PIL import Image

from . import limits
from .errors import DifflabError
from .files import atomic_path, file_path
from .files import uninterrupted as uninterrupted  # the atomic writers, public through difflab.io (docs/api.md)
from .files import write_json_atomic as write_json_atomic
from .files import write_text_atomic as write_text_atomic
from .files import write_together as write_together
from .limits import short_path
from .picture import read_picture, sample_depth, unreadable, why

__all__ = ["load_image", "save_image", "read_image", "LoadedImage", "sample_bits", "srgb_to_linear", "linear_to_srgb",
           "code_step", "write_text_atomic", "write_json_atomic", "write_together", "uninterrupted"]


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 decoding: c/12.92 for c <= 0.04045, else ((c + 0.055)/1.055)^2.4 (c in [0, 1])."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def code_step(linear, step: float, gamma: float | None = None) -> np.ndarray:
    """The width in linear units of one code step `step` (1 / (2^bits - 1)) of a file's samples s
    at the linear values they decode to: step * d linear / d s there. sRGB (`gamma` None, the slope of
    `srgb_to_linear` written in linear values): 1 / 12.92 at linear <= 0.0031308 (s <= 0.04045), else
    (2.4 / 1.055) ((s + 0.055) / 1.055)^1.4 = (2.4 / 1.055) linear^(1.4 / 2.4): 0.077 steps in the
    darks, 2.275 at white. A file gamma g (linear = s^(1 / g)): (1 / g) linear^(1 - g), taken at least
    half a step up from 0 (where the slope is 0 or infinite for g != 1); g = 1: `step` everywhere.
    Its square / 12 is the variance that rounding to the code adds to a linear value."""
    linear = np.asarray(linear, dtype=np.float64)
    if gamma is None:
        with np.errstate(invalid="ignore"):  # (the dark branch's power of values < 0, not taken)
            slope = np.where(linear <= 0.0031308, 1.0 / 12.92, (2.4 / 1.055) * linear ** (1.4 / 2.4))
    elif gamma == 1.0:
        return np.full(linear.shape, float(step))
    else:
        slope = np.maximum(linear, (0.5 * step) ** (1.0 / gamma)) ** (1.0 - gamma) / gamma
    return step * slope


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 encoding of linear values clamped to [0, 1]."""
    c = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1.0 / 2.4) - 0.055)


def _as_image(image) -> np.ndarray:
    """A float32 (H, W, 3 or 4) array from a 2-D or 3-D array of real numbers; DifflabError otherwise."""
    array = image if isinstance(image, np.ndarray) else np.asarray(image)
    if array.dtype.kind not in IMAGE_DTYPE_KINDS:
        raise DifflabError(f"image: must hold real numbers (bool, int, uint or float), got dtype {array.dtype}")
    image = array.astype(np.float32)
    if image.ndim == 2:
        image = image[..., None].repeat(3, axis=-1)
    if image.ndim != 3 or image.shape[-1] not in (3, 4):
        raise DifflabError(f"image: expected shape (H, W, 3), got {image.shape}")
    return image


def save_image(path: str | os.PathLike, image, srgb: bool = True) -> Path:
    """Write a linear float image (H, W, 3) atomically.

    `.npy` keeps the linear float32 values exactly. Other suffixes (PNG, ...) are written 8-bit,
    clamped to [0, 1] and sRGB-encoded when `srgb` is true (linear 8-bit otherwise).
    Non-finite pixels are not hidden: they raise, with their count.
    """
    path = file_path(path, "image")
    with atomic_path(path) as tmp:
        write_image(tmp, image, srgb, name=path)
    return path


def write_image(path: Path, image, srgb: bool = True, name=None) -> None:
    """`save_image`'s writing, into `path` as it stands (a temporary: `atomic_path`,
    `write_together`), in the format its suffix names; errors name `name` (default: `path`)."""
    name = path if name is None else name
    image = _as_image(image)
    if path.suffix.lower() == ".npy":
        with open(path, "wb") as f:  # (np.save(name) appends .npy to "x.NPY")
            np.save(f, image)
        return
    bad = int(np.count_nonzero(~np.isfinite(image)))
    if bad:
        raise DifflabError(f"{name}: image has {bad} non-finite values; not written")
    encoded = linear_to_srgb(image) if srgb else np.clip(image, 0.0, 1.0)
    pixels = np.round(encoded * 255.0).astype(np.uint8)
    Image.fromarray(pixels).save(path, format=Image.registered_extensions().get(path.suffix.lower(), "PNG"))


#: numpy dtype kinds an image file may hold: bool, signed and unsigned integers, real floats.
IMAGE_DTYPE_KINDS = "biuf"


def read_npy(path: Path) -> np.ndarray:
    """An image array from a .npy file, as stored: header checked (numeric real dtype, image shape, size within
    the memory budget, file long enough) before the data is read; pickles are never loaded."""
    try:
        with open(path, "rb") as f:
            version = np.lib.format.read_magic(f)
            read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else \
                np.lib.format.read_array_header_2_0
            shape, _, dtype = read_header(f)
            data_start = f.tell()
    except Exception as exc:  # numpy raises ValueError, OSError, EOFError, SyntaxError on bad headers
        raise DifflabError(f"{path}: not a valid .npy file ({why(exc)})") from None
    if dtype.hasobject or dtype.kind not in IMAGE_DTYPE_KINDS or dtype.fields is not None or dtype.subdtype:
        raise DifflabError(f"{path}: image array must hold real numbers (bool, int, uint or float), got dtype {dtype}")
    if len(shape) not in (2, 3) or (len(shape) == 3 and shape[-1] > 4) or 0 in shape:
        raise DifflabError(f"{path}: expected an image array of shape (H, W) or (H, W, C) with C = 1 (grey), 2 (grey, "
                           f"alpha), 3 (RGB) or 4 (RGBA), got {shape}")
    limits.require_image(shape[1], shape[0], str(path), limits.IMAGE_LOAD_BYTES)
    needed = data_start + int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if path.stat().st_size < needed:
        raise DifflabError(f"{path}: .npy file is truncated ({path.stat().st_size} of {needed} bytes)")
    try:
        return np.load(path, allow_pickle=False)
    except Exception as exc:
        raise DifflabError(f"{path}: cannot read .npy file ({why(exc)})") from None


def refuse_code_values(dtype, name: str) -> None:
    """The one rule for integer image data (an integer .npy file, an integer array given as a fit's
    target): its values are a file's code values, not linear light, and are refused -- DifflabError
    naming `name`, saying how to decode them for their dtype. Other dtypes pass."""
    dtype = np.dtype(dtype)
    if dtype.kind not in "iu":
        return
    if dtype.itemsize == 1:
        how = "image / 255.0, then difflab.io.srgb_to_linear() of that if sRGB-encoded (ordinary 8-bit pictures are)"
    elif dtype.itemsize == 2:
        how = ("image / 65535.0: linear if the source wrote linear samples (POV-Ray File_Gamma=1.0, PNG gAMA 1.0), "
               "else difflab.io.srgb_to_linear() of that")
    else:
        how = "image / (2^bits - 1) for the bits its source wrote, then that source's transfer function"
    raise DifflabError(f"{name}: integer data ({dtype}) are code values, not linear light; give linear floats -- "
                       f"{how} -- or the PNG / TIFF, which difflab decodes")


def sample_bits(path: str | os.PathLike) -> int | None:
    """Bits per sample of an image file as `load_image` reads it: 16 for a 16-bit PNG / TIFF, 8 for other
    pictures, None for .npy (float data). Reads the header only; DifflabError naming the path."""
    path = file_path(path, "image")
    if path.suffix.lower() == ".npy":
        return None
    try:
        with Image.open(path) as im:
            return sample_depth(im)
    except Exception as exc:
        raise DifflabError(f"{short_path(path)}: cannot read image: {unreadable(exc, path)}") from None


def image_file(path, what: str = "image") -> Path:
    """`path` (an image, mask or texture file to read) as a Path to a regular file, else DifflabError
    naming it and `what` it is."""
    path = file_path(path, what)
    if not path.exists():
        raise DifflabError(f"{short_path(path)}: {what} file not found")
    if path.is_dir():
        raise DifflabError(f"{short_path(path)}: a folder, not {'an' if what[0] in 'aeiou' else 'a'} {what} file")
    if not path.is_file():
        raise DifflabError(f"{short_path(path)}: not a regular file")
    return path


class LoadedImage(NamedTuple):
    """An image file as `read_image` reads it."""
    image: np.ndarray  # linear float32 (H, W, 3): `load_image`
    bits: int | None  # bits per sample: 8 or 16 (its samples' step is 1 / (2^bits - 1)); None for .npy floats
    channels: int  # colour channels the file holds: 1 (a grey picture or .npy, repeated into 3) or 3
    gamma: float | None  # how the samples were decoded: linear = s^(1 / gamma) (1.0: as linear); None: sRGB or .npy


def read_image(path: str | os.PathLike, srgb: bool = True, what: str = "image") -> LoadedImage:
    """`load_image`'s image, with the bits per sample and colour channels of the file, from one read
    of it (its header once). Errors name the path and `what` the file is (an "image", a "texture")."""
    path = image_file(path, what)
    if path.suffix.lower() == ".npy":
        array = read_npy(path)
        refuse_code_values(array.dtype, short_path(path))
        grey = array.ndim == 2 or array.shape[-1] < 3  # (H, W), (H, W, 1), (H, W, 2): grey, alpha aside
        image = _as_image(array[..., 0] if grey and array.ndim == 3 else array)
        return LoadedImage(image[..., :3].copy(), None, 1 if grey else 3, None)
    pixels, gamma, bits, channels = read_picture(path)
    image = np.take(decode_table(np.iinfo(pixels.dtype).max, srgb, gamma if srgb else None), pixels)
    return LoadedImage(image, bits, channels, gamma if srgb else 1.0)


@functools.lru_cache(maxsize=8)
def decode_table(top: int, srgb: bool, gamma: float | None) -> np.ndarray:
    """The float32 linear value of each sample 0 .. `top` (255, 65535) as `read_image` decodes it: s / top,
    by sRGB's transfer function (`gamma` None) or s^(1 / gamma) when `srgb`. Read-only, formed once per
    kind of file (65536 values for 16 bits: ~1 ms), and each file's samples gathered from it (np.take:
    indexing takes 1.6x): reading a 256 x 256 16-bit sRGB PNG took 3.8 ms, now 1.5 (its transfer
    function was evaluated at every sample), an 8-bit one with a gAMA chunk 0.58, now 0.31."""
    samples = np.arange(top + 1) / float(top)
    if srgb:
        samples = srgb_to_linear(samples) if gamma is None else samples ** (1.0 / gamma)
    table = samples.astype(np.float32)
    table.setflags(write=False)
    return table


def load_image(path: str | os.PathLike, srgb: bool = True) -> np.ndarray:
    """Read an image as linear float32 (H, W, 3).

    `.npy` files hold linear values (float or bool dtypes; an alpha channel is dropped; a grey array
    -- (H, W), or (H, W, 1) / (H, W, 2) with alpha, as a grey PNG -- is repeated into the 3 channels); an integer .npy holds code values, which are refused
    (`refuse_code_values`: how to decode them); other files are whatever Pillow reads, 8-bit, or
    16-bit PNG / TIFF (all 16 bits kept; a grey file fills the 3 channels; a palette file reads as
    its entries' colours, alpha dropped, and is grey where they all are), their samples
    s / (2^bits - 1) decoded when `srgb` is true by the file's transfer function: sRGB (IEC
    61966-2-1), unless a PNG declares a gamma g without an sRGB chunk (linear = s^(1/g); g = 1: the
    samples are linear, as POV-Ray writes with File_Gamma=1.0). With `srgb` false the samples are
    read as linear values. Every failure -- missing or not a regular file, bad header, truncated
    data, a pickled or string array, an image over the memory budget (checked from the header
    before decoding) -- raises DifflabError naming the path.
    """
    return read_image(path, srgb).image

