"""Integration: small renders against golden images (regenerate with `python tests/golden_scenes.py`).

On failure the render, the reference and the difference are written to the test's temporary folder.
Tolerance: renders are deterministic on one machine; across machines (compilers, FMA) a few edge
samples may flip, so at most 0.5 % of pixels may differ by more than 1e-3 and the mean by 1e-4.
"""

import numpy as np
import pytest

from golden_scenes import GOLDEN, SCENES, render_golden


@pytest.mark.parametrize("name", sorted(SCENES))
def test_render_matches_golden_image(name, compare_images):
    reference = np.load(GOLDEN / f"{name}.npy")
    got = render_golden(name)
    assert reference.std() > 0.05  # the reference is a picture, not a flat colour
    err = np.abs(got - reference).max(axis=-1)
    if (err > 1e-3).mean() > 0.005 or err.mean() > 1e-4:
        compare_images(got, reference, atol=1e-3, name=name)
