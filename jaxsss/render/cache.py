"""Subsurface irradiance caching with gradients (Keng, Lee and Chuang 2006): the ``cached`` renderer method.

Three passes:

1. the irradiance samples, octree and shading points, as in the hierarchical method (:mod:`jaxsss.render.renderer`);
2. **cache generation** at the visible points in bottom-up scanline order: a point that no earlier cache covers becomes
   a cache; each cache stores the subsurface illuminance ``S`` (the exitance ``M_o``), its gradient ``grad S`` and
   the irradiance spread ``V`` of the split-disk model;
3. **interpolation** at every visible point with the gradient-corrected weighted mean of the valid caches (Eq. 10).

Which points become caches depends only on geometry, lights and the scene's material (through the split-disk
constant), so it is decided once in NumPy; ``S`` and ``grad S`` at the caches are JAX functions of the material and
the interpolation weights are fixed, so the image stays differentiable in the material with cache positions fixed.

Decisions (written down as the issue asks):

- **The error bound ``a`` is relative.** The paper's ``epsilon_k(p) = |p - p_k| V_k C(R)`` (Eq. 11) is an absolute
  change of ``S``; we divide it by the local estimate ``S_k ~ Rd E_k`` (mean transmitted irradiance ``E_k`` in the
  disk times the total diffuse reflectance), so ``a = 0.01`` means "about 1% interpolation error", as in Ward's
  irradiance caching. ``w_k(p) = 1 / epsilon_k(p)``; cache ``k`` is valid at ``p`` when ``w_k(p) > 1 / a``.
- **``V`` is the standard deviation** of the transmitted irradiance of the samples within the disk: the paper's
  split disk (half ``E``, half dark) has ``E = 2 V`` only for a standard deviation, not a variance.
- **The disk radius** is ``R = DISK_RADIUS_IN_LD * l_d`` with the smallest ``l_d`` over channels (the most local
  channel). A larger ``R`` sees more of the surrounding light, raising ``V`` near shadow edges and placing more caches
  there; a smaller one makes ``V`` noisy (few samples).
- **Upper bound of a cache's domain**: ``R`` itself, and the normals must agree (``n_p . n_k > NORMAL_COS``), as in
  Ward's criterion; the paper leaves this bound heuristic. ``V`` is taken over the samples whose normals also agree,
  so the far side of a thin part does not count as a dark half of the disk.

- **Which gradient.** ``grad S`` in Eq. 10 is, by default, the far-field part of the paper's analytic gradient
  (``gradient="far"``): the derivative of the hierarchical sum over the interaction list, leaving out the near-field
  disc term within ``rho0`` (4 sample radii) of the cache. That term's exact derivative is dominated by where the
  irradiance samples happen to lie (the point-sampled kernel's derivative is large at sample spacing), not by how the
  light varies, and extrapolating it over a cache's domain paints each domain with a ramp. Measured on the marble
  teapot at 256 x 256 (relative RMS against the hierarchical image): at ``a = 0.3`` (13% caches) no gradient gives
  3.1%, the full analytic gradient 5.3%, the near term alone 5.7%, the far term alone 2.6%; at ``a = 0.05`` (35%
  caches) 1.9%, 4.2% and 1.8%. The full analytic gradient (``"analytic"``, Eq. 9) and its autodiff check
  (``"autodiff"``) stay available and agree to 1e-8 (tests); ``"none"`` is Ward's plain weighted mean.
- **What limits the error.** The hierarchical image is itself noisy at the pixel scale (1.8% relative RMS against a
  4x denser sample set at 256 x 256): its near field follows the sample positions. The cached image interpolates
  smooth values between caches, so its distance to the hierarchical image cannot fall below that noise until nearly
  every point is a cache; ``benchmarks/render_cache.py`` also reports both against the dense reference.
- **The split-disk constant** ``C(R) = 2 alpha' / (pi R) sum_z (e^{-sigma_tr z} - z e^{-sigma_tr R_z} / R_z)``
  (Eq. 11) is ``4 / (pi R)`` times the disc integral of the dipole (:func:`jaxsss.render.radiance.disc_integral`),
  evaluated stably; the channel with the largest ``C / Rd`` decides.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial import cKDTree

from jaxsss._config import render_jit, to_device
from jaxsss.fresnel import fresnel_reflectance
from jaxsss.medium import Medium
from jaxsss.reflectance import medium_total_diffuse_reflectance
from jaxsss.render import radiance as rad
from jaxsss.render.bssrdf import shift_reach
from jaxsss.render.camera import camera_rays
from jaxsss.render.methods import Preparation, register_method, resolve_method
from jaxsss.render.pairs import pair_info, pair_lists
from jaxsss.render.plan import PlanItem, make_plan
from jaxsss.render.radiance import F_dt_external, diffuse_albedo
from jaxsss.render.rays import OBJECT_TRANSLUCENT, scene_geometry
from jaxsss.render.renderer import assemble_prepared, irradiance_pass
from jaxsss.render.samples import lit_positions
from jaxsss.render.shading import shading_points

__all__ = [
    "DISK_RADIUS_IN_LD",
    "GRADIENTS",
    "NORMAL_COS",
    "CachePlacement",
    "CACHE_MIN_POINTS",
    "CachedPrepared",
    "DEFAULT_ERROR_BOUND",
    "caching_pays",
    "debug_images",
    "explain_cached",
    "place_caches",
    "prepare_cached",
    "split_disk_constant",
]

CACHE_MIN_POINTS = 20_000
"""The registered method caches only images with at least this many shaded points (:func:`caching_pays`)."""
DEFAULT_ERROR_BOUND = 0.3
"""The default relative error bound ``a`` (``jaxsss render --method cached --cache-error``)."""
GRADIENTS = ("far", "analytic", "autodiff", "none")
"""The ``grad S`` used in Eq. 10: the far-field part of the analytic gradient (default), the full analytic gradient
(Eq. 9), the full gradient by autodiff, or none (plain weighted mean). See the module docstring, "Which gradient"."""
DISK_RADIUS_IN_LD = 1.0
"""The split disk's radius ``R`` in diffuse mean free paths ``l_d`` (smallest over channels)."""
NORMAL_COS = 0.9
"""A cache is valid only where the normals agree: ``n_p . n_k > NORMAL_COS`` (about 25 degrees)."""
EPS_FLOOR = 1e-12
"""The relative error estimate is floored here, so that a cache with uniform light around it has finite weights."""
SPREAD_FLOOR = 0.01
"""``V / E`` is never taken below 1%: a disk with uniform (or no) direct light still sees light diffusing in from
farther away, which the split-disk model ignores; the floor keeps the domain shrinking as ``a -> 0``."""


