"""Built-in meshes, the Utah teapot, mesh files, placement transforms and UV interpolation."""

import math

import numpy as np
import pytest
import trimesh

from jaxsss.render.meshes import (
    BUILTIN_MESHES,
    MeshParamError,
    builtin_mesh,
    load_mesh_file,
    transform_matrix,
    uv_at,
)
from jaxsss.render.teapot import TEAPOT_HEIGHT, load_teapot_patches, teapot_mesh

WATERTIGHT = ["sphere", "box", "slab", "torus", "teapot_closed"]


def _front_facing_fraction(mesh: trimesh.Trimesh, n_rays: int = 4000, seed: int = 0) -> float:
    """Fraction of first hits, for rays shot from far outside at the mesh, that land on a face facing the ray."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n_rays, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    target = mesh.bounds.mean(axis=0) + rng.uniform(-0.5, 0.5, (n_rays, 3)) * mesh.extents
    origins = target - d * 10.0 * np.linalg.norm(mesh.extents)
    tri, ray = mesh.ray.intersects_id(origins, d, multiple_hits=False)
    assert len(tri) > n_rays // 4
    return float(np.mean(np.einsum("ij,ij->i", mesh.face_normals[tri], d[ray]) < 0.0))


@pytest.mark.parametrize("name", WATERTIGHT)
def test_builtin_watertight_outward_with_uv(name):
    mesh = builtin_mesh(name)
    assert mesh.is_watertight
    assert mesh.volume > 0.0  # outward normals
    assert _front_facing_fraction(mesh) == 1.0
    uv = mesh.visual.uv
    assert uv.shape == (len(mesh.vertices), 2)
    assert np.all(np.isfinite(uv)) and uv.min() >= 0.0 and uv.max() <= 1.0


@pytest.mark.parametrize("name", list(BUILTIN_MESHES))
def test_builtin_defaults_match_registry(name):
    _builder, defaults = BUILTIN_MESHES[name]
    a, b = builtin_mesh(name), builtin_mesh(name, **defaults)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)


@pytest.mark.parametrize(
    "name, params, area, volume, rtol",
    [
        # Inscribed polyhedra: the area of a subdivision-5 icosphere is ~0.03% low; 1% is the stated tolerance.
        ("sphere", {"radius": 7.0}, 4 * math.pi * 7.0**2, 4 / 3 * math.pi * 7.0**3, 1e-2),
        # 64 x 32 sections: the area is low by ~(1 - (pi/64)^2/6)(1 - (pi/32)^2/6) ~ 0.2%.
        ("torus", {"major_radius": 15.0, "minor_radius": 5.0}, 4 * math.pi**2 * 15 * 5, 2 * math.pi**2 * 15 * 25, 2e-2),
        ("box", {"extents": [10.0, 20.0, 30.0]}, 2 * (200 + 300 + 600), 6000.0, 1e-12),
        ("slab", {"width": 80.0, "depth": 60.0, "thickness": 5.0}, 2 * (4800 + 400 + 300), 24000.0, 1e-12),
    ],
)
def test_builtin_area_volume(name, params, area, volume, rtol):
    mesh = builtin_mesh(name, **params)
    assert mesh.area == pytest.approx(area, rel=rtol)
    assert mesh.volume == pytest.approx(volume, rel=rtol)


def test_slab_centred_with_thickness_along_z():
    mesh = builtin_mesh("slab", width=40.0, depth=30.0, thickness=4.0)
    np.testing.assert_allclose(mesh.bounds, [[-20, -15, -2], [20, 15, 2]])
    # Planar projection along z: exact (u, v) on the top face.
    top = mesh.vertices[:, 2] > 0
    np.testing.assert_allclose(mesh.visual.uv[top], mesh.vertices[top, :2] / [40.0, 30.0] + 0.5)


@pytest.mark.parametrize(
    "name, params, param",
    [
        ("sphere", {"radius": -1.0}, "radius"),
        ("sphere", {"radius": float("nan")}, "radius"),
        ("sphere", {"subdivisions": 9}, "subdivisions"),
        ("sphere", {"subdivisions": 2.0}, "subdivisions"),
        ("box", {"extents": [1.0, 0.0, 1.0]}, "extents"),
        ("box", {"extents": [1.0, 1.0]}, "extents"),
        ("slab", {"thickness": 0.0}, "thickness"),
        ("torus", {"minor_radius": 20.0}, "minor_radius"),
        ("torus", {"major_sections": 2}, "major_sections"),
        ("teapot", {"size": -5.0}, "size"),
        ("teapot", {"resolution": 0}, "resolution"),
        ("teapot_closed", {"grid": 8}, "grid"),
        ("sphere", {"radiuss": 1.0}, "radiuss"),
    ],
)
def test_builtin_bad_params(name, params, param):
    with pytest.raises(MeshParamError) as info:
        builtin_mesh(name, **params)
    assert info.value.param == param
    assert param in str(info.value)


def test_builtin_unknown_name_and_param_list_the_valid_ones():
    with pytest.raises(ValueError, match="valid: sphere, box, slab, torus, teapot"):
        builtin_mesh("cube")
    with pytest.raises(ValueError, match="valid: radius, subdivisions"):
        builtin_mesh("sphere", extents=[1, 2, 3])


# --- the teapot --------------------------------------------------------------------------------------------------
def test_teapot_patch_data():
    data = load_teapot_patches()
    assert data.patches.shape == (32, 16)
    assert data.vertices.shape == (306, 3)
    assert data.patches.min() >= 0 and data.patches.max() <= 305
    assert data.vertices[:, 2].min() == 0.0 and data.vertices[:, 2].max() == TEAPOT_HEIGHT
    # Spot values of the classic data (1-based point 1 and the lid-knob tip).
    np.testing.assert_array_equal(data.vertices[0], [1.4, 0.0, 2.4])
    np.testing.assert_array_equal(data.control_points[20, 0, 0], [0.0, 0.0, 3.15])


@pytest.mark.parametrize("size", [60.0, 17.5])
def test_teapot_placement(size):
    mesh = teapot_mesh(size=size, resolution=6)
    lo, hi = mesh.bounds
    assert hi[2] - lo[2] == pytest.approx(size, rel=1e-12)
    assert lo[2] == pytest.approx(0.0, abs=1e-12)
    assert (lo[0] + hi[0]) == pytest.approx(0.0, abs=1e-9 * size)
    assert (lo[1] + hi[1]) == pytest.approx(0.0, abs=1e-9 * size)
    # The classic shape is about twice as long (handle to spout, x) as it is tall.
    assert 1.9 < (hi[0] - lo[0]) / size < 2.1


def test_teapot_mesh_properties():
    mesh = builtin_mesh("teapot")
    assert not mesh.is_watertight  # documented: lid gap, open spout, handle and spout not joined to the body
    assert mesh.visual.uv.shape == (len(mesh.vertices), 2)
    assert mesh.visual.uv.min() >= 0.0 and mesh.visual.uv.max() <= 1.0
    assert np.all(mesh.area_faces > 0.0)  # pole triangles dropped
    # Outward on average: area-weighted n . (centre - centroid) > 0, and every patch grid agrees.
    c = mesh.triangles_center
    assert np.sum(mesh.area_faces * np.einsum("ij,ij->i", mesh.face_normals, c - c.mean(axis=0))) > 0.0
    # Rays from outside hit front faces; the ~1% exceptions pass through the gap between lid and rim (or into the
    # spout) and meet the inside of the body, which is correctly back-facing.
    assert _front_facing_fraction(mesh) > 0.97


def test_closed_teapot_is_the_solid_the_patches_bound():
    """The watertight teapot lies on the patch surface (within the grid spacing, except where the open surface has
    no counterpart: the solid spout's mouth, the filled lid gap) and its volume converges with the grid."""
    from jaxsss.render.teapot import closed_teapot_mesh

    size = 60.0
    mesh, coarse = closed_teapot_mesh(size, grid=160), closed_teapot_mesh(size, grid=96)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert len(mesh.split()) == 1  # one solid: spout, handle, lid and knob joined to the body
    assert mesh.extents[2] == pytest.approx(size, abs=1.5 * size / 159)
    open_surface = teapot_mesh(size=size, resolution=16)
    np.testing.assert_allclose(mesh.extents[:2], open_surface.extents[:2], atol=1.5 * size / 159 * 2)
    sample = mesh.vertices[np.random.default_rng(0).choice(len(mesh.vertices), 1500, replace=False)]
    # Distance to the open surface: exact point-triangle distances to the 16 triangles with the nearest centres.
    from scipy.spatial import cKDTree

    _, near = cKDTree(open_surface.triangles_center).query(sample, k=16)
    tris = open_surface.triangles[near.ravel()]
    closest = trimesh.triangles.closest_point(tris, np.repeat(sample, 16, axis=0))
    dist = np.linalg.norm(closest - np.repeat(sample, 16, axis=0), axis=1).reshape(-1, 16).min(axis=1)
    h = mesh.extents.max() / 159
    assert np.quantile(dist, 0.99) < h, np.quantile(dist, [0.5, 0.99, 1.0])
    assert coarse.volume == pytest.approx(mesh.volume, rel=1e-2)


def test_teapot_area_converges():
    coarse, fine = teapot_mesh(resolution=12).area, teapot_mesh(resolution=40).area
    assert coarse < fine  # inscribed facets
    assert coarse == pytest.approx(fine, rel=1e-2)


# --- files, transforms, UVs -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", ["ply", "obj", "stl"])
def test_load_mesh_file_round_trip(tmp_path, suffix):
    box = trimesh.creation.box(extents=[1.0, 2.0, 3.0])
    path = tmp_path / f"box.{suffix}"
    box.export(path)
    mesh = load_mesh_file(path)
    assert mesh.volume == pytest.approx(6.0)


def test_load_mesh_file_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing.ply"):
        load_mesh_file(tmp_path / "nothing.ply")
    points_only = tmp_path / "points.obj"
    points_only.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(ValueError, match="points.obj.*no faces"):
        load_mesh_file(points_only)
    garbage = tmp_path / "garbage.ply"
    garbage.write_text("not a mesh\n")
    with pytest.raises(ValueError, match="garbage.ply"):
        load_mesh_file(garbage)


def test_transform_matrix_composition():
    p = np.array([1.0, 2.0, 3.0, 1.0])
    # Scale first, then rotate 90 degrees about x (y -> z, z -> -y), then about z (x -> y, y -> -x), then translate.
    M = transform_matrix(scale=[2.0, 1.0, 1.0], rotate_deg=[90.0, 0.0, 90.0], translate=[10.0, 0.0, 0.0])
    scaled = [2.0, 2.0, 3.0]
    about_x = [scaled[0], -scaled[2], scaled[1]]
    about_z = [-about_x[1], about_x[0], about_x[2]]
    np.testing.assert_allclose(M @ p, [about_z[0] + 10.0, about_z[1], about_z[2], 1.0], atol=1e-12)
    # Rotation about y follows the right-hand rule (z -> x) and comes after x.
    np.testing.assert_allclose(transform_matrix(rotate_deg=[0, 90, 0]) @ [0, 0, 1, 1], [1, 0, 0, 1], atol=1e-12)
    Rx, Ry = transform_matrix(rotate_deg=[30, 0, 0]), transform_matrix(rotate_deg=[0, 40, 0])
    np.testing.assert_allclose(transform_matrix(rotate_deg=[30, 40, 0]), Ry @ Rx, atol=1e-12)
    np.testing.assert_allclose(transform_matrix(scale=3.0)[:3, :3], 3.0 * np.eye(3))
    np.testing.assert_allclose(transform_matrix(), np.eye(4))


def test_uv_at_sphere_matches_analytic():
    mesh = builtin_mesh("sphere", radius=10.0, subdivisions=5)
    points, face_index = trimesh.sample.sample_surface(mesh, 2000, seed=1)
    uv = mesh.visual.uv[mesh.faces[face_index]]
    # Away from the u seam (faces whose vertex u wrap) and the poles (where u is undefined).
    ok = (np.ptp(uv[:, :, 0], axis=1) < 0.5) & (uv[:, :, 1].min(axis=1) > 0.03) & (uv[:, :, 1].max(axis=1) < 0.97)
    assert ok.mean() > 0.9
    d = points[ok] / np.linalg.norm(points[ok], axis=1, keepdims=True)
    expected = np.stack([np.mod(np.arctan2(d[:, 1], d[:, 0]) / (2 * np.pi), 1.0), np.arccos(d[:, 2]) / np.pi], 1)
    np.testing.assert_allclose(uv_at(mesh, points[ok], face_index[ok]), expected, atol=1e-2)


def test_uv_at_reproduces_vertex_uvs_and_rejects_meshes_without_uv():
    mesh = builtin_mesh("torus")
    faces = np.arange(0, len(mesh.faces), 97)
    corner = mesh.vertices[mesh.faces[faces, 1]]
    np.testing.assert_allclose(uv_at(mesh, corner, faces), mesh.visual.uv[mesh.faces[faces, 1]], atol=1e-9)
    with pytest.raises(ValueError, match="no UVs"):
        uv_at(trimesh.creation.box(), np.zeros((1, 3)), [0])
