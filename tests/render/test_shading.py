"""Shading points (jaxsss.render.shading) and the camera's rays: the edge pixels that get the camera's edge_spp rays
(silhouettes, terminators, shadow edges), the per-ray weights of a pixel's mean, and that the extra rays bring an edge
pixel to its area mean."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from jaxsss.render import parse_scene, render, scene_with
from jaxsss.render.camera import camera_rays
from jaxsss.render.rays import SceneGeometry
from jaxsss.render.shading import edge_pixels


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


def test_edge_pixels_are_the_silhouette_and_the_terminator():
    scene = _sphere()
    edges = edge_pixels(scene, SceneGeometry(scene.mesh, []))
    rays = camera_rays(scene.camera)
    hit = SceneGeometry(scene.mesh, []).first_hit(rays.origins, rays.directions).hit.reshape(24, 24)
    # Every pixel on the disc's rim (a neighbour misses) is an edge; none deep in the background.
    rim = hit & ~np.all([np.roll(hit, s, axis=a) for a in (0, 1) for s in (-1, 1)], axis=0)
    assert np.all(edges[rim])
    assert not edges[0, 0] and not edges[-1, -1]
    # The light comes from the camera's left: the terminator is a curve of edges inside the disc, right of its
    # centre; the lit left part of the disc has none.
    inner = hit & ~np.any([np.roll(np.roll(~hit, dy, 0), dx, 1) for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)
    assert (edges & inner).sum() >= 8
    assert np.all(np.nonzero(edges & inner)[1] >= 10)
    lit_interior = inner & (np.arange(24)[None, :] < 10)
    assert lit_interior.sum() > 20 and not np.any(edges & lit_interior)


def test_an_environment_alone_has_only_silhouette_edges():
    scene = parse_scene({
        "mesh": {"builtin": "sphere", "radius": 10.0, "subdivisions": 4},
        "material": {"name": "skin1", "eta": 1.0},
        "environment": {"radiance": 1.0, "samples": 8},
        "camera": {"position": [0.0, -60.0, 0.0], "look_at": [0.0, 0.0, 0.0], "fov_deg": 25.0,
                   "resolution": [24, 24]},
    })
    geometry = SceneGeometry(scene.mesh, [])
    edges = edge_pixels(scene, geometry)
    rays = camera_rays(scene.camera)
    hit = geometry.first_hit(rays.origins, rays.directions).hit.reshape(24, 24)
    interior = hit & np.all([np.roll(hit, s, axis=a) for a in (0, 1) for s in (-1, 1)], axis=0)
    interior &= np.all([np.roll(np.roll(hit, 1, 0), 1, 1), np.roll(np.roll(hit, -1, 0), -1, 1),
                        np.roll(np.roll(hit, 1, 0), -1, 1), np.roll(np.roll(hit, -1, 0), 1, 1)], axis=0)
    assert interior.sum() > 100 and not np.any(edges & interior)


def test_edge_rays_bring_edge_pixels_to_their_area_mean():
    """The image with edge_spp = 9 at the edge pixels (spp 1 elsewhere) is closer to the pixels' area mean (spp 36
    everywhere) at the edges than the pixel centres are, and the spp-1 image away from them (the same rays there;
    the hierarchical sum over a larger query set differs by up to 0.4% of the image's peak in a few dim pixels)."""
    base = _sphere(edge_spp=1)
    geometry = SceneGeometry(base.mesh, [])
    edges = edge_pixels(base, geometry)
    images = {k: np.asarray(render(scene_with(base, camera=dataclasses.replace(base.camera, spp=s, edge_spp=e))).image)
              for k, (s, e) in {"centre": (1, 1), "edge": (1, 9), "mean": (36, 1)}.items()}
    far = ~edges
    np.testing.assert_allclose(images["edge"][far], images["centre"][far], rtol=0.0,
                               atol=0.01 * float(images["centre"].max()))
    err_edge = np.abs(images["edge"][edges] - images["mean"][edges]).sum()
    err_centre = np.abs(images["centre"][edges] - images["mean"][edges]).sum()
    assert err_edge < 0.5 * err_centre, (err_edge, err_centre)
    # A background pixel's weights sum to one: with a grey background the rim pixels lie between it and the object.
    grey = scene_with(base, camera=dataclasses.replace(base.camera, edge_spp=9),
                      output=dataclasses.replace(base.output, background=np.full(3, 0.25)))
    img = np.asarray(render(grey).image)
    np.testing.assert_allclose(img[0, 0], 0.25, rtol=1e-12)
