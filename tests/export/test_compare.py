"""Image metrics (jaxsss.export.compare) on known images and the sphere's known geometry."""

from pathlib import Path

import numpy as np
import pytest

from jaxsss.export.compare import COS_BINS, compare_images, error_by_cos, error_map, pixel_geometry
from jaxsss.render import load_scene

REFERENCES = Path(__file__).parent / "references"


@pytest.fixture(scope="module")
def sphere():
    scene = load_scene(REFERENCES / "skin1_sphere.toml")
    return scene, pixel_geometry(scene, coverage_spp=16)


def test_known_errors(sphere):
    scene, px = sphere
    rng = np.random.default_rng(0)
    ref = np.where(px.hit[..., None], 1.0 + rng.random((64, 64, 3)), 0.0)
    same = compare_images(ref, ref, px)
    assert same["mare_lit"] == [0.0] * 3 and same["sum_ratio"] == [1.0] * 3
    m = compare_images(1.1 * ref, ref, px)
    np.testing.assert_allclose(m["mare_lit"], 0.1, rtol=1e-12)
    np.testing.assert_allclose(m["mare_band"], 0.1, rtol=1e-12)
    np.testing.assert_allclose(m["bias_lit"], 0.1, rtol=1e-12)
    np.testing.assert_allclose(m["sum_ratio"], 1.1, rtol=1e-12)
    # Errors confined to the silhouette (partly covered pixels) are not counted.
    edge = px.hit & (px.coverage < 1.0)
    assert edge.any()
    assert compare_images(np.where(edge[..., None], 5.0 * ref, ref), ref, px)["mare_lit"] == [0.0] * 3


def test_binned_error_sees_a_smooth_bias_through_pixel_noise(sphere):
    scene, px = sphere
    rng = np.random.default_rng(1)
    ref = np.where(px.hit[..., None], np.ones((64, 64, 3)), 0.0)
    noisy = ref * (1.0 + 0.2 * rng.standard_normal(ref.shape))  # a reference with 20% noise per pixel
    m = compare_images(1.05 * ref, noisy, px)
    # Per pixel the noise dominates (its mean |.| is about 0.8 x 0.2 and more through 1 / ref); in 4 x 4 blocks it is
    # 4 times smaller, so the 5% bias shows.
    assert all(0.15 < e < 0.23 for e in m["mare_lit"])
    assert all(0.04 < e < 0.08 for e in m["mare_binned"]), m["mare_binned"]
    assert m["n_binned"][0] > 50 and 16 * m["n_binned"][0] <= m["n_lit"][0]
    exact = compare_images(1.05 * ref, ref, px)
    np.testing.assert_allclose(exact["mare_binned"], 0.05, rtol=1e-12)


def test_lit_threshold_and_band(sphere):
    scene, px = sphere
    # Radiance = max(cos to the light, 0) + 0.005: dark side below 1% of the peak, so not lit.
    cos = px.cos[..., 0]
    ref = np.repeat(np.where(px.hit, np.clip(np.nan_to_num(cos), 0.0, None) + 0.005, 0.0)[..., None], 3, axis=-1)
    m = compare_images(2.0 * ref, ref, px)
    covered = px.hit & (px.coverage >= 1.0 - 1e-3)
    assert m["n_covered"] == covered.sum()
    assert m["n_lit"][0] == (covered & (ref[..., 0] > 0.01 * ref[..., 0][covered].max())).sum()
    assert m["n_lit"][0] < m["n_covered"]
    band = covered & (np.abs(cos) <= 0.1) & (ref[..., 0] > 0.01 * ref[..., 0][covered].max())
    assert m["n_band"][0] == band.sum() > 10
    # The sphere's terminator is a great circle: the band pixels' cosines are small by construction.
    assert np.all(np.abs(cos[band]) <= 0.1)


def test_bad_input(sphere):
    _, px = sphere
    with pytest.raises(ValueError, match=r"test \(64, 64, 3\) and ref \(64, 63, 3\)"):
        compare_images(np.ones((64, 64, 3)), np.ones((64, 63, 3)), px)
    with pytest.raises(ValueError, match="pixel geometry is"):
        compare_images(np.ones((8, 8, 3)), np.ones((8, 8, 3)), px)
    assert np.isnan(error_map(np.ones((64, 64, 3)), np.ones((64, 64, 3)), px)[0, 0]).all()


def test_error_by_cos_locates_a_planted_error(sphere):
    """20% too bright where cos > 0.7, exact elsewhere: only the bins above 0.7 show it."""
    _, px = sphere
    cos = np.nan_to_num(px.cos[..., 0], nan=-1.0)
    ref = np.repeat(np.where(px.hit, 1.0, 0.0)[..., None], 3, axis=-1)
    test = ref * np.where(cos > 0.7, 1.2, 1.0)[..., None]
    bins = error_by_cos(test, ref, px)
    assert [b["cos"] for b in bins] == [list(p) for p in zip(COS_BINS[:-1], COS_BINS[1:])]
    for b in bins:
        if b["n"] == 0:
            continue
        expected = 0.2 if b["cos"][0] >= 0.7 else 0.0
        np.testing.assert_allclose(b["bias"], expected, atol=1e-12)
    assert sum(b["n"] for b in bins if b["cos"][0] >= 0.7) > 50
