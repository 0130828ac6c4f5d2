"""The pair machinery of the hierarchical sums: interaction lists split into a far and a near part, padded into
blocks for ``lax.scan``, and their counts for the report.

A hierarchical sum is a segment-sum over (shaded point, octree entity) pairs; the list depends only on geometry
(:func:`~jaxsss.render.interactions.build_interactions`). :func:`pair_lists` builds it for a set of points and
splits off the near field (sample pairs closer than ``rho0``, summed with the disc correction of
:mod:`jaxsss.render.radiance`); :func:`pair_blocks` pads an index array into ``(B, K)`` blocks; :func:`pair_info`
summarises a :class:`PairLists` for the render report. The hierarchical, cached and photon methods use them.
"""

from __future__ import annotations

import functools
import math
from typing import Any, NamedTuple

import numpy as np

from jaxsss._config import to_device
from jaxsss.render.interactions import build_interactions

__all__ = ["BLOCK_PAIRS", "MIN_BLOCK", "NEAR_RADIUS_IN_SAMPLES", "PairLists", "near_radius", "pair_blocks", "pair_info",
           "pair_lists", "split_near"]

BLOCK_PAIRS = 1 << 16
"""Pairs per block of the hierarchical sum (one ``lax.scan`` step)."""
MIN_BLOCK = 256
"""The smallest block :func:`pair_blocks` makes for a short list."""

NEAR_RADIUS_IN_SAMPLES = 4.0
"""The near-field radius ``rho_0`` in sample radii ``sqrt(A_p / pi)`` (about 16 samples inside; see
:mod:`jaxsss.render.radiance`). On a uniformly lit plane at the paper's density (stratified samples) 2 gives 3-4%
pixel noise, 3 gives 1.4-2.4%, 4 gives 0.8-1.4% and 6 gives 0.4-0.7%, at the price of smoothing the irradiance over
a larger neighbourhood (about ``rho_0 / 2``)."""


class PairLists(NamedTuple):
    """Interaction lists of ``Q`` points: far pairs in ``(B, K)`` blocks (padded with query ``Q``, entity 0), near
    (query, sample) pairs, the near radius and per-point counts. The direct method has no lists (all None)."""

    far_query: Any  # (B, K) int32 jax array, or None
    far_entity: Any  # (B, K) int32 jax array, or None
    near_query: np.ndarray | None  # (K2,) int32, sorted by query
    near_sample: np.ndarray | None  # (K2,) int32
    rho0: float  # mm
    counts: np.ndarray  # (Q,) interactions per point
    nodes_inside: int  # accepted octree nodes with their centroid inside rho0


