"""Octree over irradiance samples: structure invariants, aggregates, cuts, duplicates and bad input."""

import numpy as np
import pytest

from jaxsss.render.octree import (
    MORTON_BITS,
    Octree,
    build_octree,
    cut_sums_from_samples,
    segment_range_sum,
)


def _sphere(n, rng, radius=10.0):
    p = rng.normal(size=(n, 3))
    return radius * p / np.linalg.norm(p, axis=1, keepdims=True)


def _point_set(kind, rng):
    """(positions, areas, weights) of a few kinds of sample sets."""
    if kind == "sphere":
        p = _sphere(3000, rng)
    elif kind == "cube":
        p = rng.uniform(-5.0, 5.0, size=(2000, 3))
    elif kind == "clusters":  # very uneven density: deep, narrow branches
        centres = rng.uniform(-10, 10, size=(5, 3))
        p = np.concatenate([c + 10.0 ** rng.uniform(-6, 0) * rng.normal(size=(400, 3)) for c in centres])
    elif kind == "duplicates":  # exact duplicates (many more than a leaf holds) mixed with distinct points
        base = rng.uniform(0, 1, size=(50, 3))
        p = np.concatenate([np.repeat(base[:3], [40, 9, 100], axis=0), base[3:], base[3:10]])
        p = p[rng.permutation(len(p))]
    elif kind == "plane":  # flat in z: the cube is much larger than the bounding box in one axis
        p = np.column_stack([rng.uniform(0, 4, 1500), rng.uniform(0, 1, 1500), np.zeros(1500)])
    else:
        raise AssertionError(kind)
    n = len(p)
    areas = rng.uniform(0.5, 2.0, n) * 1e-2
    weights = rng.uniform(0.0, 1.0, n)
    weights[rng.random(n) < 0.2] = 0.0
    return p, areas, weights


KINDS = ["sphere", "cube", "clusters", "duplicates", "plane"]


@pytest.fixture(params=KINDS)
def case(request):
    rng = np.random.default_rng(KINDS.index(request.param))
    p, a, w = _point_set(request.param, rng)
    return p, a, w, build_octree(p, a, w)


def _internal(tree):
    return np.arange(tree.n_samples, tree.n_entities)


def test_layout_and_permutation(case):
    p, a, w, tree = case
    n = len(p)
    assert isinstance(tree, Octree)
    assert tree.n_samples == n and tree.root == n
    np.testing.assert_array_equal(np.sort(tree.order), np.arange(n))
    np.testing.assert_array_equal(tree.centroid[:n], p[tree.order])
    np.testing.assert_array_equal(tree.area[:n], a[tree.order])
    np.testing.assert_array_equal(tree.weight[:n], w[tree.order])
    assert np.all(np.diff(tree.codes) >= 0)
    np.testing.assert_array_equal(tree.start[:n], np.arange(n))
    np.testing.assert_array_equal(tree.stop[:n], np.arange(n) + 1)
    assert tree.start[tree.root] == 0 and tree.stop[tree.root] == n
    assert tree.parent[tree.root] == -1 and tree.depth[tree.root] == 0
    for arr in (tree.start, tree.stop, tree.children, tree.depth, tree.parent, tree.order):
        assert arr.dtype == np.int64
    assert np.all(tree.children[:n] == -1) and not tree.is_leaf_node[:n].any()


def test_every_sample_in_exactly_one_leaf(case):
    _, _, _, tree = case
    n = tree.n_samples
    leaves = np.flatnonzero(tree.is_leaf_node)
    assert np.all(leaves >= n)
    held = tree.children[leaves]
    held = held[held >= 0]
    assert np.all(held < n)
    np.testing.assert_array_equal(np.sort(held), np.arange(n))
    # Non-leaf internal nodes hold only internal nodes.
    inner = _internal(tree)[~tree.is_leaf_node[n:]]
    ch = tree.children[inner]
    assert np.all(ch[ch >= 0] >= n)


def test_children_partition_parent_range(case):
    _, _, _, tree = case
    for v in _internal(tree):
        ch = tree.children[v]
        assert np.all(ch[: np.count_nonzero(ch >= 0)] >= 0), "children are packed left"
        ch = ch[ch >= 0]
        assert ch.size >= 1
        assert tree.start[ch[0]] == tree.start[v] and tree.stop[ch[-1]] == tree.stop[v]
        np.testing.assert_array_equal(tree.stop[ch[:-1]], tree.start[ch[1:]])
        assert np.all(tree.stop[ch] > tree.start[ch])
        assert np.all(tree.parent[ch] == v) and np.all(tree.depth[ch] == tree.depth[v] + 1)
        nodes = ch[ch >= tree.n_samples]
        assert np.all(nodes > v), "parents precede children (breadth-first ids)"


