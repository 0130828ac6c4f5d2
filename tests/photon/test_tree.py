"""The source octree (jaxsss.photon.tree): averaged incidence planes (unit normals, power-weighted, depth kept >= 0)
and the interaction lists (the renderer's cut, volumetric shadows by blockers, the gamma split for the multipole)."""

from __future__ import annotations

import numpy as np
import pytest

from jaxsss.photon import Sources, emit_photons, trace_photons
from jaxsss.photon.tree import pair_lists, source_tree
from jaxsss.render.interactions import build_interactions
from jaxsss.render.meshes import builtin_mesh
from jaxsss.render.octree import cut_sums_from_samples
from jaxsss.render.rays import SceneGeometry
from jaxsss.render.scene import Light

EPS = 0.05


def make_sources(position, normal, depth, power):
    position = np.asarray(position, dtype=np.float64)
    n = len(position)
    power = np.asarray(power, dtype=np.float64)
    power = np.repeat(power[:, None], 3, axis=1) if power.ndim == 1 else power
    return Sources(position, np.asarray(normal, dtype=np.float64), np.asarray(depth, dtype=np.float64), power,
                   np.ones(n), np.full(n, 0.1), np.zeros(n, np.int64), np.ones(n))


@pytest.fixture(scope="module")
def box():
    return builtin_mesh("box", extents=[20.0, 20.0, 10.0])  # top face z = 5, bottom z = -5


@pytest.fixture(scope="module")
def lit_from_above(box):
    """Sources of a box lit straight down: they all entered through the top face."""
    sun = Light("directional", intensity=np.array([1.0, 1.0, 1.0]), direction=np.array([0.0, 0.0, -1.0]))
    sphere = box.bounding_sphere.primitive
    photons = emit_photons([sun], sphere.center, float(sphere.radius), 1500, seed=1)
    src = trace_photons(SceneGeometry(box), photons, 0.1, 1.0, 1.3, walk="sources", seed=2).sources
    return src, source_tree(src)


# --- averaged planes ------------------------------------------------------------------------------------------------

def test_single_source_node_has_the_source_plane():
    n = np.array([[0.6, 0.0, 0.8]])
    src = make_sources([[1.0, 2.0, 3.0]], n, [0.7], [2.0])
    st = source_tree(src)
    assert st.octree.n_samples == 1 and st.octree.n_entities == 2
    np.testing.assert_allclose(st.normal, np.repeat(n, 2, axis=0), rtol=1e-14)
    np.testing.assert_allclose(st.depth, [0.7, 0.7], rtol=1e-12)
    assert st.fixed_depth == 0


