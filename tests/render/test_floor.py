"""The scene floor's NumPy pieces that every method stands on: the plan (jaxsss.render.plan), the sample count and
placement (jaxsss.render.samples), the lights (jaxsss.render.lights) and the camera (jaxsss.render.camera)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jaxsss.render import builtin_mesh, make_plan
from jaxsss.render.camera import camera_frame, camera_rays
from jaxsss.render.lights import light_field, spot_factor
from jaxsss.render.plan import PlanItem, ScenePlan, explain_items
from jaxsss.render.samples import sample_count, sample_surface, self_irradiance, texture_lookup
from jaxsss.render.scene import Camera, Light
from tests.render.test_renderer import _scene


# --- the plan -------------------------------------------------------------------------------------------------------
def test_plan_of_a_lone_convex_sphere():
    plan = make_plan(_scene())
    items = {i.name: i for i in plan.items}
    assert isinstance(plan, ScenePlan) and plan.method == "hierarchical"
    # A convex mesh alone: no shadow rays, no indirect bounce, no bounce off itself, and the reasons say why.
    assert not plan.shadows and "convex mesh alone" in items["shadow rays"].reason
    assert not plan.indirect and "lone object" in items["indirect bounce"].reason
    assert not plan.self_bounce and "convex mesh" in items["self inter-reflection"].reason
    assert plan.n_samples >= 16 and f"{plan.n_samples} samples" in items["irradiance samples"].reason
    d = plan.to_dict()
    assert d["method"] == "hierarchical" and len(d["items"]) == len(plan.items)
    assert plan.explain().splitlines()[0].startswith("+ method")


@pytest.mark.parametrize("light, behind", [
    ({"type": "point", "position": [-20.0, -25.0, 10.0], "intensity": 300.0}, False),  # beside the camera
    ({"type": "point", "position": [5.0, 40.0, 0.0], "intensity": 300.0}, True),  # behind the sphere
    ({"type": "directional", "direction": [0.0, -1.0, 0.0], "intensity": 1.0}, True),  # travelling towards the camera
    ({"type": "directional", "direction": [0.0, 1.0, 0.0], "intensity": 1.0}, False),  # from behind the camera
])
@pytest.mark.parametrize("eta", [1.0, 1.3])
def test_plan_says_where_the_exits_azimuth_matters(light, behind, eta):
    """The plan notes the exit's azimuth, and warns where a light is more than 90 degrees from the camera about the
    object (the camera then sees the terminator from its dark side, docs/path_tracer.md). There it keeps the exit's
    current when the first order is marched (the current is the orders >= 2's), and says what it cannot fix. Behind a
    dielectric boundary it keeps every light's current, both signs, wherever the light is
    (:mod:`jaxsss.render.dielectric_current`)."""
    scene = _scene(lights=[light], material={"sigma_a": [0.05, 0.1, 0.2], "sigma_s_prime": [1.0, 1.5, 2.0],
                                             "eta": eta})
    plan = make_plan(scene, bssrdf="auto")
    item = {i.name: i for i in plan.items}["exit azimuth"]
    if eta != 1.0:
        assert item.included and plan.exit_current and plan.current_lights == (True,) and not plan.first_order
        assert "both signs" in item.reason and not item.reason.startswith("WARNING")
        return
    assert plan.first_order
    assert item.included == plan.exit_current == (behind and plan.first_order)
    assert item.reason.startswith("WARNING") == behind
    assert ("current is added" in item.reason) == item.included
    assert ("light[0] is" in item.reason) == behind
    # The angle: camera at (0, -30, 10) and the light about the sphere's centre.
    view = np.array([0.0, -30.0, 10.0])
    to_light = np.asarray(light.get("position", -np.asarray(light.get("direction", [0, 0, 0]), float)), float)
    angle = math.degrees(math.acos(view @ to_light / np.linalg.norm(view) / np.linalg.norm(to_light)))
    assert f"{angle:.0f}" in item.reason
    # Methods with their own transport model (no bssrdf) have no such line.
    assert "exit azimuth" not in {i.name for i in make_plan(scene).items}


@pytest.mark.parametrize("radius_in_l_u", [29.0, 31.0])
def test_plan_keeps_the_dielectric_current_by_the_objects_size_in_transport_lengths(radius_in_l_u):
    """Behind a dielectric boundary the exit's current is kept for objects under EXIT_CURRENT_MAX_RADIUS transport
    lengths (the largest channel's l_u) in radius and left out above, for every light, and the line says why; the
    ``[render].exit_current`` switch overrides it both ways."""
    from jaxsss.render.plan import EXIT_CURRENT_MAX_RADIUS

    material = {"sigma_a": [0.05, 0.1, 0.2], "sigma_s_prime": [0.95, 1.5, 2.0], "eta": 1.4}  # red: l_u = 1 mm
    lights = [{"type": "point", "position": [-20.0, -25.0, 10.0], "intensity": 300.0},
              {"type": "point", "position": [5.0, 40.0, 0.0], "intensity": 300.0}]
    mesh = {"builtin": "sphere", "radius": radius_in_l_u, "subdivisions": 2}
    kept = radius_in_l_u < EXIT_CURRENT_MAX_RADIUS
    plan = make_plan(_scene(mesh=mesh, material=material, lights=lights), bssrdf="auto")
    item = {i.name: i for i in plan.items}["exit azimuth"]
    assert item.included == plan.exit_current == kept and plan.current_lights == (kept, kept)
    assert f"{radius_in_l_u:.3g} l_u in radius" in item.reason and ("left out" in item.reason) == (not kept)
    for switch in ("on", "off"):
        forced = make_plan(_scene(mesh=mesh, material=material, lights=lights, render_opts={"exit_current": switch}),
                           bssrdf="auto")
        on = switch == "on"
        assert forced.current_lights == (on, on) and f"forced {switch} by [render].exit_current" in \
            {i.name: i for i in forced.items}["exit azimuth"].reason


def test_the_exit_current_switch_at_an_index_matched_boundary():
    """At eta = 1 the switch keeps (on) or leaves out (off) every light's current, on the camera's side or behind; on
    needs the first order marched and says so where the plan does not march it (g != 0)."""
    from jaxsss.render.scene import SceneError

    material = {"sigma_a": [0.05, 0.1, 0.2], "sigma_s_prime": [1.0, 1.5, 2.0], "eta": 1.0}
    lights = [{"type": "point", "position": [-20.0, -25.0, 10.0], "intensity": 300.0},  # beside the camera
              {"type": "point", "position": [5.0, 40.0, 0.0], "intensity": 300.0}]  # behind the sphere
    assert make_plan(_scene(material=material, lights=lights), bssrdf="auto").current_lights == (False, True)
    for switch, kept in (("on", (True, True)), ("off", (False, False))):
        plan = make_plan(_scene(material=material, lights=lights, render_opts={"exit_current": switch}), bssrdf="auto")
        assert plan.first_order and plan.current_lights == kept and plan.exit_current == (switch == "on")
    with pytest.raises(ValueError, match=r"exit_current = 'on' at eta = 1 needs .* first order"):
        make_plan(_scene(material={**material, "g": 0.5}, lights=lights, render_opts={"exit_current": "on"}),
                  bssrdf="auto")
    with pytest.raises(SceneError, match="render.exit_current"):
        _scene(render_opts={"exit_current": "sometimes"})
    # The dipole kernel has no current; methods with their own transport model say the switch does not apply.
    with pytest.raises(ValueError, match="exit_current = 'on' needs a white kernel"):
        make_plan(_scene(material=material, render_opts={"exit_current": "on"}), bssrdf="dipole")
    own = make_plan(_scene(material=material, render_opts={"exit_current": "on"}))
    item = {i.name: i for i in own.items}["exit azimuth"]
    assert not item.included and "does not apply" in item.reason and own.current_lights == ()


def test_plan_switches_and_forced_settings():
    floor = [{"builtin": "slab", "width": 80.0, "depth": 80.0, "thickness": 1.0, "translate": [0.0, 0.0, -6.0]}]
    plan = make_plan(_scene(occluders=floor))
    assert plan.shadows and plan.indirect  # an occluder casts shadows and reflects light
    forced = make_plan(_scene(occluders=floor, render_opts={"shadows": "off", "single_scattering": "on"}))
    items = {i.name: i for i in forced.items}
    assert not forced.shadows and "forced off" in items["shadow rays"].reason
    assert forced.single_scattering and "forced on" in items["single scattering"].reason


def test_plan_bounces_light_off_a_concave_object_unless_forced_off():
    teapot = {"builtin": "teapot", "size": 20.0, "resolution": 6}
    plan = make_plan(_scene(mesh=teapot))
    items = {i.name: i for i in plan.items}
    assert plan.self_bounce and "not convex" in items["self inter-reflection"].reason
    assert not plan.indirect  # nothing else in the scene
    off = make_plan(_scene(mesh=teapot, render_opts={"indirect": "off"}))
    assert not off.self_bounce and not off.indirect
    assert "forced off" in {i.name: i for i in off.items}["self inter-reflection"].reason
    assert make_plan(_scene(render_opts={"indirect": "on"})).self_bounce  # forced on even for the sphere


def test_plan_cut_off_radius_and_shared_channel():
    # sigma_tr = sqrt(3 sa st') = sqrt(3 * 0.5 * 2.5) = 1.94/mm: r_cut = ln(1/tol)/sigma_tr = 3.6 mm < the 10 mm sphere.
    grey = {"sigma_a": 0.5, "sigma_s_prime": 2.0, "eta": 1.3}
    plan = make_plan(_scene(material=grey))
    sigma_tr = math.sqrt(3 * 0.5 * 2.5)
    assert plan.r_cut == pytest.approx(math.log(1e3) / sigma_tr) and plan.shared_channel
    # Fitting turns both off (they depend on the material).
    fit = make_plan(_scene(material=grey), cutoff=False, share_channels=False)
    assert fit.r_cut is None and not fit.shared_channel
    assert make_plan(_scene(material=grey), method="direct").r_cut is None


def test_explain_items_marks_kept_and_left_out():
    text = explain_items([PlanItem("a", True, "kept"), PlanItem("longer", False, "left out")])
    assert text.splitlines() == ["+ a       kept", "- longer  left out"]


# --- samples --------------------------------------------------------------------------------------------------------
def test_sample_count_follows_the_paper_and_caps():
    n, why = sample_count(area=1000.0, l_u=0.5)
    assert n == math.ceil(1000.0 / (math.pi * 0.25)) and "A/(pi l_u^2)" in why
    assert sample_count(1000.0, 0.5, density=2.0)[0] == math.ceil(2000.0 / (math.pi * 0.25))
    capped, why = sample_count(1000.0, 0.5, max_samples=100)
    assert capped == 100 and "capped at max_samples = 100" in why
    assert sample_count(1e-6, 10.0)[0] == 16  # never fewer than 16


@pytest.mark.parametrize("method", ["stratified", "even"])
def test_samples_lie_on_the_mesh_and_carry_its_area(method):
    mesh = builtin_mesh("sphere", radius=3.0, subdivisions=3)
    pos, face, areas = sample_surface(mesh, 400, seed=1, method=method)
    assert pos.shape == (len(face), 3) and len(areas) == len(pos) > 200
    assert areas.sum() == pytest.approx(mesh.area, rel=1e-12)  # the total area is exact
    # On the faces they name (distance to the face's plane).
    n = mesh.face_normals[face]
    assert np.abs(np.einsum("ij,ij->i", pos - mesh.triangles[face, 0], n)).max() < 1e-9
    again = sample_surface(mesh, 400, seed=1, method=method)[0]
    np.testing.assert_array_equal(pos, again)  # deterministic for a seed


def test_stratified_samples_split_area_evenly():
    """Every half of a flat square gets its share of the points to within one point (stratification), where
    independent random points would scatter by sqrt(N)/2."""
    mesh = builtin_mesh("slab", width=10.0, depth=10.0, thickness=0.01, subdivisions=4)
    pos, _, _ = sample_surface(mesh, 2000, seed=3)
    top = pos[pos[:, 2] > 0]
    left = np.count_nonzero(top[:, 0] < 0)
    assert abs(left - len(top) / 2) <= 0.02 * len(top)


def test_sample_surface_rejects_bad_arguments():
    mesh = builtin_mesh("sphere", radius=1.0, subdivisions=1)
    with pytest.raises(ValueError, match="method='nope'"):
        sample_surface(mesh, 10, method="nope")
    with pytest.raises(ValueError, match=r"n=0\) is outside the allowed range \[1, inf\)"):
        sample_surface(mesh, 0)


def test_texture_lookup_is_bilinear_and_wraps():
    tex = np.arange(4.0).reshape(2, 2, 1)
    # Texel centres return their value; halfway between two texels, the mean; u = 1 wraps to u = 0.
    values = texture_lookup(tex, np.array([[0.25, 0.75], [0.5, 0.75], [1.25, 0.75]]))
    assert values.shape == (3, 1)
    assert values[0, 0] == pytest.approx(values[2, 0])


def test_self_irradiance_between_facing_plates_is_the_view_factor_integral():
    """A point on the inner face of one plate sees the other plate, lit by a point light midway between them:
    ``E_self = (1/pi) int E_B cos_A cos_B / r^2 dA_B = 2 h^2 int E_B(rho) rho drho / (rho^2 + h^2)^2`` with ``E_B(rho)
    = I (h/2) / (rho^2 + h^2/4)^(3/2)`` (plates 200 mm wide, 10 mm apart: the kernel falls as rho^-7, so they are
    infinite to 1e-8). A convex object never sees itself: zero."""
    from types import SimpleNamespace

    import trimesh
    from scipy.integrate import quad

    from jaxsss.render.rays import SceneGeometry

    h, intensity = 10.0, 300.0
    low = builtin_mesh("slab", width=200.0, depth=200.0, thickness=2.0)
    low.apply_translation([0.0, 0.0, -1.0])  # inner face at z = 0
    high = builtin_mesh("slab", width=200.0, depth=200.0, thickness=2.0)
    high.apply_translation([0.0, 0.0, h + 1.0])  # inner face at z = h
    geometry = SceneGeometry(trimesh.util.concatenate([low, high]))
    scene = SimpleNamespace(lights=[_light("point", position=[0.0, 0.0, h / 2], intensity=[intensity] * 3)])
    pts = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, h]])
    nrm = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    got = self_irradiance(scene, geometry, pts, nrm, n_rays=40_000, seed=3)

    def integrand(rho):
        return intensity * (h / 2) / (rho * rho + h * h / 4) ** 1.5 * rho / (rho * rho + h * h) ** 2

    want = 2.0 * h * h * quad(integrand, 0.0, 100.0, points=[h])[0]
    assert got.shape == (2, 3)
    np.testing.assert_allclose(got, want, rtol=0.03)  # 40,000 cosine-weighted rays: ~0.8% noise (measured 0.4, 1.6%)
    sphere = builtin_mesh("sphere", radius=5.0, subdivisions=3)
    on = SceneGeometry(sphere)
    normals = sphere.vertex_normals[:50]
    assert np.all(self_irradiance(scene, on, sphere.vertices[:50], normals, n_rays=64) == 0.0)


# --- lights ---------------------------------------------------------------------------------------------------------
def _light(kind, **kw):
    base = {"position": None, "direction": None, "intensity": np.array([1.0, 1.0, 1.0]), "cone_deg": 180.0,
            "falloff_deg": 0.0}
    base.update(kw)
    return Light(kind, **{k: (np.asarray(v, float) if k in ("position", "direction", "intensity") and v is not None
                              else v) for k, v in base.items()})


def test_point_light_follows_the_inverse_square_and_cosine_laws():
    light = _light("point", position=[0.0, 0.0, 10.0], intensity=[100.0, 50.0, 25.0])
    pts = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 0.0, -5.0]])
    nrm = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    f = light_field([light], pts, nrm)
    # E = I cos / d^2: straight below at 10 mm; 45 degrees at sqrt(200) mm; facing away: 0.
    np.testing.assert_allclose(f.irradiance[0, 0], np.array([100.0, 50.0, 25.0]) / 100.0)
    np.testing.assert_allclose(f.irradiance[1, 0], np.array([100.0, 50.0, 25.0]) / 200.0 * math.sqrt(0.5))
    np.testing.assert_array_equal(f.irradiance[2, 0], 0.0)
    np.testing.assert_allclose(f.cos[:, 0], [1.0, math.sqrt(0.5), 0.0])
    np.testing.assert_allclose(np.linalg.norm(f.to_light, axis=-1), 1.0)


def test_directional_light_is_irradiance_on_a_facing_surface():
    light = _light("directional", direction=[0.0, 0.0, -1.0], intensity=[2.0, 2.0, 2.0])
    nrm = np.array([[0.0, 0.0, 1.0], [math.sqrt(0.5), 0.0, math.sqrt(0.5)]])
    f = light_field([light], np.zeros((2, 3)), nrm)
    np.testing.assert_allclose(f.irradiance[:, 0, 0], [2.0, 2.0 * math.sqrt(0.5)])


def test_spot_factor_and_cone():
    assert spot_factor(np.array([1.0]), 30.0, 0.0)[0] == 1.0
    assert spot_factor(np.array([math.cos(math.radians(31.0))]), 30.0, 0.0)[0] == 0.0
    # Smoothstep over the falloff: half way in angle gives 1/2.
    assert spot_factor(np.array([math.cos(math.radians(25.0))]), 30.0, 10.0)[0] == pytest.approx(0.5)
    spot = _light("spot", position=[0.0, 0.0, 10.0], direction=[0.0, 0.0, -1.0], cone_deg=30.0)
    pts = np.array([[0.0, 0.0, 0.0], [20.0, 0.0, 0.0]])  # on the axis; 63 degrees off it
    f = light_field([spot], pts, np.tile([0.0, 0.0, 1.0], (2, 1)))
    assert f.irradiance[0, 0, 0] > 0 and f.irradiance[1, 0, 0] == 0.0


def test_shadow_rays_block_lights_behind_an_occluder():
    from jaxsss.render.rays import SceneGeometry

    blocker = builtin_mesh("slab", width=4.0, depth=4.0, thickness=0.5)
    blocker.apply_translation([0.0, 0.0, 5.0])
    ground = builtin_mesh("slab", width=40.0, depth=40.0, thickness=0.5)
    geometry = SceneGeometry(ground, [blocker])
    light = _light("point", position=[0.0, 0.0, 20.0], intensity=[1.0, 1.0, 1.0])
    pts = np.array([[0.0, 0.0, 0.25], [15.0, 0.0, 0.25]])  # under the blocker; in the open
    nrm = np.tile([0.0, 0.0, 1.0], (2, 1))
    lit = light_field([light], pts, nrm, geometry).irradiance[:, 0, 0]
    unshadowed = light_field([light], pts, nrm).irradiance[:, 0, 0]
    assert lit[0] == 0.0 and unshadowed[0] > 0 and lit[1] == pytest.approx(unshadowed[1])


# --- camera ---------------------------------------------------------------------------------------------------------
def _camera(**kw):
    base = dict(position=np.array([0.0, -10.0, 0.0]), look_at=np.zeros(3), up=np.array([0.0, 0.0, 1.0]),
                fov_deg=60.0, resolution=(4, 2), spp=1)
    base.update(kw)
    return Camera(**base)


def test_camera_frame_is_orthonormal_and_right_handed():
    f, r, u = camera_frame(_camera())
    np.testing.assert_allclose(f, [0.0, 1.0, 0.0])
    np.testing.assert_allclose(r, [1.0, 0.0, 0.0], atol=1e-15)  # looking along +y with z up: +x is to the right
    # (right, up, -forward) is right-handed: the camera looks down its own -z axis.
    np.testing.assert_allclose(np.cross(r, u), -f, atol=1e-15)
    np.testing.assert_allclose([f @ r, f @ u, r @ u], 0.0, atol=1e-15)


def test_camera_rays_cover_the_field_of_view():
    rays = camera_rays(_camera(resolution=(64, 32)))
    assert rays.shape == (32, 64) and rays.spp == 1 and len(rays.pixel) == 64 * 32
    np.testing.assert_allclose(np.linalg.norm(rays.directions, axis=1), 1.0)
    # Row 0 is the top: its rays point up (+z); column 0 is the left (-x, the camera looks along +y).
    d = rays.directions.reshape(32, 64, 3)
    assert np.all(d[0, :, 2] > 0) and np.all(d[-1, :, 2] < 0) and np.all(d[:, 0, 0] < 0)
    # The vertical field of view: the angle between the top and bottom edge rays approaches fov_deg.
    top, bottom = d[0, 32], d[-1, 32]
    assert math.degrees(math.acos(top @ bottom)) == pytest.approx(60.0 * 31 / 32, rel=0.02)


def test_camera_rays_with_samples_per_pixel_are_stratified_and_seeded():
    rays = camera_rays(_camera(spp=4), seed=2)
    assert len(rays.pixel) == 8 * 4 and np.all(np.bincount(rays.pixel) == 4)
    np.testing.assert_array_equal(rays.directions, camera_rays(_camera(spp=4), seed=2).directions)
    assert not np.array_equal(rays.directions, camera_rays(_camera(spp=4), seed=3).directions)
    assert camera_rays(_camera(), resolution=(6, 3)).shape == (3, 6)


def test_plan_keeps_the_exits_current_for_the_lights_behind():
    """The back-lit skin1 sphere (eta 1, g 0: the first order is marched): lit from behind alone, the plan keeps the
    exit's current and the far field's correction for that light; with a second light on the camera's side it keeps
    them for the light behind only and sums the other apart (both act on every pair, and the far field would undo the
    front light's terminator), and says so; with a second light behind too it keeps them for both."""
    import tomllib
    from pathlib import Path

    from jaxsss.render.scene import parse_scene

    path = Path(__file__).parents[2] / "benchmarks" / "references" / "materials" / "skin1_sphere_backlit.toml"
    data = tomllib.loads(path.read_text())
    behind = data["light"][0]
    cases = [([behind], (True,)),
             ([behind, {"type": "point", "position": [-90.0, -70.0, 50.0], "intensity": 1e4}], (True, False)),
             ([behind, {"type": "point", "position": [90.0, 100.0, -20.0], "intensity": 1e4}], (True, True))]
    for lights, kept in cases:
        plan = make_plan(parse_scene({**data, "light": lights}, path=str(path), base_dir=path.parent), bssrdf="auto")
        item = {i.name: i for i in plan.items}["exit azimuth"]
        assert plan.first_order and item.included and plan.exit_current and plan.current_lights == kept, item
        assert item.reason.startswith("WARNING")
        assert ("light[1] (on the camera's side) is summed apart" in item.reason) == (not all(kept))
