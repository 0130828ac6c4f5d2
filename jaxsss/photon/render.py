"""The photon-diffusion renderer (``--method photon``): photons traced into the mesh, a volumetric source octree and
the hierarchical sum of blended dipole, quadpole and multipole profiles (Donner and Jensen 2007, Sections 4-5).

:func:`prepare_photon` does all the geometry in NumPy -- photon tracing (:mod:`jaxsss.photon.trace`), the source
octree, camera rays, interaction lists, shadow rays to sources through blockers -- and returns a
:class:`PhotonPrepared` whose :meth:`~PhotonPrepared.image` is a jitted JAX function of the material:

    M_o(x_o) = sum_v Phi_v kappa(|x_o - P_v|) R_blend(x_o, n_o; P_v, n_v, depth_v)

- ``Phi_v`` -- a node's power, the sum of its sources' ``power alpha' sigma_t' e^{-sigma_t' s} / p_ref(s)`` (the
  Eq. 8 PDF ratio against the tracing mixture; equal to the traced power at the scene's material, smooth in any
  other);
- ``kappa`` -- Eq. 9 with ``sigma_t'`` (the coefficient chosen against Monte Carlo, docs/photon_diffusion.md);
- ``R_blend`` -- Eq. 15 (:func:`jaxsss.profiles.blend.blended_exitance`) with the view depth kept ``>= 0`` (a
  source above a curved surface's tangent plane is moved onto it: the half-space models have no meaning there).

The exitance then goes through the renderer's exit radiance, single scattering (the analytic term, where the plan
keeps it) and specular terms (:class:`~jaxsss.render.renderer.ShadedPoints`).
"""

from __future__ import annotations

import math
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxsss._config import to_device
from jaxsss.validate import check_integer
from jaxsss.medium import Medium
from jaxsss.photon.emit import emit_photons
from jaxsss.photon.trace import PhotonTrace, trace_photons
from jaxsss.photon.tree import PairLists, SourceTree, pair_lists, source_tree
# The unchecked kernels of the profiles package (their arguments are validated once, in prepare). The public
# blended_exitance and attenuation_kernel validate every argument with equinox.error_if, which inside this sum's scan
# raised spuriously during Levenberg-Marquardt fits (fit_image(method="photon")) and costs time in the inner loop.
from jaxsss.profiles.blend import blended_unchecked
from jaxsss.profiles.oblique import KAPPA_COEFFICIENTS, kappa_unchecked
from jaxsss.profiles.point_sources import DEFAULT_N_PAIRS
from jaxsss.render import radiance as rad
from jaxsss.render.lights import DELTA_KINDS, refuse_lights
from jaxsss.render.methods import Preparation, register_method
from jaxsss.render.pairs import BLOCK_PAIRS, pair_blocks
from jaxsss.render.plan import EPS_DEFAULT, PlanItem, make_plan
from jaxsss.render.rays import SceneGeometry, scene_geometry
from jaxsss.render.mirror import ReflectingPoints, mirror_field
from jaxsss.render.shading import point_shading, shaded_fields, shading_points

PHOTON_LIGHTS = (*DELTA_KINDS, "environment")
_AREA_REFUSAL = "its photons are emitted from point, spot, directional and environment lights only (jaxsss.photon.emit)"

__all__ = ["DEFAULT_EPS", "PhotonPrepared", "photon_geometry", "prepare_photon", "source_power", "trace_scene"]

DEFAULT_EPS = 0.05
"""Solid-angle threshold (sr) of the source octree, as the renderer's default."""


def source_power(medium: Medium, power, path, sigma_t_ref):
    """Each source's power in ``medium``, ``(S, C)`` W: ``power alpha' sigma_t' e^{-sigma_t' s} / p_ref(s)``.

    Args:
        medium: the material (``(C,)`` channels).
        power: ``(S, C)`` traced power that started each source's flight, W.
        path: ``(S,)`` that flight's length ``s``, mm.
        sigma_t_ref: ``(C,)`` the tracing material's ``sigma_t'``: ``p_ref(s) = mean_k sigma_k e^{-sigma_k s}``.
    """
    s = path[:, None]
    st = medium.sigma_t_prime
    # Eq. 8's PDF sigma_t' e^{-sigma_t' s} over the tracing mixture, in logs (both underflow for long flights).
    log_ref = jax.scipy.special.logsumexp(jnp.log(sigma_t_ref) - sigma_t_ref * s, axis=1, keepdims=True) \
        - jnp.log(sigma_t_ref.shape[0])
    return power * medium.alpha_prime * jnp.exp(jnp.log(st) - st * s - log_ref)


