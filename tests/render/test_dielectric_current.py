"""The exit's current behind a dielectric boundary (jaxsss.render.dielectric_current): the table against a fresh Fresnel
walk, shapes and the interpolation in eta, bad input, invariants (weaker behind a denser boundary, symmetric pairs
cancel, both signs kept and never below 0), autodiff, and the renderer's current against a walk on a point-lit
sphere."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.medium import Medium
from jaxsss.render.bssrdf import (
    current_radiance,
    exit_weights,
    row_parts,
    white_kernel,
    white_tables,
)
from jaxsss.render.dielectric_correction import DIELECTRIC_ETAS, DIELECTRIC_MUS
from jaxsss.render.dielectric_current import _fit, load_dielectric_current_table, main
from jaxsss.render.exit_current import (
    CURRENT_ALBEDO,
    CURRENT_D,
    _tally,
    current_amplitude,
    current_exit_distribution,
)
from tests.gradcheck import assert_grad_matches_fd
from tests.render.kernel_calls import kernel_pair, kernel_sources
from tests.render.test_exit_current import _mean_flow
from tests.render.test_exit_curvature import sphere_pairs

_amplitude = jax.jit(current_amplitude)
_exit = jax.jit(current_exit_distribution, static_argnums=1)


def test_the_table_against_a_fresh_walk():
    """Reference: a fresh Fresnel walk on the half-space (another seed, 20000 photons, eta 1.4, albedo 0.9, normal
    incidence): its light leaves along the flow, mean ``e . u`` 0.1-0.3 at 1-4 transport lengths (below the
    index-matched orders >= 2's 0.2-0.4: internal reflection turns the light back), and the shipped tallies agree
    within 0.04; refitted from its own tallies the table is the shipped one (to rounding)."""
    table = load_dielectric_current_table()
    e, j = DIELECTRIC_ETAS.index(1.4), CURRENT_ALBEDO.index(0.9)
    fresh = _tally(0.9, 1.0, 20_000, seed=11, eta=1.4)
    flow = _mean_flow(fresh, 1.0, 4.0)
    assert 0.1 < flow < 0.3
    assert _mean_flow(table["tallies"][e, DIELECTRIC_MUS.index(1.0), j], 1.0, 4.0) == pytest.approx(flow, abs=0.04)
    refit = _fit(table["tallies"], tuple(table["mus"]))
    # Equal to rounding: another CPU's vector units sum in another order (5e-15 relative on a new machine).
    np.testing.assert_allclose(refit["ab"], table["ab"], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(refit["psi"], table["psi"], rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(table["eta"], DIELECTRIC_ETAS)
    # The amplitude at albedo 0.9: 0.25-0.7 from 1 to 10 transport lengths.
    a = np.asarray(_amplitude(jnp.array([0.9]), 1.4))[:, 0]
    far = (np.asarray(CURRENT_D) > 1.0) & (np.asarray(CURRENT_D) < 11.0)
    assert np.all((a[far] > 0.25) & (a[far] < 0.7)), a


def test_shapes_interpolation_in_eta_and_bad_input():
    albedo = jnp.array([0.2, 0.9, 0.999])
    a = _amplitude(albedo, 1.4)
    assert a.shape == (len(CURRENT_D), 3) and np.all(np.isfinite(np.asarray(a)))
    # Linear in eta between the nodes, held beyond them.
    mid = 0.5 * (np.asarray(_amplitude(albedo, 1.3)) + np.asarray(_amplitude(albedo, 1.4)))
    np.testing.assert_allclose(np.asarray(_amplitude(albedo, 1.35)), mid, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(_amplitude(albedo, 1.05)), np.asarray(_amplitude(albedo, 1.1)))
    np.testing.assert_allclose(np.asarray(_amplitude(albedo, 2.0)), np.asarray(_amplitude(albedo, 1.6)))
    y = _exit(jnp.array([0.0, 0.5, 1.0]), (1.0, 0.5, 0.1), jnp.array([0.5, 0.99]), 1.4)
    assert y.shape == (3, 3, 2) and np.all(np.isfinite(np.asarray(y)))
    mus, sources = white_tables(0.0, 1.4, True)
    medium = Medium(sigma_a=jnp.array([0.015]), sigma_s_prime=jnp.array([0.15]), eta=1.4)
    with pytest.raises(ValueError, match=r"exit_current=True\) needs .* one exit"):
        white_kernel(medium, sources, mus, shift=True, exit_split=True, exit_current=True)
    with pytest.raises(ValueError, match="needs view_tangent"):
        exit_weights(medium, jnp.array([0.5]), mus, "refracted-current", 4 * len(mus), 1)
    with pytest.raises(ValueError, match="mus"):
        _exit(jnp.array([0.5]), (1.0, 0.3), jnp.array([0.9]), 1.4)


def test_extreme_albedo_eta_and_exit_stay_finite():
    """Stability: albedos at and beyond the table's ends, the smallest and largest relative indices, grazing and
    normal exits."""
    for eta in (1.0001, 1.6, 3.0):
        a = np.asarray(_amplitude(jnp.array([0.0, 1e-9, 1.0 - 1e-12, 1.0]), eta))
        assert np.all(np.isfinite(a))
        y = np.asarray(_exit(jnp.array([0.0, 1e-12, 1.0]), (1.0, 0.5, 0.1), jnp.array([0.0, 1.0]), eta))
        assert np.all(np.isfinite(y))


def test_the_current_weakens_behind_a_denser_boundary():
    """Invariant: internal reflection randomises the light's direction, so the amplitude at 1-10 transport lengths
    falls with eta (1.1 > 1.4 > 1.6) and lies below the index-matched orders >= 2's, at every albedo from 0.8 up."""
    far = (np.asarray(CURRENT_D) > 1.0) & (np.asarray(CURRENT_D) < 11.0)
    albedo = jnp.array([0.8, 0.9, 0.97, 0.995])
    means = [np.asarray(_amplitude(albedo, eta))[far].mean(axis=0) for eta in (1.1, 1.4, 1.6)]
    matched = np.asarray(current_amplitude(albedo))[far].mean(axis=0)
    assert np.all(matched > means[0]) and np.all(means[0] > means[1]) and np.all(means[1] > means[2]), means


@pytest.fixture(scope="module")
def kernels():
    mus, sources = white_tables(0.0, 1.4, True)
    medium = Medium(sigma_a=jnp.array([0.015, 0.1]), sigma_s_prime=jnp.array([0.15, 1.0]), eta=1.4)
    return (mus, medium, white_kernel(medium, sources, mus, shift=True, curvature=True),
            white_kernel(medium, sources, mus, shift=True, curvature=True, exit_current=True))


def test_the_kernels_rows_and_both_signs(kernels):
    """Invariants: the first K rows are the plain kernel's, the current's 3K are tangential at the shaded point;
    symmetric pairs on a plane cancel; by exit weights the pair gives the two parts of :func:`row_parts` with ``K``
    exitance rows; behind the boundary the current is kept with both signs and the radiance never goes below 0."""
    mus, _, plain, current = kernels
    k = len(mus)
    rng = np.random.default_rng(2)
    n = 8
    x, p, delta = sphere_pairs(rng, n)
    flux = jnp.asarray(rng.uniform(0.1, 1.0, size=(n, 4, k, 2)))
    normals = (jnp.asarray(x), jnp.asarray(p))
    a = np.asarray(kernel_pair(plain, delta, kernel_sources(plain, flux), normals))
    b = np.asarray(kernel_pair(current, delta, kernel_sources(current, flux), normals))
    assert b.shape == (n, 4 * k, 2) and current.rows_per_node == 4 and plain.rows_per_node == 1
    np.testing.assert_allclose(b[:, :k], a, rtol=1e-12)
    vec = b[:, k:].reshape(n, 3, k, 2)
    assert np.max(np.abs(np.einsum("nikc,ni->nkc", vec, x))) < 1e-9 * np.max(np.abs(vec))
    up = jnp.tile(jnp.array([[0.0, 0.0, 1.0]]), (2, 1))
    d = jnp.array([[3.0, 1.0, 0.0], [-3.0, -1.0, 0.0]])
    still = jnp.zeros((2, 4, k, 2)).at[:, 0].set(1.0)
    pair = np.asarray(kernel_pair(current, d, kernel_sources(current, still), (up, up)))
    np.testing.assert_allclose(pair[0, k:] + pair[1, k:], 0.0, atol=1e-12 * np.abs(pair).max())
    weights = jnp.asarray(rng.uniform(-1.0, 1.0, size=(n, 4 * k, 2)))
    packed = np.asarray(kernel_pair(current, delta, kernel_sources(current, flux), normals, weights))  # complex
    parts = np.stack([packed.real, packed.imag], axis=1)
    np.testing.assert_allclose(parts, np.asarray(row_parts(jnp.asarray(b), weights, k)), rtol=1e-10)
    np.testing.assert_array_equal(np.asarray(current.weighted_disc(3.0))[k:], 0.0)
    radiance, flow = jnp.array([[1.0, 1.0, 1.0]]), jnp.array([[0.3, -0.3, -2.0]])
    np.testing.assert_allclose(np.asarray(current_radiance(radiance, flow, along_only=False)), [[1.3, 0.7, 0.0]])
    np.testing.assert_allclose(np.asarray(current_radiance(radiance, flow)), [[1.3, 1.0, 1.0]])


def test_gradients_match_finite_differences():
    """Autodiff: the amplitude and the exit shape in the albedo, and both in eta between the table's nodes."""
    mu_o = jnp.array([0.2, 0.7, 0.95])
    assert_grad_matches_fd(lambda al: jnp.sum(current_amplitude(al[None], 1.37) ** 2), 0.93, rtol=1e-5)
    assert_grad_matches_fd(lambda et: jnp.sum(current_amplitude(jnp.array([0.93]), et) ** 2), 1.37, rtol=1e-5)
    assert_grad_matches_fd(lambda al: jnp.sum(current_exit_distribution(mu_o, (1.0, 0.5, 0.1), al[None], 1.37)),
                           0.93, rtol=1e-5, jit=True)
    assert_grad_matches_fd(lambda et: jnp.sum(current_exit_distribution(mu_o, (1.0, 0.5, 0.1), jnp.array([0.93]),
                                                                        et)), 1.37, rtol=1e-5, jit=True)


def test_the_renderers_current_against_a_walk_on_a_point_lit_sphere():
    """Reference against transport: chicken1 on the 20 mm sphere at eta 1.4 under a point light on the camera's side
    (``benchmarks/sphere_transport.py``; red, 3.3 transport lengths in radius; 50000 photons). From the terminator into
    the shadow (cosine to the light -0.3..+0.1) the walk's light leaves towards the camera 20-35% below its azimuthal
    mean (the camera looks against the flow), and the renderer's current takes off 15-25% there, within 0.1 of the
    walk; on the lit side (cosine 0.5-1) both are within 4% of 1. The benchmark's full run (1e6 photons) quotes the
    radiance that results (docs/path_tracer.md, "Behind a dielectric boundary: the exit's current")."""
    import equinox as eqx

    from benchmarks import sphere_transport as st
    from jaxsss.render import make_plan, render

    scene, radius, light, intensity = st._scene("chicken1_sphere.toml", None, None, 1.4)
    plan = make_plan(scene, bssrdf="auto")
    item = {i.name: i for i in plan.items}["exit azimuth"]
    assert item.included and "both signs" in item.reason and plan.exit_current and plan.current_lights == (True,)
    state, medium = render(scene).prepared.state, scene.material.medium
    assert state.bssrdf_exit == "refracted-current"
    # The exitance's radiance and the current's, (Q, 2, C), in one program.
    parts = np.asarray(eqx.filter_jit(lambda s, m: s.exitance(m, weights=s.exit_weights(m)))(state, medium))[..., 0]
    sa, ss = float(np.asarray(medium.sigma_a)[0]), float(np.asarray(medium.sigma_s_prime)[0])
    walk = st.sphere_walk(sa, ss, radius, light, intensity, 50_000, seed=5, min_order=1, eta=1.4)
    pos, cos_o, to_eye = (np.asarray(v) for v in (state.query_pos, state.cos_o, state.to_eye))
    factor = st.camera_factor(walk, radius, light, pos, cos_o, to_eye, parts[:, 0])
    band, inside = st.light_bands(pos, radius, light)[3:]
    for b in (2, 3, 6, 7, 8):  # cos -0.3..-0.1, -0.1..+0.1; 0.5..0.7, 0.7..0.9, 0.9..1
        sel = inside & (band == b)
        current = 1.0 + parts[sel, 1].sum() / parts[sel, 0].sum()
        if b < 6:
            assert 0.65 < factor[b] < 0.85 and 0.7 < current < 0.9, (b, factor[b], current)
        else:
            assert abs(factor[b] - 1.0) < 0.04 and abs(current - 1.0) < 0.04, (b, factor[b], current)
        assert abs(current - factor[b]) <= 0.1, (b, factor[b], current)


def test_the_cli_describes_the_table(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    assert "dielectric_current.npz" in out and "eta [1.1, 1.2, 1.3, 1.4, 1.5, 1.6]" in out
