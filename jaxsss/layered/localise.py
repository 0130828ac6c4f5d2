"""Point localisation in a subsurface texture (Francois et al., Sec. 2.1 and Algorithm 1), in JAX.

A point ``M`` below the surface point ``P`` is located by projecting ``PM`` into the tangent space at ``P``:
``(u_M, v_M) = (u_P, v_P) + (PM . T, PM . B)`` with ``T`` and ``B`` the surface gradients of ``u`` and ``v``
(:mod:`jaxsss.layered.tangents`), and its depth is ``MP . N`` along the normal ``N`` at ``P``. ``FindLayer``
compares that depth with the layer bottoms read from the texture at ``(u_M, v_M)``; ``LayerThickness`` returns
their differences.

Lookups are bilinear with wrap-around (texels at their centres; ``v = 0`` is the bottom image row,
:mod:`jaxsss.layered.textures`). They depend on geometry only, so they carry no gradient with respect to the
material.
"""

from __future__ import annotations

import jax.numpy as jnp

__all__ = ["find_layer", "layer_thickness", "texture_lookup", "texture_offset"]


def texture_lookup(boundaries, uv):
    """Bilinear, wrapping lookup of the layer bottoms.

    Args:
        boundaries: ``(H, W, n)`` depths of the layer bottoms, mm (non-decreasing along the last axis).
        uv: ``(..., 2)`` texture coordinates (any real values; the texture repeats).

    Returns:
        ``(..., n)`` depths, mm.
    """
    h, w = boundaries.shape[0], boundaries.shape[1]
    x = uv[..., 0] * w - 0.5
    y = (1.0 - uv[..., 1]) * h - 0.5
    x0, y0 = jnp.floor(x), jnp.floor(y)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    i0 = jnp.mod(x0.astype(jnp.int32), w)
    j0 = jnp.mod(y0.astype(jnp.int32), h)
    i1 = jnp.mod(i0 + 1, w)
    j1 = jnp.mod(j0 + 1, h)
    top = boundaries[j0, i0] * (1.0 - fx) + boundaries[j0, i1] * fx
    bottom = boundaries[j1, i0] * (1.0 - fx) + boundaries[j1, i1] * fx
    return top * (1.0 - fy) + bottom * fy


def texture_offset(uv_p, T, B, d):
    """Texture coordinates of ``P + d``: ``uv_P + (d . T, d . B)`` (Algorithm 1; Sec. 2.1 projection)."""
    return uv_p + jnp.stack([jnp.sum(d * T, axis=-1), jnp.sum(d * B, axis=-1)], axis=-1)


def find_layer(depth, bounds):
    """``FindLayer``: index of the layer holding a point at ``depth`` (mm) below layer bottoms ``bounds`` ``(..., n)``.

    Layer ``i`` spans ``[b_{i-1}, b_i)`` (``b_{-1} = 0``); ``n`` means below the deepest layer (nothing there).
    Points above the surface (``depth < 0``) count as layer 0.
    """
    return jnp.sum((bounds <= depth[..., None]).astype(jnp.int32), axis=-1)


def layer_thickness(bounds):
    """``LayerThickness``: ``(..., n)`` thickness of each layer from its bottom depths (mm, ``>= 0``)."""
    upper = jnp.concatenate([jnp.zeros_like(bounds[..., :1]), bounds[..., :-1]], axis=-1)
    return bounds - upper
