"""Textures on the host: load (sRGB PNG -> linear), build mip pyramids, pack into one `TexturesW`.

Orientation. Arrays here are in *texture* orientation: row 0 is v = 0, the image's bottom row
(`load_texture` returns image orientation, row 0 at the top, like every difflab image;
`TextureStore` flips it once).

Mip pyramid rule. Level l + 1 has ceil(H_l / 2) x ceil(W_l / 2) texels; texel (r, c) is the mean of
the 2x2 block rows 2r, 2r + 1, columns 2c, 2c + 1 of level l, where a row or column beyond an odd
edge is the last one repeated (edge clamp). For even sizes every level is the exact 2x2 box mean of
the one below. The pyramid ends at 1x1.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from ..._warp import wp

from ...errors import DifflabError, TextureError
from ...io import read_image
from ...limits import TEXEL_BYTES, require_count, require_memory
from .sampling import TexturesW


def load_texture(path: str | os.PathLike, srgb: bool = True) -> np.ndarray:
    """A texture image as linear float32 (H, W, 3), row 0 at the top (8-bit files are sRGB-decoded
    when `srgb`; .npy files are taken as linear). Raises TextureError naming the path if the file is
    missing, a folder, unreadable, empty or not finite (`io.read_image`'s checks)."""
    try:
        image = read_image(path, srgb, what="texture").image
    except DifflabError as exc:
        raise TextureError(str(exc)) from None
    if image.shape[0] < 1 or image.shape[1] < 1:
        raise TextureError(f"{path}: texture is empty ({image.shape})")
    if not np.all(np.isfinite(image)):
        raise TextureError(f"{path}: texture has non-finite texels")
    return image


def downsample(level: np.ndarray) -> np.ndarray:
    """The next mip level: 2x2 box means, an odd last row / column repeated (see the module doc)."""
    h, w = level.shape[:2]
    padded = np.pad(level.astype(np.float64), ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
    h2, w2 = padded.shape[0] // 2, padded.shape[1] // 2
    return padded.reshape(h2, 2, w2, 2, -1).mean(axis=(1, 3)).astype(np.float32)


def mip_pyramid(texels: np.ndarray) -> list[np.ndarray]:
    """[level 0 = texels, level 1, ..., 1x1] of a (H, W, C) array (see the module doc)."""
    levels = [np.ascontiguousarray(texels, dtype=np.float32)]
    while levels[-1].shape[0] > 1 or levels[-1].shape[1] > 1:
        levels.append(downsample(levels[-1]))
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
    out.texels = wp.array(np.concatenate(blocks).astype(np.float32), dtype=wp.vec3, device=device)
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
