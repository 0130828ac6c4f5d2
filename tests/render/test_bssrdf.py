"""The renderer's BSSRDF kernels (jaxsss.render.bssrdf): the oblique white Monte Carlo tables against Chandrasekhar's
exact albedo, the exit distribution, the per-image profile grid, the forward shift, the normal-incidence profile from
the white Monte Carlo family, the oblique nodes of pairs without tables (leave-one-out against a table), the plan's
choice, and gradients in the material."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxsss
from jaxsss.mc.white import white_mc_profile
from jaxsss.mc.white_family import white_family_profile
from jaxsss.render import bssrdf, make_plan, parse_scene, prepare
from jaxsss.render.bssrdf import (
    OBLIQUE_MUS,
    chandrasekhar_h,
    choose_bssrdf,
    directional_albedo,
    exit_distribution,
    half_space_reflection,
    hat_weights,
    incident_flux,
    oblique_sources,
    refracted_exit_distribution,
    surface_tangents,
    white_kernel,
    white_table,
    white_tables,
)
from jaxsss.render.curvature import KAPPA_MAX_ZR, N_KAPPA, curvature_ratio
from jaxsss.render.radiance import near_weight
from tests.gradcheck import assert_grad_matches_fd
from tests.render.kernel_calls import kernel_pair, kernel_sources

MUS = (1.0,) + OBLIQUE_MUS


def _all_tables():
    """The g = 0, n = 1 kernel's sources with every oblique table (normal incidence: the family)."""
    mus, sources = white_tables(0.0, 1.0, True, mus=OBLIQUE_MUS)
    assert mus == MUS
    return sources


def _h_iterated(mu, a, n=200, iterations=3000):
    """H(mu) from its integral equation H = 1 + (a/2) mu H int_0^1 H(mu') / (mu + mu') dmu', by fixed-point iteration
    on 200 Gauss-Legendre nodes (an independent route to the same function)."""
    x, w = np.polynomial.legendre.leggauss(n)
    m, w = 0.5 * (x + 1.0), 0.5 * w
    h = np.ones(n)
    for _ in range(iterations):
        h = 1.0 / (1.0 - 0.5 * a * m * np.sum(w * h / (m[:, None] + m), axis=1))
    mu = np.asarray(mu, dtype=float)
    return 1.0 / (1.0 - 0.5 * a * mu * np.sum(w * h / (mu[:, None] + m), axis=1))


@pytest.mark.parametrize("a", [0.3, 0.9, 0.99])
def test_h_function_matches_its_integral_equation(a):
    mu = np.array([0.0, 0.05, 0.3, 0.7, 1.0])
    # 64-node explicit form vs 200-node iteration: agree to 1e-6 (measured 1e-8 at a = 0.99).
    np.testing.assert_allclose(np.asarray(chandrasekhar_h(mu, a)), _h_iterated(mu, a), rtol=1e-6)
    # Shapes: per-channel albedo broadcasts against the angles.
    h = np.asarray(chandrasekhar_h(mu[:, None], jnp.array([a, 0.5])))
    assert h.shape == (5, 2) and np.all(h >= 1.0)


def test_oblique_tables_reproduce_chandrasekhars_albedo():
    # Exact for g = 0, eta = 1: the directional albedo 1 - H(mu) sqrt(1 - a) (Chandrasekhar 1960). The plane integral
    # of each table's profile (sigma_t = 1/mm; albedos as channels) must match: measured within 0.25% (Monte Carlo
    # noise of 2e5 photons, lost weight).
    a = np.array([0.5, 0.9, 0.98])
    # (shift=True only shares the compiled kernel with the tests below: the radial profiles do not depend on it.)
    kernel = white_kernel(jaxsss.Medium(jnp.asarray(1.0 - a), jnp.asarray(a), 1.0), _all_tables(), MUS, shift=True)
    x, w = np.polynomial.legendre.leggauss(300)
    lo, hi = np.log(1e-4), np.log(400.0)
    r = np.exp(lo + 0.5 * (x + 1.0) * (hi - lo))
    w = 0.5 * w * (hi - lo)
    total = np.einsum("p,pkc->kc", w * 2.0 * np.pi * r * r, np.asarray(kernel.profile(jnp.asarray(r))))
    exact = 1.0 - np.asarray(chandrasekhar_h(jnp.asarray(MUS)[:, None], jnp.asarray(a))) * np.sqrt(1.0 - a)
    np.testing.assert_allclose(total, exact, rtol=5e-3)


@pytest.mark.parametrize("albedo", [0.4, 0.95])
def test_exit_distribution_conserves_the_exitance(albedo):
    x, w = np.polynomial.legendre.leggauss(200)
    mu_o, w = 0.5 * (x + 1.0), 0.5 * w
    X = np.asarray(exit_distribution(jnp.asarray(mu_o), jnp.asarray(MUS), jnp.array([albedo])))  # (Q, K, 1)
    # int_0^1 X 2 mu dmu = 1: the radiance integrates to the exitance.
    np.testing.assert_allclose(np.einsum("q,qkc->kc", 2.0 * w * mu_o, X), 1.0, rtol=1e-5)
    # Grazing light leaves more of it at grazing angles than normal light does (the 1 / (mu_o + mu_i) factor).
    assert X[0, -1, 0] > X[0, 0, 0]


@pytest.mark.parametrize("albedo, rtol", [(0.0, 1e-4), (0.3, 1e-4), (0.9585, 1e-4), (0.999, 1e-4),
                                         (1.0 - 1e-9, 3e-4)])  # (64-node H loses digits as a -> 1)
