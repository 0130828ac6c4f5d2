"""jaxsss.render.first_order: the first scattering order marched in the object's geometry, and the half-space's first
order the white kernels give up for it (reference values, shapes, bad input, invariants, autodiff; the images against
Mitsuba are in tests/render/test_passage.py and tests/export/test_compare_bssrdf.py)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from jaxsss.medium import Medium
from jaxsss.render import bssrdf as B
from jaxsss.render.first_order import (AREA_SAMPLES, MARCH_NODES, diffuse_first_order_restore, first_order_paths,
                                       first_order_profile,
                                       first_order_radiance, first_order_total)
from jaxsss.render.rays import SceneGeometry
from jaxsss.render.scene import Light
from tests.gradcheck import assert_grad_matches_fd

MUS = (1.0, 0.5, 0.1)


def _scene(*lights):
    """A stand-in scene: only ``lights`` is read."""
    return type("S", (), {"lights": list(lights)})()


def _slab(depth=100.0, width=400.0):
    """A box whose top face is z = 0 (the lit side), ``depth`` mm deep: a half-space for sigma_t >> 1 / depth."""
    box = trimesh.creation.box(extents=(width, width, depth))
    box.apply_translation((0.0, 0.0, -depth / 2))
    return box


def _march_top(geometry, scene, mu_o, n_channels=1):
    """The first order's paths at the top face's centre seen at cosine ``mu_o`` (azimuth along +x)."""
    to_eye = np.array([[np.sqrt(1 - mu_o**2), 0.0, mu_o]])
    return first_order_paths(scene, geometry, np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), to_eye, n_channels)


@pytest.mark.parametrize("mu", MUS)
def test_profile_integrates_to_chandrasekhars_first_order(mu):
    """The half-space's first-order profile over the plane is ``(a / 2) (1 - mu ln((1 + mu) / mu))`` per incident
    photon (Chandrasekhar 1960), for strong and weak absorption (the disc below the tables' first bin included)."""
    rho = 10.0 ** np.arange(-2.0, 4.0, 1.0 / 400)
    albedo = jnp.array([0.02, 0.5, 0.95])
    r1 = np.asarray(first_order_profile(rho, mu, albedo))
    # The disc below 0.01 (held at its mean) and the rest.
    disc = np.pi * 1e-4 * np.asarray(first_order_profile(np.array([0.0]), mu, albedo))[0]
    plane = disc + np.trapezoid(2 * np.pi * rho[:, None] * r1, rho, axis=0)
    np.testing.assert_allclose(plane, np.asarray(first_order_total(mu, albedo)), rtol=3e-3)


def test_march_reproduces_the_half_spaces_single_scattering():
    """On a thick slab under a directional light the marched first order is Hanrahan and Krueger's half-space value
    ``a E p / (mu_o / mu_i + 1)`` with ``E`` the irradiance facing the light (g = 0), for any view and medium."""
    geometry = SceneGeometry(_slab())
    mu_i = 0.6
    light = Light("directional", np.array([2.0]), direction=np.array([-np.sqrt(1 - mu_i**2), 0.0, -mu_i]))
    medium = Medium(jnp.array([0.05, 2.0]), jnp.array([1.0, 0.1]), 1.0)
    sigma_s, sigma_t = np.array([1.0, 0.1]), np.array([1.05, 2.1])
    for mu_o in (1.0, 0.5, 0.15):
        paths = _march_top(geometry, _scene(light), mu_o, 2)
        got = np.asarray(first_order_radiance(medium, paths))[0]
        want = sigma_s / sigma_t * 2.0 / (4 * np.pi) / (mu_o / mu_i + 1.0)
        np.testing.assert_allclose(got, want, rtol=2e-3)


def test_shapes_and_columns():
    """``(Q, N, M, C)``: a delta light one column, an area light AREA_SAMPLES; the radiance ``(Q, C)``."""
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=10.0)
    geometry = SceneGeometry(sphere)
    lights = (Light("point", np.array([1.0, 2.0, 3.0]) * 1e4, position=np.array([0.0, -60.0, 40.0])),
              Light("sphere", np.array([5.0, 5.0, 5.0]), position=np.array([50.0, 0.0, 0.0]), radius=5.0, samples=16))
    pos = np.array([[0.0, -10.0, 0.0], [0.0, 0.0, 10.0]])
    normal = pos / 10.0
    paths = first_order_paths(_scene(*lights), geometry, pos, normal, normal, 3)
    m = 1 + AREA_SAMPLES
    assert paths.s.shape == paths.weight.shape == (2, MARCH_NODES)
    assert paths.t_light.shape == paths.cos.shape == (2, MARCH_NODES, m)
    assert paths.irradiance.shape == (2, MARCH_NODES, m, 3)
    # The march spans the chord: a diameter (20 mm) seen along the normal.
    np.testing.assert_allclose(np.sum(paths.weight, axis=1), 20.0, rtol=1e-3)
    medium = Medium(jnp.array([0.03, 0.2, 0.5]), jnp.array([0.7, 0.9, 1.0]), 1.0)
    assert first_order_radiance(medium, paths).shape == (2, 3)


