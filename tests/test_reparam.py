"""Reparameterisation (Rd, l_d, eta) <-> (sigma_a, sigma_s') (hierarchical paper Eq. 15-16)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.medium import Medium
from jaxsss.reparam import from_rd_ld, to_rd_ld
from tests.gradcheck import assert_grad_matches_fd
from tests.test_reflectance import mp_invert

import mpmath as mp


def groenhuis_A(eta):
    Fdr = -1.4399 / eta**2 + 0.7099 / eta + 0.6681 + 0.0636 * eta
    return (1 + Fdr) / (1 - Fdr)


# --- 1. Reference values ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("rd", [1e-4, 0.5, 0.9999])
@pytest.mark.parametrize("eta", [1.0, 2.5])
def test_eq16_against_50_digit_oracle(rd, eta):
    ld = 1.7
    rep = from_rd_ld(rd, ld, eta)
    alpha, one_minus, u = mp_invert(rd, groenhuis_A(eta))
    sigma_tr = 1 / mp.mpf(ld)
    sigma_t_prime = sigma_tr / u  # Eq. 16
    expected = {"sigma_s_prime": alpha * sigma_t_prime, "sigma_a": one_minus * sigma_t_prime}
    for name, want in expected.items():
        assert abs(float(getattr(rep.medium, name)) / float(want) - 1) < 1e-12, name
    assert abs(float(rep.alpha_prime) / float(alpha) - 1) < 1e-12


def test_marble_round_trip_matches_table_values():
    m = Medium([0.0021, 0.0041, 0.0071], [2.19, 2.62, 3.00], 1.5)
    rd, ld = to_rd_ld(m)
    rep = from_rd_ld(rd, ld, 1.5)
    np.testing.assert_allclose(rep.medium.sigma_a, m.sigma_a, rtol=1e-12)
    np.testing.assert_allclose(rep.medium.sigma_s_prime, m.sigma_s_prime, rtol=1e-12)


# --- 2. Shapes --------------------------------------------------------------------------------------------------
def test_channels_broadcast_and_g_gives_sigma_s_and_sigma_t():
    rep = from_rd_ld(jnp.array([0.3, 0.5, 0.7]), 2.0, 1.3, g=0.9)
    assert rep.medium.sigma_a.shape == (3,) and rep.converged.shape == (3,)
    np.testing.assert_allclose(rep.medium.sigma_s, rep.medium.sigma_s_prime / 0.1, rtol=1e-14)
    np.testing.assert_allclose(rep.medium.sigma_t, rep.medium.sigma_s + rep.medium.sigma_a, rtol=1e-14)
    single = from_rd_ld(0.5, 2.0, 1.3)
    assert float(single.medium.sigma_a) == pytest.approx(float(rep.medium.sigma_a[1]), rel=1e-14)


# --- 3. Bad and extreme input ------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "args,match",
    [
        ((1.0, 1.0, 1.3), r"from_rd_ld\(rd=1\) is outside the allowed range \(0, 1\)"),
        ((0.0, 1.0, 1.3), r"rd=0"),
        ((0.5, 0.0, 1.3), r"from_rd_ld\(ld=0\) is outside the allowed range \(0, inf\)"),
        ((0.5, -2.0, 1.3), r"ld=-2"),
        ((0.5, 1.0, 0.0), r"eta=0"),
        ((0.5, np.nan, 1.3), r"ld=nan"),
    ],
)
def test_bad_input_names_argument(args, match):
    with pytest.raises(ValueError, match=match):
        from_rd_ld(*args)


def test_non_absorbing_medium_has_infinite_ld_and_unit_rd():
    rd, ld = to_rd_ld(Medium(0.0, 11.6, 1.3))  # spectralon
    assert float(rd) == 1.0 and float(ld) == np.inf


def test_stiff_ends_finite():
    rep = from_rd_ld(jnp.array([1e-12, 1 - 1e-12]), jnp.array([1e-3, 1e3]), 2.5)
    for leaf in jax.tree_util.tree_leaves(rep.medium):
        assert bool(jnp.all(jnp.isfinite(leaf)))


# --- 4. Physical invariants --------------------------------------------------------------------------------------
def test_reverse_then_forward_is_identity_over_a_grid():
    rd = jnp.array([1e-4, 0.01, 0.2, 0.6, 0.95, 0.9999])
    ld = jnp.array([0.1, 1.0, 10.0, 3.0, 0.5, 100.0])
    for eta in [0.5, 1.0, 1.3, 2.5]:
        rep = from_rd_ld(rd, ld, eta, fresnel="exact")
        rd2, ld2 = to_rd_ld(rep.medium)
        np.testing.assert_allclose(rd2, rd, rtol=1e-12)
        np.testing.assert_allclose(ld2, ld, rtol=1e-13)


def test_longer_ld_means_weaker_coefficients():
    a = from_rd_ld(0.5, 1.0, 1.3).medium
    b = from_rd_ld(0.5, 2.0, 1.3).medium
    assert float(b.sigma_a) == pytest.approx(float(a.sigma_a) / 2, rel=1e-14)
    assert float(b.sigma_s_prime) == pytest.approx(float(a.sigma_s_prime) / 2, rel=1e-14)


# --- 5. Autodiff --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("rd", [1e-4, 0.5, 0.9999])
def test_gradients_match_finite_differences(rd):
    def f(x):
        m = from_rd_ld(x[0], x[1], x[2]).medium
        return jnp.log(m.sigma_a) + 0.3 * jnp.log(m.sigma_s_prime)

    # Step relative to the distance from the nearer end of (0, 1), so the difference resolves the stiff end.
    step = 1e-6 * min(rd, 1 - rd) / rd
    assert_grad_matches_fd(f, jnp.array([rd, 1.5, 1.3]), rel_step=step, rtol=1e-5)
