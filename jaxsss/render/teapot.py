"""The Utah teapot, tessellated from Martin Newell's 1975 bicubic Bezier patches (public-domain data).

The data (``jaxsss/render/data/teapot_patches.txt``, with its source in the header) are 32 patches over 306 control
points, z up, the body spanning z in ``[0, 3.15]``: rim, body, handle, spout, lid knob, lid and the bottom.

:func:`teapot_mesh` makes a triangle mesh in mm:

- each patch is evaluated on a ``(resolution + 1)^2`` grid of its parameters with the cubic Bernstein basis,
  ``S(u, v) = sum_ij B_i(u) B_j(v) P_ij``, and each grid cell is split into two triangles;
- vertices are *not* merged across patch seams: each patch keeps its own grid so that every vertex has the one
  ``(u, v)`` of its patch (``mesh.visual.uv``); the seams coincide in position;
- triangles of zero area (where a patch edge collapses to a pole: the knob's top, the bottom's centre) are dropped;
- each patch is wound so its normals point outward: a patch whose area-weighted mean of
  ``n . (face centre - centroid of the teapot)`` is negative is flipped. (In the classic data every patch has the
  same parametric orientation, with ``dS/du x dS/dv`` pointing inward, so all patches are flipped alike.);
- the teapot stays z up; it is moved so that its bounding box is centred on the origin in x and y with the bottom
  at ``z = 0``, and scaled uniformly so that its height (z extent, bottom to knob) is ``size`` mm.

The mesh is **not watertight**: the lid sits in the rim with a gap, the spout's mouth is open, and the handle and
spout pass into the body without being joined to it. Use it where an open, self-intersecting surface is acceptable
(it renders as a closed object seen from outside, but volumes and inside tests are approximate).
"""

from __future__ import annotations

import functools
import math
from importlib import resources

import numpy as np

from jaxsss.validate import check_integer
import trimesh

__all__ = ["TEAPOT_HEIGHT", "TeapotPatches", "load_teapot_patches", "teapot_mesh"]

#: Height (z extent) of the teapot in the units of its control points.
TEAPOT_HEIGHT = 3.15

_DATA_FILE = "teapot_patches.txt"


class TeapotPatches:
    """The raw patch data: ``patches`` ``(32, 16)`` 0-based control-point indices, ``vertices`` ``(306, 3)``.

    Control point ``patches[p, 4 * i + j]`` is ``P_ij`` of patch ``p``; ``i`` runs along the parameter ``u``.
    """

    def __init__(self, patches: np.ndarray, vertices: np.ndarray):
        self.patches = patches
        self.vertices = vertices

    @property
    def control_points(self) -> np.ndarray:
        """``(32, 4, 4, 3)`` control points ``P_ij`` of each patch."""
        return self.vertices[self.patches].reshape(-1, 4, 4, 3)


def _section(lines: list[tuple[int, str]], at: int, keyword: str, source: str) -> tuple[int, int]:
    line_no, text = lines[at]
    parts = text.split()
    if len(parts) != 2 or parts[0] != keyword or not parts[1].isdigit():
        raise ValueError(f"{source}:{line_no}: expected '{keyword} <count>', got {text!r}")
    return int(parts[1]), at + 1


@functools.cache
def load_teapot_patches() -> TeapotPatches:
    """Read and check the packaged patch data (32 patches of 16 1-based indices, 306 points; see the file header)."""
    source = f"jaxsss/render/data/{_DATA_FILE}"
    text = resources.files("jaxsss.render").joinpath("data", _DATA_FILE).read_text(encoding="utf-8")
    lines = [(n, s.strip()) for n, s in enumerate(text.splitlines(), 1) if s.strip() and not s.startswith("#")]
    n_patches, at = _section(lines, 0, "patches", source)
    patches = []
    for line_no, row in lines[at : at + n_patches]:
        cells = row.split(",")
        if len(cells) != 16 or not all(c.strip().isdigit() for c in cells):
            raise ValueError(f"{source}:{line_no}: expected 16 comma-separated indices, got {row!r}")
        patches.append([int(c) for c in cells])
    n_vertices, at = _section(lines, at + n_patches, "vertices", source)
    vertices = []
    for line_no, row in lines[at : at + n_vertices]:
        try:
            xyz = [float(c) for c in row.split(",")]
        except ValueError:
            xyz = []
        if len(xyz) != 3:
            raise ValueError(f"{source}:{line_no}: expected 'x,y,z', got {row!r}")
        vertices.append(xyz)
    if len(patches) != n_patches or len(vertices) != n_vertices or at + n_vertices != len(lines):
        raise ValueError(f"{source}: section counts do not match the data ({n_patches} patches, {n_vertices} points)")
    idx = np.asarray(patches, dtype=np.int64)
    if idx.min() < 1 or idx.max() > n_vertices:
        raise ValueError(f"{source}: patch indices must lie in [1, {n_vertices}]")
    return TeapotPatches(idx - 1, np.asarray(vertices, dtype=np.float64))


