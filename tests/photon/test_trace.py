"""Photon tracing into meshes (jaxsss.photon.trace): exact power bookkeeping, where sources go, the first-scattering
depth, blockers, occluders and re-entry, the mesh Monte Carlo's diffuse reflectance against published half-space
values (all channels from one walk included) and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jaxsss.photon import TALLIES, emit_photons, trace_photons
from jaxsss.render.meshes import builtin_mesh
from jaxsss.render.rays import SceneGeometry
from jaxsss.render.scene import Light

DOWN = np.array([0.0, 0.0, -1.0])


def sun(direction=DOWN):
    return Light("directional", intensity=np.array([1.0, 1.0, 1.0]), direction=np.asarray(direction, float))


def pencil(height=500.0, cone_deg=0.2):
    """A narrow spot straight down on the origin: normal incidence on a small patch at the top face's centre."""
    return Light("spot", intensity=np.full(3, 1e4), position=np.array([0.0, 0.0, height]), direction=DOWN,
                 cone_deg=cone_deg)


def trace(geometry: SceneGeometry, light, n, sigma_a, sigma_s_prime, eta, *, seed=0, **kw):
    sphere = geometry.meshes[0].bounding_sphere.primitive
    photons = emit_photons([light], sphere.center, float(sphere.radius), n, seed=seed)
    return trace_photons(geometry, photons, sigma_a, sigma_s_prime, eta, seed=seed + 1, **kw)


def imbalance(tally):
    """Relative violation of emitted + reentered = missed + ... + capped, per channel."""
    lhs = tally["emitted"] + tally["reentered"]
    rhs = sum(tally[k] for k in TALLIES if k not in ("emitted", "reentered"))
    return np.abs(lhs - rhs) / lhs


def top_reflectance(box, result):
    """Diffuse reflectance: exit weight on the top face over the power that reached the object."""
    top = box.face_normals[result.exits.face][:, 2] > 0.5
    return result.exits.weight[top].sum(axis=0) / (result.tally["emitted"] - result.tally["missed"])


@pytest.fixture(scope="module")
def box():
    return builtin_mesh("box", extents=[40.0, 40.0, 20.0])


@pytest.fixture(scope="module")
def box_geometry(box):
    return SceneGeometry(box)


@pytest.fixture(scope="module")
def grey_full(box_geometry):
    """Identical channels, every walk to its end, the sun straight down (the disc is wider than the box)."""
    return trace(box_geometry, sun(), 4000, 0.1, 0.9, 1.5, walk="full")


@pytest.fixture(scope="module")
def deep_sources(box_geometry):
    """Sources only (first scattering), sigma_t' = 2/mm, the sun straight down (normal incidence)."""
    return trace(box_geometry, sun(), 12_000, [0.2, 0.2, 0.2], [1.8, 1.8, 1.8], 1.3, walk="sources", seed=5)


# --- power conservation -------------------------------------------------------------------------------------------

def test_identical_channels_conserve_power_exactly(grey_full):
    t = grey_full.tally
    assert set(t) == set(TALLIES)
    assert np.all(imbalance(t) < 1e-9), imbalance(t)
    np.testing.assert_array_equal(t["reweighted"], np.zeros(3))  # the analog walk: every ratio is exactly 1
    for name in ("missed", "reflected", "absorbed", "exited"):
        assert np.all(t[name] > 0), name
    for name in ("occluded", "blocked", "capped", "reentered"):
        np.testing.assert_array_equal(t[name], np.zeros(3), err_msg=name)
    # Normal incidence from air into eta = 1.5: 4% of what reaches the box is reflected at entry.
    np.testing.assert_allclose(t["reflected"], 0.04 * (t["emitted"] - t["missed"]), rtol=1e-9)
    # Every exit is recorded with its weight; the exits sum to the tally.
    np.testing.assert_allclose(grey_full.exits.weight.sum(axis=0), t["exited"], rtol=1e-12)
    assert grey_full.exits.order.min() >= 1  # straight down into 20 mm: every photon scatters before it leaves
    assert grey_full.n_photons == 4000


