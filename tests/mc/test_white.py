"""White ("scaled") Monte Carlo model: agreement with direct engine runs at held-out parameters, plane integral,
gradients against finite differences, shapes and bad input."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.mc import (
    Stack,
    WhiteTable,
    available_white_tables,
    load_white_table,
    simulate,
    white_mc_medium_profile,
    white_mc_profile,
    white_mc_profile_stderr,
)
from jaxsss.mc.white import TABLE_DIR
from jaxsss.medium import Medium
from tests.gradcheck import assert_grad_matches_fd

# Held-out media (not the tables' own non-absorbing runs): (g, n, sigma_a, sigma_s', photons of the direct run).
HELD_OUT = [
    (0.0, 1.4, 0.05, 2.0, 200_000),
    (0.9, 1.0, 0.1, 1.0, 40_000),
]

_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)


def _annulus_average(table, sigma_a, sigma_s_prime, edges):
    """The model averaged over each annulus (8-point Gauss-Legendre in r per bin), as the engine bins it."""
    a, b = edges[:-1, None], edges[1:, None]
    r = 0.5 * (b - a) * _GL_X + 0.5 * (b + a)
    R = np.asarray(white_mc_profile(r, sigma_a, sigma_s_prime, table))
    return (R * r * _GL_W).sum(1) * (b - a)[:, 0] / (b[:, 0] ** 2 - a[:, 0] ** 2)


@pytest.fixture(scope="module", params=HELD_OUT, ids=lambda p: f"g{p[0]}-n{p[1]}")
def direct(request):
    g, n, sa, ssp, photons = request.param
    m = Medium(sa, ssp, eta=n)
    l_u, l_d = float(m.l_u), float(m.l_d)
    edges = np.geomspace(0.1 * l_u, 20 * l_d, 31)
    res = simulate(Stack.half_space(sa, ssp / (1 - g), g, n), photons, seed=7, r_edges=edges, progress=False)
    return dict(g=g, n=n, sigma_a=sa, sigma_s_prime=ssp, edges=edges, res=res, table=load_white_table(g, n))


def test_profile_matches_direct_run(direct):
    """Plain direct runs, where they have counts (to ~6-10 l_d); out to 20 l_d see tests/mc/test_splitting.py."""
    res, tab, edges = direct["res"], direct["table"], direct["edges"]
    sa, ssp = direct["sigma_a"], direct["sigma_s_prime"]
    model = _annulus_average(tab, sa, ssp, edges)
    centres = np.sqrt(edges[1:] * edges[:-1])
    rel_table = np.asarray(white_mc_profile_stderr(centres, sa, ssp, tab))
    ok = res.R_r_stderr < 0.1 * res.R_r  # bins where the direct run has >~ 100 photons
    assert ok.sum() >= 15, ok
    se = np.sqrt(res.R_r_stderr**2 + (rel_table * model) ** 2)
    diff = np.abs(model - res.R_r)
    bound = np.maximum(0.02 * res.R_r, 3.0 * se)
    bad = ok & (diff > bound)
    assert not bad.any(), list(zip(centres[bad], model[bad], res.R_r[bad], res.R_r_stderr[bad]))


def test_plane_integral_is_r_diffuse(direct):
    res, tab = direct["res"], direct["table"]
    sa, ssp = direct["sigma_a"], direct["sigma_s_prime"]
    sigma_s = ssp / (1 - tab.g)
    # Log grid from far inside the first bin to far beyond the decay; trapezoid in log r of 2 pi r^2 R(r).
    r = np.geomspace(1e-6 / sigma_s, 3e3 / sigma_s, 20_000)
    R = np.asarray(white_mc_profile(r, sa, ssp, tab))
    total = np.trapezoid(2 * np.pi * r * r * R, np.log(r))
    # The table's own noise on a total is ~1/sqrt(photons) of the dominant terms: allow 3 sigma of both runs.
    se_table = 1.0 / np.sqrt(tab.photons)
    assert abs(total - res.R_diffuse) <= 3 * np.hypot(res.R_diffuse_stderr, se_table) + 2e-3, (total, res.R_diffuse)


def test_gradients_match_finite_differences():
    tab = load_white_table(0.0, 1.4)
    r = jnp.array([0.05, 0.3, 1.0, 4.0, 12.0])

    def f(x):
        return jnp.sum(jnp.log(white_mc_profile(r, x[0], x[1], tab)))

    assert_grad_matches_fd(f, np.array([0.03, 1.7]), rtol=2e-5)
    tab9 = load_white_table(0.9, 1.0)
    assert_grad_matches_fd(lambda x: jnp.sum(white_mc_profile(r, x[0], x[1], tab9)), np.array([0.2, 0.8]), rtol=2e-5)


def test_shapes_and_channels():
    tab = load_white_table(0.0, 1.0)
    r = np.linspace(0.0, 5.0, 7)
    sa, ssp = np.array([0.01, 0.1, 0.5]), np.array([1.0, 2.0, 3.0])
    R = white_mc_profile(r[:, None], sa, ssp, tab)
    assert R.shape == (7, 3) and R.dtype == jnp.float64
    for c in range(3):
        np.testing.assert_allclose(R[:, c], white_mc_profile(r, sa[c], ssp[c], tab), rtol=1e-13)
        np.testing.assert_allclose(R[2, c], white_mc_profile(r[2], sa[c], ssp[c], tab), rtol=1e-13)
    assert white_mc_profile(0.0, 0.1, 1.0, tab).shape == ()
    assert np.all(np.isfinite(R)) and np.all(R > 0)
    # r = 0 is finite (held at the first bin), and far beyond the table the tail decays.
    far = white_mc_profile(np.array([1e4, 1e5]), 0.1, 1.0, tab)
    assert np.all(np.isfinite(far)) and far[1] <= far[0]
    # Medium front end and vmap/jit.
    m = Medium(0.1, 2.0, eta=1.0)
    np.testing.assert_allclose(white_mc_medium_profile(r, m), white_mc_profile(r, 0.1, 2.0, tab), rtol=1e-13)
    vm = jax.vmap(lambda s: white_mc_profile(r, s, 1.0, tab))(jnp.array(sa))
    np.testing.assert_allclose(vm, white_mc_profile(r[:, None], sa, 1.0, tab).T, rtol=1e-12)


def test_bad_input():
    tab = load_white_table(0.0, 1.0)
    with pytest.raises(ValueError, match=r"white_mc_profile\(sigma_a=-0.1\).*allowed range"):
        white_mc_profile(1.0, -0.1, 1.0, tab)
    with pytest.raises(ValueError, match=r"sigma_s_prime=0"):
        white_mc_profile(1.0, 0.1, 0.0, tab)
    with pytest.raises(ValueError, match=r"r=-1"):
        white_mc_profile(-1.0, 0.1, 1.0, tab)
    with pytest.raises(ValueError, match=r"sigma_a=nan"):
        white_mc_profile(1.0, np.nan, 1.0, tab)
    with pytest.raises(ValueError, match=r"available: .*\(g=0, n=1\).*--regenerate"):
        load_white_table(0.5, 1.2)
    with pytest.raises(ValueError, match="WhiteTable"):
        white_mc_profile(1.0, 0.1, 1.0, "table")


def test_shipped_tables_are_small_and_account_for_their_weight():
    pairs = available_white_tables()
    assert (0.0, 1.0) in pairs and (0.9, 1.4) in pairs
    for g, n in pairs:
        path = TABLE_DIR / f"white_g{g:.2f}_n{n:.2f}.npz"
        assert path.stat().st_size < 300 * 1024
        tab = load_white_table(g, n)
        assert isinstance(tab, WhiteTable) and tab.g == g and tab.n == n
        with np.load(path) as z:
            # Non-absorbing: specular + tabulated + lost = 1 exactly; the loss is the walks beyond path_max.
            assert float(z["R_specular"] + z["R_in_table"] + z["lost_weight"]) == pytest.approx(1.0, abs=1e-9)
            assert 0.0 <= float(z["lost_weight"]) < 0.06
