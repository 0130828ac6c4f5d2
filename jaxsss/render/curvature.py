"""How a curved surface changes the half-space profile: the diffusion ratio of a sphere to a plane, per pair.

The renderer's profiles (:mod:`jaxsss.render.bssrdf`) are those of a *half-space*. On a convex object light escapes
sooner than under a plane (the surface curves towards the paths), so less of it is absorbed and more comes out far
from where it entered. Measured against Mitsuba's volumetric path tracer on the 20 mm skin1 sphere (summed radiance
of the sphere over that of the same sphere with every coefficient scaled up, i.e. the same medium under a flatter
surface; ``docs/path_tracer.md``, "Curvature"): under a uniform environment at ``eta = 1.4`` the sphere gives 15 / 10 /
8% (R, G, B) more diffuse light than its half-space limit; under a sky with a sun 12 / 7 / 4%; at ``eta = 1`` under a
point light 3 / 2 / 1%. The half-space kernel summed over the chord distances has no such term at all: on a sphere the
area within chord ``d`` of a point is exactly ``pi d^2`` (Archimedes), so the sum over a uniformly lit sphere *is*
the plane's.

The correction multiplies the profile of each (shaded point ``x``, sample ``P``) pair by

    C(d, kappa) = R_sphere(d; a = 1 / kappa) / R_dipole(d),

the exitance at chord ``d`` of the diffusion dipole on a sphere of radius ``a`` -- the real source one reduced mean
free path ``z_r`` below the surface (radius ``b = a - z_r``), a negative image at Kelvin's point ``a_e^2 / b``
outside (``a_e = a + z_b``, the extrapolated boundary), whose strength makes the fluence vanish on the extrapolated
sphere at the pair's own angle, ``(d_2e / d_1e) exp(-sigma_tr (d_1e - d_2e))`` (``d_ie``: the distances from the
source and the image to that point; Kelvin's ``a_e / b`` without absorption, where it is exact at every angle) --
over the planar dipole's at the same distance (Jensen et al. 2001 Eq. 4 is ``kappa = 0``, where ``C = 1`` exactly).
Integrated over a uniformly lit sphere it is within 1-2% of the exact diffusion solution (a shell of sources;
``tests/render/test_curvature.py``): for skin1 on the 20 mm sphere 1.186 / 1.116 / 1.069 against 1.196 / 1.115 /
1.069 at ``eta = 1.4``. (Kelvin's strength at every angle, tried first, leaves the boundary condition off by ``~
sigma_tr d (z_b + z_r) / a``: at 27 mm on the 20 mm sphere its ratio was 2.5-10x this one, and the uniformly lit
total 1.140 / 1.097 / 1.064.) ``C`` is about 1 near the source and grows with distance: for skin1 at ``eta = 1.4`` on the 20 mm sphere 1.06
/ 1.07 / 1.09 at 1 mm and 1.30 / 1.43 / 1.56 at 4 mm (R, G, B). The ratio, not the dipole itself, is applied: the
transport-accurate white Monte Carlo profile keeps its shape and gains the curvature's.

Oblique incidence. Light that enters at the refracted cosine ``mu_t`` first scatters about ``mu_t / sigma_t'`` below
the surface, not ``1 / sigma_t'``: the directional dipole's source (Frisvad et al. 2014) sits one mean free path along
the refracted ray. The ratio of each incidence node of the white kernels (:data:`jaxsss.render.bssrdf.OBLIQUE_MUS`)
places its source there (``depth = mu_t``). A shallow source feels the curvature less, and most of the light that
reaches the far side of a sphere entered near its terminator at grazing angles: with one depth for every node, the
ketchup sphere's red channel (``l_u = 4.1`` mm on a 20 mm sphere) was 47-108% too bright past the terminator against
Mitsuba (cos to the light below -0.1), with the node's own depth 29-62% (``docs/path_tracer.md``, "Each incidence
node's curvature source at its own depth").

The curvature of a pair is that of the sphere through both points with their normals, ``kappa = (n_x - n_P) . (x -
P) / |x - P|^2`` (exactly ``1 / a`` on a sphere of radius ``a``; 0 in a plane), from the shaded point's normal and the
sample's (an octree node's: its area-weighted mean normal). It is clipped to ``[0, min(2 / d, 1 / (4 l_u))]``:
concave pairs (``kappa < 0``) get no correction (the medium outside a sphere would need its own images; left out),
and the sphere must hold the source well inside it and the chord.

Tabulated. The renderer does not evaluate ``C`` per pair: per image, :func:`log_ratio_table` tabulates ``log C`` once
per incidence node and channel on the profiles' distance grid and :data:`N_KAPPA` curvature nodes, and each pair
interpolates it bilinearly together with the profile (:meth:`jaxsss.render.bssrdf.WhiteKernel.profile`). The
curvature axis is the fraction ``u = kappa / kappa_cap(d)`` of the largest curvature the ratio admits at the pair's
distance, on nodes ``u_j = 1 - (1 - j / (N - 1))^2`` (:func:`curvature_coordinate`): the cap ``2 / d`` is then the
table's edge, not a kink inside it, and the nodes crowd towards the antipode, where ``C`` turns fastest. Against
:func:`curvature_ratio` for skin1 (eta 1 and 1.4), ketchup and marble, sources at depth 1 and 0.1, chords 0.01-15 mm:
within 1.5% wherever ``kappa d < 1.5`` (a chord spanning under 97 degrees of arc), within 8.5% beyond (one distance
interval, where the cap changes from ``KAPPA_MAX_ZR sigma_t'`` to ``2 / d``: 8.4% in skin1's red at the cap 0.15;
docs/path_tracer.md, "The curvature ratio, tabulated").
"""

