"""The HG half-space's directional albedo (:mod:`jaxsss.render.anisotropic_albedo`), index-matched and behind a
dielectric boundary, against adding-doubling, the white Monte Carlo tables, a Fresnel walk and Chandrasekhar; its use
in :func:`jaxsss.render.bssrdf.albedo_correction`."""

import iadpython
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.render import bssrdf
from jaxsss.render.anisotropic_albedo import (
    ETA_NODES,
    G_NODES,
    X_NODES,
    anisotropic_directional_albedo,
    dielectric_directional_albedo,
    load_anisotropic_albedo,
    load_dielectric_albedo,
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


# The dielectric boundary: A(mu; alpha', g, eta) = (1 - F(mu)) B.


def _adding_doubling_dielectric(alpha_prime: float, g: float, eta: float, quad_pts: int = 32):
    """``(mu outside, A(mu))`` of a fresh adding-doubling run with the boundary (iadpython), specular reflection
    taken off by a run without scattering."""
    a = 1.0 / (1.0 + (1.0 - alpha_prime) / alpha_prime * (1.0 - g))
    sums = []
    for albedo in (a, 0.0):
        sample = iadpython.Sample(a=albedo, b=1e4, g=g, n=eta, quad_pts=quad_pts)
        r = sample.rt_matrices()[0]
        nu, w = np.asarray(sample.nu), np.asarray(sample.twonuw)
        k = np.flatnonzero(nu > sample.nu_c())
        sums.append(w[k] @ r[np.ix_(k, k)])
    mu = np.sqrt(1.0 - eta**2 * (1.0 - nu[k] ** 2))
    return mu, sums[0] - sums[1]


@pytest.mark.parametrize("eta", [1.015, 1.33, 1.44, 1.57])
@pytest.mark.parametrize(("g", "alpha_prime"), [(0.0, 0.987), (0.0, 0.71), (0.33, 0.951), (0.88, 0.83)])
def test_behind_a_boundary_it_matches_fresh_adding_doubling(eta, g, alpha_prime):
    """Off every node (``eta``, ``g``, ``x``, and a 32-point run's cosines against the table's 48), every escaping
    cosine: within 0.3% at ``alpha' >= 0.95`` and 0.65% at 0.71-0.83 (measured 2026-11-29; linear in ``eta`` over
    steps of 0.1 is most of it)."""
    mu, exact = _adding_doubling_dielectric(alpha_prime, g, eta)
    table = np.asarray(dielectric_directional_albedo(mu, jnp.array([alpha_prime]), g, eta))[:, 0]
    np.testing.assert_allclose(table, exact, rtol=3e-3 if alpha_prime > 0.9 else 6.5e-3)


@pytest.mark.parametrize("eta", [1.33, 1.4])
def test_behind_a_boundary_the_white_tables_reflect_the_same_totals(eta):
    """The renderer's white Monte Carlo tables at ``(g = 0, n = eta)`` (a separate transport code, per incident
    photon with the entry's transmittance) integrate to this table's ``A`` at their incidence cosines within 1%."""
    from jaxsss.mc.white import white_mc_profile

    r = np.concatenate([np.linspace(0.0, 2.0, 2001)[1:], np.geomspace(2.0, 400.0, 4000)[1:]])
    sigma_a, sigma_s_prime = 0.05, 1.0
    mus = (1.0, 0.75, 0.5, 0.25, 0.1)
    alpha_prime = jnp.array([sigma_s_prime / (sigma_a + sigma_s_prime)])
    exact = np.asarray(dielectric_directional_albedo(np.array(mus), alpha_prime, 0.0, eta))[:, 0]
    for k, mu in enumerate(mus):
        profile = np.asarray(white_mc_profile(r, sigma_a, sigma_s_prime, bssrdf.white_table(0.0, eta, mu)))
        np.testing.assert_allclose(np.trapezoid(2.0 * np.pi * r * profile, r), exact[k], rtol=1e-2, err_msg=f"mu={mu}")


def test_behind_a_boundary_a_walk_under_diffuse_light_agrees():
    """``2 int A(mu) mu dmu`` against the Fresnel walk under diffuse light (:func:`jaxsss.render.walk.
    diffuse_light_walk`, isotropic, 2e5 photons: 0.3% noise)."""
    from jaxsss.render.walk import diffuse_light_walk

    t, w = np.polynomial.legendre.leggauss(200)
    t = 0.5 * (t + 1.0)
    for albedo, eta in ((0.95, 1.4), (0.8, 1.2)):
        curve = np.asarray(dielectric_directional_albedo(t, jnp.array([albedo]), 0.0, eta))[:, 0]
        walk = diffuse_light_walk(albedo, eta, 200_000, 11)
        np.testing.assert_allclose(np.sum(w * t * curve), walk, rtol=1.2e-2)


def test_behind_a_boundary_shapes_ends_and_invariants():
    """``(M, C)``; without absorption it is the Fresnel transmittance (everything that enters comes back); 0 without
    scattering and at grazing incidence; concave: the chord between cos 0.1 and 0.5 lies under the curve; less
    light comes back at a larger ``eta`` (more is trapped); at ``eta = 1`` it is the index-matched table."""
    from jaxsss.fresnel import fresnel_unpolarised

    mu = np.array([0.0, 0.05, 0.1, 0.25, 0.5, 0.75, 1.0])
    out = np.asarray(dielectric_directional_albedo(mu, jnp.array([1.0, 0.95, 0.6, 0.0]), 0.2, 1.45))
    assert out.shape == (7, 4)
    np.testing.assert_allclose(out[:, 0], 1.0 - fresnel_unpolarised(mu, 1.45, xp=np), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(out[:, 3], 0.0, atol=1e-12)
    assert out[0, 1] == 0.0 and np.all(out[1:, 1] > out[1:, 2])
    chord = 0.625 * out[2, 1:3] + 0.375 * out[4, 1:3]
    assert np.all(out[3, 1:3] > 1.1 * chord), (out[3], chord)
    lo, hi = (np.asarray(dielectric_directional_albedo(mu[1:], jnp.array([0.95]), 0.2, e)) for e in (1.3, 1.5))
    assert np.all(hi < lo)
    np.testing.assert_array_equal(dielectric_directional_albedo(mu, jnp.array([0.9]), 0.5, 1.0),
                                  anisotropic_directional_albedo(mu, jnp.array([0.9]), 0.5))
    tab = load_dielectric_albedo()
    assert tab["B"].shape == (len(G_NODES), len(ETA_NODES), len(X_NODES), len(tab["t"]))
    # The dielectric table's relative cosines are the index-matched table's (one axis for eta interpolation).
    np.testing.assert_allclose(tab["t"], load_anisotropic_albedo()["mu"], rtol=1e-12)


def test_behind_a_boundary_bad_input_is_named():
    with pytest.raises(ValueError, match=r"dielectric_directional_albedo\(eta=1.7\).*\[1.0, 1.6\]"):
        dielectric_directional_albedo(np.array([0.5]), jnp.array([0.9]), 0.0, 1.7)
    with pytest.raises(ValueError, match=r"dielectric_directional_albedo\(eta=0.9\)"):
        dielectric_directional_albedo(np.array([0.5]), jnp.array([0.9]), 0.0, 0.9)
    with pytest.raises(ValueError, match=r"dielectric_directional_albedo\(g=0.97\)"):
        dielectric_directional_albedo(np.array([0.5]), jnp.array([0.9]), 0.97, 1.4)
    with pytest.raises(ValueError, match=r"mu in \[0.5, 1.2\].*\[0, 1\]"):
        dielectric_directional_albedo(np.array([0.5, 1.2]), jnp.array([0.9]), 0.0, 1.4)


def test_behind_a_boundary_the_gradient_matches_central_differences():
    mu = np.array([0.07, 0.4, 0.9])
    f = jax.jit(lambda a: jnp.sum(dielectric_directional_albedo(mu, a, 0.3, 1.38)))
    for alpha_prime in (0.83, 0.97):
        grad = float(jax.grad(f)(jnp.array([alpha_prime]))[0])
        h = 1e-7
        fd = (float(f(jnp.array([alpha_prime + h]))) - float(f(jnp.array([alpha_prime - h])))) / (2 * h)
        np.testing.assert_allclose(grad, fd, rtol=1e-5)
    assert np.isfinite(float(jax.grad(f)(jnp.array([1.0]))[0]))


def test_behind_a_boundary_the_correction_follows_the_concave_curve():
    """:func:`~jaxsss.render.bssrdf.albedo_correction` at ``eta = 1.4``: the nodes times the correction are the
    dielectric ``A(mu)`` (5e-4: the grid is linear where the transmittance bends), 1 at the nodes; between cos 0.1
    and 0.5 it adds 15-35% (the mix under-reflects a concave curve), below 0.1 it takes light away (grazing light
    hardly enters)."""
    mus = (1.0,) + bssrdf.KERNEL_MUS
    albedo = jnp.array([0.9, 0.99])
    correction = jax.jit(bssrdf.albedo_correction, static_argnums=(1, 3, 4))
    mu = np.linspace(0.0, 1.0, 397)
    nodes = dielectric_directional_albedo(np.asarray(mus), albedo, 0.0, 1.4)
    exact = np.asarray(dielectric_directional_albedo(mu, albedo, 0.0, 1.4))
    mix = np.asarray(bssrdf.hat_weights(jnp.asarray(mu), mus) @ nodes)
    got = np.asarray(correction(jnp.asarray(mu), mus, albedo, 0.0, 1.4))
    np.testing.assert_allclose(mix * got, exact, rtol=5e-4, atol=1e-12)
    np.testing.assert_allclose(correction(jnp.asarray(mus), mus, albedo, 0.0, 1.4), 1.0, rtol=1e-12)
    at = np.asarray(correction(jnp.array([0.25, 0.05]), mus, albedo, 0.0, 1.4))
    assert np.all((at[0] > 1.15) & (at[0] < 1.35)) and np.all(at[1] < 0.8), at
    t, w = np.polynomial.legendre.leggauss(200)
    t = 0.5 * (t + 1.0)
    diffuse = np.sum((w * t)[:, None] * np.asarray(dielectric_directional_albedo(t, albedo, 0.0, 1.4)), axis=0)
    diffuse_mix = np.asarray(bssrdf._diffuse_weights(mus) @ np.asarray(nodes))
    np.testing.assert_allclose(diffuse_mix * np.asarray(correction(None, mus, albedo, 0.0, 1.4)), diffuse, rtol=1e-6)


def test_the_command_line_describes_both_tables(capsys):
    from jaxsss.render.anisotropic_albedo import main

    assert main([]) == 0
    out = capsys.readouterr().out
    assert "anisotropic_albedo.npz: A (g, x, mu) (20, 41, 24)" in out
    assert f"dielectric_albedo.npz: B (g, eta, x, t) (20, {len(ETA_NODES)}, 41, 24), eta 1.01-1.6" in out
