"""White Monte Carlo family over (g, n): exact at its nodes, continuous and C1 between them, gradients against finite
differences, sigma_a = 0, the plane integral, shapes, bad input, and one held-out off-grid reference."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.fresnel import fresnel_reflectance
from jaxsss.mc import white_family as wf
from tests.gradcheck import assert_grad_matches_fd

OFFGRID = wf.FAMILY_DIR.parent / "offgrid" / wf.node_file(0.7, 1.35)


@pytest.fixture(scope="module")
def fam():
    return wf.load_white_family()


def _single(t):
    return wf.family_from_nodes({(t["g"], t["n"]): t}, (t["g"],), (t["n"],))


@pytest.mark.parametrize("g, n", [(0.0, 1.0), (0.6, 1.2), (0.95, 1.6)])
def test_node_reproduced_exactly(fam, g, n):
    # At a node the Hermite weights are a unit vector: the family is that node's own table, exactly.
    t = wf.load_node(wf.FAMILY_DIR / wf.node_file(g, n))
    mu = jnp.array([0.0, 0.01, 0.3])
    np.testing.assert_allclose(wf.log_bin_profile(mu, g, n, fam), wf.log_bin_profile(mu, g, n, _single(t)),
                               rtol=0, atol=1e-12)


R3 = jnp.array([0.05, 0.5, 5.0])


@pytest.fixture(scope="module")
def full_jac(fam):
    """Traced (sigma_a, sigma_s', g, n) -> (Jacobian (3, 4), values (3,)) at the radii R3: every node is used."""

    def f(p):
        y = wf.white_family_profile(R3, p[0], p[1], p[2], p[3], fam)
        return y, y

    return jax.jit(jax.jacfwd(f, has_aux=True))


@pytest.mark.parametrize("axis, at", [("g", 0.6), ("g", 0.9), ("n", 1.2), ("n", 1.4)])
def test_continuous_and_c1_across_cell_boundaries(full_jac, axis, at):
    k = 2 if axis == "g" else 3
    eps = 1e-9
    p = np.array([0.02, 1.5, 0.45, 1.3])
    lo, hi = p.copy(), p.copy()
    lo[k], hi[k] = at - eps, at + eps
    (j_lo, v_lo), (j_hi, v_hi) = full_jac(jnp.asarray(lo)), full_jac(jnp.asarray(hi))
    np.testing.assert_allclose(v_lo, v_hi, rtol=1e-7)
    # Cubic Hermite with shared node slopes: the derivative is continuous too.
    np.testing.assert_allclose(j_lo[:, k], j_hi[:, k], rtol=1e-5, atol=1e-7 * float(np.abs(v_lo).max()))


def test_fixed_g_n_block_equals_the_whole_grid(fam, full_jac):
    # Concrete (g, n) evaluates only the 4 x 4 block of nodes with non-zero weights; traced ones use every node.
    for g, n in [(0.72, 1.33), (0.0, 1.0), (0.95, 1.6), (0.1, 1.55)]:
        _, full = full_jac(jnp.array([0.02, 1.5, g, n]))
        np.testing.assert_allclose(wf.white_family_profile(R3, 0.02, 1.5, g, n, fam), full, rtol=1e-12)


@pytest.mark.parametrize("r", [0.3, 3.0])
def test_gradients_match_finite_differences(fam, r):
    # d/d(sigma_a, sigma_s', g, n) at an off-grid point, inside a cell of both axes.
    def f(p):
        return wf.white_family_profile(r, p[0], p[1], p[2], p[3], fam)

    assert_grad_matches_fd(f, jnp.array([0.03, 1.7, 0.72, 1.33]), rel_step=1e-6, rtol=2e-5)


def test_sigma_a_zero_finite_and_plane_integral(fam):
    # Non-absorbing: every photon that enters eventually leaves through the top, so the plane integral of the
    # annulus averages plus the tail beyond the grid equals 1 - R_specular, up to the weight the runs lost (radii
    # beyond the grid with L' < 1000, step cap: < 1% measured) and the tail model's error.
    area = np.pi * np.diff(np.asarray(fam.r_edges) ** 2)
    for g, n in [(0.0, 1.0), (0.45, 1.3), (0.92, 1.5)]:
        y = np.exp(np.asarray(wf.log_bin_profile(0.0, g, n, fam)))
        total = float((y * area).sum())
        grid = np.asarray(fam.R[..., fam.n_simulated:]).sum(-1) @ area  # tail inside the grid, per node (G, N)
        beyond = float(np.asarray(wf._hermite_weights(jnp.asarray(g), fam.g_nodes))
                       @ (np.asarray(fam.tail_weight) - grid) @ np.asarray(wf._hermite_weights(jnp.asarray(n), fam.n_nodes)))
        expect = 1.0 - float(fresnel_reflectance(n, 1.0))
        assert abs(total + beyond - expect) < 0.012 * expect, (g, n, total, beyond, expect)
    grads = jax.grad(lambda p: wf.white_family_profile(2.0, p[0], p[1], p[2], p[3], fam))(
        jnp.array([0.0, 1.0, 0.5, 1.3]))
    assert np.all(np.isfinite(np.asarray(grads))), grads
    assert float(grads[0]) < 0.0  # absorption lowers R


def test_shapes_broadcast(fam):
    r = jnp.linspace(0.0, 5.0, 7)[:, None]
    sa = jnp.array([0.01, 0.1, 0.5])
    out = wf.white_family_profile(r, sa, 1.2, 0.3, 1.4, fam)
    assert out.shape == (7, 3)
    for c in range(3):
        np.testing.assert_allclose(out[:, c], wf.white_family_profile(r[:, 0], sa[c], 1.2, 0.3, 1.4, fam), rtol=1e-12)
    per_g = wf.white_family_profile(1.0, 0.05, 1.0, jnp.array([0.1, 0.5]), jnp.array([[1.1], [1.5]]), fam)
    assert per_g.shape == (2, 2)
    assert np.all(np.isfinite(np.asarray(out))) and np.all(np.asarray(out) > 0)


@pytest.mark.parametrize("kw, name, allowed", [
    ({"g": 0.96}, "g", "[0, 0.95]"), ({"g": -0.1}, "g", "[0, 0.95]"),
    ({"n": 1.7}, "n", "[1, 1.6]"), ({"n": 0.99}, "n", "[1, 1.6]"),
    ({"sigma_a": -1.0}, "sigma_a", "[0, inf)"), ({"sigma_s_prime": 0.0}, "sigma_s_prime", "(0, inf)"),
    ({"g": float("nan")}, "g", "[0, 0.95]"),
])
def test_out_of_range_errors_name_the_argument(fam, kw, name, allowed):
    args = {"r": 1.0, "sigma_a": 0.01, "sigma_s_prime": 1.0, "g": 0.5, "n": 1.3} | kw
    with pytest.raises(ValueError, match=rf"white_family_profile\({name}=") as e:
        wf.white_family_profile(**args, family=fam)
    assert allowed in str(e.value)


def test_offgrid_reference(fam):
    # A held-out white run at (g, n) = (0.7, 1.35), between nodes on both axes (other seed, same engine and grid):
    # band medians of the family's annulus averages (10 per decade) within 2% from 0.1 l_u to 10 l_d (acceptance of
    # issue 15; every case and absorption is in benchmarks/white_interpolation.py, compare_node).
    from benchmarks.white_interpolation import compare_node

    t = wf.load_node(OFFGRID)
    for row in compare_node(fam, t, (0.01, 0.1), "offgrid", "test", 1.0):
        assert len(row["bands"]) == 4, row["bands"]
        assert row["error"] < 0.02, row


def test_merge_nodes_pools_photons():
    # Pooling two runs of one node: photon-weighted means, standard errors combined, costs added; other nodes refused.
    a = wf.load_node(wf.FAMILY_DIR / wf.node_file(0.3, 1.3))
    b = dict(a, photons=3 * int(a["photons"]), R=2 * a["R"], seconds=5.0, seed=1)
    m = wf.merge_nodes(a, b)
    np.testing.assert_allclose(m["R"], 1.75 * a["R"], rtol=1e-6)
    np.testing.assert_allclose(m["R_stderr"], np.hypot(0.25, 0.75) * a["R_stderr"], rtol=1e-6)
    assert m["photons"] == 4 * int(a["photons"]) and m["seconds"] == float(a["seconds"]) + 5.0
    with pytest.raises(ValueError, match="different nodes"):
        wf.merge_nodes(a, wf.load_node(wf.FAMILY_DIR / wf.node_file(0.3, 1.4)))


def test_stderr_at_a_node_is_the_node_tables_noise(fam):
    # Reference value: at a node the weights are a unit vector, so the family's noise is that node's own: sqrt(sum
    # (E w)^2) / sum(R w) over its pathlength cells (the diffusion tail counted as exact), the annulus holding r.
    g, n, mu = 0.6, 1.2, 0.02
    t = wf.load_node(wf.FAMILY_DIR / wf.node_file(g, n))
    p = t["pathlength_edges"]
    w = np.exp(-mu * p[:-1]) * -np.expm1(-mu * np.diff(p)) / (mu * np.diff(p))  # <exp(-mu L)> over each bin
    R, E = t["R"].astype(float), t["R_stderr"].astype(float)
    _, tail = wf.fit_tail(t, wf.valid_bins(t, np.zeros((R.shape[0], len(wf.tail_edges()) - 1))))
    te = wf.tail_edges()
    wt = np.exp(-mu * te[:-1]) * -np.expm1(-mu * np.diff(te)) / (mu * np.diff(te))
    expect = np.sqrt(((E * w) ** 2).sum(1)) / ((R * w).sum(1) + (tail * wt).sum(1))
    m = np.array([20, 40, 60])  # bins inside the valid range
    rho = np.sqrt(t["r_edges"][m] * t["r_edges"][m + 1])
    got = wf.white_family_profile_stderr(rho, mu, 1.0, g, n, fam)
    np.testing.assert_allclose(got, expect[m], rtol=0.02)


def test_a_bin_no_photon_reached_is_not_valid():
    # Extreme input: a node whose far bins hold no photon, with a diffusion tail there. The tail alone made their
    # error look small, so they counted as valid and the node was refused as having empty valid bins (a held-out run
    # with 1.8e6 photons did this); now the valid range ends before the first empty bin.
    t = wf.load_node(wf.FAMILY_DIR / wf.node_file(0.3, 1.3))
    R, E = t["R"].copy(), t["R_stderr"].copy()
    first_empty = 70
    R[first_empty:], E[first_empty:] = 0.0, 0.0
    t = dict(t, R=R, R_stderr=E)
    tail = np.full((R.shape[0], len(wf.tail_edges()) - 1), 1e-3)  # a tail in every bin
    assert wf.valid_bins(t, tail) <= first_empty


def test_stderr_shapes_invariants_and_bad_input(fam):
    r = np.geomspace(0.1, 100.0, 30)
    sa = jnp.array([0.0, 0.01, 0.1])
    e = np.asarray(wf.white_family_profile_stderr(r[:, None], sa, 1.0, 0.45, 1.15, fam))
    assert e.shape == (30, 3) and np.all(np.isfinite(e)) and np.all(e >= 0)
    # Physical trend: at strong absorption few photons reach far annuli (noisy), near the source many do.
    near, far = (r > 1) & (r < 5), (r > 10) & (r < 50)
    assert e[far, 2].max() > 5 * e[near, 2].max()
    assert np.all(e[near] < 0.01)
    with pytest.raises(ValueError, match=r"white_family_profile_stderr\(g="):
        wf.white_family_profile_stderr(1.0, 0.01, 1.0, 0.99, 1.3, fam)