def test_half_space_reflection_integrates_to_the_directional_albedo(albedo, rtol):
    x, w = np.polynomial.legendre.leggauss(400)
    mu_o, w = 0.5 * (x + 1.0), 0.5 * w
    mu_i = jnp.asarray(MUS)
    f = np.asarray(half_space_reflection(mu_i[None, :], jnp.asarray(mu_o)[:, None], albedo))  # (Q, K)
    assert f.shape == (400, len(MUS)) and np.all(np.isfinite(f)) and np.all(f >= 0)
    # 2 pi int_0^1 f_r mu_o dmu_o = A(mu_i), Chandrasekhar's albedo of every order.
    np.testing.assert_allclose(np.einsum("q,qk->k", 2.0 * np.pi * w * mu_o, f),
                               directional_albedo(mu_i, albedo), rtol=rtol, atol=1e-12)
    # Reciprocity.
    np.testing.assert_allclose(half_space_reflection(0.3, 0.8, albedo), half_space_reflection(0.8, 0.3, albedo))
    # It is the exit distribution times the albedo over pi.
    if albedo > 0:
        np.testing.assert_allclose(f, np.pi ** -1 * np.asarray(directional_albedo(mu_i, albedo))[None]
                                   * np.asarray(exit_distribution(jnp.asarray(mu_o), mu_i, jnp.array([albedo])))[..., 0],
                                   rtol=rtol)


def test_half_space_reflection_gradient():
    assert_grad_matches_fd(lambda a: half_space_reflection(0.4, 0.9, a[0]) + half_space_reflection(1.0, 0.1, a[1]),
                           jnp.array([0.5, 0.999]), rtol=1e-5, jit=True)


@pytest.mark.parametrize("albedo, eta", [(0.4, 1.3), (0.95, 1.3), (0.68, 1.4), (0.999, 1.55)])
def test_refracted_exit_conserves_the_exitance(albedo, eta):
    x, w = np.polynomial.legendre.leggauss(400)
    mu_o, w = 0.5 * (x + 1.0), 0.5 * w
    Y = np.asarray(refracted_exit_distribution(jnp.asarray(mu_o), jnp.asarray(MUS), jnp.array([albedo]), eta))
    # int_0^1 Y 2 mu dmu = 1 (its own 32-node normalisation against a 400-node rule).
    np.testing.assert_allclose(np.einsum("q,qkc->kc", 2.0 * w * mu_o, Y), 1.0, rtol=1e-4)
    assert np.all(np.isfinite(Y)) and np.all(Y >= 0)


def test_refracted_exit_is_chandrasekhars_at_a_matched_boundary():
    mu_o = jnp.linspace(0.01, 1.0, 21)  # (F_t at eta = 1 is 0 exactly at grazing: the renderer uses X itself there)
    albedo = jnp.array([0.3, 0.9, 0.999])
    np.testing.assert_allclose(refracted_exit_distribution(mu_o, jnp.asarray(MUS), albedo, 1.0),
                               exit_distribution(mu_o, jnp.asarray(MUS), albedo), rtol=2e-6)


def test_refracted_exit_grazing_views_by_albedo():
    """Through a dielectric (eta 1.4) a weakly scattering channel sends more light to grazing views than a
    Lambertian exit through the same boundary (``F_t``), a strongly scattering one less."""
    from jaxsss.fresnel import fresnel_unpolarised

    mu = jnp.array([0.05, 1.0])
    Y = np.asarray(refracted_exit_distribution(mu, jnp.array([1.0]), jnp.array([0.3, 0.999]), 1.4))[:, 0]
    f_t = 1.0 - np.asarray(fresnel_unpolarised(mu, 1.4))
    lambertian = f_t[0] / f_t[1]
    assert Y[0, 0] / Y[1, 0] > 1.1 * lambertian
    assert Y[0, 1] / Y[1, 1] < 0.99 * lambertian  # 0.976: inside, the grazing view is mu_t = 0.71


def test_refracted_exit_gradients():
    mu_o = jnp.array([0.05, 0.4, 0.9])

    def f(p):
        return jnp.sum(refracted_exit_distribution(mu_o, jnp.asarray(MUS), p[:2], p[2]) ** 2)

    assert_grad_matches_fd(f, np.array([0.6, 0.97, 1.35]), rtol=1e-5, jit=True)


def test_the_tables_are_host_arrays_even_when_first_asked_for_inside_a_trace():
    """:func:`white_tables` is cached per process. Built for the first time inside ``jax.jit``, its arrays must still
    be concrete: a cache holding the trace's values fails every later call (UnexpectedTracerError). (The family under
    it, ``load_white_family``, is built the same way, under ``jax.ensure_compile_time_eval``; rebuilding it here would
    cost 10 s.)"""
    bssrdf._white_tables.cache_clear()
    r = jnp.array([0.5, 2.0])

    def profile(sigma_a):
        mus, sources = white_tables(0.0, 1.0, True)
        return white_kernel(jaxsss.Medium(sigma_a, jnp.array([0.74]), 1.0), sources, mus).profile(r)

    try:
        inside = jax.jit(profile)(jnp.array([0.032]))
        np.testing.assert_allclose(profile(jnp.array([0.032])), inside, rtol=1e-12)
        leaves = jax.tree_util.tree_leaves(white_tables(0.0, 1.0, True))
        assert leaves and not any(isinstance(x, jax.core.Tracer) for x in leaves)
    finally:
        bssrdf._white_tables.cache_clear()


def test_hat_weights_interpolate_linearly():
    mu = jnp.array([1.0, 0.9, 0.75, 0.3, 0.1, 0.05, 0.0])
    h = np.asarray(hat_weights(mu, MUS))
    np.testing.assert_allclose(h.sum(axis=1), 1.0, rtol=1e-14)
    # A linear function of mu is reproduced inside the nodes' range and held below the last node.
    np.testing.assert_allclose(h @ np.asarray(MUS), [1.0, 0.9, 0.75, 0.3, 0.1, 0.1, 0.1], rtol=1e-14)
    np.testing.assert_allclose(h[2], np.eye(5)[1], atol=1e-15)
    # The host's NumPy form (the renderer's geometry) is the same function.
    np.testing.assert_array_equal(hat_weights(np.asarray(mu), MUS, xp=np), h)


