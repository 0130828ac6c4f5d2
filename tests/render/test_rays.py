"""Ray casting (jaxsss.render.rays): Embree's first hits refined in double precision; geometry kept by content."""

import numpy as np
import pytest
import trimesh

from jaxsss.render import rays
from jaxsss.render.rays import OBJECT_NONE, OBJECT_TRANSLUCENT, SceneGeometry, scene_geometry


def _rays(n, spread, seed=0):
    rng = np.random.default_rng(seed)
    origins = rng.normal(size=(n, 3)) * spread
    directions = rng.normal(size=(n, 3))
    return origins, directions / np.linalg.norm(directions, axis=1, keepdims=True)


def _brute_force(mesh, origins, directions):
    """``(face, t)``: every ray against every face (Moller-Trumbore in double precision); -1 and inf on a miss."""
    v0, v1, v2 = (mesh.triangles[:, i][None] for i in range(3))  # (1, F, 3)
    e1, e2 = v1 - v0, v2 - v0
    d = directions[:, None, :]
    p = np.cross(d, e2)
    det = np.sum(e1 * p, axis=-1)
    ok = np.abs(det) > 1e-14
    inv = 1.0 / np.where(ok, det, 1.0)
    s = origins[:, None, :] - v0
    u = np.sum(s * p, axis=-1) * inv
    q = np.cross(s, e1)
    v = np.sum(d * q, axis=-1) * inv
    t = np.sum(e2 * q, axis=-1) * inv
    tol = 1e-12
    t = np.where(ok & (u >= -tol) & (v >= -tol) & (u + v <= 1 + tol) & (t > 0), t, np.inf)
    face = np.argmin(t, axis=1)
    best = t[np.arange(len(t)), face]
    return np.where(np.isfinite(best), face, -1), best


@pytest.mark.parametrize("mesh", [trimesh.creation.icosphere(subdivisions=3, radius=8.0),
                                  trimesh.creation.box(extents=(10.0, 4.0, 6.0))], ids=["sphere", "box"])
def test_first_hits_are_the_exact_intersections(mesh):
    """Reference: every ray against every face in double precision. Rays from inside, outside and missing; the same
    faces (but where a ray meets an edge, within 1e-6 of the scene's size of another face's hit), and distances and
    points to 1e-12 of the scene's size."""
    origins, directions = _rays(3000, 6.0)
    hits = SceneGeometry(mesh).first_hit(origins, directions)
    face, t = _brute_force(mesh, origins, directions)
    assert 0 < hits.hit.sum() < len(origins)  # both kinds are tested
    np.testing.assert_array_equal(hits.hit, face >= 0)
    ray = np.flatnonzero(hits.hit)
    same = hits.face[ray] == face[ray]
    assert same.mean() > 0.99
    err = np.abs(hits.t[ray] - t[ray]) / mesh.scale
    assert err[same].max() < 1e-12 and err.max() < 1e-6
    np.testing.assert_allclose(hits.position[ray], origins[ray] + t[ray, None] * directions[ray], rtol=0,
                               atol=1e-6 * mesh.scale)
    miss = ~hits.hit
    assert np.all(np.isinf(hits.t[miss])) and np.all(np.isnan(hits.position[miss]))
    assert np.all(hits.face[miss] == -1) and np.all(hits.obj[miss] == OBJECT_NONE)
    assert np.all(hits.obj[hits.hit] == OBJECT_TRANSLUCENT)


@pytest.mark.parametrize("radius", [1e-4, 1e5])
def test_first_hits_at_extreme_sizes(radius):
    """A sphere a tenth of a micrometre and one 100 m across: rays from the centre meet it at its radius (the
    tessellation's inscribed distance at least), in single-precision Embree scaled to a box."""
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    _, directions = _rays(500, 1.0, seed=1)
    hits = SceneGeometry(mesh).first_hit(np.zeros((500, 3)), directions)
    assert hits.hit.all()
    assert np.all(hits.t <= radius * (1 + 1e-12)) and np.all(hits.t >= 0.99 * radius)
    np.testing.assert_allclose(np.linalg.norm(hits.position, axis=1), hits.t, rtol=1e-12)


