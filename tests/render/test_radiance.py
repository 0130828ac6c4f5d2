"""The renderer's material-dependent terms (jaxsss.render.radiance): normalisation, reference values, shapes, bad
and extreme input, and gradients."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxsss
from jaxsss.render import radiance as rad
from tests.gradcheck import assert_grad_matches_fd


def _hemisphere(n=96):
    """Gauss-Legendre nodes in mu = cos(theta) on [0, 1] with weights for int ... dmu."""
    x, w = np.polynomial.legendre.leggauss(n)
    return jnp.asarray(0.5 * (x + 1)), jnp.asarray(0.5 * w)


@pytest.mark.parametrize("eta", [0.75, 1.0, 1.33, 1.5, 2.0])
def test_exit_radiance_integrates_to_exitance(eta):
    # Trap 1: int L_o cos dw = 2 pi int L_o(mu) mu dmu must equal M_o exactly (exact F_dr).
    medium = jaxsss.Medium(0.01, 1.0, eta, fresnel="exact")
    mu, w = _hemisphere(96)
    # For eta < 1 the transmittance vanishes below the critical angle like sqrt(mu - mu_c): integrate from mu_c
    # with mu = mu_c + (1 - mu_c) s^2, which makes the integrand smooth in s.
    mu_c = np.sqrt(1 - eta**2) if eta < 1 else 0.0
    mu, w = mu_c + (1 - mu_c) * mu**2, 2 * (1 - mu_c) * mu * w
    m_o = jnp.array([[2.5, 1.0, 0.25]])
    radiance = rad.exit_radiance(medium, jnp.broadcast_to(m_o, (mu.shape[0], 3)), mu)
    total = 2 * jnp.pi * jnp.sum((w * mu)[:, None] * radiance, axis=0)
    np.testing.assert_allclose(total, m_o[0], rtol=1e-10)


def test_F_dt_external_reciprocity():
    eta = jnp.array([1.1, 1.3, 1.5, 2.0])
    np.testing.assert_allclose(rad.F_dt_external(eta, "exact"), eta**2 * jaxsss.F_dt(eta, "exact"), rtol=1e-10)


def test_hg_phase_normalised():
    mu, w = _hemisphere(400)
    cos = 2 * mu - 1  # [-1, 1]
    for g in (0.0, 0.5, -0.3, 0.9):
        total = 2 * jnp.pi * 2 * jnp.sum(w * rad.hg_phase(cos, g))
        np.testing.assert_allclose(total, 1.0, rtol=1e-6 if g < 0.9 else 1e-3)


def test_single_scattering_matches_chandrasekhar_half_space():
    # Index-matched, isotropic, no absorption: the single-scattering albedo at normal incidence is
    # 2 pi int_0^1 f_r mu dmu = (1 - ln 2) / 2.
    medium = jaxsss.Medium(jnp.array([0.0, 0.0]), jnp.array([1.0, 3.0]), 1.0)
    mu, w = _hemisphere(128)
    eye = jnp.stack([jnp.sqrt(1 - mu**2), jnp.zeros_like(mu), mu], -1)
    n = jnp.broadcast_to(jnp.array([0.0, 0.0, 1.0]), eye.shape)
    light = jnp.broadcast_to(jnp.array([0.0, 0.0, 1.0]), (mu.shape[0], 1, 3))
    f = rad.single_scattering(medium, n, eye, light, jnp.ones((mu.shape[0], 1, 2)))
    r1 = 2 * jnp.pi * jnp.sum((w * mu)[:, None] * f, axis=0)
    np.testing.assert_allclose(r1, (1 - np.log(2)) / 2, rtol=1e-6)


def test_single_scattering_share_bounds():
    forward = rad.single_scattering_share(jaxsss.Medium(0.01, 1.0, 1.3, g=0.95))
    iso = rad.single_scattering_share(jaxsss.Medium(0.01, 1.0, 1.3))
    absorbing = rad.single_scattering_share(jaxsss.Medium(1.0, 1.0, 1.3))
    assert 0 < float(forward[0]) < float(iso[0]) < float(absorbing[0]) < 1


def test_single_scattering_scales_with_albedo_and_vanishes_under_tir():
    n = jnp.array([[0.0, 0.0, 1.0]])
    eye = jnp.array([[0.0, 0.0, 1.0]])
    light = jnp.array([[[0.0, 0.0, 1.0]]])
    e = jnp.ones((1, 1, 1))
    a = rad.single_scattering(jaxsss.Medium(0.0, 1.0, 1.3), n, eye, light, e)
    b = rad.single_scattering(jaxsss.Medium(1.0, 1.0, 1.3), n, eye, light, e)
    np.testing.assert_allclose(b, 0.5 * a, rtol=1e-12)
    # eta < 1: light from 80 degrees cannot enter (total internal reflection of the reversed path).
    s80 = np.sin(np.radians(80))
    grazing = jnp.array([[[s80, 0.0, np.cos(np.radians(80))]]])
    assert float(rad.single_scattering(jaxsss.Medium(0.0, 1.0, 0.7), n, eye, grazing, e)[0, 0]) == 0.0


def test_specular_ggx_conserves_energy():
    medium = jaxsss.Medium(0.01, 1.0, 1.5)
    mu, w = _hemisphere(200)
    phi = jnp.linspace(0, 2 * jnp.pi, 128, endpoint=False)
    m, p = jnp.meshgrid(mu, phi, indexing="ij")
    s = jnp.sqrt(1 - m**2)
    eye = jnp.stack([s * jnp.cos(p), s * jnp.sin(p), m], -1).reshape(-1, 3)
    n = jnp.broadcast_to(jnp.array([0.0, 0.0, 1.0]), eye.shape)
    theta = np.radians(30)
    light = jnp.broadcast_to(jnp.array([np.sin(theta), 0.0, np.cos(theta)]), (eye.shape[0], 1, 3))
    for roughness in (0.2, 0.5):
        # E = 1 W/mm^2: the reflected exitance int L cos dw is the directional albedo (< F(eta, ...) + masking).
        f = rad.specular_ggx(medium, n, eye, light, jnp.ones((eye.shape[0], 1, 1)), roughness).reshape(m.shape)
        albedo = float(jnp.sum((w * mu)[:, None] * f) * (2 * jnp.pi / 128))
        assert 0.02 < albedo < 0.1, albedo  # about F(1.5) = 0.04 for a smooth-ish surface


def test_transmitted_flux_shapes_and_entry_fresnel():
    medium = jaxsss.Medium(jnp.array([0.01, 0.02, 0.03]), jnp.array([1.0, 1.1, 1.2]), 1.4)
    n, L = 5, 2
    cos = jnp.linspace(0.1, 1.0, n * L).reshape(n, L)
    irr = jnp.ones((n, L, 3))
    flux = rad.transmitted_flux(medium, jnp.full(n, 2.0), cos, irr)
    assert flux.shape == (n, 3)
    expect = 2.0 * jnp.sum(1 - jaxsss.fresnel_reflectance(1.4, cos), axis=1)
    np.testing.assert_allclose(flux[:, 1], expect, rtol=1e-12)
    with_ind = rad.transmitted_flux(medium, jnp.full(n, 2.0), cos, irr, indirect=jnp.ones((n, 3)),
                                    texture=jnp.full((n, 3), 0.5))
    np.testing.assert_allclose(with_ind[:, 0], 0.5 * (expect + 2.0 * rad.F_dt_external(1.4)), rtol=1e-12)


def test_disc_integral_limits():
    medium = jaxsss.Medium(jnp.array([0.001, 0.05, 1.0]), jnp.array([1.0, 2.0, 0.5]), 1.4)
    np.testing.assert_allclose(rad.disc_integral(1e6, medium), jaxsss.medium_total_diffuse_reflectance(medium),
                               rtol=1e-12)
    # Against quadrature of the profile over the disc.
    x, w = np.polynomial.legendre.leggauss(200)
    rho0 = 0.7
    r = jnp.asarray(0.5 * rho0 * (x + 1))[:, None]
    quad = jnp.sum(jnp.asarray(0.5 * rho0 * w)[:, None] * 2 * jnp.pi * r * jaxsss.dipole_profile(r, medium), axis=0)
    np.testing.assert_allclose(rad.disc_integral(rho0, medium), quad, rtol=1e-10)
    assert float(rad.disc_integral(0.0, medium)[0]) == 0.0


def test_weighted_disc_integral_against_quadrature():
    medium = jaxsss.Medium(jnp.array([0.001, 0.05, 1.0]), jnp.array([1.0, 2.0, 0.5]), 1.4)
    x, w = np.polynomial.legendre.leggauss(400)
    for rho0 in (0.05, 0.7, 5.0):
        r = jnp.asarray(0.5 * rho0 * (x + 1))[:, None]
        t = r / rho0
        weight = 1 - 3 * t**2 + 2 * t**3
        quad = jnp.sum(jnp.asarray(0.5 * rho0 * w)[:, None] * weight * 2 * jnp.pi * r * jaxsss.dipole_profile(r, medium),
                       axis=0)
        np.testing.assert_allclose(rad.weighted_disc_integral(rho0, medium), quad, rtol=1e-9)
    assert float(rad.weighted_disc_integral(0.0, medium)[0]) == 0.0


def test_entity_flux_range_sums():
    rng = np.random.default_rng(0)
    flux = jnp.asarray(rng.random((10, 3)))
    start = jnp.array(list(range(10)) + [0, 3, 0])
    stop = jnp.array(list(range(1, 11)) + [3, 10, 10])
    got = rad.entity_flux(flux, start, stop)
    np.testing.assert_allclose(got[:10], flux)
    np.testing.assert_allclose(got[10:], np.stack([flux[:3].sum(0), flux[3:].sum(0), flux.sum(0)]), rtol=1e-12)


def _random_problem(n_q=7, n_s=40, seed=1):
    rng = np.random.default_rng(seed)
    q = jnp.asarray(rng.normal(size=(n_q, 3)))
    s = jnp.asarray(rng.normal(size=(n_s, 3)))
    flux = jnp.asarray(rng.random((n_s, 3)))
    # Every (query, sample) pair, in blocks of 16 with padding pairs pointing at query n_q.
    pq = np.repeat(np.arange(n_q), n_s)
    pe = np.tile(np.arange(n_s), n_q)
    pad = (-len(pq)) % 16
    pq = jnp.asarray(np.concatenate([pq, np.full(pad, n_q)]).reshape(-1, 16).astype(np.int32))
    pe = jnp.asarray(np.concatenate([pe, np.zeros(pad, int)]).reshape(-1, 16).astype(np.int32))
    return q, s, flux, pq, pe


def test_pairs_equal_direct_sum_and_shared_channel():
    q, s, flux, pq, pe = _random_problem()
    medium = jaxsss.Medium(jnp.array([0.01, 0.05, 0.2]), jnp.array([1.0, 2.0, 3.0]), 1.3)
    a = rad.exitance_pairs(medium, q, s, flux, pq, pe)
    b = rad.exitance_direct(medium, q, s, flux, jnp.ones(40), 0.0, block=4)
    assert a.shape == b.shape == (7, 3)
    np.testing.assert_allclose(a, b, rtol=1e-12)  # every pair far (no near field): the pair sum is the direct sum
    # With a near field: pairs inside rho0 are split by w(r) between the spread (weighted-mean irradiance times I_w)
    # and the point sum.
    rho0 = 1.0
    c = rad.exitance_direct(medium, q, s, flux, jnp.full(40, 0.5), rho0, block=4)
    r = np.linalg.norm(np.asarray(q)[:, None] - np.asarray(s)[None], axis=-1)
    t = np.clip(r / rho0, 0, 1)
    w = 1 - 3 * t**2 + 2 * t**3
    prof = np.asarray(jaxsss.dipole_profile(jnp.asarray(r)[..., None], medium))
    point = np.sum((1 - w)[..., None] * prof * np.asarray(flux)[None], axis=1)
    mean_irr = (w[..., None] * np.asarray(flux)[None]).sum(1) / np.maximum(0.5 * w.sum(1), 1e-300)[:, None]
    np.testing.assert_allclose(c, point + mean_irr * np.asarray(rad.weighted_disc_integral(rho0, medium)),
                               rtol=1e-12)
    # The hierarchical near-field function agrees with the direct one when every pair is near.
    nq = jnp.asarray(np.repeat(np.arange(7), 40).astype(np.int32))
    ns = jnp.asarray(np.tile(np.arange(40), 7).astype(np.int32))
    near = rad.exitance_near(medium, q, s, jnp.full(40, 0.5), flux, nq, ns, 100.0)
    np.testing.assert_allclose(near, rad.exitance_direct(medium, q, s, flux, jnp.full(40, 0.5), 100.0, block=4),
                               rtol=1e-12)
    grey = jaxsss.Medium(jnp.full(3, 0.02), jnp.full(3, 1.5), 1.3)
    np.testing.assert_allclose(rad.exitance_pairs(grey, q, s, flux, pq, pe, shared_channel=True),
                               rad.exitance_pairs(grey, q, s, flux, pq, pe), rtol=1e-13)


def test_the_dipole_refuses_exit_weights_by_name():
    """Bad input: exit weights are the white kernels' (their nodes' exit distributions); the dipole's sums are
    exitance, so every sum that would take them says so instead of ignoring them."""
    q, s, flux, pq, pe = _random_problem()
    medium = jaxsss.Medium(jnp.array([0.01, 0.05, 0.2]), jnp.array([1.0, 2.0, 3.0]), 1.0)
    weights = jnp.ones((q.shape[0], 1, 3))
    nq = jnp.asarray(np.repeat(np.arange(7), 40).astype(np.int32))
    ns = jnp.asarray(np.tile(np.arange(40), 7).astype(np.int32))
    for call in (lambda: rad.exitance_pairs(medium, q, s, flux, pq, pe, weights=weights),
                 lambda: rad.exitance_near(medium, q, s, jnp.full(40, 0.5), flux, nq, ns, 1.0, weights=weights),
                 lambda: rad.exitance_direct(medium, q, s, flux, jnp.ones(40), 1.0, block=4, weights=weights)):
        with pytest.raises(ValueError, match="DipoleKernel: exit weights are for the white kernels"):
            call()


def test_exitance_gradient_matches_finite_differences():
    q, s, flux, pq, pe = _random_problem(n_q=3, n_s=20)

    def f(theta):
        medium = jaxsss.Medium(jnp.exp(theta[:3]), jnp.exp(theta[3:]), 1.4)
        m = rad.exitance_pairs(medium, q, s, flux, pq, pe)
        cos = jnp.full(3, 0.8)
        return jnp.sum(rad.exit_radiance(medium, m, cos) ** 2)

    theta = jnp.log(jnp.array([0.01, 0.05, 0.2, 1.1, 2.0, 3.0]))
    assert_grad_matches_fd(f, theta, rtol=1e-6, jit=True)


def test_extreme_media_stay_finite():
    q, s, flux, pq, pe = _random_problem(n_q=3, n_s=10)
    for sa, ss in [(1e-9, 1e4), (1e4, 1e-6), (0.0, 1.0)]:
        m = rad.exitance_pairs(jaxsss.Medium(sa, ss, 1.3), q, s, flux[:, :1], pq, pe)
        assert np.isfinite(np.asarray(m)).all() and (np.asarray(m) >= 0).all()
    jax.clear_caches()
