"""The exit direction of forward-scattering media (jaxsss.render.exit_direction): the shipped table, its evaluation
and the light's azimuth at shaded points."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.render.bssrdf import exit_distribution
from jaxsss.render.exit_direction import (EXIT_ALBEDO, EXIT_G, EXIT_HARMONICS, EXIT_MUS, anisotropic_exit_distribution,
                                          azimuth_harmonics, load_exit_table)
from jaxsss.render.scene import Light

KERNEL_NODES = np.array([1.0, 0.5, 0.1])


def _centres(tab):
    e = tab["mu_edges"]
    return 0.5 * (e[1:] + e[:-1]), np.diff(e)


def test_table_shape_nodes_and_normalisation():
    """Every node's X_0 integrates to 1 over the exit cosines (sum X_0 2 mu dmu over the bins: the table is relative
    to the node's own total) and the normal-incidence harmonics are 0 (symmetry)."""
    tab = load_exit_table()
    x = tab["X"]
    assert x.shape == (len(EXIT_G), len(EXIT_ALBEDO), len(EXIT_MUS), len(tab["mu_edges"]) - 1, EXIT_HARMONICS)
    assert np.all(np.isfinite(x))
    c, w = _centres(tab)
    norm = np.einsum("gakuh,u->gakh", x, 2.0 * c * w)[..., 0]
    mc = np.asarray(EXIT_G) > 0
    np.testing.assert_allclose(norm[mc], 1.0, rtol=1e-9)
    # g = 0: Chandrasekhar's X sampled at bin centres (the midpoint rule on a smooth X: within 1%).
    np.testing.assert_allclose(norm[~mc], 1.0, atol=0.01)
    assert np.all(x[:, :, list(EXIT_MUS).index(1.0), :, 1:] == 0.0)
    # Monte Carlo totals are physical.
    assert np.all((tab["R_diffuse"][mc] > 0) & (tab["R_diffuse"][mc] < 1))


def test_g0_node_is_chandrasekhars_exit_and_the_model_is_continuous_in_g():
    tab = load_exit_table()
    c, _ = _centres(tab)
    albedo = jnp.array([0.5, 0.9, 0.99])
    zero = jnp.zeros((len(c), EXIT_HARMONICS - 1))
    x0 = anisotropic_exit_distribution(jnp.asarray(c), zero, KERNEL_NODES, albedo, 0.0)
    exact = exit_distribution(jnp.asarray(c), jnp.asarray(KERNEL_NODES), albedo)
    np.testing.assert_allclose(x0, exact, rtol=0.03)  # linear in albedo between nodes: within 3% of exact
    x_small = anisotropic_exit_distribution(jnp.asarray(c), zero, KERNEL_NODES, albedo, 1e-4)
    np.testing.assert_allclose(x_small, x0, rtol=1e-3)


def test_forward_scattering_shows_the_forward_peak_the_eye_sees_along_the_beam():
    """g = 0.9, alpha' 0.95, light at mu_i 0.1, seen at mu_o 0.7: along the beam (phi = 0) brighter than the
    azimuth average, against it (phi = pi) darker, and the average below the isotropic medium's (Monte Carlo,
    module docstring: 0.65 of it)."""
    mu_o = jnp.array([0.7, 0.7, 0.7])
    m = np.arange(1, EXIT_HARMONICS)
    harm = jnp.asarray(np.stack([np.cos(m * phi) for phi in (0.0, np.pi / 2, np.pi)]))
    x = np.asarray(anisotropic_exit_distribution(mu_o, harm, np.array([0.1]), jnp.array([0.95]), 0.9))[:, 0, 0]
    avg = np.asarray(anisotropic_exit_distribution(mu_o[:1], jnp.zeros((1, EXIT_HARMONICS - 1)), np.array([0.1]),
                                                   jnp.array([0.95]), 0.9))[0, 0, 0]
    iso = float(exit_distribution(jnp.array([0.7]), jnp.array([0.1]), jnp.array([0.95]))[0, 0, 0])
    assert x[0] > avg > x[2] > 0.0
    assert 0.5 * iso < avg < 0.8 * iso


def test_shapes_and_bad_incidence_node():
    q = 7
    x = anisotropic_exit_distribution(jnp.linspace(0.0, 1.0, q), jnp.zeros((q, EXIT_HARMONICS - 1)), KERNEL_NODES,
                                      jnp.array([0.3, 0.8]), 0.5)
    assert x.shape == (q, 3, 2) and bool(jnp.all(jnp.isfinite(x)))
    with pytest.raises(ValueError, match="mu_i=0.3"):
        anisotropic_exit_distribution(jnp.ones(2), jnp.zeros((2, EXIT_HARMONICS - 1)), np.array([0.3]),
                                      jnp.array([0.5]), 0.5)


@pytest.mark.parametrize("g, albedo", [(0.05, 1e-6), (0.95, 0.9999), (0.99, 0.5)])
def test_extreme_media_give_finite_values(g, albedo):
    """Beyond the table's nodes (alpha' near 0 or 1, g above 0.95) the model holds the last node: finite, positive
    azimuth averages."""
    x = anisotropic_exit_distribution(jnp.linspace(0.0, 1.0, 5), jnp.zeros((5, EXIT_HARMONICS - 1)), KERNEL_NODES,
                                      jnp.array([albedo]), g)
    assert bool(jnp.all(jnp.isfinite(x))) and bool(jnp.all(x > 0))


