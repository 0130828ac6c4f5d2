"""The exit's current (jaxsss.render.exit_current): the table against a fresh walk, shapes, bad input, invariants
(symmetric pairs cancel, the exitance rows are the curved kernel's, the current is added along the flow only) and
autodiff."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.medium import Medium
from jaxsss.render.bssrdf import (current_radiance, exit_radiance_nodes, exit_weights, row_parts, white_kernel,
                                  white_tables)
from jaxsss.render.exit_current import (CURRENT_ALBEDO, CURRENT_D, CURRENT_D_EDGES, CURRENT_MUS, _tally,
                                        current_amplitude, current_amplitude_at, current_exit_distribution,
                                        fit_exit_current, load_exit_current_table, tangential_unit)
from tests.gradcheck import assert_grad_matches_fd
from tests.render.kernel_calls import kernel_pair, kernel_sources
from tests.render.test_exit_curvature import sphere_pairs

_amplitude = jax.jit(current_amplitude)
_exit = jax.jit(current_exit_distribution, static_argnums=1)


def _mean_flow(tallies, lo: float, hi: float) -> float:
    """The light-weighted mean of ``e . u`` (the exit's tangential direction along the flow away from the entry)
    between ``lo`` and ``hi`` transport lengths from the entry, from :func:`_tally`'s ``(4, D, B)``."""
    sel = (CURRENT_D_EDGES[:-1] >= lo) & (CURRENT_D_EDGES[1:] <= hi)
    return float(tallies[1, sel].sum() / tallies[0, sel].sum())


def test_the_table_against_a_fresh_walk():
    """Reference: a fresh half-space walk (another seed, 20000 photons, albedo 0.9, normal incidence): its light
    leaves along the flow, mean ``e . u`` 0.2-0.4 at 1-4 transport lengths, and the shipped table's tallies agree
    within 0.05; the rank-1 fit ``a(d) psi(mu_o)`` gives back the tallies' mean (``<e . u> = a psi / 2``) within 15%."""
    table = load_exit_current_table()
    j = CURRENT_ALBEDO.index(0.9)
    fresh = _tally(0.9, 1.0, 20_000, seed=11)
    shipped = table["tallies"][CURRENT_MUS.index(1.0), j]
    flow = _mean_flow(fresh, 1.0, 4.0)
    assert 0.2 < flow < 0.4
    assert _mean_flow(shipped, 1.0, 4.0) == pytest.approx(flow, abs=0.05)
    ab, psi = fit_exit_current(table["tallies"])
    sel = (CURRENT_D_EDGES[:-1] >= 1.0) & (CURRENT_D_EDGES[1:] <= 4.0)
    light = shipped[0, sel]
    model = np.sum(light * ab[0, j, sel, 0][:, None] * psi[0, j][None, :]) / 2.0 / light.sum()
    assert model == pytest.approx(_mean_flow(shipped, 1.0, 4.0), rel=0.15)
    np.testing.assert_allclose(ab, table["ab"], atol=1e-12)
    np.testing.assert_allclose(psi, table["psi"], atol=1e-12)
    # The amplitude at albedo 0.9: 0.8-1 out to 10 transport lengths (the tallies' light ends there).
    a = np.asarray(_amplitude(jnp.array([0.9])))[:, 0]
    assert np.all((a[:11] > 0.7) & (a[:11] < 1.1))


def test_shapes_and_bad_input():
    a = _amplitude(jnp.array([0.2, 0.9, 0.999]))
    assert a.shape == (len(CURRENT_D), 3) and np.all(np.isfinite(np.asarray(a)))
    d = jnp.array([0.0, 0.3, 5.0, 1e6])[:, None, None] * jnp.ones((1, 2, 3))
    assert current_amplitude_at(a, d).shape == (4, 2, 3)
    # Held beyond the last node.
    np.testing.assert_allclose(np.asarray(current_amplitude_at(a, d))[-1, 0], np.asarray(a)[-1])
    y = _exit(jnp.array([0.0, 0.5, 1.0]), (1.0, 0.5, 0.1), jnp.array([0.5, 0.99]))
    assert y.shape == (3, 3, 2) and np.all(np.isfinite(np.asarray(y)))
    t = tangential_unit(jnp.array([[1.0, 0.0, 1.0], [0.0, 0.0, 2.0]]), jnp.array([[0.0, 0.0, 1.0]] * 2))
    np.testing.assert_allclose(np.asarray(t), [[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]], atol=1e-15)
    mus, sources = white_tables(0.0, 1.0, True)
    medium = Medium(sigma_a=jnp.array([0.015]), sigma_s_prime=jnp.array([0.15]), eta=1.0)
    with pytest.raises(ValueError, match=r"exit_current=True\) needs exit_curved=True"):
        white_kernel(medium, sources, mus, shift=True, first_order=True, exit_current=True)
    with pytest.raises(ValueError, match="needs view_tangent"):
        exit_weights(medium, jnp.array([0.5]), mus, "multiple-current", 5 * len(mus), 1)


def test_extreme_albedo_and_distance_stay_finite():
    """Stability: albedos at and beyond the table's ends (held), distances 0 and 1e6 transport lengths, grazing and
    normal exits."""
    a = _amplitude(jnp.array([0.0, 1e-9, 1.0 - 1e-12, 1.0]))
    assert np.all(np.isfinite(np.asarray(a)))
    np.testing.assert_allclose(np.asarray(a)[:, 0], np.asarray(a)[:, 1])
    np.testing.assert_allclose(np.asarray(a)[:, 2], np.asarray(a)[:, 3])
    y = _exit(jnp.array([0.0, 1e-12, 1.0]), (1.0, 0.5, 0.1), jnp.array([0.0, 1.0]))
    assert np.all(np.isfinite(np.asarray(y)))


@pytest.fixture(scope="module")
def kernels():
    mus, sources = white_tables(0.0, 1.0, True)
    medium = Medium(sigma_a=jnp.array([0.015, 0.1]), sigma_s_prime=jnp.array([0.15, 1.0]), eta=1.0)
    common = dict(shift=True, curvature=True, first_order=True, exit_curved=True)
    return (mus, medium, white_kernel(medium, sources, mus, **common),
            white_kernel(medium, sources, mus, exit_current=True, **common))


def test_the_current_rows_follow_the_flow_and_cancel_on_symmetric_pairs(kernels):
    """Invariants: the first 2K rows are the curved kernel's; the current's rows are the exitance times ``a`` times a
    tangential direction (orthogonal to the shaded point's normal); two entities placed symmetrically about a shaded
    point on a plane, with the same flux and no shift, give currents that cancel; radiance by exit weights is the
    rows times the weights."""
    mus, medium, curved, current = kernels
    k = len(mus)
    rng = np.random.default_rng(1)
    n = 8
    x, p, delta = sphere_pairs(rng, n)
    flux = jnp.asarray(rng.uniform(0.1, 1.0, size=(n, 4, k, 2)))
    normals = (jnp.asarray(x), jnp.asarray(p))
    a = np.asarray(kernel_pair(curved, delta, kernel_sources(curved, flux), normals))
    b = np.asarray(kernel_pair(current, delta, kernel_sources(current, flux), normals))
    assert b.shape == (n, 5 * k, 2) and current.value_shape(flux.shape) == (5 * k, 2) and current.rows_per_node == 5
    np.testing.assert_allclose(b[:, :2 * k], a, rtol=1e-12)
    vec = b[:, 2 * k:].reshape(n, 3, k, 2)
    assert np.max(np.abs(np.einsum("nikc,ni->nkc", vec, x))) < 1e-9 * np.max(np.abs(vec))
    assert np.max(np.abs(vec)) > 0.0
    # Symmetric pairs on a plane: no shift (zero travel), offsets +d and -d.
    up = jnp.tile(jnp.array([[0.0, 0.0, 1.0]]), (2, 1))
    d = jnp.array([[3.0, 1.0, 0.0], [-3.0, -1.0, 0.0]])
    still = jnp.zeros((2, 4, k, 2)).at[:, 0].set(1.0)
    pair = np.asarray(kernel_pair(current, d, kernel_sources(current, still), (up, up)))
    np.testing.assert_allclose(pair[0, 2 * k:] + pair[1, 2 * k:], 0.0, atol=1e-12 * np.abs(pair).max())
    assert np.all(pair[0, 2 * k:3 * k] > 0.0)  # along +x, away from the entry at -d
    # With exit weights: the exitance's rows and the current's as two radiances per pair (their sign is taken after
    # the sum), as row_parts gives them from the rows: one complex value per channel, the current's part imaginary
    # (the sums unpack it to value_shape's two rows).
    weights = jnp.asarray(rng.uniform(-1.0, 1.0, size=(n, 5 * k, 2)))
    packed = np.asarray(kernel_pair(current, delta, kernel_sources(current, flux), normals, weights))
    assert packed.shape == (n, 2) and np.iscomplexobj(packed) and current.value_shape(flux.shape, True) == (2, 2)
    parts = np.stack([packed.real, packed.imag], axis=1)
    np.testing.assert_allclose(parts, np.asarray(row_parts(jnp.asarray(b), weights, 2 * k)), rtol=1e-10)
    np.testing.assert_allclose(parts.sum(axis=1), np.sum(b * np.asarray(weights), axis=1), rtol=1e-10)
    # The near field's disc carries no current.
    np.testing.assert_array_equal(np.asarray(current.weighted_disc(3.0))[2 * k:], 0.0)


def test_the_current_is_added_along_the_flow_only(kernels):
    """Invariant: ``current_radiance`` adds the current where it is positive and nothing against the flow; the exit
    model's radiance of the rows is the curved exit's plus that."""
    mus, medium, _, _ = kernels
    k = len(mus)
    np.testing.assert_array_equal(np.asarray(current_radiance(jnp.array([1.0, 2.0]), jnp.array([-0.5, 0.25]))),
                                  [1.0, 2.25])
    rng = np.random.default_rng(2)
    cos_o = jnp.array([0.2, 0.7, 0.9])
    rows = jnp.asarray(rng.uniform(0.0, 1.0, size=(3, 5 * k, 2)))
    view = tangential_unit(jnp.asarray(rng.normal(size=(3, 3))), jnp.array([[0.0, 0.0, 1.0]] * 3))
    out = np.asarray(exit_radiance_nodes(medium, rows, cos_o, mus, "multiple-current", view_tangent=view))
    curved = np.asarray(exit_radiance_nodes(medium, rows[:, :2 * k], cos_o, mus, "multiple-curved"))
    w = np.asarray(exit_weights(medium, cos_o, mus, "multiple-current", 5 * k, 2, view_tangent=view))
    flow = np.sum(np.asarray(rows)[:, 2 * k:] * w[:, 2 * k:], axis=1)
    np.testing.assert_allclose(out, curved + np.maximum(flow, 0.0), rtol=1e-12)
    np.testing.assert_allclose(w[:, :2 * k], np.asarray(exit_weights(medium, cos_o, mus, "multiple-curved", 2 * k, 2)),
                               rtol=1e-12)


def test_gradients_match_finite_differences(kernels):
    """Autodiff: the amplitude in the albedo and the distance, the exit shape in the albedo, and a kernel's current
    rows in the pairs' offset."""
    mus, _, _, current = kernels
    k = len(mus)
    d = jnp.array([[2.0, 1.0, 0.3], [-4.0, 0.5, 1.0]])
    normals = (jnp.array([[0.0, 0.0, 1.0]] * 2), jnp.array([[0.0, 0.1, 0.995]] * 2))
    flux = jnp.ones((2, 4, k, 2)).at[:, 1:4].set(0.1)
    sources = kernel_sources(current, flux)

    def f(p):
        a = current_amplitude_at(current_amplitude(p[:1]), p[1] * jnp.array([0.3, 2.2, 6.1])[:, None, None])
        y = current_exit_distribution(jnp.array([0.3, 0.8]), mus, p[2:3])
        rows = kernel_pair(current, p[3] * d, sources, normals)
        return jnp.sum(a) + jnp.sum(y * jnp.arange(1.0, k + 1.0)[None, :, None]) + jnp.sum(rows[:, 2 * k:] ** 2)

    assert_grad_matches_fd(f, jnp.array([0.93, 1.1, 0.87, 1.3]), jit=True)


def test_lights_on_both_sides_are_summed_apart(monkeypatch):
    """A key light on the camera's side and one behind the sphere (eta 1, g 0: the first order is marched). The plan
    sums the light behind with the exit's current and the key light apart without it, and says so. The lights are
    opposite, so no sample sees both (a sample's oblique shift is its lights' flux-weighted mean travel, not linear in
    the light where two light it): the image is then the key light's part plus the rim light's (each the same scene
    with the other light off), to rounding, and the key light's part is the key light's own image without the current
    on the same incidence nodes (a scene with a light behind sums both sides with ``LIGHTS_BEHIND_MUS``; the key light
    alone takes ``KERNEL_MUS``, whose image differs by the nodes' interpolation, up to 4% here). The mixed image is
    differentiable through both sums."""
    from jaxsss.render import bssrdf
    import dataclasses

    from jaxsss.render import make_plan, prepare
    from tests.render.test_renderer import _scene

    # Not 2.0 in blue: l_u = 1 / 2.2 mm on the 5 mm sphere puts pairs exactly on a node of the curvature correction's
    # table, where forward mode takes one side's slope of the piecewise-linear table and central differences the mean.
    material = {"sigma_a": [0.05, 0.1, 0.2], "sigma_s_prime": [1.0, 1.5, 2.1], "eta": 1.0}
    key = {"type": "point", "position": [-5.0, -40.0, 0.0], "intensity": 300.0}
    rim = {"type": "point", "position": [5.0, 40.0, 0.0], "intensity": 300.0}
    # One ray per pixel everywhere: edge pixels (where more rays go) depend on the lights.
    camera = {"position": [0.0, -30.0, 10.0], "look_at": [0.0, 0.0, 0.0], "fov_deg": 25.0, "resolution": [12, 12],
              "edge_spp": 1}
    scene, alone = (_scene(material=material, lights=lights, camera=camera) for lights in ([key, rim], [key]))
    plan = make_plan(scene, method="direct", bssrdf="auto")
    assert plan.current_lights == (False, True) and plan.exit_current
    assert make_plan(alone, method="direct", bssrdf="auto").current_lights == ()
    item = {i.name: i for i in plan.items}["exit azimuth"]
    assert item.included and "light[0] (on the camera's side) is summed apart" in item.reason
    # The same plan with one light off (intensity 0): the same program, each side's part.
    def lit(keep):
        return dataclasses.replace(scene, lights=tuple(dataclasses.replace(light, intensity=light.intensity * on)
                                                       for light, on in zip(scene.lights, keep)))

    parts = [scene, lit((1.0, 0.0)), lit((0.0, 1.0))]
    prepared = [prepare(s, method="direct", plan=plan)[0] for s in parts]
    mixed = prepared[0]
    assert mixed.current_columns == (1,) and mixed.bssrdf_exit == "multiple-current"
    assert [side.bssrdf_exit for side in mixed.light_sides()] == ["multiple-current", "multiple-curved"]
    medium = scene.material.medium
    images = [np.asarray(p.image(medium)) for p in prepared]
    assert np.all(np.isfinite(images[0])) and images[2].max() > 0.05 * images[1].max()
    np.testing.assert_allclose(images[0], images[1] + images[2], rtol=1e-9, atol=1e-12 * images[0].max())
    assert mixed.bssrdf_mus == (1.0,) + bssrdf.LIGHTS_BEHIND_MUS
    with monkeypatch.context() as m:
        m.setattr(bssrdf, "KERNEL_MUS", bssrdf.LIGHTS_BEHIND_MUS)
        own = prepare(alone, method="direct")[0]
    assert own.bssrdf_exit == "multiple-curved" and own.bssrdf_mus == mixed.bssrdf_mus
    np.testing.assert_allclose(images[1], np.asarray(own.image(medium)), rtol=1e-9, atol=1e-12 * images[0].max())

    # Forward mode against central differences along one direction of sigma_a (reverse mode through the white kernels:
    # tests/render/test_renderer.py).
    def image(sigma_a):
        return mixed.image(eqx.tree_at(lambda m: m.sigma_a, medium, sigma_a))

    # h: the kernels' tables are piecewise linear in the albedo (and the key light's kernel takes min(Q, 1),
    # jaxsss.render.curvature_correction), so a difference that straddles a kink is not the one-sided derivative: at
    # h = 1e-6 one pixel of 432 straddled Q = 1 (1.3e-5 off relative); none does at 1e-7.
    x, v, h = medium.sigma_a, jnp.array([1.0, -0.5, 0.3]), 1e-7
    tangent = np.asarray(jax.jvp(image, (x,), (v,))[1])
    fd = (np.asarray(image(x + h * v)) - np.asarray(image(x - h * v))) / (2 * h)
    assert np.abs(tangent).max() > 0
    np.testing.assert_allclose(tangent, fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max())
