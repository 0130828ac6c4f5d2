"""Texture coordinates and tangent frames on a mesh (NumPy, once per scene).

The paper's tangent ``T`` and bi-normal ``B`` are "related to the texture coordinates: the tangent gives the
direction of variation of the u coordinate and the bi-normal that of v", and Algorithm 1 adds ``(PM . T, PM . B)`` to
``(u_P, v_P)``. For that sum to be a texture-coordinate offset, ``T`` and ``B`` must be the surface *gradients* of
``u`` and ``v`` (units 1/mm), which is what we store: on a flat, linearly mapped surface the offset is then exact.

Per face, the gradient of ``u`` is the vector in the face plane with ``grad_u . e1 = du1`` and ``grad_u . e2 = du2``
(edges ``e1, e2`` from corner 0, UV differences ``du``). Per face *corner* we average it (area-weighted) over the
faces around the vertex whose normals lie within the crease angle of this face, as :func:`corner_normals` does for
normals, so a box's edges do not mix the top's mapping with the sides'. At a surface point the corner values are
interpolated barycentrically and projected onto the tangent plane of the shading normal.

Seams. Built-in meshes cannot duplicate vertices (they are watertight), so the sphere's and box's ``u`` and both of
the torus's coordinates wrap from 1 back to 0 inside some faces. With ``wrap`` set for a coordinate, a face whose
corners span more than 1/2 in it has 1 added to its small values before interpolating, and looked-up coordinates
are taken modulo 1 (textures repeat anyway). Mesh files usually duplicate seam vertices and need no wrapping.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import trimesh

from jaxsss.render.rays import CREASE_DEG, corner_normals

__all__ = ["SurfaceFrames", "WRAP_BY_BUILTIN", "face_uv", "frames_at", "surface_frames", "wrap_for"]

#: Which texture coordinates wrap around on each built-in mesh (see :mod:`jaxsss.render.meshes`).
WRAP_BY_BUILTIN = {
    "sphere": (True, False),
    "box": (True, False),
    "torus": (True, True),
    "slab": (False, False),
    "teapot": (False, False),
}


def wrap_for(mesh_description: str) -> tuple[bool, bool]:
    """The ``(wrap_u, wrap_v)`` of a scene's mesh from its description (``"builtin sphere ..."``); files: none."""
    words = str(mesh_description).split()
    if len(words) >= 2 and words[0] == "builtin":
        return WRAP_BY_BUILTIN.get(words[1].rstrip(","), (False, False))
    return (False, False)


def mesh_uv(mesh: trimesh.Trimesh) -> np.ndarray:
    """``(V, 2)`` per-vertex UVs, or a ``ValueError`` that says the mesh has none."""
    uv = getattr(mesh.visual, "uv", None)
    if uv is None:
        raise ValueError("layered rendering needs texture coordinates: the mesh has no UVs (mesh.visual.uv); use a "
                         "built-in mesh or a mesh file with UVs (e.g. OBJ with vt lines)")
    uv = np.asarray(uv, dtype=np.float64)
    if uv.shape != (len(mesh.vertices), 2) or not np.all(np.isfinite(uv)):
        raise ValueError(f"the mesh's UVs have shape {uv.shape} (or non-finite values); expected one finite row per "
                         f"vertex ({len(mesh.vertices)}, 2)")
    return uv


def face_uv(mesh: trimesh.Trimesh, wrap=(False, False)) -> np.ndarray:
    """``(F, 3, 2)`` UVs of each face's corners, unwrapped across seams for the coordinates in ``wrap``."""
    fuv = mesh_uv(mesh)[mesh.faces].copy()
    for c, w in enumerate(wrap):
        if not w:
            continue
        x = fuv[..., c]
        seam = (x.max(axis=1) - x.min(axis=1)) > 0.5
        x[seam] = np.where(x[seam] < 0.5, x[seam] + 1.0, x[seam])
    return fuv


