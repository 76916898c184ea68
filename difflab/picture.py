"""Picture files as Pillow opens them: their samples at full depth (8 or 16 bits, alpha kept where
the file has it) and their transfer function. Internal: `io.load_image` and `fit.targets.load_mask` read
pictures through it.

Pillow unpacks 16-bit colour PNG / TIFF samples to 8 bits (each sample's high byte). Those files
are decoded twice here -- as Pillow does, and with every tile's byte order swapped, which takes the
low bytes -- and a 16-bit grey + alpha PNG (which Pillow opens as 8-bit RGBA) once, its rows
unpacked as raw bytes (high, low) of grey and alpha. 16-bit grey files Pillow keeps whole.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import NamedTuple

import numpy as np
from PIL import Image

from . import limits
from .errors import DifflabError

FLOAT_FORMATS = (".exr", ".hdr", ".pfm")  # float image files that Pillow does not read

#: 16-bit colour layouts Pillow unpacks to 8 bits (the sample's high byte), and their other byte order.
_OTHER_ORDER = {"RGB;16B": "RGB;16L", "RGB;16L": "RGB;16B", "RGBA;16B": "RGBA;16L", "RGBA;16L": "RGBA;16B"}
#: 16-bit layouts without an other-order unpacker, and the 8-bit raw mode of the same bytes per pixel.
_AS_BYTES = {"LA;16B": "RGBA"}  # PNG grey + alpha: bytes (grey high, grey low, alpha high, alpha low)


def why(exc: Exception) -> str:
    """'Kind: message' of a library's exception, cut to one short line."""
    return f"{type(exc).__name__}: {' '.join(str(exc).split())[:120]}"


#: picture formats by file ending, as messages name them
FORMAT_NAMES = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG", ".tif": "TIFF", ".tiff": "TIFF", ".bmp": "BMP",
                ".gif": "GIF", ".webp": "WebP"}


def unreadable(exc: Exception, path: Path) -> str:
    """Why Pillow could not read the picture file `path`, in plain words (Pillow's exception classes
    are its own business): not a picture it knows, damaged or cut short, or too many pixels."""
    text = " ".join(str(exc).split())[:120]
    if isinstance(exc, Image.DecompressionBombError):
        return f"more pixels than Pillow opens ({text})"
    if isinstance(exc, Image.UnidentifiedImageError):  # no format's header matched (or it was cut inside one)
        kind = FORMAT_NAMES.get(Path(path).suffix.lower())
        if kind:
            return f"not a {kind} file Pillow can read (its header is not a valid {kind} header), nor a picture " \
                   f"in another format Pillow reads"
        return "not a picture file Pillow can read (its header is no PNG, JPEG, TIFF, BMP, ... header)"
    if isinstance(exc, PermissionError):
        return "no permission to read the file"
    if isinstance(exc, (OSError, SyntaxError, ValueError)):  # Pillow's decoders: "image file is truncated", ...
        return f"the file is damaged or cut short ({text})"
    return f"Pillow could not decode it ({text})"


def _rawmode(tile) -> str | None:
    """A decoder tile's raw mode: its args (PNG) or their first entry (TIFF, ...)."""
    args = tile[3] if len(tile) == 4 else None
    return args if isinstance(args, str) else (args[0] if isinstance(args, tuple) and args else None)


def _retiled(tile, table):
    """The tile unpacked by raw mode table[its raw mode] instead."""
    args = tile[3]
    args = table[args] if isinstance(args, str) else (table[args[0]], *args[1:])
    return tile._replace(args=args) if hasattr(tile, "_replace") else (*tile[:3], args)


def wide(im) -> str | None:
    """How a 16-bit image Pillow opened (header only) is laid out: "grey" (kept whole, "I;16"),
    "colour" (16-bit RGB(A) PNG / TIFF, of which Pillow keeps only the high bytes), "grey+alpha"
    (a 16-bit grey + alpha PNG, likewise), or None (8-bit samples, or not a 16-bit layout)."""
    if im.mode in ("I;16", "I;16B", "I;16L") or (im.mode == "I" and im.tile and
                                                all((_rawmode(tile) or "").startswith("I;16") for tile in im.tile)):
        return "grey"  # (mode "I" also holds 32-bit integer files: only 16-bit samples are read as such)
    raw = {_rawmode(tile) for tile in im.tile}
    if im.mode in ("RGB", "RGBA") and im.tile and raw <= set(_OTHER_ORDER):
        return "colour"
    return "grey+alpha" if im.mode == "RGBA" and im.tile and raw <= set(_AS_BYTES) else None