from __future__ import annotations

import jax.numpy as jnp

__all__ = ["DEPTH_MIN", "KAPPA_MAX_ZR", "N_KAPPA", "curvature_coordinate", "curvature_ratio", "kappa_cap",
           "log_ratio_table", "pair_curvature"]

KAPPA_MAX_ZR = 0.15
"""The largest curvature the ratio uses, in units of ``sigma_t'``: a sphere of radius at least ``6.7 l_u``. Diffusion's
gain on a sphere only a few transport lengths across is too large for the orders >= 2 (the first order is marched in
the geometry, :mod:`jaxsss.render.first_order`): against Mitsuba, chicken1's red and green (``a = 3.3`` and ``5.7
l_u``) and ketchup's red (``4.9 l_u``) were 2.6-3.5% too bright in sum at 0.25, and within 2.3% at 0.15; media with
``l_u`` under a seventh of the radius do not reach the cap (docs/path_tracer.md, "The curvature cap, re-measured with
the first order marched"). Since 2026-12-02 it is the cap of the index-matched kernels without the first
order marched (``g > 0``, skies): the marched ones take transport's correction with caps of their own
(:data:`jaxsss.render.curvature_correction.KAPPA_MAX_NEAR` from the light's side, ``KAPPA_MAX_MARCHED`` behind)."""
DEPTH_MIN = 0.05
"""The shallowest source the ratio places, in units of ``l_u``: a source on the surface itself would make both dipoles
singular at ``d = 0`` (the nodes' own depths are at least 0.1)."""
N_KAPPA = 33
"""Curvature nodes of :func:`log_ratio_table` (17 left up to 3.5% at ``kappa d < 1`` in skin1's blue at eta 1.4)."""


def pair_curvature(delta, normal_x, normal_p):
    """Curvature of the sphere through two surface points with their normals, 1/mm (positive: convex).

    Args:
        delta: ``(..., 3)`` offsets ``x - P``, mm.
        normal_x, normal_p: ``(..., 3)`` unit outward normals at ``x`` and at ``P``.

    Returns:
        ``(...)``: ``(n_x - n_P) . (x - P) / |x - P|^2``; 0 for coincident points.
    """
    d2 = jnp.sum(delta * delta, axis=-1)
    num = jnp.sum((normal_x - normal_p) * delta, axis=-1)
    return jnp.where(d2 > 0.0, num / jnp.where(d2 > 0.0, d2, 1.0), 0.0)