def split_disk_constant(radius, medium: Medium):
    """``C(R) / Rd`` per channel (1/mm): the split-disk bound of Eq. 11 per unit ``V / E``, relative to ``S ~ Rd E``.

    ``C(R) = 2 alpha'/(pi R) sum_z (e^{-s z} - z e^{-s R_z} / R_z) = 4 disc_integral(R) / (pi R)``.
    """
    return 4.0 * rad.disc_integral(radius, medium) / (jnp.pi * radius) / medium_total_diffuse_reflectance(medium)


class CachePlacement(NamedTuple):
    """Pass 2 of the cached method, in NumPy (``Q`` visible points, ``K`` caches, ``P`` interpolation pairs)."""

    cache_point: np.ndarray  # (K,) index of each cache's visible point, in creation order
    created_before: np.ndarray  # (Q,) caches that existed when each point was visited (the one-pass variant's view)
    spread: np.ndarray  # (K,) V_k / E_k: relative standard deviation of the irradiance in the disk
    radius: np.ndarray  # (K,) the domain radius of each cache, mm
    pair_point: np.ndarray  # (P,) int32, ascending
    pair_cache: np.ndarray  # (P,) int32
    pair_weight: np.ndarray  # (P,) w_k(p) (1 at a cache's own point, which is interpolated from itself alone)
    pair_error: np.ndarray  # (P,) epsilon_k(p), the relative error estimate of each valid pair
    disk_radius: float
    constant: float  # max over channels of C(R) / Rd, 1/mm


def _irradiance_spread(sample_tree: cKDTree, sample_irradiance: np.ndarray, sample_normal: np.ndarray,
                       point: np.ndarray, normal: np.ndarray, radius: float):
    """``V / E``: standard deviation over mean of the transmitted irradiance of the samples within ``radius`` whose
    normals agree with the cache's (the split disk approximates the nearby surface, not the far side of a thin
    part)."""
    idx = np.asarray(sample_tree.query_ball_point(point, radius), dtype=np.int64)
    idx = idx[sample_normal[idx] @ normal > NORMAL_COS] if len(idx) else idx
    if len(idx) < 2:
        return 0.0
    e = sample_irradiance[idx]
    mean = float(e.mean())
    return float(e.std()) / mean if mean > 0 else 0.0


