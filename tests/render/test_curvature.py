"""The curvature ratio of the renderer's white kernels (jaxsss.render.curvature): reference values, shapes, bad and
extreme input, invariants (the Kelvin image's zero fluence, the planar limit), autodiff, and its effect on a render."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss import Medium
from jaxsss.render.curvature import (
    DEPTH_MIN,
    KAPPA_MAX_ZR,
    N_KAPPA,
    _sphere_exitance,
    curvature_coordinate,
    curvature_ratio,
    kappa_cap,
    log_ratio_table,
    pair_curvature,
)
from tests.gradcheck import assert_grad_matches_fd

SKIN1_A = np.array([0.032, 0.17, 0.48])
SKIN1_S = np.array([0.74, 0.88, 1.01])
# The table jitted (one program each, kept by the persistent cache): op by op, its tests compiled every primitive, 10-12
# s per test.
_jit_table = jax.jit(log_ratio_table)
_jit_ratio = jax.jit(curvature_ratio)
_jit_table_grad = jax.jit(jax.grad(lambda p, r, A, depth: jnp.sum(log_ratio_table(r, p[:1], p[1:], A, depth))))


def _A(eta):
    return np.asarray(Medium(SKIN1_A, SKIN1_S, eta=eta).A)


def _image_fluence(rho, cos_t, a, z_r, z_b, s):
    """Fluence (up to a constant) of the real source and its image at Kelvin's point at radius ``rho``, angle
    ``cos_t``, the image's strength matched on the extrapolated sphere at that angle (the direct, unstable form)."""
    b = a - z_r
    a_e = a + z_b
    bi = a_e**2 / b

    def dist(r, c):
        return np.sqrt(r**2 + c**2 - 2 * r * c * cos_t)

    q = (dist(a_e, bi) / dist(a_e, b)) * np.exp(-s * (dist(a_e, b) - dist(a_e, bi)))
    return np.exp(-s * dist(rho, b)) / dist(rho, b) - q * np.exp(-s * dist(rho, bi)) / dist(rho, bi)


def _shell_ratio(sa, ss, A, a):
    """Exact diffusion: total exitance of a uniformly lit sphere of radius ``a`` (a shell of sources ``z_r`` deep,
    zero fluence at ``a + z_b``) over the half-space's (Jensen et al. 2001's total diffuse reflectance)."""
    st = sa + ss
    D, s, z_r, z_b, ap = 1 / (3 * st), np.sqrt(3 * sa * st), 1 / st, 2 * A / (3 * st), ss / st
    b, a_e = a - z_r, a + z_b
    f1, f1p = np.sinh(s * b) / b, (s * np.cosh(s * b) * b - np.sinh(s * b)) / b**2
    f2b = np.sinh(s * (a_e - b)) / b
    f2pb = (-s * np.cosh(s * (a_e - b)) * b - np.sinh(s * (a_e - b))) / b**2
    f2pa = (-s * np.cosh(s * (a_e - a)) * a - np.sinh(s * (a_e - a))) / a**2
    amp = ap * a**2 / b**2 / (D * (f2b * f1p / f1 - f2pb))
    x = np.sqrt(3 * (1 - ap))
    return -D * amp * f2pa / (ap / 2 * (1 + np.exp(-4 / 3 * A * x)) * np.exp(-x))


def test_reference_values_skin1_on_the_20mm_sphere():
    """Against the direct (unstable) form ``a^2 + c^2 - 2 a c cos t`` of the same sources (docs/path_tracer.md,
    "Curvature")."""
    r = curvature_ratio(np.array([1.0, 4.0])[:, None], 1 / 20, SKIN1_A, SKIN1_S, _A(1.4))
    np.testing.assert_allclose(r, [[1.0571, 1.0709, 1.0866], [1.3028, 1.4281, 1.5558]], atol=2e-4)
    r1 = curvature_ratio(4.0, 1 / 20, SKIN1_A, SKIN1_S, _A(1.0))
    np.testing.assert_allclose(r1, [1.1357, 1.1819, 1.2205], atol=2e-4)


