"""Photon emission (jaxsss.photon.emit): each light's photons carry exactly its flux into the object's bounding
sphere, point and spot lights only sample directions that can reach it, and bad input names the argument."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jaxsss.photon import emit_photons
from jaxsss.render.scene import Light

CENTRE = np.array([1.0, -2.0, 3.0])
RADIUS = 5.0


def directional(intensity=(1.0, 2.0, 0.5), direction=(0.0, 0.0, -1.0)):
    d = np.asarray(direction, dtype=np.float64)
    return Light("directional", intensity=np.asarray(intensity, dtype=np.float64), direction=d / np.linalg.norm(d))


def point(position, intensity=(100.0, 50.0, 10.0)):
    return Light("point", intensity=np.asarray(intensity, dtype=np.float64), position=np.asarray(position, float))


def spot(position, direction, cone_deg, falloff_deg=0.0, intensity=(1e3, 2e3, 3e3)):
    d = np.asarray(direction, dtype=np.float64)
    return Light("spot", intensity=np.asarray(intensity, dtype=np.float64), position=np.asarray(position, float),
                 direction=d / np.linalg.norm(d), cone_deg=cone_deg, falloff_deg=falloff_deg)


def test_directional_power_is_irradiance_times_the_disc_and_rays_start_outside():
    light = directional(direction=(0.3, -0.2, -1.0))
    rays = emit_photons([light], CENTRE, RADIUS, 1000, seed=3)
    assert rays.origin.shape == (1000, 3) and rays.power.shape == (1000, 3)
    np.testing.assert_allclose(rays.power.sum(axis=0), light.intensity * math.pi * RADIUS**2, rtol=1e-12)
    np.testing.assert_allclose(rays.spread, math.pi * RADIUS**2 / 1000, rtol=1e-12)
    assert not rays.solid_angle.any()
    np.testing.assert_allclose(rays.direction, np.broadcast_to(light.direction, (1000, 3)), atol=1e-15)
    # Every ray starts outside the sphere, and its line passes within R of the centre (the disc across the beam).
    rel = rays.origin - CENTRE
    assert np.all(np.linalg.norm(rel, axis=1) > RADIUS)
    along = rel @ light.direction
    assert np.all(along < -RADIUS)  # before the sphere
    perp = np.linalg.norm(rel - along[:, None] * light.direction, axis=1)
    assert np.all(perp <= RADIUS * (1 + 1e-12))
    # Stratified over the disc: each quarter of the disc gets about a quarter of the photons.
    u = np.cross(light.direction, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(light.direction, u)
    quad = (rel @ u > 0).astype(int) * 2 + (rel @ v > 0)
    assert np.all(np.abs(np.bincount(quad, minlength=4) - 250) < 25)


@pytest.mark.parametrize("distance", [8.0, 40.0])
def test_point_light_outside_sends_its_intensity_times_the_cone_solid_angle(distance):
    axis = np.array([2.0, 1.0, -2.0]) / 3.0
    light = point(CENTRE - distance * axis)
    rays = emit_photons([light], CENTRE, RADIUS, 2000, seed=1)
    cos_max = math.sqrt(1.0 - (RADIUS / distance) ** 2)
    omega = 2.0 * math.pi * (1.0 - cos_max)
    np.testing.assert_allclose(rays.power.sum(axis=0), light.intensity * omega, rtol=1e-12)
    np.testing.assert_allclose(rays.spread.sum(), omega, rtol=1e-12)
    assert rays.solid_angle.all()
    np.testing.assert_allclose(rays.origin, np.broadcast_to(light.position, (2000, 3)))
    np.testing.assert_allclose(np.linalg.norm(rays.direction, axis=1), 1.0, atol=1e-12)
    # Every direction falls in the cone that holds the sphere (so every ray line meets the sphere) ...
    cos = rays.direction @ axis
    assert cos.min() >= cos_max - 1e-12
    rel = CENTRE - light.position
    t = rays.direction @ rel
    miss = np.linalg.norm(rel - t[:, None] * rays.direction, axis=1)
    assert np.all(miss <= RADIUS * (1 + 1e-9))
    # ... and fills it uniformly in solid angle (cos theta uniform in [cos_max, 1]).
    frac = (cos > 0.5 * (1.0 + cos_max)).mean()
    assert abs(frac - 0.5) < 0.02


def test_point_light_inside_the_sphere_sends_every_direction():
    light = point(CENTRE + np.array([1.0, 0.0, 0.0]), intensity=(2.0, 2.0, 2.0))
    rays = emit_photons([light], CENTRE, RADIUS, 4000, seed=2)
    np.testing.assert_allclose(rays.power.sum(axis=0), 4.0 * math.pi * light.intensity, rtol=1e-12)
    mean_dir = rays.direction.mean(axis=0)
    assert np.linalg.norm(mean_dir) < 0.03  # isotropic
    assert (rays.direction[:, 2] < -0.9).any() and (rays.direction[:, 2] > 0.9).any()


def test_spot_narrower_than_the_sphere_samples_its_own_cone():
    # 1 degree half-angle, aimed off-centre but inside the sphere's cone (half-angle ~ 5.7 degrees here).
    light = spot(CENTRE + np.array([0.0, 0.0, 50.0]), (0.02, 0.0, -1.0), cone_deg=1.0)
    rays = emit_photons([light], CENTRE, RADIUS, 3000, seed=4)
    cos_spot = math.cos(math.radians(1.0))
    cos_axis = rays.direction @ light.direction
    assert cos_axis.min() >= cos_spot - 1e-12
    assert np.all(rays.power > 0)  # no photon wasted outside the spot's cone
    omega = 2.0 * math.pi * (1.0 - cos_spot)
    np.testing.assert_allclose(rays.spread.sum(), omega, rtol=1e-12)
    np.testing.assert_allclose(rays.power.sum(axis=0), light.intensity * omega, rtol=1e-12)


def test_spot_wider_than_the_sphere_samples_the_sphere_with_its_angular_factor():
    distance = 30.0
    light = spot(CENTRE + np.array([0.0, 0.0, distance]), (0.0, 0.0, -1.0), cone_deg=60.0, falloff_deg=50.0)
    rays = emit_photons([light], CENTRE, RADIUS, 3000, seed=5)
    cos_max = math.sqrt(1.0 - (RADIUS / distance) ** 2)
    assert (rays.direction @ light.direction).min() >= cos_max - 1e-12
    omega = 2.0 * math.pi * (1.0 - cos_max)
    # Every direction is within the spot's inner cone (10 deg > the sphere's 9.6 deg): the factor is 1.
    theta = np.degrees(np.arccos(np.clip(rays.direction @ light.direction, -1, 1)))
    assert theta.max() < 10.0
    np.testing.assert_allclose(rays.power.sum(axis=0), light.intensity * omega, rtol=1e-12)
    # A spot of 9 degrees (inside the sphere's cone: it samples its own) with the falloff over all of it: each
    # photon carries the intensity times its solid angle times the factor at its direction (linear in the angle).
    soft = spot(light.position, light.direction, cone_deg=9.0, falloff_deg=9.0)
    r2 = emit_photons([soft], CENTRE, RADIUS, 3000, seed=5)
    th = np.degrees(np.arccos(np.clip(r2.direction @ soft.direction, -1, 1)))
    s = np.clip((9.0 - th) / 9.0, 0, 1)
    np.testing.assert_allclose(r2.power, s[:, None] * soft.intensity * r2.spread[:, None],
                               rtol=1e-12, atol=1e-300)


def test_photons_are_split_by_flux_and_each_light_keeps_its_own():
    lights = [directional(intensity=(1.0, 1.0, 1.0)), point(CENTRE + np.array([0.0, 30.0, 0.0]),
                                                             intensity=(30.0, 30.0, 30.0))]
    rays = emit_photons(lights, CENTRE, RADIUS, 5000, seed=0)
    assert len(rays.origin) == 5000
    flux_d = math.pi * RADIUS**2
    cos_max = math.sqrt(1.0 - (RADIUS / 30.0) ** 2)
    flux_p = 30.0 * 2.0 * math.pi * (1.0 - cos_max)
    counts = np.bincount(rays.light, minlength=2)
    assert abs(counts[0] / 5000 - flux_d / (flux_d + flux_p)) < 2e-3
    np.testing.assert_allclose(rays.power[rays.light == 0].sum(axis=0), flux_d, rtol=1e-12)
    np.testing.assert_allclose(rays.power[rays.light == 1].sum(axis=0), flux_p, rtol=1e-12)
    assert not rays.solid_angle[rays.light == 0].any() and rays.solid_angle[rays.light == 1].all()


def test_emission_is_deterministic_in_the_seed():
    light = point(CENTRE + np.array([0.0, 0.0, 20.0]))
    a = emit_photons([light], CENTRE, RADIUS, 300, seed=7)
    b = emit_photons([light], CENTRE, RADIUS, 300, seed=7)
    c = emit_photons([light], CENTRE, RADIUS, 300, seed=8)
    np.testing.assert_array_equal(a.direction, b.direction)
    assert not np.array_equal(a.direction, c.direction)


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"n_photons": 0}, r"emit_photons\(n_photons=0\)"),
    ({"n_photons": 2.5}, r"emit_photons\(n_photons=2.5\)"),
    ({"radius": 0.0}, r"emit_photons\(radius=0.0\)"),
    ({"radius": -1.0}, r"emit_photons\(radius=-1.0\)"),
    ({"radius": math.inf}, r"emit_photons\(radius=inf\)"),
    ({"lights": ()}, r"emit_photons\(lights="),
    ({"lights": [spot(CENTRE + np.array([0.0, 0.0, 50.0]), (0.0, 0.0, -1.0), cone_deg=10.0,
                       intensity=(0.0, 0.0, 0.0))]}, r"emit_photons\(lights="),
])
def test_bad_input_names_the_argument(kwargs, match):
    args = {"lights": [directional()], "centre": CENTRE, "radius": RADIUS, "n_photons": 10}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        emit_photons(args.pop("lights"), args.pop("centre"), args.pop("radius"), args.pop("n_photons"))