def test_bad_light_is_refused_by_name():
    """An environment light is not marched: the error names its kind and the allowed ones."""
    geometry = SceneGeometry(_slab())
    env = Light("environment", np.array([1.0]))
    with pytest.raises(ValueError, match="'environment'.*point, spot, directional, sphere, rectangle"):
        _march_top(geometry, _scene(env), 1.0)


def test_invariants_occluder_additivity_and_extremes():
    """Lights add; an occluder between the slab and its light leaves no first order; no scattering, no first order;
    grazing views and extreme coefficients stay finite and non-negative."""
    slab = _slab()
    a = Light("point", np.array([1e4]), position=np.array([30.0, 0.0, 80.0]))
    b = Light("spot", np.array([2e4]), position=np.array([-30.0, 10.0, 60.0]), direction=np.array([0.4, -0.1, -1.0])
              / np.linalg.norm([0.4, -0.1, -1.0]), cone_deg=40.0, falloff_deg=10.0)
    medium = Medium(jnp.array([0.1]), jnp.array([1.0]), 1.0)
    geometry = SceneGeometry(slab)
    both = first_order_radiance(medium, _march_top(geometry, _scene(a, b), 0.7))
    each = sum(first_order_radiance(medium, _march_top(geometry, _scene(x), 0.7)) for x in (a, b))
    np.testing.assert_allclose(both, each, rtol=1e-12)
    plate = trimesh.creation.box(extents=(300.0, 300.0, 1.0))
    plate.apply_translation((0.0, 0.0, 40.0))
    shaded = first_order_radiance(medium, _march_top(SceneGeometry(slab, [plate]), _scene(a), 0.7))
    assert float(shaded[0, 0]) == 0.0 and float(both[0, 0]) > 0.0
    clear = Medium(jnp.array([0.1]), jnp.array([0.0]), 1.0)
    assert float(first_order_radiance(clear, _march_top(geometry, _scene(a), 0.7))[0, 0]) == 0.0
    for sigma_a, sigma_s in ((1e-6, 1e-4), (1e-6, 1e3), (1e3, 1e-3), (50.0, 50.0)):
        extreme = Medium(jnp.array([sigma_a]), jnp.array([sigma_s]), 1.0)
        value = np.asarray(first_order_radiance(extreme, _march_top(geometry, _scene(a), 0.02)))
        assert np.all(np.isfinite(value)) and np.all(value >= 0.0), (sigma_a, sigma_s, value)


def test_gradient_matches_finite_differences():
    """d L1 / d(sigma_a, sigma_s') against central differences, on a sphere whose light crosses the object."""
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=10.0)
    light = Light("point", np.array([1e4]), position=np.array([-60.0, -50.0, 30.0]))
    pos = np.array([[0.0, -10.0, 0.0], [8.0, -6.0, 0.0]])
    normal = pos / 10.0
    paths = first_order_paths(_scene(light), SceneGeometry(sphere), pos, normal, np.array([[0.0, -1.0, 0.0]] * 2), 1)

    def f(x):
        return jnp.sum(first_order_radiance(Medium(x[:1], x[1:], 1.0), paths))

    x = jnp.array([0.06, 0.2])
    grad = np.asarray(jax.grad(f)(x))
    for i in range(2):
        h = 1e-6 * float(x[i])
        e = jnp.zeros(2).at[i].set(h)
        fd = (float(f(x + e)) - float(f(x - e))) / (2 * h)
        np.testing.assert_allclose(grad[i], fd, rtol=1e-6)