def test_distinct_channels_still_close_the_tallies_exactly(box_geometry):
    res = trace(box_geometry, sun(), 3000, [0.01, 0.2, 0.8], [0.5, 1.5, 3.0], 1.3, walk="full", seed=2)
    t = res.tally
    assert np.all(imbalance(t) < 1e-9), imbalance(t)
    # The mixture ratios' deviations from 1 are booked, nonzero, and small against the power (zero in expectation).
    assert np.all(t["reweighted"] != 0)
    assert np.all(np.abs(t["reweighted"]) < 0.1 * t["emitted"])
    np.testing.assert_allclose(res.exits.weight.sum(axis=0), t["exited"], rtol=1e-12)
    np.testing.assert_allclose(res.sigma_t_ref, [0.51, 1.7, 3.8], rtol=1e-15)


def test_sources_walk_records_no_exits_and_still_balances(box_geometry, deep_sources, grey_full):
    assert len(deep_sources.exits.order) == 0 and deep_sources.exits.weight.shape == (0, 3)
    assert np.all(imbalance(deep_sources.tally) < 1e-9)
    assert np.all(deep_sources.tally["capped"] > 0)  # the weight left after the first scattering
    # One source per photon that entered (a 20 mm deep box: every first flight scatters).
    again = trace(box_geometry, sun(), 4000, 0.1, 0.9, 1.5, walk="sources")
    assert again.sources.n == grey_full.sources.n
    np.testing.assert_allclose(again.sources.power.sum(axis=0), grey_full.sources.power.sum(axis=0), rtol=1e-12)


# --- sources ------------------------------------------------------------------------------------------------------

def test_sources_lie_inside_with_unit_normals_and_nonnegative_depth(box, grey_full, deep_sources):
    for res in (grey_full, deep_sources):
        src = res.sources
        assert src.n > 1000
        assert box.contains(src.position).all()
        lo, hi = box.bounds
        assert np.all((src.position > lo) & (src.position < hi))
        np.testing.assert_allclose(np.linalg.norm(src.normal, axis=1), 1.0, atol=1e-12)
        assert np.all(src.depth >= 0) and np.all(src.path > 0) and np.all(src.area > 0)
        assert np.all(src.power > 0)
        np.testing.assert_array_equal(src.generation, 0)  # a convex box: nothing re-enters


def test_entry_points_lie_on_the_lit_face(deep_sources):
    """The sun straight down on the box: every leg entered its top face (z = 10 mm), where the entry points are (the
    directly lit surface the renderer's dark pixels measure their distance from)."""
    entries = deep_sources.sources.entry_points()
    assert entries.shape == (deep_sources.sources.n, 3)
    np.testing.assert_allclose(entries[:, 2], 10.0, atol=1e-9)


def test_normal_incidence_sources_sit_one_mean_free_path_deep(box_geometry, deep_sources):
    src = deep_sources.sources
    np.testing.assert_array_equal(src.normal, np.broadcast_to([0.0, 0.0, 1.0], src.normal.shape))
    np.testing.assert_allclose(src.cos_in, 1.0, rtol=1e-12)
    # Refraction keeps normal incidence straight: the depth is the first flight (which starts the self-intersection
    # offset below the surface), exponential with mean 1/sigma_t'.
    np.testing.assert_allclose(src.depth, src.path + box_geometry.offset, rtol=1e-9, atol=1e-12)
    assert src.n > 6000
    assert abs(src.depth.mean() / 0.5 - 1.0) < 0.05, src.depth.mean()
    assert abs(np.mean(src.depth > 1.0) - math.exp(-2.0)) < 0.02  # P(depth > 2 mean free paths)
    # Every source carries its photon's transmitted power (1 - F(1)) and the disc share of the sun as its area.
    sphere_r = float(builtin_mesh("box", extents=[40.0, 40.0, 20.0]).bounding_sphere.primitive.radius)
    np.testing.assert_allclose(src.area, math.pi * sphere_r**2 / 12_000, rtol=1e-12)
    f_1 = ((1.3 - 1.0) / (1.3 + 1.0)) ** 2
    np.testing.assert_allclose(src.power, (1.0 - f_1) * math.pi * sphere_r**2 / 12_000, rtol=1e-9)


