"""Irradiance caching with gradients (jaxsss.render.cache): analytic against autodiff gradients, exact values at the
caches, convergence to the hierarchical image as a -> 0, both variants, and gradients in the material."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import jaxsss
from jaxsss.render import prepare
from jaxsss.render import radiance as rad
from jaxsss.render.cache import prepare_cached, render_cached, split_disk_constant
from tests.gradcheck import assert_grad_matches_fd
from tests.render.test_renderer import _scene


@pytest.fixture(scope="module")
def sphere():
    return _scene()


def test_analytic_gradient_equals_autodiff(sphere):
    prepared, _, _ = prepare(sphere, resolution=(10, 10))
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
    reference = np.asarray(prepare(sphere, resolution=(16, 16))[0].exitance(m))
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
    two = render_cached(sphere, 0.2, resolution=(16, 16))
    one = render_cached(sphere, 0.2, resolution=(16, 16), one_pass=True)
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
