"""Figure helpers shared by every demo section: atomic matplotlib saves and labelled image grids of
linear images."""

from __future__ import annotations

import math
from pathlib import Path

from ..files import atomic_path
from ..io import linear_to_srgb


def save_figure(fig, path: Path, tight: bool = True) -> Path:
    """Save a matplotlib figure atomically (format from the suffix, 100 dpi) and close it; `tight`:
    cropped to what is drawn, else the figure's own size."""
    import matplotlib.pyplot as plt

    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip("."), dpi=100, bbox_inches="tight" if tight else None)
    plt.close(fig)
    return path


def image_grid(images, titles, path: Path, columns: int, row_labels=None) -> Path:
    """A grid of linear (H, W, 3) images, sRGB-encoded for display, one title per panel and an
    optional label per row; written atomically to `path`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = math.ceil(len(images) / columns)
    fig, axes = plt.subplots(rows, columns, figsize=(3 * columns, 3 * rows * images[0].shape[0] / images[0].shape[1]),
                             squeeze=False)
    for k, ax in enumerate(axes.flat):
        ax.set_xticks([])
        ax.set_yticks([])
        if k < len(images):
            ax.imshow(linear_to_srgb(images[k]))
            ax.set_title(titles[k], fontsize=9)
        else:
            ax.axis("off")
    if row_labels:
        for r, label in enumerate(row_labels):
            axes[r, 0].set_ylabel(label)
    return save_figure(fig, Path(path))
