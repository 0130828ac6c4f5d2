"""The exit on a curved surface (jaxsss.render.exit_curvature): the sphere walk, reference values, shapes, bad and
extreme input, invariants and autodiff; the curved kernel keeps the flat one's exitance."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.medium import Medium
from jaxsss.render.bssrdf import multiple_exit_distribution, white_kernel, white_tables
from jaxsss.render.exit_curvature import (CURVED_ALBEDO, CURVED_D, CURVED_KAPPA, CURVED_MU_EDGES, CURVED_MUS,
                                          curved_amplitude, curved_amplitude_at, curved_amplitude_cells,
                                          curved_exit_distribution,
                                          load_exit_curvature_table)
from jaxsss.render.walk import pencil_beam_walk
from tests.gradcheck import assert_grad_matches_fd
from tests.render.kernel_calls import kernel_pair, kernel_sources

# The table's functions jitted (one program each, kept by the persistent cache; the incidence nodes static): op by
# op, the first test to call them compiled every primitive (9 s).
_amplitude = jax.jit(curved_amplitude, static_argnums=0)
_cells = jax.jit(curved_amplitude_cells)
_at = jax.jit(curved_amplitude_at)
_exit = jax.jit(curved_exit_distribution, static_argnums=1)


def _tally(albedo, mu_i, radius, photons=4000, seed=3, min_order=1):
    out = []

    def add(first, exit_point, direction, weight):
        out.append((exit_point, direction, weight))

    pencil_beam_walk(albedo, mu_i, photons, seed, add, radius=radius, min_order=min_order)
    return [np.concatenate(x) for x in zip(*out)]


def sphere_pairs(rng, n: int, radius: float = 20.0):
    """``(x, p, delta)``: ``n`` shaded points ``x`` and samples ``p`` on a sphere of ``radius`` mm about the origin
    (unit normals, ``(n, 3)`` each; a sample near each point) and their offsets ``delta = radius (x - p)``."""
    x = rng.normal(size=(n, 3))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    p = x + rng.normal(size=(n, 3)) * 0.3
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    return x, p, jnp.asarray(radius * (x - p))


def test_sphere_walk_conserves_light_and_tends_to_the_half_space():
    """The walk in a sphere: without absorption every photon leaves, uncollided ones included (``min_order=0``: total
    weight = photons, exactly); each exit lies on the sphere; a sphere 1e7 mean free paths across gives the
    half-space's walk (same seed: the same paths but for the rare photon within 1e-5 of the surface, where the two
    disagree on which side it is): the same light to 0.5% and mean exit distance to 1%."""
    points, directions, weights = _tally(1.0, 0.3, 2.0, photons=3000, min_order=0)
    assert weights.sum() == pytest.approx(3000.0, rel=1e-12)
    np.testing.assert_allclose(np.linalg.norm(points - [0.0, 0.0, -2.0], axis=1), 2.0, rtol=1e-9)
    # Leaving: the direction points out of the sphere.
    assert np.all(np.einsum("ij,ij->i", points - [0.0, 0.0, -2.0], directions) > 0.0)
    flat = _tally(0.9, 0.5, None)
    huge = _tally(0.9, 0.5, 1e7)
    assert huge[2].sum() == pytest.approx(flat[2].sum(), rel=5e-3)
    radius = [np.sum(np.linalg.norm(t[0], axis=1) * t[2]) / t[2].sum() for t in (flat, huge)]
    assert radius[1] == pytest.approx(radius[0], rel=1e-2)
    # min_order=2 leaves out exactly the photons that leave after one interaction.
    once = _tally(0.9, 0.5, None, min_order=2)
    assert 0 < len(once[2]) < len(flat[2])


def test_a_small_sphere_leaves_less_grazing():
    """Reference (the walk, table): on a sphere 3.3 transport lengths in radius at albedo 0.9, light exiting 5
    transport lengths from a normally incident beam leaves at ``mu_o = 0.05`` under half the half-space's radiance
    and near the normal over 1.2x (the walk: 0.17 and 1.78 at 6-8 transport lengths, where the rank-1 form's
    positivity clip holds ``c`` back); on a plane (``kappa = 0``) nothing changes; the amplitude grows with the
    curvature and with the distance."""
    assert CURVED_ALBEDO[3] == 0.9 and CURVED_MUS[0] == 1.0
    table = _cells(_amplitude((1.0,), jnp.array([0.9])))
    kappa = jnp.array([0.0, 1.0 / 16.0, 1.0 / 3.3, 1.0 / 3.3])[:, None, None]
    d = jnp.array([5.0, 5.0, 5.0, 0.25])[:, None, None]
    c = np.asarray(_at(table, kappa, d))[:, 0, 0]
    assert c[0] == 0.0 and 0.0 < c[1] < c[2] and c[3] < c[2]
    x = np.asarray(_exit(jnp.array([0.05, 0.95]), (1.0,), jnp.array([0.9])))[:, :, 0]
    grazing, normal = 1.0 + c[2] * x[0, 1] / x[0, 0], 1.0 + c[2] * x[1, 1] / x[1, 0]
    assert grazing < 0.5 and normal > 1.2, (grazing, normal)


def test_shape_keeps_the_exitance_and_the_exit_positive():
    """Invariants: ``int X_2 phi 2 mu dmu = 0`` over the bins (the exitance is the flat kernel's), and ``1 + c phi``
    is positive at every tabulated curvature, distance, incidence, albedo and exit cosine (extreme: the rank-1 form
    cannot send negative light)."""
    tab = load_exit_curvature_table()
    centres = 0.5 * (CURVED_MU_EDGES[1:] + CURVED_MU_EDGES[:-1])
    x = np.asarray(multiple_exit_distribution(centres, np.asarray(CURVED_MUS), np.asarray(CURVED_ALBEDO)))
    np.testing.assert_allclose(np.einsum("bua,uab,b->ua", x, tab["phi"], 2.0 * centres), 0.0, atol=1e-9)
    assert np.all(1.0 + tab["c"][..., None] * tab["phi"][:, :, None, None, :] > 0.0)
    np.testing.assert_array_equal(tab["c"][:, :, 0], 0.0)


def test_cells_reproduce_the_table_at_its_nodes():
    """The kernel's uniform cells (:func:`curved_amplitude_cells`) against the table at its own nodes: every distance
    node lies on the grid; between the curvature nodes the grid cuts the kinks of the piecewise-linear table (0.007
    of an amplitude up to 0.4 at kappa l_u = 1 / 16)."""
    table = _amplitude((1.0, 0.5, 0.1), jnp.array([0.75, 0.9]))
    n_k, n_d = len(CURVED_KAPPA), len(CURVED_D)
    kappa = jnp.repeat(jnp.asarray(CURVED_KAPPA), n_d)[:, None, None] * jnp.ones((1, 1, 2))
    d = jnp.tile(jnp.asarray(CURVED_D), n_k)[:, None, None] * jnp.ones((1, 1, 2))
    c = np.asarray(_at(_cells(table), kappa, d)).reshape(n_k, n_d, 3, 2)
    np.testing.assert_allclose(c, np.asarray(table), atol=0.01)
    np.testing.assert_allclose(c[0], 0.0, atol=1e-15)


def test_shapes_and_bad_input():
    x = _exit(jnp.linspace(0.0, 1.0, 7), (1.0, 0.5, 0.1), jnp.array([0.2, 0.7, 0.999]))
    assert x.shape == (7, 6, 3) and np.all(np.isfinite(np.asarray(x)))
    table = _amplitude((1.0, 0.5, 0.1), jnp.array([0.2, 0.999]))
    assert table.shape == (len(CURVED_KAPPA), len(CURVED_D), 3, 2)
    ones = jnp.ones((1, 1, 2))
    c = _at(_cells(table), jnp.array([0.0, 0.1, 10.0])[:, None, None] * ones,
            jnp.array([0.0, 1.0, 1e6])[:, None, None] * ones)
    assert c.shape == (3, 3, 2) and np.all(np.isfinite(np.asarray(c)))
    with pytest.raises(ValueError, match="mus"):
        curved_exit_distribution(jnp.array([0.5]), (0.3,), jnp.array([0.5]))
    mus, sources = white_tables(0.0, 1.0, True)
    medium = Medium(sigma_a=jnp.array([0.015]), sigma_s_prime=jnp.array([0.15]), eta=1.0)
    with pytest.raises(ValueError, match=r"exit_curved=True\) needs first_order=True"):
        white_kernel(medium, sources, mus, shift=True, exit_curved=True)


def test_curved_kernel_keeps_the_exitance_and_a_plane_keeps_its_exit():
    """Invariants: the curved kernel's first K node rows (pairs, near terms, disc) are the flat kernel's; its second
    rows vanish for coplanar pairs (``kappa = 0``) and for concave ones, and are positive for convex ones (light that
    travelled leaves less grazing: in sum; the table's noise near the entry can leave single pairs slightly negative);
    radiance by exit weights is the nodes' rows times the weights."""
    mus, sources = white_tables(0.0, 1.0, True)
    medium = Medium(sigma_a=jnp.array([0.015, 0.1]), sigma_s_prime=jnp.array([0.15, 1.0]), eta=1.0)
    flat = white_kernel(medium, sources, mus, shift=True, curvature=True, first_order=True)
    curved = white_kernel(medium, sources, mus, shift=True, curvature=True, first_order=True, exit_curved=True)
    rng = np.random.default_rng(0)
    n = 9
    x, p, delta = sphere_pairs(rng, n)
    flux = jnp.asarray(rng.uniform(0.1, 1.0, size=(n, 4, 3, 2)))
    sources_ = kernel_sources(curved, flux)
    convex = (jnp.asarray(x), jnp.asarray(p))
    a = np.asarray(kernel_pair(flat, delta, sources_, convex))
    b = np.asarray(kernel_pair(curved, delta, sources_, convex))
    assert b.shape == (n, 6, 2) and curved.value_shape(flux.shape) == (6, 2)
    np.testing.assert_allclose(b[:, :3], a, rtol=1e-12)
    assert np.sum(b[:, 3:]) > 0.0
    up = jnp.tile(jnp.array([[0.0, 0.0, 1.0]]), (n, 1))
    plane_delta = delta.at[:, 2].set(0.0)
    assert np.all(np.asarray(kernel_pair(curved, plane_delta, sources_, (up, up)))[:, 3:] == 0.0)
    assert np.all(np.asarray(kernel_pair(curved, delta, sources_, (jnp.asarray(-x), jnp.asarray(-p))))[:, 3:] == 0.0)
    weights = jnp.asarray(rng.uniform(0.0, 1.0, size=(n, 6, 2)))
    np.testing.assert_allclose(np.asarray(kernel_pair(curved, delta, sources_, convex, weights)),
                               np.sum(b * np.asarray(weights), axis=1), rtol=1e-12)
    area = jnp.asarray(rng.uniform(0.5, 1.0, size=n))
    point, w_flux, _ = curved.near_terms(delta, sources_, area, 5.0, convex)
    np.testing.assert_allclose(np.asarray(point)[:, :3], np.asarray(flat.near_terms(delta, sources_, area, 5.0,
                                                                                     convex)[0]), rtol=1e-12)
    wd, wd2 = np.asarray(flat.weighted_disc(3.0)), np.asarray(curved.weighted_disc(3.0))
    np.testing.assert_allclose(wd2[:3], wd, rtol=1e-12)
    np.testing.assert_array_equal(wd2[3:], 0.0)


def test_gradients_match_finite_differences():
    def f(p):
        x = curved_exit_distribution(jnp.array([0.07, 0.4, 0.93]), (1.0, 0.1), p[:2])
        cells = curved_amplitude_cells(curved_amplitude((1.0, 0.1), p[:2]))
        c = curved_amplitude_at(cells, p[2] * jnp.array([0.05, 0.2])[:, None, None],
                                p[3] * jnp.array([1.0, 1.7])[:, None, None])
        return jnp.sum(x * jnp.arange(1.0, 5.0)[None, :, None]) + jnp.sum(c)

    assert_grad_matches_fd(f, jnp.array([0.62, 0.93, 1.13, 2.3]), jit=True)