def _skin(n_channels=3):
    return jaxsss.Medium(jnp.array([0.032, 0.17, 0.48])[:n_channels], jnp.array([0.74, 0.88, 1.01])[:n_channels], 1.0)


@pytest.fixture(scope="module")
def skin_kernel():
    return white_kernel(_skin(), _all_tables(), MUS, shift=True)


def test_each_nodes_curvature_source_sits_at_its_refracted_cosine(skin_kernel):
    # The curvature table carries sigma_t' and the depth mu_t of each node in units of l_u: mu itself at eta = 1 ...
    kernel = white_kernel(_skin(), _all_tables(), MUS, shift=True, curvature=True)
    coefficients, st, depth, kappa_max = (np.asarray(x) for x in kernel.curvature)
    assert float(kappa_max) == KAPPA_MAX_ZR  # unmarched: diffusion's cap
    assert coefficients.shape == (5 * 260 * (N_KAPPA - 1) * 3, 4)
    np.testing.assert_allclose(st, _skin().sigma_a + _skin().sigma_s_prime, rtol=1e-15)
    np.testing.assert_allclose(depth, np.broadcast_to(np.asarray(MUS)[:, None], (5, 3)), rtol=1e-14)
    # ... and Snell's refracted cosine at eta = 1.33 (steeper inside: grazing light is never shallower than 0.66).
    medium = jaxsss.Medium(jnp.array([0.032, 0.17, 0.48]), jnp.array([0.74, 0.88, 1.01]), 1.33)
    mus, sources = white_tables(0.0, 1.33, True)
    depth = np.asarray(white_kernel(medium, sources, mus, curvature=True).curvature[2])
    mu = np.asarray(mus)[:, None]
    np.testing.assert_allclose(depth, np.broadcast_to(np.sqrt(1 - (1 - mu**2) / 1.33**2), (3, 3)), rtol=1e-14)
    assert depth.min() > 0.66


@pytest.fixture(scope="module")
def curved_kernel():
    return white_kernel(_skin(), _all_tables(), MUS, shift=True, curvature=True)


def test_the_curved_profile_is_the_profile_times_the_curvature_ratio(curved_kernel):
    """The bilinear table of log(R C) against the half-space profile times :func:`curvature_ratio` per node: within
    1.5% for chords under 97 degrees of arc (``kappa d < 1.5``), 9% beyond (docs/path_tracer.md, "The curvature
    ratio, tabulated"), and exactly the flat profile at ``kappa <= 0``. Beyond is one distance interval: the cap's
    kink at ``d = 2 / (KAPPA_MAX_ZR sigma_t')`` falls inside it. With the cap at 0.15 (2026-11-28) that is 17.4 mm in
    skin1's red, ``kappa d`` about 2, and the largest error there is 8.4% (under 8% at the old cap of 0.25)."""
    kernel, medium = curved_kernel, _skin()
    rng = np.random.default_rng(3)
    d = np.exp(rng.uniform(np.log(0.01), np.log(25.0), 4000))
    kappa = rng.uniform(0.0, 0.2, 4000)
    r = jnp.broadcast_to(jnp.asarray(d)[:, None, None], (4000, 5, 3))
    curved = np.asarray(kernel.profile(r, jnp.asarray(kappa)[:, None, None]))
    depth = np.asarray(kernel.curvature[2])
    ratio = np.asarray(curvature_ratio(d[:, None, None], kappa[:, None, None], medium.sigma_a, medium.sigma_s_prime,
                                       medium.A, depth))
    err = np.abs(curved / (np.asarray(kernel.profile(r)) * ratio) - 1.0)
    arc = (kappa * d < 1.5)[:, None, None]
    assert np.max(np.where(arc, err, 0.0)) < 0.015, np.max(np.where(arc, err, 0.0))
    assert np.max(err) < 0.09, np.max(err)
    for flat in (0.0, -0.3):
        np.testing.assert_array_equal(kernel.profile(r, jnp.full((4000, 1, 1), flat)), kernel.profile(r))


def test_the_curved_profiles_gradient_in_the_medium():
    """The curvature table is differentiable in the medium (through both the profile and the ratio)."""
    d = jnp.array([0.3, 2.0, 7.0])[:, None, None]
    r = jnp.broadcast_to(d, (3, 5, 3))
    kappa = jnp.array([0.05, 0.1, 0.15])[:, None, None]

    def f(p):
        medium = jaxsss.Medium(p[:3], jnp.array([0.74, 0.88, 1.01]) * p[3], 1.0)
        return jnp.sum(jnp.log(white_kernel(medium, _all_tables(), MUS, curvature=True).profile(r, kappa)))

    assert_grad_matches_fd(f, np.array([0.032, 0.17, 0.48, 1.0]), rtol=1e-5)


