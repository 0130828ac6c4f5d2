"""Interaction lists of the hierarchical sum: exact cuts, the Eq. 12 criterion, r_cut coverage and bad input."""

import itertools

import numpy as np
import pytest

from jaxsss.render.interactions import (
    MAX_DIRECT_PAIRS,
    Interactions,
    build_interactions,
    direct_interactions,
)
from jaxsss.render.octree import MORTON_BITS, build_octree


def _sphere(n, rng, radius=5.0):
    p = rng.normal(size=(n, 3))
    return radius * p / np.linalg.norm(p, axis=1, keepdims=True)


@pytest.fixture(scope="module")
def scene():
    """Samples on a sphere (one coincident clump), queries on it, at samples, inside, outside the cube, far away."""
    rng = np.random.default_rng(0)
    p = np.concatenate([_sphere(2500, rng), np.tile([[0.0, 0.0, 5.0]], (20, 1))])
    a = rng.uniform(0.5, 1.5, len(p)) * (4 * np.pi * 25 / len(p))
    w = rng.uniform(0, 1, len(p))
    tree = build_octree(p, a, w)
    x = np.concatenate([
        _sphere(60, rng),
        p[rng.choice(len(p), 20, replace=False)],
        [[0.0, 0.0, 5.0]],
        rng.uniform(-4, 4, size=(10, 3)),
        [[0.0, 0.0, 0.0], [12.0, -3.0, 1.0], [1e3, 1e3, 1e3]],
    ])
    return tree, x


def _coverage(tree, inter):
    """(Q, N) number of times each query's accepted entities cover each sample."""
    diff = np.zeros((inter.n_queries, tree.n_samples + 1), dtype=np.int64)
    np.add.at(diff, (inter.query, tree.start[inter.entity]), 1)
    np.add.at(diff, (inter.query, tree.stop[inter.entity]), -1)
    return np.cumsum(diff, axis=1)[:, :-1]


def _accept_test(tree, x, eps):
    """Eq. 12 as written: area / |x - P|^2 < eps, for every (query, entity) pair."""
    d2 = ((x[:, None, :] - tree.centroid[None, :, :]) ** 2).sum(-1)
    return tree.area[None, :] < eps * d2


def _strictly_inside(tree, x, margin=1e-9):
    m = margin * tree.side
    return ((x[:, None, :] > tree.lo[None] + m) & (x[:, None, :] < tree.hi[None] - m)).all(-1)


EPS = [1e-3, 0.05, 0.3, 2.0, 50.0]


@pytest.mark.parametrize("eps", EPS)
def test_cut_partitions_the_samples(scene, eps):
    tree, x = scene
    inter = build_interactions(tree, x, eps, chunk_size=17)
    assert isinstance(inter, Interactions)
    assert inter.n_queries == len(x) and inter.eps == eps
    np.testing.assert_array_equal(_coverage(tree, inter), 1)


@pytest.mark.parametrize("eps", EPS)
def test_accepted_nodes_pass_eq12_and_parents_fail_it(scene, eps):
    tree, x = scene
    n = tree.n_samples
    inter = build_interactions(tree, x, eps)
    ok = _accept_test(tree, x, eps)
    inside = _strictly_inside(tree, x)
    q, e = inter.query, inter.entity
    node = e >= n
    assert np.all(ok[q[node], e[node]]), "every accepted internal node satisfies A_v / |x - P_v|^2 < eps"
    assert not np.any(inside[q[node], e[node]]), "a node whose cell contains the query is never accepted"
    # The cut is no finer than needed: the parent of every accepted entity was opened (test failed or contained x).
    par = tree.parent[e]
    has_par = par >= 0
    parent_accepted = ok[q[has_par], par[has_par]] & ~_on_or_inside(tree, x)[q[has_par], par[has_par]]
    assert not np.any(parent_accepted)


def _on_or_inside(tree, x, margin=1e-9):
    m = margin * tree.side
    return ((x[:, None, :] >= tree.lo[None] - m) & (x[:, None, :] <= tree.hi[None] + m)).all(-1)


def test_containing_cells_are_opened_even_when_eq12_would_accept(scene):
    tree, x = scene
    inter = build_interactions(tree, x, 1e6)
    n = tree.n_samples
    counts = inter.counts()
    root_inside = _on_or_inside(tree, x)[:, tree.root]
    # Queries outside the root's cell take the root alone; queries inside it must open it.
    outside = ~root_inside
    assert outside.any() and root_inside.any()
    np.testing.assert_array_equal(counts[outside], 1)
    first = inter.entity[np.searchsorted(inter.query, np.flatnonzero(outside))]
    np.testing.assert_array_equal(first, tree.root)
    assert np.all(counts[root_inside] > 1)
    # With huge eps the cut is made of the cells containing x and their children only: few pairs.
    assert counts[root_inside].max() < 8 * tree.depth[:n].max() + 8
    assert counts.sum() < 0.05 * n * len(x)


