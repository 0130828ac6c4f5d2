"""The quadpole: diffusion at a right-angled edge (photon-diffusion paper, Section 3.1, Eq. 14 re-derived).

Geometry (the "view frame"). The medium fills the quarter-space bounded by two perpendicular faces: the *viewed*
face, where the exitance is wanted, and the *adjoining* face. A unit isotropic source lies at ``depth`` below the
viewed face and at distance ``offset`` from the adjoining face. A shading point on the viewed face lies at distance
``u >= 0`` from the edge and ``y`` along the edge from the source. (For a beam entering the top face of a box at
distance ``a`` from its edge, the top face is viewed with ``depth = l_u, offset = a`` and the side face with
``depth = a, offset = l_u``.)

Derivation (DESIGN.md trap 5; the printed Eq. 14 drops 4 pi in two terms, swaps two exponents and loses the signs).
Each face has the zero-fluence condition on its extrapolated boundary, ``z_b = 2 A D`` outside it (Eq. 10). With
coordinates ``(w, h)`` = (distance from the adjoining face, depth below the viewed face), the boundaries are
``h = -z_b`` and ``w = -z_b``. Mirroring the source in both gives four sources with alternating signs,

    S1 = +1 at (offset, depth)                   S2 = -1 at (offset, -depth - 2 z_b)
    S3 = -1 at (-offset - 2 z_b, depth)          S4 = +1 at (-offset - 2 z_b, -depth - 2 z_b)

The pairs (S1, S2) and (S3, S4) cancel on ``h = -z_b``; (S1, S3) and (S2, S4) cancel on ``w = -z_b``: both
conditions hold exactly with four sources, because the right angle divides pi (the method of images for a wedge of
angle pi/2). The diffusive flux through the viewed face (``h = 0``) of a unit source at height ``h_k`` below it is
the dipole building block ``E(h_k, rho_k)`` (:mod:`jaxsss.profiles._sources`), odd in ``h_k``. Summing the four,
with ``z_r = depth``, ``z_v = depth + 2 z_b`` and the in-face distances

    rho_r^2 = (u - offset)^2 + y^2              (to S1 and S2)
    rho_v^2 = (u + offset + 2 z_b)^2 + y^2      (to S3 and S4),

    R_q(u, y) = E(z_r, rho_r) + E(z_v, rho_r) - E(z_r, rho_v) - E(z_v, rho_v)                       (Eq. 14)

per unit source power. In the paper's notation (viewed = side face) ``x_r = depth``, ``x_v = x_r + 2 z_b``, and each
term is ``x (1 + sigma_tr d) e^{-sigma_tr d} / (4 pi d^3)`` at its own distance ``d``. Properties (tested): the first
two terms are the dipole of the viewed face and the last two its mirror image in the adjoining boundary, so
``R_q -> dipole`` as ``offset -> inf``; ``R_q`` is even in ``y``; the fluence vanishes on both extrapolated planes;
exchanging the roles of the faces is a reflection of the whole configuration.

Units: mm, 1/mm^2. All arguments broadcast against the medium's arrays (trailing channel axis).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from jaxsss import _config  # noqa: F401  (float64)
from jaxsss.validate import check_range
from jaxsss.medium import Medium
from jaxsss.profiles._sources import point_source_exitance
from jaxsss.profiles.point_sources import safe_sqrt

__all__ = ["quadpole_exitance", "quadpole_profile", "quadpole_sources"]


def _check(u, y, depth, offset, owner):
    u = check_range(u, "u", 0.0, None, owner=owner)
    y = check_range(y, "y", None, None, owner=owner)
    depth = check_range(depth, "depth", 0.0, None, owner=owner)
    offset = check_range(offset, "offset", 0.0, None, owner=owner)
    return u, y, depth, offset


def quadpole_sources(depth, offset, medium: Medium):
    """The four sources of the quadpole in the view frame: ``(w, h, sign)``, each of shape ``(4, *S)``.

    ``w`` is the distance from the adjoining face, ``h`` the depth below the viewed face (mm); ``sign`` is
    ``(+1, -1, -1, +1)`` for S1..S4 of the module docstring.
    """
    depth = check_range(depth, "depth", 0.0, None, owner="quadpole_sources")
    offset = check_range(offset, "offset", 0.0, None, owner="quadpole_sources")
    z_b = medium.z_b
    shape = jnp.broadcast_shapes(jnp.shape(depth), jnp.shape(offset), jnp.shape(z_b))
    # Mirror images in the extrapolated boundaries h = -z_b and w = -z_b (Eq. 10 on both faces, Figure 4).
    w_img = -offset - 2.0 * z_b
    h_img = -depth - 2.0 * z_b
    w = jnp.stack([jnp.broadcast_to(v, shape) for v in (offset, offset, w_img, w_img)])
    h = jnp.stack([jnp.broadcast_to(v, shape) for v in (depth, h_img, depth, h_img)])
    sign = jnp.array([1.0, -1.0, -1.0, 1.0], jnp.result_type(w)).reshape((4,) + (1,) * len(shape))
    return w, h, sign


def quadpole_exitance(u, y, depth, offset, medium: Medium):
    """Quadpole exitance ``R_q`` on the viewed face of a right-angled edge, per unit source power (Eq. 14).

    Args:
        u: distance of the shading point from the edge, in the viewed face, mm, ``>= 0``.
        y: offset along the edge from the source, mm.
        depth: depth of the source below the viewed face, mm, ``>= 0``.
        offset: distance of the source from the adjoining face, mm, ``>= 0``.
        medium: the :class:`~jaxsss.medium.Medium`.

    Returns:
        1/mm^2 per unit source power (multiply by ``alpha'`` for flux entering; DESIGN.md trap 2), broadcast shape.
    """
    u, y, depth, offset = _check(u, y, depth, offset, "quadpole_exitance")
    return _quadpole(u, y, depth, offset, medium)


@eqx.filter_jit
def _quadpole(u, y, depth, offset, medium):
    sigma_tr, z_b = medium.sigma_tr, medium.z_b
    z_r = depth
    z_v = depth + 2.0 * z_b
    rho_r = safe_sqrt((u - offset) ** 2 + y * y)
    rho_v = safe_sqrt((u + offset + 2.0 * z_b) ** 2 + y * y)
    # Eq. 14 (re-derived): the viewed face's dipole (S1, S2) ...
    dipole = point_source_exitance(z_r, rho_r, sigma_tr) + point_source_exitance(z_v, rho_r, sigma_tr)
    # ... minus its mirror image in the adjoining face's extrapolated boundary (S3, S4).
    mirror = point_source_exitance(z_r, rho_v, sigma_tr) + point_source_exitance(z_v, rho_v, sigma_tr)
    return dipole - mirror


def quadpole_profile(u, y, medium: Medium, edge_distance, *, face: str = "side"):
    """Quadpole profile of a normally incident pencil beam entering the top face at ``edge_distance`` from the edge.

    The classical source at one mean free path (depth ``l_u``), per unit flux *entering* (``alpha'`` included, the
    normalisation of :func:`~jaxsss.profiles.dipole.dipole_profile`).

    Args:
        u: distance from the edge in the viewed face, mm, ``>= 0`` (on the side face: the depth below the top face).
        y: offset along the edge, mm.
        medium: the :class:`~jaxsss.medium.Medium`.
        edge_distance: distance of the beam from the edge, mm, ``>= 0``.
        face: ``"top"`` (the lit face: depth ``l_u``, offset ``edge_distance``) or ``"side"`` (depth
            ``edge_distance``, offset ``l_u``).

    Returns:
        1/mm^2, the broadcast shape.
    """
    if face not in ("top", "side"):
        raise ValueError(f"quadpole_profile(face={face!r}) is not a face; valid names: ['side', 'top']")
    owner = "quadpole_profile"
    u = check_range(u, "u", 0.0, None, owner=owner)
    y = check_range(y, "y", None, None, owner=owner)
    a = check_range(edge_distance, "edge_distance", 0.0, None, owner=owner)
    l_u = medium.l_u
    depth, offset = (l_u, a) if face == "top" else (a, l_u)
    return medium.alpha_prime * _quadpole(u, y, depth, offset, medium)
