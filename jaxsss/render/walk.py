"""A pencil beam into an index-matched isotropic half-space or sphere: the analogue walk behind the renderer's small
transport tables (:mod:`jaxsss.render.passage`'s cut beam, :mod:`jaxsss.render.exit_distance`'s exit by distance,
:mod:`jaxsss.render.exit_curvature`'s exit on a curved surface).

Units of the mean free path (``sigma_t = 1``); isotropic scattering (``g = 0``) at an index-matched boundary (every
photon that reaches the surface leaves); absorption by weight (``albedo`` per interaction) and roulette below a weight
of 1e-3 (survival 0.1, unbiased). NumPy: the tables are made once, offline, and shipped.

:func:`diffuse_light_walk` is the one walk with a dielectric boundary (Fresnel at every crossing, uniform diffuse light):
transport's curvature gain of a sphere, the evidence behind the curvature cap's note in ``docs/path_tracer.md``.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["SEED_ORDER", "diffuse_light_walk", "fresnel_walk", "insert_albedo", "insert_node", "isotropic_directions",
           "load_table", "pencil_beam_walk", "roulette", "seed_slot", "sphere_and_plane_tallies", "table_main",
           "walk_photons"]

SEED_ORDER = (1.0, 0.5, 0.1, 0.75)
"""Incidence nodes in the order they joined the walks' tables (0.75 on 2026-12-02, for lights behind:
:data:`jaxsss.render.bssrdf.LIGHTS_BEHIND_MUS`). A node's seeds come from its place here (:func:`seed_slot`), so a node
added later leaves the shipped rows as they were."""


def seed_slot(mu: float, mus) -> int:
    """The seed slot ``k`` of incidence node ``mu`` in a table over the nodes ``mus``: its place in :data:`SEED_ORDER`
    among the table's nodes. A node that is not in both has no seeds: a ValueError says where to add it."""
    order = [m for m in SEED_ORDER if m in tuple(float(v) for v in mus)]
    if float(mu) not in order:
        raise ValueError(f"seed_slot: mu {float(mu):g} must be one of the table's nodes {tuple(float(v) for v in mus)} "
                         f"and of SEED_ORDER {SEED_ORDER} (jaxsss.render.walk; a new node goes at SEED_ORDER's end)")
    return order.index(float(mu))


def isotropic_directions(rng: np.random.Generator, n: int) -> np.ndarray:
    """``(n, 3)`` unit directions, uniform on the sphere (isotropic scattering)."""
    u = rng.random((n, 2))
    cz, phi = 1.0 - 2.0 * u[:, 0], 2.0 * np.pi * u[:, 1]
    sz = np.sqrt(1.0 - cz * cz)
    return np.stack([sz * np.cos(phi), sz * np.sin(phi), cz], axis=1)


def roulette(rng: np.random.Generator, w: np.ndarray) -> np.ndarray:
    """Russian roulette below a weight of 1e-3: survive with probability 0.1 (weight x 10), unbiased. Changes ``w``
    in place and returns the mask of photons still alive."""
    low = np.flatnonzero(w < 1e-3)
    survive = rng.random(len(low)) < 0.1
    w[low[survive]] /= 0.1
    alive = np.ones(len(w), dtype=bool)
    alive[low[~survive]] = False
    return alive