def test_flat_face_planes_are_the_face_and_depth_is_the_mean_member_depth(lit_from_above):
    src, st = lit_from_above
    tree = st.octree
    n = tree.n_samples
    assert n == src.n and tree.n_nodes > 10
    np.testing.assert_allclose(np.linalg.norm(st.normal, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(st.normal, np.broadcast_to([0.0, 0.0, 1.0], st.normal.shape), atol=1e-12)
    # Samples keep their own plane exactly.
    np.testing.assert_array_equal(st.depth[:n], src.depth[tree.order])
    np.testing.assert_array_equal(st.normal[:n], src.normal[tree.order])
    # With one common normal, a node's depth is its members' power-weighted mean depth, > 0.
    w = tree.sorted_samples(src.power.mean(axis=1))
    expect = cut_sums_from_samples(tree, w * tree.sorted_samples(src.depth)) / cut_sums_from_samples(tree, w)
    np.testing.assert_allclose(st.depth, expect, rtol=1e-9, atol=1e-12)
    assert np.all(st.depth[n:] > 0) and np.all(st.depth >= 0)
    assert st.fixed_depth == 0


def test_edge_planes_are_power_weighted_unit_normals():
    # Sources under the edge x = 0, z = 0 of a body in x < 0, z < 0: half entered through the top, half the side.
    rng = np.random.default_rng(0)
    k = 200
    top = np.c_[rng.uniform(-3, 0, k), rng.uniform(-3, 3, k), -rng.uniform(0.05, 1.0, k)]
    side = np.c_[-rng.uniform(0.05, 1.0, k), rng.uniform(-3, 3, k), rng.uniform(-3, 0, k)]
    normal = np.r_[np.tile([0.0, 0.0, 1.0], (k, 1)), np.tile([1.0, 0.0, 0.0], (k, 1))]
    depth = np.r_[-top[:, 2], -side[:, 0]]
    power = np.r_[np.full(k, 3.0), np.full(k, 1.0)]
    st = source_tree(make_sources(np.r_[top, side], normal, depth, power))
    np.testing.assert_allclose(np.linalg.norm(st.normal, axis=1), 1.0, atol=1e-12)
    assert np.all(st.depth >= 0)
    # The root's normal: the power-weighted mean of (0, 0, 1) x 3 and (1, 0, 0) x 1, normalised.
    root = st.octree.root
    np.testing.assert_allclose(st.normal[root], np.array([1.0, 0.0, 3.0]) / np.sqrt(10.0), rtol=1e-12)
    assert st.depth[root] > 0


def test_opposite_faces_keep_depth_positive():
    # A 2 mm sheet lit from both sides, interleaved: strong shallow sources from the top (normal +z) and weak deep
    # ones from the bottom (normal -z). The averaged plane (+z) would put mixed nodes' centroids above it.
    g = np.stack(np.meshgrid(np.arange(8.0), np.arange(8.0), indexing="ij"), -1).reshape(-1, 2)
    top = np.c_[g, np.full(len(g), 0.9)]  # 0.1 below z = 1
    bottom = np.c_[g + 0.5, np.full(len(g), 0.5)]  # 1.5 above z = -1
    normal = np.r_[np.tile([0.0, 0.0, 1.0], (len(g), 1)), np.tile([0.0, 0.0, -1.0], (len(g), 1))]
    depth = np.r_[np.full(len(g), 0.1), np.full(len(g), 1.5)]
    power = np.r_[np.full(len(g), 1.0), np.full(len(g), 0.5)]
    st = source_tree(make_sources(np.r_[top, bottom], normal, depth, power))
    assert st.fixed_depth > 0
    np.testing.assert_allclose(np.linalg.norm(st.normal, axis=1), 1.0, atol=1e-12)
    assert np.all(st.depth >= 0)
    # The root is one of them: it takes the power-weighted mean depth of its members.
    root = st.octree.root
    np.testing.assert_allclose(st.normal[root], [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(st.depth[root], (0.1 * 1.0 + 1.5 * 0.5) / 1.5, rtol=1e-12)


def test_normals_that_cancel_fall_back_to_a_member_normal():
    src = make_sources([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]], [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]], [0.3, 0.3],
                       [1.0, 1.0])
    st = source_tree(src)
    root = st.octree.root
    first = st.octree.start[root]
    np.testing.assert_array_equal(st.normal[root], st.normal[first])
    assert np.isfinite(st.depth).all() and np.all(st.depth >= 0)


def test_empty_sources_raise():
    empty = make_sources(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))
    with pytest.raises(ValueError, match=r"source_tree\(sources="):
        source_tree(empty)


# --- interaction lists ----------------------------------------------------------------------------------------------

def queries_on(z, nz, k=40, seed=3, half=9.5):
    rng = np.random.default_rng(seed)
    pos = np.c_[rng.uniform(-half, half, (k, 2)), np.full(k, z)]
    return pos, np.tile([0.0, 0.0, nz], (k, 1))


def test_without_blockers_pairs_are_the_cut_and_partition_the_sources(lit_from_above):
    _, st = lit_from_above
    tree = st.octree
    pos, nrm = queries_on(5.0, 1.0)
    pl = pair_lists(st, pos, nrm, EPS)
    assert pl.n_blocked == 0 and pl.n_pairs == pl.n_total
    ref = build_interactions(tree, pos, EPS)
    assert pl.n_total == ref.n_pairs
    q = np.concatenate(pl.query)
    e = np.concatenate(pl.entity)
    assert set(zip(q.tolist(), e.tolist(), strict=True)) == set(zip(ref.query.tolist(), ref.entity.tolist(),
                                                                    strict=True))
    for lq, le in zip(pl.query, pl.entity, strict=True):
        assert np.all(np.diff(lq) >= 0)  # sorted by query (segment sums)
        assert len(lq) == len(le)
    # Each query's entities cover every source exactly once.
    for i in range(len(pos)):
        ents = e[q == i]
        cover = np.zeros(tree.n_samples, int)
        for s0, s1 in zip(tree.start[ents], tree.stop[ents], strict=True):
            cover[s0:s1] += 1
        np.testing.assert_array_equal(cover, 1)


def segment_hits_box(a, b, lo, hi):
    """Whether segments a -> b (K, 3) cross the axis-aligned box [lo, hi] (slab test)."""
    d = b - a
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (lo - a) / d
        t1 = (hi - a) / d
    tmin = np.nanmax(np.minimum(t0, t1), axis=1)
    tmax = np.nanmin(np.maximum(t0, t1), axis=1)
    return (tmax >= np.maximum(tmin, 0.0)) & (tmin <= 1.0)


def test_blocker_between_queries_and_sources_drops_exactly_the_shadowed_pairs(lit_from_above):
    _, st = lit_from_above
    plate = builtin_mesh("box", extents=[10.0, 30.0, 1.0])
    plate.apply_translation([-5.0, 0.0, 0.0])  # x in [-10, 0], z in [-0.5, 0.5]: halfway down the box
    pos, nrm = queries_on(-5.0, -1.0, k=30)  # on the bottom face
    free = pair_lists(st, pos, nrm, EPS)
    pl = pair_lists(st, pos, nrm, EPS, blockers=SceneGeometry(plate))
    assert pl.n_total == free.n_total and pl.n_blocked > 0
    assert pl.n_pairs + pl.n_blocked == pl.n_total
    # Kept pairs are exactly those whose segment (query -> entity centroid) misses the plate.
    q0, e0 = np.concatenate(free.query), np.concatenate(free.entity)
    crosses = segment_hits_box(pos[q0], st.octree.centroid[e0], *plate.bounds)
    kept = set(zip(np.concatenate(pl.query).tolist(), np.concatenate(pl.entity).tolist(), strict=True))
    expect = {(int(a), int(b)) for a, b, c in zip(q0, e0, crosses, strict=True) if not c}
    assert kept == expect
    assert pl.n_blocked == int(crosses.sum())
    # Deep under the plate every pair to a source straight above is gone; the other half keeps them all.
    under = np.flatnonzero(pos[:, 0] < -3.0)
    clear = np.flatnonzero(pos[:, 0] > 3.0)
    assert under.size and clear.size
    counts = np.bincount(np.concatenate(pl.query), minlength=len(pos))
    counts_free = np.bincount(q0, minlength=len(pos))
    assert np.all(counts[under] < counts_free[under])
    assert np.all(counts[clear] > 0)


def test_gamma_split_sends_the_opposite_face_to_the_multipole(lit_from_above):
    _, st = lit_from_above
    n_q = 12
    top, n_top = queries_on(5.0, 1.0, k=n_q, seed=4)
    bottom, n_bottom = queries_on(-5.0, -1.0, k=n_q, seed=5)
    side = np.c_[np.full(n_q, 10.0), np.linspace(-9, 9, n_q), np.linspace(-4, 4, n_q)]
    n_side = np.tile([1.0, 0.0, 0.0], (n_q, 1))
    tilted = n_side + np.array([0.0, 0.0, -0.01])  # the side face seen slightly from below: gamma just over pi/2
    pos = np.r_[top, bottom, side, side]
    nrm = np.r_[n_top, n_bottom, n_side, tilted / np.linalg.norm(tilted, axis=1, keepdims=True)]
    pl = pair_lists(st, pos, nrm, EPS)
    without = np.bincount(pl.query[0], minlength=len(pos))
    multi = np.bincount(pl.query[1], minlength=len(pos))
    group = np.repeat(np.arange(4), n_q)
    assert np.all(multi[group == 0] == 0) and np.all(without[group == 0] > 0)  # top: gamma = 0
    assert np.all(without[group == 1] == 0) and np.all(multi[group == 1] > 0)  # bottom: gamma = pi
    assert np.all(multi[group == 2] == 0) and np.all(without[group == 2] > 0)  # side: gamma = pi/2 exactly
    assert np.all(without[group == 3] == 0) and np.all(multi[group == 3] > 0)  # just past pi/2
    np.testing.assert_array_equal(pl.entity[1].size, pl.query[1].size)