def test_nodes_split_by_position_have_two_children(case):
    """Compressed octree: a node split by position has >= 2 children (single-child chains are merged)."""
    _, _, _, tree = case
    n = tree.n_samples
    inner = _internal(tree)[~tree.is_leaf_node[n:]]
    by_position = inner[tree.level[inner] < MORTON_BITS]
    assert np.all(tree.n_children[by_position] >= 2)


@pytest.mark.parametrize("max_leaf", [1, 3, 8])
@pytest.mark.parametrize("max_depth", [0, 2, MORTON_BITS])
def test_at_most_max_leaf_samples_per_leaf(max_leaf, max_depth):
    rng = np.random.default_rng(7)
    p, a, w = _point_set("duplicates", rng)
    tree = build_octree(p, a, w, max_leaf=max_leaf, max_depth=max_depth)
    leaves = np.flatnonzero(tree.is_leaf_node)
    sizes = tree.stop[leaves] - tree.start[leaves]
    assert sizes.max() <= max_leaf
    assert np.all(tree.n_children <= 8)
    assert np.all(tree.level[tree.n_samples :] <= max_depth)
    _check_aggregates(tree, p, a, w)


def test_duplicates_share_the_deepest_cell():
    rng = np.random.default_rng(3)
    p = np.concatenate([np.tile([[1.0, 2.0, 3.0]], (1000, 1)), rng.uniform(0, 5, size=(20, 3))])
    a, w = np.full(len(p), 0.1), np.ones(len(p))
    tree = build_octree(p, a, w)
    leaves = np.flatnonzero(tree.is_leaf_node)
    assert (tree.stop[leaves] - tree.start[leaves]).max() <= 8
    # The 1000 copies sit under one node at the deepest level, split by rank into a balanced subtree.
    inner = _internal(tree)
    deep = inner[(tree.level[inner] == MORTON_BITS) & (tree.stop[inner] - tree.start[inner] > 8)]
    top = deep[tree.level[tree.parent[deep]] < MORTON_BITS]
    assert len(top) == 1 and tree.stop[top[0]] - tree.start[top[0]] == 1000
    assert tree.depth.max() <= tree.depth[top[0]] + 1 + int(np.ceil(np.log(1000 / 8) / np.log(8))) + 1
    _check_aggregates(tree, p, a, w)


@pytest.mark.parametrize("n", [1, 2, 8, 9])
def test_small_sets(n):
    rng = np.random.default_rng(n)
    p = rng.normal(size=(n, 3))
    tree = build_octree(p, np.ones(n), np.ones(n))
    assert tree.root == n
    if n <= 8:
        assert tree.n_nodes == 1 and tree.is_leaf_node[n]
        np.testing.assert_array_equal(tree.children[n][:n], np.arange(n))
    else:
        assert tree.n_nodes > 1 and not tree.is_leaf_node[n]
    _check_aggregates(tree, p, np.ones(n), np.ones(n))


def test_all_points_coincident():
    p = np.tile([[0.5, -1.0, 2.0]], (30, 1))
    tree = build_octree(p, np.full(30, 0.2), np.zeros(30))
    np.testing.assert_allclose(tree.area[tree.root], 6.0, rtol=1e-14)
    np.testing.assert_allclose(tree.centroid[tree.root], p[0], rtol=1e-14)
    assert (tree.stop - tree.start)[tree.is_leaf_node].max() <= 8


def _check_aggregates(tree, p, a, w):
    """Direct per-node sums over the node's sorted samples (independent of the build's reduceat)."""
    pos, area, weight = p[tree.order], a[tree.order], w[tree.order]
    for v in _internal(tree):
        s = slice(tree.start[v], tree.stop[v])
        np.testing.assert_allclose(tree.area[v], area[s].sum(), rtol=1e-12)
        np.testing.assert_allclose(tree.weight[v], weight[s].sum(), rtol=1e-12, atol=1e-300)
        ww = weight[s] if weight[s].sum() > 0 else area[s]
        np.testing.assert_allclose(tree.centroid[v], (ww[:, None] * pos[s]).sum(0) / ww.sum(), rtol=1e-12, atol=1e-12)