def pencil_beam_walk(albedo: float, mu_i: float, photons: int, seed: int, tally, *, radius: float | None = None,
                     min_order: int = 1, eta: float = 1.0) -> None:
    """Walk ``photons`` photons entering at the origin along ``(sin theta_i, 0, -mu_i)`` and call ``tally(first,
    exit_point, direction, weight)`` with each batch that leaves: their first flight's length ``(M,)``, where they
    cross the surface ``(M, 3)``, their direction inside ``(M, 3)`` and weight ``(M,)``.

    ``radius`` (mean free paths): a sphere of that radius centred at ``(0, 0, -radius)`` (its surface touches the
    plane ``z = 0`` at the entry, with the same outward normal there) instead of the half-space ``z < 0``; the outward
    normal at an exit point ``p`` is then ``(p - c) / radius``. ``min_order``: tally only photons that have
    interacted at least that many times (the default 1 leaves out the light that crosses a sphere uncollided).

    ``eta``: the relative index of a smooth boundary (:func:`fresnel_walk`); ``mu_i`` is then the cosine outside,
    the beam enters refracted by Snell with the weight ``1 - F(mu_i)`` (per incident photon). 1: index-matched
    (:func:`walk_photons`; every order counts one interaction per step)."""
    from jaxsss.fresnel import fresnel_unpolarised

    rng = np.random.default_rng(seed)
    pos = np.zeros((photons, 3))
    centre = None if radius is None else np.array([0.0, 0.0, -float(radius)])
    if eta == 1.0:
        d = np.tile([np.sqrt(1.0 - mu_i * mu_i), 0.0, -mu_i], (photons, 1))
        walk_photons(rng, pos, d, albedo, tally, centre=centre, radius=radius, min_order=min_order)
        return
    # Snell: the refracted direction, and the Fresnel transmittance of the entry.
    sin_t = np.sqrt(1.0 - mu_i * mu_i) / eta
    d = np.tile([sin_t, 0.0, -np.sqrt(1.0 - sin_t * sin_t)], (photons, 1))
    w = np.full(photons, 1.0 - float(fresnel_unpolarised(np.asarray(mu_i), eta, xp=np)))
    fresnel_walk(rng, pos, d, w, albedo, eta, tally, centre=centre, radius=radius, min_order=min_order)


def _crossing(p: np.ndarray, v: np.ndarray, centre, radius) -> tuple[np.ndarray, np.ndarray]:
    """Where flights from ``p`` along ``v`` ``(M, 3)`` leave the half-space ``z < 0`` (``centre`` None) or the sphere
    of ``radius`` about ``centre``, and the outward normal there: ``(hit, normal)``, each ``(M, 3)``."""
    if centre is None:
        t = -p[:, 2] / v[:, 2]
        hit = p + t[:, None] * v
        return hit, np.broadcast_to([0.0, 0.0, 1.0], hit.shape)
    # The larger root of |q + t v| = radius, q = p - centre.
    q = p - centre
    b = np.einsum("ij,ij->i", q, v)
    t = -b + np.sqrt(np.maximum(b * b - (np.einsum("ij,ij->i", q, q) - radius * radius), 0.0))
    hit = p + t[:, None] * v
    return hit, (hit - centre) / radius


def walk_photons(rng: np.random.Generator, pos: np.ndarray, d: np.ndarray, albedo: float, tally, *,
                 centre=None, radius: float | None = None, min_order: int = 1, payload=None) -> None:
    """The walk itself: photons at ``pos`` ``(N, 3)`` on the surface, heading inwards along ``d`` ``(N, 3)``, in the
    half-space ``z < 0`` (``centre`` None) or the sphere of ``radius`` about ``centre`` (mean free paths). Calls
    ``tally(payload, exit_point, direction, weight)`` with each batch that leaves after at least ``min_order``
    interactions; ``payload`` ``(N,)`` is carried with each photon (None: its first flight's length)."""
    w = np.ones(len(pos))
    order = 0  # interactions so far, the same for every photon still inside
    while len(w):
        step = -np.log(rng.random(len(w)))
        payload = step if payload is None else payload
        new = pos + step[:, None] * d
        if centre is None:
            out = new[:, 2] > 0.0  # the first flight points down: it never leaves
        else:
            rel = new - centre
            out = np.einsum("ij,ij->i", rel, rel) > radius * radius
        if out.any() and order >= min_order:
            p, v = pos[out], d[out]
            tally(payload[out], _crossing(p, v, centre, radius)[0], v, w[out])
        keep = ~out
        pos, w, payload = new[keep], w[keep] * albedo, payload[keep]
        order += 1
        d = isotropic_directions(rng, len(w))
        alive = roulette(rng, w)
        pos, d, w, payload = pos[alive], d[alive], w[alive], payload[alive]