def _sphere_exitance(d, kappa, z_r, z_b, s):
    """The dipole's exitance on a sphere of curvature ``kappa`` at chord ``d`` (up to the common factor ``alpha' /
    4 pi``), each exponential taken relative to ``exp(-s sqrt(z_r^2 + d^2))`` (the ratio's common scale)."""
    k_r, k_b = kappa * z_r, kappa * z_b
    inside = 1.0 - k_r  # b / a
    d2 = d * d
    ref = jnp.sqrt(z_r * z_r + d2)
    # Real source at b = a - z_r: |x - b|^2 = z_r^2 + (b / a) d^2, (a - b cos t) = z_r + (b / a) kappa d^2 / 2.
    d1 = jnp.sqrt(z_r * z_r + inside * d2)
    n1 = z_r + inside * kappa * d2 / 2.0
    # Image at Kelvin's point a_e^2 / b (a_e = a + z_b).
    h = (2.0 * z_b + z_r + k_b * z_b) / inside  # its height above the surface, bi - a
    outside = (1.0 + k_b) ** 2 / inside  # bi / a
    dv = jnp.sqrt(h * h + outside * d2)
    nv = -h + outside * kappa * d2 / 2.0
    # Its strength cancels the fluence on the extrapolated sphere at the pair's angle: -(d2e / d1e) exp(-s (d1e -
    # d2e)), the distances from the source and the image to that point. On that sphere d2e / d1e = a_e / b at every
    # angle (Kelvin), so d2e = q d1e (the strength is Kelvin's -a_e / b when s = 0; -1 flat).
    q = (1.0 + k_b) / inside
    d1e = jnp.sqrt((z_b + z_r) ** 2 + (1.0 + k_b) * inside * d2)
    return (n1 * (1.0 + s * d1) * jnp.exp(-s * (d1 - ref)) / d1**3
            - q * nv * (1.0 + s * dv) * jnp.exp(-s * (dv - ref + (1.0 - q) * d1e)) / dv**3)


def _plane_exitance(d, z_r, z_b, s):
    """:func:`_sphere_exitance` at ``kappa = 0`` in closed form: Jensen et al. 2001 Eq. 4 (real source at ``z_r``,
    image at ``z_v = z_r + 2 z_b``), on the same scale."""
    z_v = z_r + 2.0 * z_b
    d2 = d * d
    ref = jnp.sqrt(z_r * z_r + d2)
    dv = jnp.sqrt(z_v * z_v + d2)
    return z_r * (1.0 + s * ref) / ref**3 + z_v * (1.0 + s * dv) * jnp.exp(-s * (dv - ref)) / dv**3


def curvature_ratio(d, kappa, sigma_a, sigma_s_prime, A, depth=1.0, kappa_max=KAPPA_MAX_ZR):
    """``C(d, kappa)``: the sphere-to-plane ratio of the diffusion dipole's exitance (module docstring).

    Args:
        d: chord distance between the points, mm, ``>= 0``.
        kappa: pair curvature, 1/mm (:func:`pair_curvature`); clipped to ``[0, min(2 / d, kappa_max / l_u)]``,
            ``l_u = 1 / sigma_t'``.
        sigma_a, sigma_s_prime: 1/mm (``sigma_a >= 0``).
        A: boundary reflection parameter ``(1 + F_dr) / (1 - F_dr)`` (:attr:`jaxsss.Medium.A`).
        depth: the source's depth in units of ``l_u``, ``(0, 1]``: the refracted cosine ``mu_t`` of the light's
            direction (module docstring, "Oblique incidence"); 1 (normal incidence) by default.
        kappa_max: the cap on the curvature in units of ``sigma_t'`` (:data:`KAPPA_MAX_ZR` by default; the marched
            kernels' transport-corrected ratio uses :data:`jaxsss.render.curvature_correction.KAPPA_MAX_MARCHED`).

    All arguments broadcast. Returns the ratio, 1 at ``kappa = 0``; differentiable (finite at ``sigma_a = 0``).
    """
    sigma_t_prime = sigma_a + sigma_s_prime
    # The real source one mean free path along the refracted ray: z_r = mu_t / sigma_t' (the directional dipole's).
    z_r = jnp.clip(depth, DEPTH_MIN, 1.0) / sigma_t_prime
    z_b = 2.0 * A / (3.0 * sigma_t_prime)
    s2 = 3.0 * sigma_a * sigma_t_prime
    pos = s2 > 0.0
    s = jnp.where(pos, jnp.sqrt(jnp.where(pos, s2, 1.0)), 0.0)  # sigma_tr, with a finite derivative at 0
    d = jnp.maximum(d, 0.0)
    kappa = jnp.clip(kappa, 0.0, kappa_cap(d, sigma_t_prime, kappa_max))
    # Jensen et al. 2001 Eq. 4 on a sphere (image at Kelvin's point) over the same on a plane; >= 0 (rounding can
    # leave a tiny negative value where the profile itself has underflowed: strong absorption, far pairs).
    ratio = _sphere_exitance(d, kappa, z_r, z_b, s) / _plane_exitance(d, z_r, z_b, s)
    return jnp.where(kappa > 0.0, jnp.maximum(ratio, 0.0), 1.0)


