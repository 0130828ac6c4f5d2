"""Tangent frames (UV gradients, seams) and the least-squares planes of Eq. 8."""

import math

import numpy as np
import pytest

from jaxsss.layered.planes import fit_planes, neighbourhood_radius, planes_at
from jaxsss.layered.tangents import barycentric, frames_at, surface_frames, wrap_for
from jaxsss.render.meshes import builtin_mesh


def test_slab_gradients_are_exact():
    mesh = builtin_mesh("slab", width=100.0, depth=50.0, thickness=10.0, subdivisions=2)
    fr = surface_frames(mesh, (False, False), tile=(2.0, 3.0))
    top = fr.normal[..., 2] > 0.99
    np.testing.assert_allclose(fr.grad_u[top], np.broadcast_to([2.0 / 100.0, 0, 0], fr.grad_u[top].shape), atol=1e-15)
    np.testing.assert_allclose(fr.grad_v[top], np.broadcast_to([0, 3.0 / 50.0, 0], fr.grad_v[top].shape), atol=1e-15)


def test_sphere_seam_is_unwrapped():
    mesh = builtin_mesh("sphere", radius=10.0, subdivisions=3)
    assert wrap_for("builtin sphere (radius=10)") == (True, False) and wrap_for("file x.obj") == (False, False)
    fr = surface_frames(mesh, wrap_for("builtin sphere"))
    # No face spans more than a small part of the texture once unwrapped (away from the poles).
    spread = fr.uv[..., 0].max(axis=1) - fr.uv[..., 0].min(axis=1)
    equator = np.abs(mesh.triangles_center[:, 2]) < 5.0
    assert spread[equator].max() < 0.1
    # |grad u| is 1 / (2 pi rho) (rho the distance from the axis); |grad v| is 1 / (pi R), pointing away from the
    # north pole (downwards).
    face = np.flatnonzero(equator)[:50]
    pts = mesh.triangles_center[face]
    uv, n, T, B = frames_at(fr, mesh, face, pts)
    np.testing.assert_allclose(np.linalg.norm(T, axis=1) * 2 * np.pi * np.hypot(pts[:, 0], pts[:, 1]), 1.0, rtol=0.05)
    np.testing.assert_allclose(np.linalg.norm(B, axis=1) * np.pi * 10.0, 1.0, rtol=0.05)
    assert np.all(B[:, 2] < 0)
    assert np.allclose(np.einsum("ij,ij->i", T, n), 0, atol=1e-12)


def test_neighbourhood_radius_eq8():
    assert neighbourhood_radius(2.0, 0.01) == pytest.approx(-math.log(0.01) / 2.0)
    with pytest.raises(ValueError, match=r"eps=1.*\(0, 1\)"):
        neighbourhood_radius(1.0, 1.0)
    with pytest.raises(ValueError, match=r"sigma_t=0"):
        neighbourhood_radius(0.0, 0.1)


def test_sphere_planes_are_radial_and_below_the_surface():
    R = 20.0
    mesh = builtin_mesh("sphere", radius=R, subdivisions=4)
    fr = surface_frames(mesh)
    r = 3.0
    pl = fit_planes(mesh, fr.normal, r)
    assert pl.fitted.all()
    V = mesh.vertices[mesh.faces[:, 0]]
    np.testing.assert_allclose(np.einsum("ij,ij->i", pl.normal[:, 0], V / R), 1.0, atol=1e-3)
    # The plane through a spherical cap of radius ~r sits below the vertex by about the cap's mean sag, r^2/(4R)
    # (area weighted), within the discretisation (25%).
    sag = R - np.linalg.norm(pl.point[:, 0], axis=1)
    assert np.all(sag > 0)
    np.testing.assert_allclose(sag.mean(), r * r / (4 * R), rtol=0.25)


def test_box_planes_ignore_the_sides():
    mesh = builtin_mesh("box", extents=[20.0, 20.0, 20.0], subdivisions=3)
    fr = surface_frames(mesh, (True, False))
    pl = fit_planes(mesh, fr.normal, 4.0)
    top = fr.normal[..., 2] > 0.999
    np.testing.assert_allclose(pl.normal[top][:, 2], 1.0, atol=1e-12)
    np.testing.assert_allclose(pl.point[top][:, 2], 10.0, atol=1e-12)
    face = np.flatnonzero(top.all(axis=1))[:5]
    bary = barycentric(mesh, face, mesh.triangles_center[face])
    n, p = planes_at(pl, bary, face)
    np.testing.assert_allclose(n[:, 2], 1.0, atol=1e-12)
