"""Geometry-only interaction lists for the hierarchical sum (Jensen and Buhler 2002, section 4.2, Eq. 12).

For each query point x (a shaded surface point) the octree is traversed from the root. A node v is accepted as a
whole when x lies outside v's cell and its solid-angle estimate is small (Eq. 12),

    Delta_omega = A_v / |x - P_v|^2 < eps,

otherwise it is opened and its children are tested; samples are accepted whenever they are reached. The accepted
entities of one query form a cut of the tree: their sample ranges partition the samples (or, with ``r_cut``, those
that may lie within ``r_cut``). The cut depends only on geometry, so it is computed once here (Numba), as a flat
list of (query, entity) pairs sorted by query; the material-dependent radiant exitance is then a JAX segment sum of
``Phi_v * R_d(|x - P_v|)`` over the pairs.
"""

from __future__ import annotations

import functools
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np

from jaxsss.validate import check_integer
from jaxsss.render.octree import MORTON_BITS, Octree

__all__ = ["Interactions", "build_interactions", "direct_interactions"]

MAX_DIRECT_PAIRS = 50_000_000
_INT32_MAX = np.iinfo(np.int32).max


class Interactions(NamedTuple):
    """(query, entity) pairs of the hierarchical sum, sorted by query, then entity.

    Attributes:
        query: ``(K,)`` int32 query index, ascending (segment ids for ``jax.ops.segment_sum`` with
            ``indices_are_sorted=True``).
        entity: ``(K,)`` int32 octree entity id (a sorted sample if ``< N``, else an internal node).
        n_queries: number of query points ``Q`` (queries may have no pairs).
        eps: the solid-angle threshold used (0.0 for :func:`direct_interactions`).
    """

    query: np.ndarray
    entity: np.ndarray
    n_queries: int
    eps: float

    def counts(self) -> np.ndarray:
        """``(Q,)`` number of interactions of each query."""
        return np.bincount(self.query, minlength=self.n_queries)

    @property
    def n_pairs(self) -> int:
        """``K``: total number of (query, entity) pairs."""
        return int(self.query.shape[0])


def _check_points(query_points) -> np.ndarray:
    try:
        x = np.asarray(query_points, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError("build_interactions(query_points=...) is not a numeric (Q, 3) array") from err
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"build_interactions(query_points=...) has shape {x.shape}; expected (Q, 3) in mm")
    bad = ~np.isfinite(x)
    if bad.any():
        i = tuple(int(k) for k in np.argwhere(bad)[0])
        raise ValueError(f"build_interactions(query_points={x[i]:g}) (element {i}) must be finite")
    if x.shape[0] > _INT32_MAX:
        raise ValueError(f"build_interactions(query_points=...) has {x.shape[0]} queries; at most {_INT32_MAX}")
    return x


def _check_positive(value, name: str, allow_none: bool) -> float | None:
    if value is None and allow_none:
        return None
    try:
        v = float(value)
    except (TypeError, ValueError) as err:
        raise ValueError(f"build_interactions({name}={value!r}) is not a number in (0, inf)") from err
    if not (v > 0 and np.isfinite(v)):
        raise ValueError(f"build_interactions({name}={v:g}) is outside the allowed range (0, inf)")
    return v


class _Tables(NamedTuple):
    """Per-internal-node arrays (indexed by ``entity - N``), packed for the traversal."""

    n: int
    area: np.ndarray
    centroid: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    shift: np.ndarray
    cell_code: np.ndarray
    first_child: np.ndarray
    n_child: np.ndarray
    is_leaf: np.ndarray
    samples: np.ndarray
    tol: float
    stack: int


