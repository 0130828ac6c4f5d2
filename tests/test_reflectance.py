"""Total diffuse reflectance (Eq. 15) and its inversion Rd -> alpha'."""

import equinox as eqx
import jax
import jax.numpy as jnp
import mpmath as mp
import numpy as np
import optimistix as optx
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxsss.reflectance import (
    alpha_prime_from_rd,
    invert_rd,
    medium_total_diffuse_reflectance,
    total_diffuse_reflectance,
    total_diffuse_reflectance_u,
)
from jaxsss.medium import Medium
from tests.gradcheck import assert_grad_matches_fd

mp.mp.dps = 50


def mp_rd(u, A):
    """Eq. 15 in u = sqrt(3 (1 - alpha')), 50-digit arithmetic."""
    return (1 - u * u / 3) / 2 * (1 + mp.exp(-4 * A * u / 3)) * mp.exp(-u)


def mp_invert(rd, A):
    """Independent oracle: 50-digit bisection of Eq. 15 for u; returns (alpha', 1 - alpha', u) as mpf."""
    rd, A = mp.mpf(rd), mp.mpf(A)
    lo, hi = mp.mpf(0), mp.sqrt(3)
    for _ in range(190):
        mid = (lo + hi) / 2
        if mp_rd(mid, A) > rd:
            lo = mid
        else:
            hi = mid
    u = (lo + hi) / 2
    return 1 - u * u / 3, u * u / 3, u


STIFF_RD = [1e-12, 1e-4, 0.01, 0.3, 0.5, 0.9, 0.9999, 1 - 1e-9]
A_VALUES = [0.45, 1.0, 2.0, 4.3, 15.0]  # eta from 0.5 to ~2.5 (and beyond)


# --- 1. Reference values ---------------------------------------------------------------------------------------
def test_forward_matches_50_digit_eq15():
    alpha = np.array([1e-6, 0.1, 0.5, 0.9, 0.999, 1 - 1e-9])
    for A in A_VALUES:
        got = total_diffuse_reflectance(alpha, A)
        want = [float(mp_rd(mp.sqrt(3 * (1 - mp.mpf(a))), A)) for a in alpha]
        # 1 - alpha' is formed in float64 from alpha', which costs ~1e-16 / (1 - alpha') relative in u.
        np.testing.assert_allclose(got, want, rtol=1e-12)


@pytest.mark.parametrize("A", A_VALUES)
def test_inversion_matches_50_digit_bisection_at_stiff_ends(A):
    inv = invert_rd(np.array(STIFF_RD), A)
    assert bool(jnp.all(inv.converged))
    for k, rd in enumerate(STIFF_RD):
        alpha, one_minus, u = mp_invert(rd, A)
        # Relative accuracy of alpha', 1 - alpha' and u: 1e-13 (observed <= 1e-14; the issue asks for 1e-9).
        assert abs(float(inv.alpha_prime[k]) / float(alpha) - 1) < 1e-13, (rd, A)
        assert abs(float(inv.one_minus_alpha_prime[k]) / float(one_minus) - 1) < 1e-13, (rd, A)
        assert abs(float(inv.u[k]) / float(u) - 1) < 1e-13, (rd, A)


# --- 2. Shapes --------------------------------------------------------------------------------------------------
def test_shapes_broadcast():
    rd = jnp.array([[0.2, 0.5, 0.8]])
    A = jnp.array([[1.0], [2.0]])
    inv = invert_rd(rd, A)
    assert inv.alpha_prime.shape == (2, 3) and inv.steps.shape == (2, 3) and inv.converged.shape == (2, 3)
    assert float(alpha_prime_from_rd(0.5, 2.0)) == pytest.approx(float(inv.alpha_prime[1, 1]), rel=1e-14)
    assert total_diffuse_reflectance(jnp.array([0.5, 0.9]), 2.0).shape == (2,)


# --- 3. Bad and extreme input ------------------------------------------------------------------------------------
@pytest.mark.parametrize("rd", [0.0, 1.0, -0.1, 1.5, np.nan])
def test_rd_outside_open_interval_is_rejected(rd):
    with pytest.raises(ValueError, match=r"invert_rd\(Rd=.*\) is outside the allowed range \(0, 1\)"):
        invert_rd(rd, 2.0)


