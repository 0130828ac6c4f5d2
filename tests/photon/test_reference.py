"""The mesh Monte Carlo reference (jaxsss.photon.reference): the disc-kernel exitance on synthetic exits (uniform
exitance recovered in the middle of a face, next to an edge and in a corner, with the area measured on the mesh; the
other face of an edge and the scattering orders kept apart), and the photon method against it on the side face of a
box lit next to its edge."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jaxsss.photon import Exits
from jaxsss.photon.reference import mesh_monte_carlo, surface_exitance
from jaxsss.photon.render import _photon_exitance, prepare_photon
from jaxsss.render.meshes import builtin_mesh
from jaxsss.render.scene import parse_scene

TOTAL = np.array([3.0, 6.0, 9.0])  # W through the top face (three channels)


def disc_area_cut_by_edge(r, h):
    """Area of a disc of radius ``r`` whose centre is ``h`` (< r) from a straight edge, on the centre's side."""
    return math.pi * r * r - (r * r * math.acos(h / r) - h * math.sqrt(r * r - h * h))


@pytest.fixture(scope="module")
def cube():
    return builtin_mesh("box", extents=[10.0, 10.0, 10.0])  # faces at +-5


def jittered(k, rng):
    """``(k*k, 2)`` stratified points in [-5, 5]^2 (one per cell of a k x k grid)."""
    ij = np.stack(np.meshgrid(np.arange(k), np.arange(k), indexing="ij"), -1).reshape(-1, 2)
    return (ij + rng.random(ij.shape)) / k * 10.0 - 5.0


@pytest.fixture(scope="module")
def uniform_exits(cube):
    """Exits spread uniformly (jittered grids) over the top face, carrying TOTAL, with scattering orders 0..3; and
    much heavier exits on the side face x = +5 (1 W each, 400 per mm^2) that must not leak into the top face's
    estimates."""
    rng = np.random.default_rng(0)
    top = np.c_[jittered(500, rng), np.full(500 * 500, 5.0)]
    side_yz = jittered(200, rng)
    side = np.c_[np.full(len(side_yz), 5.0), side_yz]
    n_top = len(top)
    top_face = int(np.flatnonzero(cube.face_normals[:, 2] > 0.99)[0])
    side_face = int(np.flatnonzero(cube.face_normals[:, 0] > 0.99)[0])
    weight = np.r_[np.broadcast_to(TOTAL / n_top, (n_top, 3)), np.full((len(side), 3), 1.0)]
    order = np.r_[rng.permutation(np.arange(n_top) % 4), np.full(len(side), 5)]
    face = np.r_[np.full(n_top, top_face), np.full(len(side), side_face)]
    return Exits(np.r_[top, side], weight, order, face, np.zeros(len(order), np.int64))


POINTS = np.array([
    [0.0, 0.0, 5.0],  # the middle of the top face
    [2.0, -3.0, 5.0],
    [4.8, 0.0, 5.0],  # 0.2 mm from the edge x = 5: the disc is cut, its area measured on the mesh
    [-4.8, 4.8, 5.0],  # near a corner: cut twice
])
SIDE_POINTS = np.array([[5.0, 0.0, 4.8], [5.0, 0.0, 0.0]])  # the same edge seen from the side face x = 5


@pytest.fixture(scope="module")
def estimates(cube, uniform_exits):
    """One estimate (many area samples) at the top-face points, then the side-face points."""
    pts = np.r_[POINTS, SIDE_POINTS]
    normals = np.r_[np.tile([0.0, 0.0, 2.0], (len(POINTS), 1)),  # not unit: normalised by the function
                    np.tile([1.0, 0.0, 0.0], (len(SIDE_POINTS), 1))]
    return surface_exitance(uniform_exits, cube, pts, normals, 1.0)


def test_uniform_exits_give_total_over_face_area(estimates):
    res = estimates._replace(**{k: v[:len(POINTS)] for k, v in estimates._asdict().items()})
    expect = TOTAL / 100.0  # W / mm^2 over the 10 x 10 face
    np.testing.assert_allclose(res.value, np.broadcast_to(expect, res.value.shape), rtol=0.05)
    # The area inside each disc, on the top face only.
    np.testing.assert_allclose(res.area[:2], math.pi, rtol=0.04)
    np.testing.assert_allclose(res.area[2], disc_area_cut_by_edge(1.0, 0.2), rtol=0.04)
    assert res.area[3] < 0.8 * res.area[2]
    # About 2500 exits per mm^2, and the standard error of equal weights is value / sqrt(count).
    np.testing.assert_allclose(res.count[:2], 2500 * math.pi, rtol=0.02)
    np.testing.assert_allclose(res.stderr, res.value / np.sqrt(res.count)[:, None], rtol=1e-12)


def test_side_face_exits_count_on_the_side_only(cube, uniform_exits, estimates):
    # Only the heavy side exits (1 W each, 400 per mm^2) count on the side face, next to the edge too.
    value, area = estimates.value[len(POINTS):], estimates.area[len(POINTS):]
    np.testing.assert_allclose(value, 400.0, rtol=0.05)
    np.testing.assert_allclose(area[0], disc_area_cut_by_edge(1.0, 0.2), rtol=0.04)
    # The face filter is what keeps the top face's exits out next to the edge: the area is measured by rays down
    # the normal, which only see faces facing the point's way, so cos_max must stay in (0, 1).
    nrm = np.tile([1.0, 0.0, 0.0], (len(SIDE_POINTS), 1))
    strict = surface_exitance(uniform_exits, cube, SIDE_POINTS, nrm, 1.0, seed=3)
    near_edge = np.linalg.norm(uniform_exits.position - SIDE_POINTS[0], axis=1) <= 1.0
    assert strict.count[0] < np.count_nonzero(near_edge)  # exits of the top face within the ball are left out
    with pytest.raises(ValueError, match=r"cos_max=-1.*\(0, 1\)"):
        surface_exitance(uniform_exits, cube, SIDE_POINTS, nrm, 1.0, cos_max=-1.0)