def diffuse_light_walk(albedo: float, eta: float, photons: int, seed: int, *, radius: float | None = None) -> float:
    """The light a sphere of ``radius`` mean free paths (None: the half-space) with a smooth dielectric boundary
    sends back under uniform diffuse light, per incident photon: every order >= 1 (the specular reflection and light
    that crosses a sphere without interacting left out), isotropic scattering, ``albedo`` per interaction.

    Each photon enters at a point of the surface (any: the light is uniform) with a cosine-weighted direction, its
    weight the Fresnel transmittance ``1 - F(eta, mu_i)``, refracted by Snell. At every boundary hit from inside it
    leaves with ``1 - F`` of its weight (after at least one interaction) and is reflected with ``F`` (total internal
    reflection: all), a new free path from the boundary (memoryless). ``eta = 1`` is the index-matched walk of
    :func:`walk_photons`. Over the half-space's, the sphere's value is transport's curvature gain for diffuse light,
    against which :mod:`jaxsss.render.curvature`'s ratio was measured at a dielectric boundary (docs/path_tracer.md,
    "Held out under the sky"). Checked against adding-doubling and Chandrasekhar (``tests/render/test_walk.py``)."""
    from jaxsss.fresnel import fresnel_unpolarised

    if not 0.0 <= albedo < 1.0:
        raise ValueError(f"diffuse_light_walk(albedo={albedo}) must be in [0, 1)")
    if not eta > 0.0:
        raise ValueError(f"diffuse_light_walk(eta={eta}) must be > 0")
    if radius is not None and not radius > 0.0:
        raise ValueError(f"diffuse_light_walk(radius={radius}) must be > 0 (mean free paths) or None")
    rng = np.random.default_rng(seed)
    mu_i = np.sqrt(rng.random(photons))
    w = 1.0 - fresnel_unpolarised(mu_i, eta, xp=np)
    # Snell: the refracted direction, about the inward normal -z at the entry.
    sin_t = np.sqrt(1.0 - mu_i * mu_i) / eta
    phi = 2.0 * np.pi * rng.random(photons)
    d = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), -np.sqrt(1.0 - sin_t * sin_t)], axis=1)
    # The sphere about the origin, entered at its top; the half-space z < 0, entered at the origin.
    centre = None if radius is None else np.zeros(3)
    pos = np.zeros((photons, 3)) if radius is None else np.tile([0.0, 0.0, float(radius)], (photons, 1))
    out = [0.0]

    def tally(payload, exit_point, direction, weight):
        out[0] += float(np.sum(weight))

    fresnel_walk(rng, pos, d, w, albedo, eta, tally, centre=centre, radius=radius)
    return out[0] / photons


def fresnel_walk(rng: np.random.Generator, pos: np.ndarray, d: np.ndarray, w: np.ndarray, albedo: float, eta: float,
                 tally, *, centre=None, radius: float | None = None, min_order: int = 1, payload=None) -> None:
    """:func:`walk_photons` behind a smooth dielectric boundary of relative index ``eta``: photons at ``pos`` ``(N,
    3)`` heading inwards along ``d`` with weights ``w`` ``(N,)`` (the entry's transmittance already in them). At every
    boundary hit from inside a photon leaves with ``1 - F`` of its weight (``F`` from inside, relative index ``1 /
    eta``; tallied after at least ``min_order`` interactions: ``tally(payload, exit_point, direction, weight)``,
    ``direction`` inside) and is reflected with ``F`` (total internal reflection: all), a new free path from the
    boundary (memoryless). ``payload`` ``(N,)`` rides with each photon (None: its first flight's length, as
    :func:`walk_photons`)."""
    from jaxsss.fresnel import fresnel_unpolarised

    order = np.zeros(len(w), dtype=np.int64)
    while len(w):
        step = -np.log(rng.random(len(w)))
        payload = step if payload is None else payload
        new = pos + step[:, None] * d
        cross = new[:, 2] > 0.0 if centre is None else np.einsum("ij,ij->i", new - centre, new - centre) > radius**2
        p, v, wc, oc, pc = pos[cross], d[cross], w[cross], order[cross], payload[cross]
        hit, normal = _crossing(p, v, centre, radius)
        cos_out = np.clip(np.einsum("ij,ij->i", v, normal), 0.0, 1.0)
        # Fresnel from inside (relative index 1 / eta): leave with 1 - F, reflect F.
        F = fresnel_unpolarised(cos_out, 1.0 / eta, xp=np)
        leaves = oc >= min_order
        if leaves.any():
            tally(pc[leaves], hit[leaves], v[leaves], (wc * (1.0 - F))[leaves])
        reflected = v - 2.0 * cos_out[:, None] * normal
        inside = ~cross
        pos = np.concatenate([new[inside], hit - 1e-9 * normal])
        d = np.concatenate([isotropic_directions(rng, int(inside.sum())), reflected])
        w = np.concatenate([w[inside] * albedo, wc * F])
        order = np.concatenate([order[inside] + 1, oc])
        payload = np.concatenate([payload[inside], pc])
        alive = roulette(rng, w) & (w > 0.0)
        pos, d, w, order, payload = pos[alive], d[alive], w[alive], order[alive], payload[alive]


