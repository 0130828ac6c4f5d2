"""Octree over the irradiance samples for the hierarchical sum (Jensen and Buhler 2002, section 4.2).

Pure NumPy geometry: the tree depends only on where the samples are, their areas and a non-negative weight used for
centroids. The material-dependent flux sums are range sums over the Morton-sorted samples (:func:`segment_range_sum`),
so the JAX side can recompute every node's flux from per-sample values with one cumulative sum.

Layout (one index space for samples and nodes, so a (query, entity) interaction list needs no case split):

- samples are stored in Morton (Z-order) order; ``order[i]`` is the original index of sorted sample ``i``;
- entity ids ``0 .. N-1`` are the sorted samples, ``N .. N+M-1`` the ``M`` internal nodes, root first, then
  breadth-first, each level in Morton order (a parent's id is always smaller than its children's);
- every entity covers the contiguous sorted-sample range ``[start, stop)``; a node's children are consecutive ids
  whose ranges partition the parent's range, packed left in ``children`` (``-1`` pads the unused slots).

The tree is a *compressed* octree: a node's cell is the smallest octree cell (of the bounding cube's dyadic
subdivision) that contains all of its samples, so a cell with a single occupied child is merged into that child and
every node that is split by position has at least two children. This gives the same cut as the plain octree for the
solid-angle traversal (a chain of single children has identical ``A_v`` and ``P_v``), with tighter cells and fewer
levels.

Coincident points: a node is split by position only down to ``max_depth`` (21 bits per axis, the Morton code's
resolution). A node at that depth that still holds more than ``max_leaf`` samples (exact or nearly exact duplicates)
is split *by rank* into at most 8 balanced contiguous groups that share the parent's cell, recursively, so every leaf
holds at most ``max_leaf`` samples and every node at most 8 children, duplicates included.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxsss.validate import check_integer

__all__ = ["Octree", "build_octree", "cut_sums_from_samples", "morton_codes", "segment_range_sum"]

MORTON_BITS = 21  # bits per axis; 3 * 21 = 63 bits fit a non-negative int64


class Octree(NamedTuple):
    """An octree over ``N`` samples with ``M`` internal nodes; every array is indexed by entity id (length ``N+M``).

    Attributes:
        order: ``(N,)`` int64 permutation; sorted sample ``i`` is original sample ``order[i]``.
        n_samples: ``N``; entity ids below ``N`` are samples (in sorted order), the rest internal nodes.
        start, stop: ``(N+M,)`` int64 sorted-sample range ``[start, stop)`` below each entity (a sample: ``i, i+1``).
        area: ``(N+M,)`` total area ``A_v`` (mm^2) of the samples below.
        weight: ``(N+M,)`` total weight below (the channel-mean transmitted flux in the renderer).
        centroid: ``(N+M, 3)`` weight-weighted mean position ``P_v`` (mm) of the samples below, area-weighted where
            the weight below is 0; a sample's own position.
        lo, hi: ``(N+M, 3)`` corners (mm) of the node's octree cell (the smallest dyadic cell holding its samples,
            not the tight bounding box); ``lo = hi = position`` for a sample.
        children: ``(N+M, 8)`` int64 child entity ids packed left, ``-1`` for none. A leaf node's children are its
            samples; a sample has none.
        is_leaf_node: ``(N+M,)`` bool, True for internal nodes whose children are samples.
        root: entity id of the root, always ``N`` (a single leaf node when ``N <= max_leaf``).
        depth: ``(N+M,)`` int64 number of edges from the root (a sample is one deeper than its leaf).
        parent: ``(N+M,)`` int64 parent entity id, ``-1`` for the root.
        level: ``(N+M,)`` int64 subdivision level of the cell (cell side = ``side / 2**level``); ``MORTON_BITS``
            for samples.
        codes: ``(N,)`` int64 Morton codes of the sorted samples (ascending).
        origin: ``(3,)`` min corner (mm) of the bounding cube whose dyadic subdivision gives the cells.
        side: side (mm) of the bounding cube.
    """

    order: np.ndarray
    n_samples: int
    start: np.ndarray
    stop: np.ndarray
    area: np.ndarray
    weight: np.ndarray
    centroid: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    children: np.ndarray
    is_leaf_node: np.ndarray
    root: int
    depth: np.ndarray
    parent: np.ndarray
    level: np.ndarray
    codes: np.ndarray
    origin: np.ndarray
    side: float

    @property
    def n_entities(self) -> int:
        """``N + M``: samples plus internal nodes."""
        return int(self.start.shape[0])

    @property
    def n_nodes(self) -> int:
        """``M``: internal nodes."""
        return self.n_entities - self.n_samples

    @property
    def n_children(self) -> np.ndarray:
        """``(N+M,)`` number of children of each entity (0 for samples)."""
        return np.count_nonzero(self.children >= 0, axis=1)

    def point_codes(self, points) -> np.ndarray:
        """Morton codes ``(n,)`` of arbitrary points ``(n, 3)`` on the samples' grid; ``-1`` outside the cube.

        A point lies in node ``v``'s cell exactly when ``point_codes >> 3 * (MORTON_BITS - level[v])`` equals the
        node's cell code (:meth:`cell_codes`). Cells are half-open boxes ``[lo, hi)`` on the quantised grid, the
        same rule that assigns the samples to cells, so a query at a sample's position is inside every cell that
        holds the sample.
        """
        return _quantise(np.asarray(points, dtype=np.float64), self.origin, self.side)[1]

    def cell_codes(self) -> np.ndarray:
        """``(N+M,)`` Morton code of each entity's cell at its own level (prefix of its samples' codes)."""
        return self.codes[self.start] >> (3 * (MORTON_BITS - self.level))

    def sorted_samples(self, values) -> np.ndarray:
        """Reorder per-original-sample ``values`` (``(N, ...)``) into sorted order (entity ids ``0 .. N-1``)."""
        return np.asarray(values)[self.order]


def segment_range_sum(values_sorted, start, stop) -> np.ndarray:
    """Sums ``values_sorted[start[j]:stop[j]].sum(axis=0)`` for every ``j``, by differences of one cumulative sum.

    This is the formula the JAX side uses to turn per-sample values into per-entity values. It costs one cumsum
    plus two gathers; its absolute error is of order ``machine eps * sum(|values|)`` (so small nodes of a large
    sample set carry that absolute, not relative, error; fine in float64).

    Args:
        values_sorted: ``(N, ...)`` per-sample values in sorted order.
        start, stop: integer arrays of the same shape with ``0 <= start <= stop <= N``.

    Returns:
        ``start.shape + values_sorted.shape[1:]`` sums (0 for empty ranges).
    """
    values_sorted = np.asarray(values_sorted)
    zero = np.zeros((1,) + values_sorted.shape[1:], dtype=values_sorted.dtype)
    cs = np.concatenate([zero, np.cumsum(values_sorted, axis=0)], axis=0)
    return cs[np.asarray(stop)] - cs[np.asarray(start)]


def cut_sums_from_samples(octree: Octree, sample_values) -> np.ndarray:
    """Per-entity sums ``(N+M, ...)`` of per-SORTED-sample values ``(N, ...)`` over each entity's sample range."""
    sample_values = np.asarray(sample_values)
    if sample_values.ndim < 1 or sample_values.shape[0] != octree.n_samples:
        raise ValueError(
            f"cut_sums_from_samples(sample_values=...) has shape {sample_values.shape}; "
            f"expected ({octree.n_samples}, ...) values in sorted sample order"
        )
    return segment_range_sum(sample_values, octree.start, octree.stop)


