"""Photon tracing into meshes (Donner and Jensen 2007, Section 5): diffusion sources, and the mesh Monte Carlo walk.

Photons from :func:`~jaxsss.photon.emit.emit_photons` are traced against the scene with Embree (trimesh + embreex;
NumPy, outside JAX):

- **Entry.** A photon that hits the translucent mesh from outside refracts in (Snell, ``eta = n_inside /
  n_outside``) carrying ``1 - F(cos theta_i)`` of its power (Fresnel, deterministic split; the reflected part is
  tallied and not traced further). The hit point and the outward normal there are the *incidence plane* of the leg.
- **First scattering.** The free flight inside is sampled; where a leg first scatters, a **diffusion source** is
  stored: position, incidence plane (normal and depth below it), the power that started the flight, the flight's
  length and the area the photon stands for. The walk then goes on (reduced, isotropic scattering: the similarity
  relation of the diffusion models), and a leg only stores again after its photon *leaves and re-enters* the mesh.
- **Boundaries.** At the surface from inside the photon reflects with probability ``F`` (all-or-none, total internal
  reflection included) or exits; every exit is recorded (position, weight, scattering order) -- that is the mesh
  Monte Carlo reference (:mod:`jaxsss.photon.reference`). An exiting photon is traced on outside and re-enters where
  it hits the translucent mesh again (non-convex shapes), or ends.
- **Blockers** (``[[blocker]]`` meshes inside the object) absorb every photon that reaches them; occluders absorb
  photons from outside (their bounce light is the renderer's indirect term, not traced).

**All channels from one walk (spectral mixture sampling).** The channels share each photon's path. Each free flight
is sampled from the mixture ``p(s) = (1/C) sum_k sigma_t,k' exp(-sigma_t,k' s)``, and each channel's weight is
multiplied by its own ratio: ``alpha_c' sigma_t,c' e^{-sigma_t,c' s} / p(s)`` at a scattering event,
``e^{-sigma_t,c' t} / ((1/C) sum_k e^{-sigma_t,k' t})`` for a flight cut by the boundary at ``t``. Every ratio is at
most ``C``, so the estimator stays bounded, and it is unbiased for every channel at once; with identical channels
the ratios are 1 and the walk is the analog one (power is then conserved path by path, which the tests check).

**Differentiability.** A stored source keeps the power that *started* its flight and the flight length ``s``. Its
power in the medium is recomputed in JAX (:mod:`jaxsss.photon.render`) as ``power_c alpha_c' sigma_t,c' e^{-sigma_t,c'
s} / p_ref(s)`` with ``p_ref`` the mixture of the tracing material, so it equals the traced value at that material
and follows any other material smoothly with the positions held fixed (the same idea as the renderer's geometry-only
interaction lists). The power a leg carries in after earlier flights (internal reflections, re-entry) is held
constant in those derivatives.

Tallies (``(C,)`` W each) close exactly: ``emitted + reentered = missed + occluded + reflected + absorbed + blocked +
exited + reweighted + roulette + capped``, where ``reweighted`` collects the mixture ratios' deviations from 1 (zero
in expectation, exactly zero with identical channels).
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
from tqdm import tqdm

from jaxsss.fresnel import fresnel_unpolarised, refract, snell_cosine
from jaxsss.photon.emit import PhotonRays
from jaxsss.render.rays import OBJECT_NONE, OBJECT_TRANSLUCENT, SceneGeometry

__all__ = ["TALLIES", "Exits", "PhotonTrace", "Sources", "trace_photons"]

TALLIES = ("emitted", "reentered", "missed", "occluded", "reflected", "absorbed", "blocked", "exited", "reweighted",
           "roulette", "capped")
MIN_COS = 0.05
"""Photon areas use ``max(cos theta_i, MIN_COS)`` (a grazing photon stands for a long strip, capped at 20x)."""


class Sources(NamedTuple):
    """``S`` stored diffusion sources (first scattering of each leg).

    Attributes:
        position: ``(S, 3)`` mm.
        normal: ``(S, 3)`` outward unit normal of the incidence plane (the smooth normal where the leg entered).
        depth: ``(S,)`` depth below the incidence plane, mm, ``>= 0`` (clamped: curved faces can put it above).
        power: ``(S, C)`` W, the weight that started the flight ending at the source.
        path: ``(S,)`` length of that flight, mm.
        area: ``(S,)`` surface area the photon stands for, mm^2.
        generation: ``(S,)`` 0 for light entering from a light, k after k exits and re-entries.
        cos_in: ``(S,)`` cosine of incidence where the leg entered.
    """

    position: np.ndarray
    normal: np.ndarray
    depth: np.ndarray
    power: np.ndarray
    path: np.ndarray
    area: np.ndarray
    generation: np.ndarray
    cos_in: np.ndarray

    def entry_points(self) -> np.ndarray:
        """``(M, 3)`` mm: where the legs that came straight from a light (generation 0) entered the surface, each
        source moved back up its incidence plane's normal by its depth: the directly lit surface, from which light
        creeps into the dark parts (:func:`jaxsss.render.shading.dark_pixel_grid`)."""
        first = self.generation == 0
        return self.position[first] + self.depth[first, None] * self.normal[first]

    @property
    def n(self) -> int:
        return int(self.position.shape[0])


class Exits(NamedTuple):
    """``X`` exits through the translucent surface: ``position`` (X, 3) mm, ``weight`` (X, C) W, scattering
    ``order`` (X,), the mesh ``face`` (X,) and the leg's ``generation`` (X,)."""

    position: np.ndarray
    weight: np.ndarray
    order: np.ndarray
    face: np.ndarray
    generation: np.ndarray


