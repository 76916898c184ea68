"""The lecture's illumination figures measured through the renderer (difflab.demos.illumination)."""

import math

import numpy as np
import pytest

from difflab.demos.illumination import (LECTURE_GEOMETRY, lecture_intensities, lecture_material,
                                        lecture_phong_table, lit_patch)


@pytest.mark.parametrize("theta", [0.0, 30.0, 60.0, 89.0])
def test_lit_patch_is_the_lecture_formula(theta):
    kd, ks, n = 0.6, 0.5, 20.0
    t = math.radians(theta)
    assert lit_patch({"ka": [0.3] * 3, "kd": [0] * 3}, theta, ambient=0.4)[0] == pytest.approx(0.12, abs=1e-6)
    assert lit_patch({"kd": [kd] * 3}, theta, 0.0, ambient=0.0)[0] == pytest.approx(kd * math.cos(t), abs=1e-6)
    # Phong: the viewer 5 degrees off the mirror direction -> cos^n(5 deg); Blinn: H halfway between.
    phong = lit_patch({"kd": [0] * 3, "ks": [ks] * 3, "n": n}, theta, theta - 5.0, ambient=0.0)[0]
    assert phong == pytest.approx(ks * math.cos(math.radians(5.0)) ** n, rel=1e-5)
    blinn = lit_patch({"kd": [0] * 3, "ks": [ks] * 3, "n": n}, theta, theta - 5.0, ambient=0.0, specular="blinn")[0]
    assert blinn == pytest.approx(ks * math.cos(math.radians(2.5)) ** n, rel=1e-5)


@pytest.mark.parametrize("d, K", [(1.0, 0.5), (3.0, 2.0), (8.0, 0.0)])
def test_attenuation_is_one_over_d_plus_k(d, K):
    value = lit_patch({"kd": [0.8] * 3}, 0.0, ambient=0.0, intensity=2.0, distance=d, attenuation=(K, 1.0, 0.0))[0]
    assert value == pytest.approx(0.8 * 2.0 / (d + K), rel=1e-5)


def test_lecture_intensities_come_out_of_the_model():
    got = lecture_intensities()
    assert got["lecture 1"] == pytest.approx(0.31, abs=5e-4)
    assert got["lecture 2"] == pytest.approx(0.52, abs=5e-4)
    assert 8.0 < LECTURE_GEOMETRY["view_deg"] < 9.0
    assert lecture_material("lecture 2")["n"] == pytest.approx(96.0)


def test_phong_table_terms_add_up_and_follow_cos_and_cos_n():
    rows = lecture_phong_table()
    assert len(rows) == 6
    for row in rows:
        assert row["total"] == pytest.approx(row["ambient"] + row["diffuse"] + row["specular"], abs=1e-5)
        t = math.radians(row["incidence_deg"])
        kd = 0.46 if row["material"] == "lecture 2" else 0.0
        assert row["diffuse"] == pytest.approx(kd * math.cos(t), abs=1e-6)
        alpha = math.radians(abs(row["incidence_deg"] - 10.0))
        assert row["specular"] == pytest.approx(0.82 * math.cos(alpha) ** row["n"], rel=1e-4, abs=1e-9)
    assert np.isclose(rows[0]["ambient"], 0.52) and np.isclose(rows[3]["ambient"], 0.39)
