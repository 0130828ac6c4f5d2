"""Geometry-aware blending of the dipole, quadpole and multipole (photon-diffusion paper, Section 4.4, Eq. 15).

A diffusion source (a stored photon) lies at ``source``, ``source_depth`` below the face through which its light
entered, whose outward unit normal is ``source_normal``. A shading point ``x_o`` has the outward unit normal
``n_o``. With ``gamma`` the angle between the two normals (``cos gamma = source_normal . n_o``), Eq. 15 blends

    R = (2/pi) [ (pi/2 - gamma) R_d + gamma R_q ]              for 0 <= gamma <= pi/2,
    R = (2/pi) [ (pi - gamma) R_q + (gamma - pi/2) R_m ]        for pi/2 <= gamma <= pi,

so ``gamma = 0`` (a flat surface) is the dipole, ``pi/2`` (a right-angled edge) the quadpole and ``pi`` (opposite
faces of a slab) the multipole. Each model is evaluated relative to the *view plane* (the tangent plane at ``x_o``):

- ``h = (x_o - source) . n_o``, the depth of the source below the view plane ("view depth"), and ``rho`` the
  distance from the foot of the source in that plane to ``x_o``;
- ``R_d`` -- the dipole of a source at depth ``h`` (:func:`~jaxsss.profiles.point_sources.dipole_exitance`);
- ``R_q`` -- the quadpole (:mod:`jaxsss.profiles.quadpole`), assuming, as the paper does, that the incidence plane
  and the view plane meet at a right angle: the view-plane dipole minus the dipole of the source's image in the
  extrapolated incidence boundary (``source + 2 (source_depth + z_b) source_normal``), with that image's own depth
  ``h' = h - 2 (source_depth + z_b) cos gamma`` and in-plane distance. For ``gamma = pi/2`` this is Eq. 14 with
  ``depth = h`` and ``offset = source_depth`` exactly;
- ``R_m`` -- the multipole with the source at depth ``h`` below the viewed face and the thickness "the sum of the
  depth of the source relative to its incident plane, and relative to the view plane", ``d = source_depth + h``
  (:func:`~jaxsss.profiles.point_sources.multipole_exitance`). The reflectance form serves for transmission too.

All three are per unit *source power* (the power carries ``alpha'``, DESIGN.md trap 2). Sources above the view
plane (``h < 0``) are outside every model's assumptions; the formulas are evaluated as they stand (no clamping).

Shapes: vectors have a trailing axis of 3 and broadcast over their leading (batch) axes ``B``; ``source_depth``
broadcasts against ``B``. The result has shape ``B + M``, ``M`` the shape of the medium's arrays (its channels), so
channels stay the trailing axis. Normals are normalised here. ``gamma`` is ``arccos`` of the clipped dot product:
its derivative with respect to the normals is infinite at ``gamma = 0`` and ``pi``; derivatives with respect to the
medium and positions are finite.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from jaxsss import _config  # noqa: F401  (float64)
from jaxsss.validate import as_float, check_range, require
from jaxsss.medium import Medium
from jaxsss.profiles._sources import point_source_exitance
from jaxsss.profiles.multipole import _check_n_pairs
from jaxsss.profiles.point_sources import DEFAULT_N_PAIRS, _multipole_sum, safe_sqrt

__all__ = ["blend_profiles", "blend_weights", "blended_exitance", "blended_unchecked"]


def blend_weights(gamma):
    """Eq. 15's weights ``(w_d, w_q, w_m)`` of the dipole, quadpole and multipole; they sum to 1.

    Args:
        gamma: angle between the source's incidence-plane normal and the shading normal, radians, in ``[0, pi]``.

    Returns:
        Three arrays of the shape of ``gamma``: piecewise linear, ``(1, 0, 0)`` at 0, ``(0, 1, 0)`` at ``pi/2`` and
        ``(0, 0, 1)`` at ``pi``.
    """
    gamma = check_range(gamma, "gamma", 0.0, jnp.pi, owner="blend_weights")
    return _weights(gamma)


def _weights(gamma):
    two_over_pi = 2.0 / jnp.pi
    first = gamma <= 0.5 * jnp.pi
    # Eq. 15, both branches.
    w_d = jnp.where(first, two_over_pi * (0.5 * jnp.pi - gamma), 0.0)
    w_q = jnp.where(first, two_over_pi * gamma, two_over_pi * (jnp.pi - gamma))
    w_m = jnp.where(first, 0.0, two_over_pi * (gamma - 0.5 * jnp.pi))
    return w_d, w_q, w_m


def blend_profiles(gamma, R_d, R_q, R_m):
    """Eq. 15 applied to given model values: ``w_d R_d + w_q R_q + w_m R_m`` (see :func:`blend_weights`)."""
    w_d, w_q, w_m = blend_weights(gamma)
    return w_d * R_d + w_q * R_q + w_m * R_m


def _unit(v, name, owner):
    v = as_float(v, name)
    if v.ndim == 0 or v.shape[-1] != 3:
        raise ValueError(f"{owner}({name}=array of shape {v.shape}): needs a trailing axis of length 3")
    norm = jnp.sqrt(jnp.sum(v * v, axis=-1, keepdims=True))
    norm = require(norm, ~(norm > 0.0) | ~jnp.isfinite(norm),
                   f"{owner}({name}=...): a normal of zero, infinite or NaN length; allowed: finite non-zero vectors")
    return v / norm


def blended_exitance(x_o, n_o, source, source_normal, source_depth, medium: Medium, *,
                     n_pairs: int = DEFAULT_N_PAIRS):
    """Exitance at ``x_o`` from a unit source, blending dipole, quadpole and multipole by Eq. 15.

    Args:
        x_o: shading point, mm, ``(*B, 3)``.
        n_o: outward normal at ``x_o``, ``(*B, 3)`` (normalised here).
        source: source position, mm, ``(*B, 3)``.
        source_normal: outward normal of the face through which the source's light entered, ``(*B, 3)``.
        source_depth: depth of the source below that face, mm, ``>= 0``, shape broadcasting with ``B``.
        medium: the :class:`~jaxsss.medium.Medium` (shape ``M``).
        n_pairs: multipole image pairs (static int ``>= 0``; see :func:`~jaxsss.profiles.point_sources.multipole_exitance`).

    Returns:
        1/mm^2 per unit source power, shape ``B + M``.
    """
    owner = "blended_exitance"
    n = _check_n_pairs(n_pairs, owner)
    x_o = check_range(x_o, "x_o", None, None, owner=owner)
    source = check_range(source, "source", None, None, owner=owner)
    n_o = _unit(n_o, "n_o", owner)
    n_i = _unit(source_normal, "source_normal", owner)
    ell = check_range(source_depth, "source_depth", 0.0, None, owner=owner)
    return blended_unchecked(x_o, n_o, source, n_i, ell, medium, n)


@eqx.filter_jit
def blended_unchecked(x_o, n_o, source, n_i, ell, medium, n_pairs):
    """The kernel of :func:`blended_exitance` without its argument checks, for callers that validated their input
    once (the photon renderer's inner loop, where a per-call check costs time and must not run inside a fit's
    solver). Same arguments (``n_pairs`` a static int) and units."""
    v = source - x_o
    # Geometry in the view plane (batch shape B), then a trailing axis per medium dimension.
    h = -jnp.sum(v * n_o, axis=-1)
    vv = jnp.sum(v * v, axis=-1)
    v_ni = jnp.sum(v * n_i, axis=-1)
    cos_g = jnp.clip(jnp.sum(n_i * n_o, axis=-1), -1.0, 1.0)
    B = jnp.broadcast_shapes(h.shape, jnp.shape(ell))
    k = len(jnp.broadcast_shapes(jnp.shape(medium.sigma_tr), jnp.shape(medium.z_b)))
    h, vv, v_ni, cos_g, ell = (jnp.broadcast_to(a, B).reshape(B + (1,) * k) for a in (h, vv, v_ni, cos_g, ell))
    gamma = jnp.arccos(cos_g)
    sigma_tr, z_b = medium.sigma_tr, medium.z_b
    # In-plane distance; rounding can leave |v|^2 - h^2 a few ulps below zero for a source right below x_o.
    rho = safe_sqrt(jnp.maximum(vv - h * h, 0.0))

    # Dipole of the view plane (photon-diffusion Eq. 6 with the source at depth h).
    R_d = point_source_exitance(h, rho, sigma_tr) + point_source_exitance(h + 2.0 * z_b, rho, sigma_tr)
    # Quadpole (Eq. 14): minus the view-plane dipole of the image in the extrapolated incidence boundary.
    a = ell + z_b
    h_img = h - 2.0 * a * cos_g
    rho_img = safe_sqrt(jnp.maximum(vv + 4.0 * a * v_ni + 4.0 * a * a - h_img * h_img, 0.0))
    R_q = R_d - (point_source_exitance(h_img, rho_img, sigma_tr)
                 + point_source_exitance(h_img + 2.0 * z_b, rho_img, sigma_tr))
    # Multipole (Eq. 12-13) with thickness = source depth + view depth (Section 4.4).
    R_m = _multipole_sum(rho, h, medium, ell + h, n_pairs)
    # Eq. 15.
    w_d, w_q, w_m = _weights(gamma)
    return w_d * R_d + w_q * R_q + w_m * R_m
