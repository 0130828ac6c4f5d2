"""Built-in meshes, mesh files, placement transforms and surface UVs (NumPy and trimesh; lengths in mm).

Built-in meshes (:func:`builtin_mesh`, registry :data:`BUILTIN_MESHES`):

==========  =====================================================  =============  ====================================
name        parameters (defaults)                                  watertight     UV (one row per vertex)
==========  =====================================================  =============  ====================================
``sphere``  ``radius=10``, ``subdivisions=5`` (icosphere)          yes            spherical: ``u = atan2(y, x) / 2 pi``
                                                                                  (mod 1), ``v = polar angle / pi``
``box``     ``extents=[20, 20, 20]``, ``subdivisions=3``           yes            spherical, of the direction from the
                                                                                  centre (as for the sphere)
``slab``    ``width=100``, ``depth=100``, ``thickness=10``,        yes            planar along z: ``u = x / width +
            ``subdivisions=0`` (a box centred at the origin,                      1/2``, ``v = y / depth + 1/2``
            thickness along z)
``torus``   ``major_radius=15``, ``minor_radius=5``,               yes            the two angles over ``2 pi``: ``u``
            ``major_sections=64``, ``minor_sections=32`` (axis z)                 around z, ``v`` around the tube
``teapot``  ``size=60`` (height, mm), ``resolution=12``            no             the Bezier patch ``(u, v)`` of each
            (see :mod:`jaxsss.render.teapot`)                                     of the 32 patches
``teapot_`` ``size=60`` (height, mm), ``grid=160``: the solid      yes            spherical, of the direction from the
``closed``  the patches bound, remeshed by marching cubes                         bounding box's centre
            (:func:`jaxsss.render.teapot.closed_teapot_mesh`;
            path tracers need it to hold a medium)
==========  =====================================================  =============  ====================================

Why these UVs: trimesh's ``is_watertight`` counts edges by vertex index, so a watertight mesh cannot duplicate
vertices along a UV seam, and then every vertex carries exactly one UV. Per-face planar projections of a box would
need duplicated vertices (and lose watertightness); instead the box uses the sphere's projection (continuous except
on the seam) on a subdivided surface, and the slab uses the projection along z, exact on its top and bottom faces
(its thin sides are stretched). Faces that straddle a seam (``u`` wrapping from 1 to 0, and the torus's ``v``)
interpolate the UV across the whole texture: :func:`uv_at` is exact away from the seams only.

Every built-in has outward normals (positive volume where watertight) and ``mesh.visual.uv`` with one row per vertex
(meshes are built with ``process=False`` so trimesh does not merge vertices and drop the UVs).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable

import numpy as np
import trimesh

__all__ = [
    "BUILTIN_MESHES",
    "MeshParamError",
    "builtin_mesh",
    "load_mesh_file",
    "transform_matrix",
    "uv_at",
]


class MeshParamError(ValueError):
    """A bad built-in mesh parameter; ``.param`` names it (``None`` for the mesh name itself)."""

    def __init__(self, message: str, param: str | None = None):
        super().__init__(message)
        self.param = param


# --- parameter checks ---------------------------------------------------------------------------------------------
def _positive(name: str, value, param: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise MeshParamError(f"builtin_mesh({name!r}, {param}={value!r}): not a number", param)
    if not (math.isfinite(value) and value > 0):
        raise MeshParamError(
            f"builtin_mesh({name!r}, {param}={value!r}): {value!r} is outside the allowed range (0, inf)", param
        )
    return float(value)


def _count(name: str, value, param: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise MeshParamError(f"builtin_mesh({name!r}, {param}={value!r}): not an integer", param)
    if not lo <= value <= hi:
        raise MeshParamError(
            f"builtin_mesh({name!r}, {param}={value!r}): {value!r} is outside the allowed range [{lo}, {hi}]", param
        )
    return int(value)


def _positive3(name: str, value, param: str) -> np.ndarray:
    arr = np.asarray(value, dtype=object)
    if arr.shape != (3,):
        raise MeshParamError(f"builtin_mesh({name!r}, {param}={value!r}): expected 3 values [x, y, z]", param)
    return np.array([_positive(name, v, param) for v in arr], dtype=np.float64)


def _textured(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray) -> trimesh.Trimesh:
    """A mesh with per-vertex UVs, built without processing (no vertex merging that would drop the UVs)."""
    mesh = trimesh.Trimesh(
        vertices=np.asarray(vertices, dtype=np.float64), faces=np.asarray(faces, dtype=np.int64), process=False
    )
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.asarray(uv, dtype=np.float64))
    return mesh


def _spherical_uv(directions: np.ndarray) -> np.ndarray:
    """``u = atan2(y, x) / 2 pi`` in ``[0, 1)``, ``v = polar angle from +z / pi`` in ``[0, 1]``."""
    d = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    u = np.mod(np.arctan2(d[:, 1], d[:, 0]) / (2.0 * np.pi), 1.0)
    v = np.arccos(np.clip(d[:, 2], -1.0, 1.0)) / np.pi
    return np.stack([u, v], axis=1)


def _subdivided_box(extents: np.ndarray, subdivisions: int) -> trimesh.Trimesh:
    box = trimesh.creation.box(extents=extents)
    for _ in range(subdivisions):
        box = box.subdivide()
    return box


# --- the built-ins ------------------------------------------------------------------------------------------------
def _sphere(radius=10.0, subdivisions=5) -> trimesh.Trimesh:
    radius = _positive("sphere", radius, "radius")
    subdivisions = _count("sphere", subdivisions, "subdivisions", 0, 7)
    ico = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return _textured(ico.vertices, ico.faces, _spherical_uv(ico.vertices))


def _box(extents=(20.0, 20.0, 20.0), subdivisions=3) -> trimesh.Trimesh:
    extents = _positive3("box", extents, "extents")
    subdivisions = _count("box", subdivisions, "subdivisions", 0, 6)
    box = _subdivided_box(extents, subdivisions)
    return _textured(box.vertices, box.faces, _spherical_uv(box.vertices))


def _slab(width=100.0, depth=100.0, thickness=10.0, subdivisions=0) -> trimesh.Trimesh:
    width = _positive("slab", width, "width")
    depth = _positive("slab", depth, "depth")
    thickness = _positive("slab", thickness, "thickness")
    subdivisions = _count("slab", subdivisions, "subdivisions", 0, 6)
    box = _subdivided_box(np.array([width, depth, thickness]), subdivisions)
    v = box.vertices
    uv = np.stack([v[:, 0] / width + 0.5, v[:, 1] / depth + 0.5], axis=1)
    return _textured(v, box.faces, uv)


def _torus(major_radius=15.0, minor_radius=5.0, major_sections=64, minor_sections=32) -> trimesh.Trimesh:
    R = _positive("torus", major_radius, "major_radius")
    r = _positive("torus", minor_radius, "minor_radius")
    if r >= R:
        raise MeshParamError(
            f"builtin_mesh('torus', minor_radius={minor_radius!r}): must be below major_radius={major_radius!r} "
            "(a self-intersecting torus has no inside)",
            "minor_radius",
        )
    n = _count("torus", major_sections, "major_sections", 3, 4096)
    m = _count("torus", minor_sections, "minor_sections", 3, 4096)
    # phi around the z axis (index i), theta around the tube (index j); vertex (i, j) -> i * m + j.
    phi = 2.0 * np.pi * np.arange(n) / n
    theta = 2.0 * np.pi * np.arange(m) / m
    P, T = np.meshgrid(phi, theta, indexing="ij")
    ring = R + r * np.cos(T)
    vertices = np.stack([ring * np.cos(P), ring * np.sin(P), r * np.sin(T)], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(m), indexing="ij")
    a = i * m + j
    b = ((i + 1) % n) * m + j
    c = ((i + 1) % n) * m + (j + 1) % m
    d = i * m + (j + 1) % m
    # Winding (a, b, c): d/dphi x d/dtheta points out of the tube, so the normals face outward.
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    uv = np.stack([P / (2.0 * np.pi), T / (2.0 * np.pi)], axis=-1).reshape(-1, 2)
    return _textured(vertices, faces, uv)


def _teapot_closed(size=60.0, grid=160) -> trimesh.Trimesh:
    from jaxsss.render.teapot import closed_teapot_mesh

    size = _positive("teapot_closed", size, "size")
    grid = _count("teapot_closed", grid, "grid", 32, 512)
    mesh = closed_teapot_mesh(size=size, grid=grid)
    centre = mesh.bounds.mean(axis=0)
    return _textured(mesh.vertices, mesh.faces, _spherical_uv(mesh.vertices - centre))


def _teapot(size=60.0, resolution=12) -> trimesh.Trimesh:
    from jaxsss.render.teapot import teapot_mesh

    size = _positive("teapot", size, "size")
    resolution = _count("teapot", resolution, "resolution", 1, 128)
    return teapot_mesh(size=size, resolution=resolution)


#: name -> (builder, allowed parameters with their defaults). Lengths in mm.
BUILTIN_MESHES: dict[str, tuple[Callable[..., trimesh.Trimesh], dict]] = {
    "sphere": (_sphere, {"radius": 10.0, "subdivisions": 5}),
    "box": (_box, {"extents": [20.0, 20.0, 20.0], "subdivisions": 3}),
    "slab": (_slab, {"width": 100.0, "depth": 100.0, "thickness": 10.0, "subdivisions": 0}),
    "torus": (_torus, {"major_radius": 15.0, "minor_radius": 5.0, "major_sections": 64, "minor_sections": 32}),
    "teapot": (_teapot, {"size": 60.0, "resolution": 12}),
    "teapot_closed": (_teapot_closed, {"size": 60.0, "grid": 160}),
}


def builtin_mesh(name: str, **params) -> trimesh.Trimesh:
    """A built-in mesh in mm (see the module table), with per-vertex UVs in ``mesh.visual.uv``.

    Args:
        name: one of :data:`BUILTIN_MESHES` (``sphere``, ``box``, ``slab``, ``torus``, ``teapot``, ``teapot_closed``).
        **params: that mesh's parameters; missing ones take their defaults.

    Raises:
        MeshParamError (a ``ValueError``): unknown name or parameter (the message lists the valid ones), or a value
            outside its range (``.param`` names the parameter).
    """
    if name not in BUILTIN_MESHES:
        raise MeshParamError(f"builtin mesh {name!r} is not known; valid: {', '.join(BUILTIN_MESHES)}")
    builder, defaults = BUILTIN_MESHES[name]
    unknown = sorted(set(params) - set(defaults))
    if unknown:
        raise MeshParamError(
            f"builtin_mesh({name!r}): unknown parameter(s) {', '.join(unknown)}; valid: {', '.join(defaults)}",
            unknown[0],
        )
    return builder(**{**defaults, **params})


def load_mesh_file(path) -> trimesh.Trimesh:
    """Load a mesh file (any format trimesh reads; a scene file's meshes are concatenated) as one ``Trimesh``.

    Raises:
        FileNotFoundError: no such file.
        ValueError: trimesh cannot read the file, or the mesh has no faces (the message names the file).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"mesh file {path!r} does not exist")
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as err:  # trimesh raises many types for unreadable files
        raise ValueError(f"mesh file {path!r} could not be read: {err}") from err
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"mesh file {path!r} has no faces; allowed: a mesh with at least one triangle")
    return mesh


