"""Shading points (jaxsss.render.shading) and the camera's rays: the edge pixels that get the camera's edge_spp rays
(creases, and terminators on a turning surface), the dark pixels that get a grid of rays (the light past a terminator
falling off within a pixel), the per-ray weights of a pixel's mean, that the extra rays bring an edge or dark pixel to
its area mean, the camera's rays followed through thin walls at eta = 1 (see_through), and the object
seen in its own smooth boundary (seen_in_mirror)."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from jaxsss.medium import Medium
from jaxsss.render import make_plan, parse_scene, render, scene_with
from jaxsss.render.camera import camera_rays
from jaxsss.render.rays import SceneGeometry
from jaxsss.render.renderer import prepare
from jaxsss.render.samples import lit_positions
from jaxsss.render.shading import centre_light, dark_pixel_grid, edge_pixels, see_through, seen_in_mirror
from tests.gradcheck import assert_grad_matches_fd


def _sphere(light=None, **camera):
    return parse_scene({
        "mesh": {"builtin": "sphere", "radius": 10.0, "subdivisions": 4},
        "material": {"name": "skin1", "eta": 1.0},
        "light": [light or {"type": "point", "position": [-60.0, -40.0, 0.0], "intensity": 1.0e4}],
        "camera": {"position": [0.0, -60.0, 0.0], "look_at": [0.0, 0.0, 0.0], "fov_deg": 25.0,
                   "resolution": [24, 24], **camera},
    })


def test_camera_rays_for_some_pixels_carry_their_weights():
    cam = _sphere().camera
    rays = camera_rays(cam, spp=4, pixels=np.array([5, 77]))
    assert rays.origins.shape == (8, 3) and list(rays.pixel) == [5] * 4 + [77] * 4
    np.testing.assert_allclose(np.bincount(rays.pixel, weights=rays.weight)[[5, 77]], 1.0)
    full = camera_rays(cam)
    assert full.origins.shape == (24 * 24, 3) and np.all(full.weight == 1.0)
    # The centre ray of a pixel subset is the full image's.
    np.testing.assert_allclose(camera_rays(cam, pixels=np.array([77])).directions[0], full.directions[77])
    with pytest.raises(ValueError, match=r"spp=0 is outside the allowed range \[1, inf\)"):
        camera_rays(cam, spp=0)


def test_a_smooth_sphere_has_few_edge_pixels():
    """Its terminator is blurred by diffusion over more than a pixel: only where the surface turns fast (near the
    rim) does the terminator flag a pixel; the lit part has none."""
    scene = _sphere(resolution=[48, 48])
    geometry = SceneGeometry(scene.mesh, [])
    edges = edge_pixels(scene, geometry)
    rays = camera_rays(scene.camera)
    hit = geometry.first_hit(rays.origins, rays.directions).hit.reshape(48, 48)
    assert not np.any(edges & ~hit)
    assert edges.sum() <= 0.1 * hit.sum()
    assert not np.any(edges[:, :20])  # the light comes from the camera's left


def _box(light=None, **camera):
    return parse_scene({
        "mesh": {"builtin": "box", "extents": [20.0, 20.0, 20.0], "subdivisions": 3},
        "material": {"name": "marble", "eta": 1.0},
        "light": [light or {"type": "point", "position": [-60.0, -50.0, 40.0], "intensity": 1.0e4}],
        "camera": {"position": [35.0, -45.0, 35.0], "look_at": [0.0, 0.0, 0.0], "fov_deg": 40.0,
                   "resolution": [24, 24], **camera},
    })


def test_edge_pixels_follow_the_creases_of_a_box():
    scene = _box(resolution=[48, 48])
    geometry = SceneGeometry(scene.mesh, [])
    edges = edge_pixels(scene, geometry)
    rays = camera_rays(scene.camera)
    hits = geometry.first_hit(rays.origins, rays.directions)
    face_normal = np.where(hits.hit[:, None], np.asarray(scene.mesh.face_normals)[np.maximum(hits.face, 0)], 0.0)
    face_normal = face_normal.reshape(48, 48, 3)
    # A pixel next to one on another face of the box lies on a crease; the faces' middles do not.
    other = np.zeros((48, 48), dtype=bool)
    for dy, dx in ((0, 1), (1, 0), (0, -1), (-1, 0)):
        shifted = np.roll(np.roll(face_normal, dy, 0), dx, 1)
        other |= np.einsum("hwc,hwc->hw", shifted, face_normal) < 0.5
    hit = hits.hit.reshape(48, 48)
    crease = hit & other & np.roll(np.roll(hit, 1, 0), 1, 1) & np.roll(np.roll(hit, -1, 0), -1, 1)
    assert crease.sum() >= 20 and edges[crease].mean() > 0.8  # (smoothed vertex normals turn over a strip)
    middle = hit & ~np.any([np.roll(np.roll(other | ~hit, dy, 0), dx, 1) for dy in range(-2, 3)
                            for dx in range(-2, 3)], axis=0)
    assert middle.sum() >= 100 and not np.any(edges & middle)


def test_an_environment_on_a_smooth_sphere_has_no_edge_pixels():
    scene = parse_scene({
        "mesh": {"builtin": "sphere", "radius": 10.0, "subdivisions": 4},
        "material": {"name": "skin1", "eta": 1.0},
        "environment": {"radiance": 1.0, "samples": 8},
        "camera": {"position": [0.0, -60.0, 0.0], "look_at": [0.0, 0.0, 0.0], "fov_deg": 25.0,
                   "resolution": [24, 24]},
    })
    assert not edge_pixels(scene, SceneGeometry(scene.mesh, [])).any()


def test_edge_rays_bring_edge_pixels_to_their_area_mean():
    """On the box: the image with edge_spp = 9 at the edge pixels (spp 1 elsewhere) is closer to the pixels' area
    mean (spp 16 everywhere) at the edges than the pixel centres are, and the spp-1 image away from them (the same rays
    there; the hierarchical sum over a larger query set differs by up to 0.4% of the image's peak in a few dim
    pixels)."""
    base = _box(edge_spp=1)
    edges = edge_pixels(base, SceneGeometry(base.mesh, []))
    assert edges.sum() >= 10
    # The dipole kernel: edge rays are geometry, and the white kernel's three programs took 38 s cold (6 s with it).
    images = {k: np.asarray(render(scene_with(base, camera=dataclasses.replace(base.camera, spp=s, edge_spp=e)),
                                     bssrdf="dipole").image)
              for k, (s, e) in {"centre": (1, 1), "edge": (1, 9), "mean": (16, 1)}.items()}
    far = ~edges
    np.testing.assert_allclose(images["edge"][far], images["centre"][far], rtol=0.0,
                               atol=0.01 * float(images["centre"].max()))
    err_edge = np.abs(images["edge"][edges] - images["mean"][edges]).sum()
    err_centre = np.abs(images["centre"][edges] - images["mean"][edges]).sum()
    assert err_edge < 0.5 * err_centre, (err_edge, err_centre)


def test_edge_spp_is_checked_by_the_scene():
    from jaxsss.render import SceneError

    with pytest.raises(SceneError, match=r"\[camera.edge_spp\] 0 is outside the allowed range \[1, inf\)"):
        _sphere(edge_spp=0)
    assert _sphere().camera.edge_spp == 9 and _sphere(edge_spp=1).camera.edge_spp == 1


def test_midpoint_rays_sit_at_their_cells_centres():
    """``jitter=False``: an n x n grid at the cells' centres, whatever the seed (the dark pixels' midpoint rule)."""
    cam = _sphere().camera
    a = camera_rays(cam, spp=9, pixels=np.array([77]), jitter=False, seed=0)
    b = camera_rays(cam, spp=9, pixels=np.array([77]), jitter=False, seed=5)
    np.testing.assert_array_equal(a.directions, b.directions)
    # The middle cell's ray is the pixel centre's; the jittered grid's is not.
    np.testing.assert_allclose(a.directions[4], camera_rays(cam, pixels=np.array([77])).directions[0], atol=1e-15)
    assert not np.allclose(camera_rays(cam, spp=9, pixels=np.array([77]), seed=0).directions[4], a.directions[4])


def _behind(**kw):
    """The sphere lit from behind and to the left: the camera sees its terminator from the dark side."""
    return _sphere({"type": "point", "position": [-50.0, 50.0, 10.0], "intensity": 1.0e4}, **kw)


def _dark_grid(scene, **kw):
    geometry = SceneGeometry(scene.mesh, [])
    plan = make_plan(scene)
    from jaxsss.render.renderer import irradiance_pass

    samples = irradiance_pass(scene, plan)[1]
    centre = centre_light(scene, geometry)
    return dark_pixel_grid(scene, geometry, centre=centre, **{"lit": lit_positions(samples), **kw}), centre


def test_dark_pixels_past_the_terminator_get_a_grid():
    """skin1 (blue ``l_d`` 0.68 mm) at about 0.55 mm per pixel: the unlit pixels near the terminator, where the light
    that crept round falls off over a pixel or less, get a grid of 2 x 2 or 3 x 3 rays; lit pixels and the far dark
    side, where every channel has faded, keep their centre."""
    scene = _behind(resolution=[48, 48])
    side, centre = _dark_grid(scene)
    assert side.shape == (48, 48) and side.dtype.kind == "i"
    assert side.min() == 1 and side.max() == 3
    lit = (centre.on & (centre.direct > 0)).reshape(48, 48)
    assert lit.sum() >= 30 and np.all(side[lit] == 1) and np.all(side[~centre.on.reshape(48, 48)] == 1)
    dark = (centre.on & (centre.direct <= 0)).reshape(48, 48)
    assert (side[dark] > 1).sum() >= 30
    # Without the lit points every channel counts everywhere: at least as many rays, more on the far dark side.
    everywhere, _ = _dark_grid(scene, lit=None)
    assert np.all(everywhere >= side) and everywhere.sum() > side.sum()
    # The camera's edge_spp caps the grid (4 rays: 2 x 2; 1: none).
    assert _dark_grid(scene, max_side=2)[0].max() == 2
    assert _dark_grid(_behind(resolution=[48, 48], edge_spp=1))[0].max() == 1


def test_dark_pixel_grid_only_where_light_falls_off_steeply():
    """No grid without absorption (the light does not fall off), with a sky (it lights the dark side itself), or when
    nothing is lit; a faster fall-off (larger sigma_tr) never gets fewer rays."""
    scene = _behind(resolution=[32, 32])
    white = scene_with(scene, material=dataclasses.replace(scene.material, medium=Medium(
        jnp.zeros(3), scene.material.medium.sigma_s_prime, 1.0)))
    assert _dark_grid(white)[0].max() == 1
    sky = parse_scene({
        "mesh": {"builtin": "sphere", "radius": 10.0, "subdivisions": 4},
        "material": {"name": "skin1", "eta": 1.0},
        "light": [{"type": "point", "position": [-50.0, 50.0, 10.0], "intensity": 1.0e4}],
        "environment": {"radiance": 0.01, "samples": 8},
        "camera": {"position": [0.0, -60.0, 0.0], "look_at": [0.0, 0.0, 0.0], "fov_deg": 25.0,
                   "resolution": [32, 32]},
    })
    assert _dark_grid(sky)[0].max() == 1
    assert _dark_grid(scene, lit=np.zeros((0, 3)))[0].max() == 1
    medium = scene.material.medium
    denser = scene_with(scene, material=dataclasses.replace(scene.material, medium=Medium(
        2.0 * medium.sigma_a, 2.0 * medium.sigma_s_prime, 1.0)))
    assert np.all(_dark_grid(denser, lit=None)[0] >= _dark_grid(scene, lit=None)[0])


def test_dark_rays_bring_dark_pixels_to_their_area_mean():
    """On the sphere lit from behind (0.83 mm per pixel, skin1's blue falls off 1.2-4 e-folds across them): the image
    with the dark pixels' grids (spp 1 elsewhere) is closer to the pixels' area mean (36 jittered rays everywhere)
    there than the pixel centres are, by more than half (measured 0.36 of the centres' error; at 1.1 mm per pixel,
    where the 3 x 3 cap leaves cells of up to 2 e-folds, 0.53); elsewhere but at the
    edge pixels it is the centres' image (the hierarchical sum over a larger query set moves a few dim pixels by up to
    1% of the peak)."""
    base = _behind(edge_spp=1, resolution=[32, 32])
    scene = _behind(resolution=[32, 32])
    side, _ = _dark_grid(scene)
    edges = edge_pixels(scene, SceneGeometry(scene.mesh, []))  # these get edge_spp jittered rays instead
    grid = (side > 1) & ~edges
    assert grid.sum() >= 10
    # The dipole kernel: the grid is geometry, and the white kernel compiles for far longer.
    images = {k: np.asarray(render(scene_with(base, camera=dataclasses.replace(base.camera, spp=s, edge_spp=e)),
                                     bssrdf="dipole").image)
              for k, (s, e) in {"centre": (1, 1), "grid": (1, 9), "mean": (36, 1)}.items()}
    np.testing.assert_allclose(images["grid"][~grid & ~edges], images["centre"][~grid & ~edges], rtol=0.0,
                               atol=0.01 * float(images["centre"].max()))
    err_grid = np.abs(images["grid"][grid] - images["mean"][grid]).sum()
    err_centre = np.abs(images["centre"][grid] - images["mean"][grid]).sum()
    assert err_grid < 0.5 * err_centre, (err_grid, err_centre)
    # In blue, the fastest fall-off, the centres are darker than the means there (the fall-off is convex).
    assert images["centre"][grid][:, 2].sum() < 0.9 * images["mean"][grid][:, 2].sum()


def _wall_and_block(wall=1.0, gap=2.0):
    """A wall ``wall`` mm thick (y from -wall - gap to -gap) in front of a block 30 mm deep (y from 0), both 40 mm wide;
    a camera far along -y looking along +y, and a directional light along the view (irradiance 1 W/mm^2)."""
    front = trimesh.creation.box(extents=(40.0, wall, 40.0))
    front.apply_translation((0.0, -gap - wall / 2, 0.0))
    block = trimesh.creation.box(extents=(40.0, 30.0, 40.0))
    block.apply_translation((0.0, 15.0, 0.0))
    scene = parse_scene({
        "mesh": {"builtin": "box", "extents": [40.0, 30.0, 40.0]},
        "material": {"sigma_a": 0.06, "sigma_s_prime": 0.45, "eta": 1.0},
        "light": [{"type": "directional", "direction": [0.0, 1.0, 0.0], "intensity": 1.0}],
        "camera": {"position": [0.0, -2000.0, 0.0], "look_at": [0.0, 0.0, 0.0], "fov_deg": 0.6,
                   "resolution": [8, 8]},
    })
    return scene_with(scene, mesh=trimesh.util.concatenate([front, block]))


def test_see_through_finds_the_part_behind_a_thin_wall():
    scene = _wall_and_block(wall=1.0, gap=2.0)
    geometry = SceneGeometry(scene.mesh, [])
    pos = np.array([[0.0, -3.0, 0.0], [5.0, -3.0, 5.0]])
    normal = np.array([[0.0, -1.0, 0.0]] * 2)
    to_eye = normal.copy()
    parent, chord, more = see_through(geometry, pos, normal, to_eye)
    # Each ray leaves the wall after 1 mm and meets the block's face at y = 0; the block's far side is open air.
    assert list(parent) == [0, 1] and list(more.root) == [0, 1]
    np.testing.assert_allclose(chord, 1.0, atol=1e-6)
    np.testing.assert_allclose(more.through, 1.0, atol=1e-6)
    np.testing.assert_allclose(more.pos[:, 1], 0.0, atol=1e-6)
    np.testing.assert_allclose(more.normal, normal, atol=1e-9)
    # Shapes and extremes: no re-entry asked for, or a block alone (the ray leaves into nothing), adds nothing.
    for args in ((geometry, pos, normal, to_eye, 0), (SceneGeometry(trimesh.creation.box(extents=(40.0, 30.0, 40.0))),
                                                      pos + [0.0, -12.0, 0.0], normal, to_eye)):
        parent, chord, more = see_through(*args)
        assert parent.shape == chord.shape == (0,) and more.pos.shape == (0, 3)


def test_the_first_order_through_a_thin_wall_is_the_half_spaces():
    """Light along the view, eta = 1, isotropic: the first order seen through a wall and a gap into a deep block is
    the half-space's, albedo E / (8 pi) (the gap changes no path's length inside). Seen only to the wall's back it
    would be (1 - exp(-2 sigma_t c)) of it."""
    for wall in (0.5, 2.0):
        scene = _wall_and_block(wall=wall)
        prepared = prepare(scene, method="direct", plan=make_plan(scene, method="direct", bssrdf="auto"))[0]
        assert int(np.sum(np.asarray(prepared.query_through) > 0)) == prepared.n_queries // 2
        medium = scene.material.medium
        first = np.asarray(prepared.first_order_image(medium))[2:6, 2:6, 0]
        np.testing.assert_allclose(first, 0.45 / 0.51 / (8.0 * np.pi), rtol=2e-3)


def test_the_light_through_a_thin_wall_is_differentiable():
    """d / d(sigma_a, sigma_s') of the radiance the eye gets from the shaded points (the wall's veil on its diffuse
    light, the marched first order, the transmission to the block behind) against central differences. The whole
    image's gradient on this scene also matches (1e-9, off the cut beam's table nodes: at albedo 0.9 exactly central
    differences average two slopes), but its compilation takes 20-40 s; the sums' gradients are checked elsewhere."""
    scene = _wall_and_block(wall=1.0)
    prepared = prepare(scene, method="direct", plan=make_plan(scene, method="direct", bssrdf="auto"))[0]
    diffusion = jnp.linspace(0.5, 1.5, prepared.n_queries)[:, None] * jnp.ones(3)

    def f(x):
        return jnp.sum(prepared.radiance_from_diffusion(Medium(jnp.full(3, x[0]), jnp.full(3, x[1]), 1.0), diffusion))

    assert_grad_matches_fd(f, np.array([0.06, 0.45]), rtol=1e-6)