def _spread_bits(v: np.ndarray) -> np.ndarray:
    """Insert two zero bits after each of the low 21 bits of ``v`` (uint64), the Morton 'part1by2' step."""
    v = v & np.uint64(0x1FFFFF)
    v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
    return v


def morton_codes(cells: np.ndarray) -> np.ndarray:
    """63-bit Morton codes (int64) of integer cell coordinates ``(n, 3)`` in ``[0, 2**21)``; x is the high bit."""
    c = np.asarray(cells).astype(np.uint64)
    code = (_spread_bits(c[:, 0]) << np.uint64(2)) | (_spread_bits(c[:, 1]) << np.uint64(1)) | _spread_bits(c[:, 2])
    return code.astype(np.int64)


def _quantise(points: np.ndarray, origin: np.ndarray, side: float):
    """Integer cell coordinates ``(n, 3)`` (clipped) and Morton codes (``-1`` where outside the cube) of points."""
    n_cells = 1 << MORTON_BITS
    f = np.floor((points - origin) * (n_cells / side))
    outside = ((f < 0) | (f >= n_cells)).any(axis=1)
    cells = np.clip(f, 0, n_cells - 1).astype(np.int64)
    return cells, np.where(outside, -1, morton_codes(cells))


def _bit_length(x: np.ndarray) -> np.ndarray:
    """Number of significant bits of non-negative int64 values (0 for 0), exactly, without float rounding."""
    x = x.copy()
    n = np.zeros(x.shape, dtype=np.int64)
    for s in (32, 16, 8, 4, 2, 1):
        big = (x >> s) > 0
        n += s * big
        x = np.where(big, x >> s, x)
    return n + (x > 0)


