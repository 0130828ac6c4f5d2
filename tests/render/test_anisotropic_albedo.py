"""The HG half-space's directional albedo (:mod:`jaxsss.render.anisotropic_albedo`) against adding-doubling, the
white Monte Carlo tables and Chandrasekhar; its use in :func:`jaxsss.render.bssrdf.albedo_correction`."""

import iadpython
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.render import bssrdf
from jaxsss.render.anisotropic_albedo import (
    G_NODES,
    X_NODES,
    anisotropic_directional_albedo,
    load_anisotropic_albedo,
)


def _adding_doubling(alpha_prime: float, g: float, quad_pts: int = 20):
    """``(nu, A(nu))`` of a fresh adding-doubling run (iadpython) at its own quadrature cosines."""
    a = 1.0 / (1.0 + (1.0 - alpha_prime) / alpha_prime * (1.0 - g))
    sample = iadpython.Sample(a=a, b=1e4, g=g, n=1.0, quad_pts=quad_pts)
    r = sample.rt_matrices()[0]
    return np.asarray(sample.nu), np.dot(sample.twonuw, r)


@pytest.mark.parametrize("g", [0.33, 0.72, 0.88, 0.93])
@pytest.mark.parametrize("alpha_prime", [0.62, 0.83, 0.951, 0.987])
def test_between_the_nodes_it_matches_fresh_adding_doubling(g, alpha_prime):
    """Off every node of the table (``g``, ``x``, and the 20-point run's cosines against the table's 24): within
    0.4% at ``mu >= 0.05`` (below, the 20-point run's own quadrature error reaches 1-2% at ``g = 0.93``)."""
    nu, exact = _adding_doubling(alpha_prime, g)
    assert float(g) not in G_NODES and round(float(np.sqrt(1.0 - alpha_prime)), 4) not in X_NODES
    table = np.asarray(anisotropic_directional_albedo(nu, jnp.array([alpha_prime]), g))[:, 0]
    keep = nu >= 0.05
    np.testing.assert_allclose(table[keep], exact[keep], rtol=4e-3)


def test_at_g_zero_it_is_chandrasekhars():
    """The ``g = 0`` row is Chandrasekhar's ``1 - H(mu) sqrt(1 - a)`` (an independent formula) within 2e-4."""
    tab = load_anisotropic_albedo()
    alpha_prime = 1.0 - tab["x"][1:-1] ** 2
    h = np.asarray(bssrdf.directional_albedo(tab["mu"][:, None], alpha_prime[None, :]))
    np.testing.assert_allclose(tab["A"][0, 1:-1].T, h, rtol=2e-4)


def test_the_white_tables_reflect_the_same_totals_at_g_09():
    """The renderer's g = 0.9 oblique tables (white Monte Carlo, a separate transport code) integrate to this table's
    ``A`` at their incidence cosines 1, 0.5 and 0.1 within 0.5%."""
    from jaxsss.mc.white import white_mc_profile

    r = np.concatenate([np.linspace(0.0, 2.0, 2001)[1:], np.geomspace(2.0, 400.0, 4000)[1:]])
    sigma_a, sigma_s_prime = 0.1, 1.0
    a_exact = np.asarray(anisotropic_directional_albedo(np.array([1.0, 0.5, 0.1]),
                                                        jnp.array([sigma_s_prime / (sigma_a + sigma_s_prime)]), 0.9))
    for k, mu in enumerate((1.0, 0.5, 0.1)):
        profile = np.asarray(white_mc_profile(r, sigma_a, sigma_s_prime, bssrdf.white_table(0.9, 1.0, mu)))
        total = np.trapezoid(2.0 * np.pi * r * profile, r)
        np.testing.assert_allclose(total, a_exact[k, 0], rtol=5e-3)


def test_shapes_ends_and_invariants():
    """``(M, C)``; ``A = 1`` without absorption and 0 without scattering; grazing light reflects more (``A`` falls
    with ``mu``); more absorption reflects less; beyond the table's cosines it is held."""
    mu = np.array([0.0, 0.001, 0.05, 0.3, 0.7, 1.0])
    out = np.asarray(anisotropic_directional_albedo(mu, jnp.array([1.0, 0.95, 0.6, 0.0]), 0.8))
    assert out.shape == (6, 4)
    np.testing.assert_allclose(out[:, 0], 1.0, rtol=1e-12)
    np.testing.assert_allclose(out[:, 3], 0.0, atol=1e-12)
    assert np.all(np.diff(out[:, 1:3], axis=0) <= 1e-12), out
    assert np.all(out[:, 1] > out[:, 2])
    assert out[0, 1] == out[1, 1]  # held below the smallest quadrature cosine (0.0023)
    tab = load_anisotropic_albedo()
    assert tab["A"].shape == (len(G_NODES), len(X_NODES), len(tab["mu"])) and np.all(np.isfinite(tab["A"]))