def place_caches(points: np.ndarray, normals: np.ndarray, pixel: np.ndarray, width: int,
                 sample_pos: np.ndarray, sample_normal: np.ndarray, sample_irradiance: np.ndarray, medium: Medium,
                 error_bound: float, *, one_pass: bool = False) -> CachePlacement:
    """Generate caches in bottom-up scanline order and the interpolation pairs (caching paper, "Cache generation").

    Args:
        points, normals: ``(Q, 3)`` visible points and their unit normals.
        pixel: ``(Q,)`` flat pixel index (``row * width + col``; row 0 at the top).
        width: image width in pixels.
        sample_pos, sample_normal: ``(N, 3)`` irradiance-sample positions and normals.
        sample_irradiance: ``(N,)`` their transmitted irradiance (channel mean), W/mm^2.
        medium: the scene's material (for ``l_d`` and the split-disk constant).
        error_bound: ``a``, the relative error bound (> 0).
        one_pass: interpolate each point only from caches that existed when it was visited (Ward's single pass; the
            paper's Figure 4 comparison) instead of from all caches (two passes, the default).
    """
    if not error_bound > 0:
        raise ValueError(f"place_caches(error_bound={error_bound}) is outside the allowed range (0, inf)")
    q = len(points)
    l_d = float(np.min(np.asarray(medium.l_d)))
    radius = DISK_RADIUS_IN_LD * l_d
    constant = float(np.max(np.asarray(split_disk_constant(radius, medium))))
    sample_tree = cKDTree(sample_pos)
    point_tree = cKDTree(points)
    rows, cols = np.divmod(pixel, width)
    order = np.lexsort((cols, -rows))  # bottom row first, left to right
    covered = np.zeros(q, dtype=bool)
    created_before = np.zeros(q, dtype=np.int64)
    cache_point, spread, domain = [], [], []
    for i in order:
        created_before[i] = len(cache_point)
        if covered[i]:
            continue
        v = max(_irradiance_spread(sample_tree, sample_irradiance, sample_normal, points[i], normals[i], radius),
                SPREAD_FLOOR)
        # w_k(p) > 1/a  <=>  |p - p_k| < a / (V/E * C/Rd), capped at the disk radius.
        rho = min(radius, error_bound / (v * constant))
        near = np.asarray(point_tree.query_ball_point(points[i], rho), dtype=np.int64)
        near = near[normals[near] @ normals[i] > NORMAL_COS]
        covered[near] = True
        covered[i] = True
        created_before[i] = len(cache_point) + 1  # a new cache is visible to its own point
        cache_point.append(i)
        spread.append(v)
        domain.append(rho)
    cache_point = np.asarray(cache_point, dtype=np.int64)
    spread = np.asarray(spread)
    domain = np.asarray(domain)
    pairs = _interpolation_pairs(points, normals, cache_point, spread, domain, constant, created_before, one_pass)
    return CachePlacement(cache_point, created_before, spread, domain, *pairs, radius, constant)


def _interpolation_pairs(points, normals, cache_point, spread, domain, constant, created_before, one_pass):
    cache_tree = cKDTree(points[cache_point])
    max_r = float(domain.max()) if len(domain) else 0.0
    lists = cache_tree.query_ball_point(points, max_r)
    counts = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(points))
    pp = np.repeat(np.arange(len(points)), counts)
    pc = np.fromiter((k for x in lists for k in x), dtype=np.int64, count=int(counts.sum()))
    dist = np.linalg.norm(points[pp] - points[cache_point[pc]], axis=1)
    ok = (dist <= domain[pc]) & (np.einsum("ij,ij->i", normals[pp], normals[cache_point[pc]]) > NORMAL_COS)
    if one_pass:
        ok &= pc < created_before[pp]
    pp, pc, dist = pp[ok], pc[ok], dist[ok]
    # Eq. 11 (relative): epsilon_k(p) = |p - p_k| (V_k / E_k) C(R) / Rd; w_k = 1 / epsilon_k.
    err = np.maximum(dist * spread[pc] * constant, EPS_FLOOR)
    weight = 1.0 / err
    # A cache's own point takes the cache's value exactly (its weight would be infinite).
    own = np.zeros(len(points), dtype=bool)
    own[cache_point] = True
    is_own_pair = cache_point[pc] == pp
    keep = ~own[pp] | is_own_pair
    pp, pc, weight, err = pp[keep], pc[keep], weight[keep], err[keep]
    weight[is_own_pair[keep]] = 1.0
    order = np.lexsort((pc, pp))
    missing = np.setdiff1d(np.arange(len(points)), pp)
    if len(missing):  # cannot happen by construction (every point is covered or is a cache); guard anyway
        raise RuntimeError(f"place_caches: {len(missing)} visible points have no valid cache")
    return (pp[order].astype(np.int32), pc[order].astype(np.int32), weight[order], err[order])