def test_the_plan_sees_through_non_convex_objects_at_eta_1():
    """On for the wall and block and the teapot at eta = 1 (with g = 0.9 too: the ray is not bent); off for a convex
    sphere, at eta = 1.4, and for the dipole (its line is not there); each with its reason."""
    from jaxsss.render.plan import make_plan as plan_for

    def line(scene, **kw):
        plan = plan_for(scene, **kw)
        items = [i for i in plan.items if i.name == "see-through"]
        assert len(items) == (0 if plan.bssrdf == "dipole" else 1)
        assert not items or items[0].included == plan.see_through
        return plan.see_through, items[0].reason if items else ""

    wall = _wall_and_block()
    assert line(wall, bssrdf="auto")[0]
    teapot = parse_scene({"mesh": {"builtin": "teapot", "size": 40.0},
                          "material": {"sigma_a": 0.01, "sigma_s_prime": 1.0, "eta": 1.0, "g": 0.9},
                          "light": [{"type": "point", "position": [0.0, -100.0, 80.0], "intensity": 1.0e4}],
                          "camera": {"position": [0.0, -150.0, 40.0], "look_at": [0.0, 0.0, 15.0],
                                     "resolution": [8, 8]}})
    assert line(teapot, bssrdf="auto")[0]
    on, why = line(_sphere(), bssrdf="auto")
    assert not on and "convex" in why
    glass = scene_with(wall, material=dataclasses.replace(wall.material, medium=Medium(0.06, 0.45, 1.4)))
    on, why = line(glass, bssrdf="auto")
    assert not on and "eta = 1.4" in why
    assert line(wall, bssrdf="dipole") == (False, "")