def _face_gradients(mesh: trimesh.Trimesh, fuv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(grad_u, grad_v)``, each ``(F, 3)`` in 1/mm: the surface gradients of u and v on each face."""
    tri = mesh.triangles
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    g11, g12, g22 = (np.einsum("ij,ij->i", a, b) for a, b in ((e1, e1), (e1, e2), (e2, e2)))
    det = g11 * g22 - g12 * g12
    ok = det > 1e-24 * np.maximum(g11 * g22, 1e-300)
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    out = []
    for c in range(2):
        d1, d2 = fuv[:, 1, c] - fuv[:, 0, c], fuv[:, 2, c] - fuv[:, 0, c]
        # Solve the 2x2 Gram system for the coefficients of grad = a e1 + b e2.
        a = (g22 * d1 - g12 * d2) * inv
        b = (g11 * d2 - g12 * d1) * inv
        out.append(a[:, None] * e1 + b[:, None] * e2)
    return out[0], out[1]


def _corner_average(mesh: trimesh.Trimesh, face_values: np.ndarray, crease_deg: float) -> np.ndarray:
    """``(F, 3, k)`` area-weighted mean of per-face values over the faces around each corner's vertex that lie within
    ``crease_deg`` of the face (the rule of :func:`jaxsss.render.rays.corner_normals`)."""
    fn = mesh.face_normals
    weighted = face_values * mesh.area_faces[:, None]
    area = mesh.area_faces
    vf = mesh.vertex_faces
    cos_crease = np.cos(np.radians(crease_deg))
    out = np.empty((len(mesh.faces), 3, face_values.shape[1]))
    for corner in range(3):
        nbr = vf[mesh.faces[:, corner]]
        nb = np.maximum(nbr, 0)
        keep = ((nbr >= 0) & (np.einsum("fk,fvk->fv", fn, fn[nb]) >= cos_crease)).astype(np.float64)
        total = np.einsum("fv,fv->f", keep, area[nb])
        out[:, corner] = np.einsum("fv,fvk->fk", keep, weighted[nb]) / np.where(total > 0, total, 1.0)[:, None]
    return out


class SurfaceFrames(NamedTuple):
    """Per face corner: ``uv`` ``(F, 3, 2)`` (unwrapped), ``normal``, ``grad_u``, ``grad_v`` ``(F, 3, 3)``."""

    uv: np.ndarray
    normal: np.ndarray
    grad_u: np.ndarray
    grad_v: np.ndarray


def surface_frames(mesh: trimesh.Trimesh, wrap=(False, False), tile=(1.0, 1.0),
                   crease_deg: float = CREASE_DEG) -> SurfaceFrames:
    """Texture coordinates and tangent frames at every face corner.

    Args:
        mesh: a mesh with per-vertex UVs.
        wrap: ``(wrap_u, wrap_v)``: which coordinates wrap around (module docstring; :func:`wrap_for`).
        tile: how many times the texture repeats over the UV range in u and v (scales UVs and gradients).
        crease_deg: faces meeting at more than this angle are not averaged across.
    """
    tile = np.asarray(tile, dtype=np.float64).reshape(2)
    fuv = face_uv(mesh, wrap)
    gu, gv = _face_gradients(mesh, fuv)
    grads = _corner_average(mesh, np.concatenate([gu, gv], axis=1), crease_deg)
    return SurfaceFrames(fuv * tile, corner_normals(mesh, crease_deg), grads[..., :3] * tile[0],
                         grads[..., 3:] * tile[1])


def barycentric(mesh: trimesh.Trimesh, face: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``(R, 3)`` barycentric coordinates of points on the given faces (clipped into the triangle)."""
    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[face], points)
    bary = np.clip(np.nan_to_num(bary, nan=1.0 / 3.0), 0.0, 1.0)
    return bary / bary.sum(axis=1, keepdims=True)


def frames_at(frames: SurfaceFrames, mesh: trimesh.Trimesh, face: np.ndarray, points: np.ndarray):
    """``(uv (R, 2), normal (R, 3), T (R, 3), B (R, 3))`` at surface points on ``face``.

    ``uv`` is the tiled texture coordinate (not reduced modulo 1); ``normal`` the smooth unit normal; ``T`` and ``B``
    the gradients of u and v projected onto the plane perpendicular to ``normal`` (1/mm).
    """
    face = np.asarray(face, dtype=np.int64)
    bary = barycentric(mesh, face, np.asarray(points, dtype=np.float64))
    uv = np.einsum("rk,rkc->rc", bary, frames.uv[face])
    n = np.einsum("rk,rkc->rc", bary, frames.normal[face])
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    fn = mesh.face_normals[face]
    n = np.where(norm > 0.5, n / np.where(norm > 0, norm, 1.0), fn)
    out = [uv, n]
    for g in (frames.grad_u, frames.grad_v):
        t = np.einsum("rk,rkc->rc", bary, g[face])
        out.append(t - np.einsum("rc,rc->r", t, n)[:, None] * n)
    return tuple(out)