def test_oblique_sun_sources_are_shallower_than_their_paths(box_geometry):
    d = np.array([math.sin(math.radians(50)), 0.0, -math.cos(math.radians(50))])
    src = trace(box_geometry, sun(d), 2000, 0.2, 1.8, 1.3, walk="sources", seed=9).sources
    top = src.normal[:, 2] > 0.5
    cos_t = math.sqrt(1.0 - (math.sin(math.radians(50)) / 1.3) ** 2)  # Snell
    np.testing.assert_allclose(src.cos_in[top], math.cos(math.radians(50)), rtol=1e-9)
    # The depth is the refracted first flight's vertical extent (except for the few legs that met the side face
    # x = +20 and reflected before scattering: their stored flight starts there).
    straight = np.abs(src.depth[top] - (src.path[top] * cos_t + box_geometry.offset)) < 1e-9
    assert straight.mean() > 0.97
    # The side face x = -20 faces the sun too: its sources carry that face's normal and depth.
    side = src.normal[:, 0] < -0.5
    assert side.sum() > 100 and top.sum() + side.sum() == src.n
    np.testing.assert_allclose(src.depth[side], src.position[side, 0] + 20.0, rtol=1e-9)


# --- blockers, occluders, re-entry ----------------------------------------------------------------------------------

def test_blocker_absorbs_what_reaches_it_and_holds_no_source():
    outer = builtin_mesh("box", extents=[20.0, 20.0, 20.0])
    bone = builtin_mesh("box", extents=[12.0, 12.0, 4.0])
    bone.apply_translation([0.0, 0.0, 5.0])  # 3 mm under the lit top face
    geometry = SceneGeometry(outer, [bone])
    res = trace(geometry, sun(), 3000, 0.05, 1.0, 1.3, walk="full", blocker_ids=(1,), seed=3)
    t = res.tally
    assert np.all(t["blocked"] > 0.01 * t["emitted"])
    np.testing.assert_array_equal(t["occluded"], 0.0)
    assert np.all(imbalance(t) < 1e-9)
    assert not bone.contains(res.sources.position).any()
    assert outer.contains(res.sources.position).all()
    # The same inner box as an occluder ends nothing from inside ...
    free = trace(SceneGeometry(outer), sun(), 3000, 0.05, 1.0, 1.3, walk="full", seed=3)
    np.testing.assert_array_equal(free.tally["blocked"], 0.0)
    assert np.all(free.tally["exited"] > t["exited"])


def test_occluder_shadows_the_photons_from_outside(box, box_geometry):
    plate = builtin_mesh("box", extents=[30.0, 50.0, 1.0])
    plate.apply_translation([-15.0, 0.0, 30.0])  # covers x < 0 above the box
    geometry = SceneGeometry(box, [plate])
    res = trace(geometry, sun(), 3000, 0.1, 0.9, 1.5, walk="sources", seed=4)
    t = res.tally
    assert np.all(t["occluded"] > 0.2 * t["emitted"])
    assert np.all(imbalance(t) < 1e-9)
    np.testing.assert_array_equal(t["blocked"], 0.0)
    # Straight down, a first scattering lies under its entry point: nothing under the plate.
    assert res.sources.n > 500 and res.sources.position[:, 0].min() >= 0.0


def test_light_leaving_a_torus_reenters_and_stores_again():
    torus = builtin_mesh("torus", major_radius=15.0, minor_radius=5.0, major_sections=48, minor_sections=24)
    assert not torus.is_convex
    d = np.array([0.3, 0.0, -1.0]) / math.hypot(0.3, 1.0)
    res = trace(SceneGeometry(torus), sun(d), 3000, 0.05, 1.0, 1.3, walk="full", seed=6)
    t = res.tally
    assert np.all(t["reentered"] > 0)
    assert np.all(imbalance(t) < 1e-9)
    gen = res.sources.generation
    assert (gen == 0).sum() > 1000 and (gen >= 1).sum() > 20
    assert np.all(res.exits.generation >= 0)
    assert torus.contains(res.sources.position).all()


# --- the mesh Monte Carlo against published half-space reflectance --------------------------------------------------

@pytest.fixture(scope="module")
def thick_box():
    box = builtin_mesh("box", extents=[40.0, 40.0, 30.0])
    return box, SceneGeometry(box)