def test_grid_matches_the_table_model_and_its_disc_integral(skin_kernel):
    medium, kernel = _skin(), skin_kernel
    r = jnp.asarray(np.geomspace(1e-3, 40.0, 97))
    direct = np.asarray(white_mc_profile(r[:, None], medium.sigma_a, medium.sigma_s_prime, white_table(0.0, 1.0, 0.5)))
    grid = np.asarray(kernel.profile(r))[:, 2]
    # Linear interpolation of log R at 40 nodes per decade vs the table's Hermite spline at 20 per decade: within 2%
    # out to 10 mm (~4 l_d; measured 1.3% at 0.03 mm, where the spline bends between its nodes, <= 0.8% beyond), and
    # the energy density 2 pi r R within 1.5% of its peak everywhere (measured 0.94%; the noisy far tail of a
    # 2e5-photon table, where R is ~1e-16 of its peak, differs more in relative terms).
    near = np.asarray(r) <= 10.0
    np.testing.assert_allclose(grid[near], direct[near], rtol=2e-2)
    density = np.asarray(r)[:, None] * np.abs(grid - direct)
    assert np.all(density / (np.asarray(r)[:, None] * direct).max(axis=0) < 1.5e-2)
    # The near-field disc integral (128-node Gauss-Legendre in r = rho0 t^2) against a fine trapezoid rule in r
    # (measured 2.8e-4; 48 nodes were 0.7% off: the interpolant has a kink at every grid node).
    rho0 = 2.5
    rr = np.linspace(0.0, rho0, 20001)[1:]
    f = (np.asarray(near_weight(jnp.asarray(rr), rho0)) * 2.0 * np.pi * rr)[:, None, None] * np.asarray(
        kernel.profile(jnp.asarray(rr)))
    np.testing.assert_allclose(np.asarray(kernel.weighted_disc(rho0)), np.trapezoid(f, rr, axis=0), rtol=5e-4)


def test_shifted_pair_is_the_profile_about_the_shifted_entry(skin_kernel):
    kernel = skin_kernel
    # One sample lit by one light at 60 degrees travelling towards +x along a surface with normal +z.
    to_light = np.array([[[-np.sqrt(0.75), 0.0, 0.5]]])
    tangent = surface_tangents(to_light, np.array([[0.0, 0.0, 1.0]]), 1.0)
    np.testing.assert_allclose(tangent, [[[np.sqrt(0.75), 0.0, 0.0]]], atol=1e-15)
    E = jnp.array([[[1.0, 2.0, 3.0]]])
    flux = incident_flux(MUS, jnp.array([0.5]), jnp.array([[0.5]]), E, tangent=jnp.asarray(tangent))
    assert flux.shape == (1, 4, 5, 3)
    # Node mu = 0.5 takes all of it, incident (no Fresnel factor): A E.
    np.testing.assert_allclose(np.asarray(flux[0, 0]), np.outer(np.eye(5)[2], [0.5, 1.0, 1.5]), atol=1e-15)
    delta = jnp.array([[2.0, 1.0, 0.0]])
    got = np.asarray(kernel_pair(kernel, delta, kernel_sources(kernel, flux)))[0, 2]
    shift = np.asarray(kernel.shift_length)[2] * np.sqrt(0.75)  # (C,) mm along +x
    r = np.sqrt((2.0 - shift) ** 2 + 1.0)
    want = [np.asarray(kernel.profile(jnp.array([rc])))[0, 2, c] * [0.5, 1.0, 1.5][c] for c, rc in enumerate(r)]
    np.testing.assert_allclose(got, want, rtol=1e-12)
    # The shift is Monte Carlo's: ~0.8 sin(theta_t) / sigma_t' for skin1's red at 60 degrees (0.853 measured).
    np.testing.assert_allclose(shift[0] / (np.sqrt(0.75) / 0.772), 0.85, atol=0.02)
    # A short chord's travel weight scales the travel, not the flux: the shift shrinks by the same factor.
    weight = jnp.array([[[0.25, 0.5, 1.0]]])
    short = incident_flux(MUS, jnp.array([0.5]), jnp.array([[0.5]]), E, tangent=jnp.asarray(tangent),
                          tangent_weight=weight)
    np.testing.assert_array_equal(np.asarray(short[:, 0]), np.asarray(flux[:, 0]))
    np.testing.assert_allclose(np.asarray(short[:, 1:]), np.asarray(flux[:, 1:]) * np.asarray(weight)[0, 0],
                               rtol=1e-15)
    np.testing.assert_allclose(np.asarray(kernel_sources(kernel, short))[0, 1, 2], shift * [0.25, 0.5, 1.0], rtol=1e-12)


def _scene_dict(material):
    return {
        "mesh": {"builtin": "sphere", "radius": 5.0, "subdivisions": 3},
        "material": material,
        "light": [{"type": "point", "position": [-20.0, -10.0, 10.0], "intensity": 300.0}],
        "camera": {"position": [0.0, -30.0, 0.0], "look_at": [0.0, 0.0, 0.0], "fov_deg": 25.0, "resolution": [8, 8]},
        "render": {"density": 0.3},
    }


def _scene(material):
    return parse_scene(_scene_dict(material), path="<test>")


def test_the_plan_chooses_the_kernel_and_counts_single_scattering_once():
    skin = {"sigma_a": [0.032, 0.17, 0.48], "sigma_s_prime": [0.74, 0.88, 1.01], "eta": 1.0}
    plan = make_plan(_scene(skin), bssrdf="auto")
    assert plan.bssrdf == "white-oblique" and not plan.single_scattering
    items = {i.name: i for i in plan.items}
    assert "counted once" in items["single scattering"].reason and "Chandrasekhar" in items["bssrdf: white-oblique"].reason
    assert "this pair's oblique tables" in items["bssrdf: white-oblique"].reason
    # Methods that do not ask keep the dipole and their single scattering.
    assert make_plan(_scene(skin)).bssrdf == "dipole" and make_plan(_scene(skin)).single_scattering
    forced = make_plan(_scene({**skin, "eta": 1.0}), bssrdf="white")
    assert forced.bssrdf == "white"


