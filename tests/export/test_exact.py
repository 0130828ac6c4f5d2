"""The exact half-space reference (jaxsss.export.exact): Chandrasekhar's reflection of a point-lit slab face, against
which both jaxsss's renderer and the exported Mitsuba scene are checked -- transport neither of them computed.

``mitsuba`` is a hard requirement here, as in test_mitsuba.py (``scalar_rgb``)."""

import math

import mitsuba as mi
import numpy as np
import pytest

from jaxsss.export import mitsuba as xm
from jaxsss.export.exact import point_lit_face
from jaxsss.render import parse_scene, render

MARGIN = 40.0  # mm from the face's edges: over four diffusion lengths of marble's red (8.5 mm)


def _slab(material, light=(0.0, -90.0, 130.0), resolution=16, **extra):
    """A 200 x 200 x 60 mm slab (face at z = 30) under one point light, seen obliquely from above."""
    return parse_scene({
        "mesh": {"builtin": "slab", "width": 200.0, "depth": 200.0, "thickness": 60.0},
        "material": {"eta": 1.0, **material},
        "light": [{"type": "point", "position": list(light), "intensity": 2.0e4}],
        "camera": {"position": [0.0, 90.0, 150.0], "look_at": [0.0, 0.0, 30.0], "up": [0.0, 0.0, 1.0],
                   "fov_deg": 30.0, "resolution": [resolution, resolution]},
        **extra,
    })


MARBLE = _slab({"name": "marble"})  # single-scattering albedo 0.99904 / 0.99844 / 0.99764


def test_face_reference_geometry_and_values():
    ref = point_lit_face(MARBLE, MARGIN)
    assert ref.image.shape == (16, 16, 3) and ref.mask.shape == ref.mu_i.shape == (16, 16)
    assert ref.mask.all(), "the view lies within the face, at least MARGIN inside its edges"
    assert np.all(np.isfinite(ref.image)) and np.all(ref.image > 0)
    # One pixel by hand: the camera ray meets the plane z = 30; L = (I mu_i / r^2) a H(mu_i) H(mu_o) / (4 pi (mu_i +
    # mu_o)).
    import dataclasses

    from jaxsss.render.bssrdf import chandrasekhar_h
    from jaxsss.render.camera import camera_rays

    rays = camera_rays(dataclasses.replace(MARBLE.camera, spp=1))
    i = 5 * 16 + 11
    o, d = np.asarray(rays.origins[i]), np.asarray(rays.directions[i])
    d = d / np.linalg.norm(d)
    p = o + (30.0 - o[2]) / d[2] * d
    to_light = np.array([0.0, -90.0, 130.0]) - p
    r2 = to_light @ to_light
    mu_i, mu_o = to_light[2] / np.sqrt(r2), -d[2]
    a = np.array([2.19, 2.62, 3.0]) / (np.array([0.0021, 0.0041, 0.0071]) + np.array([2.19, 2.62, 3.0]))
    h = lambda mu: np.array([float(chandrasekhar_h(mu, ac)) for ac in a])  # noqa: E731
    expected = 2.0e4 * mu_i / r2 * a * h(mu_i) * h(mu_o) / (4.0 * np.pi * (mu_i + mu_o))
    np.testing.assert_allclose(ref.image[5, 11], expected, rtol=1e-9)
    np.testing.assert_allclose(ref.mu_i[5, 11], mu_i, rtol=1e-12)
    # A margin wider than the view leaves the pixels near the face's edge out.
    assert 0 < point_lit_face(MARBLE, 80.0).mask.sum() < ref.mask.sum()


@pytest.mark.parametrize("key, value, match", [
    ("material", {"name": "marble", "eta": 1.4}, r"material.eta=1.4 is not supported"),
    ("material", {"sigma_a": 0.01, "sigma_s_prime": 1.0, "g": 0.9, "eta": 1.0}, r"material.g=0.9 is not supported"),
])
def test_face_reference_refuses_what_it_cannot_compute(key, value, match):
    scene = parse_scene({
        "mesh": {"builtin": "slab"}, key: value,
        "light": [{"type": "point", "position": [0.0, 0.0, 100.0], "intensity": 1.0}],
        "camera": {"position": [0.0, 1.0, 100.0], "look_at": [0.0, 0.0, 0.0], "resolution": [8, 8]},
    })
    with pytest.raises(ValueError, match=match):
        point_lit_face(scene, 10.0)
    with pytest.raises(ValueError, match=r"margin=0.0 is outside the allowed range \(0, inf\) mm"):
        point_lit_face(MARBLE, 0.0)