@pytest.mark.parametrize("eta, a", [(1.0, 20.0), (1.4, 20.0), (1.4, 80.0), (1.0, 80.0)])
def test_uniformly_lit_sphere_matches_the_exact_diffusion_solution(eta, a):
    """Reference: the exact diffusion solution of a uniformly lit sphere (a radially symmetric shell source). The
    per-pair ratio times the planar dipole, integrated over the sphere, is within 2.5% of it (the image is exact only
    at the pair's own angle)."""
    from jaxsss.profiles.dipole import dipole_profile

    medium = Medium(SKIN1_A, SKIN1_S, eta=eta)
    theta = np.linspace(1e-6, np.pi, 20001)[:, None]
    chord = 2 * a * np.sin(theta / 2)
    # The surface is uniformly lit: sum over sources = integral over the sphere around one point.
    plane = np.asarray(dipole_profile(chord, medium))
    curved = plane * np.asarray(curvature_ratio(chord, 1 / a, SKIN1_A, SKIN1_S, medium.A))
    w = 2 * np.pi * a**2 * np.sin(theta)
    ours = np.trapezoid(curved * w, theta[:, 0], axis=0) / np.trapezoid(plane * w, theta[:, 0], axis=0)
    exact = _shell_ratio(SKIN1_A, SKIN1_S, np.asarray(medium.A), a)
    np.testing.assert_allclose(ours, exact, rtol=0.025)
    assert np.all(ours > 1.0)


def test_the_image_cancels_the_fluence_on_the_extrapolated_sphere():
    """The image's strength is matched so that the fluence vanishes on the extrapolated sphere at the pair's angle
    (for any absorption; Kelvin's -a_e / b at every angle without absorption)."""
    a, z_r, z_b = 20.0, 1.0, 0.7
    cos_t = np.cos(np.linspace(0.0, np.pi, 50))
    for s in (0.0, 0.3):
        phi = _image_fluence(a + z_b, cos_t, a, z_r, z_b, s)
        assert np.max(np.abs(phi)) < 1e-12 / z_r
    # ... and the stable form used by the kernel is the radial derivative of that fluence at the surface.
    s, d = 0.3, np.array([0.5, 3.0, 12.0])
    cos_d = 1 - 0.5 * (d / a) ** 2
    h = 1e-6
    flux = -(_image_fluence(a + h, cos_d, a, z_r, z_b, s) - _image_fluence(a - h, cos_d, a, z_r, z_b, s)) / (2 * h)
    ref = np.exp(-s * np.sqrt(z_r**2 + d**2))
    np.testing.assert_allclose(np.asarray(_sphere_exitance(d, 1 / a, z_r, z_b, s)) * ref, flux, rtol=1e-6)


@pytest.mark.parametrize("depth", [1.0, 0.5, 0.1])
def test_an_oblique_source_against_the_direct_form(depth):
    """Ketchup's red channel (l_u = 4.1 mm) on a 30 mm sphere (7.2 l_u: under the cap ``KAPPA_MAX_ZR``), its source
    ``depth l_u`` deep: the ratio equals the radial flux of the direct (unstable) form of the same source and image
    over the planar dipole's (Jensen et al. 2001 Eq. 4, written out here) with the source at that depth."""
    sa, ss, a = 0.061, 0.18, 30.0
    assert 1 / a < KAPPA_MAX_ZR * (sa + ss)
    st = sa + ss
    z_r, z_b, s = depth / st, 2 / (3 * st), np.sqrt(3 * sa * st)
    d = np.array([0.7, 3.0, 9.0, 20.0])
    cos_d = 1 - 0.5 * (d / a) ** 2
    h = 1e-6
    flux = -(_image_fluence(a + h, cos_d, a, z_r, z_b, s) - _image_fluence(a - h, cos_d, a, z_r, z_b, s)) / (2 * h)
    z_v = z_r + 2 * z_b
    dr, dv = np.sqrt(z_r**2 + d**2), np.sqrt(z_v**2 + d**2)
    plane = z_r * (1 + s * dr) * np.exp(-s * dr) / dr**3 + z_v * (1 + s * dv) * np.exp(-s * dv) / dv**3
    np.testing.assert_allclose(curvature_ratio(d, 1 / a, sa, ss, 1.0, depth), flux / plane, rtol=1e-5)


def test_depth_is_clipped_to_its_range():
    d = np.array([1e-6, 0.5, 5.0, 40.0])
    np.testing.assert_array_equal(curvature_ratio(d, 0.05, 0.061, 0.18, 1.0, 0.0),
                                  curvature_ratio(d, 0.05, 0.061, 0.18, 1.0, DEPTH_MIN))
    np.testing.assert_array_equal(curvature_ratio(d, 0.05, 0.061, 0.18, 1.0, 3.0),
                                  curvature_ratio(d, 0.05, 0.061, 0.18, 1.0))
    val = np.asarray(curvature_ratio(d, 0.05, 0.061, 0.18, 1.0, DEPTH_MIN))
    assert np.all(np.isfinite(val)) and np.all(val >= 0)