def test_tiny_eps_gives_the_direct_list(scene):
    tree, x = scene
    inter = build_interactions(tree, x, 1e-14)
    direct = direct_interactions(tree, len(x))
    np.testing.assert_array_equal(inter.query, direct.query)
    np.testing.assert_array_equal(inter.entity, direct.entity)


def test_cut_coarsens_monotonically_with_eps(scene):
    tree, x = scene
    counts = [build_interactions(tree, x, eps).counts() for eps in EPS]
    for fine, coarse in itertools.pairwise(counts):
        assert np.all(coarse <= fine)
    assert counts[0].sum() > 5 * counts[-1].sum()


@pytest.mark.parametrize("r_cut", [0.3, 1.0, 3.0])
@pytest.mark.parametrize("eps", [0.01, 0.2])
def test_r_cut_covers_every_sample_within_it_once(scene, r_cut, eps):
    tree, x = scene
    n = tree.n_samples
    inter = build_interactions(tree, x, eps, r_cut=r_cut, chunk_size=31)
    cover = _coverage(tree, inter)
    dist = np.linalg.norm(x[:, None, :] - tree.centroid[None, :n, :], axis=-1)
    assert cover.max() <= 1, "no sample counted twice"
    np.testing.assert_array_equal(cover[dist <= r_cut], 1)
    assert np.all(dist[cover == 0] > r_cut), "only samples beyond r_cut are dropped"
    q, e = inter.query, inter.entity
    samp = e < n
    assert np.all(dist[q[samp], e[samp]] <= r_cut)
    gap = np.maximum(np.maximum(tree.lo[e] - x[q], x[q] - tree.hi[e]), 0.0)
    assert np.all(np.linalg.norm(gap, axis=1) <= r_cut * (1 + 1e-9))
    # Without r_cut there are at least as many pairs.
    assert np.all(build_interactions(tree, x, eps).counts() >= inter.counts())


def test_far_query_with_r_cut_has_no_pairs(scene):
    tree, _ = scene
    inter = build_interactions(tree, np.array([[100.0, 0.0, 0.0], [0.0, 0.0, 5.0]]), 0.1, r_cut=1.0)
    counts = inter.counts()
    assert counts[0] == 0 and counts[1] > 0


def test_sorted_int32_and_deterministic(scene):
    tree, x = scene
    ref = build_interactions(tree, x, 0.05)
    assert ref.query.dtype == np.int32 and ref.entity.dtype == np.int32
    key = ref.query.astype(np.int64) * tree.n_entities + ref.entity
    assert np.all(np.diff(key) > 0), "sorted by query, then entity, without repeats"
    np.testing.assert_array_equal(ref.counts(), np.bincount(ref.query, minlength=len(x)))
    assert ref.counts().sum() == ref.n_pairs
    for kw in ({"chunk_size": 1}, {"chunk_size": 5, "n_threads": 3}, {"chunk_size": 10_000, "n_threads": 1}):
        other = build_interactions(tree, x, 0.05, **kw)
        np.testing.assert_array_equal(other.query, ref.query)
        np.testing.assert_array_equal(other.entity, ref.entity)


