"""The mesh Monte Carlo reference: the photon walks of :mod:`jaxsss.photon.trace` continued to their exits, and the
exitance they leave on the surface (ground truth for corners, edges, thin parts and blockers, which the slab engine
of :mod:`jaxsss.mc` cannot represent).

:func:`mesh_monte_carlo` traces a scene's lights into its mesh with ``walk="full"`` (every exit recorded, with its
weight and scattering order). :func:`surface_exitance` turns the exits into radiant exitance at given surface points
by a disc kernel: the exit power within ``radius`` of the point, on surface facing the same way (``n . n_q >
cos_max``, so the other face of an edge does not leak in), divided by the *surface area* inside that ball --
measured on the mesh by casting a stratified grid of rays down the point's normal onto the surface (each hit counts
its projected area over ``|n_f . n_q|``), so a disc cut by an edge or a hole is not under-counted. This is exact for
flat pieces up to the stratification (1/4096 of the disc by default; uniform surface samples, tried first, left 12%
noise on a 0.5 mm disc of a 4200 mm^2 box even with 4e5 samples). It is ``W/mm^2`` with a standard error from the
exits' weights.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from jaxsss.validate import check_integer
from jaxsss.photon.trace import Exits, PhotonTrace

__all__ = ["SurfaceExitance", "mesh_monte_carlo", "surface_exitance"]


def mesh_monte_carlo(scene, n_photons: int, *, seed: int | None = None, progress: bool = False) -> PhotonTrace:
    """Trace ``n_photons`` into the scene's mesh with every walk continued to its exit (see the module)."""
    from jaxsss.photon.render import trace_scene

    return trace_scene(scene, n_photons, walk="full", seed=seed, progress=progress)


class SurfaceExitance(NamedTuple):
    """Exitance estimates at ``Q`` points: ``value`` ``(Q, C)`` W/mm^2, ``stderr`` ``(Q, C)`` (its standard error),
    ``area`` ``(Q,)`` mm^2 of surface inside each disc, ``count`` ``(Q,)`` exits inside."""

    value: np.ndarray
    stderr: np.ndarray
    area: np.ndarray
    count: np.ndarray


def surface_exitance(exits: Exits, mesh: trimesh.Trimesh, points, normals, radius: float, *, min_order: int = 0,
                     max_order: int | None = None, cos_max: float = 0.5, area_rays: int = 4096,
                     seed: int = 0) -> SurfaceExitance:
    """Radiant exitance at surface ``points`` from Monte Carlo exits, by a disc kernel of ``radius`` (mm).

    Args:
        exits: from a ``walk="full"`` trace.
        mesh: the translucent mesh (for the surface area inside each disc).
        points, normals: ``(Q, 3)`` surface points (mm) and outward normals.
        radius: the disc radius, mm, ``> 0``; bias grows like ``radius^2`` times the profile's curvature, noise
            like ``1 / radius``.
        min_order, max_order: keep exits with ``min_order <= order <= max_order`` scattering events (``2, None``: the
            multiply scattered light that diffusion models).
        cos_max: an exit (or surface hit) counts only where its face normal has ``n . n_q > cos_max``, in (0, 1).
        area_rays: stratified rays per point that measure the surface area inside the disc, ``>= 16``.
        seed: jitter of the stratified rays.
    """
    from jaxsss.photon.emit import _concentric_disc, _jittered_square
    from jaxsss.render.rays import SceneGeometry

    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"surface_exitance(radius={radius!r}) is outside the allowed range (0, inf) mm")
    if not (0.0 < cos_max < 1.0):
        raise ValueError(f"surface_exitance(cos_max={cos_max!r}) is outside the allowed range (0, 1): the area is "
                         "measured by rays down the point's normal, which only see faces facing its way")
    check_integer(area_rays, "area_rays", 16, owner="surface_exitance")
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    keep = exits.order >= min_order
    if max_order is not None:
        keep &= exits.order <= max_order
    x = exits.position[keep]
    w = exits.weight[keep]
    n_x = mesh.face_normals[exits.face[keep]]  # the translucent mesh is object 0: its faces come first
    q = len(points)
    c = exits.weight.shape[1]
    total = np.zeros((q, c))
    total2 = np.zeros((q, c))
    count = np.zeros(q, np.int64)
    if len(x):
        pairs = cKDTree(points).sparse_distance_matrix(cKDTree(x), radius, output_type="ndarray")
        qi, xi = pairs["i"], pairs["j"]
        ok = np.einsum("ij,ij->i", normals[qi], n_x[xi]) > cos_max
        qi, xi = qi[ok], xi[ok]
        np.add.at(total, qi, w[xi])
        np.add.at(total2, qi, w[xi] ** 2)
        count = np.bincount(qi, minlength=q)
    area = _disc_area(SceneGeometry(mesh), points, normals, radius, cos_max, area_rays,
                      _concentric_disc(_jittered_square(area_rays, np.random.default_rng(seed))))
    safe = np.where(area > 0, area, np.nan)[:, None]
    return SurfaceExitance(total / safe, np.sqrt(total2) / safe, area, count)


def _disc_area(geometry, points, normals, radius, cos_max, n_rays, disc, chunk: int = 256):
    """Surface area (mm^2) within ``radius`` of each point on faces facing its way: rays from a stratified disc of
    that radius, ``radius`` above the tangent plane, cast down the normal; a hit counts ``pi r^2 / n / |n_f . n_q|``."""
    helper = np.where((np.abs(normals[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    t1 = np.cross(normals, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normals, t1)
    area = np.zeros(len(points))
    for s in range(0, len(points), chunk):
        sl = slice(s, s + chunk)
        p, n = points[sl], normals[sl]
        origin = (p[:, None, :] + radius * (disc[None, :, :1] * t1[sl, None, :] + disc[None, :, 1:] * t2[sl, None, :])
                  + radius * n[:, None, :])
        direction = np.broadcast_to(-n[:, None, :], origin.shape)
        hits = geometry.first_hit(origin.reshape(-1, 3), direction.reshape(-1, 3))
        n_f = geometry.combined.face_normals[np.maximum(hits.face, 0)].reshape(origin.shape)
        cos = np.einsum("qkj,qj->qk", n_f, n)
        dist = np.linalg.norm(np.nan_to_num(hits.position).reshape(origin.shape) - p[:, None, :], axis=-1)
        ok = hits.hit.reshape(cos.shape) & (cos > cos_max) & (dist <= radius)
        area[sl] = np.where(ok, 1.0 / np.where(ok, cos, 1.0), 0.0).sum(axis=1) * (np.pi * radius * radius / n_rays)
    return area