def _tables(octree: Octree) -> _Tables:
    n = octree.n_samples
    ch = octree.children[n:]
    n_child = np.count_nonzero(ch >= 0, axis=1)
    first = ch[:, 0]
    # The traversal relies on each node's children being consecutive entity ids (true by construction).
    consecutive = np.where(ch >= 0, ch - first[:, None] == np.arange(8), True).all()
    if not consecutive or (n_child == 0).any():
        raise ValueError("build_interactions(octree=...) is not an Octree from build_octree (children not consecutive)")
    return _Tables(
        n=n,
        area=np.ascontiguousarray(octree.area[n:]),
        centroid=np.ascontiguousarray(octree.centroid[n:]),
        lo=np.ascontiguousarray(octree.lo[n:]),
        hi=np.ascontiguousarray(octree.hi[n:]),
        shift=np.ascontiguousarray(3 * (MORTON_BITS - octree.level[n:]), dtype=np.int64),
        cell_code=np.ascontiguousarray(octree.cell_codes()[n:], dtype=np.int64),
        first_child=first.astype(np.int64),
        n_child=n_child.astype(np.int64),
        is_leaf=octree.is_leaf_node[n:].copy(),
        samples=np.ascontiguousarray(octree.centroid[:n]),
        tol=1e-9 * octree.side,  # rounding margin of the cell boxes for the r_cut test
        # Depth-first, a node's unvisited siblings wait on the stack: at most 7 per level below the root, plus 8.
        stack=8 * (int(octree.depth[n:].max()) + 2),
    )


@functools.cache
def _compiled_traversal():
    """The traversal of one chunk of queries, compiled by Numba (cached on disk; released GIL, so threads share the
    chunks). Depth-first per query: its samples come out in increasing id (children are visited in Morton order),
    its accepted nodes are sorted apart and follow them (every node id exceeds every sample id).

    The function closes over nothing: Numba's disk cache keys a closure on its variables' pickles, and a jitted helper
    pickles differently in every process (a growth helper here made every process compile the traversal again)."""
    from jaxsss._config import host_jit

    @host_jit
    def traverse(area, centroid, lo, hi, shift, cell_code, first_child, n_child, is_leaf, samples, n, x, code, eps,
                 r2_cell, r2_sample, stack_size):
        n_q = x.shape[0]
        cap = max(1024, 64 * n_q)
        query = np.empty(cap, np.int32)
        entity = np.empty(cap, np.int32)
        nodes = np.empty(1024, np.int64)
        stack = np.empty(stack_size, np.int64)
        m = 0
        for iq in range(n_q):
            x0, x1, x2 = x[iq, 0], x[iq, 1], x[iq, 2]
            n_nodes = 0
            stack[0] = 0
            sp = 1
            while sp > 0:
                sp -= 1
                v = stack[sp]
                if r2_cell >= 0.0:
                    # Drop a node whose cell lies entirely beyond r_cut of the query.
                    g2 = 0.0
                    for k, xk in enumerate((x0, x1, x2)):
                        g = max(lo[v, k] - xk, xk - hi[v, k], 0.0)
                        g2 += g * g
                    if g2 > r2_cell:
                        continue
                # Eq. 12: accept v when A_v / |x - P_v|^2 < eps and x is outside v's cell (same code at v's level).
                d0, d1, d2 = x0 - centroid[v, 0], x1 - centroid[v, 1], x2 - centroid[v, 2]
                if area[v] < eps * (d0 * d0 + d1 * d1 + d2 * d2) and (code[iq] >> shift[v]) != cell_code[v]:
                    if n_nodes == nodes.shape[0]:
                        nodes = np.concatenate((nodes, np.empty_like(nodes)))
                    nodes[n_nodes] = v + n
                    n_nodes += 1
                    continue
                c0, nc = first_child[v], n_child[v]
                if is_leaf[v]:
                    # A leaf hands over its samples (those within r_cut, when there is one).
                    if m + nc > cap:
                        cap = 2 * (m + nc)
                        query = np.concatenate((query, np.empty(cap - query.shape[0], np.int32)))
                        entity = np.concatenate((entity, np.empty(cap - entity.shape[0], np.int32)))
                    for e in range(c0, c0 + nc):
                        if r2_sample >= 0.0:
                            s0, s1, s2 = x0 - samples[e, 0], x1 - samples[e, 1], x2 - samples[e, 2]
                            if s0 * s0 + s1 * s1 + s2 * s2 > r2_sample:
                                continue
                        query[m] = iq
                        entity[m] = e
                        m += 1
                else:
                    # Children pushed last first, so that they are visited in order (Morton, then rank).
                    for c in range(nc - 1, -1, -1):
                        stack[sp] = c0 + c - n
                        sp += 1
            if m + n_nodes > cap:
                cap = 2 * (m + n_nodes)
                query = np.concatenate((query, np.empty(cap - query.shape[0], np.int32)))
                entity = np.concatenate((entity, np.empty(cap - entity.shape[0], np.int32)))
            accepted = np.sort(nodes[:n_nodes])
            for j in range(n_nodes):
                query[m] = iq
                entity[m] = accepted[j]
                m += 1
        return query[:m].copy(), entity[:m].copy()

    return traverse


