"""Forward tracing from the light wastes almost every ray (difflab.demos.tracing)."""

import numpy as np

from difflab.demos import forward_trace, light_buffer_counts
import difflab


def test_forward_tracing_counts_are_consistent_and_few_rays_arrive():
    r = forward_trace(n_rays=100_000, pupil_radius=0.1, width=32, height=24, seed=1)
    assert r["emitted"] == 100_000
    assert 0.1 < r["hit_scene"] / r["emitted"] < 0.3  # the light sees the floor and ball under ~17% of its sphere
    assert r["in_view"] <= r["reached_eye"] < 1e-3 * r["emitted"]
    assert r["image"].sum() == r["in_view"] and r["image"].shape == (24, 32)
    again = forward_trace(n_rays=100_000, pupil_radius=0.1, width=32, height=24, seed=1)
    assert np.array_equal(again["image"], r["image"])  # seeded


def test_light_buffer_counts_shape_and_directional_lights():
    scene = difflab.example_scene("lecture_teapot", width=32, height=24).with_overrides(
        lights=[{"type": "point", "position": [0, 3, 0]}, {"type": "directional", "direction": [0, -1, 0]}])
    counts = light_buffer_counts(scene, 8)
    assert counts[0].shape == (6, 8, 8) and counts[1] is None
    assert counts[0][3].sum() > counts[0][2].sum()  # looking down (-y) the light sees the teapot and the floor
