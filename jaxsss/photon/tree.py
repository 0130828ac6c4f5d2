"""The volumetric octree of photon sources (photon diffusion, Section 5) and its geometry-only interaction lists.

The stored sources fill a volume a few mean free paths deep under the lit surface. They go into the renderer's octree
(:func:`jaxsss.render.octree.build_octree`, at most 8 sources per leaf), with

- **power-weighted centroids** -- the weight is each source's channel-mean power at the tracing material;
- the **area** each photon stands for on the surface (:mod:`jaxsss.photon.trace`), so a node's ``A_v`` is the patch
  of lit surface its sources came through and the solid-angle test ``A_v / |x - P_v|^2 < eps`` (hierarchical paper
  Eq. 12) means what it means for irradiance samples;
- an **averaged incidence plane** per node: the unit power-weighted mean of the sources' normals ``n_v`` through the
  power-weighted mean entry point ``e_v = mean(x_i + depth_i n_i)``, and the node's depth ``(e_v - P_v) . n_v``,
  **kept positive**: where the averaged plane would put the centroid above it (sources entering through differently
  oriented faces of an edge) the node takes its members' mean depth instead.

Interaction lists (:func:`jaxsss.render.interactions.build_interactions`) are then split in NumPy by what each pair
needs, all from geometry:

- **shadow rays**: with blockers in the scene, a ray from the shading point to the entity's centroid; a pair whose ray
  hits a blocker is dropped (volumetric shadow), which is only the blockers' geometry (``blocked`` counts them);
- **multipole or not**: Eq. 15 gives the multipole weight only where ``gamma > pi/2``; pairs at ``gamma <= pi/2``
  are evaluated without image pairs (``n_pairs = 0``), the others with them.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxsss.photon.trace import Sources
from jaxsss.render.interactions import build_interactions
from jaxsss.render.octree import Octree, build_octree, cut_sums_from_samples
from jaxsss.render.rays import SceneGeometry

__all__ = ["PairLists", "SourceTree", "pair_lists", "source_tree"]


class SourceTree(NamedTuple):
    """The octree of sources with each entity's averaged incidence plane.

    Attributes:
        octree: the :class:`~jaxsss.render.octree.Octree` (entities: sorted sources, then nodes).
        normal: ``(E, 3)`` unit averaged incidence-plane normal of each entity.
        depth: ``(E,)`` depth of the entity's centroid below that plane, mm, ``>= 0``.
        fixed_depth: number of nodes whose averaged-plane depth was not positive (they use the mean depth).
    """

    octree: Octree
    normal: np.ndarray
    depth: np.ndarray
    fixed_depth: int


def source_tree(sources: Sources, *, max_leaf: int = 8) -> SourceTree:
    """Octree over ``sources`` (power-weighted centroids, averaged planes with positive depth); see the module."""
    if sources.n == 0:
        raise ValueError("source_tree(sources=...) is empty: no photon scattered inside the object (is it lit?)")
    weight = np.maximum(sources.power.mean(axis=1), 0.0)
    area = np.maximum(sources.area, 1e-300)
    tree = build_octree(sources.position, area, weight, max_leaf=max_leaf)
    w_s = tree.sorted_samples(weight)
    # Area weights where a node's power is zero, as for the centroids.
    w_s = np.where(w_s > 0, w_s, 0.0)
    n_s = tree.sorted_samples(sources.normal)
    d_s = tree.sorted_samples(sources.depth)
    entry = tree.sorted_samples(sources.position) + d_s[:, None] * n_s
    tot = cut_sums_from_samples(tree, w_s)
    use_area = tot <= 0
    a_s = tree.sorted_samples(area)
    tot_a = cut_sums_from_samples(tree, a_s)

    def mean(values_w, values_a):
        num = np.where(use_area[:, None] if values_w.ndim > 1 else use_area, values_a, values_w)
        den = np.where(use_area, tot_a, tot)
        return num / (den[:, None] if num.ndim > 1 else den)

    # Power-weighted mean normal and entry point, and the members' mean depth.
    normal = mean(cut_sums_from_samples(tree, w_s[:, None] * n_s), cut_sums_from_samples(tree, a_s[:, None] * n_s))
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    degenerate = length[:, 0] < 1e-12  # opposite faces cancel: keep the first member's normal
    normal = np.where(degenerate[:, None], n_s[tree.start], normal / np.where(length > 0, length, 1.0))
    e_v = mean(cut_sums_from_samples(tree, w_s[:, None] * entry), cut_sums_from_samples(tree, a_s[:, None] * entry))
    mean_depth = mean(cut_sums_from_samples(tree, w_s * d_s), cut_sums_from_samples(tree, a_s * d_s))
    depth = np.einsum("ij,ij->i", e_v - tree.centroid, normal)
    bad = ~(depth > 0)
    n = tree.n_samples
    depth = np.where(bad, np.maximum(mean_depth, 0.0), depth)
    depth[:n] = d_s  # a source keeps its own plane exactly
    normal[:n] = n_s
    return SourceTree(tree, normal, depth, int(np.count_nonzero(bad[n:])))


class PairLists(NamedTuple):
    """Pairs (query, entity) of the hierarchical sum, sorted by query, split into those without and with the
    multipole (``gamma <= pi/2`` and ``> pi/2``), after volumetric shadowing.

    Attributes:
        query, entity: ``(2,)`` tuples of int32 arrays: index 0 without, 1 with the multipole.
        n_total: pairs before shadowing.
        n_blocked: pairs dropped by a blocker.
    """

    query: tuple
    entity: tuple
    n_total: int
    n_blocked: int

    @property
    def n_pairs(self) -> int:
        return int(sum(len(q) for q in self.query))


def pair_lists(stree: SourceTree, query_pos, query_normal, eps: float, *, blockers: SceneGeometry | None = None,
               progress: bool = False, chunk: int = 1 << 21) -> PairLists:
    """Interaction lists for shading points ``(Q, 3)`` with outward normals ``(Q, 3)``: the octree cut by Eq. 12,
    shadowed by ``blockers`` (a geometry of the blocker meshes only) and split by ``gamma`` (see the module)."""
    tree = stree.octree
    inter = build_interactions(tree, query_pos, eps, progress=progress)
    pos_e = tree.centroid
    qs, es = inter.query, inter.entity
    keep = np.ones(len(qs), bool)
    if blockers is not None and len(qs):
        for s in range(0, len(qs), chunk):
            q, e = qs[s:s + chunk], es[s:s + chunk]
            delta = pos_e[e] - query_pos[q]
            dist = np.linalg.norm(delta, axis=1)
            d = delta / np.maximum(dist, 1e-300)[:, None]
            hits = blockers.first_hit(query_pos[q] - blockers.offset * query_normal[q], d)
            keep[s:s + chunk] = ~(hits.hit & (hits.t < dist))
    n_blocked = int(np.count_nonzero(~keep))
    qs, es = qs[keep], es[keep]
    cos_g = np.einsum("ij,ij->i", stree.normal[es], query_normal[qs])
    multi = cos_g < 0.0  # gamma > pi/2
    return PairLists((qs[~multi], qs[multi]), (es[~multi], es[multi]), inter.n_pairs, n_blocked)
