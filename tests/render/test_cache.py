"""Irradiance caching with gradients (jaxsss.render.cache): analytic against autodiff gradients, exact values at the
caches, convergence to the hierarchical image as a -> 0, both variants, gradients in the material, the gradient
modes, where caches go, the plan's cache ratio and fitting through the cached image."""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import jaxsss
from jaxsss.render import prepare, render
from jaxsss.render import radiance as rad
from jaxsss.render.cache import (
    GRADIENTS,
    explain_cached,
    place_caches,
    prepare_cached,
    split_disk_constant,
)
from tests.gradcheck import assert_grad_matches_fd
from tests.render.test_renderer import _scene


@pytest.fixture(scope="module")
def sphere():
    return _scene()


def test_analytic_gradient_equals_autodiff(sphere):
    prepared, _, _ = prepare(sphere, resolution=(10, 10), bssrdf="dipole")  # the analytic gradient is the dipole's
    m = sphere.material.medium
    analytic = np.asarray(eqx.filter_jit(lambda p, m: p.exitance_gradient(m))(prepared, m))
    autodiff = np.asarray(eqx.filter_jit(lambda p, m: p.exitance_gradient_autodiff(m))(prepared, m))
    assert analytic.shape == (prepared.n_queries, 3, 3)
    np.testing.assert_allclose(analytic, autodiff, rtol=1e-8, atol=1e-8 * np.abs(autodiff).max())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_dipole_gradient_factor_on_random_configurations(seed):
    rng = np.random.default_rng(seed)
    medium = jaxsss.Medium(jnp.asarray(rng.uniform(1e-3, 0.5, 3)), jnp.asarray(rng.uniform(0.5, 5.0, 3)),
                           float(rng.uniform(1.0, 1.6)))
    x, p = rng.normal(size=(2, 3))

    def profile(xx):
        return jaxsss.dipole_profile(jnp.linalg.norm(xx - p)[None], medium)

    import jax

    expect = np.asarray(jax.jacfwd(profile)(jnp.asarray(x)))  # (C, 3)
    got = np.asarray(rad.dipole_gradient_factor(jnp.linalg.norm(x - p), medium))[:, None] * (x - p)[None, :]
    np.testing.assert_allclose(got, expect, rtol=1e-10)


def test_interpolation_is_exact_at_caches_and_converges(sphere):
    m = sphere.material.medium
    reference = np.asarray(prepare(sphere, resolution=(16, 16), bssrdf="dipole")[0].exitance(m))  # as the caches
    errors = []
    for a in (0.5, 0.05, 1e-6):
        cached, _, info, placement = prepare_cached(sphere, a, resolution=(16, 16))
        got = np.asarray(cached.exitance(m))
        cp = placement.cache_point
        np.testing.assert_allclose(got[cp], reference[cp], rtol=1e-12)
        errors.append(float(np.sqrt(np.mean(((got - reference) / reference) ** 2))))
        assert info["n_caches"] == len(cp) and 0 < info["cache_ratio"] <= 1
    assert errors[-1] < 1e-12, errors  # every point its own cache
    assert errors[0] >= errors[1] >= errors[2], errors


def test_one_pass_and_two_pass_both_run(sphere):
    two = render(sphere, "cached", error_bound=0.2, resolution=(16, 16), always=True)
    one = render(sphere, "cached", error_bound=0.2, resolution=(16, 16), one_pass=True, always=True)
    assert two.report["n_caches"] == one.report["n_caches"]  # same placement, fewer caches visible in one pass
    for res in (one, two):
        assert res.image.shape == (16, 16, 3) and np.isfinite(res.image).all()
        for key in ("n_caches", "cache_ratio", "interpolation_error_estimate_mean", "timings"):
            assert key in res.report


def test_cached_image_gradient_in_the_material(sphere):
    cached, _, _, _ = prepare_cached(sphere, 0.1, resolution=(8, 8))

    def loss(theta):
        medium = jaxsss.Medium(jnp.exp(theta[:3]), jnp.exp(theta[3:]), 1.3)
        return jnp.sum(cached.image(medium) ** 2)

    assert_grad_matches_fd(loss, jnp.log(jnp.array([0.05, 0.1, 0.2, 1.05, 1.5, 2.0])), rtol=1e-5)


def test_split_disk_constant_and_bad_bound(sphere):
    m = jaxsss.Medium(0.01, 1.0, 1.3)
    c = np.asarray(split_disk_constant(2.0, m))
    assert c > 0 and np.isfinite(c)
    with pytest.raises(ValueError, match="error_bound"):
        prepare_cached(sphere, 0.0, resolution=(4, 4))