class CachedPrepared(eqx.Module):
    """The cached method's state: the hierarchical state at the caches and the interpolation to every point.

    ``image(medium)`` is a JAX function of the material (cache positions and weights fixed).
    """

    cache: Any  # Prepared with the caches as query points (interaction lists built)
    points: Any  # Prepared of every visible point (no interaction lists: radiance and image assembly only)
    pair_point: jax.Array  # (P,) int32 ascending
    pair_cache: jax.Array  # (P,) int32
    pair_weight: jax.Array  # (P,)
    pair_offset: jax.Array  # (P, 3) p - p_k, mm
    gradient: str = eqx.field(static=True)  # one of GRADIENTS

    def cache_values(self, medium: Medium):
        """``(S, grad S)`` at the caches: ``(K, C)`` and ``(K, 3, C)``."""
        s = self.cache.exitance(medium)
        if self.gradient == "far":
            g = self.cache.exitance_gradient(medium, near=False)
        elif self.gradient == "analytic":
            g = self.cache.exitance_gradient(medium)
        elif self.gradient == "autodiff":
            g = self.cache.exitance_gradient_autodiff(medium)
        else:
            g = jnp.zeros(s.shape[:1] + (3,) + s.shape[1:], s.dtype)
        return s, g

    def exitance(self, medium: Medium):
        """``M_o`` at every visible point by Eq. 10: ``sum w_k (S_k + (p - p_k) . grad S_k) / sum w_k``."""
        s, g = self.cache_values(medium)
        n = self.points.query_pos.shape[0]
        # Caching paper Eq. 10: gradient-corrected weighted interpolation.
        value = s[self.pair_cache] + jnp.einsum("pj,pjc->pc", self.pair_offset, g[self.pair_cache])
        num = jax.ops.segment_sum(self.pair_weight[:, None] * value, self.pair_point, num_segments=n,
                                  indices_are_sorted=True)
        den = jax.ops.segment_sum(self.pair_weight, self.pair_point, num_segments=n, indices_are_sorted=True)
        return num / den[:, None]

    shape = property(lambda self: self.points.shape, doc="``(H, W)`` of the image.")
    spp = property(lambda self: self.points.spp, doc="Camera rays per pixel.")

    def image(self, medium: Medium):
        """The linear radiance image ``(H, W, C)``."""
        return _cached_image(self, medium)


@render_jit
def _cached_image(prepared: CachedPrepared, medium: Medium):
    pts = prepared.points
    return pts.image_from_radiance(pts.radiance_from_exitance(medium, prepared.exitance(medium)))


@render_jit
def _cache_values(prepared: CachedPrepared, medium: Medium):
    return prepared.cache_values(medium)


SILHOUETTE_COS = 0.3
"""For the plan's breakdown: a cache is "on a silhouette" where ``n . v < SILHOUETTE_COS`` (about 73 degrees)."""
VARYING_SPREAD = 0.1
"""For the plan's breakdown: a cache is "where the light varies" (shadow edges, grazing light) when ``V / E`` exceeds
this."""


class _CacheGeometry(NamedTuple):
    """Passes 1 and 2 of the cached method in NumPy: everything but the material-dependent sums."""

    plan: Any
    samples: Any
    tree: Any
    shading: Any
    placement: CachePlacement
    timings: dict


