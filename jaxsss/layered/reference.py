"""An exact reference for the layered march: the true entry point by ray casting, exact layer crossings.

Same physics as :mod:`jaxsss.layered.march` (single scattering, straight rays, no refraction, the same lights and
shadowing), without its two approximations:

- **Entry point.** For every sample ``M`` and light, ``K`` is the first intersection of the ray from ``M`` towards
  the light with the mesh (Embree), instead of the intersection with an interpolated plane (Eqs. 9-10). A light is
  blocked when a shadow ray from ``K`` hits anything (or when the first hit is an occluder). A ray that never leaves
  the mesh (an open mesh) enters at ``M``.
- **Path lengths.** The light path ``KM`` is divided into ``n_light`` sub-steps in the tangent frame of ``K``
  (texture coordinates ``uv_K + (KX . T_K, KX . B_K)``, depth ``(K - X) . N_K``); on each sub-step the fraction below
  each layer bottom is found by linear interpolation of ``depth - b_i`` between its ends (the crossing inside the
  step), so the length in each layer is second-order accurate in the step, instead of Eq. 12's mean of two
  thickness lookups.
- **View ray.** ``n_view`` steps from ``P`` to where the medium ends (the deepest layer bottom along ``N_P``, or
  where the view ray leaves the mesh), with the same fractional layer occupancy for ``sigma_s`` and ``sigma_t``.

Localisation of view samples is Algorithm 1's (tangent space of ``P``): that is the definition of the material. On a
flat slab every frame agrees, so there the reference is exact (to the quadrature) and the planar reduced intensity
equals it for constant layers.

Geometry (ray casts and the per-layer path lengths) is computed once in NumPy and JAX; :func:`reference_radiance` is
then a cheap differentiable function of the :class:`~jaxsss.layered.layers.LayerStack`.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from jaxsss.layered.layers import LayerStack
from jaxsss.layered.lighting import LightArrays, lights_at
from jaxsss.layered.localise import texture_lookup
from jaxsss.layered.march import PixelGeometry
from jaxsss.phase import PHASE_FUNCTIONS
from jaxsss.layered.tangents import SurfaceFrames, frames_at
from jaxsss.render.rays import OBJECT_TRANSLUCENT, SceneGeometry

__all__ = ["EntryPoints", "ReferenceData", "exact_entry", "light_path_lengths", "prepare_reference",
           "reference_radiance"]


class EntryPoints(NamedTuple):
    """Per (point, light): ``K`` ``(R, L, 3)``, ``normal``/``T``/``B`` ``(R, L, 3)`` at ``K``, ``uv`` ``(R, L, 2)``,
    ``visible`` ``(R, L)`` (0 or 1), ``has_entry`` ``(R, L)`` False where the ray never left the mesh (``K = M``)."""

    K: np.ndarray
    normal: np.ndarray
    T: np.ndarray
    B: np.ndarray
    uv: np.ndarray
    visible: np.ndarray
    has_entry: np.ndarray


def exact_entry(geometry: SceneGeometry, mesh, frames: SurfaceFrames, lights: LightArrays, points) -> EntryPoints:
    """Cast a ray from each point towards each light; the first hit on the translucent mesh is the entry ``K``."""
    points = np.asarray(points, dtype=np.float64)
    r, n_l = len(points), lights.n_lights
    w_in, _, dist = (np.asarray(a) for a in _lights_at(lights, jnp.asarray(points)))
    K = np.repeat(points[:, None, :], n_l, axis=1)
    normal = np.zeros((r, n_l, 3))
    T = np.zeros((r, n_l, 3))
    B = np.zeros((r, n_l, 3))
    uv = np.zeros((r, n_l, 2))
    visible = np.ones((r, n_l))
    has = np.zeros((r, n_l), dtype=bool)
    for k in range(n_l):
        hits = geometry.first_hit(points, w_in[:, k])
        within = hits.hit & (hits.t < dist[:, k])
        on_mesh = within & (hits.obj == OBJECT_TRANSLUCENT)
        visible[within & ~on_mesh, k] = 0.0  # an occluder between M and the light
        idx = np.flatnonzero(on_mesh)
        has[idx, k] = True
        K[idx, k] = hits.position[idx]
        if idx.size:
            u, n, t, b = frames_at(frames, mesh, hits.face[idx], hits.position[idx])
            uv[idx, k], normal[idx, k], T[idx, k], B[idx, k] = u, n, t, b
            # Shadow ray from K onwards (self-occlusion by other parts of the mesh, occluders).
            rest = None if not np.isfinite(dist[idx, k]).all() else dist[idx, k] - hits.t[idx]
            vis = geometry.visible(hits.position[idx], n, w_in[idx, k], rest)
            visible[idx, k] = np.where(vis, visible[idx, k], 0.0)
        # No entry (open mesh): K = M, frame of nothing; path length 0.
    return EntryPoints(K, normal, T, B, uv, visible, has)


_lights_at = eqx.filter_jit(lights_at)


def _below_fraction(f_a, f_b):
    """Fraction of a segment where a linear function with end values ``f_a, f_b`` is positive."""
    num = jnp.maximum(f_a, 0.0) + jnp.maximum(f_b, 0.0)
    den = jnp.abs(f_a) + jnp.abs(f_b)
    return jnp.where(den > 0, num / jnp.where(den > 0, den, 1.0), 0.0)


def _occupancy(depth, bounds):
    """Per-step layer occupancy fractions: ``depth`` ``(..., S + 1)`` at step ends, ``bounds`` ``(..., S + 1, n)``
    -> ``(..., S, n)`` fraction of each step inside each layer (layer i: below b_{i-1} and above b_i)."""
    f = depth[..., None] - bounds  # > 0 below the bottom of layer i
    below = _below_fraction(f[..., :-1, :], f[..., 1:, :])
    top = _below_fraction(depth[..., :-1], depth[..., 1:])[..., None]  # below the surface
    upper = jnp.concatenate([top, below[..., :-1]], axis=-1)
    return jnp.maximum(upper - below, 0.0)


@eqx.filter_jit
def _path_lengths_chunk(boundaries, K, M, normal, T, B, uv, n_light: int):
    s = jnp.linspace(0.0, 1.0, n_light + 1)
    X = K[..., None, :] + s[:, None] * (M - K)[..., None, :]  # (R, S+1, 3)
    d = X - K[..., None, :]
    depth = -jnp.sum(d * normal[..., None, :], axis=-1)
    uv_x = uv[..., None, :] + jnp.stack([jnp.sum(d * T[..., None, :], -1), jnp.sum(d * B[..., None, :], -1)], -1)
    occ = _occupancy(depth, texture_lookup(boundaries, uv_x))
    length = jnp.linalg.norm(M - K, axis=-1)
    return jnp.sum(occ, axis=-2) * (length / n_light)[..., None]


def light_path_lengths(boundaries, entry: EntryPoints, points, n_light: int = 64, chunk: int = 8192) -> np.ndarray:
    """``(R, L, n)`` length (mm) of the path from ``K`` to each point inside each layer (exact crossings)."""
    r, n_l = entry.K.shape[:2]
    M = np.repeat(np.asarray(points, dtype=np.float64)[:, None, :], n_l, axis=1).reshape(-1, 3)
    flat = [a.reshape(-1, a.shape[-1]) for a in (entry.K, entry.normal, entry.T, entry.B, entry.uv)]
    total = len(M)
    chunk = max(1, min(chunk, total))
    out = []
    for s in range(0, total, chunk):
        part = [a[s:s + chunk] for a in (flat[0], M, *flat[1:])]
        pad = chunk - len(part[0])
        if pad:
            part = [np.concatenate([a, np.repeat(a[:1], pad, axis=0)]) for a in part]
        lengths = _path_lengths_chunk(boundaries, *(jnp.asarray(a) for a in part), n_light)
        out.append(np.asarray(lengths)[: chunk - pad])
    lengths = np.concatenate(out).reshape(r, n_l, -1)
    return np.where(entry.has_entry[..., None], lengths, 0.0)


@eqx.filter_jit
def _view_occupancy(boundaries, geom: PixelGeometry, h, n_view: int):
    """``(Q, S, n)`` length (mm) of each view-ray step inside each layer (Algorithm 1's localisation)."""
    t_ends = jnp.arange(n_view + 1, dtype=h.dtype)[None, :] * h[:, None]  # (Q, S+1)
    depth = t_ends * jnp.sum(geom.w_out * geom.normal, axis=-1)[:, None]
    ends = -t_ends[..., None] * geom.w_out[:, None, :]
    uv_ends = geom.uv[:, None, :] + jnp.stack([jnp.sum(ends * geom.T[:, None, :], -1),
                                               jnp.sum(ends * geom.B[:, None, :], -1)], -1)
    return _occupancy(depth, texture_lookup(boundaries, uv_ends)) * h[:, None, None]


class ReferenceData(eqx.Module):
    """Geometry of the reference for ``Q`` points: ``view_occ`` ``(Q, S, n)`` length of each view step in each
    layer (mm); ``step`` ``(Q,)``; ``mu`` ``(Q, S, L)`` scattering-angle cosines; ``E`` ``(Q, S, L, C)`` flux
    density times visibility; ``light_path`` ``(Q, S, L, n)`` mm."""

    view_occ: jnp.ndarray
    mu: jnp.ndarray
    E: jnp.ndarray
    light_path: jnp.ndarray


def prepare_reference(geometry: SceneGeometry, mesh, frames: SurfaceFrames, boundaries, geom: PixelGeometry,
                      lights: LightArrays, t_end, *, n_view: int = 256, n_light: int = 64) -> ReferenceData:
    """Ray casts and path lengths for the reference at ``Q`` shaded points (``geom`` unchunked, ``(Q, ...)``).

    Args:
        t_end: ``(Q,)`` end of the view integral, mm (where the medium ends along the view ray).
        n_view: view-ray steps; n_light: sub-steps of each light path.
    """
    P, w_out = np.asarray(geom.P), np.asarray(geom.w_out)
    q = len(P)
    h = np.asarray(t_end) / n_view
    view_occ = np.asarray(_view_occupancy(boundaries, geom, jnp.asarray(h), n_view))
    t_mid = (np.arange(n_view)[None, :] + 0.5) * h[:, None]
    M = (P[:, None, :] - t_mid[..., None] * w_out[:, None, :]).reshape(-1, 3)
    entry = exact_entry(geometry, mesh, frames, lights, M)
    w_in, E, _ = _lights_at(lights, jnp.asarray(M))
    mu = -np.einsum("rlk,rk->rl", np.asarray(w_in), np.repeat(w_out, n_view, axis=0))
    E = np.asarray(E) * entry.visible[..., None]
    path = light_path_lengths(boundaries, entry, M, n_light)
    n_l = lights.n_lights
    return ReferenceData(jnp.asarray(view_occ), jnp.asarray(mu.reshape(q, n_view, n_l)),
                         jnp.asarray(E.reshape(q, n_view, n_l, -1)), jnp.asarray(path.reshape(q, n_view, n_l, -1)))


@eqx.filter_jit
def reference_radiance(stack: LayerStack, data: ReferenceData):
    """``(Q, C)`` single-scattered radiance of the reference, W/(mm^2 sr), differentiable in ``stack``."""
    tau_light = jnp.sum(data.light_path[..., :, None] * stack.sigma_t, axis=-2)  # (Q, S, L, C)
    L_ri = data.E * jnp.exp(-tau_light)
    g = jnp.broadcast_to(stack.g, (stack.n_layers, stack.g.shape[1]))
    # Per layer: sigma_s^i p_i(mu) summed over lights, weighted by the step's length inside layer i.
    source = 0.0
    for i in range(stack.n_layers):
        p = PHASE_FUNCTIONS[stack.phase[i]](data.mu[..., None], g[i])  # (Q, S, L, c)
        source = source + data.view_occ[..., i, None] * stack.sigma_s[i] * jnp.sum(p * L_ri, axis=-2)
    tau_step = jnp.sum(data.view_occ[..., :, None] * stack.sigma_t, axis=-2)  # (Q, S, C)
    # Attenuation to each step's midpoint: the steps before it and half of its own.
    tau_view = jnp.cumsum(tau_step, axis=1) - 0.5 * tau_step
    return jnp.sum(source * jnp.exp(-tau_view), axis=1)