class PhotonTrace(NamedTuple):
    """The result of :func:`trace_photons`.

    Attributes:
        sources: the stored :class:`Sources`.
        exits: the :class:`Exits` (empty when ``walk="sources"``).
        tally: ``{name: (C,) W}`` for each of :data:`TALLIES`.
        sigma_t_ref: ``(C,)`` the tracing material's ``sigma_t'`` (1/mm): the mixture the flights were drawn from.
        n_photons: photons emitted.
        steps: loop iterations (scattering events of the longest walk, about).
        seconds: wall time.
    """

    sources: Sources
    exits: Exits
    tally: dict
    sigma_t_ref: np.ndarray
    n_photons: int
    steps: int
    seconds: float


def _fresnel_np(cos_i, rel):
    """``(F, cos_t)`` at incidence cosine ``cos_i`` onto relative index ``rel = n_t / n_i`` (the physics core's
    Fresnel and Snell, in NumPy)."""
    cos_i = np.asarray(cos_i, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return fresnel_unpolarised(cos_i, rel, xp=np), snell_cosine(cos_i, rel, xp=np)[0]


def _refract(d, n, cos_i, cos_t, rel):
    """Refracted unit direction for incidence ``d`` on a surface whose unit normal ``n`` faces the incident side
    (``cos_i = -d . n``), onto relative index ``rel = n_t / n_i`` (Snell, :func:`jaxsss.fresnel.refract`)."""
    t = refract(d, n, cos_i, cos_t, rel, xp=np)
    return t / np.linalg.norm(t, axis=1, keepdims=True)


def _sphere(n, rng):
    cz = 2.0 * rng.random(n) - 1.0
    phi = 2.0 * np.pi * rng.random(n)
    sz = np.sqrt(np.maximum(0.0, 1.0 - cz * cz))
    return np.stack([sz * np.cos(phi), sz * np.sin(phi), cz], axis=1)


class _State:
    """Per-photon arrays of the walk (all photons; ``alive`` marks the ones still traced)."""

    def __init__(self, photons: PhotonRays):
        p = len(photons.origin)
        c = photons.power.shape[1]
        self.pos = photons.origin.astype(np.float64).copy()
        self.dir = photons.direction.astype(np.float64).copy()
        self.power = photons.power.astype(np.float64)
        self.spread = photons.spread
        self.solid = photons.solid_angle
        self.w = np.ones((p, c))
        self.order = np.zeros(p, np.int64)
        self.inside = np.zeros(p, bool)
        self.alive = np.ones(p, bool)
        self.fresh = np.zeros(p, bool)  # the current leg has not scattered yet
        self.entry_pos = np.zeros((p, 3))
        self.entry_n = np.zeros((p, 3))
        self.cos_in = np.ones(p)
        self.area = np.zeros(p)
        self.gen = np.full(p, -1, np.int64)  # -1 until the first entry
        self.steps = np.zeros(p, np.int64)


def trace_photons(geometry: SceneGeometry, photons: PhotonRays, sigma_a, sigma_s_prime, eta: float, *,
                  blocker_ids=(), walk: str = "full", max_steps: int = 100_000, weight_threshold: float = 1e-4,
                  roulette_chance: float = 0.1, seed: int = 0, progress: bool = False) -> PhotonTrace:
    """Trace photons into the translucent mesh (object 0 of ``geometry``): sources, exits and tallies.

    Args:
        geometry: the scene's meshes; object 0 is the translucent one, ``blocker_ids`` the absorbing inner meshes,
            every other object an occluder.
        photons: from :func:`~jaxsss.photon.emit.emit_photons`; their ``power`` has ``C`` channels.
        sigma_a, sigma_s_prime: ``(C,)`` (or scalars) absorption and reduced scattering, 1/mm.
        eta: ``n_inside / n_outside`` (one value for all channels), ``> 0``.
        blocker_ids: object ids in ``geometry`` that are blockers.
        walk: ``"full"`` continues every walk to its end (exits recorded, re-entry traced); ``"sources"`` ends a
            photon at its first scattering (enough for convex meshes, where no light re-enters; no exits).
        max_steps: scattering events per photon before it is ended (tallied in ``capped``, as is the weight left
            when ``walk="sources"`` ends a photon).
        weight_threshold: Russian roulette below this fraction of the photon's power (largest channel).
        roulette_chance: survival probability in the roulette, in (0, 1].
        seed: NumPy random seed.
        progress: show a tqdm bar of photons finished.

    Returns:
        :class:`PhotonTrace`.
    """
    if walk not in ("full", "sources"):
        raise ValueError(f"trace_photons(walk={walk!r}) is not one of: full, sources")
    sa = np.atleast_1d(np.asarray(sigma_a, dtype=np.float64))
    ss = np.atleast_1d(np.asarray(sigma_s_prime, dtype=np.float64))
    c = photons.power.shape[1]
    sa, ss = np.broadcast_to(sa, (c,)).copy(), np.broadcast_to(ss, (c,)).copy()
    st_ = sa + ss
    if not (np.all(sa >= 0) and np.all(ss >= 0) and np.all(st_ > 0) and np.all(np.isfinite(st_))):
        raise ValueError(f"trace_photons(sigma_a={sa.tolist()}, sigma_s_prime={ss.tolist()}): need sigma_a >= 0, "
                         "sigma_s' >= 0, sigma_a + sigma_s' in (0, inf) 1/mm")
    eta = float(eta)
    if not (np.isfinite(eta) and eta > 0):
        raise ValueError(f"trace_photons(eta={eta!r}) is outside the allowed range (0, inf)")
    if not (0 < roulette_chance <= 1):
        raise ValueError(f"trace_photons(roulette_chance={roulette_chance!r}) is outside the allowed range (0, 1]")
    alpha = ss / st_
    identical = bool(np.all(st_ == st_[0]))
    blockers = np.asarray(sorted(blocker_ids), dtype=np.int64)
    convex = bool(geometry.meshes[0].is_convex)
    rng = np.random.default_rng(seed)
    t_start = time.perf_counter()
    s = _State(photons)
    tally = {k: np.zeros(c) for k in TALLIES}
    tally["emitted"] = photons.power.sum(axis=0)
    src_parts: list[tuple] = []
    exit_parts: list[tuple] = []
    off = geometry.offset
    n_total = len(s.pos)
    bar = tqdm(total=n_total, desc="photons", unit="photon", disable=not progress, leave=False)
    done_before = 0
    iteration = 0

    def end(idx, name, weight):
        if name is not None:
            tally[name] += weight.sum(axis=0)
        s.alive[idx] = False

    while s.alive.any():
        iteration += 1
        # --- outside: fly to the next surface; enter the translucent mesh or end ---------------------------------
        out = np.flatnonzero(s.alive & ~s.inside)
        if out.size:
            d = s.dir[out]
            hits = geometry.first_hit(s.pos[out], d)
            wpow = s.w[out] * s.power[out]
            first = s.gen[out] < 0
            miss = hits.obj == OBJECT_NONE
            end(out[miss & first], "missed", wpow[miss & first])
            end(out[miss & ~first], None, wpow[miss & ~first])  # already tallied when it exited
            other = ~miss & (hits.obj != OBJECT_TRANSLUCENT)
            end(out[other & first], "occluded", wpow[other & first])
            end(out[other & ~first], None, wpow[other & ~first])  # exited light stopped by an occluder
            enter = np.flatnonzero(hits.obj == OBJECT_TRANSLUCENT)
            if enter.size:
                ids = out[enter]
                face = hits.face[enter]
                x = hits.position[enter]
                dd = d[enter]
                n_f = geometry.combined.face_normals[face]
                cos_i = -np.einsum("ij,ij->i", dd, n_f)
                back = cos_i <= 0  # hit from inside: an open mesh or a light inside it; the photon is lost
                if back.any():  # (light that already exited was tallied then)
                    lost = ids[back & (s.gen[ids] < 0)]
                    tally["missed"] += (s.w[lost] * s.power[lost]).sum(axis=0)
                    s.alive[ids[back]] = False
                keep = ~back
                ids, face, x, dd, n_f, cos_i = ids[keep], face[keep], x[keep], dd[keep], n_f[keep], cos_i[keep]
                reenter = s.gen[ids] >= 0
                tally["reentered"] += (s.w[ids[reenter]] * s.power[ids[reenter]]).sum(axis=0)
                # Fresnel at entry (deterministic split) and Snell refraction.
                F, cos_t = _fresnel_np(cos_i, eta)
                tally["reflected"] += (F[:, None] * s.w[ids] * s.power[ids]).sum(axis=0)
                s.w[ids] *= (1.0 - F)[:, None]
                s.dir[ids] = _refract(dd, n_f, cos_i, cos_t, eta)
                n_s = geometry.shading_normals(face, x)
                n_s = np.where(np.einsum("ij,ij->i", n_s, n_f)[:, None] < 0, -n_s, n_s)
                s.entry_pos[ids] = x
                s.entry_n[ids] = n_s
                s.cos_in[ids] = cos_i
                t_hit = hits.t[enter][keep]
                cos_a = np.maximum(cos_i, MIN_COS)
                new_area = np.where(s.solid[ids], s.spread[ids] * t_hit**2, s.spread[ids]) / cos_a
                s.area[ids] = np.where(reenter, s.area[ids], new_area)
                s.gen[ids] += 1
                s.pos[ids] = x - off * n_f
                s.inside[ids] = True
                s.fresh[ids] = True
        # --- inside: a free flight; scatter, or reach the surface or a blocker ---------------------------------
        ins = np.flatnonzero(s.alive & s.inside)
        if ins.size:
            p0, d = s.pos[ins], s.dir[ins]
            hits = geometry.first_hit(p0, d)
            t_hit = np.where(hits.hit, hits.t, np.inf)
            # Free flight from the channel mixture.
            k = rng.integers(0, c, ins.size)
            flight = -np.log1p(-rng.random(ins.size)) / st_[k]
            scat = (flight < t_hit) & hits.hit  # a ray that hits nothing leaves through a hole of an open mesh
            # -- scattering events
            i_s = ins[scat]
            if i_s.size:
                fl = flight[scat]
                e = np.exp(-np.outer(fl, st_))  # (n, C)
                mix = (e * st_).mean(axis=1, keepdims=True)
                ratio = np.ones_like(e) if identical else e * st_ / mix
                w_before = s.w[i_s]
                pos = p0[scat] + fl[:, None] * d[scat]
                fresh = s.fresh[i_s]
                if fresh.any():
                    j = i_s[fresh]
                    en = s.entry_n[j]
                    depth = np.maximum(np.einsum("ij,ij->i", s.entry_pos[j] - pos[fresh], en), 0.0)
                    src_parts.append((pos[fresh], en, depth, w_before[fresh] * s.power[j], fl[fresh], s.area[j],
                                      s.gen[j], s.cos_in[j]))
                    s.fresh[j] = False
                pw = s.power[i_s]
                tally["reweighted"] += (w_before * (1.0 - ratio) * pw).sum(axis=0)
                tally["absorbed"] += (w_before * ratio * (1.0 - alpha) * pw).sum(axis=0)
                s.w[i_s] = w_before * ratio * alpha
                s.pos[i_s] = pos
                s.order[i_s] += 1
                s.steps[i_s] += 1
                s.dir[i_s] = _sphere(i_s.size, rng)
                if walk == "sources":
                    stop = i_s[fresh]
                    tally["capped"] += (s.w[stop] * s.power[stop]).sum(axis=0)
                    s.alive[stop] = False
                # Russian roulette on the largest channel, then the step cap.
                live = i_s[s.alive[i_s]]
                low = live[s.w[live].max(axis=1) < weight_threshold]
                if low.size:
                    survive = rng.random(low.size) < roulette_chance
                    wl = s.w[low] * s.power[low]
                    tally["roulette"] += wl[~survive].sum(axis=0) - wl[survive].sum(axis=0) * (1 / roulette_chance - 1)
                    s.w[low[survive]] /= roulette_chance
                    s.alive[low[~survive]] = False
                cap = live[s.alive[live] & (s.steps[live] >= max_steps)]
                end(cap, "capped", s.w[cap] * s.power[cap])
            # -- flights cut by a surface
            i_b = ins[~scat]
            if i_b.size:
                th = t_hit[~scat]
                obj = hits.obj[~scat]
                face = hits.face[~scat]
                x = hits.position[~scat]
                dd = d[~scat]
                e = np.exp(-np.outer(np.where(np.isfinite(th), th, 0.0), st_))  # (no hit: no reweighting)
                surv = np.ones_like(e) if identical else e / e.mean(axis=1, keepdims=True)
                tally["reweighted"] += (s.w[i_b] * (1.0 - surv) * s.power[i_b]).sum(axis=0)
                s.w[i_b] *= surv
                lost = obj == OBJECT_NONE  # left through a hole of an open mesh
                end(i_b[lost], "exited", s.w[i_b[lost]] * s.power[i_b[lost]])
                blk = np.isin(obj, blockers) | ((obj != OBJECT_TRANSLUCENT) & ~lost)
                end(i_b[blk], "blocked", s.w[i_b[blk]] * s.power[i_b[blk]])
                srf = np.flatnonzero(obj == OBJECT_TRANSLUCENT)
                if srf.size:
                    ids, dd, x, face = i_b[srf], dd[srf], x[srf], face[srf]
                    n_f = geometry.combined.face_normals[face]
                    cos_i = np.abs(np.einsum("ij,ij->i", dd, n_f))
                    n_in = np.where(np.einsum("ij,ij->i", dd, n_f)[:, None] > 0, -n_f, n_f)  # faces the photon
                    F, cos_t = _fresnel_np(cos_i, 1.0 / eta)
                    refl = rng.random(ids.size) < F
                    # Internal (total) reflection: mirror and stay inside.
                    r = ids[refl]
                    s.dir[r] = dd[refl] + 2.0 * cos_i[refl][:, None] * n_in[refl]
                    s.pos[r] = x[refl] + off * n_in[refl]
                    # Exit: record, refract out, and carry on outside (non-convex) or end.
                    q = ~refl
                    xi = ids[q]
                    wq = s.w[xi] * s.power[xi]
                    tally["exited"] += wq.sum(axis=0)
                    if walk == "full":
                        exit_parts.append((x[q], wq, s.order[xi].copy(), face[q], s.gen[xi].copy()))
                    if convex or walk == "sources":
                        s.alive[xi] = False
                    else:
                        s.dir[xi] = _refract(dd[q], n_in[q], cos_i[q], cos_t[q], 1.0 / eta)
                        s.pos[xi] = x[q] - off * n_in[q]
                        s.inside[xi] = False
        finished = n_total - int(np.count_nonzero(s.alive))
        bar.update(finished - done_before)
        done_before = finished
    bar.close()

    def cat(parts, n_fields, shapes):
        if not parts:
            return [np.zeros(sh) for sh in shapes]
        return [np.concatenate([p[i] for p in parts]) for i in range(n_fields)]

    src = Sources(*cat(src_parts, 8, [(0, 3), (0, 3), (0,), (0, c), (0,), (0,), (0,), (0,)]))
    ex = Exits(*cat(exit_parts, 5, [(0, 3), (0, c), (0,), (0,), (0,)]))
    return PhotonTrace(src, ex, tally, st_, n_total, iteration, time.perf_counter() - t_start)