def test_bad_input_is_named():
    with pytest.raises(ValueError, match=r"anisotropic_directional_albedo\(g=0.97\).*\[0.0, 0.95\]"):
        anisotropic_directional_albedo(np.array([0.5]), jnp.array([0.9]), 0.97)
    with pytest.raises(ValueError, match=r"anisotropic_directional_albedo\(g=-0.1\)"):
        anisotropic_directional_albedo(np.array([0.5]), jnp.array([0.9]), -0.1)
    with pytest.raises(ValueError, match=r"mu in \[-0.2, 0.5\].*\[0, 1\]"):
        anisotropic_directional_albedo(np.array([-0.2, 0.5]), jnp.array([0.9]), 0.5)


@pytest.mark.parametrize("alpha_prime", [0.83, 0.97, 1.0])
def test_gradient_in_the_albedo(alpha_prime):
    """Against central differences (one table cell: linear in ``x = sqrt(1 - a')``); finite at ``a' = 1``."""
    mu = np.array([0.07, 0.4, 0.9])
    f = jax.jit(lambda a: jnp.sum(anisotropic_directional_albedo(mu, a, 0.9)))
    grad = float(jax.grad(f)(jnp.array([alpha_prime]))[0])
    assert np.isfinite(grad)
    if alpha_prime == 1.0:
        return
    h = 1e-7
    fd = (float(f(jnp.array([alpha_prime + h]))) - float(f(jnp.array([alpha_prime - h])))) / (2 * h)
    np.testing.assert_allclose(grad, fd, rtol=1e-5)


def test_the_renderers_correction_follows_the_hg_curve():
    """:func:`~jaxsss.render.bssrdf.albedo_correction` with ``g > 0``: the hat-weighted nodes times the correction are
    the HG medium's ``A(mu)`` (2e-4 of the grid's interpolation), 1 at the nodes, and the diffuse light's
    ``2 int A mu dmu``. At g = 0.9 this is not the isotropic equivalent's curve: at ``mu = 0.3`` that one reflected
    2.7% too much, at ``mu = 0.03`` 5% too little."""
    mus = (1.0,) + bssrdf.KERNEL_MUS
    albedo = jnp.array([0.833])
    correction = jax.jit(bssrdf.albedo_correction, static_argnums=(1, 3))
    mu = np.linspace(0.0, 1.0, 397)
    nodes = anisotropic_directional_albedo(np.asarray(mus), albedo, 0.9)
    exact = np.asarray(anisotropic_directional_albedo(mu, albedo, 0.9))
    mix = np.asarray(bssrdf.hat_weights(jnp.asarray(mu), mus) @ nodes)
    np.testing.assert_allclose(mix * np.asarray(correction(jnp.asarray(mu), mus, albedo, 0.9)), exact, rtol=2e-4)
    np.testing.assert_allclose(correction(jnp.asarray(mus), mus, albedo, 0.9), 1.0, rtol=1e-12)
    t, w = np.polynomial.legendre.leggauss(200)
    t = 0.5 * (t + 1.0)
    diffuse = np.sum(w * t * np.asarray(anisotropic_directional_albedo(t, albedo, 0.9))[:, 0])
    diffuse_mix = float(bssrdf._diffuse_weights(mus) @ np.asarray(nodes)[:, 0])
    np.testing.assert_allclose(diffuse_mix * float(correction(None, mus, albedo, 0.9)[0]), diffuse, rtol=1e-6)
    iso = np.asarray(correction(jnp.array([0.3, 0.03]), mus, albedo, 0.0))[:, 0]
    hg = np.asarray(correction(jnp.array([0.3, 0.03]), mus, albedo, 0.9))[:, 0]
    assert iso[0] / hg[0] > 1.02 and iso[1] / hg[1] < 0.96, (iso, hg)
