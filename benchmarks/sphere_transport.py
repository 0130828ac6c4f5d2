"""The renderer's orders >= 2 on a whole sphere against a transport walk: exitance by the light's cosine, where it
entered, and what the exit's azimuth would change.

A point light on an index-matched isotropic sphere (``eta = 1``, ``g = 0``: the scenes whose first order the renderer
marches, :mod:`jaxsss.render.first_order`; its kernels then hold the orders >= 2), and on the same spheres behind a
smooth dielectric boundary (``eta = 1.4``: every order, Fresnel at every crossing; the kernels keep the exit's current
there, :mod:`jaxsss.render.dielectric_current`). The walk is independent of the
renderer: photons leave the light into the cone that the sphere subtends, enter where they hit it, and scatter
analogue (isotropic, absorption by weight, roulette below a weight of 1e-3) until they leave; the light that leaves
after two or more interactions is tallied

- by the cosine to the light at its exit point: the exitance, W/mm^2, against the renderer's
  (:meth:`jaxsss.render.renderer.Prepared.exitance`, the node rows summed, at its shaded points: the pixels' hits),
  the walk's interpolated at each shaded point from :data:`FINE_EDGES` and both summed per band (:data:`LIGHT_EDGES`).
  Where the renderer cuts the eye's ray at a finite chord (the cut beam, ``WhiteKernel._view_kept``: a limb seen
  through a short path inside), that factor is inside its sums, so its "exitance" there is towards the camera: on
  chicken1's sphere lit from behind it reads 8-44% under the walk at the normal node where the kernel alone agrees
  within 3-8% (docs/path_tracer.md, "The azimuth's harmonics on the kernel as rendered"); against Mitsuba the eye's
  cut is right;
- and by the cosine to the light at its *entry* (:data:`ENTRY_EDGES`): the renderer's side masks its irradiance
  samples to the same bins and sums again, so each band's error is split by the light that feeds it;
- and by its exit direction: the first azimuthal harmonic ``A1`` of the radiance (``L ~ 1 + A1 cos phi``, ``phi``
  from the light's flow, the direction along the surface away from the light) per band and exit cosine. The
  renderer's exit has no azimuth (its exit distributions depend on the exit cosine only). ``camera_factor`` is what
  the walk's ``A1`` makes of the camera's view at the renderer's shaded points, exitance-weighted per band: below 1
  where the camera looks against the flow (from the light's side, at the terminator). ``current_factor`` is the
  renderer's own: ``1 + current / radiance`` of its orders >= 2 summed per band, with the plan made to keep the
  exit's current (:mod:`jaxsss.render.exit_current`; both signs, before the renderer keeps the positive part at ``eta
  = 1``; behind the dielectric boundary the renderer keeps both). ``radiance_ratio`` is what the two make of the
  exitance's ratio towards the camera: ``exitance_ratio * current_factor / camera_factor``.

Rows: one per scene, channel and light band; ``error`` is ``|renderer / walk - 1|`` of the band's exitance; seconds:
the walk's (NumPy; a diagnostic against transport, not a speed comparison: the renderer's exitance rows are summed
op by op here). ``--quick``: 1e5 photons per channel (full: 1e6). docs/path_tracer.md, "Two errors that cancel at
the terminator", quotes the full run.
"""

from __future__ import annotations

import functools
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

from benchmarks._harness import make_row, parse_args, write_results
from jaxsss.fresnel import snell_cosine
from jaxsss.render.walk import fresnel_walk, walk_photons