def test_bad_albedo_and_A_are_rejected():
    with pytest.raises(ValueError, match=r"alpha_prime=1.5"):
        total_diffuse_reflectance(1.5, 2.0)
    with pytest.raises(ValueError, match=r"A=0"):
        invert_rd(0.5, 0.0)


def test_iteration_cap_is_reported_not_raised():
    inv = invert_rd(jnp.array([0.3, 0.9999]), 2.0, max_steps=1)
    assert not bool(jnp.any(inv.converged))
    assert bool(jnp.all(inv.result == optx.RESULTS.nonlinear_max_steps_reached))


def test_extremes_are_finite():
    inv = invert_rd(jnp.array([1e-300, 1 - 1e-16]), 2.0)
    assert bool(jnp.all(jnp.isfinite(inv.alpha_prime))) and bool(jnp.all(inv.alpha_prime > 0))
    assert float(total_diffuse_reflectance(1.0, 2.0)) == 1.0 and float(total_diffuse_reflectance(0.0, 2.0)) == 0.0


# --- 4. Physical invariants --------------------------------------------------------------------------------------
@settings(max_examples=60, deadline=None)
@given(
    log10_one_minus=st.floats(min_value=-12, max_value=-1e-3),
    A=st.floats(min_value=0.4, max_value=20.0),
)
def test_inversion_round_trip(log10_one_minus, A):
    u = np.sqrt(3 * 10.0**log10_one_minus)
    rd = float(total_diffuse_reflectance_u(u, A))
    if not 0.0 < rd < 1.0:
        return
    inv = invert_rd(rd, A)
    assert bool(inv.converged)
    assert float(inv.u) == pytest.approx(u, rel=1e-12)


def test_rd_increases_with_albedo_and_decreases_with_A():
    alpha = jnp.linspace(0.0, 1.0, 101)
    Rd = np.asarray(total_diffuse_reflectance(alpha, 2.0))
    assert np.all(np.diff(Rd) > 0) and Rd[0] == 0.0 and Rd[-1] == 1.0
    assert float(total_diffuse_reflectance(0.9, 1.0)) > float(total_diffuse_reflectance(0.9, 3.0))


def test_medium_form_agrees_and_avoids_cancellation():
    m = Medium(1e-12, 1.0, 1.3)
    u = np.sqrt(3 * 1e-12 / (1 + 1e-12))
    assert float(medium_total_diffuse_reflectance(m)) == pytest.approx(
        float(total_diffuse_reflectance_u(u, m.A)), rel=1e-15
    )


# --- 5. Autodiff --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("rd", [1e-4, 0.3, 0.9, 0.9999])
@pytest.mark.parametrize("A", [1.0, 4.3])
def test_implicit_gradient_is_reciprocal_of_forward_derivative(rd, A):
    alpha = alpha_prime_from_rd(rd, A)
    d_rd_d_alpha = jax.grad(total_diffuse_reflectance)(alpha, A)
    d_alpha_d_rd = jax.grad(alpha_prime_from_rd)(rd, A)
    assert float(d_alpha_d_rd) == pytest.approx(1.0 / float(d_rd_d_alpha), rel=1e-9)


@pytest.mark.parametrize("rd", [1e-4, 0.5, 0.9999])
def test_inversion_gradient_matches_finite_differences(rd):
    # Derivatives of 1 - alpha' (the stiff quantity) with respect to Rd and A.
    assert_grad_matches_fd(lambda x: invert_rd(x[0], x[1]).one_minus_alpha_prime, jnp.array([rd, 2.0]), rtol=1e-5)


def test_forward_gradient_matches_finite_differences():
    assert_grad_matches_fd(lambda x: total_diffuse_reflectance(x[0], x[1]), jnp.array([0.9, 2.0]))


def test_jitted_inversion_does_not_retrace():
    @jax.jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def f(rd):
        return invert_rd(rd, 2.0).alpha_prime

    f(jnp.array([0.3, 0.5]))
    f(jnp.array([0.7, 0.9]))