def _rotation(axis: int, degrees: float) -> np.ndarray:
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    j, k = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(4)
    R[j, j], R[j, k], R[k, j], R[k, k] = c, -s, s, c
    return R


def transform_matrix(scale=1.0, rotate_deg=(0.0, 0.0, 0.0), translate=(0.0, 0.0, 0.0)) -> np.ndarray:
    """The ``(4, 4)`` placement ``T @ Rz @ Ry @ Rx @ S``: scale, then rotate about x, y, z (degrees), then translate.

    Args:
        scale: scalar or 3 per-axis factors.
        rotate_deg: right-handed rotations about the fixed x, y and z axes, applied in that order (degrees).
        translate: offset in mm.
    """
    S = np.eye(4)
    S[:3, :3] = np.diag(np.broadcast_to(np.asarray(scale, dtype=np.float64), (3,)))
    rx, ry, rz = (float(a) for a in np.asarray(rotate_deg, dtype=np.float64).reshape(3))
    T = np.eye(4)
    T[:3, 3] = np.asarray(translate, dtype=np.float64).reshape(3)
    return T @ _rotation(2, rz) @ _rotation(1, ry) @ _rotation(0, rx) @ S


def uv_at(mesh: trimesh.Trimesh, points, face_index) -> np.ndarray:
    """``(N, 2)`` UVs at surface points: barycentric interpolation of the vertex UVs of each point's face.

    Args:
        mesh: a mesh with ``mesh.visual.uv`` (one row per vertex).
        points: ``(N, 3)`` points on the faces, mm.
        face_index: ``(N,)`` index of the face each point lies on.

    Raises:
        ValueError: the mesh has no UVs (or not one per vertex), or the shapes disagree.
    """
    uv = getattr(mesh.visual, "uv", None)
    if uv is None:
        raise ValueError("uv_at(mesh=...): the mesh has no UVs (mesh.visual.uv is missing)")
    uv = np.asarray(uv, dtype=np.float64)
    if uv.shape != (len(mesh.vertices), 2):
        raise ValueError(
            f"uv_at(mesh=...): mesh.visual.uv has shape {uv.shape}; expected one row per vertex ({len(mesh.vertices)}, 2)"
        )
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    face_index = np.asarray(face_index, dtype=np.int64).reshape(-1)
    if len(face_index) != len(points):
        raise ValueError(f"uv_at: {len(points)} points but {len(face_index)} face indices")
    faces = mesh.faces[face_index]
    bary = trimesh.triangles.points_to_barycentric(mesh.vertices[faces], points)
    return np.einsum("nk,nkc->nc", bary, uv[faces])
