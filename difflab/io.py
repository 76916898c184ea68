"""Image files at the boundary: sRGB <-> linear, PNG/NPY load and save, atomic writes.

Images inside difflab are numpy float32 arrays (H, W, 3) of linear RGB, row 0 at the top.
sRGB encoding happens only here, when an 8-bit file is written or read.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

from .errors import DifflabError

_UMASK = os.umask(0o022)  # read the process umask once (setting it is not thread-safe), then restore it
os.umask(_UMASK)


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 decoding: c/12.92 for c <= 0.04045, else ((c + 0.055)/1.055)^2.4 (c in [0, 1])."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 encoding of linear values clamped to [0, 1]."""
    c = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1.0 / 2.4) - 0.055)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path in the folder of `path`; rename it onto `path` only if the block succeeds.

    A writer that fails midway leaves the old file (if any) untouched and no temporary file behind.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + path.suffix, dir=path.parent)
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; give the file the usual permissions
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write a text file atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_json_atomic(path: str | os.PathLike, data) -> None:
    """Write `data` as indented JSON, atomically."""
    write_text_atomic(path, json.dumps(data, indent=2) + "\n")


def _as_image(image) -> np.ndarray:
    image = np.asarray(image, dtype=np.float32)
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
    path = Path(path)
    image = _as_image(image)
    if path.suffix.lower() == ".npy":
        with atomic_path(path) as tmp:
            np.save(tmp, image)
        return path
    bad = int(np.count_nonzero(~np.isfinite(image)))
    if bad:
        raise DifflabError(f"{path}: image has {bad} non-finite values; not written")
    encoded = linear_to_srgb(image) if srgb else np.clip(image, 0.0, 1.0)
    pixels = np.round(encoded * 255.0).astype(np.uint8)
    with atomic_path(path) as tmp:
        Image.fromarray(pixels).save(tmp, format=Image.registered_extensions().get(path.suffix.lower(), "PNG"))
    return path


def load_image(path: str | os.PathLike, srgb: bool = True) -> np.ndarray:
    """Read an image as linear float32 (H, W, 3); 8-bit files are sRGB-decoded when `srgb` is true."""
    path = Path(path)
    if not path.is_file():
        raise DifflabError(f"{path}: image file not found")
    if path.suffix.lower() == ".npy":
        return _as_image(np.load(path))[..., :3].copy()
    try:
        with Image.open(path) as im:
            pixels = np.asarray(im.convert("RGB"), dtype=np.float64) / 255.0
    except OSError as exc:
        raise DifflabError(f"{path}: cannot read image ({exc})") from None
    return (srgb_to_linear(pixels) if srgb else pixels).astype(np.float32)