class PhotonPrepared(ReflectingPoints):
    """The photon method's state: shaded points, sources (octree order), entity planes and the two pair lists.

    ``S`` sources, ``E`` entities (sources then nodes), ``C`` channels; pair lists in blocks ``(B, K)``.
    """

    src_power: jax.Array  # (S, C) W, traced power starting each source's flight (octree order)
    src_path: jax.Array  # (S,) mm
    sigma_t_ref: jax.Array  # (C,) 1/mm
    ent_pos: jax.Array  # (E, 3)
    ent_normal: jax.Array  # (E, 3)
    ent_depth: jax.Array  # (E,)
    ent_start: jax.Array  # (E,)
    ent_stop: jax.Array  # (E,)
    pair_query: tuple  # ((B0, K), (B1, K)) int32: without / with the multipole
    pair_entity: tuple
    n_pairs: int = eqx.field(static=True)  # multipole image pairs for gamma > pi/2
    kappa: str = eqx.field(static=True)

    def source_power(self, medium: Medium):
        """``(S, C)`` W (:func:`source_power`)."""
        return source_power(medium, self.src_power, self.src_path, self.sigma_t_ref)

    def exitance(self, medium: Medium):
        """Radiant exitance at the shaded points, ``(Q, C)`` W/mm^2 (module docstring)."""
        ent_power = rad.entity_flux(self.source_power(medium), self.ent_start, self.ent_stop)
        coeff = KAPPA_COEFFICIENTS[self.kappa]
        out = 0.0
        for pq, pe, n_pairs in zip(self.pair_query, self.pair_entity, (0, self.n_pairs), strict=True):
            if pq.shape[0] == 0:
                continue

            def contrib(q, e, n_pairs=n_pairs):
                x, n = self.query_pos[q], self.query_normal[q]
                src = self.ent_pos[e]
                # View depth >= 0: move a source above the tangent plane onto it.
                h = jnp.sum((x - src) * n, axis=-1, keepdims=True)
                src = src + jnp.minimum(h, 0.0) * n
                # Eq. 15 (blend of dipole, quadpole, multipole) times Eq. 9 (kappa), per unit source power.
                prof = blended_unchecked(x, n, src, self.ent_normal[e], self.ent_depth[e], medium, n_pairs)
                d_r = jnp.sqrt(jnp.sum((x - src) ** 2, axis=-1, keepdims=True))
                return prof * kappa_unchecked(coeff, d_r, medium) * ent_power[e]

            out = out + rad.scan_pairs(contrib, self.n_queries, ent_power.shape[-1:], ent_power.dtype, pq, pe)
        if isinstance(out, float):
            return jnp.zeros((self.n_queries, self.src_power.shape[-1]), self.src_power.dtype)
        return out

    def image(self, medium: Medium):
        """The linear radiance image ``(H, W, C)``, a JAX function of the medium (jitted)."""
        return _photon_image(self, medium)


@eqx.filter_jit
def _photon_image(prepared: PhotonPrepared, medium: Medium):
    return prepared.image_from_radiance(prepared.radiance_from_exitance(medium, prepared.exitance(medium)))


@eqx.filter_jit
def _photon_exitance(prepared: PhotonPrepared, medium: Medium):
    return prepared.exitance(medium)


def photon_geometry(scene) -> tuple[SceneGeometry, tuple[int, ...]]:
    """The geometry photons are traced against (translucent mesh, occluders, blockers) and the blockers' ids."""
    meshes = [o.mesh for o in scene.occluders] + [b.mesh for b in scene.blockers]
    first = 1 + len(scene.occluders)
    return scene_geometry(scene.mesh, meshes), tuple(range(first, first + len(scene.blockers)))


def trace_scene(scene, n_photons: int, *, walk: str | None = None, seed: int | None = None,
                progress: bool = False) -> PhotonTrace:
    """Emit ``n_photons`` from the scene's lights and trace them into its translucent mesh with its material.

    ``walk`` defaults to ``"sources"`` for a convex mesh (no light re-enters, so a photon is done once it has stored
    its source) and ``"full"`` otherwise (:func:`~jaxsss.photon.trace.trace_photons`)."""
    refuse_lights(scene, "photon", PHOTON_LIGHTS, why=_AREA_REFUSAL)
    geometry, blockers = photon_geometry(scene)
    sphere = scene.mesh.bounding_sphere.primitive
    seed = scene.render.seed if seed is None else seed
    photons = emit_photons(scene.lights, sphere.center, float(sphere.radius), int(n_photons), seed=seed)
    if walk is None:
        walk = "sources" if scene.mesh.is_convex else "full"
    m = scene.material.medium
    return trace_photons(geometry, photons, np.asarray(m.sigma_a), np.asarray(m.sigma_s_prime),
                         float(np.mean(np.asarray(m.eta))), blocker_ids=blockers, walk=walk, seed=seed,
                         progress=progress)