def _common_level(codes_first: np.ndarray, codes_last: np.ndarray) -> np.ndarray:
    """Deepest level at which two Morton codes share their cell (the common 3-bit-group prefix length)."""
    b = _bit_length(codes_first ^ codes_last)  # highest differing bit is b - 1; equal codes give b = 0
    return MORTON_BITS - (b + 2) // 3


def _concat_ranges(start: np.ndarray, stop: np.ndarray):
    """Concatenation of ``arange(start[j], stop[j])`` and, for each element, which ``j`` it came from."""
    lens = stop - start
    owner = np.repeat(np.arange(start.shape[0]), lens)
    offsets = np.cumsum(lens) - lens
    idx = np.arange(int(lens.sum()), dtype=np.int64) - offsets[owner] + start[owner]
    return idx, owner


def _range_sums_exact(values: np.ndarray, start: np.ndarray, stop: np.ndarray) -> np.ndarray:
    """Range sums by ``np.add.reduceat`` (pairwise per range, no cancellation); ranges must be non-empty."""
    padded = np.concatenate([values, np.zeros((1,) + values.shape[1:], dtype=values.dtype)], axis=0)
    idx = np.stack([start, stop], axis=1).ravel()
    return np.add.reduceat(padded, idx, axis=0)[::2]


def _as_array(x, name: str, shape_text: str, ndim: int) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"build_octree({name}=...) is not a numeric array (expected {shape_text})") from err
    if a.ndim != ndim or (ndim == 2 and a.shape[1] != 3):
        raise ValueError(f"build_octree({name}=...) has shape {a.shape}; expected {shape_text}")
    return a


def _check_inputs(positions, areas, weights, max_leaf, max_depth):
    positions = _as_array(positions, "positions", "(N, 3) in mm", 2)
    n = positions.shape[0]
    areas = _as_array(areas, "areas", f"({n},) in mm^2", 1)
    weights = _as_array(weights, "weights", f"({n},)", 1)
    if n < 1:
        raise ValueError("build_octree(positions=...) has no samples; need N >= 1 positions of shape (N, 3)")
    for name, a in (("areas", areas), ("weights", weights)):
        if a.shape[0] != n:
            raise ValueError(f"build_octree({name}=...) has shape {a.shape}; expected ({n},) to match positions")
    bad = ~np.isfinite(positions)
    if bad.any():
        i = tuple(int(k) for k in np.argwhere(bad)[0])
        raise ValueError(f"build_octree(positions={positions[i]:g}) (element {i}) must be finite")
    bad = ~(np.isfinite(areas) & (areas > 0))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"build_octree(areas={areas[i]:g}) (element {i}) is outside the allowed range (0, inf)")
    bad = ~(np.isfinite(weights) & (weights >= 0))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"build_octree(weights={weights[i]:g}) (element {i}) is outside the allowed range [0, inf)")
    check_integer(max_leaf, "max_leaf", 1, 8, owner="build_octree")  # the 8 child slots
    check_integer(max_depth, "max_depth", 0, MORTON_BITS, owner="build_octree")
    return positions, areas, weights


