"""The mesh Monte Carlo reference: the photon walks of :mod:`jaxsss.photon.trace` continued to their exits, and the
exitance they leave on the surface (ground truth for corners, edges, thin parts and blockers, which the slab engine
of :mod:`jaxsss.mc` cannot represent).

:func:`mesh_monte_carlo` traces a scene's lights into its mesh with ``walk="full"`` (every exit recorded, with its
weight and scattering order). :func:`surface_exitance` turns the exits into radiant exitance at given surface points
by a disc kernel: the exit power within ``radius`` of the point, on surface facing the same way (``n . n_q >
cos_max``, so the other face of an edge does not leak in), divided by the *surface area* inside that disc -- measured
on the mesh with uniform surface samples, so a disc cut by an edge or a hole is not under-counted. It is
``W/mm^2`` with a relative standard error from the exits' weights.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import trimesh
from scipy.spatial import cKDTree

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
                     max_order: int | None = None, cos_max: float = 0.5, area_samples: int = 400_000,
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
        cos_max: an exit (or area sample) counts only where its face normal has ``n . n_q > cos_max``.
        area_samples: uniform surface samples used to measure the area inside each disc.
    """
    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"surface_exitance(radius={radius!r}) is outside the allowed range (0, inf) mm")
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
    qtree = cKDTree(points)
    if len(x):
        pairs = qtree.sparse_distance_matrix(cKDTree(x), radius, output_type="ndarray")
        qi, xi = pairs["i"], pairs["j"]
        ok = np.einsum("ij,ij->i", normals[qi], n_x[xi]) > cos_max
        qi, xi = qi[ok], xi[ok]
        np.add.at(total, qi, w[xi])
        np.add.at(total2, qi, w[xi] ** 2)
        count = np.bincount(qi, minlength=q)
    # Surface area inside each disc, from uniform samples of the mesh.
    rng_pts, face = trimesh.sample.sample_surface(mesh, area_samples, seed=seed)
    a_each = float(mesh.area) / area_samples
    pairs = qtree.sparse_distance_matrix(cKDTree(rng_pts), radius, output_type="ndarray")
    qi, si = pairs["i"], pairs["j"]
    ok = np.einsum("ij,ij->i", normals[qi], mesh.face_normals[face[si]]) > cos_max
    area = np.bincount(qi[ok], minlength=q) * a_each
    safe = np.where(area > 0, area, np.nan)[:, None]
    return SurfaceExitance(total / safe, np.sqrt(total2) / safe, area, count)