def test_the_white_kernels_sample_densest_under_a_light_with_a_sharp_terminator():
    """Base density WHITE_DENSITY_KINKED (3) under a point, spot or directional light, WHITE_DENSITY (2) under an
    environment or area light alone, the paper's 1 for the dipole; the plan line says which and why, and the scene's
    density multiplies the base."""
    from jaxsss.render.bssrdf import KINKED_LIGHTS, WHITE_DENSITY, WHITE_DENSITY_KINKED

    assert (WHITE_DENSITY, WHITE_DENSITY_KINKED) == (2.0, 3.0)
    assert set(KINKED_LIGHTS) == {"point", "spot", "directional"}
    skin = {"sigma_a": [0.032, 0.17, 0.48], "sigma_s_prime": [0.74, 0.88, 1.01], "eta": 1.0}
    sphere_light = [{"type": "sphere", "position": [-20.0, -10.0, 10.0], "radius": 2.0, "radiance": 30.0}]
    lights = {"point": _scene_dict(skin)["light"], "sphere": sphere_light,
              "both": _scene_dict(skin)["light"] + sphere_light}

    def samples(light, bssrdf="auto", density=0.3):
        scene = parse_scene({**_scene_dict(skin), "light": lights[light], "render": {"density": density}},
                            path="<test>")
        item = {i.name: i for i in make_plan(scene, bssrdf=bssrdf).items}["irradiance samples"]
        return int(item.reason.split()[0]), item.reason

    (n_point, why_point), (n_sphere, why_sphere) = samples("point"), samples("sphere")
    assert "3; a point light's sharp terminator" in why_point and "2; no light with a sharp terminator" in why_sphere
    assert n_point / n_sphere == pytest.approx(1.5, rel=0.01)
    assert samples("both")[0] == n_point  # any light with a kink decides
    n_dipole, why_dipole = samples("point", bssrdf="dipole")
    assert n_point / n_dipole == pytest.approx(3.0, rel=0.01) and "kernel's" not in why_dipole
    assert samples("point", density=0.6)[0] / n_point == pytest.approx(2.0, rel=0.01)


@pytest.mark.parametrize("g, eta, kernel, needle", [
    # skin1 at its table index: no oblique tables, so the ratio of the nearest tabulated pair, and no advice to make
    # tables (the family covers the pair).
    (0.0, 1.3, "white-oblique", "ratio of (g=0, n=1.33) x 1.00"),
    (0.3, 1.0, "white-oblique", "(g=0, n=1) x 0.67 and (g=0.9, n=1) x 0.33"),
    # Forward scattering behind a dielectric boundary: the white kernels too, with the isotropic refracted exit (until
    # 2026-12-02 the dipole, 13-30% too bright in blue against Mitsuba; docs/path_tracer.md).
    (0.5, 1.45, "white-oblique", "isotropic scattering's: the forward-scattering exit is tabulated for"),
    (0.9, 1.4, "white-oblique", "(g=0, n=1.4) x 1.00 (no oblique tables for this pair; the transfer is UNMEASURED"),
    # Index-matched forward scattering: the white kernels, exit by jaxsss.render.exit_direction.
    (0.9, 1.0, "white-oblique", "forward-scattering exit distribution by the light's azimuth"),
    (0.0, 2.0, "dipole", "eta=2 is outside the white Monte Carlo family's range (g in [0, 0.95], eta in [1, 1.6])"),
    (0.97, 1.3, "dipole", "g=0.97, eta=1.3 is outside the white Monte Carlo family's range"),
])
def test_auto_takes_the_family_wherever_it_covers_the_medium(g, eta, kernel, needle):
    skin = {"sigma_a": [0.032, 0.17, 0.48], "sigma_s_prime": [0.74, 0.88, 1.01], "eta": eta, "g": g}
    plan = make_plan(_scene(skin), bssrdf="auto")
    item = next(i for i in plan.items if i.name.startswith("bssrdf"))
    assert plan.bssrdf == kernel and item.name == f"bssrdf: {kernel}"
    assert needle in item.reason and "make_white_tables" not in item.reason
    assert plan.single_scattering == (kernel == "dipole")


def test_the_plan_picks_eps_by_kernel_unless_the_scene_or_caller_sets_it():
    """No ``[render].eps``: the white kernels' EPS_WHITE (their error against transport dwarfs the sum's), the dipole's
    EPS_DEFAULT; the scene's value and the caller's override it."""
    from jaxsss.render.plan import EPS_DEFAULT, EPS_WHITE

    skin = {"sigma_a": [0.032, 0.17, 0.48], "sigma_s_prime": [0.74, 0.88, 1.01], "eta": 1.0}
    scene = _scene(skin)
    assert scene.render.eps is None
    white, dipole = make_plan(scene, bssrdf="auto"), make_plan(scene, bssrdf="dipole")
    assert white.eps == EPS_WHITE == 0.1 and dipole.eps == EPS_DEFAULT == 0.05
    assert "eps = 0.1 sr (Eq. 12) (the white-oblique kernel's" in white.items[0].reason
    assert make_plan(scene, bssrdf="auto", eps=0.02).eps == 0.02
    fixed = parse_scene({**{k: v for k, v in _scene_dict(skin).items() if k != "render"}, "render": {"eps": 0.3}},
                        path="<test>")
    assert make_plan(fixed, bssrdf="auto").eps == 0.3 and make_plan(fixed).eps == 0.3


def test_bad_kernel_requests_name_the_argument_and_range():
    medium = _scene({"sigma_a": 0.1, "sigma_s_prime": 1.0, "eta": 2.0}).material.medium
    for request in ("white", "white-oblique"):
        with pytest.raises(ValueError, match=rf"bssrdf='{request}': eta=2 is outside the white Monte Carlo family's "
                                             r"range \[1, 1.6\]"):
            choose_bssrdf(medium, request)
    assert white_tables(0.0, 2.0, True) is None and white_tables(-0.1, 1.3, False) is None
    with pytest.raises(ValueError, match=r"bssrdf='multipole' is not one of auto, dipole, white, white-oblique"):
        choose_bssrdf(medium, "multipole")
    per_channel = jaxsss.Medium(jnp.array([0.1, 0.2]), jnp.array([1.0, 1.0]), jnp.array([1.3, 1.4]))
    with pytest.raises(ValueError, match="bssrdf='white' needs scalar eta and g"):
        choose_bssrdf(per_channel, "white")
    assert choose_bssrdf(per_channel)[0] == "dipole"


