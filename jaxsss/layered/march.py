"""The per-pixel single-scattering march through a layered material (Francois et al., Algorithms 1 and 2), in JAX.

For a visible point ``P`` with direction ``w_out`` towards the eye, samples ``M`` lie on the continuation of the
view ray inside the medium, ``M = P - t w_out`` for ``t`` in ``[0, t_max]``; ``t_max`` comes from Eq. 15
(:mod:`jaxsss.layered.render`). Each sample adds (Eqs. 1-5)

    sigma_s(M) p(M, w_in, w_out) L_ri(M) exp(-int_M^P sigma_t) dt,

summed over the lights. Steps:

1. Localise ``M`` (Algorithm 1): texture coordinates ``uv_P + (PM . T, PM . B)``, depth ``t w_out . N_P``, layer by
   depth comparison.
2. Reduced intensity (Algorithm 2): the plane at ``M`` interpolates the tangent plane at ``P`` and the fitted
   plane at ``P`` (Eq. 9, weights ``alpha = |M M_max|`` on the tangent plane and ``beta = |M P|`` on the fitted
   plane, so shallow samples use the tangent plane); ``|K'M| = h / cos(theta)`` with ``h`` the depth of ``M`` below
   that plane and ``cos(theta) = N_M . w_in`` (Eq. 10); the layer thicknesses are the mean of those at ``M`` and at
   ``K'`` (Eq. 12), and the path length in layer ``i`` is ``d_i = clip(|K'M| - sum_{j<i} D_j / cos, 0, D_i / cos)``
   (Eq. 12 with the lower clip at 0 that the printed formula lacks); ``L_ri = E exp(-sum_i sigma_t^i d_i)``
   (Eq. 11).
3. Attenuation towards ``P`` is carried from sample to sample (Eq. 13).

Quadrature: ``N`` samples at the *midpoints* of ``N`` equal steps, the attenuation to a sample being that of the
steps before it times half a step of its own layer (Algorithm 1 samples the left ends and multiplies a whole step
after adding; the midpoint rule costs the same and converges as ``1/N^2`` inside a layer).

Where ``cos(theta) <= 0`` the light lies behind the approximating plane: the planar model has no entry point on the
light's side and the sample gets no light from it. (Eq. 10 prints absolute values, which would mirror a light behind
the object to the front; we do not.)

Everything here is a JAX function of arrays, differentiable in the :class:`~jaxsss.layered.layers.LayerStack`. The
march is a ``lax.scan`` over the samples (carry: attenuation and radiance) inside a ``lax.map`` over pixel chunks,
with the scan body rematerialised in reverse mode, so memory stays bounded for whole frames and for gradients.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxsss.layered.layers import LayerStack
from jaxsss.layered.lighting import LightArrays, lights_at
from jaxsss.layered.localise import find_layer, layer_thickness, texture_lookup, texture_offset
from jaxsss.phase import PHASE_FUNCTIONS

__all__ = ["PixelGeometry", "march", "march_pixels", "phase_mixture", "reduced_intensity", "sample_state"]


class PixelGeometry(eqx.Module):
    """Per shaded point (``Q`` of them; all geometry, no material):

    ``P`` ``(Q, 3)`` mm; ``w_out`` ``(Q, 3)`` unit, towards the eye; ``normal`` ``N_P`` ``(Q, 3)``; ``plane_normal``
    ``NS_P`` and ``plane_point`` ``PS_P`` ``(Q, 3)`` (the fitted plane, :mod:`jaxsss.layered.planes`); ``T``, ``B``
    ``(Q, 3)`` gradients of u and v (1/mm); ``uv`` ``(Q, 2)``; ``length`` ``(Q,)`` the march length ``|P M_max|`` (mm);
    ``visible`` ``(Q, L)`` 1 where the light is not blocked from ``P``, else 0.
    """

    P: jnp.ndarray
    w_out: jnp.ndarray
    normal: jnp.ndarray
    plane_normal: jnp.ndarray
    plane_point: jnp.ndarray
    T: jnp.ndarray
    B: jnp.ndarray
    uv: jnp.ndarray
    length: jnp.ndarray
    visible: jnp.ndarray


def _dot(a, b):
    return jnp.sum(a * b, axis=-1)


def _extended(stack: LayerStack):
    """Coefficients with one extra all-zero row for "below the deepest layer"."""
    c = stack.n_channels
    zeros = jnp.zeros((1, c), dtype=stack.sigma_s.dtype)
    g = jnp.broadcast_to(stack.g, (stack.n_layers, stack.g.shape[1]))
    return (jnp.concatenate([stack.sigma_s, zeros]), jnp.concatenate([stack.sigma_t, zeros]),
            jnp.concatenate([g, jnp.zeros((1, g.shape[1]), dtype=g.dtype)]))


def phase_mixture(stack: LayerStack, layer, mu):
    """``p`` of each point's layer: ``layer`` ``(...)`` int, ``mu`` ``(..., L)`` -> ``(..., L, 1 or C)``, 1/sr."""
    _, _, g_ext = _extended(stack)
    g = jnp.take(g_ext, layer, axis=0)[..., None, :]
    names = sorted(set(stack.phase))
    if len(names) == 1:
        return PHASE_FUNCTIONS[names[0]](mu[..., None], g)
    out = 0.0
    for name in names:
        ids = jnp.asarray([i for i, p in enumerate(stack.phase) if p == name])
        use = jnp.any(layer[..., None] == ids, axis=-1)[..., None, None]
        out = out + jnp.where(use, PHASE_FUNCTIONS[name](mu[..., None], g), 0.0)
    return out


