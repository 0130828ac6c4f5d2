"""Uncollided passage (jaxsss.render.passage): reference values (a sphere's chord), shapes, bad and extreme input,
invariants, autodiff, and its effect on a render against the path-traced ketchup sphere."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.render.meshes import builtin_mesh
from jaxsss.render.passage import entry_chords, interaction_probability, truncated_travel
from jaxsss.render.rays import SceneGeometry
from tests.gradcheck import assert_grad_matches_fd

RADIUS = 20.0


@pytest.fixture(scope="module")
def sphere():
    return SceneGeometry(builtin_mesh("sphere", radius=RADIUS, subdivisions=5))


def _columns(mus, azimuth=0.3):
    """A point on top of the sphere (normal +z) and light columns at incidence cosines ``mus``."""
    mus = np.asarray(mus, dtype=np.float64)
    s = np.sqrt(1.0 - mus**2)
    to_light = np.stack([s * np.cos(azimuth), s * np.sin(azimuth), mus], axis=-1)[None]  # (1, L, 3)
    return np.array([[0.0, 0.0, RADIUS]]), np.array([[0.0, 0.0, 1.0]]), to_light, mus[None]


@pytest.mark.parametrize("eta", [1.0, 1.4])
def test_chord_of_a_sphere_is_two_a_cos_theta_t(sphere, eta):
    """Reference: on a sphere of radius ``a`` a ray entering at refracted cosine ``cos_t`` runs ``2 a cos_t``."""
    mus = np.array([0.05, 0.1, 0.3, 0.7, 1.0])
    chord = entry_chords(sphere, *_columns(mus), eta)
    cos_t = np.sqrt(1.0 - (1.0 - mus**2) / eta**2)
    # The icosphere's facets (edges ~0.7 mm) sit up to ~0.004 mm inside the sphere, which moves a ray at slope mu by
    # ~0.004 / mu mm: 0.07 mm at mu = 0.05.
    np.testing.assert_allclose(chord[0], 2.0 * RADIUS * cos_t, rtol=2e-3, atol=0.1)


def test_shapes_and_unlit_columns(sphere):
    points, normals, to_light, cos = _columns([0.5, 0.2])
    cos = np.concatenate([cos, [[0.0, -0.3]]], axis=1)
    to_light = np.concatenate([to_light, to_light], axis=1)
    chord = entry_chords(sphere, np.repeat(points, 3, 0), np.repeat(normals, 3, 0), np.repeat(to_light, 3, 0),
                         np.repeat(cos, 3, 0), 1.0)
    assert chord.shape == (3, 4)
    assert np.all(np.isfinite(chord[:, :2])) and np.all(np.isinf(chord[:, 2:]))  # unlit columns are not traced
    p = interaction_probability(jnp.asarray(chord), jnp.array([0.1, 1.0, 10.0]))
    assert p.shape == (3, 4, 3)
    np.testing.assert_array_equal(np.asarray(p[:, 2:]), 1.0)


def test_an_open_surface_never_loses_light():
    """A plane (an open mesh, the half-space): the refracted ray never leaves, so nothing passes through."""
    import trimesh

    w = 1e4
    plane = SceneGeometry(trimesh.Trimesh([[-w, -w, 0.0], [w, -w, 0.0], [w, w, 0.0], [-w, w, 0.0]],
                                          [[0, 1, 2], [0, 2, 3]], process=False))
    points, normals, to_light, cos = _columns([0.05, 0.5, 1.0])
    chord = entry_chords(plane, points * 0.0, normals, to_light, cos, 1.3)
    assert np.all(np.isinf(chord))
    np.testing.assert_array_equal(np.asarray(interaction_probability(jnp.asarray(chord), jnp.array([1.0]))), 1.0)


def test_extreme_coefficients_and_chords():
    chord = jnp.array([[0.0, 1e-12, 1.0, 1e6, jnp.inf]])
    p = np.asarray(interaction_probability(chord, jnp.array([0.0, 1e-9, 1.0, 1e6])))
    assert np.all(np.isfinite(p)) and np.all((p >= 0.0) & (p <= 1.0))
    np.testing.assert_array_equal(p[0, 0], 0.0)  # no path: nothing interacts
    np.testing.assert_array_equal(p[0, 4], 1.0)  # an infinite chord: everything does, even at sigma_t = 0
    np.testing.assert_allclose(p[0, 2], -np.expm1(-np.array([0.0, 1e-9, 1.0, 1e6])), rtol=1e-12)
    np.testing.assert_allclose(p[0, 1, 1], 1e-21, rtol=1e-9)  # expm1: no cancellation for a thin chord


def test_probability_grows_with_the_chord_and_the_extinction():
    chord = jnp.asarray(np.geomspace(1e-3, 1e3, 50))[None]
    sigma = jnp.asarray(np.geomspace(1e-3, 1e2, 7))
    p = np.asarray(interaction_probability(chord, sigma))[0]
    assert np.all(np.diff(p, axis=0) >= 0.0) and np.all(np.diff(p, axis=1) >= 0.0)


def test_gradient_matches_finite_differences_and_is_finite_at_infinite_chords():
    chord = jnp.array([[0.5, 4.0, jnp.inf]])

    def f(sigma_t):
        return jnp.sum(interaction_probability(chord, sigma_t) * jnp.array([1.0, 2.0, 3.0])[:, None])

    assert_grad_matches_fd(f, jnp.array([0.3, 0.77, 1.5]))


def test_truncated_travel_reference_values_and_limits():
    """Reference: the mean of an exponential free path (rate ``s``) given that it ends before ``t``, by quadrature of
    ``int_0^t u s e^(-s u) du / (1 - e^(-s t))``, over the untruncated mean ``1 / s``."""
    sigma = jnp.array([0.24, 0.67, 2.2])
    chord = jnp.array([[1e-6, 0.5, 2.0, 4.0, 40.0, jnp.inf]])
    f = np.asarray(truncated_travel(chord, sigma))[0]  # (6, 3)
    assert f.shape == (6, 3)
    for i, t in enumerate([1e-6, 0.5, 2.0, 4.0, 40.0]):
        for c, s in enumerate(np.asarray(sigma)):
            x, w = np.polynomial.legendre.leggauss(64)
            u = 0.5 * t * (x + 1.0)
            mean = np.sum(0.5 * t * w * u * s * np.exp(-s * u)) / -np.expm1(-s * t)
            np.testing.assert_allclose(f[i, c], mean * s, rtol=1e-10)
    np.testing.assert_array_equal(f[5], 1.0)  # no chord end: the half-space's travel
    np.testing.assert_allclose(f[0], 0.5e-6 * np.asarray(sigma), rtol=1e-6)  # a thin chord: half of it
    assert np.all(np.diff(f, axis=0) >= 0.0) and np.all((f > 0.0) & (f <= 1.0))


def test_truncated_travel_extremes_and_gradient():
    chord = jnp.array([[0.0, 1e-300, 1e-3, 1.0, 1e300, jnp.inf]])
    f = np.asarray(truncated_travel(chord, jnp.array([0.0, 1e-9, 1.0, 1e6])))
    assert np.all(np.isfinite(f)) and np.all((f >= 0.0) & (f <= 1.0))
    np.testing.assert_array_equal(f[0, 0], 0.0)  # no path: no travel
    np.testing.assert_array_equal(f[0, 5], 1.0)
    # Continuous across the series' switch at x = 1e-3: the step is the slope f' = 1/2 - x/6 times the step in x.
    x = jnp.array([[1e-3 * (1 - 1e-9), 1e-3 * (1 + 1e-9)]])
    a, b = np.asarray(truncated_travel(x, jnp.array([1.0])))[0, :, 0]
    assert abs((b - a) - (0.5 - 1e-3 / 6) * 2e-12) < 1e-14
    chord = jnp.array([[0.5, 4.0, 1e-4, jnp.inf]])

    def g(sigma_t_prime):
        return jnp.sum(truncated_travel(chord, sigma_t_prime) * jnp.array([1.0, 2.0, 3.0, 4.0])[:, None])

    assert_grad_matches_fd(g, jnp.array([0.3, 0.77, 1.5]))


def test_the_terminator_of_the_path_traced_ketchup_sphere():
    """Ketchup (albedo 0.75 / 0.067 / 0.020) on the 20 mm sphere, eta 1, one point light, against Mitsuba at 8192 spp
    (2.3 / 1.5 / 1.7% pixel noise; tests/export/references/ketchup_sphere). Measured 2026-11-27: with the passage the
    terminator band's mare is 0.114 / 0.127 / 0.158 and mare_lit 0.170 / 0.058 / 0.073, sums 1.055 / 1.038 / 1.054;
    without it (every chord infinite, the half-space) the band is 0.249 / 0.157 / 0.180 and mare_lit 0.248 / 0.062 /
    0.076. With Chandrasekhar's exact albedo between the incidence nodes (``bssrdf.albedo_correction``, later that
    day): band 0.096 / 0.132 / 0.173, mare_lit 0.155 / 0.041 / 0.050, sums 1.040 / 1.006 / 1.022 (blue's band is the
    one number that rose). With each incidence node's curvature source at its own depth (``mu_t l_u``;
    jaxsss.render.curvature, "Oblique incidence"; later still): band 0.067 / 0.127 / 0.170, mare_lit 0.101 / 0.040 /
    0.049, sums 1.018 / 1.004 / 1.020. With the oblique shift's travel bounded by the chord (``truncated_travel``):
    band 0.092 / 0.119 / 0.166, mare_lit 0.077 / 0.039 / 0.048, sums 1.015 / 1.002 / 1.019. With the white kernels'
    sample density 2 (``bssrdf.WHITE_DENSITY``): band 0.099 / 0.108 / 0.121 (the goal met in blue), mare_lit 0.084 /
    0.040 / 0.046, sums 1.010 / 1.007 / 1.022. Red still misses the goal: its sphere is 4.8 transport lengths in radius, and at cos -1 to -0.3 to the light it is 36% too bright (62%
    before the bound, 108% with one curvature depth; docs/path_tracer.md). Bounds: the achieved level plus about 10%
    (the goal's 3% for the sums), and the passage must beat the half-space in the band of every channel."""
    from jaxsss.export.compare import compare_images, pixel_geometry
    from jaxsss.render import load_scene, render
    from jaxsss.render.methods import image_of, resolve_method
    from tests.export.test_compare_bssrdf import REFERENCES

    scene = load_scene(REFERENCES / "ketchup_sphere.toml")
    data = np.load(REFERENCES / "ketchup_sphere.npz")
    ref, coverage = data["image"].astype(np.float64), data["coverage"].astype(np.float64)
    result = render(scene)
    pixels = pixel_geometry(scene)
    m = compare_images(result.image, ref, pixels, coverage=coverage)
    assert np.all(np.array(m["mare_band"]) <= (0.109, 0.119, 0.133)), m["mare_band"]
    assert np.all(np.array(m["mare_lit"]) <= (0.092, 0.044, 0.05)), m["mare_lit"]
    assert np.all(np.abs(np.array(m["sum_ratio"]) - 1.0) <= 0.03), m["sum_ratio"]
    state = result.prepared.state
    half_space = eqx.tree_at(lambda s: s.light_chord, state, jnp.full_like(state.light_chord, jnp.inf))
    image = np.asarray(image_of(half_space, resolve_method("hierarchical").params(scene)))
    flat = compare_images(image, ref, pixels, coverage=coverage)
    assert np.all(np.array(m["mare_band"]) < np.array(flat["mare_band"])), (m["mare_band"], flat["mare_band"])
