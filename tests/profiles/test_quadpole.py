"""The quadpole (photon-diffusion Eq. 14, re-derived from four image sources): boundary conditions, symmetry,
reference values, limits, shapes, bad input and gradients."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.medium import Medium
from jaxsss.profiles import (
    dipole_exitance,
    dipole_profile,
    quadpole_exitance,
    quadpole_profile,
    quadpole_sources,
)
from tests.gradcheck import assert_grad_matches_fd

MEDIA = [(0.01, 1.0, 1.3), (0.2, 1.0, 1.0), (0.005, 2.0, 2.5)]


def fluence(w, h, y, sources, medium):
    """NumPy fluence of the image sources at (w, h, y), sources at y = 0: sum sign e^{-s d} / (4 pi D d)."""
    ws, hs, sign = (np.asarray(a)[:, None] for a in sources)
    s_tr, D = float(medium.sigma_tr), float(medium.D)
    d = np.sqrt((w - ws) ** 2 + (h - hs) ** 2 + y**2)
    return np.sum(sign * np.exp(-s_tr * d) / (4 * np.pi * D * d), axis=0)


# --- 4. Boundary conditions and symmetry --------------------------------------------------------------------------
@pytest.mark.parametrize("sa,ss,eta", MEDIA)
def test_fluence_vanishes_on_both_extrapolated_boundaries(sa, ss, eta):
    m = Medium(sa, ss, eta)
    z_b = float(m.z_b)
    src = quadpole_sources(0.7, 1.3, m)
    t = np.linspace(-z_b, 6.0, 25)
    y = np.linspace(-2.0, 2.0, 25)
    scale = np.max(np.abs(fluence(np.full(25, 1.3), np.full(25, 0.2), y, src, m)))
    # Both conditions of Eq. 10, the adjoining face's too, to rounding (the terms cancel in exact pairs).
    assert np.max(np.abs(fluence(t, np.full(25, -z_b), y, src, m))) < 1e-14 * scale
    assert np.max(np.abs(fluence(np.full(25, -z_b), t, y, src, m))) < 1e-14 * scale
    # ... and is positive inside (a check that the conditions above are not met by a zero field).
    assert np.all(fluence(np.full(25, 1.0), np.full(25, 0.5), y, src, m) > 0)


@pytest.mark.parametrize("sa,ss,eta", MEDIA)
def test_exitance_is_the_diffusive_flux_of_the_four_sources(sa, ss, eta):
    # Independent of Eq. 6's algebra: D d(phi)/dh through the viewed face (h = 0, outward is -h) by a central
    # difference of the NumPy fluence; step 1e-5 mm gives ~1e-9 relative error.
    m = Medium(sa, ss, eta)
    depth, offset = 0.9, 0.4
    src = quadpole_sources(depth, offset, m)
    u = np.array([0.0, 0.2, 0.4, 1.0, 3.0, 7.0])
    y = np.array([0.3, 0.0, -0.5, 1.0, 0.0, 2.0])
    eps = 1e-5
    flux = float(m.D) * (fluence(u, np.full(6, eps), y, src, m) - fluence(u, np.full(6, -eps), y, src, m)) / (2 * eps)
    np.testing.assert_allclose(quadpole_exitance(u, y, depth, offset, m), flux, rtol=1e-7)


def test_green_function_reciprocity():
    # The image construction keeps the wedge's Green's function symmetric: fluence at q from a source at p equals the
    # fluence at p from a source at q (y = 0 plane).
    m = Medium(0.03, 1.0, 1.4)
    p, q = (0.6, 1.7), (2.2, 0.35)
    a = fluence(np.array([q[0]]), np.array([q[1]]), 0.0, quadpole_sources(p[1], p[0], m), m)
    b = fluence(np.array([p[0]]), np.array([p[1]]), 0.0, quadpole_sources(q[1], q[0], m), m)
    assert float(a[0]) == pytest.approx(float(b[0]), rel=1e-13)


def test_even_in_y_positive_and_below_the_dipole():
    m = Medium(0.01, 1.0, 1.3)
    u = jnp.linspace(0.0, 5.0, 11)
    a = quadpole_exitance(u, 0.7, 1.0, 0.5, m)
    np.testing.assert_allclose(a, quadpole_exitance(u, -0.7, 1.0, 0.5, m), rtol=1e-15)
    dip = dipole_exitance(jnp.sqrt((u - 0.5) ** 2 + 0.49), 1.0, m)
    # The mirror dipole is farther than the real one (u >= 0), so R_q is positive and below the viewed-face dipole.
    assert bool(jnp.all(a > 0)) and bool(jnp.all(a < dip))


def test_far_from_the_edge_is_the_dipole():
    m = Medium(0.01, 1.0, 1.3)
    r = jnp.array([0.0, 0.5, 2.0, 10.0])
    a = 1e3 * float(m.l_d)  # the mirror term is ~exp(-2000) of the dipole
    np.testing.assert_allclose(quadpole_exitance(a + r, 0.0, 0.8, a, m), dipole_exitance(r, 0.8, m), rtol=1e-14)
    np.testing.assert_allclose(quadpole_profile(a + r, 0.0, m, a, face="top"), dipole_profile(r, m), rtol=1e-14)


def test_profile_faces_follow_the_view_frame():
    m = Medium(0.02, 1.5, 1.4)
    z, y, a = jnp.array([0.1, 1.0, 3.0]), jnp.array([0.0, 0.4, -1.0]), 0.8
    side = quadpole_profile(z, y, m, a, face="side")
    np.testing.assert_allclose(side, m.alpha_prime * quadpole_exitance(z, y, a, m.l_u, m), rtol=1e-15)
    top = quadpole_profile(z, y, m, a, face="top")
    np.testing.assert_allclose(top, m.alpha_prime * quadpole_exitance(z, y, m.l_u, a, m), rtol=1e-15)


# --- 2. Shapes ----------------------------------------------------------------------------------------------------
def test_scalar_channel_and_batched_inputs_agree():
    m = Medium([0.01, 0.02, 0.05], [1.0, 1.5, 2.0], [1.3, 1.3, 1.4])
    u = jnp.linspace(0.0, 4.0, 5)[:, None]
    R = quadpole_exitance(u, 0.2, 0.9, 0.4, m)
    assert R.shape == (5, 3)
    for c in range(3):
        mc = Medium(float(m.sigma_a[c]), float(m.sigma_s_prime[c]), float(m.eta[c]))
        np.testing.assert_allclose(R[:, c], quadpole_exitance(u[:, 0], 0.2, 0.9, 0.4, mc), rtol=1e-14)
    batched = jax.vmap(lambda d: quadpole_exitance(u[:, 0], 0.2, d, 0.4, Medium(0.01, 1.0, 1.3)))(jnp.array([0.5, 1.0]))
    assert batched.shape == (2, 5)


# --- 3. Bad input -------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("args,match", [((-0.1, 0.0, 1.0, 1.0), r"quadpole_exitance\(u=-0.1\)"),
                                        ((0.1, np.nan, 1.0, 1.0), r"quadpole_exitance\(y=nan\)"),
                                        ((0.1, 0.0, -1.0, 1.0), r"quadpole_exitance\(depth=-1\)"),
                                        ((0.1, 0.0, 1.0, np.inf), r"quadpole_exitance\(offset=inf\)")])
def test_bad_input_is_rejected(args, match):
    with pytest.raises(ValueError, match=match):
        quadpole_exitance(*args, Medium(0.01, 1.0, 1.3))


def test_bad_face_and_edge_distance():
    m = Medium(0.01, 1.0, 1.3)
    with pytest.raises(ValueError, match="valid names"):
        quadpole_profile(1.0, 0.0, m, 1.0, face="bottom")
    with pytest.raises(ValueError, match=r"quadpole_profile\(edge_distance=-1\)"):
        quadpole_profile(1.0, 0.0, m, -1.0)


# --- 5. Autodiff --------------------------------------------------------------------------------------------------
def test_gradient_matches_finite_differences():
    # Two points in one scalar: a generic one, and the stiff point right above the source (u = offset, y = 0, where
    # rho_r = 0 and a plain sqrt would give 0 * inf = NaN).
    @jax.jit
    def f(p):
        m = Medium(p[0], p[1], p[2])
        return (quadpole_exitance(p[3], p[4], p[5], p[6], m)
                + quadpole_exitance(p[6], 0.0 * p[4], p[5], p[6], m))

    assert_grad_matches_fd(f, jnp.array([0.02, 1.2, 1.4, 0.6, 0.3, 0.9, 0.4]), rtol=1e-6, atol=1e-10)


def test_second_call_does_not_retrace():
    @jax.jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def f(u, m):
        return quadpole_exitance(u, 0.1, 1.0, 0.5, m)

    u = jnp.linspace(0.0, 1.0, 4)
    f(u, Medium(0.01, 1.0, 1.3))
    f(u + 1.0, Medium(0.02, 2.0, 1.4))