def insert_node(table: dict, part: dict, keys) -> dict:
    """``table`` (incidence nodes ``mus``, descending, on the first axis of its entries ``keys``) with the one-node
    table ``part`` put in at its node's place; ``seconds`` the sum of both."""
    mu, mus = float(part["mus"][0]), [float(m) for m in table["mus"]]
    if len(part["mus"]) != 1 or mu in mus:
        raise ValueError(f"insert_node: part must hold one node that the table lacks; got {list(part['mus'])}, the "
                         f"table has {mus}")
    at = sum(m > mu for m in mus)
    out = dict(table)
    for key in ("mus",) + tuple(keys):
        out[key] = np.insert(np.asarray(table[key]), at, np.asarray(part[key])[0], axis=0)
    out["seconds"] = float(table["seconds"]) + float(part["seconds"])
    return out


def insert_albedo(table: dict, part: dict, keys) -> dict:
    """``table`` (albedo nodes ``albedo``, ascending, on the second axis of its entries ``keys``) with the one-albedo
    table ``part`` (the same incidence nodes) put in at the end: a new albedo node must exceed the table's last, so
    that its seed slot (its index in the whole tuple, :func:`sphere_and_plane_tallies`) is the one ``--regenerate``
    gives it. ``seconds`` the sum of both."""
    a, albedo = float(part["albedo"][0]), [float(v) for v in table["albedo"]]
    if len(part["albedo"]) != 1 or a <= albedo[-1]:
        raise ValueError(f"insert_albedo: part must hold one albedo above the table's last {albedo[-1]:g}; got "
                         f"{list(part['albedo'])}")
    if [float(m) for m in part["mus"]] != [float(m) for m in table["mus"]]:
        raise ValueError(f"insert_albedo: part's mus {list(part['mus'])} must be the table's {list(table['mus'])}")
    out = dict(table)
    out["albedo"] = np.append(np.asarray(table["albedo"]), a)
    for key in keys:
        out[key] = np.concatenate([np.asarray(table[key]), np.asarray(part[key])], axis=1)
    out["seconds"] = float(table["seconds"]) + float(part["seconds"])
    return out


