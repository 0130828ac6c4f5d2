"""Phase functions: normalisation, mean cosines, the angle convention, shapes and bad names."""

import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate

from jaxsss.phase import (
    PHASE_FUNCTIONS,
    SCHLICK_G_MAX,
    hg_phase,
    phase_value,
    schlick_k_from_g,
    schlick_mean_cosine,
    schlick_phase,
)

G_VALUES = [-0.9, -0.5, 0.0, 0.25, 0.4, 0.8, 0.95]


def _sphere_integral(f):
    # Integral over the sphere of an azimuth-independent function: 2 pi int_{-1}^{1} f(mu) dmu.
    val, _ = integrate.quad(lambda mu: float(f(mu)), -1.0, 1.0, limit=200, epsabs=1e-13, epsrel=1e-12)
    return 2.0 * np.pi * val


@pytest.mark.parametrize("name, g", [("hg", g) for g in G_VALUES] + [("schlick", g) for g in G_VALUES[:-1] + [0.938]])
def test_phase_functions_integrate_to_one(name, g):
    # Tolerance 1e-9: adaptive quadrature of a smooth integrand (peaked for |g| = 0.95, hence not 1e-12).
    total = _sphere_integral(lambda mu: phase_value(name, jnp.asarray(mu), g))
    assert total == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("g", G_VALUES)
def test_hg_mean_cosine_is_g(g):
    mean = _sphere_integral(lambda mu: mu * hg_phase(jnp.asarray(mu), g))
    assert mean == pytest.approx(g, abs=1e-9)


@pytest.mark.parametrize("k", [-0.9, -0.3, 1e-4, 0.2, 0.6, 0.95])
def test_schlick_mean_cosine_closed_form(k):
    mean = _sphere_integral(lambda mu: mu * schlick_phase(jnp.asarray(mu), k))
    assert float(schlick_mean_cosine(k)) == pytest.approx(mean, abs=1e-9)


def test_schlick_k_matches_hg_shape_roughly():
    # k = 1.55 g - 0.55 g^3 is odd, stays inside (-1, 1), and its mean cosine is within 0.08 of g (a shape match,
    # not an exact moment match; documented in docs/layered.md).
    g = np.linspace(-SCHLICK_G_MAX, SCHLICK_G_MAX, 199)
    k = np.asarray(schlick_k_from_g(jnp.asarray(g)))
    np.testing.assert_allclose(k, -k[::-1], atol=1e-15)
    assert np.all(np.abs(k) < 1.0)
    # Just beyond the bound the cubic leaves (-1, 1): why "schlick" layers reject larger |g|.
    assert float(schlick_k_from_g(0.9385)) > 1.0
    assert np.max(np.abs(np.asarray(schlick_mean_cosine(jnp.asarray(k))) - g)) < 0.08  # largest near the bound, 0.075 at g = 0.938


@pytest.mark.parametrize("name", sorted(PHASE_FUNCTIONS))
def test_positive_g_scatters_forward(name):
    # mu is the cosine of the scattering angle: mu = 1 is straight on; positive g favours it.
    assert float(phase_value(name, 1.0, 0.5)) > float(phase_value(name, -1.0, 0.5))
    assert float(phase_value(name, 1.0, -0.5)) < float(phase_value(name, -1.0, -0.5))


def test_shapes_broadcast_over_channels():
    mu = jnp.linspace(-1.0, 1.0, 5)[:, None]
    g = jnp.array([0.1, 0.5, 0.9])
    out = phase_value("schlick", mu, g)
    assert out.shape == (5, 3)
    for c in range(3):
        np.testing.assert_allclose(out[:, c], phase_value("schlick", mu[:, 0], g[c]), rtol=1e-15)


def test_unknown_phase_name_lists_valid():
    with pytest.raises(ValueError, match="hg, schlick"):
        phase_value("rayleigh", 0.0, 0.0)