def test_rays_along_a_face_stay_finite():
    """A ray in the plane of a face (where the plane gives no distance) keeps Embree's own distance."""
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    origins = np.array([[-3.0, 0.3, 1.0], [-3.0, 0.3, 0.5]])  # the first runs in the plane of the top face
    hits = SceneGeometry(box).first_hit(origins, np.array([[1.0, 0.0, 0.0]] * 2))
    assert np.all(np.isfinite(hits.t[hits.hit]))
    assert hits.hit[1] and hits.t[1] == pytest.approx(2.0, abs=1e-12)


def test_occluders_are_numbered_in_order():
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    wall = trimesh.creation.box(extents=(0.2, 4.0, 4.0))
    wall.apply_translation([3.0, 0.0, 0.0])
    geometry = SceneGeometry(sphere, [wall])
    hits = geometry.first_hit(np.array([[-5.0, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, 5.0, 0.0]]),
                              np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    np.testing.assert_array_equal(hits.obj, [OBJECT_TRANSLUCENT, 1, OBJECT_NONE])


def test_scene_geometry_is_kept_by_content(monkeypatch):
    """Equal meshes (other objects) share one geometry; a moved mesh, other occluders or a full cache build anew."""
    monkeypatch.setattr(rays, "_GEOMETRIES", type(rays._GEOMETRIES)())
    a = trimesh.creation.icosphere(subdivisions=2, radius=2.0)
    first = scene_geometry(a)
    assert scene_geometry(a.copy()) is first
    wall = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    assert scene_geometry(a, [wall]) is not first
    moved = a.copy()
    moved.apply_translation([1.0, 0.0, 0.0])
    other = scene_geometry(moved)
    assert other is not first
    np.testing.assert_allclose(other.first_hit(np.array([[-9.0, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]])).t,
                               first.first_hit(np.array([[-9.0, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]])).t + 1.0)
    for k in range(rays.GEOMETRY_CACHE_SIZE):
        scene_geometry(trimesh.creation.icosphere(subdivisions=1, radius=3.0 + k))
    assert scene_geometry(a) is not first  # evicted, least recently used first
    assert len(rays._GEOMETRIES) == rays.GEOMETRY_CACHE_SIZE


def _two_spheres():
    a = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    b = a.copy()
    b.apply_translation([5.0, 0.0, 0.0])
    return trimesh.util.concatenate([a, b])


def _sphere_faces(edit):
    sphere = trimesh.creation.icosphere(subdivisions=3)
    return trimesh.Trimesh(sphere.vertices, edit(sphere.faces), process=False)


@pytest.mark.parametrize(("make", "convex"), [
    (lambda: trimesh.creation.icosphere(subdivisions=3, radius=4.0), True),
    (lambda: trimesh.creation.box(extents=(1.0, 2.0, 3.0)), True),
    (_two_spheres, False),  # convex at every edge, in two pieces
    (lambda: trimesh.creation.torus(5.0, 1.0), False),
    (lambda: _sphere_faces(lambda f: f[:-10]), False),  # open
    (lambda: _sphere_faces(lambda f: f[:, ::-1]), False),  # inside out
], ids=["sphere", "box", "two-spheres", "torus", "open", "inside-out"])
def test_a_lone_convex_mesh_is_told_apart(make, convex):
    """``convex_alone``: one closed convex piece and no occluders (what lets a light's path stop at its exit)."""
    mesh = make()
    assert SceneGeometry(mesh).convex_alone is convex
    assert SceneGeometry(mesh, [trimesh.creation.box(extents=(0.1, 0.1, 0.1))]).convex_alone is False


def test_large_batches_are_cast_in_chunks_over_threads(monkeypatch):
    """Chunks smaller than the batch (spread over the cores) give the same hits as one call, on a scene whose BVH was
    built when it was made."""
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=8.0)
    origins, directions = _rays(5000, 6.0, seed=2)
    whole = SceneGeometry(mesh).first_hit(origins, directions)
    monkeypatch.setattr(rays, "RAY_CHUNK", 333)
    geometry = SceneGeometry(mesh)
    # The BVH is built before any query: threads never race to build it.
    assert geometry.intersector.scene.is_committed
    chunked = geometry.first_hit(origins, directions)
    for a, b in zip(whole, chunked, strict=True):
        np.testing.assert_array_equal(a, b)
