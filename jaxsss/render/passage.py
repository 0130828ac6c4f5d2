"""Light that crosses the object without interacting: the white kernels' entry on a curved or thin surface.

The white Monte Carlo profiles (:mod:`jaxsss.render.bssrdf`) are a half-space's: every photon that enters interacts
somewhere below the surface. On a convex object a photon entering at grazing incidence runs along a chord of finite
length and leaves through the far side if it has not interacted by then. On a sphere of radius ``a`` the chord of
light refracted at ``cos theta_t`` is ``2 a cos theta_t``: 4 mm at cos 0.1 on the 20 mm sphere, against a mean free
path of 1.3 mm for skin1's red (4.5% passes straight through) and 4.1 mm for ketchup's red (38%). Thin parts (a
handle, an ear) lose light the same way at any incidence.

Each irradiance sample's light column (:class:`jaxsss.render.lights.LightField`) is traced once, in pass 1, along its
refracted direction to where it leaves the translucent mesh: the chord ``t`` (mm; ``inf`` where the ray never
leaves, e.g. an open mesh or a plane, and where the column holds no light). Its incident flux is then weighted by
the probability of interacting along the chord (Beer-Lambert on the uncollided path),

    P_int = 1 - exp(-sigma_t t),    sigma_t = sigma_a + sigma_s' / (1 - g),

the real extinction, not the reduced one (a photon's first interaction is what the half-space profile starts from).
The light that crosses is lost to the object (it leaves; a lone object never gets it back). What is left out: on a
convex surface the photons that do interact do so at a shallower depth than in the half-space (second order).

Measured against Mitsuba's volumetric path tracer (20 mm spheres, point light, eta 1; ``docs/path_tracer.md``,
"Uncollided passage"): the terminator band of skin1 and ketchup, where light arrives at grazing incidence, is where
it matters; the side facing the light is unchanged.

The chord also bounds how far the light that does interact travels forward. The oblique profiles are shifted along
the light's travel by the half-space's mean (:data:`jaxsss.render.bssrdf.SHIFT_RATIO` times ``sin theta_t /
sigma_t'``); along a chord ``t`` the mean travel before the first interaction, given one, is
``f(sigma_t' t) / sigma_t'`` with

    f(x) = (1 - (1 + x) e^-x) / (1 - e^-x)    (1 for x -> inf, x / 2 for x -> 0),

so each light column's share of the shift is weighted by ``f`` (:func:`truncated_travel`; in transport units, as the
shift). Without it the forward-shifted light of grazing columns landed past the terminator: ketchup's red was 62%
too bright at cos -1 to -0.3 to the light and the chicken1 sphere's red 72% (``docs/path_tracer.md``, "The shift's
travel along a short chord").
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxsss.fresnel import refract, snell_cosine

__all__ = ["entry_chords", "interaction_probability", "truncated_travel"]


def entry_chords(geometry, points: np.ndarray, normals: np.ndarray, to_light: np.ndarray, cos: np.ndarray,
                 eta: float) -> np.ndarray:
    """Length of each light column's refracted ray inside the object, mm (NumPy; pass 1).

    Args:
        geometry: the scene's :class:`~jaxsss.render.rays.SceneGeometry` (its first mesh is the translucent object).
        points: ``(N, 3)`` surface points, mm.
        normals: ``(N, 3)`` unit outward normals.
        to_light: ``(N, L, 3)`` unit directions towards each light column.
        cos: ``(N, L)`` cosines to the normal (columns at or below 0 hold no light and are not traced).
        eta: relative index of refraction ``n_inside / n_outside``.

    Returns:
        ``(N, L)``: the distance from each point along its refracted direction to where the ray next meets the
        translucent mesh; ``inf`` where it does not (or meets an occluder first) and for unlit columns.
    """
    from jaxsss.render.rays import OBJECT_TRANSLUCENT

    n_pts, n_cols = cos.shape
    chord = np.full((n_pts, n_cols), np.inf)
    lit = cos > 0.0
    if not lit.any():
        return chord
    p, col = np.nonzero(lit)
    nrm = normals[p]
    cos_i = np.clip(cos[p, col], 0.0, 1.0)
    cos_t, ok = snell_cosine(cos_i, eta, xp=np)
    # Snell: the direction of travel inside.
    inside = refract(-to_light[p, col], nrm, cos_i, cos_t, eta, xp=np)
    origins = points[p] - geometry.offset * nrm
    hits = geometry.first_hit(origins, inside)
    t = np.where(hits.hit & (hits.obj == OBJECT_TRANSLUCENT) & ok, hits.t + geometry.offset, np.inf)
    chord[p, col] = t
    return chord


def interaction_probability(chord, sigma_t):
    """``1 - exp(-sigma_t t)``: the probability that light entering along a chord of length ``t`` interacts before
    it leaves.

    Args:
        chord: ``(N, L)`` mm, ``inf`` allowed (probability 1).
        sigma_t: ``(C,)`` extinction coefficient, 1/mm.

    Returns:
        ``(N, L, C)``, differentiable in ``sigma_t`` (finite gradients where the chord is infinite).
    """
    finite = jnp.isfinite(chord)[..., None]
    t = jnp.where(finite, chord[..., None], 0.0)
    return jnp.where(finite, -jnp.expm1(-sigma_t * t), 1.0)


def truncated_travel(chord, sigma_t_prime):
    """``f(x) = (1 - (1 + x) e^-x) / (1 - e^-x)``, ``x = sigma_t' t``: the mean distance light travels along its
    refracted ray before it interacts, given that it interacts before the chord of length ``t`` ends, in units of the
    half-space's ``1 / sigma_t'`` (1 for an infinite chord, ``x / 2`` for a short one).

    Args:
        chord: ``(N, L)`` mm, ``inf`` allowed (1).
        sigma_t_prime: ``(C,)`` reduced extinction coefficient, 1/mm.

    Returns:
        ``(N, L, C)`` in ``[0, 1]`` (0 for a chord of length 0), differentiable (a series below ``x = 1e-3``, where the
        closed form cancels).
    """
    finite = jnp.isfinite(chord)[..., None]
    x = sigma_t_prime * jnp.where(finite, chord[..., None], 1.0)
    small = x < 1e-3
    xs = jnp.where(small, 1.0, x)
    # E[s | s < t] sigma_t' for an exponential free path s.
    closed = (-jnp.expm1(-xs) - xs * jnp.exp(-xs)) / -jnp.expm1(-xs)
    return jnp.where(finite, jnp.where(small, x / 2.0 - x * x / 12.0, closed), 1.0)