def test_oblique_sources_weights():
    assert oblique_sources(0.0, 1.33) == ((0.0, 1.33, 1.0),)
    np.testing.assert_allclose([w for *_, w in oblique_sources(0.0, 1.365)], [0.5, 0.5], rtol=1e-12)
    assert [p[:2] for p in oblique_sources(0.2, 1.365)] == [(0.0, 1.33), (0.0, 1.4)]
    assert oblique_sources(0.0, 1.55) == ((0.0, 1.4, 1.0),) and oblique_sources(0.0, 1.1) == ((0.0, 1.33, 1.0),)
    np.testing.assert_allclose([w for *_, w in oblique_sources(0.3, 1.0)], [2.0 / 3.0, 1.0 / 3.0], rtol=1e-12)
    # A request far (in g) from every source is allowed, and the reason says the transfer is unmeasured there.
    def why(g, eta):
        return choose_bssrdf(jaxsss.Medium(0.1, 1.0, eta, g=g), "white-oblique")[1]

    assert "UNMEASURED" in why(0.9, 1.4) and "UNMEASURED" not in why(0.45, 1.45) + why(0.6, 1.0)


def _grid_r(kernel, nodes):
    """Radii (mm) of grid nodes ``nodes`` of a kernel (where its interpolation is exact)."""
    return jnp.asarray(bssrdf.GRID_RHO_MIN * 10.0 ** (np.asarray(nodes) / bssrdf.GRID_PER_DECADE))[:, None] / kernel.sigma_s


def test_normal_node_is_the_family_and_a_tabulated_pair_keeps_its_oblique_tables():
    # skin1 at n = 1.33, where both the family and oblique tables exist.
    medium = jaxsss.Medium(jnp.array([0.032, 0.17, 0.48]), jnp.array([0.74, 0.88, 1.01]), 1.33)
    mus, sources = white_tables(0.0, 1.33, True)
    kernel = white_kernel(medium, sources, mus)
    assert mus == (1.0,) + bssrdf.KERNEL_MUS and kernel.log_R.shape[0] == 3
    r = _grid_r(kernel, np.arange(0, 201, 8))  # (P, C): 1e-3 to 1e2 optical units of each channel
    prof = np.asarray(kernel.profile(jnp.broadcast_to(r[:, None, :], (r.shape[0], 3, 3))))  # (P, K, C)
    fam = np.asarray(white_family_profile(r, medium.sigma_a, medium.sigma_s_prime, 0.0, 1.33))
    # At the grid nodes the kernel is the family's profile to rounding (the node is exact in log R).
    np.testing.assert_allclose(prof[:, 0], fam, rtol=1e-12)
    # Reference: the independent 1e6-photon white table at n = 1.33 (not a node of the family, which interpolates
    # between n = 1.3 and 1.4), per incident photon at normal incidence. Plane integrals (log-r Gauss-Legendre,
    # 1e-3 to 200 mm) measured within 0.1-0.3%; point values differ by up to 3.4% (the family's ~2% accuracy and
    # the table's noise), so the test takes the integral.
    x, w = np.polynomial.legendre.leggauss(200)
    lo, hi = np.log(1e-3), np.log(200.0)
    rq = np.exp(lo + 0.5 * (x + 1.0) * (hi - lo))
    wq = 0.5 * w * (hi - lo) * 2.0 * np.pi * rq * rq
    table = white_mc_profile(jnp.asarray(rq)[:, None], medium.sigma_a, medium.sigma_s_prime, white_table(0.0, 1.33))
    np.testing.assert_allclose(wq @ np.asarray(kernel.profile(jnp.asarray(rq)))[:, 0], wq @ np.asarray(table),
                               rtol=5e-3)
    # The oblique nodes are the (independently simulated) oblique tables there (ratio x family = table).
    for k, mu in enumerate(mus[1:]):
        table = np.asarray(white_mc_profile(r, medium.sigma_a, medium.sigma_s_prime, white_table(0.0, 1.33, mu)))
        np.testing.assert_allclose(prof[:, k + 1], table, rtol=1e-10)


def test_white_oblique_image_gradient_matches_finite_differences(monkeypatch):
    # One oblique node instead of the default two: the same code (hat weights, shift, exit per node), less to compile.
    monkeypatch.setattr(bssrdf, "KERNEL_MUS", (0.5,))
    scene = _scene({"sigma_a": [0.05, 0.1, 0.2], "sigma_s_prime": [1.1, 1.5, 2.0], "eta": 1.0})
    prepared, plan, _ = prepare(scene, method="direct", share_channels=False)
    assert plan.bssrdf == "white-oblique" and prepared.light_tangent is not None

    def loss(theta):
        medium = jaxsss.Medium(jnp.exp(theta[:3]), jnp.exp(theta[3:]), 1.0)
        return jnp.sum(prepared.image(medium) ** 2)

    theta = jnp.log(jnp.array([0.05, 0.1, 0.2, 1.1, 1.5, 2.0]))
    # Forward mode (what fit_image differentiates with) along two directions against central differences. The profile
    # is piecewise linear in log r: a 1e-6 step stays on one piece for nearly every pair; measured agreement 1e-8.
    for v in (jnp.array([1.0, -0.5, 0.3, 0.7, -1.0, 0.4]), jnp.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])):
        jvp = float(jax.jvp(loss, (theta,), (v,))[1])
        h = 1e-6
        fd = (float(loss(theta + h * v)) - float(loss(theta - h * v))) / (2.0 * h)
        np.testing.assert_allclose(jvp, fd, rtol=1e-5)



