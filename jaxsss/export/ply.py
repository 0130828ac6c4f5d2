"""Binary PLY meshes for the exporters: positions (mm) and jaxsss's own shading normals per vertex.

jaxsss shades with crease-aware smooth normals (:func:`jaxsss.render.rays.corner_normals`: faces meeting at more than
:data:`~jaxsss.render.rays.CREASE_DEG` keep their own normal). A PLY has one normal per vertex, so vertices are split
where their corners' normals differ; the positions of split vertices are bit-identical, so the surface stays
watertight for a path tracer. Mitsuba 3 and pbrt-v4 both read the file (``x y z nx ny nz`` float32,
``vertex_indices``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from jaxsss.render.rays import corner_normals

__all__ = ["OBJECT_ID", "shading_mesh", "write_meshes", "write_ply"]

OBJECT_ID = "object"
"""Id (and file stem) of the translucent shape; occluders are ``occluder_0``, ``occluder_1``, ...."""


def shading_mesh(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(vertices (V, 3) mm, normals (V, 3), faces (F, 3))`` with one normal per vertex (split at creases)."""
    if len(mesh.faces) == 0:
        raise ValueError("mesh has no faces; allowed: at least one triangle")
    corners = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces)].reshape(-1, 3)
    normals = corner_normals(mesh).reshape(-1, 3)
    key = np.concatenate([corners, normals.round(6)], axis=1)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return corners[first], normals[first], inverse.reshape(-1, 3).astype(np.int32)


def write_ply(mesh: trimesh.Trimesh, path) -> Path:
    """Write ``mesh`` as binary little-endian PLY with per-vertex shading normals; return the path."""
    vertices, normals, faces = shading_mesh(mesh)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment jaxsss export: mm, jaxsss shading normals\n"
        f"element vertex {len(vertices)}\n"
        + "".join(f"property float {c}\n" for c in ("x", "y", "z", "nx", "ny", "nz"))
        + f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    vert = np.concatenate([vertices, normals], axis=1).astype("<f4")
    face = np.zeros(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face["n"], face["i"] = 3, faces
    with path.open("wb") as f:
        f.write(header.encode("ascii"))
        f.write(vert.tobytes())
        f.write(face.tobytes())
    return path


def write_meshes(scene, directory, *, relative: bool = False) -> dict[str, str]:
    """Write the object and occluders as PLY files into ``directory``; return ``{shape id: file name}`` (relative to
    ``directory`` when ``relative``, else absolute)."""
    directory = Path(directory)
    files = {OBJECT_ID: write_ply(scene.mesh, directory / f"{OBJECT_ID}.ply")}
    for i, occ in enumerate(scene.occluders):
        files[f"occluder_{i}"] = write_ply(occ.mesh, directory / f"occluder_{i}.ply")
    return {k: (p.name if relative else str(p.resolve())) for k, p in files.items()}