def _bernstein(t: np.ndarray) -> np.ndarray:
    """``(len(t), 4)`` cubic Bernstein polynomials ``B_k(t) = C(3, k) t^k (1 - t)^(3 - k)``."""
    s = 1.0 - t
    return np.stack([s**3, 3.0 * t * s**2, 3.0 * t**2 * s, t**3], axis=1)


def _grid_faces(resolution: int) -> np.ndarray:
    """Two triangles per cell of a ``(resolution + 1)^2`` grid, vertex ``(a, b) -> a * (resolution + 1) + b``."""
    n = resolution + 1
    a, b = np.meshgrid(np.arange(resolution), np.arange(resolution), indexing="ij")
    v00 = a * n + b
    v10, v01, v11 = v00 + n, v00 + 1, v00 + n + 1
    # Winding (v00, v10, v11): normal along dS/du x dS/dv.
    return np.concatenate([np.stack([v00, v10, v11], -1), np.stack([v00, v11, v01], -1)], axis=0).reshape(-1, 3)


def teapot_mesh(size: float = 60.0, resolution: int = 12) -> trimesh.Trimesh:
    """The Utah teapot as a triangle mesh, ``size`` mm tall, z up (see the module docstring for every choice).

    Args:
        size: height (z extent) in mm, ``> 0``.
        resolution: grid cells per patch edge, ``>= 1``; ``32 * 2 * resolution^2`` triangles before dropping the
            degenerate ones at the poles.

    Returns:
        A ``trimesh.Trimesh`` (not watertight) with ``mesh.visual.uv`` = each vertex's patch parameters ``(u, v)``.
    """
    if not (np.isfinite(size) and size > 0):
        raise ValueError(f"teapot_mesh(size={size!r}): outside the allowed range (0, inf)")
    resolution = check_integer(resolution, "resolution", 1, owner="teapot_mesh")
    data = load_teapot_patches()
    C = data.control_points  # (32, 4, 4, 3)
    t = np.linspace(0.0, 1.0, resolution + 1)
    B = _bernstein(t)
    # S(u, v) = sum_ij B_i(u) B_j(v) P_ij on the grid, all patches at once.
    S = np.einsum("ai,bj,pijc->pabc", B, B, C)  # (32, n, n, 3)
    n_patches, n = S.shape[0], resolution + 1
    grid_uv = np.stack(np.meshgrid(t, t, indexing="ij"), axis=-1).reshape(-1, 2)

    cell = _grid_faces(resolution)
    vertices = S.reshape(-1, 3)
    faces = (cell[None, :, :] + (np.arange(n_patches) * n * n)[:, None, None]).reshape(-1, 3)
    patch_of_face = np.repeat(np.arange(n_patches), len(cell))
    uv = np.tile(grid_uv, (n_patches, 1))

    # Drop the zero-area triangles where a patch edge collapses to a pole.
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    keep = area2 > 1e-12 * TEAPOT_HEIGHT**2
    faces, cross, area2, patch_of_face = faces[keep], cross[keep], area2[keep], patch_of_face[keep]

    # Orient each patch outward: area-weighted mean of n . (centre - centroid) must be positive.
    centres = vertices[faces].mean(axis=1)
    centroid = np.average(centres, axis=0, weights=area2)
    outward = np.einsum("fc,fc->f", cross, centres - centroid)  # |cross| n . (c - centroid)
    flip = np.bincount(patch_of_face, weights=outward, minlength=n_patches) < 0.0
    faces = np.where(flip[patch_of_face][:, None], faces[:, ::-1], faces)

    # Drop the pole vertices no triangle uses any more, keeping the UVs aligned.
    used = np.zeros(len(vertices), dtype=bool)
    used[faces] = True
    new_index = np.cumsum(used) - 1
    vertices, uv, faces = vertices[used], uv[used], new_index[faces]

    # Centre x, y on the bounding box, bottom at z = 0, height = size.
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    offset = np.array([(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0, lo[2]])
    vertices = (vertices - offset) * (float(size) / (hi[2] - lo[2]))

    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv)
    return mesh