def _traverse_chunk(t: _Tables, x: np.ndarray, eps: float, r_cut: float | None, code: np.ndarray):
    """Accepted pairs ``(local query, entity)`` (int32 each) for the queries ``x`` of one chunk, sorted by query then
    entity. ``code`` holds the queries' Morton codes (``-1`` outside the cube)."""
    r2_cell = -1.0 if r_cut is None else (r_cut + t.tol) ** 2
    r2_sample = -1.0 if r_cut is None else r_cut**2
    return _compiled_traversal()(t.area, t.centroid, t.lo, t.hi, t.shift, t.cell_code, t.first_child, t.n_child,
                                 t.is_leaf, t.samples, t.n, np.ascontiguousarray(x), np.ascontiguousarray(code),
                                 float(eps), r2_cell, r2_sample, t.stack)


_MIN_CHUNK = 256
"""The fewest queries :func:`build_interactions` gives a thread (below it the per-chunk overhead dominates)."""


def build_interactions(
    octree: Octree,
    query_points,
    eps: float,
    *,
    r_cut: float | None = None,
    chunk_size: int = 4096,
    progress: bool = False,
    n_threads: int | None = None,
) -> Interactions:
    """Interaction list of the hierarchical sum: for every query, the octree cut chosen by Eq. 12.

    A node ``v`` is accepted for query ``x`` when ``x`` is outside ``v``'s cell and ``A_v / |x - P_v|^2 < eps``;
    otherwise its children are tested. Samples are accepted whenever reached. "Outside the cell" uses the octree's
    quantised grid (:meth:`Octree.point_codes`): cells are half-open boxes ``[lo, hi)``, the rule that put the
    samples into them, so a query at a sample's position is inside every cell holding that sample.

    Args:
        octree: from :func:`jaxsss.render.octree.build_octree`.
        query_points: ``(Q, 3)`` query positions in mm.
        eps: solid-angle threshold of Eq. 12, in ``(0, inf)``; smaller is more accurate and makes more pairs.
        r_cut: optional cut-off radius in mm, in ``(0, inf)``. A node is dropped when its cell box is farther than
            ``r_cut`` from the query, a sample when it is; every sample within ``r_cut`` stays covered exactly once
            (accepted nodes may also cover samples beyond ``r_cut``).
        chunk_size: queries per call of the compiled traversal (a thread takes one chunk at a time).
        progress: show a tqdm bar over chunks.
        n_threads: worker threads over chunks (the compiled traversal releases the GIL); default: the usable
            cores. The result does not depend on it.

    Returns:
        :class:`Interactions`, sorted by query then entity. Without ``r_cut`` each query's accepted entities'
        sample ranges ``[start, stop)`` partition ``0 .. N-1``.
    """
    if not isinstance(octree, Octree):
        raise TypeError(f"build_interactions(octree={type(octree).__name__}) must be an Octree from build_octree")
    x = _check_points(query_points)
    eps = _check_positive(eps, "eps", allow_none=False)
    r_cut = _check_positive(r_cut, "r_cut", allow_none=True)
    check_integer(chunk_size, "chunk_size", 1, owner="build_interactions")
    if n_threads is None:
        from jaxsss.mc.engine import usable_cores

        n_threads = usable_cores()
    check_integer(n_threads, "n_threads", 1, owner="build_interactions")
    if octree.n_entities > _INT32_MAX:
        raise ValueError(f"build_interactions(octree=...) has {octree.n_entities} entities; int32 ids need <= "
                         f"{_INT32_MAX}")
    t = _tables(octree)
    n_q = x.shape[0]
    code = octree.point_codes(x)
    # Fewer queries than one chunk per thread: split them evenly, so that every core traverses (the 64 x 64 skin1
    # sphere has 2,024 queries, one default chunk: 0.22-0.27 s on one thread, 0.14-0.15 s split over 2 cores).
    chunk_size = min(chunk_size, max(_MIN_CHUNK, -(-n_q // n_threads)))

    def run(q0: int):
        sl = slice(q0, q0 + chunk_size)
        query, entity = _traverse_chunk(t, x[sl], eps, r_cut, code[sl])
        # Chunks come in query order, so concatenating the sorted chunks sorts the whole list.
        query += q0
        return query, entity

    starts = range(0, n_q, chunk_size)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(starts), desc="interactions", unit="chunk")
    queries, entities = [], []
    with ThreadPoolExecutor(max_workers=min(n_threads, max(len(starts), 1))) as pool:
        for qc, ec in pool.map(run, starts):
            queries.append(qc)
            entities.append(ec)
            if bar is not None:
                bar.update(1)
    if bar is not None:
        bar.close()
    return Interactions(_concat_freeing(queries), _concat_freeing(entities), int(n_q), eps)


def _concat_freeing(parts: list) -> np.ndarray:
    """Concatenate int32 arrays, releasing each part once copied (peak memory ~ one copy of the result)."""
    out = np.empty(sum(a.size for a in parts), dtype=np.int32)
    pos = 0
    parts.reverse()
    while parts:
        a = parts.pop()
        out[pos : pos + a.size] = a
        pos += a.size
    return out


def direct_interactions(octree: Octree, n_queries: int, query_subset=None) -> Interactions:
    """Every query with every sample (the exact O(Q N) sum), for small problems and tests.

    Args:
        octree: gives the samples (entity ids ``0 .. N-1``).
        n_queries: ``Q``, the number of query points.
        query_subset: optional indices of the queries to include (the others get no pairs); default all.

    Raises:
        ValueError: beyond ``5e7`` pairs, with the pair count.
    """
    check_integer(n_queries, "n_queries", 0, _INT32_MAX, owner="direct_interactions")
    if query_subset is None:
        qs = np.arange(n_queries, dtype=np.int64)
    else:
        qs = np.unique(np.asarray(query_subset, dtype=np.int64).ravel())
        if qs.size and (qs[0] < 0 or qs[-1] >= n_queries):
            bad = qs[0] if qs[0] < 0 else qs[-1]
            raise ValueError(f"direct_interactions(query_subset={bad}) is outside the allowed range [0, {n_queries})")
    n = octree.n_samples
    pairs = qs.size * n
    if pairs > MAX_DIRECT_PAIRS:
        raise ValueError(
            f"direct_interactions(...) would make {pairs} pairs ({qs.size} queries x {n} samples); "
            f"the limit is {MAX_DIRECT_PAIRS:.0e}, use build_interactions"
        )
    query = np.repeat(qs, n).astype(np.int32)
    entity = np.tile(np.arange(n, dtype=np.int32), qs.size)
    return Interactions(query, entity, int(n_queries), 0.0)