def _plan_items(scene, trace: PhotonTrace, walk: str, stree: SourceTree, pairs: PairLists, eps: float,
                n_pairs: int, base_plan) -> tuple[PlanItem, ...]:
    n_multi = len(pairs.query[1])
    total = max(pairs.n_pairs, 1)
    items = [
        PlanItem("method", True, f"photon diffusion: {trace.n_photons} photons, {trace.sources.n} sources, "
                                 f"solid-angle threshold eps = {eps:g} sr"),
        PlanItem("photon walks", walk == "full",
                 "continued to their exit: the mesh is not convex, light that leaves can re-enter and store again"
                 if walk == "full" else "ended at the first scattering: the mesh is convex, no light re-enters"),
        PlanItem("volumetric shadows", bool(scene.blockers),
                 f"{len(scene.blockers)} blocker(s): photons end there; shadow rays from shading points to sources "
                 f"dropped {pairs.n_blocked} of {pairs.n_total} pairs" if scene.blockers
                 else "no [[blocker]] meshes: no shadow rays to sources"),
        PlanItem("multipole", n_multi > 0,
                 f"{n_multi} of {total} pairs ({100.0 * n_multi / total:.1f}%) see their source's incidence plane at "
                 f"gamma > pi/2 (Eq. 15): {n_pairs} image pairs there, none elsewhere"),
        PlanItem("averaged planes", True, f"{stree.fixed_depth} of {stree.octree.n_nodes} nodes took their members' "
                                          "mean depth (the averaged plane put them above it)"),
    ]
    keep = {"single scattering", "specular highlights", "shared channel"}
    items += [i for i in base_plan.items if i.name in keep]
    if scene.occluders:
        items.append(PlanItem("occluders", True, f"{len(scene.occluders)} opaque object(s): shaded directly, and "
                                                 "they absorb photons"))
    return tuple(items)