def sample_state(geom: PixelGeometry, boundaries, t):
    """Localise the samples ``M = P - t w_out`` (Algorithm 1): ``(M, uv_M, bounds_M (Q, n), layer (Q,))``."""
    d = -t[:, None] * geom.w_out
    M = geom.P + d
    uv_m = texture_offset(geom.uv, geom.T, geom.B, d)
    bounds_m = texture_lookup(boundaries, uv_m)
    depth = t * _dot(geom.w_out, geom.normal)
    return M, uv_m, bounds_m, find_layer(depth, bounds_m)


def reduced_intensity(sigma_t, boundaries, geom: PixelGeometry, lights: LightArrays, t, M, bounds_m):
    """Algorithm 2 at samples ``M = P - t w_out``: ``(L_ri (Q, L, C), w_in (Q, L, 3), path (Q, L, n))``.

    ``sigma_t`` ``(n, C)`` 1/mm; ``path[..., i]`` is the estimated path length ``d_i`` (mm) in layer ``i``.
    """
    alpha = jnp.maximum(geom.length - t, 0.0)  # |M M_max|
    beta = t  # |M P|
    total = jnp.maximum(alpha + beta, 1e-300)
    # Eq. 9: the plane at M interpolates the tangent plane at P and the fitted plane.
    n_m = (alpha[:, None] * geom.normal + beta[:, None] * geom.plane_normal) / total[:, None]
    n_m = n_m / jnp.maximum(jnp.linalg.norm(n_m, axis=-1, keepdims=True), 1e-300)
    p_m = (alpha[:, None] * geom.P + beta[:, None] * geom.plane_point) / total[:, None]
    w_in, E, _ = lights_at(lights, M)
    cos = jnp.sum(n_m[:, None, :] * w_in, axis=-1)  # (Q, L)
    lit = cos > 1e-6
    cos_safe = jnp.where(lit, cos, 1.0)
    # Eq. 10: |K'M| = h / cos(theta), h the depth of M below the plane.
    h = jnp.maximum(_dot(p_m - M, n_m), 0.0)
    km = h[:, None] / cos_safe
    k_prime = M[:, None, :] + km[..., None] * w_in
    uv_k = texture_offset(geom.uv[:, None, :], geom.T[:, None, :], geom.B[:, None, :], k_prime - geom.P[:, None, :])
    bounds_k = texture_lookup(boundaries, uv_k)  # (Q, L, n)
    # Eq. 12: mean thickness of M and K', and the path length in each layer.
    D = 0.5 * (layer_thickness(bounds_m)[:, None, :] + layer_thickness(bounds_k))
    above = jnp.cumsum(D, axis=-1) - D
    path = jnp.clip(km[..., None] - above / cos_safe[..., None], 0.0, D / cos_safe[..., None])
    # Eq. 11: attenuation through the layers.
    tau = jnp.sum(path[..., :, None] * sigma_t, axis=-2)  # (Q, L, C); a broadcast sum beats a tiny dot on CPU
    L_ri = jnp.where(lit[..., None], E * geom.visible[..., None] * jnp.exp(-tau), 0.0)
    return L_ri, w_in, path