def _axis_winding(mesh: trimesh.Trimesh, axis: int, coords: list[np.ndarray]):
    """Winding number and distance to the nearest outer-boundary crossing at every grid point, from rays along
    ``axis`` (one ray per grid column, every hit kept).

    Each hit adds ``-sign(d . n)`` to the running count (entering an outward-facing surface: +1), so overlapping
    parts (the spout and handle inside the body) count twice rather than flipping a parity. Only crossings where
    the count passes between 0 and >= 1 bound the union; the distance is to the nearest such crossing along the
    ray (exact along grid lines of this axis, an upper bound of the true distance elsewhere).
    """
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    others = [a for a in range(3) if a != axis]
    ga, gb = np.meshgrid(coords[others[0]], coords[others[1]], indexing="ij")
    origins = np.zeros((ga.size, 3))
    origins[:, others[0]], origins[:, others[1]] = ga.ravel(), gb.ravel()
    origins[:, axis] = coords[axis][0] - 1.0
    direction = np.zeros(3)
    direction[axis] = 1.0
    locations, ray_index, tri_index = RayMeshIntersector(mesh).intersects_location(
        origins, np.broadcast_to(direction, origins.shape), multiple_hits=True)
    sign = -np.sign(mesh.face_normals[tri_index, axis])
    t = locations[:, axis]
    order = np.lexsort((t, ray_index))
    ray_index, t, sign = ray_index[order], t[order], sign[order]
    samples = coords[axis]
    n_rays, n_s = origins.shape[0], len(samples)
    winding = np.zeros((n_rays, n_s))
    distance = np.full((n_rays, n_s), np.inf)
    starts = np.searchsorted(ray_index, np.arange(n_rays + 1))
    for r in range(n_rays):
        lo, hi = starts[r], starts[r + 1]
        if lo == hi:
            continue
        tr, count = t[lo:hi], np.cumsum(sign[lo:hi])
        k = np.searchsorted(tr, samples, side="right")
        winding[r] = np.concatenate([[0.0], count])[k]
        before = np.concatenate([[0.0], count[:-1]])
        boundary = tr[(before <= 0) != (count <= 0)]
        if boundary.size:
            j = np.clip(np.searchsorted(boundary, samples), 1, boundary.size) - 1
            jj = np.clip(j + 1, 0, boundary.size - 1)
            distance[r] = np.minimum(np.abs(samples - boundary[j]), np.abs(samples - boundary[jj]))
    shape = [len(c) for c in coords]
    perm = [others[0], others[1], axis]
    winding = winding.reshape(shape[others[0]], shape[others[1]], n_s).transpose(np.argsort(perm))
    distance = distance.reshape(shape[others[0]], shape[others[1]], n_s).transpose(np.argsort(perm))
    return winding, distance


def closed_teapot_mesh(size: float = 60.0, grid: int = 160) -> trimesh.Trimesh:
    """A watertight Utah teapot: the solid that the open patch surface bounds, ``size`` mm tall, z up.

    The open teapot (:func:`teapot_mesh`; lid gap, open spout mouth, handle and spout passing into the body) cannot
    hold a medium in a path tracer. This builds the solid instead:

    1. on a regular grid with ``grid`` points along the longest side (spacing ``h``), the winding number of the
       surface at every point from rays along x, y and z (:func:`_axis_winding`); a point is inside where at least
       two of the three counts are ``>= 1`` (a ray that slips through the lid gap disagrees with the other two);
    2. a signed distance ``+-min_axis(distance to the nearest crossing of the union's boundary)``, negative inside;
    3. its zero level set by marching cubes (scikit-image), oriented outward.

    The result is the union of body, lid, knob, spout (solid to its mouth) and handle, smooth to about ``h``
    (``size / grid * 1.5``: 0.5 mm at the defaults). No UVs (the patch parameters do not survive the remeshing).

    Args:
        size: height (z extent) in mm, ``> 0``.
        grid: grid points along the longest side, in ``[32, 512]``.
    """
    if not (np.isfinite(size) and size > 0):
        raise ValueError(f"closed_teapot_mesh(size={size!r}): outside the allowed range (0, inf)")
    grid = check_integer(grid, "grid", 32, 512, owner="closed_teapot_mesh")
    return _closed_teapot(float(size), grid).copy()


@functools.lru_cache(maxsize=4)
def _closed_teapot(size: float, grid: int) -> trimesh.Trimesh:
    """:func:`closed_teapot_mesh`'s solid, built once per ``(size, grid)`` in a process (2.3 s at the defaults: three
    sweeps of rays through a 160^3 grid and marching cubes); callers get copies, since a Trimesh is mutable."""
    from skimage.measure import marching_cubes

    surface = teapot_mesh(size=size, resolution=16)
    lo, hi = surface.bounds
    h = float((hi - lo).max()) / (grid - 1)
    # Two empty cells around the object; a tiny irrational offset keeps rays off the patch seams.
    coords = [np.arange(lo[a] - 2 * h, hi[a] + 2.5 * h, h) + h * 1e-3 * math.sqrt(2 + a) for a in range(3)]
    windings, distances = zip(*(_axis_winding(surface, a, coords) for a in range(3)))
    inside = (np.stack(windings) >= 0.5).sum(axis=0) >= 2
    distance = np.minimum.reduce(distances)
    distance = np.where(np.isfinite(distance), distance, 2 * h)
    sdf = np.where(inside, -distance, distance)
    verts, faces, _, _ = marching_cubes(sdf, level=0.0, spacing=(h, h, h))
    verts += np.array([c[0] for c in coords])
    mesh = trimesh.Trimesh(vertices=verts, faces=faces, process=True)
    trimesh.repair.fix_normals(mesh)
    if mesh.volume < 0:
        mesh.invert()
    # Bottom at z = 0 and x, y centred, as for the open teapot.
    lo, hi = mesh.bounds
    mesh.apply_translation([-(lo[0] + hi[0]) / 2.0, -(lo[1] + hi[1]) / 2.0, -lo[2]])
    return mesh
