"""Least-squares planes approximating the surface around each vertex (Francois et al., Sec. 2.2, Eqs. 7-8 and 14).

For a vertex ``V`` the plane is fitted to the mesh vertices inside the sphere of radius ``r = -log(eps) / sigma_t``
(Eq. 8: light entering farther away than ``r`` is attenuated by more than ``eps``; ``sigma_t`` of the first layer,
its smallest channel value, so the sphere is the largest). The fit is the usual total least squares: the plane
through the (vertex-area weighted) centroid ``c`` whose normal is the eigenvector of the smallest eigenvalue of the
weighted covariance, oriented along the vertex normal.

Choices the paper leaves open:

- Fits are made per face *corner* with the crease-aware corner normal ``n`` (:func:`jaxsss.render.rays.corner_normals`),
  and use only neighbours whose vertex normal is within :data:`AGREE_DEG` of ``n``: across a box edge the sides do not
  tilt the top's plane, and on a thin shell the far side does not enter the fit.
- Fewer than 3 usable neighbours, or collinear ones, fall back to the tangent plane at ``V`` (the flat-slab case).
- Eq. 14 stores only ``NS_V`` and recovers the plane point as ``P_V = V + |NS_V| N_V``: the length of the stored
  normal encodes how far along the vertex normal the plane lies. We store the unit normal and that point,
  ``P_V = V + s N_V`` with ``s = (c - V) . NS_V / (N_V . NS_V)`` (the plane meets the line through ``V`` along
  ``N_V`` there).

The radius depends on the material only through ``sigma_t``; it is a precomputation knob (fixed while fitting), so
the image has no gradient with respect to it.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import trimesh
from scipy.spatial import cKDTree

__all__ = ["AGREE_DEG", "Planes", "fit_planes", "neighbourhood_radius", "planes_at"]

AGREE_DEG = 60.0
"""Neighbours whose vertex normal is farther than this from the corner normal are left out of a fit."""


def neighbourhood_radius(sigma_t: float, eps: float) -> float:
    """Eq. 8: ``r = -log(eps) / sigma_t`` (mm) for ``sigma_t`` in 1/mm and ``eps`` in ``(0, 1)``."""
    if not (0.0 < eps < 1.0):
        raise ValueError(f"neighbourhood_radius(eps={eps!r}): outside the allowed range (0, 1)")
    if not (sigma_t > 0.0 and math.isfinite(sigma_t)):
        raise ValueError(f"neighbourhood_radius(sigma_t={sigma_t!r}): outside the allowed range (0, inf) 1/mm")
    return -math.log(eps) / sigma_t


class Planes(NamedTuple):
    """Per face corner: unit ``normal`` ``(F, 3, 3)`` and plane ``point`` ``(F, 3, 3)`` (mm); ``radius`` (mm);
    ``fitted`` ``(F, 3)`` False where the fit fell back to the tangent plane."""

    normal: np.ndarray
    point: np.ndarray
    radius: float
    fitted: np.ndarray


def _vertex_areas(mesh: trimesh.Trimesh) -> np.ndarray:
    area = np.zeros(len(mesh.vertices))
    np.add.at(area, mesh.faces.reshape(-1), np.repeat(mesh.area_faces / 3.0, 3))
    return area


def fit_planes(mesh: trimesh.Trimesh, corner_normal: np.ndarray, radius: float, *,
               agree_deg: float = AGREE_DEG) -> Planes:
    """Fit one plane per face corner (module docstring).

    Args:
        mesh: the translucent mesh (mm).
        corner_normal: ``(F, 3, 3)`` unit normals at the face corners.
        radius: neighbourhood radius, mm (:func:`neighbourhood_radius`).
    """
    if not (radius > 0 and math.isfinite(radius)):
        raise ValueError(f"fit_planes(radius={radius!r}): outside the allowed range (0, inf) mm")
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    vnorm = np.asarray(mesh.vertex_normals, dtype=np.float64)
    weight = _vertex_areas(mesh)
    corner_vertex = mesh.faces.reshape(-1)
    cn = corner_normal.reshape(-1, 3)
    # Corners that share a vertex and a normal share a plane: fit each distinct (vertex, normal) once.
    key = np.concatenate([corner_vertex[:, None].astype(np.float64), np.round(cn, 9)], axis=1)
    uniq, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    uv_idx = uniq[:, 0].astype(np.int64)
    un = uniq[:, 1:]
    un = un / np.linalg.norm(un, axis=1, keepdims=True)
    tree = cKDTree(verts)
    lists = tree.query_ball_point(verts[uv_idx], r=radius)
    counts = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
    owner = np.repeat(np.arange(len(uniq)), counts)
    nbr = np.concatenate([np.asarray(x, dtype=np.int64) for x in lists]) if len(owner) else np.zeros(0, np.int64)
    keep = np.einsum("ij,ij->i", vnorm[nbr], un[owner]) >= math.cos(math.radians(agree_deg))
    owner, nbr = owner[keep], nbr[keep]
    w = weight[nbr]
    x = verts[nbr]
    k = len(uniq)
    W = np.bincount(owner, weights=w, minlength=k)
    n_used = np.bincount(owner, minlength=k)
    S1 = np.stack([np.bincount(owner, weights=w * x[:, i], minlength=k) for i in range(3)], axis=1)
    S2 = np.stack([np.stack([np.bincount(owner, weights=w * x[:, i] * x[:, j], minlength=k) for j in range(3)], 1)
                   for i in range(3)], axis=1)
    Wsafe = np.where(W > 0, W, 1.0)
    c = S1 / Wsafe[:, None]
    cov = S2 / Wsafe[:, None, None] - c[:, :, None] * c[:, None, :]
    evals, evecs = np.linalg.eigh(cov)
    normal = evecs[:, :, 0]
    normal *= np.where(np.einsum("ij,ij->i", normal, un) < 0, -1.0, 1.0)[:, None]
    # Degenerate: too few neighbours, or (nearly) collinear ones (the two largest eigenvalues are not both > 0).
    scale = np.maximum(evals[:, 2], 1e-300)
    ok = (n_used >= 3) & (W > 0) & (evals[:, 1] > 1e-6 * scale) & (evals[:, 2] > 0)
    V = verts[uv_idx]
    cos_nn = np.einsum("ij,ij->i", un, normal)
    ok &= cos_nn > 0.1
    s = np.where(ok, np.einsum("ij,ij->i", c - V, normal) / np.where(ok, cos_nn, 1.0), 0.0)
    normal = np.where(ok[:, None], normal, un)
    # Eq. 14: the plane point on the line through V along its normal.
    point = V + s[:, None] * un
    F = len(mesh.faces)
    return Planes(normal[inverse].reshape(F, 3, 3), point[inverse].reshape(F, 3, 3), float(radius),
                  ok[inverse].reshape(F, 3))


def planes_at(planes: Planes, bary: np.ndarray, face: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(NS_P, PS_P)``: the plane at surface points, interpolated barycentrically from the face corners (normal
    renormalised), as the paper's rasteriser interpolates the per-vertex planes."""
    n = np.einsum("rk,rkc->rc", bary, planes.normal[face])
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    p = np.einsum("rk,rkc->rc", bary, planes.point[face])
    return n, p
