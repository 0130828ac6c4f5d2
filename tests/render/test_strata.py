"""Stratified points in the unit square (jaxsss.render.strata): a grid of exactly n cells, one point in each, so that
the mean of a function over the square has no unsampled corner (the camera's rays in a pixel, the bounce rays)."""

from __future__ import annotations

import numpy as np
import pytest

from jaxsss.render.camera import camera_rays
from jaxsss.render.samples import _cosine_directions
from jaxsss.render.strata import grid_shape, unit_square


@pytest.mark.parametrize("n, shape", [(1, (1, 1)), (4, (2, 2)), (7, (1, 7)), (8, (2, 4)), (9, (3, 3)), (12, (3, 4))])
def test_the_grid_has_exactly_n_cells(n, shape):
    assert grid_shape(n) == shape


def test_bad_counts_are_refused():
    with pytest.raises(ValueError, match=r"grid_shape\(n=0\) is outside the allowed range \[1, inf\)"):
        grid_shape(0)


@pytest.mark.parametrize("n", [2, 5, 8, 9, 16])
def test_one_point_in_each_cell(n):
    a, b = grid_shape(n)
    u = unit_square(np.random.default_rng(3), 50, n)
    assert u.shape == (50, n, 2) and np.all((u >= 0.0) & (u < 1.0))
    cell = np.floor(u[..., 1] * a).astype(int) * b + np.floor(u[..., 0] * b).astype(int)
    assert np.all(np.sort(cell, axis=1) == np.arange(n))
    # Without a generator: the cells' centres, the same for every row.
    mid = unit_square(None, 2, n)
    np.testing.assert_allclose(mid[0], mid[1])
    np.testing.assert_allclose(mid.mean(axis=1), 0.5)


@pytest.mark.parametrize("n", [3, 8])
def test_the_mean_over_the_square_is_unbiased(n):
    """The mean of ``u0 u1`` (1/4 over the square) from many rows: no corner is left out (a 3 x 3 grid with 8 of its
    cells used gave 0.22)."""
    u = unit_square(np.random.default_rng(0), 20000, n)
    assert abs(np.mean(u[..., 0] * u[..., 1]) - 0.25) < 0.002


def test_eight_rays_per_pixel_cover_the_pixel():
    """The camera's 8 rays per pixel (a 2 x 4 grid) average to the pixel's centre direction."""
    from jaxsss.render import parse_scene

    cam = parse_scene({"mesh": {"builtin": "sphere", "radius": 10.0}, "material": {"name": "skin1"},
                       "light": [{"type": "point", "position": [0.0, -60.0, 0.0], "intensity": 1.0}],
                       "camera": {"position": [0.0, -60.0, 0.0], "look_at": [0.0, 0.0, 0.0], "fov_deg": 25.0,
                                  "resolution": [8, 8]}}).camera
    many = camera_rays(cam, spp=8, pixels=np.full(4000, 27), seed=1)
    centre = camera_rays(cam, pixels=np.array([27])).directions[0]
    np.testing.assert_allclose(many.directions.mean(axis=0) / np.linalg.norm(many.directions.mean(axis=0)), centre,
                               atol=2e-5)


def test_bounce_directions_are_cosine_distributed():
    """About the normal z: the mean cosine of cosine-distributed directions is 2/3, and the azimuth is uniform."""
    d = _cosine_directions(np.tile([[0.0, 0.0, 1.0]], (5000, 1)), 8, np.random.default_rng(2)).reshape(-1, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    assert abs(d[:, 2].mean() - 2.0 / 3.0) < 0.003
    assert np.all(d[:, 2] >= 0.0) and abs(d[:, 0].mean()) < 0.005 and abs(d[:, 1].mean()) < 0.005
