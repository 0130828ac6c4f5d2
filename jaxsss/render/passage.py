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

**The cut beam** (white-oblique kernel, :func:`passage_loss`). Weighting a whole column by ``P_int`` spreads the cut
evenly over the profile; transport does not. A pencil beam whose first flight is cut at ``t`` keeps almost all of the
half-space's light within about ``t`` of its entry (the light there comes from the early interactions) and loses far
more than ``exp(-sigma_t t)`` beyond it (the light there comes from the photons that travelled on): a walk on
ketchup's red at cos 0.1 (chord 4 mm on the 20 mm sphere, ``P_int`` 0.62) keeps 0.99 / 0.95 / 0.64 / 0.24 / 0.20 at
0.75 / 2.5 / 4 / 6.25 / 8.75 mm (``benchmarks/curvature_transport.py``, ``half_space_cut``). So the white-oblique
kernel takes the whole column and multiplies each pair by the share kept at its distance ``d`` from the entry,
``1 - loss(tau, d / t, ahead)``, from a table made by :func:`cut_beam_tallies` (index-matched isotropic half-space,
1e6 photons per node, ``python -m jaxsss.render.passage --regenerate``, 46 s) over the incidence node
(:data:`PASSAGE_MUS`), the similarity albedo, ``tau = sigma_t' t`` and ``x = d / t``, behind and ahead of the entry
along the light's travel. Octree nodes carry the flux-weighted mean chord of their columns (two more flux rows,
:meth:`jaxsss.render.bssrdf.WhiteKernel.sources`). For ``g > 0`` the table is used in the similarity medium (``tau =
sigma_t' t``), and for ``eta > 1`` as it is (refraction makes the chords long there). Against Mitsuba (mare_lit;
far dark side, cos -1 to -0.3 to the light): ketchup 0.084 / 0.040 / 0.046 -> 0.082 / 0.039 / 0.047, its red far side
+33% -> -0.2%; the held-out chicken1 sphere 0.117 / 0.086 / 0.077 -> 0.108 / 0.081 / 0.077 (its red far side stays
+32%: the curvature ratio's far field, not the cut).

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

import functools
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from jaxsss.fresnel import refract, snell_cosine

__all__ = ["CUT_MIN_LOSS", "PASSAGE_ALBEDO", "PASSAGE_FLOOR", "PASSAGE_MUS", "PASSAGE_TAU", "PASSAGE_X",
           "cut_beam_tallies", "cut_matters", "entry_chords", "generate_passage_table", "interaction_probability",
           "load_passage_table", "node_interval", "passage_cells", "passage_loss", "passage_loss_table",
           "piecewise_linear", "truncated_travel", "view_chords"]

PASSAGE_MUS = (1.0, 0.75, 0.5, 0.1)
"""Incidence cosines of the cut-beam table: the white-oblique kernel's nodes (1 and
:data:`jaxsss.render.bssrdf.KERNEL_MUS`) and 0.75, the lights-behind kernel's
(:data:`jaxsss.render.bssrdf.LIGHTS_BEHIND_MUS`); descending (the lookups take the shipped table's own ``mus``)."""
PASSAGE_ALBEDO = (0.3, 0.5, 0.7, 0.8, 0.9, 0.97, 0.99)
"""Single-scattering albedos of the table (the similarity albedo ``sigma_s' / sigma_t'``; held beyond the ends)."""
PASSAGE_TAU = (0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 10.0)
"""Optical chord lengths ``tau = sigma_t' t`` of the table (held below 0.25; the loss is 0 from 10 on)."""
PASSAGE_X = (0.0, 0.3, 0.6, 0.8, 0.9, 1.0, 1.1, 1.25, 1.5, 2.0, 3.0)
"""Distances from the point of entry in units of the chord, ``x = d / t`` (held beyond 3)."""
PASSAGE_FLOOR = 1.0
"""The cut beam's step at ``d = t`` is resolved no finer than this many near-field radii ``rho_0``: within ``rho_0``
the sums spread each sample's light over a disc anyway. A chord shorter than that (the last light before a
terminator) made the step fall between samples and the image blotchy: ketchup's green terminator band 0.127 per pixel
with no floor, 0.119 at 0.5 rho_0, 0.100 at rho_0 (0.109 before the cut beam); chicken1's blue 0.071 / 0.069 / 0.077
per pixel (0.077 before)."""
CUT_MIN_LOSS = 0.02
"""The cut beam (both ends) is kept for a scene when its plateau loss (``x = 3``) reaches this share of the light at
either end, in any channel (:func:`cut_matters`): ketchup 9-10% and chicken1 10-11% in red keep it; skin1 (0.6%),
the marble teapot (1.2%), potato (1.7% in blue), apple and the g = 0.9 and sky-lit spheres (under 0.5%) take the
uniform ``1 - exp(-sigma_t t)``. Its lookups cost 2.5x the render's pairs (skin1's image 0.41 -> 1.01 s after the
pass-2 speed-up of 2026-11-28; 0.26 -> 1.2 s before it), and on those scenes they change mare_lit by under 0.002."""
PASSAGE_PHOTONS = 1_000_000
PASSAGE_TABLE = Path(__file__).resolve().parent / "data" / "passage_loss.npz"
_D_EDGES = np.concatenate([[0.0], np.geomspace(0.02, 60.0, 160)])


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


def view_chords(geometry, shading, eta: float) -> np.ndarray:
    """``(Q, 4)``: the chord (mm) of each shaded point's refracted view ray inside the object (1e9 where it never
    leaves) and the ray's inward direction projected on the surface (length ``sin theta_t``): the eye's side of the
    cut beam (:meth:`jaxsss.render.bssrdf.WhiteKernel._view_kept`). ``shading``: the
    :class:`~jaxsss.render.shading.ShadingPoints` (``pos``, ``normal``, ``to_eye``)."""
    from jaxsss.render.bssrdf import surface_tangents

    to_eye = np.asarray(shading.to_eye)[:, None, :]
    normals = np.asarray(shading.normal)
    cos = np.clip(np.einsum("qlj,qj->ql", to_eye, normals), 1e-6, 1.0)
    chord = entry_chords(geometry, np.asarray(shading.pos), normals, to_eye, cos, eta)[:, 0]
    tangent = surface_tangents(to_eye, normals, eta)[:, 0]
    return np.concatenate([np.where(np.isfinite(chord), chord, 1e9)[:, None], tangent], axis=1)


def cut_matters(medium, samples, view=None) -> bool:
    """Whether the cut beam changes a scene enough to pay for it (:data:`CUT_MIN_LOSS`): the largest, over the
    channels, of the flux-weighted plateau loss of the lit light columns (``samples``: pass 1's
    :class:`~jaxsss.render.samples.IrradianceSamples` with chords) and of the mean plateau loss of the shaded points'
    view chords (``view``, :func:`view_chords`, or None), at the azimuthal mean (NumPy on the shipped table)."""
    from jaxsss.render.bssrdf import hat_weights

    if samples.chord is None:
        return False
    n_c = samples.light.irradiance.shape[-1]
    sigma_t_prime = np.broadcast_to(np.asarray(medium.sigma_a + medium.sigma_s_prime, dtype=np.float64), (n_c,))
    table = passage_loss_table(np.broadcast_to(np.asarray(medium.alpha_prime, dtype=np.float64), (n_c,)), PASSAGE_MUS,
                               xp=np)
    # The plateau (the last x node), azimuthal mean: (K, T, C), linear in tau between the nodes (NumPy: the eager
    # JAX lookup took 70 ms of the skin1 sphere's 0.5 s of geometry).
    nodes = table[:, :, -1].mean(axis=2)

    def plateau(chord, cos):
        # The loss at x = 3 of chords (M,) at cosines (M,), mixed over the table's nodes: (M, C).
        tau = np.where(np.isfinite(chord), chord, 1e9)[:, None] * sigma_t_prime  # (M, C)
        loss = np.stack([np.stack([np.interp(tau[:, c], PASSAGE_TAU, nodes[k, :, c]) for c in range(n_c)], axis=-1)
                         for k in range(len(PASSAGE_MUS))], axis=1)  # (M, K, C)
        return np.einsum("mk,mkc->mc", hat_weights(np.clip(cos, 0.0, 1.0), PASSAGE_MUS, xp=np), loss)

    lit = samples.light.cos > 0.0
    largest = 0.0
    if lit.any():
        n, col = np.nonzero(lit)
        weight = samples.light.irradiance[n, col] * samples.areas[n, None]  # (M, C)
        entry = (weight * plateau(samples.chord[n, col], samples.light.cos[n, col])).sum(0) / np.maximum(
            weight.sum(0), 1e-300)
        largest = float(entry.max())
    if view is not None and len(view):
        mu = np.sqrt(np.clip(1.0 - np.sum(view[:, 1:] ** 2, axis=1), 0.0, 1.0))
        largest = max(largest, float(plateau(view[:, 0], mu).mean(0).max()))
    return largest >= CUT_MIN_LOSS


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


def cut_beam_tallies(albedo: float, mu_i: float, photons: int, seed: int = 1,
                     tau_edges=PASSAGE_TAU[:-1], d_edges: np.ndarray = _D_EDGES) -> np.ndarray:
    """``(2, len(tau_edges) + 1, len(d_edges) - 1)``: the light a pencil beam puts out of an index-matched isotropic
    half-space (``sigma_t = 1``, albedo ``albedo``, incidence cosine ``mu_i``; analogue walk, absorption by weight,
    roulette below 1e-3) per photon, behind and ahead of the entry point along the beam's travel (first axis), by
    the length of the photon's first flight (bins split at ``tau_edges``) and by the exit point's distance from the
    entry point (``d_edges``, mean free paths). Cutting the beam at a chord ``tau`` removes the rows of first flights
    longer than ``tau`` (NumPy)."""
    from jaxsss.render.walk import pencil_beam_walk

    s_edges = np.concatenate([[0.0], np.asarray(tau_edges, float), [np.inf]])
    tally = np.zeros((2, len(s_edges) - 1, len(d_edges) - 1))

    def add(first, exit_point, direction, weight):
        ahead = exit_point[:, 0] > 0.0
        for half in (0, 1):
            sel = ahead == bool(half)
            tally[half] += np.histogram2d(first[sel], np.hypot(exit_point[sel, 0], exit_point[sel, 1]),
                                          [s_edges, d_edges], weights=weight[sel])[0]

    pencil_beam_walk(albedo, mu_i, photons, seed, add)
    return tally / photons


def _loss_from_tallies(tally: np.ndarray, d_edges: np.ndarray = _D_EDGES) -> np.ndarray:
    """``(len(PASSAGE_TAU), len(PASSAGE_X))`` loss ``1 - cut / full`` from one half of :func:`cut_beam_tallies`: over
    the annulus
    about each ``x`` node (half-way to its neighbours), held from the previous node where the full beam puts out less
    than 1e-7 per photon there; 0 at the last ``tau`` node."""
    centres = np.sqrt(d_edges[1:] * np.maximum(d_edges[:-1], 1e-3))
    x = np.asarray(PASSAGE_X)
    bounds = np.concatenate([[0.0], 0.5 * (x[1:] + x[:-1]), [x[-1] + 0.5]])
    full = tally.sum(axis=0)
    out = np.zeros((len(PASSAGE_TAU), len(x)))
    for i, tau in enumerate(PASSAGE_TAU[:-1]):
        cut = tally[: i + 1].sum(axis=0)
        for j in range(len(x)):
            inside = (centres >= bounds[j] * tau) & (centres < bounds[j + 1] * tau)
            total = full[inside].sum()
            if total < 1e-7 and j > 0:
                out[i, j] = out[i, j - 1]
                continue
            # The loss: 1 - (cut beam) / (whole beam) over the annulus.
            out[i, j] = 1.0 - cut[inside].sum() / max(total, 1e-300)
    return np.clip(out, 0.0, 1.0)


def generate_passage_table(photons: int = PASSAGE_PHOTONS, seed: int = 1, progress: bool = True,
                           mus=PASSAGE_MUS) -> dict:
    """Run the walks (seeds ``seed + 100 k + j``, ``k`` the node's :func:`jaxsss.render.walk.seed_slot` among
    :data:`PASSAGE_MUS`) and return the table ``loss`` ``(U, A, T, X, 2)`` over ``mus`` (default :data:`PASSAGE_MUS`),
    :data:`PASSAGE_ALBEDO`, :data:`PASSAGE_TAU`, :data:`PASSAGE_X` and the half-plane behind and ahead of the entry
    point, with its metadata."""
    from tqdm.auto import tqdm

    from jaxsss.render.walk import seed_slot

    t0 = time.perf_counter()
    mus = tuple(float(m) for m in mus)
    loss = np.zeros((len(mus), len(PASSAGE_ALBEDO), len(PASSAGE_TAU), len(PASSAGE_X), 2))
    nodes = [(k, j) for k in range(len(mus)) for j in range(len(PASSAGE_ALBEDO))]
    for k, j in tqdm(nodes, desc="passage table", disable=not progress):
        tally = cut_beam_tallies(PASSAGE_ALBEDO[j], mus[k], photons, seed + 100 * seed_slot(mus[k], PASSAGE_MUS) + j)
        for half in (0, 1):
            loss[k, j, ..., half] = _loss_from_tallies(tally[half])
    return {"loss": loss, "mus": np.asarray(mus), "albedo": np.asarray(PASSAGE_ALBEDO),
            "tau": np.asarray(PASSAGE_TAU), "x": np.asarray(PASSAGE_X), "photons": photons, "seed": seed,
            "seconds": time.perf_counter() - t0,
            "source": "jaxsss.render.passage.cut_beam_tallies: index-matched isotropic half-space, pencil beam, "
                      "first flight cut at tau"}


@functools.lru_cache(maxsize=1)
def load_passage_table() -> dict:
    """The shipped table (:data:`PASSAGE_TABLE`) as NumPy arrays (cached)."""
    with np.load(PASSAGE_TABLE) as f:
        return {k: f[k] for k in f.files}


def passage_loss_table(albedo, mus, xp=jnp):
    """``(K, T, X, 2, C)``: the loss table (behind, ahead) at the kernel's incidence nodes ``mus`` (each one of
    :data:`PASSAGE_MUS`, the shipped table's ``mus``), interpolated linearly to the channels' similarity albedos
    ``albedo`` ``(C,)`` (held beyond the ends; differentiable in ``albedo``). ``xp``: the array module (``numpy`` for
    the host's test of whether the cut matters, :func:`cut_matters`, where eager JAX compiled each operation: 0.45 s of
    a process's first render)."""
    tab = load_passage_table()
    nodes = tuple(float(m) for m in tab["mus"])
    missing = [m for m in mus if float(m) not in nodes]
    if missing:
        raise ValueError(f"passage_loss_table: mus {missing} have no cut-beam table; the table has {nodes}")
    loss = xp.asarray(tab["loss"][[nodes.index(float(m)) for m in mus]])  # (K, A, T, X, 2)
    i, t = node_interval(xp.atleast_1d(albedo), PASSAGE_ALBEDO, xp)
    # Linear in the albedo between the table's nodes.
    w0, w1 = (1.0 - t)[None, :, None, None, None], t[None, :, None, None, None]
    return xp.moveaxis(loss[:, i] * w0 + loss[:, i + 1] * w1, 1, -1)


def node_interval(v, nodes, xp=jnp):
    """``(i, t)``: the interval index (int32) and fraction of ``v`` (any shape) among the sorted ``nodes`` (a tuple or
    NumPy array: concrete), held beyond the ends: linear interpolation is ``(1 - t) f[i] + t f[i + 1]``. ``xp``: the
    array module (``jax.numpy`` or ``numpy``)."""
    nodes = tuple(float(n) for n in np.asarray(nodes))
    v = xp.clip(v, nodes[0], nodes[-1])
    # The interval by counting the interior nodes at or below v: elementwise, so it fuses with its neighbours
    # (jnp.searchsorted's binary search took 12x as long on 6e5 values on the CPU).
    if _vectorised(xp.shape(v), len(nodes)):
        # A few values (a material's channels): one comparison along a node axis (:data:`UNROLL_MIN_SIZE`).
        interior = xp.asarray(nodes[1:-1], dtype=xp.result_type(v, 0.0))
        i = xp.sum((v[..., None] >= interior).astype(xp.int32), axis=-1, dtype=xp.int32)
    else:
        i = xp.zeros(xp.shape(v), xp.int32) + sum((v >= n).astype(xp.int32) for n in nodes[1:-1])
    # The nodes in v's dtype (float32 values stay float32).
    dtype = xp.result_type(v, 0.0)
    lo, hi = xp.asarray(nodes[:-1], dtype=dtype)[i], xp.asarray(nodes[1:], dtype=dtype)[i]
    return i, (v - lo) / (hi - lo)


UNROLL_MIN_SIZE = 1 << 17
"""Element count from which :func:`node_interval` and :func:`piecewise_linear` unroll their loop over the nodes (one
elementwise step per node, which fuses over a block of pairs: 2^16 pairs times the nodes and channels). Below it they
take one vectorised step along a node axis: a material's tables (up to ~8e4 values, the curvature correction's) are
computed once per image, and unrolled they were a third of a white-kernel image's traced program (piecewise_linear:
1972 of 6321 operations for the marble teapot, each traced, lowered and compiled)."""


VECTORISED_MAX_ELEMENTS = 1 << 22
"""The most elements the vectorised step's node axis may hold (the values times the nodes: 32 MB in float64). The
largest table today holds 1.2e6 (the curvature correction's 77,517 values by 15 intervals)."""


def _vectorised(shape: tuple, n_nodes: int) -> bool:
    """Whether a lookup among ``n_nodes`` nodes over ``shape`` takes the vectorised step (:data:`UNROLL_MIN_SIZE`,
    :data:`VECTORISED_MAX_ELEMENTS`)."""
    size = int(np.prod(shape, dtype=np.int64))
    return n_nodes > 2 and size < UNROLL_MIN_SIZE and size * (n_nodes - 1) <= VECTORISED_MAX_ELEMENTS


def piecewise_linear(v, nodes, f):
    """The linear interpolant of ``f`` ``(N, ...)`` at the sorted ``nodes`` ``(N,)`` (concrete), held beyond the ends,
    at ``v`` (broadcast against ``f[0]``): a sum of clipped ramps, with no index (elementwise, so it fuses; on the
    CPU it took a tenth of the time of an interval lookup and two gathers). Over fewer than :data:`UNROLL_MIN_SIZE`
    elements the ramps are one array along a node axis instead of one traced step per node."""
    nodes = tuple(float(n) for n in np.asarray(nodes))
    shape = jnp.broadcast_shapes(jnp.shape(v), jnp.shape(f)[1:])
    if _vectorised(shape, len(nodes)):
        # The same sum of clipped ramps along a leading node axis (a material's few values: UNROLL_MIN_SIZE).
        # The nodes in v's dtype, as the unrolled loop's Python floats are (float32 values stay float32).
        axis, dtype = (-1,) + (1,) * len(shape), jnp.result_type(v, 0.0)
        lo = jnp.asarray(np.asarray(nodes[:-1]).reshape(axis), dtype=dtype)
        width = jnp.asarray(np.diff(np.asarray(nodes)).reshape(axis), dtype=dtype)
        slopes = (f[1:] - f[:-1]).reshape((len(nodes) - 1,) + (1,) * (len(shape) + 1 - jnp.ndim(f)) + f.shape[1:])
        ramps = jnp.clip(jnp.broadcast_to(v, shape)[None] - lo, 0.0, width)
        return f[0] + jnp.sum(slopes / width * ramps, axis=0)
    out = f[0]
    for j in range(len(nodes) - 1):
        width = nodes[j + 1] - nodes[j]
        # f_0 + sum_j slope_j clip(v - n_j, 0, n_j+1 - n_j).
        out = out + (f[j + 1] - f[j]) / width * jnp.clip(v - nodes[j], 0.0, width)
    return out


def passage_cells(table) -> jnp.ndarray:
    """``(K, T - 1, X - 1, C, 8)``: each ``(tau, x)`` cell's bilinear coefficients of :func:`passage_loss_table`'s
    ``table`` ``(K, T, X, 2, C)``, behind then ahead (``f00, f10 - f00, f01 - f00, f11 - f10 - f01 + f00``), so that a
    lookup is one gather of a row (:func:`passage_loss`)."""
    f = jnp.moveaxis(table, 3, 4)  # (K, T, X, C, 2)
    f00, f10, f01, f11 = f[:, :-1, :-1], f[:, 1:, :-1], f[:, :-1, 1:], f[:, 1:, 1:]
    coefficients = jnp.stack([f00, f10 - f00, f01 - f00, f11 - f10 - f01 + f00], axis=-1)  # (K, T-1, X-1, C, 2, 4)
    return coefficients.reshape(coefficients.shape[:4] + (8,))


def passage_loss(cells, tau, x, ahead=0.5):
    """``(P, K, C)``: the fraction of a cut beam's light lost at distance ``x`` chords from its entry, bilinear in
    ``(tau, x)`` on ``cells`` (:func:`passage_cells` of :func:`passage_loss_table`) and linear between the
    half-planes behind (``ahead = 0``) and ahead of the entry (``ahead = 1``; 0.5: the azimuthal mean); ``tau``,
    ``x``, ``ahead`` ``(P, K, C)``."""
    n_k, n_t, n_x, n_c, _ = cells.shape
    it, ft = node_interval(tau, PASSAGE_TAU)
    ix, fx = node_interval(x, PASSAGE_X)
    k = jnp.arange(n_k, dtype=jnp.int32)[None, :, None]
    c = jnp.arange(n_c, dtype=jnp.int32)[None, None, :]
    # One gather of the cell's eight coefficients.
    y = cells.reshape(-1, 8)[((k * n_t + it) * n_x + ix) * n_c + c]
    # Bilinear in (tau, x), each half-plane.
    behind = y[..., 0] + ft * y[..., 1] + fx * (y[..., 2] + ft * y[..., 3])
    front = y[..., 4] + ft * y[..., 5] + fx * (y[..., 6] + ft * y[..., 7])
    # Linear between behind and ahead.
    return behind + ahead * (front - behind)


def main(argv=None) -> int:
    from jaxsss.render.walk import table_main

    return table_main(
        argv, prog="python -m jaxsss.render.passage", path=PASSAGE_TABLE, photons=PASSAGE_PHOTONS,
        description="The cut-beam loss table of the white kernels' passage (jaxsss.render.passage).",
        photons_help="photons per (incidence, albedo) node", load=load_passage_table, refit=None,
        generate=generate_passage_table, node_keys=("loss",),
        describe=lambda tab: (f"loss {tab['loss'].shape} (mu_i, albedo, tau, x = d / t, behind/ahead); "
                              f"{int(tab['photons'])} photons per node, {float(tab['seconds']):.0f} s"))


if __name__ == "__main__":
    sys.exit(main())
