"""The dipole profile: the five kinds of tests, including the plane integral = Eq. 15 identity (DESIGN.md trap 1)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad

from jaxsss.medium import Medium
from jaxsss.profiles.dipole import dipole_depths, dipole_profile
from jaxsss.reflectance import medium_total_diffuse_reflectance
from tests.gradcheck import assert_grad_matches_fd

# (sigma_a, sigma_s', eta): measured marble/skin values, stiff albedos at both ends, index-matched and high index.
MEDIA = [
    (0.0021, 2.19, 1.5),
    (0.032, 0.74, 1.3),
    (1.0, 1e-3, 1.3),
    (1e-6, 1.0, 1.0),
    (0.3, 1.0, 2.5),
    (0.01, 1.0, 0.5),
]


def paper_eq8(r, sigma_a, sigma_s_prime, eta):
    """Independent NumPy transcription of the hierarchical paper's Eq. 8-10 (C1, C2 form)."""
    st = sigma_a + sigma_s_prime
    alpha = sigma_s_prime / st
    sigma_tr = np.sqrt(3 * sigma_a * st)
    Fdr = -1.4399 / eta**2 + 0.7099 / eta + 0.6681 + 0.0636 * eta if eta >= 1 else (
        -0.4399 + 0.7099 / eta - 0.3319 / eta**2 + 0.0636 / eta**3)
    A = (1 + Fdr) / (1 - Fdr)
    z_r = 1 / st
    z_v = z_r * (1 + 4 * A / 3)
    d_r = np.sqrt(r**2 + z_r**2)
    d_v = np.sqrt(r**2 + z_v**2)
    C1 = z_r * (sigma_tr + 1 / d_r)
    C2 = z_v * (sigma_tr + 1 / d_v)
    return alpha / (4 * np.pi) * (C1 * np.exp(-sigma_tr * d_r) / d_r**2 + C2 * np.exp(-sigma_tr * d_v) / d_v**2)


def plane_integral(f, scale):
    """2 pi int_0^inf r f(r) dr by adaptive quadrature on log-spaced panels (the profile spans many decades)."""
    edges = np.concatenate([[0.0], scale * np.logspace(-4, 6, 41), [np.inf]])
    return sum(
        quad(lambda r: 2 * np.pi * r * f(r), a, b, epsabs=0, epsrel=1e-13, limit=200)[0]
        for a, b in zip(edges[:-1], edges[1:])
    )


# --- 1. Reference values ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("sa,ss,eta", MEDIA)
def test_matches_independent_transcription_of_eq8(sa, ss, eta):
    m = Medium(sa, ss, eta)
    r = np.concatenate([[0.0], np.logspace(-3, 2, 40)]) * float(m.l_u)
    np.testing.assert_allclose(dipole_profile(r, m), paper_eq8(r, sa, ss, eta), rtol=1e-12, atol=0)


@pytest.mark.parametrize("sa,ss,eta", MEDIA)
def test_plane_integral_equals_closed_form_Rd(sa, ss, eta):
    # DESIGN.md trap 1 / issue: the profile per unit flux entering integrates to Eq. 15 to 1e-10.
    m = Medium(sa, ss, eta)
    total = plane_integral(lambda r: paper_eq8(r, sa, ss, eta), float(m.l_u))
    assert abs(total - float(medium_total_diffuse_reflectance(m))) < 1e-10


# --- 2. Shapes --------------------------------------------------------------------------------------------------
def test_scalar_channel_and_batched_inputs_agree():
    m = Medium([0.0021, 0.0041, 0.0071], [2.19, 2.62, 3.00], 1.5)
    r = jnp.linspace(0.0, 5.0, 9)[:, None]
    R = dipole_profile(r, m)
    assert R.shape == (9, 3)
    for c in range(3):
        mc = Medium(float(m.sigma_a[c]), float(m.sigma_s_prime[c]), 1.5)
        np.testing.assert_allclose(R[:, c], dipole_profile(r[:, 0], mc), rtol=1e-14)
        assert float(dipole_profile(float(r[4, 0]), mc)) == pytest.approx(float(R[4, c]), rel=1e-14)
    batched = jax.vmap(lambda a: dipole_profile(r[:, 0], Medium(a, 1.0, 1.3)))(jnp.array([0.01, 0.1]))
    assert batched.shape == (2, 9)


# --- 3. Bad and extreme input ------------------------------------------------------------------------------------
@pytest.mark.parametrize("r", [-1.0, np.nan, np.inf])
def test_bad_radius_is_rejected(r):
    with pytest.raises(ValueError, match=r"dipole_profile\(r="):
        dipole_profile(r, Medium(0.01, 1.0, 1.3))


def test_extremes_are_finite():
    m = Medium(0.0, 1.0, 1.3)  # no absorption: sigma_tr = 0, profile decays as a power law
    assert np.isfinite(float(dipole_profile(1e6, m))) and float(dipole_profile(1e6, m)) > 0
    m = Medium(1e4, 1e-8, 2.5)  # nearly pure absorber
    assert float(dipole_profile(1e3, m)) == 0.0 and np.isfinite(float(dipole_profile(0.0, m)))


# --- 4. Physical invariants --------------------------------------------------------------------------------------
@pytest.mark.parametrize("sa,ss,eta", MEDIA)
def test_positive_and_decreasing(sa, ss, eta):
    m = Medium(sa, ss, eta)
    R = np.asarray(dipole_profile(np.logspace(-3, 3, 200) * float(m.l_u), m))
    assert np.all(R >= 0) and np.all(np.diff(R) <= 0)


def test_depths_follow_the_paper():
    m = Medium(0.01, 1.0, 1.3)
    z_r, z_v = dipole_depths(m)
    assert float(z_r) == pytest.approx(float(m.l_u), rel=1e-15)
    assert float(z_v) == pytest.approx(float(m.l_u) * (1 + 4 * float(m.A) / 3), rel=1e-14)


# --- 5. Autodiff --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("r_over_lu", [0.0, 0.5, 10.0, 300.0])
def test_gradient_matches_finite_differences(r_over_lu):
    def f(x):
        m = Medium(x[0], x[1], x[2])
        return dipole_profile(x[3] * m.l_u, m)

    # atol: near r = 0 the profile is flat, so dR/dr is ~1e-3 of the other components and its central
    # difference carries ~1e-8 absolute roundoff at a relative step of 1e-6 (1.6e-8 measured since the damping is
    # evaluated from (sigma_tr d)^2); a 1e-5 step keeps it at ~1e-9 with a truncation error ~1e-10 relative.
    assert_grad_matches_fd(f, jnp.array([0.01, 1.3, 1.4, max(r_over_lu, 1e-3)]), rel_step=1e-5, rtol=1e-6,
                           atol=1e-8)


def test_second_call_does_not_retrace():
    @jax.jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def f(r, m):
        return dipole_profile(r, m)

    r = jnp.linspace(0.0, 1.0, 5)
    f(r, Medium(0.01, 1.0, 1.3))
    f(r + 1.0, Medium(0.02, 2.0, 1.4))
