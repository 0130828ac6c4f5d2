"""The renderer's BSSRDF kernels: the dipole (Jensen et al. 2001) and transport-accurate white Monte Carlo profiles
with an incidence-angle dependence.

The hierarchical and direct sums (:mod:`jaxsss.render.radiance`) add ``Phi_p R(|x - P_p|)`` over irradiance samples
``p``; a *kernel* says what ``Phi`` and ``R`` are:

- ``"dipole"``: ``Phi_p`` is the flux *entering* (exact Fresnel transmittance per light), ``R`` the dipole per entering
  flux, and the Hanrahan-Krueger single-scattering term is added at the shaded point (the pre-issue-17 renderer).
- ``"white"``: the white ("scaled") Monte Carlo profile of a half-space at normal incidence for the medium's
  ``(g, eta)`` from the white Monte Carlo *family* (:func:`jaxsss.mc.white_family.white_family_profile`; Kienle and
  Patterson 1996), which covers any ``g`` in [0, 0.95] and ``eta`` in [1, 1.6]: the one source of normal-incidence
  profiles. It holds *every* scattering order, single
  scattering included, so the separate single-scattering term is left out (counted once). Its normalisation is per
  *incident* photon with the specular reflection excluded, so ``Phi_p`` is the incident flux ``A_p sum_l E_lp`` and the
  entry Fresnel transmittance is already in the profile (multiplying by ``F_t`` again would count it twice).
- ``"white-oblique"``: the same at ``K`` incidence cosines ``mu_k`` (``1`` and :data:`KERNEL_MUS`, from the tables
  at :data:`OBLIQUE_MUS`): each sample's
  flux is split over the angle nodes by linear ("hat") weights in ``mu = cos(normal, to the light)``,
  ``Phi_pk = A_p sum_l h_k(mu_lp) E_lp``, and ``M_o(x) = sum_p sum_k Phi_pk R_k(|x - P_p|)``, where ``R_k`` is the
  white Monte Carlo profile for incidence ``mu_k`` averaged over azimuth about the point of entry
  (:mod:`jaxsss.render.make_oblique_tables`). Grazing light enters shallower and more of it comes back (at albedo
  0.96 and ``eta = 1`` about 1.5x as much per incident photon at ``mu = 0.1`` as at normal incidence): the dipole,
  which treats every light as if it fell along the normal, is 28-38% too dark at the terminator. At an index-matched
  boundary the light of each column is scaled so that the nodes' linear mix reflects the exact directional albedo
  at its cosine (:func:`albedo_correction`; Chandrasekhar's for ``g = 0``, the HG medium's by adding-doubling for
  ``g > 0``, :mod:`jaxsss.render.anisotropic_albedo`: the albedo is convex in ``mu``, so the mix alone was 0.4-1.7%
  too bright for skin1 under a point light, up to 4% at cos 0.3). Behind a dielectric boundary the same with the
  share that the boundary lets in and the half-space sends back out, by adding-doubling with the boundary: concave in
  ``mu`` (the transmittance falls to 0 at grazing incidence), so the mix alone under-reflected cos 0.25 by 20-30% at
  ``eta = 1.4``. The forward shift of
  an oblique profile (towards where the light travels) is averaged out: the kernel stays radial, so the hierarchical
  sum and its octree are unchanged. Diffuse indirect light enters with the cosine-weighted hemispherical average of
  the node weights.

Evaluation (``"white*"``). Per image the profiles are tabulated once per channel on a grid uniform in ``log(r
sigma_s)`` (:data:`GRID_PER_DECADE` nodes per decade from :data:`GRID_RHO_MIN` to :data:`GRID_RHO_MAX` optical
units) from the public :func:`~jaxsss.mc.white_family.white_family_profile` (normal incidence) and
:func:`~jaxsss.mc.white.white_mc_profile` (the oblique tables); each pair then interpolates ``log R`` linearly
there (no search: the index is computed). Below the grid ``R`` is held, above it ``log R`` continues along the last
interval. The near-field disc integral ``I_w = int_0^rho0 w(r) 2 pi r R(r) dr`` is a Gauss-Legendre quadrature in
``r = rho0 t^2`` (128 nodes; smooth even for the ``1/r`` single-scattering peak at the source). Everything is differentiable in
``sigma_a`` and ``sigma_s'`` through the family and the table model.

Oblique nodes (``"white-oblique"``). The oblique white Monte Carlo tables (:data:`OBLIQUE_MUS`,
``jaxsss/render/data``) exist for a few ``(g, n)`` only (:func:`oblique_pairs`). Node ``k`` of any other medium in the
family's range is the family's normal-incidence profile times the *oblique/normal ratio* of tabulated pairs
(:func:`oblique_sources`), in transport units (each source evaluated at the medium's ``sigma_a`` and ``sigma_s'``) and
with the entry Fresnel transmittance divided out (``T(n, mu) = 1 - F(n, mu)``)::

    R_k(r; g, n) = R_fam(r; g, n) T(n, mu_k)/T(n, 1) prod_j [R_obl,j(r) / R_fam(r; g_j, n_j) / (T(n_j, mu_k)/T(n_j, 1))]^w_j

with weights ``w_j`` (summing to 1): at an index-matched boundary (``n = 1``) linear in ``g`` between the ``n = 1``
pairs (g = 0 and 0.9); for ``n > 1`` linear in ``n`` between the ``n > 1`` pairs (g = 0: n = 1.33 and 1.4; held
beyond), whatever ``g``. At a tabulated pair the node *is* the oblique table. Beyond the last radial bin of a source's
oblique table its ratio is held (the family's diffusion tail carries the shape there). Measured at cos 0.5 and 0.1
(energy-weighted mean |relative error| over the plane; plane-integral ratio; ``sigma_a/sigma_s'`` 0.001 to 0.475):
leave-one-out on the shipped 2e5-photon tables, (0, 1.33) from (0, 1.4) 2.3-5.4%, totals 0.973-1.000, and (0, 1.4)
from (0, 1.33) 2.3-5.4%, totals 0.999-1.028; against 1e5-photon runs made for the check (noise 2.3-4.7%), (0, 1.2)
3.3-7.5%, (0, 1.55) 3.0-8.5%, (0.3, 1.3) 3.1-7.1%, (0.45, 1.45) 3.4-9.8%, (0.3, 1.0) 2.9-8.3%, (0.45, 1.0)
2.7-11.3%; worst (0, 1.1): 4.5-13.2%, totals 0.87-1.0 at strong absorption and grazing light (docs/path_tracer.md).
Normal incidence only (``"white"``) puts the plane integral of grazing light (cos 0.1) 1.2-2.2x off at every ``n > 1``
(the entry Fresnel loss alone) and 0.4-0.95x at ``n = 1``, so ``"auto"`` keeps the oblique nodes everywhere.

Curvature (``"white*"``). The profiles are a half-space's; on a convex object more light escapes, further from where
it entered (the 20 mm skin1 sphere gives 12-15% more red light under a sky at eta 1.4 than its flat limit, measured
in Mitsuba by scaling the coefficients). Each pair's profile is multiplied by the diffusion dipole's sphere-to-plane
ratio at the pair's curvature, estimated from the two normals (:mod:`jaxsss.render.curvature`; octree nodes carry
their area-weighted mean normal, :attr:`jaxsss.render.renderer.Prepared.ent_normal`), interpolated with the profile
from a table made once per image (:func:`white_kernel`, ``curvature=True``). The ratio is capped at a radius of
6.7 ``l_u`` at an index-matched boundary (:data:`jaxsss.render.curvature.KAPPA_MAX_ZR`); the marched kernels' orders
>= 2 take transport's correction ``Q`` of it (:mod:`jaxsss.render.curvature_correction`): from the light's side its
near part, ``min(Q, 1)``, capped at 5 ``l_u`` (:data:`jaxsss.render.curvature_correction.KAPPA_MAX_NEAR`), lit from
behind its far part, ``max(Q, 1)``, capped at 3.3 ``l_u``; behind a dielectric
boundary at 1.47 ``l_u`` with transport's near part, ``min(Q, 1)`` of Fresnel walks
(:mod:`jaxsss.render.dielectric_correction`). The dipole kernel stays flat (it is the pre-issue-17 renderer).

Passage (``"white*"``). A half-space takes in all the light that enters it; on a curved or thin part light entering
at grazing incidence can run through the object and leave without interacting. Pass 1 traces each light column's
refracted ray to where it leaves the mesh. ``"white"`` weights the incident flux by the probability of interacting
on the way, ``1 - exp(-sigma_t t)``; ``"white-oblique"`` keeps the whole column and multiplies each pair by the share
of a cut beam's light kept at its distance from the entry (a transport table: nearly all within the chord, far less
than ``exp(-sigma_t t)`` beyond; :mod:`jaxsss.render.passage`, "The cut beam").

Exit by distance (exit model ``"distance"``: ``eta = 1``, ``g = 0``). Light that has travelled several mean free
paths leaves less grazing than the half-space's whole exit ``X``: the sums carry each node's exitance weighted by a
tabulated amplitude ``c(d)`` too, which leaves by ``X phi(mu_o)`` (:mod:`jaxsss.render.exit_distance`).

The exit on a curved surface (exit model ``"multiple-curved"``: the first order marched apart, the kernel holding the
orders >= 2). A convex surface's light leaves less grazing than a half-space's: the sums carry each node's exitance
weighted by an amplitude ``c(kappa l_u, d / l_u)`` of the pair's curvature and distance too, which leaves by ``X_2
phi(mu_o)`` (:mod:`jaxsss.render.exit_curvature`).

The exit's current (exit model ``"multiple-current"``, kept by the scene plan for the lights behind the object):
light leaves brighter along its flow over the surface, away from where it entered. The sums carry each node's
current too, three rows of ``a(d / l_u)`` times the pair's tangential direction, which leave by ``t_o Y(mu_o)``
where the view looks along the flow (:mod:`jaxsss.render.exit_current`). With it the curvature ratio's far field is
corrected by transport (:mod:`jaxsss.render.curvature_correction`). Behind a dielectric boundary (exit model
``"refracted-current"``, kept by the plan for every light): every order's exitance leaves by the refracted exit and its
current by ``t_o Y(mu_o)`` of the Fresnel walks' table, with both signs (:mod:`jaxsss.render.dielectric_current`).

Which kernel a scene gets is the scene plan's decision (:func:`choose_bssrdf`): ``white-oblique`` wherever the
family covers ``(g, eta)``, the dipole with its reason otherwise (``eta`` or ``g`` outside the family, or per channel).
Until 2026-12-02 forward scattering (``g >= 0.5``) behind a dielectric boundary kept the dipole, a choice made from
index-matched renders; against Mitsuba under a sky and a sphere light at ``eta = 1.4`` the dipole was 13-30% too bright
in blue, the white kernels within 4.4% (docs/path_tracer.md, "Forward scattering behind a dielectric boundary"). The
oblique tables are looked up by :func:`white_table` only.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxsss.fresnel import snell_cosine
from jaxsss.medium import Medium
from jaxsss.render.curvature import (KAPPA_MAX_ZR, N_KAPPA, curvature_coordinate, kappa_cap, log_ratio_table,
                                     pair_curvature)
from jaxsss.render.exit_direction import anisotropic_exit_distribution

__all__ = ["BSSRDFS", "GRID_PER_DECADE", "KERNEL_MUS", "LIGHTS_BEHIND_MUS", "OBLIQUE_MUS", "PURE_ABSORBER_SCATTERING",
           "WhiteKernel", "albedo_correction",
           "chandrasekhar_h",
           "choose_bssrdf", "current_radiance", "directional_albedo", "exit_distribution", "exit_radiance_nodes",
           "exit_weights",
           "half_space_reflection", "row_parts", "hat_weights", "multiple_exit_distribution", "multiple_orders",
           "refracted_exit_distribution", "shift_ratio_table", "surface_tangents", "incident_flux", "oblique_dir",
           "oblique_pairs",
           "oblique_sources", "shift_reach", "KINKED_LIGHTS", "WHITE_DENSITY", "WHITE_DENSITY_KINKED", "WhiteSources",
           "white_kernel", "white_table", "white_tables"]

BSSRDFS = ("auto", "dipole", "white", "white-oblique")
"""The values of the ``bssrdf`` option (``"auto"``: the plan chooses)."""
OBLIQUE_DIR = Path(__file__).resolve().parent / "data"
OBLIQUE_MUS = (0.75, 0.5, 0.25, 0.1)
"""Incidence cosines (in air) of the oblique tables, besides normal incidence."""
KERNEL_MUS = (0.5, 0.1)
"""The oblique nodes the ``white-oblique`` kernel uses (each costs one profile per pair and channel). Two are enough:
against the skin1 reference all four gave mare_lit 0.061 / 0.045 / 0.043 and sums 0.960 / 0.981 / 0.995 in 11.7 s
(compile 103 s), these two 0.057 / 0.043 / 0.044 and 0.966 / 0.991 / 1.008 in 3.1 s (compile 42 s); docs/path_tracer.md."""
LIGHTS_BEHIND_MUS = (0.75, 0.5, 0.1)
"""The oblique nodes of the index-matched kernel that sums the light of lights behind the object (the plan's exit
current, :mod:`jaxsss.render.exit_current`, with the first order marched): a third oblique node, at 0.75. There the
light that crosses the object lights its far side, and the hat mix of the 0.5 and normal nodes put light entering
between them at two places on the far side instead of one: on chicken1's back-lit sphere light entering at 0.6-0.9
reached the far dark side at 0.57-0.64 (green) and 0.76-0.83 (red) of the sphere walk's, with the node 0.78-1.01 and
0.82-1.00 (docs/path_tracer.md, "A node at 0.75 for lights behind")."""
SHIFT_ALBEDO = (0.3, 0.5, 0.7, 0.8, 0.9, 0.97, 0.99)
SHIFT_RATIO = ((0.577, 0.660, 0.775, 0.898),
               (0.555, 0.637, 0.758, 0.880),
               (0.586, 0.670, 0.792, 0.898),
               (0.635, 0.715, 0.817, 0.911),
               (0.711, 0.776, 0.869, 0.936),
               (0.801, 0.858, 0.918, 0.970),
               (0.872, 0.926, 0.946, 0.973))
"""The forward shift of the profile of light entering at ``theta_t``, as a multiple of ``sin(theta_t) / sigma_t'``:
rows the albedo ``alpha'`` of :data:`SHIFT_ALBEDO`, columns the incidence cosines of :data:`OBLIQUE_MUS`. Measured
as the first moment of the exit positions in Monte Carlo (``jaxsss.mc.simulate`` with ``xy_edges``, 1e5 photons,
g = 0, eta = 1; ``python -m jaxsss.render.make_oblique_tables --shifts`` reprints it). Wang and Jacques' diffusion
estimate ``3 D sin theta_t`` would be 1 everywhere: it overestimates the shift of absorbing media at steep incidence
by up to 45%. Interpolated linearly in ``alpha'`` (held beyond the ends); in ``g`` with :data:`SHIFT_RATIO_FORWARD`
(:func:`shift_ratio_table`)."""
SHIFT_RATIO_FORWARD = {
    0.5: ((0.781, 0.823, 0.850, 0.870), (0.754, 0.783, 0.792, 0.791), (0.769, 0.793, 0.780, 0.753),
          (0.792, 0.798, 0.778, 0.748), (0.824, 0.820, 0.798, 0.752), (0.885, 0.860, 0.821, 0.770),
          (0.923, 0.884, 0.838, 0.779)),
    0.7: ((0.867, 0.880, 0.866, 0.825), (0.850, 0.829, 0.785, 0.716), (0.847, 0.825, 0.759, 0.665),
          (0.854, 0.818, 0.749, 0.657), (0.858, 0.830, 0.763, 0.659), (0.884, 0.853, 0.767, 0.671),
          (0.904, 0.870, 0.787, 0.686)),
    0.9: ((0.960, 0.960, 0.877, 0.738), (0.935, 0.896, 0.773, 0.611), (0.931, 0.862, 0.726, 0.563),
          (0.918, 0.854, 0.716, 0.555), (0.922, 0.847, 0.721, 0.565), (0.916, 0.858, 0.737, 0.586),
          (0.924, 0.863, 0.754, 0.602)),
    0.95: ((0.995, 0.983, 0.881, 0.715), (0.971, 0.912, 0.769, 0.583), (0.943, 0.873, 0.717, 0.536),
           (0.928, 0.857, 0.710, 0.532), (0.918, 0.853, 0.716, 0.541), (0.917, 0.864, 0.738, 0.566),
           (0.935, 0.864, 0.750, 0.587)),
}
""":data:`SHIFT_RATIO` for forward-scattering media, by ``g`` (the same measurement, ``--shifts --g G``; ``sigma_s'
= 1/mm``). Forward scattering moves the light further at steep incidence (g 0.9: 0.92-0.96 at cos 0.75, against
0.58-0.87 at g 0) and less at grazing incidence (0.56-0.74 at cos 0.1, against 0.90-0.97): there much of it leaves
near the entry point after a few small-angle deflections, forwards and grazing (:mod:`jaxsss.render.exit_direction`).
With the ``g = 0`` table the g09_sphere's terminator band was 11-19% too bright (docs/path_tracer.md, "Forward
scattering's exit direction"). Linear in ``g`` between these nodes and ``g = 0``: the g 0.5 and 0.7 tables lie within
3% of the line between g 0 and g 0.9 (measured after it; taken as nodes all the same)."""
CURVATURE_WHY = ("the surface's curvature per pair (jaxsss.render.curvature: a convex object lets more light out "
                 "than a half-space; flat surfaces are unchanged); light that crosses the object without interacting "
                 "(jaxsss.render.passage: each light's refracted ray traced to where it leaves; the light kept by "
                 "distance from the entry relative to that chord, a cut-beam transport table, or 1 - exp(-sigma_t "
                 "chord) for normal incidence only; grazing light on curved or thin parts)")
"""What the plan says of the white kernels' geometry terms: the curvature ratio (always on: 1 on a plane, one ratio
per pair) and the uncollided passage (always on: 1 where a light's refracted ray never leaves the object)."""
DIELECTRIC_WHY = ("behind the dielectric boundary the nodes' mix reflects the exact directional albedo, concave in the "
                  "cosine (jaxsss.render.anisotropic_albedo, adding-doubling), and the curvature ratio reaches spheres "
                  "of 1.47 l_u with transport's near part (jaxsss.render.dielectric_correction, Fresnel walks)")
"""What the plan adds for the white kernels at ``eta != 1``."""
WHITE_DENSITY = 2.0
"""The white kernels' irradiance samples per ``pi l_u^2`` (the paper's dipole: 1; the scene's ``density`` multiplies
both). The near field spreads each pair's ``w R`` over ``rho_0`` = four sample radii, about ``2 l_u``, and that blur
shows where ``R`` is narrow and the light has a kink: the terminator of an absorbing channel. Against Mitsuba (mare_lit;
band; docs/path_tracer.md, "Sample density"), density 1 -> 2: skin1 0.042 / 0.043 / 0.044 -> 0.042 / 0.038 / 0.039,
band 0.080 / 0.111 / 0.142 -> 0.087 / 0.095 / 0.119; ketchup's blue band 0.166 -> 0.121; the teapot 0.080 / 0.070 /
0.069 -> 0.077 / 0.065 / 0.063; potato (held out) 0.098 / 0.095 / 0.089 -> 0.082 / 0.070 / 0.055. It costs 15-50% of
the render's time. The base under environment maps and area lights; under a light with a sharp terminator,
:data:`WHITE_DENSITY_KINKED`."""
WHITE_DENSITY_KINKED = 3.0
"""The white kernels' base density under a light whose irradiance has a kink: a point, spot or directional light
(:data:`KINKED_LIGHTS`), whose terminator is sharp. There the near field's disc mean (``rho_0``, four sample radii)
carries lit light past the terminator in the channel of shortest ``l_u``, which sets the spacing: skin1's blue was
+20 to +32% at cos -0.1 to 0 in the zoomed view. Against Mitsuba (hierarchical, auto; band; docs/path_tracer.md, "The
near field's blur at a hard terminator"), density 2 -> 3: the skin1 sphere's band 0.065 / 0.083 / 0.114 -> 0.062 /
0.072 / 0.086, its zoomed view 0.043 / 0.086 / 0.152 -> 0.038 / 0.068 / 0.084, held-out potato 0.079 / 0.096 / 0.148
-> 0.058 / 0.066 / 0.100 and chicken1 (mean of four seeds) 0.076 / 0.087 / 0.178 -> 0.072 / 0.076 / 0.151; ketchup,
nearly single scattering in green, loses (mare_lit red 0.076 -> 0.082, green band 0.096 -> 0.116). It costs 10-25% of
the render's time. Environment maps and area lights have no such kink (their terminator is a penumbra): density 3
left their errors within 0.003 and cost 12-47%, so they keep :data:`WHITE_DENSITY`."""
KINKED_LIGHTS = ("point", "spot", "directional")
"""Light kinds whose irradiance has a kink at the terminator (:data:`WHITE_DENSITY_KINKED`)."""
MEASURED_DG = 0.45
"""How far in ``g`` from its oblique sources the transfer of the oblique/normal ratio was measured (module docstring)."""
PURE_ABSORBER_SCATTERING = 1e-9
"""The white kernels' floor on ``sigma_s' / sigma_a``: a medium that does not scatter (``sigma_s' = 0``, allowed) is
profiled at this ratio, a diffuse radiance ~1e-20 of the light's, instead of NaN from its infinite optical unit."""
GRID_RHO_MIN = 1e-3
GRID_RHO_MAX = 10**3.5
GRID_PER_DECADE = 40
"""Nodes per decade of the per-image profile grid in ``log(r sigma_s)``: linear interpolation of ``log R`` there is
within ~0.1% of the table model where ``R`` matters (module docstring)."""
_GL_X, _GL_W = np.polynomial.legendre.leggauss(128)  # the interpolant has kinks at its nodes: 48 was 0.7% off
_GL_T, _GL_W = 0.5 * (_GL_X + 1.0), 0.5 * _GL_W  # nodes and weights on [0, 1]


def oblique_dir(mu: float) -> Path:
    """The directory of the oblique tables at incidence cosine ``mu`` (file names as :mod:`jaxsss.mc.white`'s)."""
    return OBLIQUE_DIR / f"oblique_mu{mu:.2f}"


def oblique_pairs() -> list[tuple[float, float]]:
    """The ``(g, n)`` pairs that have a table at every incidence of :data:`OBLIQUE_MUS`."""
    from jaxsss.mc.white import available_white_tables

    sets = [set(available_white_tables(oblique_dir(mu))) for mu in OBLIQUE_MUS]
    return sorted(set.intersection(*sets))


def white_table(g: float, n: float, mu: float = 1.0):
    """The white Monte Carlo table for anisotropy ``g``, index ``n`` (ambient 1) and incidence cosine ``mu``, or
    None when there is none. The renderer's one lookup of oblique tables (``g`` and ``n`` rounded to 2 decimals, as
    the file names); the kernel takes its normal-incidence profile from the family instead (module docstring)."""
    from jaxsss.mc.white import available_white_tables, load_white_table

    directory = None if mu == 1.0 else oblique_dir(mu)
    key = (round(float(g), 2), round(float(n), 2))
    if key not in available_white_tables(directory):
        return None
    return load_white_table(*key, directory=directory)


def _linear(x: float, nodes) -> list[tuple[float, float]]:
    """``[(node, weight)]`` of piecewise-linear interpolation at ``x`` over sorted ``nodes``, held beyond the ends
    (zero weights dropped)."""
    nodes = sorted(nodes)
    if x <= nodes[0] or len(nodes) == 1:
        return [(nodes[0], 1.0)]
    if x >= nodes[-1]:
        return [(nodes[-1], 1.0)]
    k = max(i for i in range(len(nodes) - 1) if nodes[i] <= x)
    t = (x - nodes[k]) / (nodes[k + 1] - nodes[k])
    return [(a, w) for a, w in ((nodes[k], 1.0 - t), (nodes[k + 1], t)) if w > 0.0]


def oblique_sources(g: float, n: float) -> tuple[tuple[float, float, float], ...]:
    """``((g_j, n_j, w_j), ...)``: the tabulated oblique pairs whose oblique/normal ratio the oblique nodes of ``(g,
    n)`` take, with weights summing to 1 (module docstring): the pair itself when tabulated; at ``n = 1`` linear in
    ``g`` between the ``n = 1`` pairs; for ``n > 1`` linear in ``n`` between the ``n > 1`` pairs at the tabulated
    ``g`` nearest to ``g`` (held beyond the ends)."""
    pairs = oblique_pairs()
    key = (round(float(g), 2), round(float(n), 2))
    if key in pairs:
        return ((key[0], key[1], 1.0),)
    if key[1] == 1.0:
        return tuple((a, 1.0, w) for a, w in _linear(float(g), [p[0] for p in pairs if p[1] == 1.0]))
    above = [p for p in pairs if p[1] > 1.0]
    g0 = min({p[0] for p in above}, key=lambda a: abs(a - float(g)))
    return tuple((g0, b, w) for b, w in _linear(float(n), [p[1] for p in above if p[0] == g0]))


class WhiteSources(eqx.Module):
    """What :func:`white_kernel` needs besides the medium: the medium's ``(g, n)``, the oblique sources
    (:func:`oblique_sources`: ``(g_j, n_j, w_j)``) and their oblique tables, ``tables[j][k]`` at the kernel's
    ``k``-th oblique cosine (empty for the ``white`` kernel), and the white family's block of nodes around each
    ``(g, n)`` the kernel evaluates (``blocks[i]`` for ``block_keys[i]``,
    :func:`jaxsss.mc.white_family.block_operands`).

    Tables and blocks are arrays, so a compiled image takes them as arguments: its program does not carry the tables as
    constants (the whole family was 49 MB of HLO text), and one compilation serves every ``(g, n)`` of the same
    structure and shapes."""

    tables: tuple
    blocks: tuple
    g: float = eqx.field(static=True)
    n: float = eqx.field(static=True)
    sources: tuple = eqx.field(static=True)
    block_keys: tuple = eqx.field(static=True)

    def block(self, g: float, n: float):
        """The family's :func:`~jaxsss.mc.white_family.block_operands` at ``(g, n)``, one of :attr:`block_keys`."""
        return self.blocks[self.block_keys.index((g, n))]


def white_tables(g: float, n: float, oblique: bool, mus: tuple | None = None) -> tuple[tuple[float, ...], WhiteSources] | None:
    """``(mus, sources)`` for the ``white`` (normal incidence only) or ``white-oblique`` kernel (oblique cosines
    ``mus``, default :data:`KERNEL_MUS`), or None when ``(g, n)`` is outside the white Monte Carlo family."""
    from jaxsss.mc.white_family import covers

    if not covers(g, n):
        return None
    obl = tuple(float(m) for m in (KERNEL_MUS if mus is None else mus)) if oblique else ()
    with jax.ensure_compile_time_eval():  # cached: concrete arrays even when first asked for inside a trace
        return _white_tables(float(g), float(n), obl)


@functools.lru_cache(maxsize=16)
def _white_tables(g: float, n: float, obl: tuple) -> tuple[tuple[float, ...], WhiteSources]:
    """:func:`white_tables`, kept per ``(g, n, oblique nodes)`` (a render's geometry took 45 ms to gather them)."""
    from jaxsss.mc.white_family import block_operands, load_white_family

    load_white_family()  # host side, before any trace (white_kernel)
    src = oblique_sources(g, n) if obl else ()
    tables = tuple(tuple(white_table(a, b, mu) for mu in obl) for a, b, _ in src)
    keys = tuple(dict.fromkeys([(float(g), float(n))] + [(float(a), float(b)) for a, b, _ in src]))
    blocks = tuple(block_operands(a, b) for a, b in keys)
    return (1.0,) + obl, WhiteSources(tables, blocks, float(g), float(n), src, keys)


def _sources_text(g: float, n: float) -> str:
    src = oblique_sources(g, n)
    if len(src) == 1 and (src[0][0], src[0][1]) == (round(g, 2), round(n, 2)):
        return "this pair's oblique tables"
    pairs = " and ".join(f"(g={a:g}, n={b:g}) x {w:.2f}" for a, b, w in src)
    # Measured between the g sources and up to MEASURED_DG away from a single one (module docstring).
    gs = [a for a, _, _ in src]
    between = len(set(gs)) > 1 and min(gs) <= g <= max(gs)
    measured = (f"UNMEASURED this far from the sources' g (measured up to {MEASURED_DG:g} away)"
                if not between and min(abs(a - g) for a in gs) > MEASURED_DG + 1e-9 else
                "measured within 2-10% of held-out tables, up to 13% at n 1.1, module docstring")
    return f"the oblique/normal ratio of {pairs} (no oblique tables for this pair; the transfer is {measured})"


def choose_bssrdf(medium: Medium, request: str = "auto") -> tuple[str, str]:
    """``(kernel, reason)``: the BSSRDF kernel for ``medium`` and the plan's one-line reason.

    ``request`` is one of :data:`BSSRDFS`; ``"auto"`` takes ``white-oblique`` inside the white Monte Carlo family's
    range (``g`` in [0, 0.95], ``eta`` in [1, 1.6]), and the dipole otherwise. A white request outside the family's
    range is a ``ValueError`` naming the argument, its value and the range."""
    from jaxsss.mc.white_family import check_covered, covers

    if request not in BSSRDFS:
        raise ValueError(f"bssrdf={request!r} is not one of {', '.join(BSSRDFS)}")
    eta, g = np.asarray(medium.eta), 0.0 if medium.g is None else np.asarray(medium.g)
    if request == "dipole":
        return "dipole", "requested: the dipole plus the Hanrahan-Krueger single-scattering term"
    if eta.ndim or np.ndim(g) or eta.size != 1:
        if request != "auto":
            raise ValueError(f"bssrdf={request!r} needs scalar eta and g (one white Monte Carlo profile per medium)")
        return "dipole", ("WARNING: eta or g varies per channel; the white Monte Carlo profile needs one (g, eta): the "
                          "dipole (up to ~25% off transport)")
    g, eta = float(g), float(eta)
    if not covers(g, eta):
        if request != "auto":
            check_covered(g, eta, owner=f"bssrdf={request!r}")
        return "dipole", (f"WARNING: g={g:g}, eta={eta:g} is outside the white Monte Carlo family's range (g in [0, "
                          "0.95], eta in [1, 1.6]): the dipole plus single scattering (up to ~25% off transport)")
    exit_why = {"distance": ("Chandrasekhar's exit distribution, split by the distance each pair's light travelled "
                             "(jaxsss.render.exit_distance: far light leaves less grazing; eta = 1)"),
                "chandrasekhar": "Chandrasekhar's exit distribution (eta = 1)",
                "anisotropic": ("the forward-scattering exit distribution by the light's azimuth to the view "
                                "(jaxsss.render.exit_direction, eta = 1)"),
                "refracted": ("Chandrasekhar's exit distribution at the refracted cosines, through the Fresnel "
                              "boundary")}[exit_model_for(medium)]
    if g > 0.0 and eta != 1.0:
        # The forward-scattering exit (jaxsss.render.exit_direction) is tabulated at eta = 1 only.
        exit_why += (" (isotropic scattering's: the forward-scattering exit is tabulated for an index-matched "
                     "boundary only; at g 0.5 and 0.9, eta 1.4, under a sky and a sphere light within 4.4% of "
                     "Mitsuba in sum, the dipole 13-30% too bright in blue)")
    boundary = "" if eta == 1.0 else f"; {DIELECTRIC_WHY}"
    if request in ("auto", "white-oblique"):
        return "white-oblique", (
            f"white Monte Carlo family profile (g={g:g}, n={eta:g}) at normal incidence and at incidence cos "
            f"{', '.join(f'{m:g}' for m in KERNEL_MUS)} from {_sources_text(g, eta)}, shifted forward: every "
            f"scattering order, grazing light's stronger response (terminator); {exit_why}; {CURVATURE_WHY}{boundary}")
    return "white", (f"white Monte Carlo family profile (g={g:g}, n={eta:g}), normal incidence only (requested): every "
                     f"scattering order, but grazing light is treated as normal (terminator off); {exit_why}; "
                     f"{CURVATURE_WHY}{boundary}")


def exit_model_for(medium: Medium) -> str:
    """The exit distribution of a white kernel: at an index-matched boundary (``eta = 1``) ``"distance"`` for
    isotropic scattering (Chandrasekhar's, by the distance from the entry: :mod:`jaxsss.render.exit_distance`) and
    ``"anisotropic"`` (:mod:`jaxsss.render.exit_direction`) for ``g > 0``; else
    ``"refracted"`` (Chandrasekhar's at the refracted cosines, through the Fresnel boundary); see
    :func:`exit_radiance_nodes`."""
    if float(np.asarray(medium.eta)) != 1.0:
        return "refracted"
    g = 0.0 if medium.g is None else float(np.asarray(medium.g))
    return "anisotropic" if g > 0.0 else "distance"


def hat_weights(mu, mus, xp=jnp):
    """``(..., K)`` linear interpolation weights of ``mu`` (any shape) between the descending nodes ``mus``; held at
    the last node below it (and at the first above 1). The weights sum to 1.

    ``xp``: the array module, ``jax.numpy`` (traced, differentiable) or ``numpy`` for host-side geometry (eager JAX
    compiles every operation anew for each new shape: about 0.45 s of a sphere's ``prepare`` at a new resolution)."""
    nodes = xp.asarray(mus)
    if nodes.shape[0] == 1:
        return xp.ones(xp.shape(mu) + (1,))
    m = xp.clip(mu, nodes[-1], nodes[0])[..., None]
    upper, lower = nodes[:-1], nodes[1:]  # interval k: [lower_k, upper_k]
    t = (m - lower) / (upper - lower)  # 1 at upper, 0 at lower
    inside = (m <= upper) & (m >= lower)
    # Node j collects t from interval j - 1 ... written as: weight to the upper node and to the lower node.
    w_up = xp.where(inside, t, 0.0)
    w_lo = xp.where(inside, 1.0 - t, 0.0)
    w = xp.pad(w_up, [(0, 0)] * (w_up.ndim - 1) + [(0, 1)]) + xp.pad(w_lo, [(0, 0)] * (w_lo.ndim - 1) + [(1, 0)])
    # A mu on a node lies in two intervals: normalise.
    return w / xp.sum(w, axis=-1, keepdims=True)


def _diffuse_weights(mus):
    """``(K,)`` node weights of diffuse light: ``int_0^1 h_k(mu) 2 mu dmu`` (cosine-weighted hemisphere)."""
    t, w = np.polynomial.legendre.leggauss(64)
    mu = 0.5 * (t + 1.0)
    return jnp.sum(hat_weights(jnp.asarray(mu), mus) * (w * mu)[:, None], axis=0)


def incident_flux(mus, areas, light_cos, light_irradiance, indirect=None, texture=None, tangent=None,
                  tangent_weight=None):
    """``(N, K, C)`` incident flux of each irradiance sample split over the angle nodes ``mus``, W; with
    ``tangent`` ``(N, 4, K, C)``, the flux and the flux-weighted tangential travel directions.

    ``Phi_pk = A_p t_p (sum_l h_k(cos_lp) E_lp + d_k E_ind)``: no Fresnel factor (the white tables are per incident
    photon, entry transmittance included); ``d_k`` are the diffuse weights. ``V_pk = A_p t_p sum_l h_k(cos_lp) E_lp
    v_lp`` with ``tangent`` ``v`` ``(N, L, 3)``: each light's travel direction inside projected on the surface
    (length ``sin theta_t``; diffuse light has none), each weighted by ``tangent_weight`` ``(N, L, C)`` when given
    (the travel a short chord allows, :func:`jaxsss.render.passage.truncated_travel`). Other arguments as
    :func:`jaxsss.render.radiance.transmitted_flux`."""
    h = hat_weights(jnp.clip(light_cos, 0.0, 1.0), mus)  # (N, L, K)
    e = jnp.einsum("nlk,nlc->nkc", h, light_irradiance)
    if indirect is not None:
        e = e + _diffuse_weights(mus)[None, :, None] * indirect[:, None, :]
    scale = areas[:, None, None] * (1.0 if texture is None else texture[:, None, :])
    if tangent is None:
        return scale * e
    travel = light_irradiance if tangent_weight is None else light_irradiance * tangent_weight
    v = jnp.einsum("nlk,nlc,nlj->njkc", h, travel, tangent)
    return jnp.concatenate([(scale * e)[:, None], scale[:, None] * v], axis=1)


def surface_tangents(to_light, normals, eta):
    """``(N, L, 3)``: the travel direction inside of light from ``to_light`` ``(N, L, 3)``, projected on the surface
    with normals ``(N, 3)``: ``-(l - (l . n) n) / eta``, of length ``sin theta_t`` (Snell)."""
    ln = np.einsum("nlj,nj->nl", to_light, normals)
    return -(to_light - ln[..., None] * normals[:, None, :]) / eta


_H_X, _H_W = np.polynomial.legendre.leggauss(64)
_H_TH, _H_W = (_H_X + 1.0) * np.pi / 4.0, _H_W * np.pi / 4.0  # theta nodes and weights on (0, pi/2)
_MU_X, _MU_W = np.polynomial.legendre.leggauss(32)
_MU_T, _MU_W = 0.5 * (_MU_X + 1.0), 0.5 * _MU_W  # mu nodes and weights on (0, 1)


def chandrasekhar_h(mu, albedo):
    """Chandrasekhar's H-function of isotropic scattering, ``H(mu)`` for single-scattering albedo ``albedo`` in
    ``[0, 1)``; ``mu`` and ``albedo`` broadcast.

    Explicit form (Chandrasekhar 1960, Radiative Transfer, Eq. V.1.43 specialised to isotropic scattering):
    ``ln H(mu) = -(mu / pi) int_0^{pi/2} ln(1 - a theta cot theta) / (cos^2 theta + mu^2 sin^2 theta) dtheta``,
    64-node Gauss-Legendre (within 1e-6 of the iterated integral equation for ``a <= 0.99``)."""
    mu = jnp.asarray(mu)[..., None]
    a = jnp.asarray(albedo)[..., None]
    # The quadrature in the albedo's dtype (float32 stays float32).
    dtype = jnp.result_type(a, 0.0)
    th, w = jnp.asarray(_H_TH, dtype), jnp.asarray(_H_W, dtype)
    # H-function, explicit integral form.
    f = jnp.log1p(-a * th / jnp.tan(th)) / (jnp.cos(th) ** 2 + mu * mu * jnp.sin(th) ** 2)
    return jnp.exp(-mu[..., 0] / jnp.pi * jnp.sum(w * f, axis=-1))


def directional_albedo(mu, albedo):
    """``A(mu) = 1 - H(mu) sqrt(1 - a)``: the fraction of light incident at cosine ``mu`` that a semi-infinite
    isotropic index-matched medium of albedo ``a`` sends back (Chandrasekhar 1960, every order; the white tables at
    ``eta = 1``, ``g = 0`` reproduce it, ``tests/render/test_bssrdf.py``). ``mu`` and ``albedo`` broadcast. At
    ``a = 1`` (no absorption) ``A = 1`` with a zero derivative (the true one is infinite; a double ``where`` keeps it
    from becoming NaN)."""
    one_minus = 1.0 - jnp.asarray(albedo)
    s = jnp.where(one_minus > 0.0, jnp.sqrt(jnp.where(one_minus > 0.0, one_minus, 1.0)), 0.0)
    return 1.0 - chandrasekhar_h(mu, albedo) * s


def albedo_correction(mu, mus, albedo, g: float = 0.0, eta: float = 1.0):
    """``(..., C)`` factor on the light incident at cosine ``mu`` ``(...)`` so that the hat-weighted nodes ``mus``
    reflect the exact total: ``A(mu) / sum_k h_k(mu) A(mu_k)`` (:func:`directional_albedo` at the similarity
    ``albedo`` ``(C,)``; for a concrete anisotropy ``g > 0`` the Henyey-Greenstein medium's own, tabulated by
    adding-doubling, :func:`jaxsss.render.anisotropic_albedo.anisotropic_directional_albedo`; behind a dielectric
    boundary, a concrete ``eta != 1``, the share that the boundary lets in and the half-space sends back out,
    :func:`jaxsss.render.anisotropic_albedo.dielectric_directional_albedo`).

    At ``eta = 1`` ``A`` is convex in ``mu``, so the linear mix of the nodes overestimates it between them (by 0.4 /
    1.1 / 1.7% of skin1's red / green / blue light under a point light, up to 2-4% at cos 0.3) and underestimates it
    below the last node (the mix holds there). Behind a boundary ``A`` is concave (the Fresnel transmittance falls to 0
    at grazing incidence): at ``eta = 1.4`` the mix under-reflects cos 0.25 by 20-30% and over-reflects below the
    last node. 1 at every node. ``mu = None``: the same for diffuse light, ``2 int A(mu) mu dmu`` over the
    cosine-weighted node weights, ``(C,)``."""
    from jaxsss.render.anisotropic_albedo import (
        albedo_cosines,
        anisotropic_directional_albedo,
        dielectric_directional_albedo,
    )

    a = jnp.asarray(albedo)
    g = float(g)

    eta = float(eta)

    def curve(cos):  # (M,) concrete cosines -> (M, C)
        if eta != 1.0:
            return dielectric_directional_albedo(np.asarray(cos), jnp.broadcast_to(a, a.shape[-1:]), g, eta)
        if g == 0.0:
            return directional_albedo(jnp.asarray(cos)[:, None], a)
        return anisotropic_directional_albedo(np.asarray(cos), jnp.broadcast_to(a, a.shape[-1:]), g)

    nodes = curve(np.asarray(mus, dtype=np.float64))  # (K, C)

    def ratio(exact, mix):  # 1 where nothing is reflected (a = 0)
        return jnp.where(mix > 0.0, exact / jnp.where(mix > 0.0, mix, 1.0), 1.0)

    if mu is None:
        t, w = np.polynomial.legendre.leggauss(64)
        t = 0.5 * (t + 1.0)
        exact = jnp.sum((w * t)[:, None] * curve(t), axis=0)
        return ratio(exact, jnp.einsum("k,kc->c", _diffuse_weights(mus), nodes))
    # Exact directional albedo over the nodes' linear mix, on a grid of cosines that holds the nodes (the ratio has
    # kinks there) and is finer below 0.05 (H is steepest there), then linear in mu at each light column: within 2e-4
    # of the exact ratio everywhere (H at every column would cost 64 quadrature nodes each).
    grid = np.union1d(np.union1d(np.linspace(0.0, 1.0, 201), np.linspace(0.0, 0.05, 101)),
                      np.asarray(mus, dtype=np.float64))
    if g != 0.0 or eta != 1.0:  # the tables' own cosines too (the curve is linear between them)
        grid = np.union1d(grid, albedo_cosines(eta))
    on_grid = ratio(curve(grid), jnp.einsum("gk,kc->gc", hat_weights(jnp.asarray(grid), mus), nodes))
    mu = jnp.clip(jnp.asarray(mu), 0.0, 1.0)
    flat = jax.vmap(lambda col: jnp.interp(mu.reshape(-1), grid, col), in_axes=1, out_axes=1)(on_grid)
    return flat.reshape(mu.shape + on_grid.shape[-1:])


def half_space_reflection(mu_i, mu_o, albedo):
    """Chandrasekhar's exact reflection function of a semi-infinite, isotropically scattering, index-matched medium,
    every scattering order, in 1/sr (Chandrasekhar 1960, Radiative Transfer, chapter IV: a beam of flux ``pi F`` at
    ``mu_i`` is reflected as ``I_r(mu_o) = (a F / 4) mu_i H(mu_i) H(mu_o) / (mu_i + mu_o)``, and ``E = pi F mu_i``)::

        f_r(mu_i, mu_o) = a H(mu_i) H(mu_o) / (4 pi (mu_i + mu_o))

    ``mu_i``, ``mu_o``: incidence and view cosines in ``(0, 1]``, ``albedo`` ``a`` in ``[0, 1)``; all broadcast. The
    radiance reflected towards ``mu_o`` under irradiance ``E`` from direction ``mu_i`` is ``E f_r``; it integrates to
    :func:`directional_albedo` (``tests/render/test_bssrdf.py``). The exact half-space reference of
    :mod:`jaxsss.export.exact`."""
    mu_i, mu_o, a = jnp.asarray(mu_i), jnp.asarray(mu_o), jnp.asarray(albedo)
    # Chandrasekhar's reflection function, isotropic scattering.
    return a * chandrasekhar_h(mu_i, a) * chandrasekhar_h(mu_o, a) / (4.0 * jnp.pi * (mu_i + mu_o))


def exit_distribution(mu_o, mu_i, albedo):
    """``X(mu_o | mu_i)``: the radiance leaving a semi-infinite isotropic index-matched medium towards ``mu_o``, relative
    to a Lambertian exit of the same exitance, for light incident at ``mu_i`` (``int_0^1 X 2 mu_o dmu_o = 1``).

    From Chandrasekhar's exact reflection function ``f_r = (a / 4 pi) H(mu_o) H(mu_i) / (mu_o + mu_i)`` (every order):
    ``X = pi f_r / A(mu_i)`` with the directional albedo ``A(mu_i) = (a / 2) H(mu_i) int_0^1 H(mu) mu / (mu + mu_i)
    dmu``; ``a`` and ``H(mu_i)`` cancel, so ``X = H(mu_o) / (2 (mu_o + mu_i) int_0^1 H(mu) mu / (mu + mu_i) dmu)``.
    ``mu_o`` ``(Q,)``, ``mu_i`` ``(K,)``, ``albedo`` ``(C,)`` give ``(Q, K, C)``."""
    # The quadrature in the albedo's dtype (float32 stays float32).
    t, w = (jnp.asarray(v, jnp.result_type(albedo, 0.0)) for v in (_MU_T, _MU_W))
    mu_i = jnp.asarray(mu_i)
    h_t = chandrasekhar_h(t[:, None], albedo)  # (T, C)
    norm = jnp.einsum("t,tc,kt->kc", w, h_t, t[None, :] / (t[None, :] + mu_i[:, None]))  # (K, C)
    h_o = chandrasekhar_h(mu_o[:, None], albedo)  # (Q, C)
    return h_o[:, None, :] / (2.0 * (mu_o[:, None, None] + mu_i[None, :, None]) * norm[None])


def multiple_exit_distribution(mu_o, mu_i, albedo):
    """``X_2(mu_o | mu_i)``: the exit distribution of the orders >= 2 of a semi-infinite isotropic index-matched
    medium, relative to a Lambertian exit of the same exitance (``int_0^1 X_2 2 mu_o dmu_o = 1``).

    Chandrasekhar's reflection function less its first order, ``f_r - f_r,1 = (a / 4 pi) (H(mu_i) H(mu_o) - 1) /
    (mu_i + mu_o)``, normalised (32-node Gauss-Legendre). The first order alone leaves towards grazing views
    brightest (``1 / (mu_i + mu_o)``); what is left is flatter. ``mu_o`` ``(Q,)``, ``mu_i`` ``(K,)``, ``albedo``
    ``(C,)`` give ``(Q, K, C)``; where nothing but the first order is (``a = 0``) it is Lambertian."""
    t, w = jnp.asarray(_MU_T), jnp.asarray(_MU_W)
    h_i = chandrasekhar_h(jnp.asarray(mu_i)[:, None], albedo)  # (K, C)

    def shape(mu):
        # Chandrasekhar's reflection function without its first order, isotropic scattering.
        return (h_i[None] * chandrasekhar_h(mu[:, None], albedo)[:, None] - 1.0) / (
            mu[:, None, None] + jnp.asarray(mu_i)[None, :, None])

    norm = jnp.einsum("t,tkc->kc", 2.0 * w * t, shape(t))
    ok = norm > 1e-12
    return jnp.where(ok[None], shape(mu_o) / jnp.where(ok, norm, 1.0)[None], 1.0)


def refracted_exit_distribution(mu_o, mu_i, albedo, eta):
    """The exit distribution through a smooth dielectric boundary (``eta = n_inside / n_outside >= 1``), relative to
    a Lambertian exit of the same exitance (``int_0^1 Y 2 mu_o dmu_o = 1``)::

        Y(mu_o | mu_i) = F_t(mu_o) X(mu_t(mu_o) | mu_t(mu_i)) / int_0^1 F_t(c) X(mu_t(c) | mu_t(mu_i)) 2 c dc

    Chandrasekhar's :func:`exit_distribution` inside the medium, at the refracted cosines ``mu_t(mu) = sqrt(1 - (1 -
    mu^2) / eta^2)`` of the view and of the incidence, carried out by the Fresnel transmittance ``F_t`` and renormalised
    to the exitance (32-node Gauss-Legendre). At ``eta = 1`` it is ``X`` itself. The internal reflection's own
    blurring of the inside distribution is left out. It carries what a Lambertian exit cannot: light of a weakly
    scattering channel leaves a dielectric towards grazing views brighter (its low orders), that of a strongly
    scattering one darker. Against Mitsuba's skin1 sphere under a sky (eta 1.3 and 1.4) the Lambertian exit was
    6.0-7.4% too dark in blue at the limb and 2-4% too bright at the centre; with ``Y`` the error is flat across the
    disc (docs/path_tracer.md, "The exit through a dielectric boundary").

    ``mu_o`` ``(Q,)`` (outside), ``mu_i`` ``(K,)`` incidence cosines in air, ``albedo`` ``(C,)``, scalar ``eta``: ``(Q,
    K, C)``."""
    from jaxsss.render.radiance import _transmittance

    def inside(mu):
        # Snell: the refracted cosine inside (eta >= 1: no total internal reflection).
        return snell_cosine(mu, eta)[0]

    mu_k = inside(jnp.asarray(mu_i))

    def shape(mu):
        return _transmittance(eta, mu)[:, None, None] * exit_distribution(inside(mu), mu_k, albedo)

    # The quadrature in the albedos' dtype (float32 stays float32).
    t, w = (jnp.asarray(v, jnp.result_type(albedo, 0.0)) for v in (_MU_T, _MU_W))
    # Renormalised to the exitance: int_0^1 F_t X 2 c dc, (K, C).
    norm = jnp.einsum("t,tkc->kc", 2.0 * w * t, shape(t))
    return shape(mu_o) / norm[None]


class WhiteKernel(eqx.Module):
    """White Monte Carlo profiles of one material on a log grid, ``K`` incidence nodes (module docstring).

    ``log_R``: ``(K, G, C)`` log of the optical-unit profile ``R(rho) / sigma_s^2`` at ``rho_j = GRID_RHO_MIN 10^(j /
    GRID_PER_DECADE)``; ``sigma_s``: ``(C,)`` 1/mm; ``shift_length``: ``(K, C)`` mm, the forward shift of each
    node's profile per unit ``sin theta_t`` (None: radial profiles only). With a shift the flux of a sample or node is
    ``(4, K, C)``: the incident flux ``F_k`` and the flux-weighted tangential travel direction ``V_k`` (3 rows)."""

    log_R: jax.Array
    sigma_s: jax.Array
    shift_length: jax.Array | None = None
    # The curvature table (None: flat): (K (G - 1) (N_KAPPA - 1) C, 4) bilinear coefficients of log(R C) per cell,
    # sigma_t' (C,), each node's source depth (K, C) and the cap on the curvature in units of sigma_t' (a scalar)
    # (:func:`white_kernel`).
    curvature: tuple | None = None
    # The cut-beam passage (None: off): the loss table's cells (K, T - 1, X - 1, C, 8) (jaxsss.render.passage.
    # passage_cells), sigma_t' (C,), the floor of the chord (mm) and the kernel's nodes mu_k (K,); the flux then
    # carries two more rows, the flux of light columns with a finite chord W_k and W_k t.
    passage: tuple | None = None
    # The exit by distance (None: off): sigma_t' (C,) and the amplitude table c (K, D, C); the sums then carry 2K
    # nodes, each node's exitance then its exitance weighted by c(d) (jaxsss.render.exit_distance).
    exit_split: tuple | None = None
    # The exit on a curved surface (None: off; the orders >= 2 only): sigma_t' (C,) and the amplitude's bilinear
    # cells (jaxsss.render.exit_curvature.curved_amplitude_cells); the sums then carry 2K nodes, each node's exitance
    # then its exitance weighted by c(kappa, d).
    exit_curved: tuple | None = None
    # The exit's current (None: off; with exit_curved): sigma_t' (C,) and the normal-incidence amplitude a(d) (D, C)
    # (jaxsss.render.exit_current); the sums then carry 3K more rows, each node's exitance times a(d) and the
    # pair's tangential direction from the node's (shifted) entry (x, y, z).
    exit_current: tuple | None = None
    # An oblique beam's light ahead of its entry (None: off; with the curvature's transport correction): sigma_t'
    # (C,) and the factor's (G, B, B_2) rows (K, C, len(CORRECTION_KAPPA), D, 3) (jaxsss.render.oblique_azimuth);
    # each far pair of an oblique node is multiplied by G (1 + B cos phi + B_2 cos 2 phi), phi the pair's azimuth
    # about the entry from the travel.
    azimuth: tuple | None = None
    # The near field's mean flux density weighted by w R instead of w (a profile without the first order's peak:
    # :func:`multiple_orders`; :meth:`near_terms`).
    profile_weighted_near: bool = eqx.field(static=True, default=False)

    def profile(self, r, kappa=None):
        """``R_k(r)`` in 1/mm^2 at distances ``r`` (mm): ``(P,)`` gives ``(P, K, C)``; ``(P, K, C)`` is evaluated
        element by element. With the pairs' curvature ``kappa`` (1/mm, broadcast against ``(P, K, C)``) and a kernel
        that carries the curvature table, ``R_k(r) C(r, kappa)`` (:mod:`jaxsss.render.curvature`, "Tabulated")."""
        x0, dx = math.log(GRID_RHO_MIN), math.log(10.0) / GRID_PER_DECADE
        n_k, n_grid, n_c = self.log_R.shape
        if r.ndim == 1:
            r = jnp.broadcast_to(r[:, None, None], (r.shape[0], n_k, n_c))
        x = (jnp.log(jnp.maximum(r * self.sigma_s, GRID_RHO_MIN)) - x0) / dx  # (P, K, C)
        node = jnp.clip(jnp.floor(x), 0.0, n_grid - 2.0)
        t = x - node
        k = jnp.arange(n_k, dtype=jnp.int32)[None, :, None]
        c = jnp.arange(n_c, dtype=jnp.int32)[None, None, :]
        cell = k * (n_grid - 1) + node.astype(jnp.int32)
        if kappa is None or self.curvature is None:
            # One gather of (log R_i, log R_i+1 - log R_i) per element from the flattened (K, G - 1, C) intervals.
            slope = self.log_R[:, 1:] - self.log_R[:, :-1]
            table = jnp.stack([self.log_R[:, :-1], slope], axis=-1).reshape(-1, 2)
            y = table[cell * n_c + c]
            # Linear interpolation of log R in log(r sigma_s).
            log_r = y[..., 0] + t * y[..., 1]
        else:
            coefficients, sigma_t_prime, _, kappa_max = self.curvature
            u = curvature_coordinate(kappa, r, sigma_t_prime, kappa_max)
            j = jnp.clip(jnp.floor(u), 0.0, N_KAPPA - 2.0)
            w = u - j
            # One gather of the cell's four bilinear coefficients of log(R C) from the (K, G - 1, N - 1, C) cells.
            y = coefficients[(cell * (N_KAPPA - 1) + j.astype(jnp.int32)) * n_c + c]
            # Bilinear interpolation of log(R C) in (log(r sigma_s), the curvature coordinate).
            log_r = y[..., 0] + t * y[..., 1] + w * (y[..., 2] + t * y[..., 3])
        # R = sigma_s^2 R_optical.
        return jnp.exp(log_r) * self.sigma_s**2

    def value_shape(self, flux_shape, weighted: bool = False):
        """One pair's value: ``(R K, C)`` node rows (:attr:`rows_per_node` ``R``), or ``(C,)`` radiance when the sums
        pass exit ``weights`` (:meth:`pair`; ``(2, C)`` with the exit's current, the exitance's part and the
        current's, :meth:`rows_radiance`: the sums' result, from one complex value per pair and channel)."""
        k, c = flux_shape[-2:]
        if weighted:
            return (2, c) if self.exit_current is not None else (c,)
        return (self.rows_per_node * k, c)

    @property
    def split(self) -> bool:
        """Whether the sums carry a second exitance per node: the exit by distance or on a curved surface."""
        return self.exit_split is not None or self.exit_curved is not None

    @property
    def rows_per_node(self) -> int:
        """The sums' rows per incidence node: the exitance, its second exit's part (:attr:`split`), and the
        current's three components (:attr:`exit_current`)."""
        return 1 + int(self.split) + 3 * int(self.exit_current is not None)

    def _amplitude(self, delta, normals=None):
        """``(P, K, C)``: the second exit's amplitude per pair. By distance: ``c(d)`` at the pairs' distance ``d``
        from the (unshifted) entry (:func:`jaxsss.render.exit_distance.amplitude_at`). On a curved surface: ``c(kappa
        l_u, d / l_u)`` at the pair's curvature from ``normals = (n_x, n_P)`` (0 without them;
        :func:`jaxsss.render.exit_curvature.curved_amplitude_at`)."""
        d = jnp.sqrt(jnp.maximum(jnp.sum(delta * delta, axis=-1), 1e-300))[:, None, None]
        if self.exit_split is not None:
            from jaxsss.render.exit_distance import amplitude_at

            sigma_t_prime, table = self.exit_split
            return amplitude_at(table, d * sigma_t_prime)
        from jaxsss.render.exit_curvature import curved_amplitude_at

        sigma_t_prime, cells = self.exit_curved
        if normals is None:
            return jnp.zeros(d.shape[:1] + cells.shape[2:4], cells.dtype)
        # The pair's curvature in transport lengths (concave pairs: a plane's exit).
        kappa = jnp.maximum(pair_curvature(delta, normals[0][:, :3], normals[1]), 0.0)[:, None, None]
        return curved_amplitude_at(cells, kappa / sigma_t_prime, d * sigma_t_prime)

    def _current(self, delta, sources, normals=None):
        """``(P, 3, K, C)``: each pair's current per unit exitance, ``a(r / l_u) t``, about each node's (shifted)
        entry at distance ``r``: ``t`` the tangential part of the offset from that entry at the shaded point, unit
        length (:mod:`jaxsss.render.exit_current`); 0 without the shaded points' normals."""
        from jaxsss.render.exit_current import current_amplitude_at, tangential_unit

        sigma_t_prime, table = self.exit_current
        k, c = sources.shape[-2:]
        if normals is None:
            return jnp.zeros((delta.shape[0], 3, k, c), table.dtype)
        d = jnp.broadcast_to(delta[:, :, None, None], (delta.shape[0], 3, k, c))
        if self.shift_length is not None:
            d = d - sources[:, 1:4]
        r = jnp.sqrt(jnp.maximum(jnp.sum(d * d, axis=1), 1e-300))  # (P, K, C)
        # Fick's flow away from the entry, a(d / l_u) of the half-space's walk at normal incidence.
        t = jnp.moveaxis(tangential_unit(jnp.moveaxis(d, 1, -1), normals[0][:, None, None, :3]), -1, 1)
        return current_amplitude_at(table, r * sigma_t_prime)[:, None] * t

    def _split(self, v, delta, normals=None, sources=None):
        """``(P, K, C)`` -> ``(P, R K, C)`` (:attr:`rows_per_node` ``R``): each node's ``v``, then ``c v``
        (:meth:`_amplitude`), then its current ``v a t`` per component (:meth:`_current`); unchanged without the
        split."""
        if not self.split and self.exit_current is None:
            return v
        rows = [v, self._amplitude(delta, normals) * v] if self.split else [v]
        if self.exit_current is not None:
            current = self._current(delta, sources, normals)
            rows += [v * current[:, i] for i in range(3)]
        return jnp.concatenate(rows, axis=1)

    def _radiance(self, v, delta, weights, normals=None, sources=None):
        """``(P, C)``: the pairs' node values ``v`` ``(P, K, C)`` as radiance, ``sum_k v_k (W_k + c_k W_K+k)`` with
        the shaded points' exit ``weights`` ``(P, J, C)`` (:func:`exit_weights`; ``J = K`` without the split) and
        the amplitude ``c`` of :meth:`_amplitude`. Each ``v_k`` is used once: with the split's two uses XLA computed
        the whole pair twice (skin1's far sum took 1.8x as long). With the exit's current, complex: the exitance's
        part real, the current's imaginary."""
        k = v.shape[1]
        if not self.split and self.exit_current is None:
            return jnp.sum(v * weights, axis=1)
        w = weights[:, :k] + self._amplitude(delta, normals) * weights[:, k:2 * k] if self.split else weights[:, :k]
        if self.exit_current is None:
            return jnp.sum(v * w, axis=1)
        current = self._current(delta, sources, normals)
        # The current's rows, weighted by the view's tangential direction: a t . t_o Y_k; kept apart for the sign of
        # their sum per shaded point (current_radiance), as the imaginary part of one complex value per channel: two
        # real rows made XLA evaluate each pair's profile twice, once per row (the back-lit skin1 sphere's sum took
        # 1.15x as long); the sums unpack it (jaxsss.render.radiance.exitance_pairs).
        first = 1 + int(self.split)
        wc = sum(current[:, i] * weights[:, (first + i) * k:(first + 1 + i) * k] for i in range(3))
        return jnp.sum(jax.lax.complex(v * w, v * wc), axis=1)

    def rows_radiance(self, rows, weights):
        """``(Q, C)``: node rows ``(Q, R K, C)`` as radiance by the exit ``weights`` ``(Q, R K, C)``; ``(Q, 2, C)``
        with the exit's current, its exitance's part and its current's (:func:`row_parts`), as :meth:`pair` gives
        per pair."""
        if self.exit_current is None:
            return jnp.sum(rows * weights, axis=1)
        return row_parts(rows, weights, (1 + int(self.split)) * (rows.shape[1] // self.rows_per_node))

    def sources(self, flux):
        """What the sums gather per entity, from its flux: with a shift, ``(E, 4, K, C)`` incident flux ``F_k`` and
        travel ``V_k`` (:func:`incident_flux`, summed over the entity) become ``F_k`` and the mean forward shift
        ``s_k = shift_length V_k / F_k`` (mm), once per entity instead of once per pair; unchanged without one."""
        if self.shift_length is None:
            return flux
        f, v = flux[:, 0], flux[:, 1:4]  # (E, K, C), (E, 3, K, C)
        safe = jnp.where(f > 0, f, 1.0)
        out = [f[:, None], self.shift_length * v / safe[:, None]]
        if self.passage is not None:
            w, wt = flux[:, 4], flux[:, 5]
            # The share of the flux that runs along a finite chord, and its flux-weighted mean chord (mm).
            out += [(w / safe)[:, None], (wt / jnp.where(w > 0, w, 1.0))[:, None]]
        return jnp.concatenate(out, axis=1)

    def _distance(self, delta, sources):
        """``(r, F)``: the distance from each node's (shifted) point of entry, ``(P,)`` or ``(P, K, C)`` mm, and the
        incident flux ``(P, K, C)``, from the pairs' :meth:`sources`."""
        if self.shift_length is None:
            return jnp.sqrt(jnp.maximum(jnp.sum(delta * delta, axis=-1), 1e-300)), sources
        d = delta[:, :, None, None] - sources[:, 1:4]
        # Oblique incidence: the profile about the shifted point of entry.
        r = jnp.sqrt(jnp.maximum(jnp.sum(d * d, axis=1), 1e-300))
        if self.passage is None:
            return r, sources[:, 0]
        return r, sources[:, 0] * self._kept(delta, sources)

    def _kept(self, delta, sources):
        """``(P, K, C)``: the share of each pair's light that a cut beam keeps, ``1 - W/F loss(sigma_t' t, d / t)``
        at the distance ``d`` from the (unshifted) point of entry and the entity's mean chord ``t``
        (:func:`jaxsss.render.passage.passage_loss`)."""
        from jaxsss.render.passage import passage_loss

        table, sigma_t_prime, floor, _ = self.passage
        share, chord = sources[:, 4], sources[:, 5]
        d = jnp.sqrt(jnp.maximum(jnp.sum(delta * delta, axis=-1), 1e-300))[:, None, None]
        # The step at d = t is resolved no finer than the samples: the chord is floored at ``floor`` for x.
        safe = jnp.maximum(chord, floor)
        # Ahead of the entry along the light's travel (the shift's direction; 1/2 where there is none).
        shift = sources[:, 1:4]
        # (A sum of products, not an einsum: that lowers to 2^16 batched 1 x 3 matrix products, 4x the whole pair.)
        along = jnp.sum(delta[:, :, None, None] * shift, axis=1)
        norm = jnp.sqrt(jnp.maximum(jnp.sum(shift * shift, axis=1), 1e-300)) * d
        ahead = 0.5 * (1.0 + jnp.where(norm > 1e-12, along / jnp.where(norm > 1e-12, norm, 1.0), 0.0))
        # Cut beam: the light lost at d / t chords from the entry (transport table).
        return 1.0 - share * passage_loss(table, sigma_t_prime * chord, d / safe, ahead)

    def _curved(self, r, delta, normals):
        """``R_k(r)`` ``(P, K, C)``, times the curvature ratio of :mod:`jaxsss.render.curvature` when the kernel has
        one and the pairs' normals ``(n_x, n_P)`` (each ``(P, 3)``) are given, at each node's distance ``r`` (from
        its shifted point of entry: the ratio's dipole sits below it)."""
        if self.curvature is None or normals is None:
            return self.profile(r)
        # Half-space profile x the sphere-to-plane diffusion ratio of the pair's curvature.
        return self.profile(r, pair_curvature(delta, normals[0][:, :3], normals[1])[:, None, None])

    def _view_kept(self, delta, normals):
        """``(P, 1, C)`` or 1: the share of each pair's light that the eye's ray keeps when its refracted path inside
        runs along a finite chord (the cut beam, :mod:`jaxsss.render.passage`, by reciprocity: a beam entering at the
        shaded point against the eye's ray, cut at that chord, seen at the pair's distance; azimuthal mean). The
        shaded points' chord and inward tangent come as columns 3-6 of ``normals[0]`` (``(P, 7)``: normal, chord mm,
        tangent of length ``sin theta_t``; :attr:`jaxsss.render.renderer.Prepared.view_chord`); 1 without them or
        without the passage."""
        if self.passage is None or normals is None or normals[0].shape[-1] != 7:
            return 1.0
        from jaxsss.render.passage import passage_loss

        table, sigma_t_prime, floor, nodes = self.passage
        chord, tangent = normals[0][:, 3], normals[0][:, 4:7]
        d = jnp.sqrt(jnp.maximum(jnp.sum(delta * delta, axis=-1), 1e-300))
        mu = jnp.sqrt(jnp.clip(1.0 - jnp.sum(tangent * tangent, axis=-1), 0.0, 1.0))
        shape = (d.shape[0], nodes.shape[0], sigma_t_prime.shape[0])
        x = jnp.broadcast_to((d / jnp.maximum(chord, floor))[:, None, None], shape)
        tau = jnp.broadcast_to(chord[:, None, None] * sigma_t_prime, shape)
        # The azimuthal mean of the table (ahead 1/2): the half-plane split is the plane's, and at a sphere's limb
        # the entries lie behind the reversed view ray where the plane loses little (chicken1's red 0.088 per pixel
        # with the split, 0.079 with the mean, which is what the sphere walk checked; docs/path_tracer.md).
        loss = passage_loss(table, tau, x, 0.5)  # (P, K, C)
        # Linear in the refracted view cosine between the kernel's nodes.
        h = hat_weights(mu, nodes)  # (P, K)
        return 1.0 - jnp.sum(h[:, :, None] * loss, axis=1, keepdims=True)

    def _azimuth(self, delta, sources, normals):
        """``(P, K, C)``: each oblique node's factor ``G (1 + B cos phi + B_2 cos 2 phi)``
        (:mod:`jaxsss.render.oblique_azimuth`) at the pair's chord and curvature, ``phi`` the azimuth of the shaded
        point about the (unshifted) entry from the node's travel (its shift's direction), in the entry's tangent plane;
        1 for the normal node."""
        from jaxsss.render.oblique_azimuth import azimuth_factor

        sigma_t_prime, rows = self.azimuth
        d = jnp.sqrt(jnp.maximum(jnp.sum(delta * delta, axis=-1), 1e-300))[:, None, None]
        kappa = jnp.maximum(pair_curvature(delta, normals[0][:, :3], normals[1]), 0.0)[:, None, None]
        # The offset in the entry's tangent plane, and its cosine with each node's travel (0 where there is none).
        n_p = normals[1]
        tangential = delta - jnp.sum(delta * n_p, axis=-1, keepdims=True) * n_p
        shift = sources[:, 1:4]  # (P, 3, K, C)
        along = sum(tangential[:, i, None, None] * shift[:, i] for i in range(3))
        norm = jnp.sqrt(jnp.maximum(jnp.sum(tangential * tangential, axis=-1), 1e-300))[:, None, None] * jnp.sqrt(
            jnp.maximum(jnp.sum(shift * shift, axis=1), 1e-300))
        cos_phi = jnp.where(norm > 1e-12, along / jnp.where(norm > 1e-12, norm, 1.0), 0.0)
        return azimuth_factor(rows, kappa / sigma_t_prime, d * sigma_t_prime, cos_phi)

    def pair(self, delta, sources, normals=None, weights=None):
        """``(P, K, C)``: ``R_k(|delta - s_k|) F_k`` for offsets ``delta = x - P`` ``(P, 3)`` mm and the entities'
        :meth:`sources` (``s_k = 0`` without a shift), times the curvature ratio when ``normals = (n_x, n_P)`` are
        given (and the oblique nodes' azimuth when the kernel has it). The nodes stay apart: their exit distributions
        differ (:func:`exit_radiance_nodes`). With the shaded points' exit ``weights`` ``(P, J, C)``
        (:func:`exit_weights`), the pairs' radiance ``(P, C)`` instead (complex with the exit's current: the
        exitance's part real, the current's imaginary, :meth:`_radiance`)."""
        r, f = self._distance(delta, sources)
        v = self._curved(r, delta, normals) * f
        if self.azimuth is not None and normals is not None:
            v = v * self._azimuth(delta, sources, normals)
        view = self._view_kept(delta, normals)  # (P, 1, C) or 1
        if weights is None:
            return self._split(v * view, delta, normals, sources)
        # The eye's cut after the sum over the nodes (it is the same for all of them).
        cut = view[:, 0] if jnp.ndim(view) else view
        radiance = self._radiance(v, delta, weights, normals, sources)
        return radiance * jnp.asarray(cut, radiance.dtype)

    def near_terms(self, delta, sources, area, rho0, normals=None, weights=None):
        """A near pair's ``(point, w F, w A)``, each ``(P, K, C)``, with the near-field weight at the distance from
        the *shifted* entry point, so that the point part ``(1 - w) R`` vanishes where ``R`` peaks
        (:func:`jaxsss.render.radiance.exitance_near`); with exit ``weights`` (:meth:`pair`) the point part is the
        pairs' radiance ``(P, C)``. With :attr:`profile_weighted_near` the spread parts are ``w R F`` and ``w R A``
        instead: the disc's mean flux density weighted as the disc integral weights it (``w R``), which a profile
        with the first order's ``1 / r`` peak cannot afford (it would be the nearest sample's; the skin1 sphere's
        blue band 0.086 -> 0.126), and a profile without it gains from (the zoomed terminator's blue past the
        terminator +11.6 -> +8.4%; docs/path_tracer.md, "The first order in the object's geometry")."""
        from jaxsss.render.radiance import near_weight

        r, f = self._distance(delta, sources)
        f = f * self._view_kept(delta, normals)
        if r.ndim == 1:
            r = jnp.broadcast_to(r[:, None, None], f.shape)
        w = near_weight(r, rho0)
        curved = self._curved(r, delta, normals)
        point = (1.0 - w) * curved * f
        point = (self._split(point, delta, normals, sources) if weights is None
                 else self._radiance(point, delta, weights, normals, sources))
        # The disc's mean flux density: weighted by w, or by w R where R has no first-order peak (a kink in the light
        # within rho_0, a point light's terminator, is then where the profile puts it).
        q = w * curved if self.profile_weighted_near else w
        return point, q * f, q * area[:, None, None]

    def weighted_disc(self, rho0):
        """``(K, C)``: ``I_w = int_0^rho0 w(r) 2 pi r R_k(r) dr`` with the near-field weight ``w`` of
        :func:`jaxsss.render.radiance.near_weight` (substitution ``r = rho0 t^2``, 128-node Gauss-Legendre: within 3e-4 of a fine trapezoid rule)."""
        from jaxsss.render.radiance import near_weight

        t, w = jnp.asarray(_GL_T), jnp.asarray(_GL_W)
        r = rho0 * t * t
        # dr = 2 rho0 t dt.
        f = (near_weight(r, rho0) * 2.0 * jnp.pi * r * 2.0 * rho0 * t * w)[:, None, None] * self.profile(r)
        if self.exit_split is not None:
            from jaxsss.render.exit_distance import amplitude_at

            # The disc's exitance and its c(d)-weighted part (exit by distance).
            sigma_t_prime, table = self.exit_split
            c = amplitude_at(table, r[:, None, None] * sigma_t_prime)
            return jnp.concatenate([jnp.sum(f, axis=0), jnp.sum(c * f, axis=0)])
        if self.exit_curved is not None or self.exit_current is not None:
            # On a curved surface the disc leaves as on a plane (c = 0 within rho_0: jaxsss.render.exit_curvature),
            # and with no current (its light enters all around the shaded point: jaxsss.render.exit_current).
            return jnp.concatenate([jnp.sum(f, axis=0)] + [jnp.zeros_like(f[0])] * (self.rows_per_node - 1))
        return jnp.sum(f, axis=0)

    def disc(self, spread, rho0):
        """``(Q, R K, C)``: ``E_k I_w,k`` for the near field's mean incident flux density ``spread`` ``(Q, K, C)``,
        per row of :meth:`weighted_disc` (:attr:`rows_per_node` ``R``: then the second exit's parts, and the
        current's, which are 0)."""
        wd = self.weighted_disc(rho0)
        if self.rows_per_node == 1:
            return spread * wd
        k = spread.shape[1]
        return jnp.concatenate([spread * wd[i * k:(i + 1) * k] for i in range(self.rows_per_node)], axis=1)


def shift_ratio_table(g: float) -> np.ndarray:
    """``(len(SHIFT_ALBEDO), len(OBLIQUE_MUS))`` forward-shift ratios at anisotropy ``g``: linear between the
    measured tables (:data:`SHIFT_RATIO` at ``g = 0``, :data:`SHIFT_RATIO_FORWARD`), held beyond the last."""
    nodes = (0.0,) + tuple(SHIFT_RATIO_FORWARD)
    tables = np.stack([np.asarray(SHIFT_RATIO)] + [np.asarray(t) for t in SHIFT_RATIO_FORWARD.values()])
    # Linear in g between the measured tables.
    w = np.interp(float(g), nodes, np.arange(len(nodes), dtype=float))
    i = min(int(w), len(nodes) - 2)
    return (1.0 - (w - i)) * tables[i] + (w - i) * tables[i + 1]


def shift_reach(medium: Medium, bssrdf: str, mus: tuple = KERNEL_MUS) -> float:
    """How far (mm) the ``white-oblique`` kernel moves a profile's centre from its sample at most: the largest
    ``SHIFT_RATIO(alpha') sin(theta_t) / sigma_t'`` over the channels and the oblique nodes ``mus``, with ``sin
    theta_t <= 1 / eta``; 0 for the other kernels (NumPy, for the geometry-only pair lists).

    The hierarchical sum hands a sample to the near field (its disc average about the shifted entry point) when it
    lies within ``rho_0`` of the shaded point *plus this reach*: a sample farther than ``rho_0`` whose shifted
    entry point is close would otherwise be summed as a point at the profile's peak (on the ketchup sphere, whose
    red shifts by up to 3.75 mm against a ``rho_0`` of 2.7 mm, that made the hierarchical image 4% brighter in sum
    than the direct sum; docs/path_tracer.md)."""
    if bssrdf != "white-oblique":
        return 0.0
    sigma_a = np.atleast_1d(np.asarray(medium.sigma_a, dtype=np.float64))
    sigma_s_prime = np.atleast_1d(np.asarray(medium.sigma_s_prime, dtype=np.float64))
    sigma_t_prime = sigma_a + sigma_s_prime
    table = shift_ratio_table(0.0 if medium.g is None else float(np.max(np.asarray(medium.g))))
    ratio = [np.interp(sigma_s_prime / sigma_t_prime, SHIFT_ALBEDO, table[:, OBLIQUE_MUS.index(mu)]) for mu in mus]
    # Oblique incidence: the shift SHIFT_RATIO sin(theta_t) / sigma_t', at its largest sin(theta_t) = 1 / eta.
    return float(np.max(np.asarray(ratio) / sigma_t_prime) / max(float(np.max(np.asarray(medium.eta))), 1.0))


def _entry_ratio(n: float, mu: float) -> float:
    """``T(n, mu) / T(n, 1)``: the entry Fresnel transmittance at incidence cosine ``mu`` (in air) relative to normal
    incidence, ``T = 1 - F(n, mu)`` (NumPy: a constant of the traced kernel)."""
    from jaxsss.fresnel import fresnel_unpolarised

    t = 1.0 - fresnel_unpolarised(np.array([mu, 1.0]), n, xp=np)
    return float(t[0] / t[1])


def _log(x):
    # Floored where R underflows (strong absorption far out): log 0 would make the interpolation NaN.
    return jnp.log(jnp.maximum(x, 1e-300))


def white_kernel(medium: Medium, sources: WhiteSources, mus: tuple = (1.0,) + KERNEL_MUS,
                 shift: bool = False, curvature: bool = False, passage: float | None = None,
                 exit_split: bool = False, first_order: bool = False, exit_curved: bool = False,
                 exit_current: bool = False, curvature_transport: bool = False,
                 oblique_azimuth: bool = False) -> WhiteKernel:
    """Tabulate the profiles at incidence cosines ``mus`` (1, then the oblique nodes of ``sources``, from
    :func:`white_tables`) for ``medium`` on the grid (differentiable in ``sigma_a`` and ``sigma_s'``): normal incidence
    from the white Monte Carlo family, oblique nodes from ``sources`` (module docstring). ``shift``: shift the
    oblique profiles forward (:data:`SHIFT_RATIO`; the samples' flux then carries the travel directions). Jitted;
    the family is loaded here, outside the trace (its first load runs JAX code on concrete values). ``curvature``:
    the kernel carries the medium for the curvature ratio (:mod:`jaxsss.render.curvature`), applied to the pairs whose
    normals the sums pass, with each node's source at the depth of its refracted cosine. ``passage`` (mm; needs
    ``shift``): the kernel carries the cut-beam loss table (:mod:`jaxsss.render.passage`), resolved no finer than
    this distance (the samples' spacing), and the flux two more rows (:meth:`WhiteKernel.sources`); None: off.
    ``exit_split``: the sums carry each node's exitance and its ``c(d)``-weighted part
    (:mod:`jaxsss.render.exit_distance`). ``first_order``: the profiles keep orders >= 2 only (the renderer marches
    the first in the object's geometry, :mod:`jaxsss.render.first_order`; :func:`multiple_orders`). ``exit_curved``
    (with ``first_order``): the sums carry each node's exitance and its part weighted by the curved-exit amplitude
    ``c(kappa, d)`` of the pair (:mod:`jaxsss.render.exit_curvature`). ``exit_current`` (with ``exit_curved``, or
    alone behind a dielectric boundary): the sums carry each node's current too, three rows of ``a(d)`` times the
    pair's tangential direction from the node's entry (:mod:`jaxsss.render.exit_current`; behind the boundary the
    Fresnel walks' table, :mod:`jaxsss.render.dielectric_current`). ``curvature_transport`` (with ``curvature`` and
    ``first_order``; lights behind): the curvature ratio times the far part of its transport correction, ``max(Q,
    1)``, capped at the correction table's smallest sphere (:mod:`jaxsss.render.curvature_correction`); without it a
    kernel with ``curvature`` and ``first_order`` takes the near part, ``min(Q, 1)``, capped at 5 ``l_u``
    (:data:`jaxsss.render.curvature_correction.KAPPA_MAX_NEAR`). ``oblique_azimuth`` (with ``curvature_transport`` and
    ``shift``): the oblique nodes' far pairs times ``G (1 + B cos phi + B_2 cos 2 phi)``
    (:mod:`jaxsss.render.oblique_azimuth`)."""
    from jaxsss.mc.white_family import load_white_family
    from jaxsss.render.passage import passage_cells, passage_loss_table

    load_white_family()
    kernel = _white_kernel(medium, sources, mus, shift)
    if first_order:
        if sources.g != 0.0 or sources.n != 1.0:
            raise ValueError(f"white_kernel(first_order=True) needs g = 0 and eta = 1 (the orders >= 2's share and exit "
                             f"are isotropic, index-matched scattering's); got g={sources.g!r}, eta={sources.n!r}")
        kernel = multiple_orders(kernel, medium, tuple(mus))
    if passage is not None:
        if not shift:
            raise ValueError("white_kernel: passage=True needs shift=True (the cut beam's rows follow the travel's)")
        c = kernel.sigma_s.shape
        sigma_t_prime = jnp.broadcast_to(medium.sigma_a + medium.sigma_s_prime, c)
        albedo = jnp.broadcast_to(medium.alpha_prime, c)
        kernel = eqx.tree_at(lambda k: k.passage, kernel,
                             (passage_cells(passage_loss_table(albedo, mus)), sigma_t_prime,
                              jnp.asarray(passage, sigma_t_prime.dtype), jnp.asarray(mus, sigma_t_prime.dtype)),
                             is_leaf=lambda x: x is None)
    if exit_split:
        from jaxsss.render.exit_distance import distance_amplitude

        c = kernel.sigma_s.shape
        amplitude = distance_amplitude(mus, jnp.broadcast_to(medium.alpha_prime, c))
        kernel = eqx.tree_at(lambda k: k.exit_split, kernel,
                             (jnp.broadcast_to(medium.sigma_a + medium.sigma_s_prime, c), amplitude),
                             is_leaf=lambda x: x is None)
    if exit_curved:
        from jaxsss.render.exit_curvature import curved_amplitude, curved_amplitude_cells

        if not first_order or exit_split:
            raise ValueError("white_kernel(exit_curved=True) needs first_order=True and exit_split=False (the table is "
                             "the orders >= 2's, and the sums carry one second exit)")
        c = kernel.sigma_s.shape
        cells = curved_amplitude_cells(curved_amplitude(mus, jnp.broadcast_to(medium.alpha_prime, c)))
        kernel = eqx.tree_at(lambda k: k.exit_curved, kernel,
                             (jnp.broadcast_to(medium.sigma_a + medium.sigma_s_prime, c), cells),
                             is_leaf=lambda x: x is None)
    if exit_current:
        from jaxsss.render.exit_current import current_amplitude

        dielectric = sources.n != 1.0
        if not (exit_curved or dielectric) or (dielectric and (exit_split or first_order)):
            raise ValueError("white_kernel(exit_current=True) needs exit_curved=True at eta = 1 (the current's rows "
                             "follow the curved exit's) or, behind a dielectric boundary, every order and one exit "
                             f"(first_order and exit_split False); got eta={sources.n!r}, exit_curved={exit_curved}, "
                             f"first_order={first_order}, exit_split={exit_split}")
        c = kernel.sigma_s.shape
        kernel = eqx.tree_at(lambda k: k.exit_current, kernel,
                             (jnp.broadcast_to(medium.sigma_a + medium.sigma_s_prime, c),
                              current_amplitude(jnp.broadcast_to(medium.alpha_prime, c),
                                                medium.eta if dielectric else None)),
                             is_leaf=lambda x: x is None)
    if curvature_transport and not (curvature and first_order):
        raise ValueError("white_kernel(curvature_transport=True) needs curvature=True and first_order=True (the "
                         "correction is the orders >= 2's)")
    if oblique_azimuth:
        from jaxsss.render.oblique_azimuth import azimuth_rows

        if not (curvature_transport and shift):
            raise ValueError("white_kernel(oblique_azimuth=True) needs curvature_transport=True and shift=True (the "
                             "factor is taken over the shifted kernel with Q, about each node's travel)")
        c = kernel.sigma_s.shape
        kernel = eqx.tree_at(lambda k: k.azimuth, kernel,
                             (jnp.broadcast_to(medium.sigma_a + medium.sigma_s_prime, c),
                              azimuth_rows(tuple(mus), jnp.broadcast_to(medium.alpha_prime, c))),
                             is_leaf=lambda x: x is None)
    if not curvature:
        return kernel
    return eqx.tree_at(lambda k: k.curvature, kernel,
                       _curvature_table(kernel, medium, tuple(mus), curvature_transport, sources.n, first_order),
                       is_leaf=lambda x: x is None)


CURRENT_EXITS = ("multiple-current", "refracted-current")
"""The exit models whose sums carry the exit's current (:mod:`jaxsss.render.exit_current`): the index-matched orders >=
2 with the curved exit, and every order behind a dielectric boundary with the refracted exit."""

MULTIPLE_FLOOR = 0.02
"""Where the half-space's first order exceeds the tabulated profile (Monte Carlo noise and the tables' binning near
the entry, at strong absorption), the orders >= 2 keep this share of the profile (:func:`multiple_orders`)."""


@eqx.filter_jit
def multiple_orders(kernel: WhiteKernel, medium: Medium, mus: tuple) -> WhiteKernel:
    """``kernel`` with each node's profile less the half-space's first order at its cosine: ``R_k - R1_k``
    (:func:`jaxsss.render.first_order.first_order_profile`), index-matched, isotropic scattering (``g = 0``; checked
    by :func:`white_kernel`).

    The white tables are Monte Carlo estimates: at strong absorption (ketchup's blue, albedo 0.02) nearly all of
    ``R`` is first order, and ``R - R1`` is noise of either sign. It is floored at :data:`MULTIPLE_FLOOR` ``R`` and
    then scaled so that its plane integral is the profile's times the exact share of the orders >= 2, ``1 - A_1 /
    A`` (Chandrasekhar's directional albedo :func:`directional_albedo` and the first order's
    :func:`jaxsss.render.first_order.first_order_total`), at least 0.1%. A floor without the rescaling kept 25% of
    ketchup's blue twice; the difference of the two profiles' integrals on the grid was 3.6% of it off (the tables'
    first radial bin)."""
    from jaxsss.render.first_order import first_order_profile, first_order_total

    n_grid = kernel.log_R.shape[1]
    rho = GRID_RHO_MIN * 10.0 ** (np.arange(n_grid) / GRID_PER_DECADE)
    sigma_a = jnp.broadcast_to(jnp.asarray(medium.sigma_a, kernel.sigma_s.dtype), kernel.sigma_s.shape)
    albedo = kernel.sigma_s / (sigma_a + kernel.sigma_s)
    r = jnp.exp(kernel.log_R)  # (K, G, C), optical units
    r1 = jnp.stack([first_order_profile(rho, mu, albedo) for mu in mus])
    # The share of the orders >= 2 in the half-space's reflectance at each node, (K, 1, C).
    cos = jnp.asarray(mus)[:, None]
    total = directional_albedo(cos, albedo)
    share = jnp.maximum(1.0 - first_order_total(cos, albedo) / jnp.where(total > 0, total, 1.0), 1e-3)[:, None]
    # Plane integrals on the grid: int 2 pi rho^2 R dlog(rho).
    w = jnp.asarray(2.0 * np.pi * rho**2 * math.log(10.0) / GRID_PER_DECADE)[None, :, None]
    r2 = jnp.maximum(r - r1, MULTIPLE_FLOOR * r)
    # Both integrals over each node's peak (a constant): at albedo 1e-6 the profiles are ~1e-300 and the quotient's
    # derivative, over the integral squared, was NaN.
    peak = jax.lax.stop_gradient(jnp.max(r, axis=1, keepdims=True))
    peak = jnp.where(peak > 0, peak, 1.0)
    r2 = r2 * share * jnp.sum(w * r / peak, axis=1, keepdims=True) / jnp.sum(w * r2 / peak, axis=1, keepdims=True)
    return dataclasses.replace(kernel, log_R=_log(r2), profile_weighted_near=True)


@eqx.filter_jit
def _curvature_table(kernel: WhiteKernel, medium: Medium, mus: tuple, transport: bool = False,
                     n: float = 1.0, first_order: bool = False) -> tuple:
    """:attr:`WhiteKernel.curvature` for ``kernel``'s profiles of ``medium`` at incidence cosines ``mus``.
    ``transport`` (the marched kernels' orders >= 2 lit from behind): the diffusion ratio times the far part of its
    transport correction, ``max(Q, 1)``, capped at the correction table's smallest sphere
    (:mod:`jaxsss.render.curvature_correction`); without it, ``first_order`` (the marched kernels' orders >= 2 lit from
    the camera's side): times the near part, ``min(Q, 1)``, capped at
    :data:`jaxsss.render.curvature_correction.KAPPA_MAX_NEAR`. Behind a dielectric
    boundary (a concrete relative index ``n != 1``, every order): capped at the Fresnel table's smallest sphere, times
    ``min(Q, 1)`` of its walks (:mod:`jaxsss.render.dielectric_correction`)."""
    from jaxsss.render.curvature_correction import KAPPA_MAX_MARCHED, KAPPA_MAX_NEAR, log_correction_table
    from jaxsss.render.dielectric_correction import KAPPA_MAX_DIELECTRIC, dielectric_log_correction_table

    c = kernel.sigma_s.shape
    sigma_a, sigma_s_prime, A = (jnp.broadcast_to(jnp.asarray(v, kernel.sigma_s.dtype), c)
                                 for v in (medium.sigma_a, medium.sigma_s_prime, medium.A))
    sigma_t_prime = sigma_a + sigma_s_prime
    # Each node's source at its refracted cosine mu_t (in units of l_u): (K, C).
    eta = jnp.broadcast_to(jnp.asarray(medium.eta, kernel.sigma_s.dtype), c)
    depth = snell_cosine(jnp.asarray(mus)[:, None], eta)[0]
    n_grid = kernel.log_R.shape[1]
    r = GRID_RHO_MIN * 10.0 ** (jnp.arange(n_grid) / GRID_PER_DECADE)[:, None] / kernel.sigma_s  # (G, C) mm
    dielectric = float(n) != 1.0
    near = first_order and not (transport or dielectric)
    kappa_max = (KAPPA_MAX_DIELECTRIC if dielectric else KAPPA_MAX_MARCHED if transport else KAPPA_MAX_NEAR if near
                 else KAPPA_MAX_ZR)
    # log(R C) on the grid x the curvature nodes, (K, G, N, C); its bilinear coefficients per cell.
    f = kernel.log_R[:, :, None, :] + log_ratio_table(r, sigma_a, sigma_s_prime, A, depth, kappa_max)
    if transport or dielectric or near:
        # C Q: Q, transport's pencil beam on a sphere over the renderer's model of it, at the nodes' curvature in l_u.
        u = 1.0 - (1.0 - jnp.linspace(0.0, 1.0, N_KAPPA)) ** 2
        kappa_lu = u[:, None] * kappa_cap(r, sigma_t_prime, kappa_max)[:, None, :] / sigma_t_prime  # (G, N, C)
        coordinates = (r * sigma_t_prime, kappa_lu, mus, sigma_s_prime / sigma_t_prime)
        if dielectric:  # the near part (Q < 1) of the Fresnel walks
            f = f + jnp.minimum(dielectric_log_correction_table(*coordinates, float(n)), 0.0)
        elif near:  # the near part (Q < 1) of the index-matched orders >= 2, lit from the camera's side
            f = f + jnp.minimum(log_correction_table(*coordinates), 0.0)
        else:  # the far part (Q > 1) of the index-matched orders >= 2, lit from behind
            f = f + jnp.maximum(log_correction_table(*coordinates), 0.0)
    f00, f10, f01, f11 = f[:, :-1, :-1], f[:, 1:, :-1], f[:, :-1, 1:], f[:, 1:, 1:]
    coefficients = jnp.stack([f00, f10 - f00, f01 - f00, f11 - f10 - f01 + f00], axis=-1).reshape(-1, 4)
    return coefficients, sigma_t_prime, depth, jnp.asarray(kappa_max, sigma_t_prime.dtype)


@eqx.filter_jit
def _white_kernel(medium: Medium, sources: WhiteSources, mus: tuple, shift: bool) -> WhiteKernel:
    # The profiles' own argument checks are left out (the grid radii are positive by construction, and the medium's
    # coefficients were checked when the Medium was built): they are host callbacks, and a program with one is never
    # written to the persistent compilation cache.
    from jaxsss.mc.white import white_table_profile as white_mc_profile
    from jaxsss.mc.white_family import white_family_block_profile
    from jaxsss.render.passage import piecewise_linear

    n_grid = round(math.log10(GRID_RHO_MAX / GRID_RHO_MIN) * GRID_PER_DECADE) + 1
    rho = GRID_RHO_MIN * 10.0 ** (np.arange(n_grid) / GRID_PER_DECADE)
    g, n = sources.g, sources.n
    sigma_a = jnp.atleast_1d(medium.sigma_a)
    sigma_s_prime = jnp.broadcast_to(jnp.atleast_1d(medium.sigma_s_prime), sigma_a.shape)
    sigma_a = jnp.broadcast_to(sigma_a, sigma_s_prime.shape)
    # A pure absorber (sigma_s' = 0) sends no diffuse light back: its profile is taken at sigma_s' = 1e-9 sigma_a (a
    # radiance ~1e-20 of the light's) rather than on the grid's optical units 1 / sigma_s, which would be infinite.
    sigma_s_prime = jnp.maximum(sigma_s_prime, PURE_ABSORBER_SCATTERING * sigma_a)
    sigma_s = sigma_s_prime / (1.0 - g)
    # The grid is in optical units (1/sigma_s); the family takes mm.
    r = jnp.asarray(rho)[:, None] / sigma_s  # (G, C) mm

    families = {}

    def family(gg, nn):
        # One evaluation per distinct (g, n) on the grid.
        if (gg, nn) not in families:
            families[gg, nn] = _log(white_family_block_profile(r, sigma_a, sigma_s_prime, sources.block(gg, nn)))
        return families[gg, nn]

    log_normal = family(g, n)
    logs = [log_normal]
    for k, mu in enumerate(mus[1:]):
        log_ratio = 0.0
        for (g_j, n_j, w_j), tabs in zip(sources.sources, sources.tables):
            table = tabs[k]
            # Oblique/normal ratio of source j in transport units, its entry Fresnel transmittance divided out.
            q = _log(white_mc_profile(r, sigma_a, sigma_s_prime, table)) - family(g_j, n_j)
            # Held from the last grid node inside the oblique table's radial range (its last centre, optical units
            # of the table, c (1 - g_j) / (1 - g) in this grid's).
            last = (table.log_r_centres[-1] + math.log((1.0 - g_j) / (1.0 - g)) - math.log(GRID_RHO_MIN)) / math.log(
                10.0) * GRID_PER_DECADE
            i = jnp.minimum(jnp.arange(q.shape[0], dtype=jnp.int32), jnp.floor(last).astype(jnp.int32))
            log_ratio = log_ratio + w_j * (q[i] - math.log(_entry_ratio(n_j, mu)))
        # Oblique node: the family's normal profile x the sources' ratio x this medium's entry transmittance.
        logs.append(log_normal + log_ratio + math.log(_entry_ratio(n, mu)))
    log_R = jnp.stack(logs)
    length = None
    if shift:
        sigma_t_prime = sigma_a + sigma_s_prime
        # Linear in the albedo on the table's (concrete) nodes, held beyond them.
        ratio = jnp.stack([jnp.ones_like(sigma_t_prime)] + [  # normal incidence: no shift to scale
            piecewise_linear(sigma_s_prime / sigma_t_prime, SHIFT_ALBEDO,
                             shift_ratio_table(g)[:, OBLIQUE_MUS.index(mu)]) for mu in mus[1:]])
        # Oblique incidence: forward shift (SHIFT_RATIO) sin(theta_t) / sigma_t'.
        length = ratio / sigma_t_prime
    return WhiteKernel(log_R - 2.0 * jnp.log(sigma_s), sigma_s, length)


def exit_radiance_nodes(medium: Medium, exitance, cos_o, mus, model: str, azimuth=None, view_tangent=None):
    """Radiance towards the eye, ``(Q, C)`` W/(mm^2 sr), from the exitance of each incidence node ``(Q, K, C)``.

    ``model="chandrasekhar"`` (index-matched boundary, ``g = 0``): ``L = sum_k M_k X(mu_o | mu_k) / pi`` with
    :func:`exit_distribution` at the similarity albedo ``sigma_s' / (sigma_a + sigma_s')`` (exact for ``g = 0``).
    ``"distance"``: the same with ``exitance`` ``(Q, 2K, C)``, each node's exitance and its part weighted by the
    distance amplitude ``c(d)``, leaving by ``X`` and ``X phi``
    (:func:`jaxsss.render.exit_distance.exit_split_distribution`).
    ``"multiple"`` (index-matched, ``g = 0``, the first order marched apart: :mod:`jaxsss.render.first_order`): the
    orders >= 2 only, by :func:`multiple_exit_distribution`. ``"multiple-curved"``: the same with ``exitance`` ``(Q,
    2K, C)``, each node's exitance and its part weighted by the curved-exit amplitude, leaving by ``X_2`` and ``X_2
    phi`` (:func:`jaxsss.render.exit_curvature.curved_exit_distribution`). ``"multiple-current"``: the same with
    ``exitance`` ``(Q, 5K, C)``, the current's three components last, leaving by ``t_o Y_k`` (``view_tangent`` ``(Q,
    3)``) where the view looks along the light's flow and not at all against it (:func:`current_radiance`).
    ``"refracted-current"`` (a dielectric boundary): ``exitance`` ``(Q, 4K, C)``, the ``"refracted"`` rows and the
    current's, the latter with both signs (:mod:`jaxsss.render.dielectric_current`).
    ``"anisotropic"`` (index-matched, ``g > 0``): the same with the Monte Carlo exit distribution of a
    forward-scattering half-space, which depends on the azimuth between the light's travel and the view
    (:func:`jaxsss.render.exit_direction.anisotropic_exit_distribution`; ``azimuth`` ``(Q, H - 1)`` its
    :func:`~jaxsss.render.exit_direction.azimuth_harmonics`). ``"refracted"`` (a dielectric boundary): the same with
    :func:`refracted_exit_distribution`. ``"fresnel"``: the dipole renderer's Lambertian exit through the boundary,
    ``F_t(cos_o) sum_k M_k / (pi F_dt,ext)`` (:func:`jaxsss.render.radiance.exit_radiance`)."""
    w = exit_weights(medium, cos_o, mus, model, exitance.shape[1], exitance.shape[-1], azimuth, view_tangent)
    if model in CURRENT_EXITS:
        # The exitance's rows, then the current's (jaxsss.render.exit_current).
        parts = row_parts(exitance, w, (2 if model == "multiple-current" else 1) * len(mus))
        return current_radiance(parts[:, 0], parts[:, 1], along_only=model == "multiple-current")
    # The exit is linear in the nodes' exitance.
    return jnp.sum(exitance * w, axis=1)


def row_parts(rows, weights, j: int):
    """``(Q, 2, C)``: the rows of an exit with the current (:data:`CURRENT_EXITS`; ``(Q, J + 3K, C)``) as radiance by
    their exit ``weights``, the exitance's first ``j`` rows (``"multiple-current"``: ``2K``, ``"refracted-current"``:
    ``K``) and the current's ``3K`` apart (:func:`current_radiance`)."""
    return jnp.stack([jnp.sum(rows[:, :j] * weights[:, :j], axis=1),
                      jnp.sum(rows[:, j:] * weights[:, j:], axis=1)], axis=1)


def current_radiance(radiance, current, along_only: bool = True):
    """``(Q, C)``: the exit's radiance ``radiance`` plus the current's ``current`` (both ``(Q, C)`` W/(mm^2 sr),
    :func:`exit_weights`' two parts of an exit in :data:`CURRENT_EXITS`).

    ``along_only`` (the index-matched ``"multiple-current"``): the current only where it is positive, the view along
    the light's flow. Against the flow it is left out: there the kernels' exitance is short by about as much (a
    sphere's terminator seen from the light's side, :mod:`jaxsss.render.exit_current`). Else (``"refracted-current"``,
    behind a dielectric boundary) both signs, never below 0."""
    if along_only:
        # L = L_M + max(t_o . J Y, 0).
        return radiance + jnp.maximum(current, 0.0)
    # L = max(L_M + t_o . J Y, 0).
    return jnp.maximum(radiance + current, 0.0)


def exit_weights(medium: Medium, cos_o, mus, model: str, n_nodes: int, n_channels: int, azimuth=None,
                 view_tangent=None):
    """``(Q, J, C)``: the radiance towards the eye (W/(mm^2 sr)) per unit exitance (W/mm^2) of each of the ``J =
    n_nodes`` node rows, at exit cosines ``cos_o`` ``(Q,)``, so that :func:`exit_radiance_nodes` is ``sum_j M_j W_j``
    (models and arguments as there). The sums take them per shaded point and add each pair's nodes as radiance
    (:meth:`WhiteKernel.pair` with ``weights``). ``"multiple-current"``: ``"multiple-curved"``'s ``2K`` rows, then the
    current's ``3K``, ``t_o,i Y_k(mu_o)`` with ``view_tangent`` ``(Q, 3)`` the unit tangential part ``t_o`` of the
    direction to the eye (:func:`jaxsss.render.exit_current.current_exit_distribution`)."""
    from jaxsss.render.radiance import exit_radiance

    mu_o = jnp.clip(cos_o, 0.0, 1.0)
    if model == "fresnel":
        # The dipole's Lambertian exit through the boundary, the same for every node.
        w = exit_radiance(medium, jnp.ones(mu_o.shape + (n_channels,)), cos_o)
        return jnp.broadcast_to(w[:, None], (mu_o.shape[0], n_nodes, n_channels))
    sigma_s_prime = jnp.broadcast_to(medium.sigma_s_prime, (n_channels,))
    albedo = sigma_s_prime / (medium.sigma_a + sigma_s_prime)
    if model == "refracted":
        x = refracted_exit_distribution(mu_o, jnp.asarray(mus), albedo, jnp.asarray(medium.eta))
    elif model == "anisotropic":
        if azimuth is None:
            raise ValueError("exit_radiance_nodes(model='anisotropic') needs azimuth=(Q, H - 1) harmonics "
                             "(jaxsss.render.exit_direction.azimuth_harmonics)")
        x = anisotropic_exit_distribution(mu_o, azimuth, mus, albedo, 0.0 if medium.g is None else medium.g)
    elif model == "distance":
        from jaxsss.render.exit_distance import exit_split_distribution

        x = exit_split_distribution(mu_o, mus, albedo)
    elif model == "multiple":
        x = multiple_exit_distribution(mu_o, jnp.asarray(mus), albedo)
    elif model == "multiple-curved":
        from jaxsss.render.exit_curvature import curved_exit_distribution

        x = curved_exit_distribution(mu_o, mus, albedo)
    elif model in CURRENT_EXITS:
        from jaxsss.render.exit_current import current_exit_distribution
        from jaxsss.render.exit_curvature import curved_exit_distribution

        if view_tangent is None:
            raise ValueError(f"exit_weights(model={model!r}) needs view_tangent=(Q, 3), the unit tangential part "
                             "of the direction to the eye")
        if model == "multiple-current":
            y = current_exit_distribution(mu_o, mus, albedo)  # (Q, K, C)
            exit_rows = curved_exit_distribution(mu_o, mus, albedo)
        else:  # behind a dielectric boundary: every order, by the refracted exit
            eta = jnp.asarray(medium.eta)
            y = current_exit_distribution(mu_o, mus, albedo, eta)
            exit_rows = refracted_exit_distribution(mu_o, jnp.asarray(mus), albedo, eta)
        x = jnp.concatenate([exit_rows] + [view_tangent[:, i, None, None] * y for i in range(3)], axis=1)
    else:
        x = exit_distribution(mu_o, jnp.asarray(mus), albedo)
    # Exit by Chandrasekhar's reflection function, node by node.
    return jnp.broadcast_to(x / jnp.pi, (mu_o.shape[0], n_nodes, n_channels))