def test_scattering_orders_are_selected(cube, uniform_exits):
    kw = {"seed": 3}
    nrm = np.tile([0.0, 0.0, 1.0], (len(POINTS), 1))
    every = surface_exitance(uniform_exits, cube, POINTS, nrm, 1.0, **kw)
    high = surface_exitance(uniform_exits, cube, POINTS, nrm, 1.0, min_order=2, **kw)
    low = surface_exitance(uniform_exits, cube, POINTS, nrm, 1.0, max_order=1, **kw)
    two = surface_exitance(uniform_exits, cube, POINTS, nrm, 1.0, min_order=2, max_order=2, **kw)
    # The same area samples: the order classes add up exactly.
    np.testing.assert_array_equal(high.area, every.area)
    np.testing.assert_array_equal(high.count + low.count, every.count)
    np.testing.assert_allclose(high.value + low.value, every.value, rtol=1e-12)
    # Orders 0..3 in equal shares: orders >= 2 carry half, order 2 alone a quarter.
    np.testing.assert_allclose(high.value / every.value, 0.5, rtol=0.04)
    np.testing.assert_allclose(two.value / every.value, 0.25, rtol=0.06)
    none = surface_exitance(uniform_exits, cube, POINTS, nrm, 1.0, min_order=4, **kw)
    np.testing.assert_array_equal(none.value, 0.0)
    np.testing.assert_array_equal(none.count, 0)


def test_points_without_exits_have_zero_exitance(cube, uniform_exits):
    res = surface_exitance(uniform_exits, cube, [[0.0, 0.0, -5.0]], [[0.0, 0.0, -1.0]], 1.0)
    np.testing.assert_array_equal(res.value, 0.0)
    assert res.count[0] == 0 and res.area[0] > 2.0


@pytest.mark.parametrize("radius", [0.0, -1.0, math.nan, math.inf])
def test_bad_radius_raises(cube, uniform_exits, radius):
    with pytest.raises(ValueError, match=r"surface_exitance\(radius="):
        surface_exitance(uniform_exits, cube, POINTS, np.tile([0.0, 0.0, 1.0], (len(POINTS), 1)), radius)


# --- validation: the photon method against the mesh Monte Carlo at an edge -----------------------------------------

def relative_l2(model, reference):
    return float(np.linalg.norm(model - reference) / np.linalg.norm(reference))


def test_photon_method_matches_mesh_monte_carlo_over_the_edge():
    # A 30 x 30 x 20 box lit by a narrow spot 3 mm from its edge x = 15 (top face z = 10): the light that diffuses
    # over the edge leaves through the side face, where the photon method's sources (entered through the top face)
    # see the exit point at gamma = pi/2. Compare the multiply scattered exitance (order >= 2) down the side face.
    scene = parse_scene({
        "mesh": {"builtin": "box", "extents": [30.0, 30.0, 20.0]},
        "material": {"sigma_a": 0.01, "sigma_s_prime": 0.99, "eta": 1.3},
        "light": [{"type": "spot", "position": [12.0, 0.0, 210.0], "direction": [0.0, 0.0, -1.0],
                   "cone_deg": 0.5, "intensity": 1e6}],
        "camera": {"position": [80.0, 0.0, 50.0], "look_at": [0.0, 0.0, 0.0], "resolution": [8, 8]},
    }, path="<test>")
    z = np.linspace(9.9, 0.0, 12)
    pts = np.c_[np.full_like(z, 15.0), np.zeros_like(z), z]
    nrm = np.tile([1.0, 0.0, 0.0], (len(z), 1))

    mc = mesh_monte_carlo(scene, 100_000, seed=3)
    assert mc.exits.order.size > 10_000
    # The disc area near the edge needs many surface samples (the box has 4200 mm^2; a 0.5 mm disc cut by the edge
    # holds ~0.5 mm^2): at the default 400k samples its noise (~12%) exceeds the exits' (~5%).
    ref = surface_exitance(mc.exits, scene.mesh, pts, nrm, 0.5, min_order=2)
    assert np.all(ref.count > 20)
    prepared, _, info = prepare_photon(scene, n_photons=50_000, points=(pts, nrm))
    assert info["n_interactions_multipole"] == 0  # gamma = pi/2 exactly: no image pairs
    model = np.asarray(_photon_exitance(prepared, scene.material.medium))
    assert np.isfinite(model).all() and np.all(model > 0)
    # Identical channels: every channel the same, in the model and in the reference.
    np.testing.assert_allclose(model, model[:, :1].repeat(3, axis=1), rtol=1e-12)
    m, r = model[:, 0], ref.value[:, 0]
    # Measured ~0.06 (the MC noise is ~5% near the edge, ~20% at the far end); scaled by 1.3 it is ~0.3.
    err = relative_l2(m, r)
    assert err < 0.2, (err, m / r)
    assert abs(m.sum() / r.sum() - 1.0) < 0.1
    # The bound rejects a clearly wrong model.
    assert relative_l2(2.0 * m, r) > 0.2 and relative_l2(0.5 * m, r) > 0.2
    # Exitance falls away from the edge in both.
    assert m[0] > 4 * m[-1] and r[0] > 4 * r[-1]
