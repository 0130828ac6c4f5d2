"""Phase functions of the physics core: Henyey-Greenstein and Schlick, in 1/sr (the renderer's single scattering,
the layered march and anything else that scatters once use these).

Angle convention (DESIGN.md trap 8). Every function here takes ``mu``, the cosine of the *scattering angle*
``theta_s`` between the direction the light travels before scattering and the direction it travels after:
``mu = (-w_in) . w_out`` where ``w_in`` is the unit vector from the scattering point towards the light and
``w_out`` the unit vector towards the eye. ``mu = 1`` is straight-on forward scattering, and a positive ``g`` (or
``k``) favours it.

Francois et al. write the Schlick function as ``(1 - g^2) / (4 pi (1 + g cos theta)^2)`` with theta the angle
*between* ``w_in`` and ``w_out``. That theta is ``pi - theta_s``, so their ``1 + g cos theta`` is the standard
``1 - k mu`` below; both conventions peak forward for a positive parameter.

Parameter convention. A layer carries ``g``, the anisotropy of a Henyey-Greenstein function (its mean cosine).
``"hg"`` uses it as is. ``"schlick"`` uses Schlick's ``k = 1.55 g - 0.55 g^3`` (Blasi, Le Saec and Schlick 1993),
which matches the shape of HG(g); its mean cosine is :func:`schlick_mean_cosine` (for example g = 0.8 gives
k = 0.958 and a mean cosine of 0.82). The cubic exceeds 1 for ``|g| > 0.9381`` (:data:`SCHLICK_G_MAX`), where
Schlick's function is no longer a density, so ``"schlick"`` layers accept ``|g| < SCHLICK_G_MAX`` only. The paper puts its Table 1 ``g`` into the Schlick formula directly, as if it
were ``k``; we do not (``docs/layered.md``).
"""

from __future__ import annotations

import jax.numpy as jnp

__all__ = [
    "PHASE_FUNCTIONS",
    "SCHLICK_G_MAX",
    "hg_phase",
    "phase_value",
    "schlick_k_from_g",
    "schlick_mean_cosine",
    "schlick_phase",
]


SCHLICK_G_MAX = 0.9381
"""Largest ``|g|`` for which ``k = 1.55 g - 0.55 g^3`` stays below 1 (the root of ``1.55 g - 0.55 g^3 = 1`` is
0.93812; rounded down)."""


def hg_phase(mu, g):
    """Henyey-Greenstein ``p(mu) = (1 - g^2) / (4 pi (1 + g^2 - 2 g mu)^{3/2})``, 1/sr; mean cosine ``g``.

    Args:
        mu: cosine of the scattering angle (module docstring), in ``[-1, 1]``.
        g: anisotropy in ``(-1, 1)``; broadcasts with ``mu``.
    """
    return (1.0 - g * g) / (4.0 * jnp.pi * (1.0 + g * g - 2.0 * g * mu) ** 1.5)


def schlick_phase(mu, k):
    """Schlick's ``p(mu) = (1 - k^2) / (4 pi (1 - k mu)^2)``, 1/sr; integrates to 1 over the sphere for |k| < 1."""
    return (1.0 - k * k) / (4.0 * jnp.pi * (1.0 - k * mu) ** 2)


def schlick_k_from_g(g):
    """Schlick's ``k`` that matches a Henyey-Greenstein ``g``: ``k = 1.55 g - 0.55 g^3`` (odd, ``|k| < 1`` for |g| < 1)."""
    return 1.55 * g - 0.55 * g**3


def schlick_mean_cosine(k):
    """Exact mean cosine of Schlick's function: ``1/k + (1 - k^2) / (2 k^2) log((1 - k) / (1 + k))`` (0 at k = 0).

    Derived by integrating ``mu p(mu)`` over the sphere; about ``2 k / 3`` for small ``k``.
    """
    k = jnp.asarray(k)
    small = jnp.abs(k) < 1e-3
    ks = jnp.where(small, 0.5, k)
    exact = 1.0 / ks + (1.0 - ks * ks) / (2.0 * ks * ks) * jnp.log((1.0 - ks) / (1.0 + ks))
    # Series for small k: 2k/3 + 2k^3/15 (avoids the cancellation of two 1/k terms).
    return jnp.where(small, 2.0 * k / 3.0 + 2.0 * k**3 / 15.0, exact)


def _schlick_from_g(mu, g):
    return schlick_phase(mu, schlick_k_from_g(g))


#: name -> ``p(mu, g)`` with ``g`` the Henyey-Greenstein anisotropy (module docstring).
PHASE_FUNCTIONS = {
    "hg": hg_phase,
    "schlick": _schlick_from_g,
}


def phase_value(name: str, mu, g):
    """``p(mu)`` of the registered phase function ``name`` (``"hg"`` or ``"schlick"``) with anisotropy ``g``.

    Raises:
        ValueError: unknown name (the message lists the valid ones).
    """
    if name not in PHASE_FUNCTIONS:
        raise ValueError(f"phase={name!r} is not known; valid: {', '.join(PHASE_FUNCTIONS)}")
    return PHASE_FUNCTIONS[name](mu, g)