def _march_chunk(stack: LayerStack, boundaries, geom: PixelGeometry, lights: LightArrays, n_samples: int):
    sigma_s_ext, sigma_t_ext, _ = _extended(stack)
    q = geom.P.shape[0]
    step = geom.length / n_samples

    @jax.checkpoint
    def body(carry, i):
        atten, radiance = carry
        t = (i + 0.5) * step
        M, _, bounds_m, layer = sample_state(geom, boundaries, t)
        sigma_s = jnp.take(sigma_s_ext, layer, axis=0)  # (Q, C)
        sigma_t = jnp.take(sigma_t_ext, layer, axis=0)
        L_ri, w_in, _ = reduced_intensity(stack.sigma_t, boundaries, geom, lights, t, M, bounds_m)
        # Scattering angle: light travelling along -w_in leaves along w_out.
        mu = -jnp.sum(w_in * geom.w_out[:, None, :], axis=-1)
        p = phase_mixture(stack, layer, mu)
        source = sigma_s * jnp.sum(p * L_ri, axis=1)  # (Q, C), Eq. 2
        half = jnp.exp(-0.5 * sigma_t * step[:, None])
        # Eq. 5 with the attenuation to the sample's midpoint; Eq. 13 carries it to the next sample.
        radiance = radiance + source * atten * half * step[:, None]
        return (atten * half * half, radiance), None

    c = stack.n_channels
    dtype = stack.sigma_s.dtype
    init = (jnp.ones((q, c), dtype=dtype), jnp.zeros((q, c), dtype=dtype))
    (_, radiance), _ = jax.lax.scan(body, init, jnp.arange(n_samples, dtype=dtype))
    return radiance


@eqx.filter_jit
def march(stack: LayerStack, boundaries, geom: PixelGeometry, lights: LightArrays, n_samples: int):
    """Single-scattered radiance ``(Q, C)`` (W/(mm^2 sr)) leaving each shaded point towards the eye.

    Args:
        stack: layer coefficients (differentiable).
        boundaries: ``(H, W, n)`` layer bottoms of the subsurface texture, mm.
        geom: :class:`PixelGeometry` of ``Q`` points (one chunk).
        lights: :class:`LightArrays`.
        n_samples: ``N`` samples along each view ray (static).
    """
    return _march_chunk(stack, boundaries, geom, lights, n_samples)


@eqx.filter_jit
def march_pixels(stack: LayerStack, boundaries, geom: PixelGeometry, lights: LightArrays, n_samples: int):
    """:func:`march` over pixel chunks: every ``geom`` array has a leading chunk axis ``(K, chunk, ...)``; returns
    ``(K * chunk, C)``. One jitted call for a whole frame; ``lax.map`` bounds the memory per chunk."""
    out = jax.lax.map(lambda g: _march_chunk(stack, boundaries, g, lights, n_samples), geom)
    return out.reshape(-1, out.shape[-1])