@pytest.mark.parametrize("material, light", [
    ({"name": "marble"}, (0.0, -90.0, 130.0)),
    # Grazing light, mu_i 0.124, between the oblique nodes; far enough that the irradiance is uniform over the view.
    ({"name": "skin1"}, (0.0, -40000.0, 5030.0)),
])
def test_renderer_reproduces_the_exact_half_space(material, light):
    """jaxsss's whole pipeline (samples, the white-oblique kernel, the near field, the exit) on a flat face: within 1%
    of exact transport per channel. Marble measured 0.998 / 0.998 / 0.998 at 48 x 48 before the first order was
    marched; 0.990 / 0.991 / 0.991 since (2026-11-30, at 16 and 48 pixels; skin1 1.002 / 0.997 / 0.992): the orders >= 2
    are mixed between the incidence nodes to every order's albedo, not to their own (docs/path_tracer.md, "Measured,
    not kept: the orders >= 2 mixed to their own albedo"). The grazing light is 110
    degrees from the camera about the slab, so the plan keeps the exit's current and the oblique azimuth there
    (jaxsss.render.oblique_azimuth): measured 1.002 / 0.997 / 0.991 (0.986 / 0.987 / 0.989 without the azimuth).
    Until 2026-11-29 that light stood 400 mm away (mu_i 0.11-0.15): the reference's ``L = E f_r`` is then off at
    first order, since grazing light leaves about 1.1 transport lengths ahead of its entry (the half-space walk's
    first moment, orders >= 2 at mu_i 0.1) while E falls by 0.74% per mm along the travel, which is 1.1 / 0.8 / 0.6%
    brighter in R / G / B than the reference; the renderer with the azimuth gave 1.012 / 1.003 / 0.994 there."""
    scene = _slab(material, light)
    ref = point_lit_face(scene, MARGIN)
    image = np.asarray(render(scene).image)
    ratio = image[ref.mask].mean(axis=0) / ref.image[ref.mask].mean(axis=0)
    np.testing.assert_allclose(ratio, 1.0, atol=0.01)


def test_exported_scene_reproduces_the_exact_half_space_at_marbles_albedo():
    """The exported integrator (volpathmis, rr_depth) in Mitsuba against exact transport at albedo 0.999: within
    1.5%. With Russian roulette from the 57th bounce (the rule before rr_depth's later start) this render came out
    2-3% dark, its missing light in rare fireflies (docs/path_tracer.md, "Mitsuba's Russian roulette at high
    albedo")."""
    mi.set_variant("scalar_rgb")
    ref = point_lit_face(MARBLE, MARGIN)
    image = xm.render_mitsuba(MARBLE, spp=256, seed=3).image
    ratio = image[ref.mask].mean(axis=0) / ref.image[ref.mask].mean(axis=0)
    np.testing.assert_allclose(ratio, 1.0, atol=0.015)


def _lit_face(mu_i: float, scale: float = 1.0, g: float = 0.9):
    """The slab (face at z = 30 scale) of g09_sphere's medium under a directional light at cosine ``mu_i``, seen at
    ``mu_o`` 0.725 along the light's flow, 12 x 12 pixels over a patch of 10 scale mm."""
    s, mu_o = math.sqrt(1.0 - mu_i**2), 0.725
    return parse_scene({
        "mesh": {"builtin": "slab", "width": 200.0 * scale, "depth": 200.0 * scale, "thickness": 60.0 * scale},
        "material": {"eta": 1.0, "g": g, "sigma_a": [0.05, 0.1, 0.2], "sigma_s_prime": 1.0},
        "light": [{"type": "directional", "direction": [0.0, s, -mu_i], "intensity": [1.0, 2.0, 0.5]}],
        "camera": {"position": [0.0, 150.0 * scale * math.sqrt(1 - mu_o**2), (150.0 * mu_o + 30.0) * scale],
                   "look_at": [0.0, 0.0, 30.0 * scale], "up": [0.0, 0.0, 1.0], "fov_deg": 4.0,
                   "resolution": [12, 12]},
    })