def test_multiple_exit_distribution_is_chandrasekhar_less_its_first_order():
    """``A X = A_1 X_1 + (A - A_1) X_2``: the whole exit is the first order's (``1 / (mu_i + mu_o)``) plus the orders
    >= 2; X_2 is normalised and Lambertian where there is nothing but the first order."""
    mu_o = jnp.linspace(0.02, 1.0, 50)
    mu_i = jnp.array([1.0, 0.5, 0.1])
    albedo = jnp.array([0.3, 0.9, 0.99])
    x2 = B.multiple_exit_distribution(mu_o, mu_i, albedo)
    t, w = np.polynomial.legendre.leggauss(64)
    t = 0.5 * (t + 1.0)
    norm = np.einsum("t,tkc->kc", w * t, np.asarray(B.multiple_exit_distribution(jnp.asarray(t), mu_i, albedo)))
    np.testing.assert_allclose(norm, 1.0, rtol=1e-4)
    a_all = np.asarray(B.directional_albedo(mu_i[:, None], albedo))
    a_1 = np.asarray(first_order_total(mu_i[:, None], albedo))
    x = np.asarray(B.exit_distribution(mu_o, mu_i, albedo))
    # The first order's exit: f_r1 = a / (4 pi (mu_i + mu_o)), as a multiple of a Lambertian exit of exitance A_1.
    mu_sum = np.asarray(mu_o)[:, None, None] + np.asarray(mu_i)[None, :, None]
    x1 = np.pi * np.asarray(albedo)[None, None, :] / (4 * np.pi * mu_sum) / a_1[None]
    np.testing.assert_allclose(a_all * x, a_1 * x1 + (a_all - a_1) * np.asarray(x2), rtol=2e-4)
    flat = B.multiple_exit_distribution(mu_o, mu_i, jnp.array([0.0]))
    np.testing.assert_allclose(flat, 1.0)


def test_the_kernel_keeps_the_orders_above_the_first():
    """``multiple_orders``: each node's plane integral is the profile's times ``1 - A_1 / A`` (0.1% where the first
    order is all of it), the profile never exceeds the whole one's, and its gradient matches finite differences."""
    mus, tables = B.white_tables(0.0, 1.0, oblique=True)
    medium = Medium(jnp.array([0.061, 0.97, 1.45]), jnp.array([0.18, 0.07, 0.03]), 1.0)
    whole = B.white_kernel(medium, tables, mus, shift=True)
    part = B.white_kernel(medium, tables, mus, shift=True, first_order=True)
    rho = B.GRID_RHO_MIN * 10.0 ** (np.arange(whole.log_R.shape[1]) / B.GRID_PER_DECADE)
    w = (2 * np.pi * rho**2 * np.log(10.0) / B.GRID_PER_DECADE)[None, :, None]
    total, kept = (np.sum(w * np.exp(np.asarray(k.log_R)), axis=1) for k in (whole, part))
    albedo = np.asarray(medium.alpha_prime)
    cos = np.asarray(mus)[:, None]
    share = np.maximum(1 - np.asarray(first_order_total(cos, albedo)) / np.asarray(B.directional_albedo(cos, albedo)),
                       1e-3)
    np.testing.assert_allclose(kept, share * total, rtol=1e-9)
    assert 0.45 < share[0, 0] < 0.6 and share[0, 2] < 0.02  # red is half multiple scattering; blue nearly none

    def f(sigma_a):
        m = dataclasses.replace(medium, sigma_a=medium.sigma_a.at[0].set(sigma_a))
        k = B.white_kernel(m, tables, mus, shift=True, first_order=True)
        return jnp.sum(k.profile(jnp.array([0.5, 2.0, 6.0]))[:, :, 0])

    h = 1e-5
    fd = (float(f(0.061 + h)) - float(f(0.061 - h))) / (2 * h)
    np.testing.assert_allclose(float(jax.grad(f)(0.061)), fd, rtol=1e-4)
    # Only isotropic, index-matched tables: the share and the exit are that case's.
    mus_g, tables_g = B.white_tables(0.9, 1.0, oblique=True)
    with pytest.raises(ValueError, match="first_order=True.*g=0.9"):
        B.white_kernel(dataclasses.replace(medium, g=jnp.asarray(0.9)), tables_g, mus_g, shift=True, first_order=True)