def _floor_and_block(eta=1.4, **material):
    """A floor slab (40 x 40 x 2 mm, top at z = 0) with a block standing on it (y from 5 to 15, z from 0.5 to 20.5),
    one mesh, under a constant environment; the camera looks down at the floor in front of the block, whose smooth
    boundary mirrors the block's face there."""
    floor = trimesh.creation.box(extents=(40.0, 40.0, 2.0))
    floor.apply_translation((0.0, 0.0, -1.0))
    block = trimesh.creation.box(extents=(40.0, 10.0, 20.0))
    block.apply_translation((0.0, 10.0, 10.5))
    scene = parse_scene({
        "mesh": {"builtin": "box", "extents": [40.0, 40.0, 2.0]},
        "material": {"sigma_a": 0.06, "sigma_s_prime": 0.45, "eta": eta, **material},
        "environment": {"radiance": [1.0, 1.0, 1.0], "samples": 16},
        "camera": {"position": [0.0, -200.0, 100.0], "look_at": [0.0, 0.0, 0.0], "fov_deg": 3.0,
                   "resolution": [8, 8]},
    })
    return scene_with(scene, mesh=trimesh.util.concatenate([floor, block]))


def test_seen_in_mirror_finds_the_part_the_boundary_mirrors():
    geometry = SceneGeometry(_floor_and_block().mesh, [])
    pos = np.array([[0.0, -2.0, 0.0], [3.0, -2.0, 0.0]])
    normal = np.array([[0.0, 0.0, 1.0]] * 2)
    to_eye = np.array([[0.0, -198.0, 100.0], [0.0, 0.0, 1.0]])
    to_eye /= np.linalg.norm(to_eye, axis=1, keepdims=True)
    parent, (mpos, mnormal, meye) = seen_in_mirror(geometry, pos, normal, to_eye)
    # The first point's mirror ray r = (0, 198, 100) / |.| meets the block's face y = 5 at z = 7 * 100 / 198; the
    # second looks straight up and its mirror ray leaves into the sky.
    assert list(parent) == [0]
    np.testing.assert_allclose(mpos[0], [0.0, 5.0, geometry.offset + 700.0 / 198.0], atol=1e-6)  # from the offset
    np.testing.assert_allclose(mnormal[0], [0.0, -1.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(meye[0], -np.array([0.0, 198.0, 100.0]) / np.hypot(198.0, 100.0), atol=1e-12)
    # A convex object never mirrors itself; no points, no output.
    sphere = SceneGeometry(_sphere().mesh, [])
    out = seen_in_mirror(sphere, np.array([[0.0, -10.0, 0.0]]), np.array([[0.0, -1.0, 0.0]]),
                         np.array([[0.0, -0.6, 0.8]]))
    assert out[0].shape == (0,) and out[1][0].shape == (0, 3)
    assert seen_in_mirror(geometry, pos[:0], normal[:0], to_eye[:0])[1][2].shape == (0, 3)


def test_the_object_in_its_mirror_adds_fresnel_times_its_radiance():
    """The plan adds the mirrored parts as points of their own; the eye gets ``F(eta, cos_o)`` (Fresnel at the
    mirroring point, an independent evaluation) of their radiance, in their parent's pixel with its ray's weight;
    nothing else changes. (The image is assembled from the radiance by ``image_from_radiance``; the diffusion radiance
    is compiled once, with the dipole kernel: the mirror does not depend on the kernel.)"""
    import jax

    from jaxsss.fresnel import fresnel_reflectance

    scene = _floor_and_block()
    plan = make_plan(scene, method="direct")
    assert plan.self_mirror
    on = prepare(scene, method="direct", plan=plan)[0]
    off = prepare(scene, method="direct", plan=plan._replace(self_mirror=False))[0]
    medium = scene.material.medium
    mirrored = np.asarray(on.query_mirrored)
    added = mirrored > 0
    assert off.query_mirrored is None and off.n_queries == int(np.sum(~added)) and 0 < added.sum() < on.n_queries
    np.testing.assert_array_equal(np.asarray(on.query_pos)[~added], np.asarray(off.query_pos))
    diffusion = jax.jit(lambda p, m: p.diffusion_radiance(m))(on, medium)
    radiance = np.asarray(on.radiance_from_diffusion(medium, diffusion))
    bare = dataclasses.replace(on, query_mirrored=None)
    unweighted = np.asarray(bare.radiance_from_diffusion(medium, diffusion))
    np.testing.assert_allclose(radiance[~added], unweighted[~added], rtol=1e-12)
    f = np.asarray(fresnel_reflectance(1.4, mirrored[added]))
    np.testing.assert_allclose(radiance[added], f[:, None] * unweighted[added], rtol=1e-10)
    assert np.all(unweighted[added] > 0) and np.all((f > 0.02) & (f < 0.2))
    # Each added point lands in its parent's pixel, with the parent ray's weight.
    pixel, weight = np.asarray(on.query_pixel), np.asarray(on.query_weight)
    assert set(zip(pixel[added], weight[added])) <= set(zip(pixel[~added], weight[~added]))
    image_on = np.asarray(on.image_from_radiance(radiance))
    image_off = np.asarray(on.image_from_radiance(np.where(added[:, None], 0.0, radiance)))
    extra = np.zeros((image_on.shape[0] * image_on.shape[1], 3))
    np.add.at(extra, pixel[added], radiance[added] * weight[added, None])
    np.testing.assert_allclose(image_on - image_off, extra.reshape(image_on.shape), atol=1e-12 * image_on.max())
    assert (extra > 0).any() and np.all(image_on >= image_off)


def test_the_object_in_its_mirror_is_differentiable_in_eta():
    scene = _floor_and_block()
    on = prepare(scene, method="direct", plan=make_plan(scene, method="direct"))[0]
    radiance = jnp.linspace(0.5, 1.5, on.n_queries)[:, None] * jnp.ones(3)

    def f(x):
        return jnp.sum(on.seen_through(Medium(jnp.full(3, 0.06), jnp.full(3, 0.45), x[0]), radiance))

    assert_grad_matches_fd(f, np.array([1.4]), rtol=1e-6)


def test_the_plan_mirrors_non_convex_objects_behind_a_smooth_boundary():
    """On for the floor and block at eta 1.4 under an environment; off, each with its reason, at eta = 1, with a
    rough boundary, under point lights only, and for a convex sphere."""
    from jaxsss.render.plan import make_plan as plan_for

    def line(scene):
        plan = plan_for(scene, bssrdf="auto")
        (item,) = [i for i in plan.items if i.name == "object in its own mirror"]
        assert item.included == plan.self_mirror
        return plan.self_mirror, item.reason

    assert line(_floor_and_block())[0]
    for scene, why in ((_floor_and_block(eta=1.0), "reflects nothing"),
                       (_floor_and_block(specular_roughness=0.3), "rough"),
                       (_wall_and_block(), "reflects nothing"),
                       (scene_with(_floor_and_block(), lights=_wall_and_block().lights), "no environment"),
                       (scene_with(_sphere(), lights=_floor_and_block().lights, material=_floor_and_block().material),
                        "convex")):
        on, reason = line(scene)
        assert not on and why in reason, reason
