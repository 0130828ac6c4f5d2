"""Eq. 15 blending and the point-source dipole/multipole it uses: limits, general geometry, shapes, bad input,
gradients."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.medium import Medium
from jaxsss.profiles import (
    blend_profiles,
    blend_weights,
    blended_exitance,
    dipole_exitance,
    dipole_profile,
    multipole_exitance,
    multipole_profile,
    quadpole_exitance,
)
from jaxsss.profiles._sources import point_source_exitance
from tests.gradcheck import assert_grad_matches_fd

M = Medium([0.01, 0.05], [1.0, 2.0], 1.3)
UP = np.array([0.0, 0.0, 1.0])


def rotation(seed):
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q * np.linalg.det(q)  # a proper rotation


# --- Eq. 15 weights -----------------------------------------------------------------------------------------------
def test_weights_limits_sum_and_linearity():
    g = jnp.array([0.0, np.pi / 4, np.pi / 2, 3 * np.pi / 4, np.pi])
    w_d, w_q, w_m = (np.asarray(a) for a in blend_weights(g))
    np.testing.assert_allclose(w_d, [1, 0.5, 0, 0, 0], atol=1e-15)
    np.testing.assert_allclose(w_q, [0, 0.5, 1, 0.5, 0], atol=1e-15)
    np.testing.assert_allclose(w_m, [0, 0, 0, 0.5, 1], atol=1e-15)
    np.testing.assert_allclose(w_d + w_q + w_m, 1.0, rtol=1e-15)
    assert float(blend_profiles(np.pi / 4, 2.0, 4.0, 100.0)) == pytest.approx(3.0, rel=1e-15)


@pytest.mark.parametrize("gamma", [-1e-3, np.pi + 1e-3, np.nan])
def test_bad_gamma_is_rejected(gamma):
    with pytest.raises(ValueError, match=r"blend_weights\(gamma="):
        blend_weights(gamma)


# --- Point sources ------------------------------------------------------------------------------------------------
def test_point_sources_reproduce_the_classic_profiles():
    m = Medium(0.02, 1.5, 1.4)
    r = jnp.linspace(0.0, 6.0, 7)
    np.testing.assert_allclose(m.alpha_prime * dipole_exitance(r, m.l_u, m), dipole_profile(r, m), rtol=1e-14)
    R, _ = multipole_profile(r, m, 2.5, n_pairs=12)
    np.testing.assert_allclose(m.alpha_prime * multipole_exitance(r, m.l_u, m, 2.5, n_pairs=12), R, rtol=1e-13)
    np.testing.assert_allclose(multipole_exitance(r, 0.7, m, 2.5, n_pairs=0), dipole_exitance(r, 0.7, m),
                               rtol=1e-15)
    # d -> infinity gives the dipole (trap 4).
    np.testing.assert_allclose(multipole_exitance(r, 0.7, m, 1e3 * float(m.l_d), n_pairs=4),
                               dipole_exitance(r, 0.7, m), rtol=1e-12)


def test_multipole_source_depth_and_the_opposite_face_agree():
    # A source at depth ell of a slab d, seen from the far face, is the source at depth d - ell seen from the near
    # face: the multipole transmittance of multipole_profile with its source moved to ell.
    m = Medium(0.02, 1.0, 1.3)
    r, d = jnp.linspace(0.0, 3.0, 4), 2.0
    T = multipole_profile(r, m, d, n_pairs=20)[1]
    np.testing.assert_allclose(m.alpha_prime * multipole_exitance(r, d - m.l_u, m, d, n_pairs=20), T, rtol=1e-12)


@pytest.mark.parametrize("args,match", [((-1.0, 0.5, 1.0), r"multipole_exitance\(r=-1\)"),
                                        ((1.0, -0.5, 1.0), r"multipole_exitance\(depth=-0.5\)"),
                                        ((1.0, 0.5, np.inf), r"thickness=inf"),
                                        ((1.0, 0.5, 0.0), r"multipole_exitance\(thickness=0\)")])
def test_point_source_bad_input(args, match):
    with pytest.raises(ValueError, match=match):
        multipole_exitance(args[0], args[1], M, args[2])
    with pytest.raises(ValueError, match=r"dipole_exitance\(depth=-1\)"):
        dipole_exitance(1.0, -1.0, M)


# --- Blending limits in 3-D geometry ------------------------------------------------------------------------------
def test_gamma_zero_is_the_dipole():
    # Flat top face (outward +z, medium below): a source 0.7 mm deep, shading points on the face.
    src = np.array([0.3, 0.1, -0.7])
    xo = np.array([[1.0, -0.5, 0.0], [0.3, 0.1, 0.0], [-4.0, 2.0, 0.0]])
    got = blended_exitance(xo, UP, src, UP, 0.7, M)
    rho = np.hypot(xo[:, 0] - 0.3, xo[:, 1] - 0.1)[:, None]
    np.testing.assert_allclose(got, dipole_exitance(rho, 0.7, M), rtol=1e-13)


@pytest.mark.parametrize("seed", [0, 1])
def test_gamma_half_pi_is_the_quadpole_in_any_frame(seed):
    # Box edge along y: top face z = 0 (outward +z), side face x = 0 (outward -x), medium x > 0, z < 0. The source is
    # a = 0.4 mm from the side face and 0.7 mm deep; shading points on the side face at depth z. The whole scene is
    # rotated: the result must not change.
    Q = rotation(seed)
    a, ell = 0.4, 0.7
    src = np.array([a, 0.1, -ell])
    z = np.array([0.0, 0.5, 1.2, 4.0])
    y = np.array([0.0, -0.5, 0.3, 1.0])
    xo = np.stack([np.zeros(4), y, -z], axis=-1)
    side = np.array([-1.0, 0.0, 0.0])
    got = blended_exitance(xo @ Q.T, side @ Q.T, src @ Q.T, UP @ Q.T, ell, M)
    expected = quadpole_exitance(z[:, None], (y - 0.1)[:, None], a, ell, M)
    np.testing.assert_allclose(got, expected, rtol=1e-12)


def test_gamma_pi_is_the_multipole_with_the_summed_thickness():
    # Slab: source 0.6 mm below the top face; shading point on the bottom face 2.0 mm down (view depth 1.4 mm):
    # thickness = 0.6 + 1.4 = 2.0 mm.
    src = np.array([0.0, 0.0, -0.6])
    xo = np.array([[0.5, 0.2, -2.0], [3.0, 0.0, -2.0]])
    got = blended_exitance(xo, -UP, src, UP, 0.6, M, n_pairs=10)
    rho = np.hypot(xo[:, 0], xo[:, 1])[:, None]
    np.testing.assert_allclose(got, multipole_exitance(rho, 1.4, M, 2.0, n_pairs=10), rtol=1e-13)


def test_intermediate_angle_matches_explicit_images():
    # gamma = 60 degrees: the view plane is tilted. Reference: the view-plane dipoles of the source and of its image
    # in the extrapolated incidence boundary built explicitly in 3-D, blended with weights 1/3 and 2/3.
    m = Medium(0.02, 1.0, 1.4)
    n_i = UP
    n_o = np.array([np.sin(np.pi / 3), 0.0, np.cos(np.pi / 3)])
    ell = 0.5
    src = np.array([-0.2, 0.3, -ell])
    xo = np.array([1.5, -0.4, 0.0]) - 0.3 * n_o  # some point; its plane has normal n_o
    z_b, s_tr = float(m.z_b), float(m.sigma_tr)

    def view_dipole(p):
        v = p - xo
        h = -v @ n_o
        rho = np.linalg.norm(v + h * n_o)
        return float(point_source_exitance(h, rho, s_tr) + point_source_exitance(h + 2 * z_b, rho, s_tr))

    image = src + 2 * (ell + z_b) * n_i
    R_d = view_dipole(src)
    R_q = R_d - view_dipole(image)
    expected = (1 / 3) * R_d + (2 / 3) * R_q
    assert float(blended_exitance(xo, n_o, src, n_i, ell, m)) == pytest.approx(expected, rel=1e-12)


def test_normals_are_normalised_and_the_blend_is_continuous():
    src = np.array([0.3, 0.0, -0.7])
    xo = np.array([1.5, 0.0, 0.0])
    a = blended_exitance(xo, 3.0 * UP, src, 0.5 * UP, 0.7, M)
    np.testing.assert_allclose(a, blended_exitance(xo, UP, src, UP, 0.7, M), rtol=1e-15)
    # Tilting the view normal through pi/2 changes the result continuously.
    t = np.pi / 2 + np.array([-1e-7, 1e-7])
    n_o = np.stack([-np.sin(t), np.zeros(2), np.cos(t)], axis=-1)
    v = np.asarray(blended_exitance(xo, n_o, src, UP, 0.7, M))
    np.testing.assert_allclose(v[0], v[1], rtol=1e-5)


# --- Shapes -------------------------------------------------------------------------------------------------------
def test_shapes_batch_then_channels():
    src = np.array([0.3, 0.0, -0.7])
    xo = np.zeros((4, 5, 3)) + np.array([1.0, 0.0, 0.0])
    assert blended_exitance(xo, UP, src, UP, 0.7, M).shape == (4, 5, 2)
    m1 = Medium(0.01, 1.0, 1.3)
    one = blended_exitance(xo, UP, src, UP, 0.7, m1)
    assert one.shape == (4, 5)
    np.testing.assert_allclose(one, blended_exitance(xo, UP, src, UP, 0.7, M)[..., 0], rtol=1e-15)
    depths = jnp.array([0.5, 0.7, 0.9, 1.1, 1.3])  # broadcasts against the batch
    assert blended_exitance(xo, UP, src, UP, depths, M).shape == (4, 5, 2)


@pytest.mark.parametrize("kwargs,match", [
    (dict(n_o=np.zeros(3)), r"blended_exitance\(n_o=...\): a normal of zero"),
    (dict(source_normal=np.ones(2)), r"source_normal=array of shape \(2,\)"),
    (dict(source_depth=-0.1), r"blended_exitance\(source_depth=-0.1\)"),
    (dict(x_o=np.array([np.nan, 0.0, 0.0])), r"blended_exitance\(x_o=nan\)"),
    (dict(n_pairs=-1), r"blended_exitance\(n_pairs=-1\)"),
])
def test_bad_input_is_rejected(kwargs, match):
    args = dict(x_o=np.array([1.0, 0.0, 0.0]), n_o=UP, source=np.array([0.0, 0.0, -0.5]), source_normal=UP,
                source_depth=0.5, medium=M) | kwargs
    with pytest.raises(ValueError, match=match):
        blended_exitance(**args)


# --- Autodiff -----------------------------------------------------------------------------------------------------
def test_gradient_matches_finite_differences():
    # An intermediate angle (all three models' pieces) in the medium and the source position.
    n_o = np.array([np.sin(2.0), 0.0, np.cos(2.0)])

    @jax.jit
    def f(p):
        src = jnp.stack([p[3], 0.2, -p[4]])
        return blended_exitance(jnp.array([1.0, 0.0, -2.0]), n_o, src, UP, p[4], Medium(p[0], p[1], p[2]),
                                n_pairs=4)

    assert_grad_matches_fd(f, jnp.array([0.02, 1.2, 1.4, 0.3, 0.6]), rtol=1e-6, atol=1e-11)


def test_second_call_does_not_retrace():
    @jax.jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def f(xo, m):
        return blended_exitance(xo, UP, jnp.array([0.0, 0.0, -0.5]), UP, 0.5, m)

    f(jnp.array([1.0, 0.0, 0.0]), Medium(0.01, 1.0, 1.3))
    f(jnp.array([2.0, 1.0, 0.0]), Medium(0.02, 2.0, 1.4))