def _samples16(im, path: Path) -> np.ndarray | None:
    """The (H, W, 3) -- (H, W, 4) with alpha -- uint16 samples of a 16-bit image Pillow opened, or
    None for other images (see the module docstring)."""
    layout = wide(im)
    if layout is None:
        return None
    if layout == "grey":
        return np.repeat(np.asarray(im).astype(np.uint16)[..., None], 3, axis=-1)
    with Image.open(path) as again:  # (a loaded image has closed its file)
        again.tile = [_retiled(tile, _OTHER_ORDER if layout == "colour" else _AS_BYTES) for tile in again.tile]
        other = np.asarray(again).astype(np.uint16)
    if layout == "colour":
        return np.asarray(im).astype(np.uint16) * 256 + other
    grey, alpha = other[..., 0] * 256 + other[..., 1], other[..., 2] * 256 + other[..., 3]
    return np.stack([grey, grey, grey, alpha], axis=-1)


def transfer(info: dict) -> float | None:
    """The file's transfer function from its PNG colour chunks: None for sRGB (an sRGB chunk, or no
    gAMA chunk), else the file gamma g of its gAMA chunk (samples are linear^g; 1.0: linear)."""
    gamma = info.get("gamma")
    return None if "srgb" in info or gamma is None or not gamma > 0 else float(gamma)


def _has_alpha(im) -> bool:
    return im.mode in ("RGBA", "LA", "PA", "La", "RGBa") or "transparency" in im.info


def sample_depth(im) -> int:
    """Bits per sample of an image Pillow opened (header only), as `read_picture` reads it: 16 for a
    16-bit PNG / TIFF, else 8."""
    return 16 if wide(im) else 8


#: Pillow modes of grey files: bilevel, 8-bit grey (with alpha), 16-bit grey.
_GREY_MODES = ("1", "L", "LA", "La", "I;16", "I;16B", "I;16L")


def colour_channels(im) -> int:
    """Colour channels an image Pillow opened stores (alpha not counted): 1 for a grey file (PNG
    colour types 0 and 4 at any depth, bilevel, and a palette -- "P", "PA" -- whose every entry is
    grey, R = G = B: what a grey picture saved with a palette holds), else 3 (RGB, a palette with
    colours, CMYK, ...). (Pillow decodes a palette image to give its palette: call this after
    `sample_depth`, which reads the tiles that decoding drops.)"""
    if im.mode in ("P", "PA"):
        entries = np.reshape(im.getpalette("RGB") or [0, 0, 0], (-1, 3))
        return 1 if (entries == entries[:, :1]).all() else 3
    return 1 if im.mode in _GREY_MODES or wide(im) in ("grey", "grey+alpha") else 3


class Picture(NamedTuple):
    """A picture file as `read_picture` reads it."""
    samples: np.ndarray  # (H, W, 3) or (H, W, 4) uint8, or uint16 for a 16-bit PNG / TIFF
    gamma: float | None  # the file's transfer function (`transfer`): None for sRGB
    bits: int  # bits per sample: 8 or 16 (`sample_depth`)
    channels: int  # colour channels the file stores: 1 (grey, repeated into the 3 of `samples`) or 3


def read_picture(path: Path, alpha: bool = False) -> Picture:
    """A `Picture` of an image file Pillow reads, its file opened once (a 16-bit colour file twice,
    see the module doc): samples (H, W, 3) -- (H, W, 4) when `alpha` and the file has an alpha
    channel or a transparent colour --, gamma, bits and colour channels. Its size (from the header,
    read lazily by Image.open) is checked against the memory budget before anything is decoded.
    DifflabError naming the path."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # our budget decides instead
            with Image.open(path) as im:
                limits.require_image(im.width, im.height, str(path), limits.IMAGE_LOAD_BYTES)
                bits, channels = sample_depth(im), colour_channels(im)  # (from the header: decoding drops the tiles)
                samples = _samples16(im, path)
                if samples is None and im.mode in ("I", "F"):
                    raise DifflabError(f"{path}: 32-bit integer or float samples (mode {im.mode!r}) are not read: "
                                       "save 8- or 16-bit samples, or the linear array as .npy")
                if samples is None:  # (a palette with alphas converts to RGBA: to RGB Pillow warns)
                    samples = np.asarray(im.convert("RGBA" if _has_alpha(im) and (alpha or im.mode == "P") else "RGB"))
                return Picture(samples if alpha else samples[..., :3], transfer(im.info), bits, channels)
    except DifflabError:
        raise
    except Exception as exc:  # Pillow raises OSError, ValueError, SyntaxError, DecompressionBombError, ...
        hint = "; float images (EXR, HDR) are read from .npy: save the linear array with numpy.save" \
            if path.suffix.lower() in FLOAT_FORMATS else ""
        raise DifflabError(f"{path}: cannot read image: {unreadable(exc, path)}{hint}") from None