def pair_blocks(values: np.ndarray, fill: int, block: int) -> np.ndarray:
    """``values`` padded with ``fill`` and reshaped ``(B, K)``: the fewest blocks of at most ``block`` pairs, ``B =
    ceil(n / block)``, each as long as an even split needs, rounded up to a multiple of :data:`MIN_BLOCK`. The
    padding is then under ``B MIN_BLOCK`` pairs, where whole blocks of ``block`` padded up to 1.5x the work of a list
    just over a block and a power of two up to 2x that of a short one (the job's image fit, 129k pairs: 197k summed,
    now 131k). The sum is the same; only its grouping changes."""
    n = len(values)
    n_blocks = max(1, -(-n // block))
    k = -(-max(n, 1) // n_blocks)
    k = min(-(-k // MIN_BLOCK) * MIN_BLOCK, max(block, 1))
    pad = n_blocks * k - n
    return np.concatenate([values, np.full(pad, fill, dtype=values.dtype)]).reshape(n_blocks, k)


@functools.cache
def _compiled_split():
    """:func:`split_near`'s loop, compiled by Numba (cached on disk): one pass over the pairs, no temporaries."""
    from jaxsss._config import host_jit

    @host_jit
    def split(query, entity, centroid, q_pos, n, r2):
        k = query.shape[0]
        far = np.empty(k, np.bool_)
        n_far = 0
        nodes_inside = 0
        for i in range(k):
            e, q = entity[i], query[i]
            d0, d1, d2 = centroid[e, 0] - q_pos[q, 0], centroid[e, 1] - q_pos[q, 1], centroid[e, 2] - q_pos[q, 2]
            close = d0 * d0 + d1 * d1 + d2 * d2 < r2
            far[i] = not (close and e < n)
            n_far += far[i]
            nodes_inside += close and e >= n
        far_q, far_e = np.empty(n_far, np.int32), np.empty(n_far, np.int32)
        near_q, near_s = np.empty(k - n_far, np.int32), np.empty(k - n_far, np.int32)
        j = m = 0
        for i in range(k):
            if far[i]:
                far_q[j], far_e[j] = query[i], entity[i]
                j += 1
            else:
                near_q[m], near_s[m] = query[i], entity[i]
                m += 1
        return far_q, far_e, near_q, near_s, nodes_inside

    return split


def split_near(inter, q_pos, tree, rho0):
    """Split an interaction list into far pairs (summed point by point) and near (query, sample) pairs closer than
    ``rho0`` (the near list's radius: the near-field radius plus any shift of the kernel). Returns ``(far_query,
    far_entity, near_query, near_sample, nodes_inside)`` (int32 index arrays in the list's order) where
    ``nodes_inside`` counts accepted octree nodes whose centroid lies within ``rho0`` (0 unless eps is very large: a
    node there subtends a solid angle far above any sensible eps). The tree's centroids begin with the sorted sample
    positions, so one gather serves samples and nodes."""
    far_q, far_e, near_q, near_s, nodes_inside = _compiled_split()(
        np.ascontiguousarray(inter.query, dtype=np.int32), np.ascontiguousarray(inter.entity, dtype=np.int32),
        np.ascontiguousarray(tree.centroid, dtype=np.float64), np.ascontiguousarray(q_pos, dtype=np.float64),
        int(tree.n_samples), float(rho0) ** 2)
    return far_q, far_e, near_q, near_s, int(nodes_inside)


def near_radius(samples) -> float:
    """The near-field radius ``rho_0`` (mm) for these samples: :data:`NEAR_RADIUS_IN_SAMPLES` sample radii."""
    return NEAR_RADIUS_IN_SAMPLES * math.sqrt(float(np.mean(samples.areas)) / math.pi)


def pair_lists(tree, samples, q_pos, plan, *, progress: bool = False, block_pairs: int = BLOCK_PAIRS,
               near_margin: float = 0.0) -> PairLists:
    """Interaction lists for the points ``q_pos`` ``(Q, 3)`` against the sample octree ``tree`` (plan's ``eps`` and
    ``r_cut``): far pairs in blocks, near pairs, and counts. ``plan.method == "direct"`` gives no lists.
    ``near_margin`` (mm): samples within ``rho0 + near_margin`` go to the near list (a kernel that shifts its profile
    by up to that much, :func:`jaxsss.render.bssrdf.shift_reach`); the near-field radius stays ``rho0``."""
    rho0 = near_radius(samples)
    if plan.method == "direct" or len(q_pos) == 0:
        return PairLists(None, None, None, None, rho0, np.full(len(q_pos), samples.n), 0)
    inter = build_interactions(tree, q_pos, plan.eps, r_cut=plan.r_cut, progress=progress)
    far_q, far_e, near_q, near_s, nodes_inside = split_near(inter, q_pos, tree, rho0 + near_margin)
    pq = to_device(pair_blocks(far_q, len(q_pos), block_pairs))
    pe = to_device(pair_blocks(far_e, 0, block_pairs))
    return PairLists(pq, pe, near_q, near_s, rho0, inter.counts(), nodes_inside)


def pair_info(pairs: PairLists, n_points: int) -> dict[str, Any]:
    """The report's counts for a :class:`PairLists` of ``n_points`` points."""
    counts = pairs.counts
    return {
        "n_interactions": int(np.sum(counts)),
        "interactions_per_point_mean": float(np.mean(counts)) if len(counts) else 0.0,
        "interactions_per_point_max": int(np.max(counts)) if len(counts) else 0,
        "near_radius_mm": pairs.rho0,
        "near_samples_per_point_mean": (float(len(pairs.near_query) / max(n_points, 1))
                                        if pairs.near_query is not None else None),
        "octree_nodes_accepted_inside_near_radius": int(pairs.nodes_inside),
    }