@pytest.mark.parametrize(("method", "first_order"), [("direct", False), ("direct", True)])
def test_the_sums_radiance_is_the_node_exitances_exit(method, first_order):
    """Invariant: the image's diffusion radiance, summed pair by pair through the shaded points' exit weights
    (:meth:`Prepared.diffusion_radiance`), is the node exitances (:meth:`Prepared.exitance`) leaving by
    :func:`exit_radiance_nodes`: with the exit by distance (eta 1, g 0: ``2K`` node rows), and with the first order
    marched apart (the orders >= 2 by their own exit on a curved surface: ``2K`` rows too). The direct sum only: the
    hierarchical one shares ``near_terms`` and ``pair`` and took 19 s here op by op (its images are checked against
    the direct sum in tests/render/test_renderer.py and against Mitsuba)."""
    from jaxsss.render.plan import make_plan

    scene = _scene({"sigma_a": [0.05, 0.1, 0.2], "sigma_s_prime": [1.1, 1.5, 2.0], "eta": 1.0})
    plan = make_plan(scene, method=method, share_channels=False, bssrdf="auto")
    assert plan.first_order
    prepared, plan, _ = prepare(scene, plan=plan._replace(first_order=first_order))
    assert plan.bssrdf == "white-oblique"
    assert prepared.bssrdf_exit == ("multiple-curved" if first_order else "distance")
    medium = scene.material.medium
    exitance = prepared.exitance(medium)
    rows = len(prepared.bssrdf_mus) * 2
    assert exitance.shape == (prepared.n_queries, rows, 3)
    nodes = bssrdf.exit_radiance_nodes(medium, exitance, prepared.cos_o, *prepared.exit_nodes)
    np.testing.assert_allclose(np.asarray(prepared.diffusion_radiance(medium)), np.asarray(nodes), rtol=1e-10,
                               atol=1e-14 * float(np.max(np.abs(nodes))))


def test_shift_reach_bounds_the_kernels_shift():
    """The reach is ``max SHIFT_RATIO(alpha') / (sigma_t' eta)`` over the channels and nodes (ketchup's red: albedo
    0.747, sigma_t' 0.241 per mm, about 3.75 mm at eta 1), smaller at a larger eta, and 0 for unshifted kernels."""
    medium = jaxsss.Medium([0.061, 0.97, 1.45], [0.18, 0.07, 0.03])
    reach = bssrdf.shift_reach(medium, "white-oblique")
    ratio = np.interp(0.18 / 0.241, bssrdf.SHIFT_ALBEDO, np.asarray(bssrdf.SHIFT_RATIO)[:, OBLIQUE_MUS.index(0.1)])
    np.testing.assert_allclose(reach, ratio / 0.241, rtol=1e-12)
    assert 3.6 < reach < 3.9
    at_14 = bssrdf.shift_reach(jaxsss.Medium([0.061, 0.97, 1.45], [0.18, 0.07, 0.03], eta=1.4), "white-oblique")
    np.testing.assert_allclose(at_14, reach / 1.4, rtol=1e-12)
    assert bssrdf.shift_reach(medium, "white") == 0.0 and bssrdf.shift_reach(medium, "dipole") == 0.0


def test_hierarchical_sum_matches_the_direct_sum_when_the_shift_exceeds_the_near_radius():
    """Ketchup's red shifts its profiles by up to 3.75 mm, more than the near-field radius (1.6 mm here). The near
    list reaches ``rho0 + shift_reach`` so that no sample is summed as a point at its shifted profile's peak: the
    hierarchical image is then within 1% of the direct sum in summed radiance (before: 4% brighter on the 20 mm
    ketchup sphere against Mitsuba's reference, docs/path_tracer.md)."""
    from jaxsss.render import render

    scene = _scene({"sigma_a": [0.061, 0.97, 1.45], "sigma_s_prime": [0.18, 0.07, 0.03], "eta": 1.0})
    scene = dataclasses.replace(scene, render=dataclasses.replace(scene.render, density=3.0))  # rho0 1.6 mm
    hier = render(scene, method="hierarchical", eps=0.05)
    assert hier.report["plan"]["bssrdf"] == "white-oblique"
    assert hier.report["near_radius_mm"] < bssrdf.shift_reach(scene.material.medium, "white-oblique")
    direct = render(scene, method="direct").image
    lit = direct.sum(axis=-1) > 0
    np.testing.assert_allclose(hier.image[lit].sum(axis=0) / direct[lit].sum(axis=0), 1.0, atol=0.01)


def test_the_compiled_image_carries_neither_host_callbacks_nor_the_tables():
    """The white kernels' tables and family blocks are arguments of the compiled image, and the profiles' traced
    argument checks are left out (the medium was checked when it was built). A host callback keeps a program out of
    JAX's persistent compilation cache, so every process compiled the image again (4-7 s on the skin1 sphere); the
    whole family baked in as constants made its HLO 49 MB of text (now 0.4 MB)."""
    from jaxsss.render.methods import image_of

    medium = _skin()
    scene = _scene({"sigma_a": [0.032, 0.17, 0.48], "sigma_s_prime": [0.74, 0.88, 1.01], "eta": 1.0})
    prepared, plan, _ = prepare(scene, method="direct")
    assert plan.bssrdf == "white-oblique"
    text = image_of.lower(prepared, medium).as_text()
    assert "callback" not in text
    assert len(text) < 2_000_000, len(text)