def test_gradient_modes(sphere):
    m = sphere.material.medium
    cached, _, info, _ = prepare_cached(sphere, 0.3, resolution=(8, 8))
    assert info["gradient"] == "far"  # the default
    values = {mode: [np.asarray(v) for v in dataclasses.replace(cached, gradient=mode).cache_values(m)]
              for mode in GRADIENTS}
    s, full = values["analytic"]
    far = np.asarray(cached.cache.exitance_gradient(m, near=False))
    np.testing.assert_allclose(values["far"][1], far, rtol=1e-12)
    np.testing.assert_allclose(values["autodiff"][1], full, rtol=1e-8, atol=1e-8 * np.abs(full).max())
    assert not np.allclose(far, full)  # the near-field term is there and is left out
    assert np.all(values["none"][1] == 0.0)
    for mode in GRADIENTS:
        np.testing.assert_array_equal(values[mode][0], s)  # S itself never depends on the gradient mode
    with pytest.raises(ValueError, match="gradient='exact'"):
        prepare_cached(sphere, 0.3, resolution=(4, 4), gradient="exact")


def _plane(n=60, spacing=0.05):
    """A flat grid of visible points and a denser grid of irradiance samples on z = 0 (mm)."""
    g = (np.arange(n) - n / 2) * spacing
    xx, yy = np.meshgrid(g, g)
    pts = np.stack([xx.ravel(), yy.ravel(), np.zeros(n * n)], axis=1)
    normals = np.tile([0.0, 0.0, 1.0], (n * n, 1))
    pixel = np.arange(n * n)
    return pts, normals, pixel, n


def test_caches_gather_at_shadow_edges():
    medium = jaxsss.Medium(0.05, 5.0, 1.3)  # l_d about 1.2 mm
    pts, normals, pixel, width = _plane()
    uniform = place_caches(pts, normals, pixel, width, pts, normals, np.ones(len(pts)), medium, 0.3)
    shadowed = np.where(pts[:, 0] < 0.0, 1.0, 0.0) + 1e-3  # a shadow edge along x = 0
    edge = place_caches(pts, normals, pixel, width, pts, normals, shadowed, medium, 0.3)
    assert len(edge.cache_point) > 3 * len(uniform.cache_point)
    # Under uniform light every domain reaches the disk radius (the largest allowed).
    np.testing.assert_allclose(uniform.radius, uniform.disk_radius)
    # With the edge, the caches crowd near it: the density of caches within l_d of x = 0 is higher than away.
    x = np.abs(pts[edge.cache_point, 0])
    near = x < uniform.disk_radius
    assert near.mean() > 0.5, near.mean()


def test_plan_reports_the_cache_ratio(sphere):
    plan, placement = explain_cached(sphere, 0.3, resolution=(16, 16))
    item = plan.items[-1]
    assert plan.method == "cached" and item.name == "irradiance caches" and item.included
    assert f"{len(placement.cache_point)} caches" in item.reason and "cache ratio" in item.reason
    cached, plan2, info, _ = prepare_cached(sphere, 0.3, resolution=(16, 16))
    assert plan2.items[-1].reason == item.reason and info["n_caches"] == len(placement.cache_point)


def test_fit_image_with_the_cached_method(sphere):
    from fitting import fit_image

    truth = sphere.material.medium
    cached = prepare_cached(sphere, 0.3, cutoff=False, share_channels=False)[0]
    target = np.asarray(cached.image(truth))
    fit = fit_image(sphere, target, method="cached", error_bound=0.3, always=True, max_pixels=300)
    assert fit.converged, fit.message
    assert not any("couples the channels" in w for w in fit.warnings), fit.warnings  # the per-channel Jacobian
    np.testing.assert_allclose(fit.sigma_a, truth.sigma_a, rtol=1e-3)
    np.testing.assert_allclose(fit.sigma_s_prime, truth.sigma_s_prime, rtol=1e-3)


@pytest.mark.parametrize("name", ["marble_teapot", "skin_sphere", "ketchup_torus", "milk_box_on_floor"])
def test_example_scenes_render_with_the_cached_method(name):
    from pathlib import Path

    from jaxsss.render import load_scene

    scene = load_scene(Path(__file__).resolve().parents[2] / "examples" / f"{name}.toml")
    result = render(scene, "cached", error_bound=0.3, resolution=(12, 12), always=True)
    assert result.image.shape == (12, 12, 3) and np.isfinite(result.image).all() and result.image.max() > 0
    assert 0 < result.report["n_caches"] <= result.report["n_shaded_points"]


def test_plan_leaves_caching_out_where_it_does_not_pay(sphere):
    """Below CACHE_MIN_POINTS shaded points the registered method renders hierarchically and its plan says why;
    ``always=True`` keeps the caches."""
    from jaxsss.render import explain_method, prepare_method
    from jaxsss.render.cache import CACHE_MIN_POINTS, caching_pays

    assert caching_pays(CACHE_MIN_POINTS)[0] and not caching_pays(CACHE_MIN_POINTS - 1)[0]
    plan = explain_method(sphere, "cached", resolution=(12, 12))
    item = plan.items[-1]
    assert plan.method == "cached" and item.name == "irradiance caches" and not item.included
    assert "left out" in item.reason and f"< {CACHE_MIN_POINTS}" in item.reason
    prep = prepare_method(sphere, "cached", resolution=(12, 12))
    assert prep.method == "cached" and prep.diagnostics["n_caches"] == 0 and "placement" not in prep.extras
    kept = prepare_method(sphere, "cached", resolution=(12, 12), always=True)
    assert kept.diagnostics["n_caches"] > 0 and kept.plan.items[-1].included