def test_planar_limit_and_near_the_source():
    d = np.geomspace(1e-3, 50.0, 40)
    np.testing.assert_array_equal(curvature_ratio(d, 0.0, 0.1, 1.0, 2.0), np.ones_like(d))
    # A gentle curvature (a = 1 m) is nearly the plane, and the plane is its limit.
    r3 = np.asarray(curvature_ratio(d, 1e-3, 0.1, 1.0, 2.0))
    r4 = np.asarray(curvature_ratio(d, 1e-4, 0.1, 1.0, 2.0))
    near = d <= 10.0  # about linear in kappa there
    assert np.all(np.abs(r3[near] - 1.0) < 1e-2)
    assert np.max(np.abs(r4[near] - 1.0)) < 0.2 * np.max(np.abs(r3[near] - 1.0))


def test_pair_curvature_is_exact_on_a_sphere_and_zero_on_a_plane():
    rng = np.random.default_rng(0)
    v = rng.normal(size=(2, 100, 3))
    n = v / np.linalg.norm(v, axis=-1, keepdims=True)
    a = 7.5
    k = pair_curvature(a * (n[0] - n[1]), n[0], n[1])
    np.testing.assert_allclose(k, 1 / a, rtol=1e-12)
    # Inside of the same sphere (normals pointing in): concave, -1/a.
    np.testing.assert_allclose(pair_curvature(a * (n[0] - n[1]), -n[0], -n[1]), -1 / a, rtol=1e-12)
    up = np.broadcast_to([0.0, 0.0, 1.0], (100, 3))
    flat = rng.normal(size=(100, 3)) * [1, 1, 0]
    np.testing.assert_array_equal(pair_curvature(flat, up, up), 0.0)
    assert float(pair_curvature(np.zeros(3), up[0], up[0])) == 0.0  # coincident points


def test_shapes_broadcast():
    d = np.linspace(0.1, 5.0, 7)[:, None, None]
    kappa = np.array([0.0, 0.05])[None, :, None]
    out = curvature_ratio(d, kappa, SKIN1_A, SKIN1_S, _A(1.3))
    assert out.shape == (7, 2, 3)
    assert pair_curvature(np.ones((4, 5, 3)), np.ones((4, 5, 3)), np.zeros((4, 5, 3))).shape == (4, 5)


def test_concave_and_extreme_curvature_are_clipped():
    """Concave pairs get no correction; a sphere tighter than 4 z_r, or a chord longer than its diameter, is held
    at the limit."""
    d = np.array([0.5, 2.0, 8.0])
    np.testing.assert_array_equal(curvature_ratio(d, -0.3, 0.1, 1.0, 2.0), 1.0)
    z_r = 1 / 1.1
    at_limit = curvature_ratio(d, KAPPA_MAX_ZR / z_r, 0.1, 1.0, 2.0)
    np.testing.assert_array_equal(curvature_ratio(d, 1e6, 0.1, 1.0, 2.0), at_limit)
    np.testing.assert_array_equal(curvature_ratio(3.0, 5.0, 0.1, 1.0, 2.0), curvature_ratio(3.0, 2 / 3, 0.1, 1.0, 2.0))


@pytest.mark.parametrize("sa, ss, A", [(0.0, 1.0, 1.0), (1e-9, 1e4, 3.0), (1e3, 1e-3, 1.0), (0.5, 1e-6, 9.0),
                                       (1e-4, 1e-4, 2.0)])
def test_stability_matrix_finite(sa, ss, A):
    d = np.geomspace(1e-6, 1e3, 30)
    z_r = 1 / (sa + ss)
    for kappa in (0.0, 1e-3 / z_r, 0.1 / z_r, 10.0):
        val = np.asarray(curvature_ratio(d, kappa, sa, ss, A))
        assert np.all(np.isfinite(val)) and np.all(val >= 0), (kappa, val)
        g = jax.grad(lambda p: jnp.sum(curvature_ratio(d, kappa, p[0], p[1], A)))(jnp.array([sa, ss]))
        assert np.all(np.isfinite(np.asarray(g))), (kappa, g)


def test_gradients_match_finite_differences():
    def f(p):
        return jnp.sum(curvature_ratio(jnp.array([0.5, 3.0, 9.0]), 1 / 15, p[0], p[1], p[2]) ** 2)

    assert_grad_matches_fd(f, np.array([0.05, 1.2, 2.5]), rtol=1e-6)

    def g(p):  # a shallow (oblique) source
        return jnp.sum(curvature_ratio(jnp.array([0.5, 3.0, 9.0]), 1 / 15, p[0], p[1], p[2], 0.3) ** 2)

    assert_grad_matches_fd(g, np.array([0.05, 1.2, 2.5]), rtol=1e-6)