NAME = "sphere_transport"
REFERENCES = Path(__file__).resolve().parents[1] / "tests" / "export" / "references"
SCENES = {"skin1, 20 mm sphere": ("skin1_sphere.toml", None, None),
          "skin1, 8 mm sphere": ("skin1_sphere.toml", 8.0, None),
          "skin1, 20 mm sphere, lit from behind": ("skin1_sphere.toml", None, (70.0, 90.0, 40.0)),
          "skin1, 8 mm sphere, lit from behind": ("skin1_sphere.toml", 8.0, (28.0, 36.0, 16.0)),
          "chicken1, 20 mm sphere": ("chicken1_sphere.toml", None, None),
          "chicken1, 20 mm sphere, lit from behind": ("chicken1_sphere.toml", None, (70.0, 90.0, 40.0)),
          "skin1, 20 mm sphere, eta 1.4": ("skin1_sphere.toml", None, None, 1.4),
          "chicken1, 20 mm sphere, eta 1.4": ("chicken1_sphere.toml", None, None, 1.4)}
"""Scene file (the path-traced reference's), the sphere's radius in mm, the point light's position in mm (None: the
file's) and, optionally, the relative index of a smooth dielectric boundary (the walk then tallies every order, and the
renderer keeps the exit's current of :mod:`jaxsss.render.dielectric_current`; no path tracer can connect a point light
through that boundary, so this walk is the check). The committed references' camera sees the terminator from the light's
side; lit from behind, it sees it from the dark side, along the light's flow. chicken1's sphere is only 3.3 / 5.7 / 11
transport lengths in radius (beyond the curvature cap in red), where the exit current of docs/path_tracer.md
overshot; lit from behind it is the committed back-lit scene with the largest error (benchmarks/references/materials,
chicken1_sphere_backlit; docs/path_tracer.md, "The second azimuthal harmonic")."""
LIGHT_EDGES = np.array([-1.0, -0.5, -0.3, -0.1, 0.1, 0.3, 0.5, 0.7, 0.9, 1.0])
FINE_EDGES = np.linspace(-1.0, 1.0, 81)
"""The walk's exitance is tallied on these finer bins and interpolated at each shaded point: within a band the
exitance changes several-fold near the terminator, and the shaded points are not spread over it as the area is."""
ENTRY_EDGES = np.array([0.0, 0.2, 0.4, 0.7, 1.0])
MU_EDGES = np.linspace(0.0, 1.0, 11)
PHOTONS, QUICK_PHOTONS = 1_000_000, 100_000
METRIC = "|renderer / walk - 1|, orders >= 2 exitance in the light-cos band (every order at eta != 1)"


def _frame(x, light):
    """``(normal, cos to the light, flow)`` at sphere points ``x`` ``(N, 3)`` (centre at the origin): the flow is the
    unit tangential direction away from the light."""
    n = x / np.linalg.norm(x, axis=-1, keepdims=True)
    to_light = light - x
    to_light /= np.linalg.norm(to_light, axis=-1, keepdims=True)
    cos = np.sum(n * to_light, axis=-1)
    flow = -(to_light - cos[:, None] * n)
    return n, cos, flow / np.maximum(np.linalg.norm(flow, axis=-1, keepdims=True), 1e-300)