def test_the_plan_marches_the_first_order_where_it_can():
    """On at eta = 1 with g = 0 under point and sphere lights on a lone convex object, and on the teapot, whose own
    bounce enters the orders >= 2 with its first order's share (the line says so); off, with the reason, at a
    dielectric boundary and for g > 0."""
    from pathlib import Path

    from jaxsss.render import load_scene
    from jaxsss.render.plan import make_plan

    refs = Path(__file__).parents[1] / "export" / "references"

    def line(name):
        plan = make_plan(load_scene(refs / f"{name}.toml"), bssrdf="auto")
        item = next(i for i in plan.items if i.name.startswith("first order"))
        assert item.included == plan.first_order
        return plan.first_order, item.reason

    for name in ("skin1_sphere", "skin1_sphere_arealight", "ketchup_sphere", "marble_teapot"):
        on, why = line(name)
        assert on and "orders >= 2" in why, (name, why)
        assert ("first order's share" in why) == (name == "marble_teapot"), (name, why)
    for name, reason in (("skin1_sphere_env", "eta = 1.4"), ("g09_sphere", "g = 0.9")):
        on, why = line(name)
        assert not on and reason in why, (name, why)


def test_diffuse_light_keeps_its_first_orders_share():
    """``diffuse_first_order_restore``: every order's diffuse reflectance over the orders >= 2's. Reference: at albedo
    1 every photon comes back (``A_d = 1``) and the first order's share is ``2 int_0^1 mu (1 / 2) (1 - mu ln((1 + mu) /
    mu)) dmu`` (scipy's quadrature of Chandrasekhar's single scattering). Invariants: above 1, falling with the albedo
    (the first order is most of the light at a low albedo); 1 where nothing comes back. Shapes; autodiff."""
    from scipy.integrate import quad

    first = quad(lambda m: m * (1.0 - m * np.log((1.0 + m) / m)), 0.0, 1.0)[0]
    got = np.asarray(diffuse_first_order_restore(jnp.array([1.0])))
    np.testing.assert_allclose(got, 1.0 / (1.0 - first), rtol=1e-6)
    a = jnp.array([0.0, 0.02, 0.3, 0.7, 0.9, 0.99, 0.999])
    r = np.asarray(diffuse_first_order_restore(a))
    assert r.shape == (7,) and r[0] == 1.0 and np.all(np.isfinite(r))
    assert np.all(r[1:] > 1.0) and np.all(np.diff(r[1:]) < 0.0) and r[1] > 20.0
    assert np.asarray(diffuse_first_order_restore(0.5)).shape == (1,)
    assert_grad_matches_fd(lambda x: jnp.sum(diffuse_first_order_restore(x)), jnp.array([0.3, 0.8, 0.95]), rtol=1e-5)


def test_a_lights_path_is_followed_through_every_crossing():
    """The length inside towards the light: on a sphere, the chord to its surface (the march stops at the exit of a
    lone convex mesh, and following it on gives the same); through a second sphere of the same mesh, both chords;
    behind an occluder, closed."""
    from jaxsss.render.first_order import _inside_length

    sphere = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    points = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [-0.3, 0.2, 0.1]])
    to_light = np.array([[1.0, 0.0, 0.0]] * 3)
    # The chord from each point to the unit sphere along +x (the tessellation's inscribed sphere within 1e-3).
    chord = -points[:, 0] + np.sqrt(1.0 - points[:, 1] ** 2 - points[:, 2] ** 2)
    lone = SceneGeometry(sphere)
    followed = SceneGeometry(sphere)
    followed.__dict__["convex_alone"] = False  # follow every crossing all the same
    assert lone.convex_alone
    for geometry in (lone, followed):
        length, open_ = _inside_length(geometry, points, to_light, None)
        np.testing.assert_allclose(length, chord, rtol=2e-3)
        assert open_.all()
    np.testing.assert_array_equal(_inside_length(lone, points, to_light, None)[0],
                                  _inside_length(followed, points, to_light, None)[0])
    second = sphere.copy()
    second.apply_translation([5.0, 0.0, 0.0])
    pair = SceneGeometry(trimesh.util.concatenate([sphere, second]))
    assert not pair.convex_alone
    length, open_ = _inside_length(pair, points, to_light, None)
    np.testing.assert_allclose(length, chord + 2.0 * np.sqrt(1.0 - points[:, 1] ** 2 - points[:, 2] ** 2), rtol=2e-3)
    assert open_.all()
    # A point light between the spheres: the second sphere's chord does not count.
    length, _ = _inside_length(pair, points, to_light, 2.5 - points[:, 0])
    np.testing.assert_allclose(length, chord, rtol=2e-3)
    wall = trimesh.creation.box(extents=(0.2, 4.0, 4.0))
    wall.apply_translation([3.0, 0.0, 0.0])
    _, open_ = _inside_length(SceneGeometry(sphere, [wall]), points, to_light, None)
    assert not open_.any()