def kappa_cap(d, sigma_t_prime, kappa_max=KAPPA_MAX_ZR):
    """The largest curvature the ratio admits at chord ``d`` (mm), 1/mm: ``min(kappa_max sigma_t', 2 / d)`` (a
    sphere that holds the source well inside it, and the chord)."""
    return jnp.minimum(kappa_max * sigma_t_prime, 2.0 / jnp.maximum(d, 1e-300))


def curvature_coordinate(kappa, d, sigma_t_prime, kappa_max=KAPPA_MAX_ZR):
    """The continuous node index ``s (N_KAPPA - 1)`` of a pair on :func:`log_ratio_table`'s curvature axis, in ``[0,
    N_KAPPA - 1]``: ``u = kappa / kappa_cap(d)`` clipped to ``[0, 1]``, ``s = 1 - sqrt(1 - u)``. Broadcasts."""
    v = 1.0 - jnp.clip(kappa / kappa_cap(d, sigma_t_prime, kappa_max), 0.0, 1.0)
    # sqrt(1 - u), with a finite derivative at the cap (u = 1), where the clip zeroes it.
    root = jnp.where(v > 0.0, jnp.sqrt(jnp.where(v > 0.0, v, 1.0)), 0.0)
    return (1.0 - root) * (N_KAPPA - 1)


def log_ratio_table(r, sigma_a, sigma_s_prime, A, depth, kappa_max=KAPPA_MAX_ZR):
    """``log C`` on a distance grid and the :data:`N_KAPPA` curvature nodes (module docstring, "Tabulated").

    Args:
        r: ``(G, C)`` distances, mm (the profiles' grid per channel).
        sigma_a, sigma_s_prime, A: ``(C,)`` (:func:`curvature_ratio`).
        depth: ``(K, C)`` each incidence node's source depth in units of ``l_u``.
        kappa_max: the cap on the curvature in units of ``sigma_t'`` (:func:`kappa_cap`).

    Returns:
        ``(K, G, N_KAPPA, C)``: ``log C(r_g, u_j kappa_cap(r_g); depth_k)``, ``u_j = 1 - (1 - j / (N_KAPPA - 1))^2``
        (0 at ``j = 0``: the flat profile). Differentiable in the medium.
    """
    sigma_t_prime = sigma_a + sigma_s_prime
    s = jnp.linspace(0.0, 1.0, N_KAPPA)
    u = 1.0 - (1.0 - s) ** 2
    kappa = u[:, None] * kappa_cap(r, sigma_t_prime, kappa_max)[:, None, :]  # (G, N, C)
    ratio = curvature_ratio(r[None, :, None, :], kappa[None], sigma_a, sigma_s_prime, A, depth[:, None, None, :],
                            kappa_max)
    # Floored where the ratio vanishes (the antipode of a strongly absorbing sphere): log 0 would poison the mix.
    return jnp.log(jnp.maximum(ratio, 1e-300))
