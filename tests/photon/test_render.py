"""The photon-diffusion renderer (jaxsss.photon.render): source powers in any material (equal to the traced ones at
the tracing material), gradients of the exitance against finite differences, the hierarchical sum against every
source summed alone, and the example scenes (blocker shadows, backlit multipole)."""

from __future__ import annotations

import math
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxsss
from jaxsss.photon import TALLIES
from jaxsss.photon.render import (
    _photon_exitance,
    prepare_photon,
    source_power,
    trace_scene,
)
from jaxsss.render import render
from jaxsss.render.scene import load_scene, parse_scene, scene_with
from tests.gradcheck import central_difference

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def box_scene(material, *, extents=(10.0, 10.0, 4.0), light=None, mesh=None):
    return parse_scene({
        "mesh": mesh or {"builtin": "box", "extents": list(extents)},
        "material": material,
        "light": [light or {"type": "spot", "position": [2.0, 0.0, 60.0], "direction": [0.0, 0.0, -1.0],
                            "cone_deg": 3.0, "intensity": 1e3}],
        "camera": {"position": [80.0, 0.0, 50.0], "look_at": [0.0, 0.0, 0.0], "resolution": [8, 8]},
    }, path="<test>")


# --- source power -----------------------------------------------------------------------------------------------------

def test_source_power_equals_the_traced_power_at_the_tracing_material():
    # walk="sources" books everything left after the first scattering in `capped`: the sources' powers in the
    # tracing material must add up to it exactly, channel by channel (mixture ratio included).
    scene = box_scene({"sigma_a": [0.02, 0.3, 0.9], "sigma_s_prime": [0.6, 1.2, 3.5], "eta": 1.4})
    trace = trace_scene(scene, 2000, walk="sources")
    src, m = trace.sources, scene.material.medium
    got = np.asarray(source_power(m, jnp.asarray(src.power), jnp.asarray(src.path), jnp.asarray(trace.sigma_t_ref)))
    st = np.asarray(m.sigma_t_prime)
    e = st * np.exp(-np.outer(src.path, st))
    expect = src.power * np.asarray(m.alpha_prime) * e / e.mean(axis=1, keepdims=True)
    np.testing.assert_allclose(got, expect, rtol=1e-12)
    np.testing.assert_allclose(got.sum(axis=0), trace.tally["capped"], rtol=1e-10)
    assert not np.allclose(expect, src.power * np.asarray(m.alpha_prime), rtol=1e-3)  # the ratio matters here


def test_source_power_with_identical_channels_is_power_times_albedo():
    scene = box_scene({"sigma_a": 0.05, "sigma_s_prime": 1.5, "eta": 1.3})
    trace = trace_scene(scene, 500, walk="sources")
    src, m = trace.sources, scene.material.medium
    got = np.asarray(source_power(m, jnp.asarray(src.power), jnp.asarray(src.path), jnp.asarray(trace.sigma_t_ref)))
    np.testing.assert_allclose(got, src.power * (1.5 / 1.55), rtol=1e-13)
    np.testing.assert_allclose(got.sum(axis=0), trace.tally["capped"], rtol=1e-12)
    # Another material re-weights the same flights by alpha' sigma_t' e^{-sigma_t' s}, relative to the tracing one:
    # (3 / 3.05) 3.05 e^{-3.05 s} / ((1.5 / 1.55) 1.55 e^{-1.55 s}) = 2 e^{-1.5 s}.
    m2 = jaxsss.Medium(jnp.full(3, 0.05), jnp.full(3, 3.0), 1.3)
    got2 = np.asarray(source_power(m2, jnp.asarray(src.power), jnp.asarray(src.path),
                                   jnp.asarray(trace.sigma_t_ref)))
    ratio = 2.0 * np.exp(-1.5 * src.path)
    np.testing.assert_allclose(got2, got * ratio[:, None], rtol=1e-12)


def test_source_power_survives_long_flights():
    # e^{-sigma_t' s} underflows for s = 800 mm; the ratio to the mixture does not: the slowest channel takes all.
    m = jaxsss.Medium(jnp.array([0.1, 0.5, 1.0]), jnp.array([0.4, 1.5, 4.0]), 1.3)
    st = np.array([0.5, 2.0, 5.0])
    power = jnp.ones((4, 3))
    path = jnp.array([0.0, 1.0, 50.0, 800.0])
    got = np.asarray(source_power(m, power, path, jnp.asarray(st)))
    assert np.isfinite(got).all()
    alpha = np.array([0.8, 0.75, 0.8])
    np.testing.assert_allclose(got[0], alpha * st / st.mean(), rtol=1e-12)
    np.testing.assert_allclose(got[3], [3.0 * alpha[0], 0.0, 0.0], atol=1e-300, rtol=1e-12)