def _transmitted_irradiance(samples, medium: Medium) -> np.ndarray:
    """``(N,)`` the samples' transmitted irradiance (channel mean, W/mm^2) at the scene's eta: what the split disk
    sees."""
    eta = float(np.asarray(medium.eta))
    f_t = 1.0 - np.asarray(fresnel_reflectance(eta, np.clip(samples.light.cos, 0.0, 1.0)))
    e_t = (f_t[..., None] * samples.light.irradiance).sum(axis=1).mean(axis=-1)
    f_dt = float(np.asarray(F_dt_external(eta, medium.fresnel)))
    if samples.indirect is not None:
        e_t = e_t + f_dt * samples.indirect.mean(axis=-1)
    if samples.self_indirect is not None:  # the object's own bounce, at the scene's material (Prepared.sample_flux)
        e_t = e_t + f_dt * (np.asarray(diffuse_albedo(medium)) * samples.self_indirect).mean(axis=-1)
    if samples.texture is not None:
        e_t = e_t * samples.texture.mean(axis=-1)
    return e_t


def _cache_geometry(scene, error_bound: float, *, eps=None, resolution=None, one_pass=False, plan=None,
                    pixel_mask=None, cutoff=True, share_channels=True) -> _CacheGeometry:
    if not error_bound > 0:
        raise ValueError(f"prepare_cached(error_bound={error_bound}) is outside the allowed range (0, inf)")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    plan = plan or make_plan(scene, method="hierarchical", eps=eps, cutoff=cutoff, share_channels=share_channels)
    if plan.method != "hierarchical":
        plan = plan._replace(method="hierarchical")
    timings["plan"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    geometry, samples, tree, timings["octree"] = irradiance_pass(scene, plan)
    timings["pass1_irradiance"] = time.perf_counter() - t0 - timings["octree"]
    t0 = time.perf_counter()
    shading = shading_points(scene, geometry, plan, resolution, pixel_mask, samples.light.irradiance.shape[-1],
                             lit=lit_positions(samples))
    timings["camera_rays"] = time.perf_counter() - t0
    # Pass 2: cache placement.
    t0 = time.perf_counter()
    placement = place_caches(shading.pos, shading.normal, shading.pixel, shading.shape[1], samples.positions,
                             samples.normals, _transmitted_irradiance(samples, scene.material.medium),
                             scene.material.medium, error_bound, one_pass=one_pass)
    timings["cache_placement"] = time.perf_counter() - t0
    return _CacheGeometry(plan, samples, tree, shading, placement, timings)


def cache_plan_item(placement: CachePlacement, normal: np.ndarray, to_eye: np.ndarray, error_bound: float):
    """The scene plan's line for the cached method: how many caches, and where they go (silhouettes, varying light,
    near-uniform light), with the reason."""
    k, q = len(placement.cache_point), len(normal)
    cos_v = np.einsum("ij,ij->i", normal[placement.cache_point], to_eye[placement.cache_point])
    silhouette = cos_v < SILHOUETTE_COS
    varying = ~silhouette & (placement.spread > VARYING_SPREAD)
    uniform = ~silhouette & ~varying
    capped = uniform & (placement.radius >= placement.disk_radius * (1 - 1e-12))
    why = (f"{k} caches for {q} visible points (cache ratio {k / max(q, 1):.2%}) at a = {error_bound:g}: "
           f"{silhouette.mean():.0%} on silhouettes (n.v < {SILHOUETTE_COS:g}: the surface turns away within a "
           f"pixel), {varying.mean():.0%} where the light varies (V/E > {VARYING_SPREAD:g}: shadow edges, grazing "
           f"light), {uniform.mean():.0%} under near-uniform light ({capped.mean():.0%} with the largest domain, "
           f"R = {placement.disk_radius:.3g} mm)") if k else "no visible points"
    return PlanItem("irradiance caches", True, why)


def explain_cached(scene, error_bound: float, *, eps: float | None = None, resolution=None, one_pass: bool = False):
    """The scene plan for the cached method with its expected cache ratio.

    The ratio comes from the actual cache placement (passes 1 and 2's geometry: the irradiance samples, the camera
    rays and the scanline placement, about a second at 512 x 512), which is exact and cheaper than any model of it:
    what decides it (silhouettes, shadow edges, the material's ``l_d``) is only known after the camera rays."""
    geo = _cache_geometry(scene, error_bound, eps=eps, resolution=resolution, one_pass=one_pass)
    item = cache_plan_item(geo.placement, geo.shading.normal, geo.shading.to_eye, error_bound)
    plan = geo.plan._replace(method="cached", items=geo.plan.items + (item,))
    return plan, geo.placement


def prepare_cached(scene, error_bound: float, *, eps: float | None = None, resolution=None, one_pass: bool = False,
                   gradient: str = "far", progress: bool = False, plan=None, pixel_mask=None, cutoff: bool = True,
                   share_channels: bool = True):
    """Passes 1 and 2 of the cached method (geometry, caches, interpolation pairs).

    Args:
        scene: a :class:`~jaxsss.render.Scene`.
        error_bound: ``a`` (> 0), the relative error bound of the split-disk weights.
        eps, resolution, plan, pixel_mask, cutoff, share_channels: as for :func:`jaxsss.render.prepare`.
        one_pass: interpolate from the caches made so far (the paper's one-pass variant).
        gradient: one of :data:`GRADIENTS`.

    Returns:
        ``(cached, plan, info, placement)``; ``plan`` ends with the "irradiance caches" item.
    """
    if gradient not in GRADIENTS:
        raise ValueError(f"prepare_cached(gradient={gradient!r}) is not one of {', '.join(map(repr, GRADIENTS))}")
    geo = _cache_geometry(scene, error_bound, eps=eps, resolution=resolution, one_pass=one_pass, plan=plan,
                          pixel_mask=pixel_mask, cutoff=cutoff, share_channels=share_channels)
    samples, tree, shading, placement, timings = geo.samples, geo.tree, geo.shading, geo.placement, geo.timings
    t0 = time.perf_counter()
    cache_shading = shading.subset(placement.cache_point)
    pairs = pair_lists(tree, samples, cache_shading.pos, geo.plan, progress=progress,
                       near_margin=shift_reach(scene.material.medium, geo.plan.bssrdf))
    timings["interactions"] = time.perf_counter() - t0
    cache = assemble_prepared(scene, geo.plan, samples, tree, cache_shading, pairs, mirror=False)
    points = assemble_prepared(scene, geo.plan, samples, tree, shading, None)
    offset = shading.pos[placement.pair_point] - shading.pos[placement.cache_point[placement.pair_cache]]
    cached = CachedPrepared(cache, points, to_device(placement.pair_point), to_device(placement.pair_cache),
                            to_device(placement.pair_weight), to_device(offset), gradient)
    item = cache_plan_item(placement, shading.normal, shading.to_eye, error_bound)
    plan = geo.plan._replace(method="cached", items=geo.plan.items + (item,))
    n_points = len(shading.pos)
    per_point_err = np.full(n_points, np.inf)
    np.minimum.at(per_point_err, placement.pair_point, placement.pair_error)
    own = np.zeros(n_points, dtype=bool)
    own[placement.cache_point] = True
    per_point_err[own] = 0.0
    info = {
        "timings": timings,
        "n_samples": int(samples.n),
        "n_shaded_points": n_points,
        "n_pixels": int(shading.shape[0] * shading.shape[1]),
        "n_caches": len(placement.cache_point),
        "cache_ratio": len(placement.cache_point) / max(n_points, 1),
        "error_bound": error_bound,
        "one_pass": one_pass,
        "gradient": gradient,
        "disk_radius_mm": placement.disk_radius,
        "interpolation_pairs_per_point_mean": len(placement.pair_point) / max(n_points, 1),
        "interpolation_error_estimate_mean": float(np.mean(per_point_err)) if n_points else 0.0,
        "interpolation_error_estimate_max": float(np.max(per_point_err)) if n_points else 0.0,
        **pair_info(pairs, len(cache_shading.pos)),
    }
    return cached, plan, info, placement


def debug_images(prepared, medium: Medium | None = None) -> dict[str, np.ndarray]:
    """The paper's Figures 8-9 as ``(H, W)`` arrays from a cached :class:`~jaxsss.render.methods.Preparation`:
    cache positions (1 at cache pixels), the gradient magnitude ``|grad S|`` (channel mean, at ``medium``, default
    the placement's) and the irradiance spread ``V / E`` of each cache, painted at the cache's pixel."""
    cached, placement = prepared.state, prepared.extras["placement"]
    _, g = _cache_values(cached, prepared.extras["medium"] if medium is None else medium)
    h, w = cached.points.shape
    pix = np.asarray(cached.points.query_pixel)[placement.cache_point]
    out = {}
    for name, values in (("caches", np.ones(len(pix))),
                         ("gradient", np.linalg.norm(np.asarray(g).mean(axis=-1), axis=1)),
                         ("variance", placement.spread)):
        img = np.zeros(h * w)
        img[pix] = values
        out[name] = img.reshape(h, w)
    return out


def _shaded_point_count(scene, resolution, pixel_mask) -> int:
    """How many camera rays hit the translucent object (the plan's measure of what caching can save)."""
    rays = camera_rays(scene.camera, resolution, seed=scene.render.seed)
    keep = slice(None) if pixel_mask is None else np.asarray(pixel_mask).reshape(-1)[rays.pixel]
    hits = scene_geometry(scene.mesh, [o.mesh for o in scene.occluders]).first_hit(rays.origins[keep],
                                                                                    rays.directions[keep])
    return int(np.count_nonzero(hits.obj == OBJECT_TRANSLUCENT))


def caching_pays(n_points: int) -> tuple[bool, str]:
    """The plan's rule for the cached method end to end: ``(pays, reason)``.

    Caching saves the interaction lists and pass 2 of every point that is not a cache, and costs the cache placement
    and a larger image function to compile (the gradient and the interpolation: about 5 s more). Measured end to end
    on the marble teapot (``jaxsss render --method cached`` against ``--method hierarchical``, a = 0.3, no
    persistent compilation cache; ``docs/benchmarks.md``): 9698 shaded points (256 x 256) 17.1 s against 12.6 s, a
    loss; 38786 points (512 x 512) 37.2 s against 172 s, 4.6x faster. It pays above :data:`CACHE_MIN_POINTS`."""
    if n_points >= CACHE_MIN_POINTS:
        return True, f"{n_points} shaded points >= {CACHE_MIN_POINTS}: caching pays end to end"
    return False, (f"left out: {n_points} shaded points < {CACHE_MIN_POINTS}, where the cache's placement and extra "
                   "compilation cost more than the interactions it saves (measured end to end, docs/benchmarks.md); "
                   "the hierarchical sum renders the image (--cache-always keeps the caches)")


def _not_cached(preparation, reason: str):
    """A hierarchical preparation presented as the cached method's, with the plan saying why."""
    plan = preparation.plan._replace(method="cached",
                                     items=preparation.plan.items + (PlanItem("irradiance caches", False, reason),))
    diagnostics = {**preparation.diagnostics, "n_caches": 0, "cache_ratio": 0.0}
    return dataclasses.replace(preparation, method="cached", plan=plan, diagnostics=diagnostics)


def _prepare_registered(scene, *, resolution=None, pixel_mask=None, fit=False, progress=False, eps=None,
                        error_bound=DEFAULT_ERROR_BOUND, one_pass=False, gradient="far", always=False):
    # The rule is for one render; a fit evaluates the image many times and keeps the caches.
    if not (always or fit):
        pays, why = caching_pays(_shaded_point_count(scene, resolution, pixel_mask))
        if not pays:
            hierarchical = resolve_method("hierarchical")
            return _not_cached(hierarchical.prepare(scene, resolution=resolution, pixel_mask=pixel_mask, fit=fit,
                                                    progress=progress, eps=eps), why)
    cached, plan, info, placement = prepare_cached(scene, error_bound, eps=eps, resolution=resolution,
                                                   one_pass=one_pass, gradient=gradient, progress=progress,
                                                   pixel_mask=pixel_mask, cutoff=not fit, share_channels=not fit)
    timings = info.pop("timings")
    return Preparation("cached", cached, plan, {"eps": plan.eps, **info}, timings,
                       {"placement": placement, "medium": scene.material.medium})


def _explain_registered(scene, *, resolution=None, eps=None, error_bound=DEFAULT_ERROR_BOUND, one_pass=False,
                        gradient="far", always=False):
    if not always:
        pays, why = caching_pays(_shaded_point_count(scene, resolution, None))
        if not pays:
            plan = make_plan(scene, method="hierarchical", eps=eps)
            return plan._replace(method="cached", items=plan.items + (PlanItem("irradiance caches", False, why),))
    return explain_cached(scene, error_bound, eps=eps, resolution=resolution, one_pass=one_pass)[0]


register_method("cached", _prepare_registered,
                "irradiance caching with gradients (Keng et al. 2006) on top of the hierarchical sum",
                options=("eps", "error_bound", "one_pass", "gradient", "always"), explain=_explain_registered)
