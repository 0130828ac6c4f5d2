"""The Medium pytree: derived quantities, validation, broadcasting, transformations."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.fresnel import F_dr_exact, F_dr_poly
from jaxsss.medium import Medium
from tests.gradcheck import assert_grad_matches_fd

MARBLE = dict(sigma_a=[0.0021, 0.0041, 0.0071], sigma_s_prime=[2.19, 2.62, 3.00], eta=1.5)


def test_derived_quantities_match_their_definitions():
    m = Medium(0.01, 1.0, 1.3, g=0.9)
    st = 1.01
    assert float(m.sigma_t_prime) == pytest.approx(st, rel=1e-15)
    assert float(m.alpha_prime) == pytest.approx(1.0 / st, rel=1e-15)
    assert float(m.one_minus_alpha_prime) == pytest.approx(0.01 / st, rel=1e-15)
    assert float(m.sigma_tr) == pytest.approx(np.sqrt(3 * 0.01 * st), rel=1e-15)
    assert float(m.D) == pytest.approx(1 / (3 * st), rel=1e-15)
    assert float(m.l_u) == pytest.approx(1 / st, rel=1e-15)
    assert float(m.l_d) == pytest.approx(1 / np.sqrt(3 * 0.01 * st), rel=1e-15)
    Fdr = float(F_dr_poly(1.3))
    assert float(m.F_dr) == pytest.approx(Fdr, rel=1e-15)
    assert float(m.F_dt) == pytest.approx(1 - Fdr, rel=1e-15)
    assert float(m.A) == pytest.approx((1 + Fdr) / (1 - Fdr), rel=1e-15)
    assert float(m.z_b) == pytest.approx(2 * (1 + Fdr) / (1 - Fdr) / (3 * st), rel=1e-15)
    assert float(m.sigma_s) == pytest.approx(10.0, rel=1e-14)
    assert float(m.sigma_t) == pytest.approx(10.01, rel=1e-14)


def test_fresnel_method_selects_exact_F_dr():
    m = Medium(0.01, 1.0, 1.3, fresnel="exact")
    assert float(m.F_dr) == pytest.approx(float(F_dr_exact(1.3)), rel=1e-15)


def test_channels_broadcast():
    m = Medium(**MARBLE)
    assert m.l_d.shape == (3,) and m.A.shape == () and m.z_b.shape == (3,)
    per_channel = [Medium(a, s, 1.5) for a, s in zip(MARBLE["sigma_a"], MARBLE["sigma_s_prime"])]
    np.testing.assert_allclose(m.l_d, [float(p.l_d) for p in per_channel], rtol=1e-15)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(sigma_a=-0.1, sigma_s_prime=1.0), r"Medium\(sigma_a=-0.1\) is outside the allowed range \[0, inf\)"),
        (dict(sigma_a=0.1, sigma_s_prime=-1.0), r"Medium\(sigma_s_prime=-1\)"),
        (dict(sigma_a=0.0, sigma_s_prime=0.0), r"must absorb or scatter"),
        (dict(sigma_a=0.1, sigma_s_prime=1.0, eta=0.0), r"Medium\(eta=0\) is outside the allowed range \(0, inf\)"),
        (dict(sigma_a=0.1, sigma_s_prime=1.0, eta=-1.3), r"eta=-1.3"),
        (dict(sigma_a=np.nan, sigma_s_prime=1.0), r"sigma_a=nan"),
        (dict(sigma_a=np.inf, sigma_s_prime=1.0), r"sigma_a=inf"),
        (dict(sigma_a=0.1, sigma_s_prime=1.0, g=1.0), r"Medium\(g=1\) is outside the allowed range \(-1, 1\)"),
        (dict(sigma_a=0.1, sigma_s_prime=[1.0, -2.0]), r"sigma_s_prime=-2\) \(element \(1,\)"),
        (dict(sigma_a=0.1, sigma_s_prime=1.0, fresnel="fit"), r"valid: 'poly', 'exact'"),
    ],
)
def test_bad_values_name_argument_value_and_range(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Medium(**kwargs)


def test_non_numeric_input_is_a_type_error():
    with pytest.raises(TypeError, match="sigma_a='abc'"):
        Medium("abc", 1.0)


def test_sigma_s_requires_g():
    with pytest.raises(ValueError, match="need the anisotropy g"):
        Medium(0.1, 1.0).sigma_s


def test_traced_bad_values_raise_at_run_time():
    f = jax.jit(lambda a: Medium(a, 1.0).l_d)
    assert np.isfinite(float(f(0.1)))
    with pytest.raises(Exception, match=r"sigma_a=\.\.\.\) is outside"):
        jax.block_until_ready(f(-0.1))


def test_medium_is_a_pytree_that_vmaps_and_does_not_retrace():
    media = jax.vmap(lambda a: Medium(a, 1.0, 1.3))(jnp.array([0.01, 0.02, 0.03]))
    assert media.sigma_a.shape == (3,)

    @jax.jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def l_d(m):
        return m.l_d

    l_d(Medium(0.01, 1.0, 1.3))
    l_d(Medium(0.05, 2.0, 1.4))  # new values, same structure: no retrace


def test_extreme_but_valid_values_are_finite():
    for sa, ss in [(1e-12, 1e4), (1e4, 1e-12), (0.0, 1.0), (1.0, 0.0)]:
        m = Medium(sa, ss, 2.5)
        for q in (m.alpha_prime, m.sigma_tr, m.l_u, m.z_b, m.A):
            assert np.isfinite(float(q))
    assert float(Medium(0.0, 1.0).l_d) == np.inf  # documented limit: no absorption, infinite l_d


def test_derived_gradients_match_finite_differences():
    def f(x):
        m = Medium(x[0], x[1], x[2])
        return m.sigma_tr * m.z_b + m.alpha_prime

    assert_grad_matches_fd(f, jnp.array([0.01, 1.3, 1.4]))