def table_main(argv, *, prog: str, description: str, path, photons: int, photons_help: str, load, refit, generate,
               describe, node_keys: tuple = (), albedo_keys: tuple = ()) -> int:
    """The command line of a transport table made by these walks (``python -m jaxsss.render.<table>``): without
    options it describes the shipped table at ``path``; ``--refit`` refits it from its own tallies (``refit(table) ->
    updated entries``, no walk; None: not offered); ``--regenerate`` runs the walks (``generate(photons) -> table``,
    with ``seconds``) and writes it (``--out`` elsewhere); ``--add-node MU`` runs one more incidence node's walks
    (``generate(photons, mus=(MU,))``, its seeds from :func:`seed_slot`) and puts its rows of ``node_keys`` in
    (:func:`insert_node`): the shipped rows stay as they were; ``--add-albedo A`` likewise one more albedo above the
    table's last (``generate(photons, albedos=(A,))``, its rows of ``albedo_keys``, :func:`insert_albedo`). ``load()``
    reads the shipped table; ``describe(table)`` is its one-line summary."""
    import argparse
    from pathlib import Path

    p = argparse.ArgumentParser(prog=prog, description=description)
    p.add_argument("--regenerate", action="store_true", help="run the walks and write the table")
    if refit is not None:
        p.add_argument("--refit", action="store_true", help="refit from the shipped tallies (no walk)")
    if node_keys:
        p.add_argument("--add-node", type=float, metavar="MU",
                       help="run the walks of one more incidence cosine MU (0 < MU <= 1) and add its rows")
    if albedo_keys:
        p.add_argument("--add-albedo", type=float, metavar="A",
                       help="run the walks of one more single-scattering albedo A (above the table's last, below 1) "
                            "and add its rows")
    p.add_argument("--photons", type=int, default=photons, help=f"{photons_help} (default {photons})")
    p.add_argument("--out", type=Path, default=Path(path), help=f"the table's path (default {path})")
    args = p.parse_args(argv)
    if getattr(args, "add_node", None) is not None:
        if not 0.0 < args.add_node <= 1.0:
            p.error(f"--add-node: the incidence cosine must lie in (0, 1]; got {args.add_node}")
        tab = insert_node(dict(load()), generate(args.photons, mus=(args.add_node,)), node_keys)
        np.savez_compressed(args.out, **tab)
        print(f"added mu_i {args.add_node:g} to {args.out} ({len(tab['mus'])} nodes)")
        return 0
    if getattr(args, "add_albedo", None) is not None:
        shipped = dict(load())
        last = float(shipped["albedo"][-1])
        if not last < args.add_albedo < 1.0:
            p.error(f"--add-albedo: the albedo must lie in ({last:g}, 1), above the table's last; "
                    f"got {args.add_albedo}")
        tab = insert_albedo(shipped, generate(args.photons, albedos=(args.add_albedo,)), albedo_keys)
        np.savez_compressed(args.out, **tab)
        print(f"added albedo {args.add_albedo:g} to {args.out} ({len(tab['albedo'])} albedos)")
        return 0
    if getattr(args, "refit", False):
        tab = dict(load())
        tab.update(refit(tab))
        np.savez_compressed(args.out, **tab)
        print(f"refitted {args.out}")
        return 0
    if not args.regenerate:
        print(f"{path}: {describe(load())}")
        return 0
    tab = generate(args.photons)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out, **{k: np.asarray(v) for k, v in tab.items()})
    print(f"wrote {args.out} in {tab['seconds']:.0f} s")
    return 0


def sphere_and_plane_tallies(tally, mus, albedos, radii, photons: int, seed: int, desc: str, progress: bool = True,
                             table_mus=None, table_albedo=None):
    """``(sphere (U, A, R, ...), plane (U, A, ...))``: ``tally(albedo, mu_i, radius, photons, seed)`` for every
    incidence cosine in ``mus`` and albedo in ``albedos``, on the half-space (``radius=None``) and each sphere of
    ``radii`` (transport lengths). Seeds: ``seed + 1000 k + 100 j`` for the half-space, then ``+ 1 + r`` per sphere
    (the shipped tables' scheme), ``k`` the node's :func:`seed_slot` among ``table_mus`` (the whole table's nodes;
    default ``mus``) and ``j`` the albedo's index in ``table_albedo`` (the whole table's albedos, ascending; default
    ``albedos``). A progress bar over the nodes (``desc``)."""
    from tqdm.auto import tqdm

    table_albedo = [float(a) for a in (albedos if table_albedo is None else table_albedo)]
    missing = [float(a) for a in albedos if float(a) not in table_albedo]
    if missing:
        raise ValueError(f"sphere_and_plane_tallies: albedos {missing} have no seed slot among the table's "
                         f"{tuple(table_albedo)} (a new albedo goes at the end of the module's albedo tuple first)")
    slots = [table_albedo.index(float(a)) for a in albedos]
    sphere, plane = {}, {}
    nodes = [(k, j) for k in range(len(mus)) for j in range(len(albedos))]
    for k, j in tqdm(nodes, desc=desc, disable=not progress):
        base = seed + 1000 * seed_slot(mus[k], mus if table_mus is None else table_mus) + 100 * slots[j]
        plane[k, j] = tally(albedos[j], mus[k], None, photons, base)
        for r, radius in enumerate(radii):
            sphere[k, j, r] = tally(albedos[j], mus[k], radius, photons, base + 1 + r)
    grid = (len(mus), len(albedos))
    return (np.stack([np.stack([sphere[k, j, r] for r in range(len(radii))]) for k, j in nodes]).reshape(
                grid + (len(radii),) + plane[0, 0].shape),
            np.stack([plane[k, j] for k, j in nodes]).reshape(grid + plane[0, 0].shape))


@functools.lru_cache(maxsize=None)
def load_table(path) -> dict:
    """A shipped ``.npz`` table as NumPy arrays (cached per path)."""
    with np.load(path) as f:
        return {k: f[k] for k in f.files}