@pytest.mark.parametrize("a", [1.0, 0.999, 0.96, 0.68, 0.1, 0.0])
def test_albedo_correction_makes_the_node_mix_reflect_chandrasekhars_total(a):
    """The hat-weighted nodes reflect ``sum_k h_k(mu) A(mu_k)``; ``A(mu) = 1 - H(mu) sqrt(1 - a)`` is convex in ``mu``,
    so that mix is too bright between the nodes and too dark below the last one. Times the correction it is ``A(mu)``
    at every cosine (grid interpolation: 2e-4), 1 at the nodes; the same for diffuse light. Differentiable in ``a``."""
    from jaxsss.render.bssrdf import albedo_correction, directional_albedo, hat_weights

    # Jitted (the incidence nodes static): op by op, the first albedo compiled every primitive (13 s).
    albedo_correction = jax.jit(albedo_correction, static_argnums=1)
    directional_albedo = jax.jit(directional_albedo)

    mus = (1.0,) + bssrdf.KERNEL_MUS
    albedo = jnp.array([a])
    mu = jnp.linspace(0.0, 1.0, 397)  # off the correction's grid
    nodes = directional_albedo(jnp.asarray(mus)[:, None], albedo)
    mix = hat_weights(mu, mus) @ nodes
    corrected = mix * albedo_correction(mu, mus, albedo)
    np.testing.assert_allclose(corrected, directional_albedo(mu[:, None], albedo), rtol=2e-4)
    np.testing.assert_allclose(albedo_correction(jnp.asarray(mus), mus, albedo), 1.0, rtol=1e-12)
    if 0.0 < a < 0.99:  # the mix is measurably off between the nodes (skin-like albedos: 0.5-4%)
        c = np.asarray(albedo_correction(jnp.array([0.3, 0.75, 0.05]), mus, albedo))[:, 0]
        assert c[0] < 0.999 and c[1] < 0.999 and c[2] > 1.001, c
    t, w = np.polynomial.legendre.leggauss(200)
    t = 0.5 * (t + 1.0)
    exact = np.sum(w * t * np.asarray(directional_albedo(jnp.asarray(t)[:, None], albedo))[:, 0])
    diffuse_mix = float(bssrdf._diffuse_weights(mus) @ nodes[:, 0])
    np.testing.assert_allclose(diffuse_mix * float(albedo_correction(None, mus, albedo)[0]), exact, rtol=1e-9)
    f = lambda x: jnp.sum(albedo_correction(jnp.array([0.3, 0.75, 0.05]), mus, x))  # noqa: E731
    grad = float(jax.grad(f)(albedo)[0])
    if a in (0.0, 1.0):  # nothing reflected / nothing absorbed: the correction is 1, its derivative finite (0 at 1)
        np.testing.assert_allclose(np.asarray(albedo_correction(mu, mus, albedo)), 1.0, rtol=1e-12)
        assert np.isfinite(grad) and (a == 0.0 or grad == 0.0), grad
        return
    h = 1e-6 * min(a, 1 - a)
    fd = (float(f(jnp.array([a + h]))) - float(f(jnp.array([a - h])))) / (2 * h)
    np.testing.assert_allclose(grad, fd, rtol=1e-5)


def test_shift_ratio_table_is_the_measured_table_at_its_nodes_and_linear_between():
    """The forward shift by g: each measured table at its node (g = 0: SHIFT_RATIO), the midpoint between two nodes
    their mean, and held outside [0, 0.95]; forward scattering shifts grazing light less than isotropic scattering
    (physical invariant of the measurement: cos 0.1 column, every albedo)."""
    assert np.array_equal(bssrdf.shift_ratio_table(0.0), np.asarray(bssrdf.SHIFT_RATIO))
    for g, table in bssrdf.SHIFT_RATIO_FORWARD.items():
        np.testing.assert_allclose(bssrdf.shift_ratio_table(g), np.asarray(table), rtol=1e-12)
    mid = 0.5 * (np.asarray(bssrdf.SHIFT_RATIO_FORWARD[0.7]) + np.asarray(bssrdf.SHIFT_RATIO_FORWARD[0.9]))
    np.testing.assert_allclose(bssrdf.shift_ratio_table(0.8), mid, rtol=1e-12)
    np.testing.assert_allclose(bssrdf.shift_ratio_table(0.99), np.asarray(bssrdf.SHIFT_RATIO_FORWARD[0.95]))
    np.testing.assert_allclose(bssrdf.shift_ratio_table(-0.5), np.asarray(bssrdf.SHIFT_RATIO))
    grazing = OBLIQUE_MUS.index(0.1)
    assert np.all(bssrdf.shift_ratio_table(0.9)[:, grazing] < np.asarray(bssrdf.SHIFT_RATIO)[:, grazing])


def test_a_pure_absorber_sends_no_diffuse_light_back():
    """``sigma_s' = 0`` is an allowed medium (the scene schema takes ``>= 0``). The white kernels' optical unit
    ``1 / sigma_s`` is infinite there: the profile was NaN, and so was every image of it. Now it is the limit, ~0, and
    continuous with a medium that barely scatters; at 1 / mm of absorption the profile at 1e-9 of that scattering is
    below 1e-15 / mm^2, next to 0.01-0.3 / mm^2 for skin1."""
    mus, sources = white_tables(0.0, 1.4, True)
    r = jnp.array([0.01, 0.5, 2.0, 10.0])
    zero, tiny = (np.asarray(white_kernel(jaxsss.Medium(jnp.ones(3), jnp.full(3, s), 1.4), sources, mus).profile(r))
                  for s in (0.0, 1e-9))
    for prof in (zero, tiny):
        assert np.isfinite(prof).all() and np.all(prof >= 0.0) and prof.max() < 1e-15, prof.max()
    np.testing.assert_allclose(zero, tiny, rtol=1e-6, atol=1e-30)