@functools.lru_cache(maxsize=8)
def fine_areas(radius: float, light: tuple) -> np.ndarray:
    """``(F,)``: each fine bin's area on the sphere of ``radius`` mm at the origin (mm^2), by the cosine to a point
    light at ``light`` (mm; a tuple, for the cache): Monte Carlo over the surface, 4e6 points, a fixed seed."""
    u = np.random.default_rng(0).normal(size=(4_000_000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    cos = _frame(radius * u, np.asarray(light, float))[1]
    return np.histogram(cos, FINE_EDGES)[0] / len(u) * 4.0 * np.pi * radius**2


def light_bands(pos, radius: float, light):
    """``(normal, cos, flow, band, inside)`` at shaded points ``pos`` ``(Q, 3)`` (projected on the sphere): the
    frame of :func:`_frame`, each point's :data:`LIGHT_EDGES` band and whether it lies within them."""
    n, cos, flow = _frame(pos / np.linalg.norm(pos, axis=1, keepdims=True) * radius, np.asarray(light, float))
    band = np.clip(np.searchsorted(LIGHT_EDGES, cos, side="right") - 1, 0, len(LIGHT_EDGES) - 2)
    return n, cos, flow, band, (cos >= LIGHT_EDGES[0]) & (cos < LIGHT_EDGES[-1])


def sphere_walk(sigma_a: float, sigma_s: float, radius: float, light, intensity: float, photons: int, seed: int = 0,
                min_order: int = 2, eta: float = 1.0) -> dict:
    """The walk (module docstring) on a sphere of ``radius`` mm at the origin under a point light at ``light`` (mm) of
    ``intensity`` W/sr: ``exitance`` ``(F, E)`` W/mm^2 by fine light bin (:data:`FINE_EDGES`) and entry bin, and
    ``harmonic`` ``(B, M, 2)`` (light, light times ``cos phi``) by light band and exit cosine
    (:func:`jaxsss.render.walk.walk_photons`); ``min_order`` 0 tallies every photon (for the tests: without absorption
    every photon that enters leaves). ``eta != 1``: a smooth dielectric boundary
    (:func:`jaxsss.render.walk.fresnel_walk`: each photon enters refracted with the weight ``1 - F``; the light that
    leaves is what crosses the boundary, binned by its cosine outside), ``min_order`` at least 1."""
    rng = np.random.default_rng(seed)
    light = np.asarray(light, dtype=float)
    sigma_t, albedo = sigma_a + sigma_s, sigma_s / (sigma_a + sigma_s)
    dist = np.linalg.norm(light)
    cos_cone = np.sqrt(1.0 - (radius / dist) ** 2)
    # Directions uniform in the cone the sphere subtends: each photon carries I Omega / N.
    axis = -light / dist
    cz = 1.0 - rng.random(photons) * (1.0 - cos_cone)
    phi = 2.0 * np.pi * rng.random(photons)
    sz = np.sqrt(1.0 - cz * cz)
    e1 = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    d = cz[:, None] * axis + (sz * np.cos(phi))[:, None] * e1 + (sz * np.sin(phi))[:, None] * e2
    b = d @ light
    disc = b * b - (light @ light - radius * radius)
    hit = disc > 0.0
    pos = light + (-b[hit] - np.sqrt(disc[hit]))[:, None] * d[hit]
    d = d[hit]
    entry_cos = -np.sum(pos / radius * d, axis=1)
    w = np.ones(len(d))
    if eta != 1.0:
        from jaxsss.fresnel import fresnel_unpolarised, refract

        # Snell and Fresnel at the entry.
        d = refract(d, pos / radius, entry_cos, snell_cosine(entry_cos, eta, xp=np)[0], eta, xp=np)
        w = 1.0 - fresnel_unpolarised(entry_cos, eta, xp=np)
    exit_light = np.zeros((len(FINE_EDGES) - 1, len(ENTRY_EDGES) - 1))
    harmonic = np.zeros((len(LIGHT_EDGES) - 1, len(MU_EDGES) - 1, 2))

    def tally(entry, exit_point, direction, weight):
        n, cos, flow = _frame(exit_point, light * sigma_t)  # mean free paths: the cosines do not change
        mu = np.clip(np.sum(n * direction, axis=1), 0.0, 1.0)
        along = direction - mu[:, None] * n
        if eta != 1.0:  # Snell: the cosine outside (the azimuth is kept)
            mu = snell_cosine(mu, 1.0 / eta, xp=np)[0]
        cos_phi = np.sum(along * flow, axis=1) / np.maximum(np.linalg.norm(along, axis=1), 1e-300)
        exit_light[:] += np.histogram2d(cos, entry, [FINE_EDGES, ENTRY_EDGES], weights=weight)[0]
        for i, f in enumerate((weight, weight * cos_phi)):
            harmonic[..., i] += np.histogram2d(cos, mu, [LIGHT_EDGES, MU_EDGES], weights=f)[0]

    # In mean free paths (sigma_t = 1), about the sphere's centre.
    if eta == 1.0:
        walk_photons(rng, pos * sigma_t, d, albedo, tally, centre=np.zeros(3), radius=radius * sigma_t,
                     min_order=min_order, payload=entry_cos)
    else:
        fresnel_walk(rng, pos * sigma_t, d, w, albedo, eta, tally, centre=np.zeros(3), radius=radius * sigma_t,
                     min_order=max(min_order, 1), payload=entry_cos)
    area = fine_areas(float(radius), tuple(float(x) for x in light))
    power = intensity * 2.0 * np.pi * (1.0 - cos_cone) / photons
    return {"exitance": exit_light * power / np.maximum(area, 1e-300)[:, None], "harmonic": harmonic,
            "area": area}


SUPERPOSE_MUS = (1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1)
"""Incidence cosines of the pencil beams :func:`pencil_superposition` walks; each entry takes the nearest."""


def pencil_superposition(sigma_a: float, sigma_s: float, radius: float, light, intensity: float, photons: int, *,
                         points: int = 60_000, queries: int = 50, seed: int = 11, mus=SUPERPOSE_MUS) -> np.ndarray:
    """``(B, 2)``: the orders >= 2 exitance (W/mm^2) per light band (:data:`LIGHT_EDGES`) of pencil-beam walks
    (:func:`jaxsss.render.walk.pencil_beam_walk` in the same sphere, ``photons`` per beam, index-matched, isotropic)
    superposed over the point-lit sphere of :func:`sphere_walk`: each of ``points`` entries (uniform on the sphere)
    carries ``E dA`` and spreads it as the beam of the nearest cosine in ``mus``, by chord
    (:data:`jaxsss.render.curvature_correction.CORRECTION_D_EDGES` bins, linear between their centres), at ``queries``
    points per band. Column 0: each beam's azimuthal mean about its entry (its ring, what the renderer's kernels are
    fitted to); column 1: times ``1 + h_1 cos phi + h_2 cos 2 phi``, the beam's first two azimuthal harmonics about its
    travel (``phi`` from the light's travel projected on the entry's tangent plane). Against :func:`sphere_walk` (the
    same transport, walked whole) the two say how much of a band's light the azimuth about each entry moves: on the
    8 mm potato sphere (5.5 ``l_u``, red) the rings put the lit centre at 1.32 of the whole walk and the harmonics at
    1.06 (docs/path_tracer.md, "The lit side of small spheres")."""
    from jaxsss.render.curvature_correction import CORRECTION_D, CORRECTION_D_EDGES
    from jaxsss.render.oblique_azimuth import _tally

    sigma_t = sigma_a + sigma_s
    light = np.asarray(light, dtype=float)
    bin_area = np.pi * (CORRECTION_D_EDGES[1:] ** 2 - CORRECTION_D_EDGES[:-1] ** 2)
    beams = []
    for k, mu in enumerate(mus):
        t = _tally(sigma_s / sigma_t, float(mu), radius * sigma_t, photons, seed + k)
        total = np.where(t[0] > 0, t[0], 1.0)
        # Per unit incident power per mm^2, and the harmonics 2 <cos n phi> (0 at normal incidence: no travel).
        beams.append((t[0] / bin_area * sigma_t**2, 2.0 * t[1] / total * (mu < 1.0), 2.0 * t[2] / total * (mu < 1.0)))
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(points, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    x = radius * u
    # The light's travel along the surface (the flow away from the light) is each beam's direction of travel.
    _, cos, travel = _frame(x, light)
    r2 = np.sum((light - x) ** 2, axis=1)
    lit = cos > 0.0
    x, u, travel, cos = x[lit], u[lit], travel[lit], cos[lit]
    power = intensity * cos / r2[lit] * 4.0 * np.pi * radius**2 / points  # E dA, W
    beam = np.argmin(np.abs(np.asarray(mus)[None, :] - cos[:, None]), axis=1)
    v = rng.normal(size=(40 * queries * len(LIGHT_EDGES), 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v_cos = v @ (light / np.linalg.norm(light))
    out = np.zeros((len(LIGHT_EDGES) - 1, 2))
    for b in range(len(LIGHT_EDGES) - 1):
        q = radius * v[(v_cos >= LIGHT_EDGES[b]) & (v_cos < LIGHT_EDGES[b + 1])][:queries]
        for k, (ring, h1, h2) in enumerate(beams):
            sel = beam == k
            if not sel.any():
                continue
            offset = q[:, None, :] - x[sel][None]
            d = np.linalg.norm(offset, axis=2) * sigma_t
            tangential = offset - np.sum(offset * u[sel][None], axis=2, keepdims=True) * u[sel][None]
            cos_phi = np.sum(tangential * travel[sel][None], axis=2) / np.maximum(
                np.linalg.norm(tangential, axis=2), 1e-300)
            base = np.interp(d, CORRECTION_D, ring) * power[sel][None]
            # The ring alone, and with the beam's two harmonics about its travel.
            out[b, 0] += base.sum(axis=1).mean()
            azimuth = (1.0 + np.interp(d, CORRECTION_D, h1) * cos_phi
                       + np.interp(d, CORRECTION_D, h2) * (2.0 * cos_phi * cos_phi - 1.0))
            out[b, 1] += (base * azimuth).sum(axis=1).mean()
    return out


def _scene(file: str, radius: float | None, position=None, eta: float | None = None):
    """The reference scene ``file`` with its sphere's ``radius`` (mm), its light's ``position`` (mm) and its material's
    ``eta`` replaced (None: kept): ``(scene, radius, light position, intensity)``."""
    from jaxsss.render.scene import parse_scene

    data = tomllib.loads((REFERENCES / file).read_text())
    if eta is not None:
        data["material"]["eta"] = float(eta)
    if radius is not None:
        data["mesh"]["radius"] = float(radius)
    light = data["light"][0]
    if position is not None:
        light["position"] = [float(x) for x in position]
    return (parse_scene(data, path=file, base_dir=REFERENCES), float(data["mesh"]["radius"]),
            np.asarray(light["position"], float), float(light["intensity"]))


def renderer_exitance(scene) -> dict:
    """The renderer's orders >= 2 exitance at its shaded points, ``(Q, C)``, whole and with the irradiance samples
    masked to each entry bin (``(E, Q, C)``), their cosines to the light, exit cosines and directions to the eye."""
    import equinox as eqx
    import jax.numpy as jnp

    from jaxsss.render import render

    result = render(scene)
    state, medium = result.prepared.state, scene.material.medium
    if state.first_order is None and state.bssrdf_exit != "refracted-current":
        raise ValueError(f"{NAME}: the scene's plan neither marches the first order (eta = 1, g = 0) nor keeps the "
                         f"exit's current behind a dielectric boundary (exit {state.bssrdf_exit!r})")
    k = len(state.bssrdf_mus)
    whole = np.asarray(state.exitance(medium))[:, :k].sum(axis=1)
    cos = np.asarray(state.light_cos)[:, 0]
    parts = []
    for lo, hi in zip(ENTRY_EDGES[:-1], ENTRY_EDGES[1:]):
        mask = jnp.asarray(((cos >= lo) & (cos < hi)).astype(float))
        masked = eqx.tree_at(lambda s: s.light_irradiance, state,
                             state.light_irradiance * mask.reshape((-1,) + (1,) * (state.light_irradiance.ndim - 1)))
        parts.append(np.asarray(masked.exitance(medium))[:, :k].sum(axis=1))
    return {"whole": whole, "parts": np.stack(parts), "pos": np.asarray(state.query_pos),
            "cos_o": np.asarray(state.cos_o), "to_eye": np.asarray(state.to_eye), **current_radiance_parts(scene)}


def current_radiance_parts(scene) -> dict:
    """The renderer's exit current at its shaded points, with the plan made to keep it whatever the light
    (:mod:`jaxsss.render.exit_current`): the orders >= 2's radiance without it, ``(Q, C)`` W/(mm^2 sr), and the
    current's part (both signs, before :func:`jaxsss.render.bssrdf.current_radiance` keeps the positive one)."""
    from jaxsss.render import make_plan
    from jaxsss.render.renderer import prepare

    plan = make_plan(scene, bssrdf="auto")._replace(exit_current=True)
    state, medium = prepare(scene, plan=plan)[0], scene.material.medium
    # The sums with exit weights keep the two parts apart: (Q, 2, C).
    parts = np.asarray(state.exitance(medium, weights=state.exit_weights(medium)))
    return {"radiance": parts[:, 0], "current": parts[:, 1]}


def camera_factor(walk: dict, radius: float, light, pos, cos_o, to_eye, weights) -> np.ndarray:
    """``(B,)``: ``1 + A1 cos phi_eye`` at the renderer's shaded points (the walk's ``A1`` of their band and exit
    cosine, ``phi_eye`` the eye's azimuth from the flow), averaged per light band with ``weights`` ``(Q,)``."""
    n, _, flow, band, inside = light_bands(pos, radius, light)
    along = to_eye - cos_o[:, None] * n
    cos_phi = np.sum(along * flow, axis=1) / np.maximum(np.linalg.norm(along, axis=1), 1e-300)
    h = walk["harmonic"]
    a1 = 2.0 * h[..., 1] / np.maximum(h[..., 0], 1e-300)  # (B, M)
    m = np.clip(np.searchsorted(MU_EDGES, cos_o, side="right") - 1, 0, len(MU_EDGES) - 2)
    factor = 1.0 + a1[band, m] * cos_phi
    out = np.full(len(LIGHT_EDGES) - 1, np.nan)
    for b in range(len(out)):
        sel = (band == b) & inside
        if sel.sum() >= 3 and weights[sel].sum() > 0:
            out[b] = np.average(factor[sel], weights=weights[sel])
    return out


def main(argv=None) -> int:
    args = parse_args(argv, __doc__.splitlines()[0])
    photons = QUICK_PHOTONS if args.quick else PHOTONS
    rows = []
    for label, (file, radius, position, *rest) in SCENES.items():
        eta = rest[0] if rest else 1.0
        scene, radius, light, intensity = _scene(file, radius, position, eta)
        medium = scene.material.medium
        ren = renderer_exitance(scene)
        _, cos, _, band, inside = light_bands(ren["pos"], radius, light)
        centres = 0.5 * (FINE_EDGES[1:] + FINE_EDGES[:-1])
        for c in range(ren["whole"].shape[1]):
            sa = float(np.broadcast_to(np.asarray(medium.sigma_a), (3,))[c])
            ss = float(np.broadcast_to(np.asarray(medium.sigma_s_prime), (3,))[c])
            t0 = time.perf_counter()
            walk = sphere_walk(sa, ss, radius, light, intensity, photons, seed=17 + c, min_order=2 if eta == 1.0 else 1,
                               eta=eta)
            seconds = time.perf_counter() - t0
            factor = camera_factor(walk, radius, light, ren["pos"], ren["cos_o"], ren["to_eye"],
                                   ren["whole"][:, c])
            # The walk at each shaded point: (E, Q), linear in the cosine between the fine bins' centres.
            at = np.stack([np.interp(cos, centres, walk["exitance"][:, e]) for e in range(len(ENTRY_EDGES) - 1)])
            for b in range(len(LIGHT_EDGES) - 1):
                sel = inside & (band == b)
                truth = at[:, sel].sum(axis=1)
                if sel.sum() < 3 or truth.sum() <= 0:
                    continue
                parts = ren["parts"][:, sel, c].sum(axis=1)
                ratio = float(ren["whole"][sel, c].sum() / truth.sum())
                rows.append(make_row(
                    NAME, f"{label}, {'RGB'[c]}", f"cos to the light {LIGHT_EDGES[b]:+.1f}..{LIGHT_EDGES[b + 1]:+.1f}",
                    abs(ratio - 1.0), METRIC, seconds, None, channel="RGB"[c], l_u_mm=1.0 / (sa + ss),
                    radius_mm=radius, eta=eta, light_band=[float(LIGHT_EDGES[b]), float(LIGHT_EDGES[b + 1])],
                    exitance_ratio=ratio, walk_exitance=float(truth.sum() / sel.sum()),
                    entry_edges=ENTRY_EDGES.tolist(), walk_share_by_entry=(truth / truth.sum()).tolist(),
                    ratio_by_entry=[float(p / t) if t > 0 else None for p, t in zip(parts, truth)],
                    camera_factor=None if np.isnan(factor[b]) else float(factor[b]),
                    current_factor=float(1.0 + ren["current"][sel, c].sum() / ren["radiance"][sel, c].sum()),
                    radiance_ratio=None if np.isnan(factor[b]) else float(
                        ratio * (1.0 + ren["current"][sel, c].sum() / ren["radiance"][sel, c].sum()) / factor[b]),
                    shaded_points=int(sel.sum()), photons=photons))
                r = rows[-1]
                print(f"{label:20s} {'RGB'[c]} {r['setting']:30s} renderer/walk {ratio:.3f}  by entry cos "
                      + " ".join("  -  " if v is None else f"{v:.2f}" for v in r["ratio_by_entry"])
                      + f"  (walk shares {' '.join(f'{s:.2f}' for s in r['walk_share_by_entry'])})"
                      + f"  camera factor {r['camera_factor']}, the renderer's current {r['current_factor']:.3f}"
                      + f", radiance {r['radiance_ratio']}",
                      flush=True)
    write_results(NAME, rows, args.out, quick=args.quick, connect=False,
                  notes=[f"point light, g 0; eta 1: orders >= 2, else every order; {photons} photons per channel; "
                         f"entry bins "
                         f"{ENTRY_EDGES.tolist()}; renderer: render(scene) defaults"],
                  title="renderer vs a walk on the whole sphere: orders >= 2 exitance by the light's cosine")
    _plot(rows, args.out, args.tag)
    return 0


def _plot(rows, out, tag: str = "") -> None:
    """Per scene: the renderer's exitance over the walk's (solid), the walk's camera factor (dashed) and the renderer's
    exit current's (dotted) against the band's cosine to the light, one colour per channel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = list(dict.fromkeys(r["method"].rsplit(",", 1)[0] for r in rows))
    fig, axes = plt.subplots(1, len(labels), figsize=(5.0 * len(labels), 4.2), layout="constrained", sharey=True)
    for ax, label in zip(np.atleast_1d(axes), labels):
        for c, colour in zip("RGB", ("tab:red", "tab:green", "tab:blue")):
            sel = [r for r in rows if r["method"] == f"{label}, {c}"]
            x = [0.5 * sum(r["light_band"]) for r in sel]
            ax.plot(x, [r["exitance_ratio"] for r in sel], "o-", color=colour, label=f"{c}: exitance, renderer / walk")
            ax.plot(x, [r["camera_factor"] for r in sel], "s--", color=colour, alpha=0.6,
                    label=f"{c}: walk's azimuth factor seen by the camera")
            ax.plot(x, [r["current_factor"] for r in sel], "^:", color=colour, alpha=0.6,
                    label=f"{c}: the renderer's exit current, the same")
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set(title=label, xlabel="cosine to the light (band centre)")
        ax.grid(True, alpha=0.3)
    np.atleast_1d(axes)[0].set_ylabel("ratio (orders >= 2)")
    np.atleast_1d(axes)[0].legend(fontsize=7)
    fig.savefig(Path(out) / f"{NAME}{tag}_bands.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