def test_the_exit_is_never_negative_where_nine_harmonics_ring():
    """Radiance is not negative. The table's nine harmonics ring below zero behind the forward peak at grazing
    incidence and exit (g >= 0.7; -3.6 against X_0 = 10 at g = 0.9, alpha' 0.995, mu_i 0.1, mu_o in the first bin),
    and a g = 0.95 sphere of alpha' 1/3 rendered pixels at -0.5 of the image's peak: the model floors the series at
    0 and leaves it unchanged wherever it is positive."""
    tab = load_exit_table()
    c, _ = _centres(tab)
    phi = np.linspace(0.0, np.pi, 61)
    cos_m_phi = np.cos(np.arange(1, EXIT_HARMONICS)[None, :] * phi[:, None])  # (P, H - 1)
    mu_o = np.repeat(c, len(phi))  # every exit bin at every azimuth: rows (u, p)
    harm = jnp.asarray(np.tile(cos_m_phi, (len(c), 1)))
    for g in (0.7, 0.9, 0.95):
        x = np.asarray(anisotropic_exit_distribution(jnp.asarray(mu_o), harm, np.array(EXIT_MUS),
                                                     jnp.asarray(EXIT_ALBEDO), g))
        assert x.min() == 0.0  # floored where the series rings (the unfloored minimum is below zero at these g)
        # The series itself, by hand from the table's node (g, alpha' and mu_i are nodes; mu_o the bins' centres).
        node = tab["X"][list(tab["g"]).index(g)]  # (A, K, U, H)
        series = node[..., :1] + 2.0 * np.einsum("akuh,ph->akup", node[..., 1:], cos_m_phi)
        series = np.transpose(series, (2, 3, 1, 0)).reshape(len(c) * len(phi), len(EXIT_MUS), len(EXIT_ALBEDO))
        assert series.min() < 0.0
        np.testing.assert_allclose(x, np.maximum(series, 0.0), rtol=1e-12, atol=1e-12)


def test_gradient_in_albedo_matches_finite_differences():
    mu_o = jnp.array([0.3, 0.6, 0.9])
    harm = jnp.asarray(np.cos(np.arange(1, EXIT_HARMONICS)[None, :] * np.array([[0.4], [1.5], [2.8]])))

    def f(a):
        return jnp.sum(anisotropic_exit_distribution(mu_o, harm, KERNEL_NODES, jnp.array([a]), 0.9)
                       * jnp.array([1.0, 2.0, 3.0])[:, None, None])

    a0, h = 0.93, 1e-6  # inside a node interval (0.9, 0.95): the model is linear in alpha' there
    fd = (f(a0 + h) - f(a0 - h)) / (2 * h)
    np.testing.assert_allclose(jax.grad(f)(a0), fd, rtol=1e-6)


def test_azimuth_harmonics_of_a_point_light_by_hand():
    """A point light straight above-left of a point on the plane z = 0 viewed from the right: the light travels
    towards +x along the surface, the view's projection points to +x too (phi = 0), or to -x (phi = pi), or to +y
    (phi = pi / 2)."""
    light = Light("point", np.full(3, 100.0), position=np.array([-10.0, 0.0, 10.0]))
    pts = np.zeros((3, 3))
    nrm = np.tile([0.0, 0.0, 1.0], (3, 1))
    eye = np.array([[1.0, 0.0, 1.0], [-1.0, 0.0, 1.0], [0.0, 1.0, 1.0]]) / np.sqrt(2.0)
    h = azimuth_harmonics([light], pts, nrm, eye)
    m = np.arange(1, EXIT_HARMONICS)
    np.testing.assert_allclose(h, np.cos(m[None, :] * np.array([[0.0], [np.pi], [np.pi / 2]])), atol=1e-12)
    # A point past the terminator (the light below its horizon) keeps the light's azimuth; a view along the normal
    # has none.
    h2 = azimuth_harmonics([light], pts[:2], np.tile([0.0, 0.0, -1.0], (2, 1)),
                           np.array([[1.0, 0.0, -1.0], [0.0, 0.0, -1.0]]) / np.array([[np.sqrt(2.0)], [1.0]]))
    np.testing.assert_allclose(h2[0], np.ones(EXIT_HARMONICS - 1), atol=1e-12)
    np.testing.assert_allclose(h2[1], 0.0, atol=1e-12)
    assert azimuth_harmonics([light], np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3))).shape == (0, 8)


def test_two_lights_mix_by_weight_and_extended_lights_add_no_azimuth():
    pts, nrm = np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]])
    eye = np.array([[1.0, 0.0, 1.0]]) / np.sqrt(2.0)
    a = Light("point", np.full(3, 100.0), position=np.array([-10.0, 0.0, 10.0]))  # phi = 0
    b = Light("point", np.full(3, 300.0), position=np.array([10.0, 0.0, 10.0]))  # phi = pi, three times as bright
    h = azimuth_harmonics([a, b], pts, nrm, eye)
    m = np.arange(1, EXIT_HARMONICS)
    np.testing.assert_allclose(h[0], 0.25 * 1.0 + 0.75 * np.cos(m * np.pi), atol=1e-12)
    lamp = Light("sphere", np.full(3, 1.0), position=np.array([-10.0, 0.0, 10.0]), radius=2.0, samples=16)
    h_lamp = azimuth_harmonics([lamp], pts, nrm, eye)
    np.testing.assert_allclose(h_lamp, 0.0)
    h_mix = azimuth_harmonics([a, lamp], pts, nrm, eye)
    assert 0.0 < h_mix[0, 0] < 1.0