def test_aggregates_equal_sums_over_samples(case):
    p, a, w, tree = case
    _check_aggregates(tree, p, a, w)


def test_aggregates_equal_sums_over_children(case):
    _, _, _, tree = case
    for v in _internal(tree):
        ch = tree.children[v][tree.children[v] >= 0]
        np.testing.assert_allclose(tree.area[v], tree.area[ch].sum(), rtol=1e-12)
        np.testing.assert_allclose(tree.weight[v], tree.weight[ch].sum(), rtol=1e-12, atol=1e-300)


def test_zero_weight_nodes_use_area_weighted_centroid():
    rng = np.random.default_rng(11)
    p = rng.uniform(0, 1, size=(500, 3))
    a = rng.uniform(0.1, 1.0, 500)
    w = np.where(p[:, 0] < 0.5, 0.0, 1.0)  # half the cube carries no weight
    tree = build_octree(p, a, w)
    zero = _internal(tree)[tree.weight[tree.n_samples :] == 0]
    assert zero.size > 0
    _check_aggregates(tree, p, a, w)
    np.testing.assert_allclose(tree.centroid[tree.root], (w[:, None] * p).sum(0) / w.sum(), rtol=1e-12)


def _random_cut(tree, rng, p_open):
    """A random cut (partition of the samples by entities) made by random descent from the root."""
    cut, stack = [], [tree.root]
    while stack:
        v = stack.pop()
        if v >= tree.n_samples and rng.random() < p_open:
            stack.extend(tree.children[v][tree.children[v] >= 0])
        else:
            cut.append(v)
    return np.array(cut)


@pytest.mark.parametrize("p_open", [0.3, 0.7, 0.95, 1.0])
def test_random_cut_has_the_total_area_and_weight(case, p_open):
    """Acceptance test of the issue: the total area and flux of any cut equal those of the leaves."""
    _p, a, w, tree = case
    rng = np.random.default_rng(int(p_open * 100))
    for _ in range(5):
        cut = _random_cut(tree, rng, p_open)
        np.testing.assert_allclose(tree.area[cut].sum(), a.sum(), rtol=1e-12)
        np.testing.assert_allclose(tree.weight[cut].sum(), w.sum(), rtol=1e-12)
        # The cut's sample ranges partition the samples.
        cover = np.zeros(tree.n_samples + 1, dtype=np.int64)
        np.add.at(cover, tree.start[cut], 1)
        np.add.at(cover, tree.stop[cut], -1)
        np.testing.assert_array_equal(np.cumsum(cover)[:-1], 1)


def test_cells_are_octree_cells_containing_their_samples(case):
    _p, _, _, tree = case
    n = tree.n_samples
    inner = _internal(tree)
    side = tree.side / 2.0 ** tree.level[inner]
    # Corners are origin + integer * side, so their difference carries rounding of order eps * |corner|.
    atol = 1e-13 * (tree.side + np.abs(tree.origin).max())
    np.testing.assert_allclose(tree.hi[inner] - tree.lo[inner], side[:, None] * np.ones(3), rtol=1e-12, atol=atol)
    # Cell corners sit on the cube's dyadic grid at the node's level.
    grid = (tree.lo[inner] - tree.origin) / side[:, None]
    np.testing.assert_allclose(grid, np.round(grid), atol=1e-6)
    tol = 1e-9 * tree.side
    pos = tree.centroid[:n]
    for v in inner:
        s = slice(tree.start[v], tree.stop[v])
        assert np.all(pos[s] >= tree.lo[v] - tol) and np.all(pos[s] <= tree.hi[v] + tol)
    child_nodes = inner[inner != tree.root]
    par = tree.parent[child_nodes]
    assert np.all(tree.lo[child_nodes] >= tree.lo[par] - tol) and np.all(tree.hi[child_nodes] <= tree.hi[par] + tol)
    np.testing.assert_array_equal(tree.lo[:n], pos)
    np.testing.assert_array_equal(tree.hi[:n], pos)


def test_point_codes_match_cells(case):
    _, _, _, tree = case
    n = tree.n_samples
    np.testing.assert_array_equal(tree.point_codes(tree.centroid[:n]), tree.codes)
    cell = tree.cell_codes()
    shift = 3 * (MORTON_BITS - tree.level)
    # Every sample is inside the cell of every ancestor.
    for v in _internal(tree)[:200]:
        s = slice(tree.start[v], tree.stop[v])
        assert np.all((tree.codes[s] >> shift[v]) == cell[v])
    far = tree.origin + np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 2.0]]) * tree.side
    np.testing.assert_array_equal(tree.point_codes(far), [-1, -1])