def build_octree(positions, areas, weights, *, max_leaf: int = 8, max_depth: int = MORTON_BITS) -> Octree:
    """Build the octree over irradiance samples (vectorised, level by level over Morton-sorted samples).

    Args:
        positions: ``(N, 3)`` sample positions in mm, finite, ``N >= 1``.
        areas: ``(N,)`` sample areas in mm^2, in ``(0, inf)``.
        weights: ``(N,)`` non-negative weights for the centroids (e.g. channel-mean transmitted flux), ``[0, inf)``.
        max_leaf: most samples in a leaf node, in ``[1, 8]`` (a leaf's samples fill its 8 child slots).
        max_depth: deepest cell level split by position, in ``[0, 21]``; fuller cells are split by rank (see the
            module docstring), which is how exact duplicates are handled.

    Returns:
        An :class:`Octree`.

    Raises:
        ValueError: naming the argument and the allowed range.
    """
    positions, areas, weights = _check_inputs(positions, areas, weights, max_leaf, max_depth)
    n = positions.shape[0]

    # Bounding cube (its side is the largest extent, padded so the far faces quantise inside); 1 mm if degenerate.
    origin = positions.min(axis=0)
    extent = float((positions.max(axis=0) - origin).max())
    side = extent * (1.0 + 1e-9) if extent > 0 else 1.0
    cells, codes_orig = _quantise(positions, origin, side)
    codes_orig = np.where(codes_orig < 0, morton_codes(cells), codes_orig)  # rounding at the far faces: clip
    order = np.argsort(codes_orig, kind="stable").astype(np.int64)
    codes = codes_orig[order]
    cells = cells[order]
    pos = positions[order]
    area_s = areas[order]
    weight_s = weights[order]

    # Level by level (tree depth): each node's cell level is the common prefix of its first and last codes.
    starts, stops, parents, depths, levels = [], [], [], [], []
    cur_start = np.array([0], dtype=np.int64)
    cur_stop = np.array([n], dtype=np.int64)
    cur_parent = np.array([-1], dtype=np.int64)
    next_id = n
    depth = 0
    while cur_start.size:
        count = cur_stop - cur_start
        level = np.minimum(_common_level(codes[cur_start], codes[cur_stop - 1]), max_depth)
        ids = next_id + np.arange(cur_start.size, dtype=np.int64)
        starts.append(cur_start)
        stops.append(cur_stop)
        parents.append(cur_parent)
        depths.append(np.full(cur_start.size, depth, dtype=np.int64))
        levels.append(level)
        next_id += cur_start.size
        depth += 1

        split = count > max_leaf
        by_code = split & (level < max_depth)
        by_rank = split & (level >= max_depth)
        new_start, new_parent = [], []
        if by_code.any():
            # Group the node's samples by their cell one level below the node's cell (contiguous in Morton order).
            idx, owner = _concat_ranges(cur_start[by_code], cur_stop[by_code])
            shift = 3 * (MORTON_BITS - 1 - level[by_code])
            key = codes[idx] >> shift[owner]
            first = np.ones(idx.size, dtype=bool)
            first[1:] = (key[1:] != key[:-1]) | (owner[1:] != owner[:-1])
            new_start.append(idx[first])
            new_parent.append(ids[by_code][owner[first]])
        if by_rank.any():
            # Cell at max_depth still too full (duplicates): split into <= 8 balanced rank groups sharing the cell.
            s, c = cur_start[by_rank], count[by_rank]
            k = np.minimum(8, -(-c // max_leaf))
            owner = np.repeat(np.arange(s.size), k)
            j = np.arange(int(k.sum()), dtype=np.int64) - np.repeat(np.cumsum(k) - k, k)
            new_start.append(s[owner] + (c[owner] * j) // k[owner])
            new_parent.append(ids[by_rank][owner])
        if not new_start:
            break
        cur_start = np.concatenate(new_start)
        cur_parent = np.concatenate(new_parent)
        perm = np.argsort(cur_start, kind="stable")
        cur_start, cur_parent = cur_start[perm], cur_parent[perm]
        # A child ends where the next child starts, or at its parent's end.
        parent_stop = np.concatenate(stops)[cur_parent - n]
        cur_stop = np.empty_like(cur_start)
        cur_stop[:-1] = np.where(cur_parent[1:] == cur_parent[:-1], cur_start[1:], parent_stop[:-1])
        cur_stop[-1] = parent_stop[-1]

    node_start = np.concatenate(starts)
    node_stop = np.concatenate(stops)
    node_parent = np.concatenate(parents)
    node_depth = np.concatenate(depths)
    node_level = np.concatenate(levels)
    m = node_start.size
    n_ent = n + m
    node_ids = n + np.arange(m, dtype=np.int64)

    # Children: child nodes are consecutive ids per parent; a leaf node's children are its samples.
    children = np.full((n_ent, 8), -1, dtype=np.int64)
    has_parent = node_parent >= 0
    child_ids = node_ids[has_parent]
    child_parent = node_parent[has_parent]
    first_child = np.full(n_ent, -1, dtype=np.int64)
    parents_with_children, first_pos = np.unique(child_parent, return_index=True)
    first_child[parents_with_children] = child_ids[first_pos]  # smallest child id per parent
    children[child_parent, child_ids - first_child[child_parent]] = child_ids
    is_leaf_node = np.zeros(n_ent, dtype=bool)
    is_leaf_node[n:] = first_child[n:] < 0
    leaf_ids = node_ids[is_leaf_node[n:]]
    samples, owner = _concat_ranges(node_start[leaf_ids - n], node_stop[leaf_ids - n])
    sample_leaf = leaf_ids[owner]
    children[sample_leaf, samples - node_start[sample_leaf - n]] = samples

    sample_ids = np.arange(n, dtype=np.int64)
    start = np.concatenate([sample_ids, node_start])
    stop = np.concatenate([sample_ids + 1, node_stop])
    parent = np.empty(n_ent, dtype=np.int64)
    parent[samples] = sample_leaf
    parent[n:] = node_parent
    depth_all = np.empty(n_ent, dtype=np.int64)
    depth_all[samples] = node_depth[sample_leaf - n] + 1
    depth_all[n:] = node_depth
    level_all = np.concatenate([np.full(n, MORTON_BITS, dtype=np.int64), node_level])

    # Aggregates over each node's contiguous sample range (Jensen and Buhler 2002: A_v, flux, P_v).
    node_area = _range_sums_exact(area_s, node_start, node_stop)
    node_weight = _range_sums_exact(weight_s, node_start, node_stop)
    node_wpos = _range_sums_exact(weight_s[:, None] * pos, node_start, node_stop)
    node_apos = _range_sums_exact(area_s[:, None] * pos, node_start, node_stop)
    has_w = node_weight > 0
    denom = np.where(has_w, node_weight, node_area)[:, None]
    node_centroid = np.where(has_w[:, None], node_wpos, node_apos) / denom

    # Cell corners from the integer cell coordinates of the node's first sample.
    cell_side = side / np.exp2(node_level)
    ijk = cells[node_start] >> (MORTON_BITS - node_level)[:, None]
    node_lo = origin + ijk * cell_side[:, None]
    node_hi = node_lo + cell_side[:, None]

    return Octree(
        order=order,
        n_samples=int(n),
        start=start,
        stop=stop,
        area=np.concatenate([area_s, node_area]),
        weight=np.concatenate([weight_s, node_weight]),
        centroid=np.concatenate([pos, node_centroid]),
        lo=np.concatenate([pos, node_lo]),
        hi=np.concatenate([pos, node_hi]),
        children=children,
        is_leaf_node=is_leaf_node,
        root=int(n),
        depth=depth_all,
        parent=parent,
        level=level_all,
        codes=codes,
        origin=origin,
        side=float(side),
    )