def test_the_table_holds_the_ratio_at_its_nodes():
    """``log_ratio_table`` is ``log C`` at ``(r_g, u_j kappa_cap(r_g))``, 0 at ``j = 0`` (the flat profile), and the
    curvature coordinate of a node's curvature is its index; shapes ``(K, G, N_KAPPA, C)``."""
    r = np.geomspace(0.01, 40.0, 23)[:, None] * np.array([1.0, 1.3, 0.7])  # (G, C)
    depth = np.array([[1.0, 1.0, 1.0], [0.5, 0.5, 0.5], [0.1, 0.2, 0.3]])
    A = _A(1.4)
    table = np.asarray(_jit_table(jnp.asarray(r), SKIN1_A, SKIN1_S, A, jnp.asarray(depth)))
    assert table.shape == (3, 23, N_KAPPA, 3)
    np.testing.assert_array_equal(table[:, :, 0], 0.0)
    j = np.arange(N_KAPPA)
    u = 1 - (1 - j / (N_KAPPA - 1)) ** 2
    kappa = u[:, None] * np.asarray(kappa_cap(r, SKIN1_A + SKIN1_S))[:, None, :]  # (G, N, C)
    for k in range(3):
        direct = np.asarray(_jit_ratio(r[:, None, :], kappa, SKIN1_A, SKIN1_S, A, depth[k]))
        np.testing.assert_allclose(table[k], np.log(direct), atol=1e-12)
    np.testing.assert_allclose(curvature_coordinate(kappa, r[:, None, :], SKIN1_A + SKIN1_S),
                               np.broadcast_to(j[:, None], kappa.shape), atol=1e-9)
    # Concave pairs sit at the flat node, curvatures beyond the cap at the last.
    assert float(curvature_coordinate(-0.2, 3.0, 1.0)) == 0.0
    assert float(curvature_coordinate(5.0, 3.0, 1.0)) == N_KAPPA - 1
    # At and beyond the cap the coordinate's derivative is 0, not NaN (sqrt(1 - u) at u = 1).
    for kappa in (0.25, 5.0):
        assert float(jax.grad(lambda st: curvature_coordinate(kappa, 3.0, st))(1.0)) == 0.0


@pytest.mark.parametrize("sa, ss, A", [(0.0, 1.0, 1.0), (1e-9, 1e4, 3.0), (1e3, 1e-3, 1.0), (1e-4, 1e-4, 2.0)])
def test_the_table_is_finite_for_extreme_media(sa, ss, A):
    r = jnp.asarray(np.geomspace(1e-6, 1e3, 30)[:, None])
    depth = jnp.array([[1.0], [0.1]])
    table = np.asarray(_jit_table(r, jnp.array([sa]), jnp.array([ss]), jnp.array([A]), depth))
    assert np.all(np.isfinite(table)), table
    g = _jit_table_grad(jnp.array([sa, ss]), r, jnp.array([A]), depth)
    assert np.all(np.isfinite(np.asarray(g))), g


@pytest.fixture(scope="module")
def sphere_prepared():
    from jaxsss.render import load_scene, prepare
    from pathlib import Path

    scene = load_scene(Path(__file__).parents[1] / "export" / "references" / "skin1_sphere.toml")
    return scene, prepare(scene, method="hierarchical", resolution=(24, 24), bssrdf="white-oblique")


def test_a_convex_object_gets_brighter_and_a_flat_kernel_is_unchanged(sphere_prepared):
    """The curvature correction adds light on the sphere; without normals the kernel is the half-space's."""
    scene, prepared = sphere_prepared
    state = prepared[0]  # (prepared, plan, info)
    medium = scene.material.medium
    curved = np.asarray(state.image(medium))
    flat_state = eqx.tree_at(lambda p: p.ent_normal, state, None)
    flat = np.asarray(flat_state.image(medium))
    ratio = curved.sum(axis=(0, 1)) / flat.sum(axis=(0, 1))
    # Against Mitsuba the sums moved from 0.966 / 0.991 / 1.008 to 1.021 / 1.026 / 1.024.
    assert np.all(ratio > 1.005) and np.all(ratio < 1.06), ratio
    assert ratio[0] > ratio[2]  # the most diffusive channel (R, longest l_d) gains most
