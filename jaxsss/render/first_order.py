"""The first scattering order in the object's own geometry, and the half-space's first order it replaces.

The white kernels' profiles are a half-space's, every scattering order included. Where the medium's transport length
``l_u`` is a fair fraction of the object (ketchup's red: 4.1 mm on a 20 mm sphere; chicken1: 1.8-6.1 mm) much of
the light that reaches the eye has scattered once, and once is where a half-space is most wrong about a curved
object: the light's path to the scattering point and the eye's path from it cross the object's real surface, not a
plane (docs/path_tracer.md, "Where ketchup's red error is": single scattering is 48-67% of the sphere's red).

With an index-matched boundary (``eta = 1``: nothing refracts) and isotropic scattering (``g = 0``), the renderer then
splits the orders (:data:`jaxsss.render.plan.ScenePlan.first_order`):

- **Orders >= 2** stay with the white kernel, whose profiles lose their first order: ``R_k - R1_k`` for each
  incidence node (:func:`first_order_profile`, the half-space's first order at the node's cosine, azimuthally
  averaged about the entry as the oblique tables are), and they leave by Chandrasekhar's multiple-scattering part
  (:func:`jaxsss.render.bssrdf.multiple_exit_distribution`).
- **The first order** is marched along each shaded point's view ray inside the object
  (:func:`first_order_paths`, NumPy and Embree, once per image) and evaluated for any medium in JAX
  (:func:`first_order_radiance`, differentiable)::

      L1 = int_0^c sigma_s p(cos theta) E_l(s) exp(-sigma_t (s + t_l(s))) ds

  with ``s`` the distance along the view ray inside (chord ``c``), ``t_l(s)`` the length of the light's path inside
  the object to the point (every crossing of the mesh towards the light), ``E_l`` the light's irradiance there
  (inverse square; a spot's cone; an area light sampled), ``p`` the phase function and ``theta`` the angle between
  the light's travel and the way to the eye.

The near field of a profile without the first order's ``1 / r`` peak weights its mean flux density by the profile
(:attr:`jaxsss.render.bssrdf.WhiteKernel.profile_weighted_near`).

Against Mitsuba's references (hierarchical, auto; mare_lit, R / G / B; docs/path_tracer.md, "The first order in the
object's geometry"), before -> after: ketchup 0.083 / 0.042 / 0.044 -> **0.046 / 0.017 / 0.021** (its red was the
last committed scene over the 5% goal), terminator band 0.089 / 0.109 / 0.094 -> 0.058 / 0.046 / 0.063; skin1 0.036 /
0.034 / 0.036 -> 0.033 / 0.022 / 0.022; skin1 under a sphere light 0.041 / 0.036 / 0.037 -> 0.035 / 0.027 / 0.027;
held-out chicken1 0.077 / 0.069 / 0.067 -> 0.075 / 0.045 / 0.039 (blue's band 0.159 -> 0.072) and potato 0.056 /
0.049 / 0.046 -> 0.055 / 0.048 / 0.033. What is left is red around the terminator, too bright (ketchup +4 to +6%,
chicken1 +6 to +10% at cos -0.3 to 0.3): the orders >= 2 on a half-space's geometry.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxsss._config import to_device
from jaxsss.medium import Medium
from jaxsss.phase import hg_phase

__all__ = ["AREA_SAMPLES", "FIRST_ORDER_LIGHTS", "MARCH_NODES", "MARCH_S_MIN", "FirstOrderPaths",
           "diffuse_first_order_restore", "first_order_paths", "first_order_profile", "first_order_radiance",
           "first_order_total"]

MARCH_NODES = 48
"""Gauss-Legendre nodes in ``log s`` along each view ray (about eight per decade between :data:`MARCH_S_MIN` and a
40 mm chord): the integrand ``s exp(-sigma_t' s)`` is a bump a decade and a half wide in ``log s`` for any
``sigma_t``, so the march is accurate to well under 1% whatever the medium (test)."""
MARCH_S_MIN = 1e-4
"""mm: the march starts here (the first order from the first ``s_min`` is a fraction ``sigma_t s_min`` of it)."""
AREA_SAMPLES = 4
"""Directions per march node towards a sphere or rectangle light (a new set at each node: 4 x 48 per pixel)."""
FIRST_ORDER_LIGHTS = ("point", "spot", "directional", "sphere", "rectangle")
"""Light kinds whose first order is marched (an environment map would need its whole sky at every node)."""
_REENTRIES = 3  # crossings of the mesh followed towards a light beyond the first (a concave object's far parts)


class FirstOrderPaths(eqx.Module):
    """The geometry of the first order at ``Q`` shaded points, ``N`` march nodes each, ``M`` light columns (each
    delta light one, each area light :data:`AREA_SAMPLES`), ``C`` channels (:func:`first_order_paths`)."""

    s: jax.Array  # (Q, N) mm along the view ray inside
    weight: jax.Array  # (Q, N) mm: the quadrature weight of each node (0 where the chord is empty)
    t_light: jax.Array  # (Q, N, M) mm: the light's path inside the object to the node
    cos: jax.Array  # (Q, N, M): cosine between the light's travel and the way to the eye
    irradiance: jax.Array  # (Q, N, M, C) W/mm^2 on a plane facing the light (0 where blocked)


def _march_nodes(chord: np.ndarray, n: int = MARCH_NODES) -> tuple[np.ndarray, np.ndarray]:
    """``(s, w)`` ``(Q, n)``: Gauss-Legendre in ``log s`` on ``[MARCH_S_MIN, chord]`` (``ds = s dlog s``)."""
    x, w = np.polynomial.legendre.leggauss(n)
    lo = math.log(MARCH_S_MIN)
    hi = np.log(np.maximum(chord, MARCH_S_MIN))
    half = 0.5 * (hi - lo)[:, None]
    s = np.exp(lo + half * (x[None, :] + 1.0))
    return s, s * half * w[None, :]


def _inside_length(geometry, points: np.ndarray, to_light: np.ndarray, dist: np.ndarray | None):
    """``(t, open)``: the length (mm) of the path from each point inside the translucent mesh towards the light that
    runs inside it, and whether the path is open (no occluder, nothing left unresolved before the light)."""
    from jaxsss.render.rays import OBJECT_TRANSLUCENT

    n = len(points)
    total = np.zeros(n)
    open_ = np.ones(n, dtype=bool)
    # The paths still followed (their ids, origins, directions, limits and lengths so far), compacted at each crossing.
    active = np.arange(n)
    origin = np.asarray(points, dtype=np.float64)
    direction = np.asarray(to_light, dtype=np.float64)
    limit = np.full(n, np.inf) if dist is None else np.asarray(dist, dtype=np.float64)
    travelled = np.zeros(n)
    inside = True
    for _ in range(2 * _REENTRIES + 1):
        if not len(active):
            break
        hits = geometry.first_hit(origin, direction)
        t = np.where(hits.hit, hits.t, np.inf)
        beyond = travelled + t >= limit
        if inside:
            # Inside, the path ends at the mesh (or the light, inside the object: the whole way counts).
            total[active] += np.minimum(t, limit - travelled)
            stray = ~hits.hit | ((hits.obj != OBJECT_TRANSLUCENT) & ~beyond)
            open_[active[stray]] = False  # a hole in the mesh, or an occluder inside it
        else:
            blocked = hits.hit & ~beyond & (hits.obj != OBJECT_TRANSLUCENT)
            open_[active[blocked]] = False
        if inside and geometry.convex_alone:
            # Out of a lone convex mesh nothing is met again: the rest of the way is open.
            active = active[:0]
            break
        go_on = hits.hit & ~beyond & (hits.obj == OBJECT_TRANSLUCENT) & open_[active]
        step = t[go_on] + geometry.offset
        active, direction, limit = active[go_on], direction[go_on], limit[go_on]
        travelled = travelled[go_on] + step
        origin = origin[go_on] + step[:, None] * direction
        inside = not inside
    open_[active] = False  # still crossing after the last followed re-entry
    return total, open_


def _light_columns(light, points: np.ndarray, rng: np.random.Generator):
    """``(to_light (P, M, 3), distance (P, M) or None, irradiance (P, M, C))`` of one light at points inside the
    object, facing the light (no cosine): ``M = 1`` for a delta light, :data:`AREA_SAMPLES` for an area light."""
    from jaxsss.render.lights import _SAMPLERS, _one_light

    if light.kind in ("point", "spot", "directional"):
        to_light, dist, factor = _one_light(light, points)
        return to_light[:, None], None if dist is None else dist[:, None], factor[:, None]
    sampler = _SAMPLERS[light.kind]
    dirs, t_hit, radiance = sampler(dataclasses.replace(light, samples=AREA_SAMPLES), points, None, rng)
    return dirs, t_hit, radiance


def first_order_paths(scene, geometry, pos: np.ndarray, normal: np.ndarray, to_eye: np.ndarray,
                      n_channels: int, seed: int = 0) -> FirstOrderPaths:
    """Trace the first order's geometry at the shaded points (NumPy and Embree; once per image).

    Args:
        scene: the scene (its lights, all of :data:`FIRST_ORDER_LIGHTS`).
        geometry: its :class:`~jaxsss.render.rays.SceneGeometry` (translucent mesh first).
        pos, normal, to_eye: ``(Q, 3)`` the shaded points (mm), their normals and unit directions to the eye.
        n_channels: ``C``.
        seed: the area lights' sample stream.

    The view ray continues into the object along ``-to_eye`` (``eta = 1``) to where it next meets the mesh (the
    chord; 0 where it does not, a mesh with a hole). Each march node's path to each light column is followed through
    every crossing of the mesh up to :data:`_REENTRIES` re-entries; an occluder, a hole or more crossings leave the
    column dark.
    """
    from jaxsss.render.rays import OBJECT_TRANSLUCENT

    bad = [light.kind for light in scene.lights if light.kind not in FIRST_ORDER_LIGHTS]
    if bad:
        raise ValueError(f"first_order_paths: light kind {bad[0]!r} is outside the allowed kinds "
                         f"{', '.join(FIRST_ORDER_LIGHTS)}")
    q = len(pos)
    inward = -np.asarray(to_eye, dtype=np.float64)
    hits = geometry.first_hit(pos - geometry.offset * normal, inward)
    chord = np.where(hits.hit & (hits.obj == OBJECT_TRANSLUCENT), hits.t + geometry.offset, 0.0)
    s, w = _march_nodes(chord)
    w = np.where((chord > MARCH_S_MIN)[:, None], w, 0.0)
    points = (pos[:, None, :] + s[..., None] * inward[:, None, :]).reshape(-1, 3)
    rng = np.random.default_rng(seed)
    t_cols, cos_cols, e_cols = [], [], []
    for light in scene.lights:
        to_light, dist, irr = _light_columns(light, points, rng)
        m = to_light.shape[1]
        flat = to_light.reshape(-1, 3)
        length, open_ = _inside_length(geometry, np.repeat(points, m, axis=0), flat,
                                       None if dist is None else dist.reshape(-1))
        irr = np.broadcast_to(irr, to_light.shape[:2] + (irr.shape[-1],)).reshape(-1, irr.shape[-1])
        irr = np.where(open_[:, None], irr, 0.0)
        if irr.shape[-1] != n_channels:
            irr = np.broadcast_to(irr, (len(irr), n_channels))
        # The light travels along -to_light; the way to the eye is to_eye.
        cos = -np.einsum("pmj,pj->pm", to_light, np.repeat(np.asarray(to_eye), s.shape[1], axis=0))
        t_cols.append(np.where(open_, length, 0.0).reshape(q, -1, m))
        cos_cols.append(cos.reshape(q, -1, m))
        e_cols.append(irr.reshape(q, -1, m, n_channels))
    return FirstOrderPaths(to_device(s), to_device(w), to_device(np.concatenate(t_cols, axis=2)),
                           to_device(np.concatenate(cos_cols, axis=2)), to_device(np.concatenate(e_cols, axis=2)))


def first_order_radiance(medium: Medium, paths: FirstOrderPaths):
    """``(Q, C)`` W/(mm^2 sr): the first order towards the eye at the shaded points (module docstring), a JAX
    function of the medium (``sigma_s = sigma_s' / (1 - g)``, Henyey-Greenstein phase)."""
    g = 0.0 if medium.g is None else medium.g
    sigma_s = medium.sigma_s_prime / (1.0 - g)
    sigma_t = medium.sigma_a + sigma_s
    phase = hg_phase(paths.cos[..., None], g)
    # L1 = int sigma_s p E exp(-sigma_t (s + t_l)) ds.
    decay = jnp.exp(-sigma_t * (paths.s[..., None, None] + paths.t_light[..., None]))
    inner = jnp.sum(phase * paths.irradiance * decay, axis=2)  # (Q, N, C)
    return sigma_s * jnp.sum(paths.weight[..., None] * inner, axis=1)


# The half-space's first order (the part of the white profiles the march replaces).
_X_GRID = 10.0 ** np.arange(-7.0, 3.0 + 1e-9, 1.0 / 40.0)  # mean free paths
_FIRST_BIN = 1e-2  # optical units: the white tables' first radial bin (jaxsss.mc.white.R_FIRST_EDGE)


@functools.lru_cache(maxsize=16)
def _first_order_shape(mu: float, g: float) -> tuple[np.ndarray, np.ndarray]:
    """``(F (X,), cumulative (X,))`` on :data:`_X_GRID` (mean free paths, ``sigma_t = 1``): the first-order exitance
    of a half-space per incident photon per unit area for unit albedo, light entering at cosine ``mu`` (index-matched),
    averaged over azimuth about the point of entry, and its flux within ``x``, ``int_0^x 2 pi x' F dx'``."""
    s_log = np.linspace(math.log(1e-10), math.log(60.0), 700)
    s = np.exp(s_log)
    ws = s * (s_log[1] - s_log[0])
    ws[[0, -1]] *= 0.5
    # The azimuth about the entry on [0, pi]: the integrand is even in it (the incident plane is a mirror plane).
    phi = (np.arange(48) + 0.5) * np.pi / 48
    sn = math.sqrt(max(0.0, 1.0 - mu * mu))
    px, pz = s * sn, s * mu  # the scattering point, depth pz below the surface
    out = np.empty(len(_X_GRID))
    for j0 in range(0, len(_X_GRID), 8):
        x = _X_GRID[j0:j0 + 8, None, None]
        dx = x * np.cos(phi)[None, :, None] - px
        dy = x * np.sin(phi)[None, :, None]
        d = np.sqrt(dx * dx + dy * dy + pz * pz)
        c = (sn * dx - mu * pz) / d  # the incident direction . the way out
        phase = np.asarray(hg_phase(c, g))
        # Interaction at s, scattering towards the exit point, escape: exp(-s) p exp(-d) cos_exit / d^2.
        f = np.exp(-s - d) * phase * pz / d**3
        out[j0:j0 + 8] = np.mean(np.sum(f * ws, axis=-1), axis=-1)
    lx = np.log(_X_GRID)
    integrand = 2.0 * np.pi * _X_GRID**2 * out
    cumulative = np.pi * _X_GRID[0]**2 * out[0] + np.concatenate(
        [[0.0], np.cumsum(0.5 * (integrand[1:] + integrand[:-1]) * np.diff(lx))])
    return out, cumulative


def first_order_total(mu, albedo):
    """The half-space's first-order reflectance per incident photon at cosine ``mu`` (index-matched, ``g = 0``):
    ``(a / 2) (1 - mu ln((1 + mu) / mu))`` (Chandrasekhar 1960; :func:`first_order_profile` integrates to it).
    ``mu`` and ``albedo`` broadcast."""
    mu = jnp.asarray(mu)
    safe = jnp.where(mu > 0.0, mu, 1.0)
    # Single scattering's reflectance: (a / 2) int_0^1 mu' / (mu + mu') dmu'.
    return 0.5 * jnp.asarray(albedo) * (1.0 - jnp.where(mu > 0.0, safe * jnp.log((1.0 + safe) / safe), 0.0))


def diffuse_first_order_restore(albedo):
    """``(C,)``: ``A_d / (A_d - A1_d)``, diffuse light's total reflectance (every order) over that of its orders >= 2,
    for albedos ``(C,)`` (index-matched, ``g = 0``; 1 where nothing is reflected). Diffuse light (the occluders' and the
    object's own bounce) is not marched: it enters the orders >= 2 profiles times this factor, which gives back its
    first order's share of the light (a fifth at albedo 1, most of it at a low albedo), placed as the orders >= 2
    place theirs. ``A_d = 2 int A(mu) mu dmu`` (:func:`jaxsss.render.bssrdf.directional_albedo`), ``A1_d`` the same of
    :func:`first_order_total`."""
    from jaxsss.render.bssrdf import directional_albedo

    a = jnp.atleast_1d(jnp.asarray(albedo))
    t, w = np.polynomial.legendre.leggauss(64)
    t, w = jnp.asarray(0.5 * (t + 1.0))[:, None], jnp.asarray(w * 0.5 * (t + 1.0))[:, None]
    # The cosine-weighted hemispherical means of every order and of the first: 2 int f(mu) mu dmu.
    every = jnp.sum(w * directional_albedo(t, a), axis=0)
    first = jnp.sum(w * first_order_total(t, a), axis=0)
    rest = every - first
    return jnp.where(rest > 0.0, every / jnp.where(rest > 0.0, rest, 1.0), 1.0)


def first_order_profile(rho, mu: float, albedo, g: float = 0.0):
    """The half-space's first order ``R1(rho) / sigma_s^2`` in optical units (``rho = r sigma_s``), per incident
    photon at cosine ``mu`` (index-matched), averaged over azimuth about the entry; ``rho`` ``(G,)``, ``albedo``
    ``(C,)`` (differentiable) give ``(G, C)``. Below the white tables' first bin (``rho < 0.01``) it is held at its
    mean over that disc, as the tables hold their profiles there."""
    from jaxsss.render.passage import piecewise_linear

    f, cumulative = _first_order_shape(float(mu), float(g))
    a = jnp.asarray(albedo)[None, :]
    log_grid = np.log(_X_GRID)
    rho = jnp.asarray(rho)[:, None]

    def at(table, x):
        # Linear in log x on the (concrete) grid, held below it and 0 beyond it (a few values per channel: one
        # vectorised step, jaxsss.render.passage.UNROLL_MIN_SIZE, where jnp.interp traced a binary-search scan).
        log_x = jnp.log(x)
        inside = piecewise_linear(log_x, log_grid, np.log(np.maximum(table, 1e-300))[:, None])
        return jnp.exp(jnp.where(log_x > log_grid[-1], -700.0, inside))

    # In mean free paths x = rho sigma_t / sigma_s = rho / a: R1 = F(rho / a) / a.
    point = at(f, rho / a) / a
    # The disc's mean over rho < 0.01: a C(0.01 / a) / (pi 0.01^2).
    disc = a * at(cumulative, _FIRST_BIN / a) / (jnp.pi * _FIRST_BIN**2)
    return jnp.where(rho < _FIRST_BIN, disc, point)