def test_single_scattering_face_by_hand_and_its_refusals():
    from jaxsss.export.exact import single_scattering_face

    scene = _lit_face(0.25)
    ref = single_scattering_face(scene, 20.0)
    assert ref.image.shape == (12, 12, 3) and ref.mask.all() and np.all(ref.image > 0)
    # The centre pixel by hand: L_1 = a p(theta) E mu_i / (mu_i + mu_o), HG g = 0.9, E = (1, 2, 0.5) W/mm^2.
    import dataclasses

    from jaxsss.render.camera import camera_rays

    rays = camera_rays(dataclasses.replace(scene.camera, spp=1))
    d = np.asarray(rays.directions[6 * 12 + 6])
    d = d / np.linalg.norm(d)
    to_light = np.array([0.0, -math.sqrt(1 - 0.25**2), 0.25])
    mu_o, c = -d[2], to_light @ d
    p = (1 - 0.81) / (4 * np.pi * (1 + 0.81 - 1.8 * c) ** 1.5)
    a = 10.0 / (10.0 + np.array([0.05, 0.1, 0.2]))  # sigma_s = sigma_s' / (1 - g) = 10 per mm
    np.testing.assert_allclose(ref.image[6, 6], a * p * np.array([1.0, 2.0, 0.5]) * 0.25 / (0.25 + mu_o), rtol=1e-9)
    # Invariant: ahead of the light's flow the first order is brighter than behind it (forward scattering).
    behind = _lit_face(0.25)
    behind = dataclasses.replace(behind, camera=dataclasses.replace(
        behind.camera, position=(0.0, -np.asarray(behind.camera.position)[1], behind.camera.position[2])))
    assert np.all(single_scattering_face(behind, 20.0).image[6, 6] < 0.2 * ref.image[6, 6])
    with pytest.raises(ValueError, match="material.eta"):
        single_scattering_face(_slab({"name": "marble", "eta": 1.3}), MARGIN)
    with pytest.raises(ValueError, match="margin"):
        single_scattering_face(scene, 0.0)


@pytest.mark.parametrize("mu_i, scale", [(0.1, 1.0), (1.0, 1.0), (0.1, 0.1)])
def test_mitsuba_skips_a_layer_below_the_boundary(mu_i, scale):
    """Mitsuba's first order (``max_depth = 2``) against the exact one is ``exp(-sigma_t epsilon / mu_i)``:
    single-precision rays leaving the null boundary start ``epsilon = RAY_EPSILON (1 + max |p_i|)`` inside it, so a
    camera path skips that layer and the light's shadow ray does not (jaxsss.export.mitsuba, "the layer below the
    boundary"). At the g = 0.9 references' scale grazing light loses a quarter of its first order; a tenth of the
    scene loses a tenth as much. This test fails when Mitsuba stops skipping (then the references' grazing light is
    right, and the note in docs/path_tracer.md, "Mitsuba's skipped layer", is stale)."""
    from jaxsss.export.exact import single_scattering_face

    mi.set_variant("scalar_rgb")
    scene = _lit_face(mu_i, scale)
    ref = single_scattering_face(scene, 20.0 * scale)
    image = xm.render_mitsuba(scene, spp=1024, seed=3, max_depth=2).image
    ratio = image[ref.mask].mean(axis=0) / ref.image[ref.mask].mean(axis=0)
    tau = xm.skipped_layer(scene, points=[[0.0, 0.0, 30.0 * scale]])[0]  # the patch: |x|, |y| < 5 scale mm
    # 3% of a 24% effect: at mu_i 0.1 the measured ratio moves by 1-2% with the samples and the variant (scalar_rgb
    # 0.765 / 0.772 at 256 / 1024 spp, llvm_ad_rgb 0.755 at 1024 spp on the central pixels; the model 0.757).
    np.testing.assert_allclose(ratio, np.exp(-tau / mu_i), rtol=0.03)
    if scale == 1.0 and mu_i == 0.1:
        assert np.all(ratio < 0.8)
