"""Textures on the host: load (sRGB PNG -> linear), build mip pyramids, pack into one `TexturesW`.

Orientation. Arrays here are in *texture* orientation: row 0 is v = 0, the image's bottom row
(`load_texture` returns image orientation, row 0 at the top, like every difflab image;
`TextureStore` flips it once).

Mip pyramid rule. Level l + 1 has max(1, H_l // 2) x max(1, W_l // 2) texels (OpenGL's level
sizes). Per axis, coarse texel j of n covers the finer level's interval [j w / n, (j + 1) w / n)
(w fine texels) and is the mean over it, each fine texel weighted by the length of its overlap:
a box filter of width w / n that splits a texel straddling two footprints between them. Every fine
texel's weights sum to n / w, so each level's mean equals the image's exactly (in float64; levels
are stored in float32). For even sizes this is the 2x2 box mean; an odd size (w / n = 2 + 2 / (w - 1))
gives no texel more weight than its neighbours. The pyramid ends at 1x1.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from ..._warp import wp

from ...errors import DifflabError, TextureError
from ...io import read_image
from ...limits import TEXEL_BYTES, require_count, require_memory, short_path
from .sampling import TexturesW


def load_texture(path: str | os.PathLike, srgb: bool = True) -> np.ndarray:
    """A texture image as linear float32 (H, W, 3), row 0 at the top: `io.load_image`'s decoding
    (8- and 16-bit PNG / TIFF samples through the file's transfer function when `srgb` -- sRGB unless
    a PNG's gAMA chunk declares another gamma; .npy files are linear). Raises TextureError naming
    the path if the file is missing, a folder, unreadable (`io.read_image`'s checks), empty, or holds
    non-finite or negative values (`check_texels`)."""
    try:
        image = read_image(path, srgb, what="texture").image
    except DifflabError as exc:
        raise TextureError(str(exc)) from None
    if image.shape[0] < 1 or image.shape[1] < 1:
        raise TextureError(f"{path}: texture is empty ({image.shape})")
    check_texels(image, path)
    return image


def check_texels(image: np.ndarray, path) -> None:
    """TextureError naming `path` if a texel value is non-finite or negative (a texel scales a
    coefficient, and coefficients are >= 0), with the count and the worst value."""
    finite = np.isfinite(image)
    if not finite.all():
        bad = image[~finite]
        raise TextureError(f"{short_path(path)}: texture has {bad.size} non-finite texel values (e.g. {bad[0]}); "
                           "texels must be finite and >= 0")
    if image.min() < 0:
        raise TextureError(f"{short_path(path)}: texture has {np.count_nonzero(image < 0)} negative texel values "
                           f"(least {image.min():.6g}); texels scale a coefficient, so they must be >= 0")


def halve(level: np.ndarray, axis: int) -> np.ndarray:
    """`level` (float32 or float64, w >= 2 texels along `axis`) with that axis averaged down to
    n = w // 2, in float64 (see the module doc). Coarse texel j's footprint [j w / n, (j + 1) w / n),
    over the fine texels it overlaps, weighted by the overlap over w / n:
    even w: texels 2j, 2j + 1, weights (1/2, 1/2) (the box mean);
    odd w = 2n + 1: the footprint starts j / n into texel 2j and ends (j + 1) / n into texel 2j + 2,
    so texels 2j, 2j + 1, 2j + 2 with weights (n - j, n, j + 1) / w -- never a fourth texel.
    The taps are strided views of `level` (no gathered copies): memory is the float64 result, plus
    one float64 product of its size for odd w."""
    w = level.shape[axis]
    n = w // 2
    shape = [1] * level.ndim
    shape[axis] = n

    def tap(k: int) -> np.ndarray:  # fine texels 2j + k, j < n
        index = [slice(None)] * level.ndim
        index[axis] = slice(k, k + 2 * n, 2)
        return level[tuple(index)]

    if w % 2 == 0:
        out = np.add(tap(0), tap(1), dtype=np.float64)
        out *= 0.5
        return out
    j = np.arange(n, dtype=np.float64).reshape(shape)
    out = np.multiply(tap(0), (n - j) / w, dtype=np.float64)
    product = np.empty_like(out)
    for k, weight in ((1, n / w), (2, (j + 1) / w)):
        out += np.multiply(tap(k), weight, out=product, dtype=np.float64)
    return out


def downsample(level: np.ndarray) -> np.ndarray:
    """The next mip level of an (H, W, C) array, in float64: `halve` along each axis longer than 1
    (an axis of size 1 does not shrink and is left as it is). Memory: the float64 result of the first
    pass (half the level's texels, x 8 bytes a channel), plus as much again for an odd size."""
    out = level
    for axis in (0, 1):
        if out.shape[axis] > 1:
            out = halve(out, axis)
    return out


def mip_pyramid(texels: np.ndarray) -> list[np.ndarray]:
    """[level 0 = texels, level 1, ..., 1x1] of a (H, W, C) array (see the module doc)."""
    level = np.ascontiguousarray(texels, dtype=np.float32)
    levels = [level]
    while level.shape[0] > 1 or level.shape[1] > 1:
        level = downsample(level)  # float64 from level 1 on: no rounding carried from level to level
        levels.append(level.astype(np.float32))
    return levels


@dataclass
class TextureStore:
    """Textures of a scene on a device. `pyramids[t]` lists texture t's levels (texture orientation,
    float32 (H_l, W_l, 3)); `warp` is the packed `TexturesW`; `paths` names where each came from."""

    pyramids: list
    paths: list
    warp: TexturesW

    @classmethod
    def from_images(cls, images, device: str = "cpu", paths=None) -> TextureStore:
        """Pack linear (H, W, 3) images given in image orientation (row 0 at the top)."""
        texels = sum(int(np.shape(image)[0]) * int(np.shape(image)[1]) for image in images)
        require_memory(texels * TEXEL_BYTES, f"textures: {texels} texels", TextureError)  # before the pyramids
        require_count(2 * texels, "textures: texels in all levels", TextureError)  # a pyramid adds < 1/3
        pyramids = [mip_pyramid(np.flipud(np.asarray(image, np.float32)[..., :3])) for image in images]
        return cls(pyramids, list(paths) if paths is not None else [None] * len(pyramids),
                   pack(pyramids, device))

    @classmethod
    def from_paths(cls, paths, device: str = "cpu") -> TextureStore:
        return cls.from_images([load_texture(p) for p in paths], device, paths)

    def largest(self) -> list[float]:
        """Per texture, its largest texel value (level 0), for the overflow report (`guards.check_image`)."""
        return [float(np.abs(pyramid[0]).max()) for pyramid in self.pyramids]


def pack(pyramids, device: str) -> TexturesW:
    """One flat texel array with per-level (offset, width, height) and per-texture level ranges."""
    blocks, levels, first, count = [], [], [], []
    offset = 0
    for pyramid in pyramids:
        first.append(len(levels))
        count.append(len(pyramid))
        for level in pyramid:
            h, w = level.shape[:2]
            levels.append((offset, w, h))
            blocks.append(level.reshape(-1, 3))
            offset += h * w
    if not blocks:  # no textures: one dummy texel keeps every array non-empty
        blocks, levels, first, count = [np.ones((1, 3), np.float32)], [(0, 1, 1)], [0], [1]
    out = TexturesW()
    out.texels = wp.array(np.concatenate(blocks, dtype=np.float32), dtype=wp.vec3, device=device)
    out.level = wp.array(np.asarray(levels, np.int32), dtype=wp.vec3i, device=device)
    out.first_level = wp.array(np.asarray(first, np.int32), dtype=wp.int32, device=device)
    out.n_levels = wp.array(np.asarray(count, np.int32), dtype=wp.int32, device=device)
    return out


def scene_textures(materials, device: str = "cpu") -> tuple[TextureStore, list[int]]:
    """The textures of scene `materials` (in material-id order), each distinct file loaded once, and
    per material its texture id (-1 for none)."""
    paths, ids = [], []
    for mat in materials:
        if mat.texture is None:
            ids.append(-1)
            continue
        if mat.texture not in paths:
            paths.append(mat.texture)
        ids.append(paths.index(mat.texture))
    return TextureStore.from_paths(paths, device), ids


def sample(store: TextureStore, tex_id: int, uv, duv_dx=None, duv_dy=None, filter: str = "bilinear",
           wrap: str = "repeat", device: str = "cpu") -> np.ndarray:
    """`texture.sample_texture` at N points: uv, duv_dx, duv_dy (N, 2) -> (N, 3) float32."""
    from .sampling import FILTERS, WRAPS, sample_texture_kernel

    uv = np.asarray(uv, np.float32).reshape(-1, 2)
    zeros = np.zeros_like(uv)
    args = [wp.array(np.ascontiguousarray(a if a is not None else zeros, np.float32).reshape(-1, 2), dtype=wp.vec2,
                     device=device) for a in (uv, duv_dx, duv_dy)]
    out = wp.empty(uv.shape[0], dtype=wp.vec3, device=device)
    wp.launch(sample_texture_kernel, dim=uv.shape[0],
              inputs=[store.warp, int(tex_id), *args, FILTERS[filter], WRAPS[wrap], out], device=device)
    return out.numpy()