def prepare_photon(scene, *, n_photons: int | None = None, eps: float | None = None, resolution=None,
                   points=None, trace: PhotonTrace | None = None, n_pairs: int = DEFAULT_N_PAIRS,
                   kappa: str = "sigma_t_prime", progress: bool = False, pixel_mask=None,
                   block_pairs: int = BLOCK_PAIRS):
    """Geometry-only work of the photon method.

    Args:
        scene: a :class:`~jaxsss.render.scene.Scene` (its ``[[blocker]]`` meshes cast volumetric shadows).
        n_photons: photons traced (default the scene's ``[render].photons``), ``>= 1``.
        eps: solid-angle threshold (sr), ``> 0``; default the scene's ``[render].eps``, else
            :data:`jaxsss.render.plan.EPS_DEFAULT`.
        resolution: ``(W, H)`` overriding the camera's.
        points: optional ``(points (Q, 3), normals (Q, 3))`` surface points to shade instead of the camera's (the
            image is then ``(1, Q, C)``; validation against the mesh Monte Carlo uses it).
        trace: a :class:`~jaxsss.photon.trace.PhotonTrace` to reuse (else :func:`trace_scene`).
        n_pairs: multipole image pairs for ``gamma > pi/2``.
        kappa: Eq. 9's coefficient (:data:`jaxsss.profiles.oblique.KAPPA_COEFFICIENTS`).

    Returns:
        ``(prepared, plan, info)``: the :class:`PhotonPrepared`, the :class:`~jaxsss.render.plan.ScenePlan` (method
        ``"photon"``, its own items) and timings (s) and counts.
    """
    refuse_lights(scene, "photon", PHOTON_LIGHTS, why=_AREA_REFUSAL)
    if kappa not in KAPPA_COEFFICIENTS:
        raise ValueError(f"prepare_photon(kappa={kappa!r}) is not one of: {', '.join(KAPPA_COEFFICIENTS)}")
    n_photons = scene.render.photons if n_photons is None else n_photons
    check_integer(n_photons, "n_photons", 1, owner="prepare_photon")
    eps = float((EPS_DEFAULT if scene.render.eps is None else scene.render.eps) if eps is None else eps)
    if not (math.isfinite(eps) and eps > 0):
        raise ValueError(f"prepare_photon(eps={eps!r}) is outside the allowed range (0, inf) sr")
    timings: dict[str, float] = {}
    t_all = time.perf_counter()
    base_plan = make_plan(scene, eps=eps)
    walk = "sources" if scene.mesh.is_convex else "full"
    t0 = time.perf_counter()
    if trace is None:
        trace = trace_scene(scene, int(n_photons), walk=walk, progress=progress)
    else:
        walk = "full" if len(trace.exits.order) else walk
    timings["photon_tracing"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    stree = source_tree(trace.sources)
    timings["octree"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if points is None:
        geometry = scene_geometry(scene.mesh, [o.mesh for o in scene.occluders])
        shading = shading_points(scene, geometry, base_plan, resolution, pixel_mask, trace.sources.power.shape[1],
                                 lit=trace.sources.entry_points())
    else:
        shading = point_shading(points, trace.sources.power.shape[1], owner="prepare_photon")
        base_plan = base_plan._replace(single_scattering=False, specular=False)
    timings["camera_rays"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    blockers = scene_geometry(scene.blockers[0].mesh, [b.mesh for b in scene.blockers[1:]]) if scene.blockers \
        else None
    pairs = pair_lists(stree, shading.pos, shading.normal, eps, blockers=blockers, progress=progress)
    timings["interactions"] = time.perf_counter() - t0
    tree = stree.octree
    n_q = len(shading.pos)
    blocks = [(to_device(pair_blocks(q.astype(np.int32), n_q, block_pairs)),
               to_device(pair_blocks(e.astype(np.int32), 0, block_pairs))) if len(q) else
              (jnp.zeros((0, block_pairs), jnp.int32), jnp.zeros((0, block_pairs), jnp.int32))
              for q, e in zip(pairs.query, pairs.entity, strict=True)]
    order = tree.order
    prepared = PhotonPrepared(
        **shaded_fields(scene, base_plan, shading),
        src_power=to_device(trace.sources.power[order]),
        src_path=to_device(trace.sources.path[order]),
        sigma_t_ref=to_device(trace.sigma_t_ref),
        ent_pos=to_device(tree.centroid),
        ent_normal=to_device(stree.normal),
        ent_depth=to_device(stree.depth),
        ent_start=to_device(tree.start),
        ent_stop=to_device(tree.stop),
        pair_query=tuple(b[0] for b in blocks),
        pair_entity=tuple(b[1] for b in blocks),
        n_pairs=int(n_pairs),
        kappa=kappa,
        mirror=mirror_field(scene, shading) if points is None else None,
    )
    counts = np.bincount(np.concatenate(pairs.query), minlength=n_q) if n_q else np.zeros(0, int)
    info = {
        "timings": timings,
        "seconds_geometry": time.perf_counter() - t_all,
        "n_photons": int(trace.n_photons),
        "n_sources": int(trace.sources.n),
        "photon_walk": walk,
        "photon_tally": {k: v.tolist() for k, v in trace.tally.items()},
        "n_shaded_points": n_q,
        "n_pixels": int(shading.shape[0] * shading.shape[1]),
        "n_octree_entities": int(tree.n_entities),
        "n_interactions": int(pairs.n_pairs),
        "n_interactions_multipole": len(pairs.query[1]),
        "n_pairs_blocked": int(pairs.n_blocked),
        "interactions_per_point_mean": float(counts.mean()) if n_q else 0.0,
        "interactions_per_point_max": int(counts.max()) if n_q else 0,
    }
    items = _plan_items(scene, trace, walk, stree, pairs, eps, n_pairs, base_plan)
    # Light that leaves a non-convex object and re-enters is in the photon walks ("photon walks"), not in the
    # diffusion renderer's self inter-reflection term.
    return prepared, base_plan._replace(method="photon", items=items, self_bounce=False), info


def _prepare_registered(scene, *, resolution=None, pixel_mask=None, fit=False, progress=False, eps=None,
                        n_photons=None):
    # fit: nothing in the photon method's geometry depends on the material beyond the traced walks, which source
    # power reweights (Eq. 8), so fitting and rendering share one preparation.
    prepared, plan, info = prepare_photon(scene, n_photons=n_photons, eps=eps, resolution=resolution,
                                          progress=progress, pixel_mask=pixel_mask)
    timings = info.pop("timings")
    info.pop("seconds_geometry")
    return Preparation("photon", prepared, plan, {"eps": plan.eps, **info}, timings)


register_method("photon", _prepare_registered,
                "photon diffusion (Donner and Jensen 2007): photons traced into the mesh store volumetric sources, "
                "summed hierarchically with the blended dipole, quadpole and multipole; [[blocker]] meshes cast "
                "volumetric shadows", options=("eps", "n_photons"))