def test_few_queries_are_split_over_the_threads(scene, monkeypatch):
    """Fewer queries than a chunk per thread are split evenly over the threads (every core traverses), with the same
    result."""
    import jaxsss.render.interactions as mod

    tree, x = scene
    ref = build_interactions(tree, x, 0.05, n_threads=1)
    chunks = []
    traverse = mod._traverse_chunk
    monkeypatch.setattr(mod, "_traverse_chunk", lambda t, xs, *a: chunks.append(len(xs)) or traverse(t, xs, *a))
    monkeypatch.setattr(mod, "_MIN_CHUNK", 1)
    other = build_interactions(tree, x, 0.05, n_threads=2)
    assert sorted(chunks) == [len(x) // 2, -(-len(x) // 2)], chunks  # threads may finish in any order
    np.testing.assert_array_equal(other.query, ref.query)
    np.testing.assert_array_equal(other.entity, ref.entity)


def _cut_by_recursion(tree, x, eps):
    """The cut of Eq. 12 for one query, written as the paper states it: recursion from the root (slow, obvious)."""
    n = tree.n_samples
    code = int(tree.point_codes(x[None])[0])
    out = []

    def visit(v):
        d = x - tree.centroid[v]
        if tree.area[v] < eps * d @ d and (code >> (3 * (MORTON_BITS - int(tree.level[v])))) != tree.cell_codes()[v]:
            out.append(v)
        elif tree.is_leaf_node[v]:
            out.extend(int(c) for c in tree.children[v] if c >= 0)
        else:
            for c in tree.children[v]:
                if c >= 0:
                    visit(int(c))

    visit(n)
    return sorted(out)


def test_the_compiled_traversal_is_the_recursive_cut():
    """Each query's list is the cut found by recursion from the root, sorted, on a deep tree: samples at halving
    distances (a level each, down to the Morton resolution) and a clump of coincident samples (split by rank)."""
    rng = np.random.default_rng(3)
    halving = np.array([[5.0 * 2.0**-k, 0.1, 0.2] for k in range(40)])
    p = np.concatenate([_sphere(800, rng), halving, np.tile([[1.0, 2.0, 4.0]], (3000, 1))])
    tree = build_octree(p, rng.uniform(0.5, 1.5, len(p)) * 0.05, rng.uniform(0, 1, len(p)))
    assert tree.depth.max() > 10
    x = np.concatenate([_sphere(12, rng), [[1.0, 2.0, 4.0], [0.0, 0.1, 0.2], [30.0, 0.0, 0.0]]])
    for eps in (0.01, 0.3):
        inter = build_interactions(tree, x, eps)
        for i in range(len(x)):
            assert inter.entity[inter.query == i].tolist() == _cut_by_recursion(tree, x[i], eps)


def test_small_tree_and_no_queries():
    p = np.array([[0.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0]])
    tree = build_octree(p, np.ones(3), np.ones(3))
    inter = build_interactions(tree, np.zeros((0, 3)), 0.1, progress=True)
    assert inter.n_pairs == 0 and inter.counts().shape == (0,)
    inter = build_interactions(tree, np.array([[0.5, 0.5, 0.0], [100.0, 0, 0]]), 0.1, progress=True)
    np.testing.assert_array_equal(inter.query, [0, 0, 0, 1])
    np.testing.assert_array_equal(inter.entity, [0, 1, 2, tree.root])


def test_direct_interactions():
    rng = np.random.default_rng(1)
    tree = build_octree(rng.normal(size=(10, 3)), np.ones(10), np.ones(10))
    d = direct_interactions(tree, 4)
    assert d.query.dtype == np.int32 and d.entity.dtype == np.int32
    np.testing.assert_array_equal(d.counts(), [10, 10, 10, 10])
    np.testing.assert_array_equal(d.entity[:10], np.arange(10))
    d = direct_interactions(tree, 4, query_subset=[3, 1])
    np.testing.assert_array_equal(d.counts(), [0, 10, 0, 10])
    with pytest.raises(ValueError, match="query_subset=4"):
        direct_interactions(tree, 4, query_subset=[4])
    with pytest.raises(ValueError, match="n_queries"):
        direct_interactions(tree, -1)
    n_big = MAX_DIRECT_PAIRS // 10 + 1
    with pytest.raises(ValueError, match=f"{n_big * 10} pairs"):
        direct_interactions(tree, n_big)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"eps": 0.0}, "eps"),
        ({"eps": -1.0}, "eps"),
        ({"eps": np.nan}, "eps"),
        ({"eps": np.inf}, "eps"),
        ({"eps": "big"}, "eps"),
        ({"r_cut": 0.0}, "r_cut"),
        ({"r_cut": -2.0}, "r_cut"),
        ({"chunk_size": 0}, "chunk_size"),
        ({"n_threads": 0}, "n_threads"),
        ({"query_points": np.zeros((3, 2))}, "query_points"),
        ({"query_points": np.array([[0, np.nan, 0]])}, "query_points"),
    ],
)
def test_bad_input_names_the_argument(kwargs, name):
    tree = build_octree(np.eye(3), np.ones(3), np.ones(3))
    args = {"query_points": np.zeros((2, 3)), "eps": 0.1} | kwargs
    with pytest.raises(ValueError, match=rf"build_interactions\({name}="):
        build_interactions(tree, **args)


def test_wrong_tree_type():
    with pytest.raises(TypeError, match="octree"):
        build_interactions({"root": 0}, np.zeros((1, 3)), 0.1)
