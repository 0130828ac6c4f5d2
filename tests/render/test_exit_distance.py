"""Exit by distance (jaxsss.render.exit_distance): reference values, shapes, bad and extreme input, invariants and
autodiff; the split kernel keeps the unsplit one's exitance."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.medium import Medium
from jaxsss.render.bssrdf import exit_distribution, white_kernel, white_tables
from jaxsss.render.exit_distance import (SPLIT_ALBEDO, SPLIT_D, SPLIT_MU_EDGES, SPLIT_MUS, amplitude_at,
                                         distance_amplitude, exit_split_distribution, load_exit_distance_table,
                                         node_rows)
from tests.gradcheck import assert_grad_matches_fd
from tests.render.kernel_calls import kernel_pair, kernel_sources


def test_a_whole_half_space_leaves_by_chandrasekhar():
    """Reference: over a whole half-space the light-weighted amplitude is 0 (the exit is Chandrasekhar's ``X``), and
    the shape changes no exitance (``int X phi 2 mu dmu = 0`` over the bins)."""
    assert SPLIT_ALBEDO[2] == 0.6
    tab = load_exit_distance_table()
    light = tab["H"].sum(axis=-1)  # (U, A, D)
    mean = np.sum(light * tab["c"], axis=-1) / light.sum(axis=-1)  # (U, A)
    # Exactly 0 but where the positivity clip bites (normal incidence at albedo <= 0.3: within 0.04).
    np.testing.assert_allclose(mean[:, 2:], 0.0, atol=2e-3)
    np.testing.assert_allclose(mean, 0.0, atol=0.04)
    centres = 0.5 * (SPLIT_MU_EDGES[1:] + SPLIT_MU_EDGES[:-1])
    x = np.asarray(exit_distribution(centres, np.asarray(SPLIT_MUS), np.asarray(SPLIT_ALBEDO)))  # (B, U, A)
    np.testing.assert_allclose(np.einsum("bua,uab,b->ua", x, tab["phi"], 2.0 * centres), 0.0, atol=1e-9)


def test_far_light_leaves_less_grazing():
    """Reference (the walk): a beam at cos 0.1 into albedo 0.9 leaves 3.0x a Lambertian exit at ``mu_o = 0.05`` over
    the whole half-space (``X``); within a quarter of a mean free path 4x, at 3 mean free paths under 2x."""
    table = distance_amplitude((0.1,), jnp.array([0.9]))
    c = np.asarray(amplitude_at(table, jnp.array([0.125, 3.0])[:, None, None]))[:, 0, 0]
    x = np.asarray(exit_split_distribution(jnp.array([0.05]), (0.1,), jnp.array([0.9])))[0, :, 0]
    assert 2.9 < x[0] < 3.2
    near, far = x[0] + c[0] * x[1], x[0] + c[1] * x[1]
    assert far < 2.0 < 3.5 < near, (near, far)


def test_shapes_and_bad_nodes():
    x = exit_split_distribution(jnp.linspace(0.0, 1.0, 7), (1.0, 0.5, 0.1), jnp.array([0.2, 0.7, 0.999]))
    assert x.shape == (7, 6, 3)
    assert np.all(np.isfinite(np.asarray(x)))
    table = distance_amplitude((1.0, 0.5, 0.1), jnp.array([0.2, 0.999]))
    assert table.shape == (3, len(SPLIT_D), 2)
    assert amplitude_at(table, jnp.array([0.0, 1.0, 1e6])[:, None, None] * jnp.ones((1, 1, 2))).shape == (3, 3, 2)
    with pytest.raises(ValueError, match="mus"):
        exit_split_distribution(jnp.array([0.5]), (0.3,), jnp.array([0.5]))


def test_exit_is_positive_at_every_distance():
    """Extreme: the exit ``X (1 + c phi)`` at every tabulated distance, incidence, albedo and exit cosine is
    positive (the rank-1 form cannot send negative light)."""
    tab = load_exit_distance_table()
    assert np.all(1.0 + tab["c"][..., :, None] * tab["phi"][..., None, :] > 0.0)


def test_split_kernel_keeps_the_exitance():
    """Invariant: the first K nodes of the split kernel (pairs and near-field disc) are the unsplit kernel's."""
    mus, sources = white_tables(0.0, 1.0, True)
    medium = Medium(sigma_a=jnp.array([0.015, 0.1]), sigma_s_prime=jnp.array([0.15, 1.0]), eta=1.0)
    plain = white_kernel(medium, sources, mus, shift=True)
    split = white_kernel(medium, sources, mus, shift=True, exit_split=True)
    rng = np.random.default_rng(0)
    delta = jnp.asarray(rng.normal(size=(9, 3)) * 6.0)
    flux = jnp.asarray(rng.uniform(0.1, 1.0, size=(9, 4, 3, 2)))
    a = np.asarray(kernel_pair(plain, delta, kernel_sources(plain, flux)))
    b = np.asarray(kernel_pair(split, delta, kernel_sources(split, flux)))
    assert b.shape == (9, 6, 2)
    np.testing.assert_allclose(b[:, :3], a, rtol=1e-12)
    wd, wd2 = np.asarray(plain.weighted_disc(3.0)), np.asarray(split.weighted_disc(3.0))
    np.testing.assert_allclose(wd2[:3], wd, rtol=1e-12)


def test_weighted_pairs_are_the_nodes_exit():
    """Invariant: a pair's radiance by the shaded point's exit weights (:meth:`WhiteKernel.pair` and
    :meth:`WhiteKernel.near_terms` with ``weights``) is its node values times the weights, summed: the sums may add
    the nodes per pair or per shaded point (with the split, the cut beam at both ends and the curvature)."""
    from jaxsss.render.passage import PASSAGE_MUS

    mus, sources = white_tables(0.0, 1.0, True)
    assert set(mus) <= set(PASSAGE_MUS)
    medium = Medium(sigma_a=jnp.array([0.015, 0.1]), sigma_s_prime=jnp.array([0.15, 1.0]), eta=1.0)
    kernel = white_kernel(medium, sources, mus, shift=True, curvature=True, passage=1.5, exit_split=True)
    rng = np.random.default_rng(1)
    n = 11
    delta = jnp.asarray(rng.normal(size=(n, 3)) * 4.0)
    flux = jnp.asarray(np.concatenate([rng.uniform(0.1, 1.0, size=(n, 4, 3, 2)),
                                       rng.uniform(0.0, 0.5, size=(n, 1, 3, 2)),
                                       rng.uniform(0.0, 3.0, size=(n, 1, 3, 2))], axis=1))
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    view = np.concatenate([rng.uniform(1.0, 20.0, size=(n, 1)), rng.normal(size=(n, 3)) * 0.3], axis=1)
    normals = (jnp.asarray(np.concatenate([normal, view], axis=1)), jnp.asarray(normal[::-1].copy()))
    weights = jnp.asarray(rng.uniform(0.0, 1.0, size=(n, 6, 2)))
    sources_ = kernel_sources(kernel, flux)
    nodes = np.asarray(kernel_pair(kernel, delta, sources_, normals))
    assert nodes.shape == (n, 6, 2) and kernel.value_shape(flux.shape, True) == (2,)
    np.testing.assert_allclose(np.asarray(kernel_pair(kernel, delta, sources_, normals, weights)),
                               np.sum(nodes * np.asarray(weights), axis=1), rtol=1e-12)
    area = jnp.asarray(rng.uniform(0.5, 1.0, size=n))
    point, w_flux, w_area = kernel.near_terms(delta, sources_, area, 5.0, normals)
    point_w, w_flux_w, _ = kernel.near_terms(delta, sources_, area, 5.0, normals, weights)
    np.testing.assert_allclose(np.asarray(point_w), np.sum(np.asarray(point) * np.asarray(weights), axis=1),
                               rtol=1e-12)
    np.testing.assert_allclose(np.asarray(w_flux_w), np.asarray(w_flux), rtol=1e-12)


def test_gradients_match_finite_differences():
    def f(p):
        x = exit_split_distribution(jnp.array([0.07, 0.4, 0.93]), (1.0, 0.1), p[:2])
        c = amplitude_at(distance_amplitude((1.0, 0.1), p[:2]), p[2] * jnp.array([1.0, 1.7])[:, None, None])
        return jnp.sum(x * jnp.arange(1.0, 5.0)[None, :, None]) + jnp.sum(c)

    assert_grad_matches_fd(f, jnp.array([0.62, 0.93, 1.4]), jit=True)


def test_node_rows_in_the_diffusion_coordinate():
    """``node_rows(..., coordinate="diffusion")``: exact at the albedo nodes, linear in ``sqrt(1 - albedo)`` between
    them (a table that is linear in it is reproduced to rounding, where linear in the albedo misses it by 5%), held
    beyond the ends, finite with a zero gradient at and above the last node (albedo 1: the square root's slope is
    infinite there), the gradient between nodes against central differences, and a bad coordinate named."""
    nodes = (0.3, 0.9, 0.97, 0.995, 0.999)
    s_nodes = np.sqrt(1.0 - np.asarray(nodes))
    table = np.stack([s_nodes, 2.0 * s_nodes + 1.0])[:, :, None]  # (U = 2, A, 1): linear in sqrt(1 - a)
    albedo = jnp.array([0.3, 0.5, 0.95, 0.987, 0.9965, 0.999, 0.9999, 1.0, 0.1])
    rows = np.asarray(node_rows(table, (1.0, 0.5), nodes, (0.5, 1.0), albedo, "test", coordinate="diffusion"))
    assert rows.shape == (2, 9, 1)
    s = np.sqrt(1.0 - np.clip(np.asarray(albedo), nodes[0], nodes[-1]))
    np.testing.assert_allclose(rows[1, :, 0], s, rtol=1e-12)
    np.testing.assert_allclose(rows[0, :, 0], 2.0 * s + 1.0, rtol=1e-12)
    linear = np.asarray(node_rows(table, (1.0, 0.5), nodes, (1.0,), albedo, "test"))[0, :, 0]
    assert abs(linear[3] / s[3] - 1.0) > 0.05  # 0.987, between 0.97 and 0.995
    assert np.all(np.isfinite(rows))

    def f(a):
        return jnp.sum(node_rows(table, (1.0, 0.5), nodes, (1.0,), a, "test", coordinate="diffusion"))

    top = np.asarray(jax.grad(f)(jnp.array([0.999, 0.99999, 1.0])))
    np.testing.assert_array_equal(top[1:], 0.0)
    assert np.all(np.isfinite(top))
    assert_grad_matches_fd(f, jnp.array([0.95, 0.987, 0.9965]), jit=True)
    with pytest.raises(ValueError, match="coordinate"):
        node_rows(table, (1.0, 0.5), nodes, (1.0,), albedo, "test", coordinate="log")
