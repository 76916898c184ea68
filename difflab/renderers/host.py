"""Host memory for device arrays: numpy-backed allocations on the CPU (transparent huge pages,
lazily zeroed pages), arrays carved from one buffer, and numpy views of device arrays."""

from __future__ import annotations

import numpy as np

from .._warp import wp

ROWS = "rows"  # a field's `zero` in `CompiledScene.reusable_structs`: zero, and a column of the rows block


def host_carved(specs: list[tuple], device: str) -> tuple[wp.array, list[wp.array]]:
    """Zero arrays of the given (shape, dtype, rows) (4-byte scalars or vectors of them), carved in
    order from one zero buffer, each from a 64-byte boundary: (buffer, arrays); the arrays keep the
    buffer alive, and `buffer.zero_()` zeroes them all in one memset. On the CPU those with `rows`
    (of one count N) are instead the columns, in order, of one (N, K) float32 block carved in the
    first one's place: strided views, whose rows a gather takes at once (a fit's G-buffer,
    `ShadingPoints.rows`)."""
    inner = [tuple(getattr(dtype, "_shape_", ())) for unused, dtype, unused in specs]
    words = [int(np.prod(shape + extra)) for (shape, unused, unused), extra in zip(specs, inner)]
    together = [i for i, spec in enumerate(specs) if spec[2]] if device.startswith("cpu") else []
    sizes = [0 if i in together else n for i, n in enumerate(words)]
    if together:
        sizes[together[0]] = sum(words[i] for i in together)
    starts = np.concatenate([[0], np.cumsum([-(-n // 16) * 16 for n in sizes])]).astype(int).tolist()
    buffer = host_empty(starts[-1], wp.float32, device, zeroed=True)
    arrays = [None if i in together else buffer[start:start + n].reshape(shape + extra).view(dtype)
              for i, (start, n, (shape, dtype, unused), extra) in enumerate(zip(starts, words, specs, inner))]
    if together:
        count = specs[together[0]][0][0]
        block = to_host(buffer)[starts[together[0]]:starts[together[0]] + sizes[together[0]]].reshape(count, -1)
        column = 0
        for i in together:
            shape, dtype, unused = specs[i]
            width = int(np.prod(shape[1:] + inner[i]))
            scalar = wp.dtype_to_numpy(getattr(dtype, "_wp_scalar_type_", dtype))
            part = block[:, column:column + width].view(scalar).reshape(shape + inner[i])
            arrays[i] = wp.array(part, dtype=dtype, device=device, copy=False)
            column += width
    return buffer, arrays


def to_host(array: wp.array) -> np.ndarray:
    """`array` as numpy: a view on the CPU (np.asarray, without the device check and stream scope of
    Warp's `numpy()`: ~0.6 instead of ~1.5 us, and a G-buffer frame reads 28 arrays), a copy from a GPU."""
    return np.asarray(array) if array.device.is_cpu else array.numpy()


def host_empty(shape, dtype, device: str, zeroed: bool = False) -> wp.array:
    """An uninitialised (or, `zeroed`, zero) device array; on the CPU in numpy's memory, which asks
    the kernel for transparent huge pages on large arrays (a page fault per 2 MiB instead of per
    4 KiB: ~1 ms instead of ~10 ms to first write a 1920x1080 RGB float image). Zeroed memory
    that large comes fresh from the kernel, zero already: what is never written costs nothing."""
    if not device.startswith("cpu"):
        return (wp.zeros if zeroed else wp.empty)(shape, dtype=dtype, device=device)
    shape = (shape,) if isinstance(shape, int) else tuple(shape)
    scalar = getattr(dtype, "_wp_scalar_type_", dtype)  # a vector / matrix type's scalar, else dtype itself
    host = (np.zeros if zeroed else np.empty)(shape + tuple(getattr(dtype, "_shape_", ())),
                                              dtype=wp.dtype_to_numpy(scalar))
    return wp.array(host, dtype=dtype, device=device, copy=False)