def test_half_space_reflectance_with_mismatch_matches_giovanelli(thick_box):
    # MCML manual Table 6.2 (Giovanelli): albedo 0.9, g = 0, n = 1.5: R_diffuse = 0.2200, specular 0.04.
    box, geometry = thick_box
    n = 20_000
    res = trace(geometry, pencil(), n, 0.1, 0.9, 1.5, walk="full", seed=11)
    assert np.all(res.tally["missed"] == 0)
    np.testing.assert_allclose(res.tally["reflected"] / res.tally["emitted"], 0.04, rtol=1e-9)
    r = top_reflectance(box, res)
    tol = 3.0 * math.sqrt(0.22 * 0.78 / n) + 1e-3  # the binomial bound on the per-photon variance
    assert np.all(np.abs(r - 0.2200) < tol), (r, tol)
    np.testing.assert_allclose(r, r[0], rtol=1e-12)  # identical channels, one walk


def test_all_channels_from_one_walk_match_their_own_half_spaces(thick_box):
    # Index matched (n = 1), isotropic: R = 0.41495 at albedo 0.9 and 0.11523 at albedo 0.5 (the H-function values
    # of tests/mc/test_reference.py); a half-space's reflectance depends only on the albedo, so channels 0 and 2
    # (sigma_t' = 1 and 1.5) must agree with each other, and channel 1 must not follow them.
    box, geometry = thick_box
    n = 24_000
    res = trace(geometry, pencil(), n, [0.1, 1.0, 0.15], [0.9, 1.0, 1.35], 1.0, walk="full", seed=12)
    np.testing.assert_array_equal(res.tally["reflected"], 0.0)
    assert np.all(imbalance(res.tally) < 1e-9)
    r = top_reflectance(box, res)
    expect = np.array([0.41495, 0.11523, 0.41495])
    tol = 4.0 * np.sqrt(expect * (1 - expect) / n) + 1e-3
    assert np.all(np.abs(r - expect) < tol), (r, tol)


# --- bad input ----------------------------------------------------------------------------------------------------

@pytest.mark.parametrize(("kwargs", "match"), [
    ({"walk": "half"}, r"trace_photons\(walk='half'\)"),
    ({"sigma_a": -0.1}, r"trace_photons\(sigma_a=\[-0.1"),
    ({"sigma_a": 0.0, "sigma_s_prime": 0.0}, r"sigma_a \+ sigma_s' in \(0, inf\)"),
    ({"sigma_s_prime": np.inf}, r"trace_photons\(sigma_a="),
    ({"eta": 0.0}, r"trace_photons\(eta=0.0\)"),
    ({"eta": np.nan}, r"trace_photons\(eta=nan\)"),
    ({"roulette_chance": 0.0}, r"trace_photons\(roulette_chance=0.0\)"),
    ({"roulette_chance": 1.5}, r"trace_photons\(roulette_chance=1.5\)"),
])
def test_bad_input_names_the_argument(box_geometry, kwargs, match):
    photons = emit_photons([sun()], [0.0, 0.0, 0.0], 30.0, 10)
    args = {"sigma_a": 0.1, "sigma_s_prime": 1.0, "eta": 1.3}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        trace_photons(box_geometry, photons, args.pop("sigma_a"), args.pop("sigma_s_prime"), args.pop("eta"),
                      **args)


def test_an_open_mesh_loses_light_through_its_hole_and_still_balances():
    """A box without its top: walks that head out through the hole end there (no source outside the mesh), and
    light that comes back in through the hole and meets a face from behind is not counted twice."""
    import trimesh

    box = builtin_mesh("box", extents=[20.0, 20.0, 20.0])
    open_box = trimesh.Trimesh(box.vertices, box.faces[box.face_normals[:, 2] < 0.5], process=False)
    geometry = SceneGeometry(open_box)
    for direction, sa, ss in (([0.5, 0.0, -1.0], 0.05, 1.0), ([-1.0, 0.0, 0.6], 0.005, 0.045)):
        result = trace(geometry, sun(direction), 3000, sa, ss, 1.3)
        assert imbalance(result.tally).max() < 1e-9
        assert result.sources.n > 0 and result.sources.position[:, 2].max() <= 10.0 + 1e-6