# --- exitance and its gradients -------------------------------------------------------------------------------------

GRAD_MATERIAL = {"sigma_a": [0.05, 0.1, 0.2], "sigma_s_prime": [1.0, 1.5, 2.0], "eta": 1.3}


def face_points(k=16, seed=0):
    """Points on the top (z = 2), bottom (z = -2) and side (x = 5) faces of the 10 x 10 x 4 box."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-4.5, 4.5, (3 * k, 2))
    top = np.c_[xy[:k], np.full(k, 2.0)]
    bottom = np.c_[xy[k:2 * k], np.full(k, -2.0)]
    side = np.c_[np.full(k, 5.0), xy[2 * k:, 0], 0.4 * xy[2 * k:, 1]]
    normals = np.r_[np.tile([0.0, 0.0, 1.0], (k, 1)), np.tile([0.0, 0.0, -1.0], (k, 1)),
                    np.tile([1.0, 0.0, 0.0], (k, 1))]
    return np.r_[top, bottom, side], normals


@pytest.fixture(scope="module")
def small():
    scene = box_scene(GRAD_MATERIAL)
    points = face_points()
    trace = trace_scene(scene, 2000)
    prepared, _items, info = prepare_photon(scene, points=points, trace=trace)
    return scene, points, trace, prepared, info


def test_exitance_is_finite_nonnegative_and_uses_both_lists(small):
    scene, points, _, prepared, info = small
    m = np.asarray(_photon_exitance(prepared, scene.material.medium))
    assert m.shape == (len(points[0]), 3)
    assert np.isfinite(m).all() and np.all(m >= 0)
    assert np.all(m[:16] > 0) and np.all(m[16:32] > 0)  # the lit top and, through 4 mm, the bottom
    assert info["n_interactions_multipole"] > 0 and info["n_interactions"] > info["n_interactions_multipole"]
    assert info["photon_walk"] == "sources" and info["n_pairs_blocked"] == 0
    # The bottom (through the box) is much darker than the lit top.
    assert m[16:32].mean() < 0.3 * m[:16].mean()


def test_exitance_gradients_match_finite_differences(small):
    scene, points, _, prepared, _ = small
    eta = scene.material.medium.eta
    weights = jnp.asarray(np.random.default_rng(1).uniform(0.5, 1.5, (len(points[0]), 3)))

    def f(p, x):
        medium = jaxsss.Medium(sigma_a=x[:3], sigma_s_prime=x[3:], eta=eta)
        return jnp.sum(weights * p.exitance(medium))

    def f_eager(x):  # the module's jitted exitance (compiled once for this prepared state)
        medium = jaxsss.Medium(sigma_a=x[:3], sigma_s_prime=x[3:], eta=eta)
        return jnp.sum(weights * _photon_exitance(prepared, medium))

    x0 = np.array(GRAD_MATERIAL["sigma_a"] + GRAD_MATERIAL["sigma_s_prime"])
    grad = np.asarray(eqx.filter_jit(jax.grad(f, argnums=1))(prepared, jnp.asarray(x0)))
    fd = central_difference(f_eager, x0, rel_step=1e-6)
    assert np.all(np.isfinite(grad)) and np.all(grad != 0)
    np.testing.assert_allclose(grad, fd, rtol=1e-5)
    assert np.all(grad[:3] < 0)  # more absorption, less light out


def test_hierarchical_sum_converges_to_every_source_alone(small):
    scene, points, trace, prepared, _ = small
    m = scene.material.medium
    exact_prep, _, info = prepare_photon(scene, points=points, trace=trace, eps=1e-9)
    # eps -> 0: every pair is one source with its own plane.
    assert info["n_interactions"] == len(points[0]) * trace.sources.n
    exact = np.asarray(_photon_exitance(exact_prep, m))
    # Nodes (power-weighted centroids, averaged planes) approximate it within a few percent at the default
    # eps = 0.05 (the worst: dim points far from the spot in the channel with the shortest diffusion length), and
    # the error shrinks with eps.
    finer, _, _ = prepare_photon(scene, points=points, trace=trace, eps=0.01)
    rel = [np.abs(np.asarray(_photon_exitance(p, m)) - exact) / exact for p in (prepared, finer)]
    assert np.median(rel[0]) < 0.02 and rel[0].max() < 0.15, (np.median(rel[0]), rel[0].max())
    assert np.median(rel[1]) < 0.005 and rel[1].max() < 0.03, (np.median(rel[1]), rel[1].max())
    assert rel[1].max() < 0.5 * rel[0].max()


def test_prepare_photon_reports_the_full_walk_for_a_non_convex_mesh():
    scene = box_scene(GRAD_MATERIAL, mesh={"builtin": "torus", "major_radius": 10.0, "minor_radius": 3.0,
                                           "major_sections": 32, "minor_sections": 16},
                      light={"type": "directional", "direction": [0.3, 0.0, -1.0], "intensity": 1.0})
    pts = np.array([[10.0, 0.0, 3.0], [-13.0, 0.0, 0.0]])
    nrm = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])
    _, plan, info = prepare_photon(scene, n_photons=500, points=(pts, nrm))
    items = plan.items
    assert info["photon_walk"] == "full"
    tally = {k: np.asarray(v) for k, v in info["photon_tally"].items()}
    assert set(tally) == set(TALLIES)
    lhs = tally["emitted"] + tally["reentered"]
    rhs = sum(tally[k] for k in TALLIES if k not in ("emitted", "reentered"))
    np.testing.assert_allclose(lhs, rhs, rtol=1e-9)
    walk_item = next(i for i in items if i.name == "photon walks")
    assert walk_item.included and "re-enter" in walk_item.reason


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"n_photons": 0}, r"prepare_photon\(n_photons=0\)"),
    ({"eps": 0.0}, r"prepare_photon\(eps=0.0\)"),
    ({"eps": math.nan}, r"prepare_photon\(eps=nan\)"),
    ({"kappa": "bogus"}, r"prepare_photon\(kappa='bogus'\)"),
    ({"n_photons": 50, "points": (np.zeros((3, 3)), np.zeros((2, 3)))}, r"prepare_photon\(points="),
])
def test_prepare_photon_bad_input_names_the_argument(kwargs, match):
    with pytest.raises(ValueError, match=match):
        prepare_photon(box_scene(GRAD_MATERIAL), **kwargs)


# --- the example scenes ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["photon_marble_edge", "photon_backlit_slab", "photon_blocker"])
def test_example_scenes_render(name):
    scene = load_scene(EXAMPLES / f"{name}.toml")
    result = render(scene, "photon", n_photons=3000, resolution=(16, 12))
    image, report = result.image, result.report
    assert image.shape == (12, 16, 3)
    assert np.isfinite(image).all() and np.all(image >= 0)
    assert (image > 0).mean() > 0.2  # the object fills part of the frame and is lit
    assert report["method"] == "photon" and report["n_sources"] > 100
    assert report["resolution"] == [16, 12]
    if name == "photon_blocker":
        assert report["n_pairs_blocked"] > 0
        assert report["photon_tally"]["blocked"][0] > 0
    else:
        assert report["n_pairs_blocked"] == 0
    if name == "photon_backlit_slab":
        # Everything seen came through the slab: the camera's side is opposite the sources' incidence plane.
        assert report["n_interactions_multipole"] > 0.5 * report["n_interactions"]


def test_blocker_casts_a_dark_band_through_the_skin():
    scene = load_scene(EXAMPLES / "photon_blocker.toml")
    x = np.array([0.0, 2.0, 20.0, -20.0])  # above the bar (|x| < 4), and well clear of it
    pts = np.c_[x, np.zeros_like(x), np.full_like(x, 6.0)]  # the top face, z = 6
    nrm = np.tile([0.0, 0.0, 1.0], (len(x), 1))
    out = []
    for s in (scene, scene_with(scene, blockers=())):
        prepared, _, info = prepare_photon(s, n_photons=3000, points=(pts, nrm))
        out.append(np.asarray(_photon_exitance(prepared, s.material.medium)))
        assert np.isfinite(out[-1]).all() and np.all(out[-1] >= 0)
    with_bar, without = out
    assert info["n_pairs_blocked"] == 0
    # Red (the most penetrating channel of skin) through 12 mm: the bar removes most of it above itself ...
    assert np.all(with_bar[:2, 0] < 0.25 * without[:2, 0]), (with_bar[:, 0], without[:, 0])
    # ... and leaves the sides nearly untouched.
    np.testing.assert_allclose(with_bar[2:, 0], without[2:, 0], rtol=0.15)