@pytest.mark.parametrize("channels", [(), (3,)])
def test_segment_range_sum_and_cut_sums(case, channels):
    _, _, _, tree = case
    rng = np.random.default_rng(5)
    vals = rng.normal(size=(tree.n_samples, *channels))
    got = cut_sums_from_samples(tree, vals)
    assert got.shape == (tree.n_entities, *channels)
    want = np.stack([vals[s:e].sum(axis=0) for s, e in zip(tree.start, tree.stop, strict=True)])
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.abs(vals).sum())
    np.testing.assert_allclose(cut_sums_from_samples(tree, tree.area[: tree.n_samples]), tree.area, rtol=1e-9)
    # Empty ranges sum to zero.
    np.testing.assert_array_equal(segment_range_sum(vals, np.array([3, 0]), np.array([3, 0])), np.zeros((2, *channels)))
    with pytest.raises(ValueError, match="sample_values"):
        cut_sums_from_samples(tree, vals[:-1])


def test_sorted_samples_helper():
    rng = np.random.default_rng(2)
    p = rng.normal(size=(50, 3))
    tree = build_octree(p, np.ones(50), np.ones(50))
    np.testing.assert_array_equal(tree.sorted_samples(p), tree.centroid[:50])


def test_deterministic():
    rng = np.random.default_rng(9)
    p, a, w = _point_set("duplicates", rng)
    t1, t2 = build_octree(p, a, w), build_octree(p.copy(), a.copy(), w.copy())
    for f1, f2 in zip(t1, t2, strict=True):
        np.testing.assert_array_equal(f1, f2)


P3 = np.zeros((4, 3))
ONES = np.ones(4)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"positions": np.zeros((4, 2)), "areas": ONES, "weights": ONES}, "positions"),
        ({"positions": np.zeros((0, 3)), "areas": np.ones(0), "weights": np.ones(0)}, "positions"),
        ({"positions": np.array([[0, 0, np.nan]] * 4), "areas": ONES, "weights": ONES}, "positions"),
        ({"positions": np.array([[0, np.inf, 0]] * 4), "areas": ONES, "weights": ONES}, "positions"),
        ({"positions": [["a", "b", "c"]], "areas": [1.0], "weights": [1.0]}, "positions"),
        ({"positions": P3, "areas": np.array([1, 0, 1, 1.0]), "weights": ONES}, "areas"),
        ({"positions": P3, "areas": np.array([1, -1, 1, 1.0]), "weights": ONES}, "areas"),
        ({"positions": P3, "areas": np.array([1, np.nan, 1, 1.0]), "weights": ONES}, "areas"),
        ({"positions": P3, "areas": np.ones(3), "weights": ONES}, "areas"),
        ({"positions": P3, "areas": np.ones((4, 1)), "weights": ONES}, "areas"),
        ({"positions": P3, "areas": ONES, "weights": np.array([1, -1e-3, 1, 1.0])}, "weights"),
        ({"positions": P3, "areas": ONES, "weights": np.array([1, np.inf, 1, 1.0])}, "weights"),
        ({"positions": P3, "areas": ONES, "weights": np.ones(5)}, "weights"),
        ({"positions": P3, "areas": ONES, "weights": ONES, "max_leaf": 0}, "max_leaf"),
        ({"positions": P3, "areas": ONES, "weights": ONES, "max_leaf": 9}, "max_leaf"),
        ({"positions": P3, "areas": ONES, "weights": ONES, "max_leaf": 2.5}, "max_leaf"),
        ({"positions": P3, "areas": ONES, "weights": ONES, "max_depth": -1}, "max_depth"),
        ({"positions": P3, "areas": ONES, "weights": ONES, "max_depth": 22}, "max_depth"),
    ],
)
def test_bad_input_names_the_argument(kwargs, name):
    with pytest.raises(ValueError, match=rf"build_octree\({name}="):
        build_octree(**kwargs)


def test_bad_range_message_gives_value_and_range():
    with pytest.raises(ValueError, match=r"build_octree\(areas=-2\) \(element 1\) is outside the allowed range \(0, inf\)"):
        build_octree(P3, np.array([1, -2, 1, 1.0]), ONES)
