"""White Monte Carlo for any ``(n, g)`` of a half-space: a family of tables on a grid in ``(g, n)``, interpolated.

Each node is one non-absorbing half-space run (index ``n`` under air, Henyey-Greenstein ``g``, normal incidence)
tallied as ``R(rho', L')`` in **transport units** (``sigma_s' = 1``: ``rho' = r sigma_s'``, ``L' = L sigma_s'``), on
one common grid for all nodes, so that tables at different ``g`` line up where transport is diffusive and the
node values can be interpolated cell by cell. Any ``(sigma_a, sigma_s')`` then follows by exact scaling (Kienle and
Patterson 1996): with ``mu' = sigma_a / sigma_s'``,

    R(r) = sigma_s'^2 sum_L' Rtab(r sigma_s', L') <exp(-mu' L')>_bin,

because a path of transport length ``L'`` loses the factor ``exp(-sigma_a L) = exp(-mu' L')``.

Beyond the last simulated pathlength ``L'_max = 1000`` a node has no photons; the missing weight (8-12% of the
incident light at ``mu' = 0``) is restored by the **diffusion tail** of the time-resolved reflectance of a
half-space with an extrapolated boundary (Patterson, Chance and Wilson 1989; Kienle and Patterson 1997),

    R(rho', L') = A L'^(-5/2) exp(-3 rho'^2 / (4 L')) [z0 e^{-3 z0^2 / (4 L')} + z1 e^{-3 z1^2 / (4 L')}],

``z0 = 1``, ``z1 = z0 + 2 z_b``, ``z_b = 2 A(n) / 3`` (transport units, ``D = 1/3``), whose amplitude ``A`` is fitted per
node to the simulated cells with ``L'`` in ``[L'_max / 4, L'_max)`` (the shape is the asymptotic law; its
corrections are of order ``z1^2 / L'``, a few % of the tail at ``L' = 1000``). The tail is added as extra pathlength
bins to ``10^7``, so the model is valid down to ``sigma_a = 0`` (where it gives the non-absorbing medium's total
diffuse reflectance, a test).

See :mod:`jaxsss.mc.white` for the radial discretisation (log-Hermite in ``r``, annulus-average correction).
"""

from __future__ import annotations

import math
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxsss import _config  # noqa: F401  (float64)
from jaxsss.fresnel import A_coefficient
from jaxsss.mc.white import _log_eval, _log_mean_exp, _node_values, log_r_centres
from jaxsss.validate import check_range, is_concrete

__all__ = [
    "WhiteFamily",
    "block_operands",
    "check_covered",
    "covers",
    "family_from_nodes",
    "generate_node",
    "load_node",
    "load_white_family",
    "log_bin_profile",
    "white_family_block_profile",
    "white_family_profile",
    "white_family_profile_stderr",
]

FAMILY_DIR = Path(__file__).resolve().parent / "data" / "family"
# The grid (transport units, sigma_s' = 1): radii and pathlengths shared by every node.
R_FIRST = 1e-2  # first radial bin [0, R_FIRST)
R_PER_DECADE = 20
R_LOG_MAX = 2.5  # 316 transport lengths
L_FIRST = 1e-3  # first pathlength bin [0, L_FIRST)
L_PER_DECADE = 40
L_MAX = 1e3  # last simulated pathlength edge; the diffusion tail continues it
TAIL_PER_DECADE = 20
TAIL_LOG_END = 7.0
MIN_COUNTS = 100.0  # radial bins measured to worse than 1/sqrt(MIN_COUNTS) (see valid_bins) are extrapolated
MU_CHECK_MAX = 0.03
N_MATCH = 3  # valid radial bins over which the diffusion model is matched to a node's simulation
G_NODES = (0.0, 0.3, 0.6, 0.8, 0.9, 0.95)
N_NODES = (1.0, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6)


def common_edges() -> tuple[np.ndarray, np.ndarray]:
    """``(r_edges, pathlength_edges)`` of every node, transport units (``1/sigma_s'``)."""
    n_r = round((R_LOG_MAX - math.log10(R_FIRST)) * R_PER_DECADE)
    r = np.concatenate([[0.0], np.logspace(math.log10(R_FIRST), R_LOG_MAX, n_r + 1)])
    n_p = round((math.log10(L_MAX) - math.log10(L_FIRST)) * L_PER_DECADE)
    p = np.concatenate([[0.0], np.logspace(math.log10(L_FIRST), math.log10(L_MAX), n_p + 1)])
    return r, p


def node_file(g: float, n: float) -> str:
    return f"node_g{g:.2f}_n{n:.2f}.npz"


def node_seed(g: float, n: float) -> int:
    return 500_000 + round(100 * g) * 1000 + round(100 * n)


def generate_node(g: float, n: float, photons: int, *, seed: int | None = None, lanes: int | None = None,
                  devices=None) -> dict:
    """Run the non-absorbing half-space for one node and return its table (NumPy arrays and scalars).

    The run uses ``sigma_s' = 1/mm`` (``sigma_s = 1 / (1 - g)``), so mm are transport lengths; the step cap is
    ``1.2 L_max / (1 - g)`` events (a walk reaching ``L' = L_max`` takes ~``L_max / (1 - g)`` scatterings)."""
    from jaxsss.mc.engine import simulate
    from jaxsss.mc.stack import Stack

    r_edges, p_edges = common_edges()
    seed = node_seed(g, n) if seed is None else seed
    max_steps = int(1.2 * L_MAX / (1.0 - g))
    res = simulate(Stack.half_space(0.0, 1.0 / (1.0 - g), g, n), photons, seed=seed, r_edges=r_edges,
                   pathlength_edges=p_edges, batch_size=photons, lanes=lanes, max_steps=max_steps, progress=False,
                   devices=devices)
    return {
        "g": g, "n": n, "photons": photons, "seed": seed, "max_steps": max_steps, "lanes": res.lanes,
        "devices": res.devices, "seconds": res.seconds, "compile_seconds": res.compile_seconds, "events": res.events,
        "r_edges": r_edges, "pathlength_edges": p_edges,
        "R": res.R_r_path.astype(np.float32), "R_stderr": res.R_r_path_stderr.astype(np.float32),
        "R_diffuse": res.R_diffuse, "R_diffuse_stderr": res.R_diffuse_stderr, "R_specular": res.R_specular,
        "step_cap_weight": res.step_cap_weight,
    }


def node_from_white_table(path) -> dict:
    """Re-bin a table of :mod:`jaxsss.mc.white` (optical units, its own grid) onto the common transport grid.

    Optical radii and pathlengths times ``1 - g`` are transport ones; the shipped grids (20 radii and 40 pathlengths
    per decade, edges at powers of ten) then fall on the common grid's edges, so re-binning only sums cells. The
    first common radial bin takes every finer leading bin (area-weighted); pathlengths below the common first edge
    go to the first pathlength bin; cells beyond ``L_MAX`` are dropped (the diffusion tail replaces them, as for
    every node). ``R`` per unit area scales by ``1 / (1 - g)^2``."""
    with np.load(path) as z:
        t = {k: z[k] for k in z.files}
    g = float(t["g"])
    s = 1.0 - g
    r_old, p_old = t["r_edges"] * s, t["pathlength_edges"] * s
    r_new, p_new = common_edges()
    R_old = t["R"].astype(np.float64) / s**2
    E_old = t["R_stderr"].astype(np.float64) / s**2
    area_old = np.pi * np.diff(r_old**2)
    W, V = R_old * area_old[:, None], (E_old * area_old[:, None]) ** 2  # weights and variances per cell

    def index(old, new, name):
        # Map each old bin to the new bin holding its midpoint; old edges inside the new range must be new edges.
        mid = 0.5 * (old[1:] + old[:-1])
        i = np.searchsorted(new, mid, side="right") - 1
        inner = old[(old > new[1] * 1.0001) & (old < new[-1] * 0.9999)]
        if not np.all(np.min(np.abs(np.log(inner[:, None] / new[None, 2:-1])), axis=1) < 1e-6):
            raise ValueError(f"node_from_white_table({path}): {name} edges are not on the common grid")
        return i

    ir = index(r_old, r_new, "radial")
    ip = index(p_old, p_new, "pathlength")
    ok_r = ir < len(r_new) - 1
    ok_p = ip < len(p_new) - 1
    M, P = len(r_new) - 1, len(p_new) - 1
    Wn, Vn = np.zeros((M, P)), np.zeros((M, P))
    for a in np.nonzero(ok_r)[0]:
        np.add.at(Wn[ir[a]], ip[ok_p], W[a, ok_p])
        np.add.at(Vn[ir[a]], ip[ok_p], V[a, ok_p])
    area_new = np.pi * np.diff(r_new**2)[:, None]
    n_old_r = len(r_old) - 1
    covered = np.zeros(M, bool)
    covered[np.unique(ir[ok_r])] = True
    last = int(np.nonzero(covered)[0].max()) + 1
    R = Wn / area_new
    E = np.sqrt(Vn) / area_new
    R[last:] = 0.0
    E[last:] = 0.0
    del n_old_r
    return {
        "g": g, "n": float(t["n"]), "photons": int(t["photons"]), "seed": int(t["seed"]),
        "max_steps": int(t["max_steps"]), "lanes": int(t["lanes"]), "devices": 1, "seconds": float(t["seconds"]),
        "compile_seconds": float("nan"), "events": int(t["events"]), "r_edges": r_new, "pathlength_edges": p_new,
        "R": R.astype(np.float32), "R_stderr": E.astype(np.float32), "R_diffuse": float(t["R_diffuse"]),
        "R_diffuse_stderr": float(t["R_diffuse_stderr"]), "R_specular": float(t["R_specular"]),
        "step_cap_weight": float(t["step_cap_weight"]), "source": str(Path(path).name),
    }


def save_node(table: dict, directory: Path = FAMILY_DIR) -> Path:
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / node_file(table["g"], table["n"])
    np.savez_compressed(path, **{k: np.asarray(v) for k, v in table.items()})
    return path


def merge_nodes(a: dict, b: dict) -> dict:
    """Pool two runs of the same node (independent seeds): photon-weighted means of the cells, standard errors
    combined accordingly, costs and photons added. The pooled table is what one run of ``a + b`` photons estimates."""
    if (a["g"], a["n"]) != (b["g"], b["n"]) or not np.array_equal(a["r_edges"], b["r_edges"]):
        raise ValueError(f"merge_nodes: different nodes or grids ({a['g']}, {a['n']}) and ({b['g']}, {b['n']})")
    Na, Nb = float(a["photons"]), float(b["photons"])
    fa, fb = Na / (Na + Nb), Nb / (Na + Nb)
    out = dict(a)

    def mean(k):
        return fa * np.asarray(a[k], np.float64) + fb * np.asarray(b[k], np.float64)

    def err(k):
        return np.hypot(fa * np.asarray(a[k], np.float64), fb * np.asarray(b[k], np.float64))

    out.update(R=mean("R").astype(np.float32), R_stderr=err("R_stderr").astype(np.float32),
               R_diffuse=float(mean("R_diffuse")), R_diffuse_stderr=float(err("R_diffuse_stderr")),
               step_cap_weight=float(mean("step_cap_weight")), photons=int(Na + Nb),
               seconds=float(a["seconds"]) + float(b["seconds"]), events=int(a["events"]) + int(b["events"]),
               seeds=np.append(np.atleast_1d(a.get("seeds", a["seed"])), b["seed"]))
    return out


def node_photons(g: float) -> int:
    """Photons per generated node: a walk costs ~``1 / (1 - g)`` events per transport length, so high ``g`` gets
    fewer photons (the whole family generates in about an hour on 2 cores)."""
    return 200_000 if g <= 0.85 else 100_000


# --- The diffusion tail beyond L_MAX ------------------------------------------------------------------------------
_GL8_X, _GL8_W = (np.asarray(a) for a in np.polynomial.legendre.leggauss(8))


def _tail_shape(r_edges, L, n):
    """Annulus-averaged time-resolved diffusion reflectance shape (module docstring) at transport pathlengths ``L``
    (``(P,)``), without its amplitude: ``(M, P)``."""
    z0 = 1.0
    z1 = z0 + 4.0 * float(A_coefficient(n)) / 3.0  # z0 + 2 z_b, z_b = 2 A D, D = 1/3
    a, b = r_edges[:-1, None], r_edges[1:, None]
    rq = 0.5 * (b - a) * _GL8_X + 0.5 * (b + a)  # (M, 8)
    wq = rq * _GL8_W * (0.5 * (b - a)) / (0.5 * (b * b - a * a))  # rows sum to 1
    Lc = L[None, None, :]
    # Patterson-Chance-Wilson reflectance: L^-5/2 exp(-3 rho^2 / 4L) [z0 e^{-3 z0^2/4L} + z1 e^{-3 z1^2/4L}].
    s = Lc**-2.5 * np.exp(-0.75 * rq[..., None] ** 2 / Lc) * (
        z0 * np.exp(-0.75 * z0**2 / Lc) + z1 * np.exp(-0.75 * z1**2 / Lc))
    return np.einsum("mq,mqp->mp", wq, s)


def tail_edges() -> np.ndarray:
    """Pathlength edges of the synthetic tail bins, ``L_MAX`` to ``10^TAIL_LOG_END`` (transport units)."""
    k = round((TAIL_LOG_END - math.log10(L_MAX)) * TAIL_PER_DECADE)
    return np.logspace(math.log10(L_MAX), TAIL_LOG_END, k + 1)


def fit_tail(table: dict, valid: int) -> tuple[float, np.ndarray]:
    """Amplitude ``A`` of the diffusion tail fitted to the node's cells with ``L`` in ``[L_MAX / 4, L_MAX)`` (and
    the node's valid radii), and the tail's cells ``(M, T)`` on :func:`tail_edges` (per unit area, per bin).

    The amplitude is the ratio of the simulated weight in the fit window to the shape's (a weighted least-squares
    fit with Poisson weights proportional to the shape)."""
    r_e, p_e = table["r_edges"], table["pathlength_edges"]
    area = np.pi * np.diff(r_e**2)[:valid, None]
    lo = p_e[:-1] >= L_MAX / 4 * 0.9999
    Lc = np.sqrt(p_e[:-1][lo] * p_e[1:][lo])
    shape = _tail_shape(r_e[: valid + 1], Lc, table["n"]) * np.diff(p_e)[lo]
    data = table["R"][:valid][:, lo].astype(np.float64)
    A = float((data * area).sum() / (shape * area).sum())
    te = tail_edges()
    cells = A * _tail_shape(r_e, np.sqrt(te[1:] * te[:-1]), table["n"]) * np.diff(te)
    return A, cells


def valid_bins(table: dict, tail_cells: np.ndarray) -> int:
    """Radial bins of a node that are used (the rest are extrapolated).

    A bin at radius ``rho`` matters for absorptions up to ``mu' = 100 / (3 rho^2)`` (``rho = 10 l_d`` in diffusion
    theory; checked at no more than ``MU_CHECK_MAX = 0.03``, reduced albedo 0.97, so from ``rho = 33`` out): bins are used out to the first one (beyond the middle of the grid) whose value at that ``mu'`` --
    simulated cells weighted by ``exp(-mu' L)`` plus the diffusion tail -- has a relative standard error above
    ``1 / sqrt(MIN_COUNTS)``. Far out, the long paths dominate and the tail carries the row."""
    r_e, p_e = table["r_edges"], table["pathlength_edges"]
    rc = np.sqrt(r_e[1:] * np.maximum(r_e[:-1], r_e[1] / 4))
    mu = np.minimum((100.0 / 3.0) / rc**2, MU_CHECK_MAX)
    Lc = 0.5 * (p_e[1:] + p_e[:-1])
    w = np.exp(-mu[:, None] * Lc[None, :])
    te = tail_edges()
    wt = np.exp(-mu[:, None] * np.sqrt(te[1:] * te[:-1])[None, :])
    R = table["R"].astype(np.float64)
    E = table["R_stderr"].astype(np.float64)
    total = (R * w).sum(1) + (tail_cells * wt).sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(total > 0, np.sqrt(((E * w) ** 2).sum(1)) / total, np.inf)
    # A bin no photon reached is not measured, however small the tail's share makes its error look.
    rel = np.where(R.sum(1) > 0, rel, np.inf)
    bad = np.nonzero(rel > 1.0 / math.sqrt(MIN_COUNTS))[0]
    bad = bad[bad > len(rel) // 2]
    keep = int(bad[0]) if bad.size else len(rel)
    if np.any(R[:keep].sum(1) <= 0):
        raise RuntimeError(f"white family node (g={table['g']}, n={table['n']}): empty radial bins "
                           f"{np.nonzero(R[:keep].sum(1) <= 0)[0].tolist()}")
    return keep


# --- The family and its interpolation -----------------------------------------------------------------------------

class WhiteFamily(eqx.Module):
    """The white Monte Carlo tables of all nodes on the ``(g, n)`` grid, transport units; see :func:`load_white_family`.

    Attributes:
        r_edges: ``(M + 1,)`` radial edges, units of ``1/sigma_s'``.
        pathlength_edges: ``(P + 1,)`` pathlength edges, ``1/sigma_s'``: the simulated bins, then the diffusion tail.
        R: ``(G, N, M, P)`` diffuse reflectance per incident photon per unit area (``sigma_s'^2``), per pathlength
            bin; zero beyond a node's valid radii.
        D: ``(G, N, M, P_sim)`` the diffusion model's cells on the simulated pathlength bins (the tail's law and
            fitted amplitude): the shape of a node's profile beyond its valid radii.
        E: ``(G, N, M, P_sim)`` standard errors of the simulated cells of ``R`` (zero beyond a node's valid radii):
            the tables' Monte Carlo noise, for :func:`white_family_profile_stderr`.
        valid: ``(G, N)`` number of radial bins each node uses (the rest are extrapolated, see ``_node_log_profiles``).
        g_nodes, n_nodes: the grid (static tuples); n is the absolute index under air (``eta = n``).
        tail_weight: ``(G, N)`` weight the diffusion tail carries at ``sigma_a = 0`` over the whole plane.
        n_simulated: the first ``n_simulated`` pathlength bins are simulated, the rest are the tail (static).
    """

    r_edges: jax.Array
    pathlength_edges: jax.Array
    R: jax.Array
    D: jax.Array
    E: jax.Array
    valid: jax.Array
    tail_weight: jax.Array
    n_simulated: int = eqx.field(static=True)
    g_nodes: tuple = eqx.field(static=True)
    n_nodes: tuple = eqx.field(static=True)

    @property
    def log_r_centres(self):
        return log_r_centres(self.r_edges)

    @property
    def valid_mu_min(self) -> float:
        """Smallest valid ``sigma_a / sigma_s``: 0 (the diffusion tail continues the long paths); the interface of
        :class:`jaxsss.mc.WhiteTable`."""
        return 0.0


def load_white_family(directory=None) -> WhiteFamily:
    """Load the family's nodes from ``directory`` (default ``jaxsss/mc/data/family``); cached per directory.

    Every node of the grid (``G_NODES`` x ``N_NODES``) must be present; each gets its diffusion tail (:func:`fit_tail`)
    appended as pathlength bins beyond ``L_MAX``."""
    key = str(FAMILY_DIR if directory is None else Path(directory))
    if key not in _FAMILIES:
        with jax.ensure_compile_time_eval():  # host values even when first asked for inside a trace (jit, grad)
            _FAMILIES[key] = _build_family(Path(key))
    return _FAMILIES[key]


_FAMILIES: dict = {}


def _build_family(directory: Path) -> WhiteFamily:
    nodes = {}
    for g in G_NODES:
        for n in N_NODES:
            path = directory / node_file(g, n)
            if not path.exists():
                raise ValueError(f"load_white_family: missing node (g={g:g}, n={n:g}) in {directory}; generate it with "
                                 f"`python -m jaxsss.mc.make_white_tables --family --g {g:g} --n {n:g}`")
            nodes[g, n] = load_node(path)
    return family_from_nodes(nodes, G_NODES, N_NODES)


def load_node(path) -> dict:
    """One node's table (as written by :func:`save_node`), with ``g`` and ``n`` as floats."""
    with np.load(path) as z:
        t = {k: z[k] for k in z.files}
    for k in ("g", "n"):
        t[k] = float(t[k])
    return t


def prepare_node(t: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, float]:
    """A node's cells with the diffusion tail appended ``(M, P + T)``; the diffusion model's cells on the simulated
    pathlength bins ``(M, P)`` (the tail's law and amplitude at ``L' < L_MAX``, for the radii beyond the valid ones);
    the standard errors of the simulated cells ``(M, P)`` (zero beyond the valid radii); its number of valid radial
    bins; and the tail's weight over the whole plane at ``sigma_a = 0``."""
    te = tail_edges()
    M = len(t["r_edges"]) - 1
    A, cells = fit_tail(t, valid_bins(t, np.zeros((M, len(te) - 1))))
    v = valid_bins(t, cells)
    R = np.concatenate([t["R"].astype(np.float64), cells], axis=1)
    R[v:, : t["R"].shape[1]] = 0.0  # simulated cells beyond the valid radii: extrapolated instead
    E = t["R_stderr"].astype(np.float64)
    E[v:] = 0.0
    p_e = t["pathlength_edges"]
    Lc = np.sqrt(p_e[1:] * np.maximum(p_e[:-1], p_e[1] / 4))
    D = A * _tail_shape(t["r_edges"], Lc, t["n"]) * np.diff(p_e)
    # The tail over the whole plane (int 2 pi rho exp(-3 rho^2 / 4L) drho = 4 pi L / 3), by quadrature in log L.
    z1 = 1.0 + 4.0 * float(A_coefficient(t["n"])) / 3.0
    Lq = np.logspace(math.log10(L_MAX), 12, 4000)
    f = Lq**-1.5 * 4.0 * np.pi / 3.0 * (np.exp(-0.75 / Lq) + z1 * np.exp(-0.75 * z1**2 / Lq))
    return R, D, E, v, A * float(np.trapezoid(f, Lq))


def family_from_nodes(nodes: dict, g_nodes, n_nodes) -> WhiteFamily:
    """A :class:`WhiteFamily` from node tables ``{(g, n): table}`` covering ``g_nodes`` x ``n_nodes`` (each sorted,
    at least two values; one value each is allowed for evaluating a single node)."""
    r_edges, p_edges = common_edges()
    rows, diff, errs, valid, tails = [], [], [], [], []
    for g in g_nodes:
        prep = [prepare_node(nodes[g, n]) for n in n_nodes]
        rows.append([p[0] for p in prep])
        diff.append([p[1] for p in prep])
        errs.append([p[2] for p in prep])
        valid.append([p[3] for p in prep])
        tails.append([p[4] for p in prep])
    return WhiteFamily(r_edges=jnp.asarray(r_edges),
                       pathlength_edges=jnp.asarray(np.concatenate([p_edges, tail_edges()[1:]])),
                       R=jnp.asarray(np.array(rows)), D=jnp.asarray(np.array(diff)),
                       E=jnp.asarray(np.array(errs)), valid=jnp.asarray(np.array(valid), jnp.int32),
                       tail_weight=jnp.asarray(np.array(tails)), n_simulated=len(p_edges) - 1, g_nodes=tuple(float(g) for g in g_nodes),
                       n_nodes=tuple(float(n) for n in n_nodes))


def _hermite_weights(x, nodes, xp=jnp):
    """Weights ``w`` (``x.shape + (K,)``) with ``sum_k w_k y_k`` the cubic Hermite interpolant of node values ``y_k``
    at ``x``: centred-difference slopes at inner nodes, one-sided at the ends (C1, exact at the nodes, linear in y).
    ``xp``: the array module, ``jax.numpy`` (traced) or ``numpy`` (a concrete ``(g, n)`` on the host, where eager JAX
    would compile each operation: 0.9 s of a process's first white-kernel render)."""
    xs = np.asarray(nodes, np.float64)
    K = xs.size
    if K == 1:  # a single node: its own values
        return xp.ones(xp.shape(x) + (1,))
    # Slopes m = S y.
    S = np.zeros((K, K))
    S[0, 0], S[0, 1] = -1.0 / (xs[1] - xs[0]), 1.0 / (xs[1] - xs[0])
    S[-1, -2], S[-1, -1] = -1.0 / (xs[-1] - xs[-2]), 1.0 / (xs[-1] - xs[-2])
    for k in range(1, K - 1):
        S[k, k - 1], S[k, k + 1] = -1.0 / (xs[k + 1] - xs[k - 1]), 1.0 / (xs[k + 1] - xs[k - 1])
    xs_j, S_j = xp.asarray(xs), xp.asarray(S)
    i = xp.clip(xp.searchsorted(xs_j, x, side="right") - 1, 0, K - 2)
    h = xs_j[i + 1] - xs_j[i]
    t = (x - xs_j[i]) / h
    t2, t3 = t * t, t * t * t
    e = xp.eye(K)
    # Cubic Hermite basis: h00 y_i + h10 h m_i + h01 y_{i+1} + h11 h m_{i+1}.
    h00, h10, h01, h11 = 2 * t3 - 3 * t2 + 1, t3 - 2 * t2 + t, -2 * t3 + 3 * t2, t3 - t2
    return (h00[..., None] * e[i] + h01[..., None] * e[i + 1]
            + (h * h10)[..., None] * S_j[i] + (h * h11)[..., None] * S_j[i + 1])


def _node_parts(mu, fam: WhiteFamily, noise: bool = False):
    """Every node's annulus averages at ``mu' = sigma_a / sigma_s'`` in two parts, ``mu.shape + (G, N, M)`` each:
    ``log`` of the simulated part (``L' < L_MAX``, extrapolated beyond the valid radii, see
    :func:`_node_log_profiles`) and ``log`` of the diffusion tail; with ``noise``, also the simulated part's relative
    standard error (beyond the valid radii: that of the match factor)."""
    L0 = fam.pathlength_edges[:-1]
    dL = jnp.diff(fam.pathlength_edges)
    logw = _log_mean_exp(mu[..., None], L0, dL)  # (..., P + T)
    P = fam.n_simulated

    def part(R, lw, square=False):
        # R_node(rho) = sum_L Rtab(rho, L) <exp(-mu L)>: one matrix product, shifted by the largest weight.
        top = jnp.max(lw, axis=-1, keepdims=True)
        k = 2.0 if square else 1.0
        s = jnp.einsum("gnmp,...p->...gnm", R, jnp.exp(k * (lw - top)))
        return jnp.log(jnp.maximum(s, 1e-300)) + k * top[..., None, None]

    y = part(fam.R[..., :P], logw[..., :P])
    y_dif = part(fam.D, logw[..., :P])
    m = jnp.arange(fam.r_edges.shape[0] - 1, dtype=fam.valid.dtype)
    inside = m < fam.valid[..., None]
    # log(simulation / model), averaged over the last N_MATCH valid bins of each node.
    near = inside & (m >= fam.valid[..., None] - N_MATCH)  # (G, N, M)
    match = jnp.sum(jnp.where(near, y - y_dif, 0.0), axis=-1, keepdims=True) / N_MATCH
    y_sim = jnp.where(inside, y, y_dif + match)
    y_tail = part(fam.R[..., P:], logw[..., P:])
    if not noise:
        return y_sim, y_tail
    # Relative standard error of the simulated cells' sum (cells independent): sqrt(sum (E w)^2) / sum(R w).
    rel = jnp.exp(0.5 * part(fam.E**2, logw[..., :P], square=True) - y)
    rel_match = jnp.sqrt(jnp.sum(jnp.where(near, rel**2, 0.0), axis=-1, keepdims=True)) / N_MATCH
    return y_sim, y_tail, jnp.where(inside, rel, rel_match)


def _node_log_profiles(mu, fam: WhiteFamily):
    """``log`` of every node's annulus averages at ``mu' = sigma_a / sigma_s'``: ``mu.shape + (G, N, M)``.

    The simulated part (``L' < L_MAX``) and the diffusion tail are summed apart. Beyond a node's valid radial bins the
    simulated part follows the diffusion model (:func:`_tail_shape` with the node's amplitude, on the simulated
    pathlength bins), scaled to meet the simulation: times the mean ratio of simulation to model over the last
    ``N_MATCH`` valid bins, at the same ``mu'``. Far from the source at weak absorption the paths are long and
    diffusive, so the model carries the shape there (measured against 10^6-photon tables: within ~5% at 20-100
    transport lengths, n = 1 to 1.4). Every node then has values on the common grid, as the interpolation needs."""
    y_sim, y_tail = _node_parts(mu, fam)
    return jnp.logaddexp(y_sim, y_tail)


def log_bin_profile(mu, g, n, fam: WhiteFamily):
    """``log`` of the family's annulus averages (before the radial spline) at ``mu' = sigma_a / sigma_s'``, in
    transport units: ``broadcast(mu, g, n).shape + (M,)``. The quantity the interpolation over nodes acts on."""
    return _log_bin_profile(*(jnp.asarray(x, jnp.float64) for x in (mu, g, n)), fam)


@eqx.filter_jit
def _log_bin_profile(mu, g, n, fam: WhiteFamily):
    wg = _hermite_weights(jnp.asarray(g, jnp.float64), fam.g_nodes)  # (..., G)
    wn = _hermite_weights(jnp.asarray(n, jnp.float64), fam.n_nodes)  # (..., N)
    return _weighted_log_bins(jnp.asarray(mu, jnp.float64), wg, wn, fam)


def _weighted_log_bins(mu, wg, wn, fam: WhiteFamily):
    ynodes = _node_log_profiles(mu, fam)  # (..., G, N, M)
    # log R interpolated over the nodes (cubic Hermite in g and in n).
    return jnp.einsum("...gnm,...g,...n->...m", ynodes, wg, wn)


STENCIL = 4  # nodes per axis that carry a non-zero Hermite weight (the cell's two and one either side)
_BLOCKS: dict = {}


def _block(fam: WhiteFamily, g: float, n: float):
    """For concrete scalar ``(g, n)``: the ``STENCIL x STENCIL`` block of nodes that holds every non-zero weight, as
    a sub-family, and the full family's weights on it -- the same result as the whole grid, at 16 of its nodes.

    The block's node tuples are empty (the weights carry its position in the grid), so every block has one pytree
    structure: a program that takes ``(wg, wn, block)`` as arguments compiles once for every ``(g, n)`` (a fit's
    compiled program, :func:`block_operands`; the kernels here, which ``filter_jit`` traces per structure)."""
    out = []
    for x, nodes in ((g, fam.g_nodes), (n, fam.n_nodes)):
        w = _hermite_weights(np.float64(x), nodes, xp=np)
        k = min(STENCIL, len(nodes))
        i = int(np.clip(np.searchsorted(nodes, x, side="right") - 2, 0, len(nodes) - k))
        assert not np.any(np.delete(w, np.arange(i, i + k))), "Hermite support wider than the stencil"
        out.append((i, k, w[i:i + k]))
    (ig, kg, wg), (in_, kn, wn) = out
    key = (id(fam), ig, in_)
    if key not in _BLOCKS:
        sl = (slice(ig, ig + kg), slice(in_, in_ + kn))
        _BLOCKS[key] = (fam, WhiteFamily(
            r_edges=fam.r_edges, pathlength_edges=fam.pathlength_edges, R=fam.R[sl], D=fam.D[sl], E=fam.E[sl],
            valid=fam.valid[sl], tail_weight=fam.tail_weight[sl], n_simulated=fam.n_simulated, g_nodes=(),
            n_nodes=()))
    return _BLOCKS[key][1], jnp.asarray(wg), jnp.asarray(wn)


def block_operands(g: float, n: float, family: WhiteFamily | None = None):
    """``(wg, wn, block)`` for a concrete scalar ``(g, n)`` inside the grid: the Hermite weights ``(STENCIL,)`` in
    ``g`` and in ``n`` and the block of nodes they fall on (:func:`_block`). Arrays only, of one structure and shape
    for every ``(g, n)``: pass them to :func:`white_family_block_profile` as runtime arguments of a compiled program,
    and one compilation serves every ``(g, n)`` (the fitting layer's ``mc`` model)."""
    fam = load_white_family() if family is None else family
    check_covered(g, n, owner="block_operands")
    with jax.ensure_compile_time_eval():  # concrete even when called inside a trace (the host's (g, n))
        sub, wg, wn = _block(fam, float(g), float(n))
    return wg, wn, sub


def white_family_block_profile(r, sigma_a, sigma_s_prime, operands):
    """:func:`white_family_profile` from :func:`block_operands` (traceable; no argument checks: the caller's)."""
    return _family_kernel(r, sigma_a, sigma_s_prime, *operands)


@eqx.filter_jit
def _family_kernel(r, sigma_a, sigma_s_prime, wg, wn, fam: WhiteFamily):
    shape = jnp.broadcast_shapes(jnp.shape(r), jnp.shape(sigma_a), jnp.shape(sigma_s_prime), wg.shape[:-1],
                                 wn.shape[:-1])
    ybin = _weighted_log_bins(sigma_a / sigma_s_prime, wg, wn, fam)
    ys = _node_values(ybin, fam)
    ys = jnp.broadcast_to(ys, shape + ys.shape[-1:])
    rho = jnp.broadcast_to(r * sigma_s_prime, shape)
    y = _log_eval(rho[..., None], fam.log_r_centres, ys)[..., 0]
    return sigma_s_prime * sigma_s_prime * jnp.exp(y)


def white_family_profile(r, sigma_a, sigma_s_prime, g, n, family: WhiteFamily | None = None):
    """Transport-accurate radial diffuse reflectance ``R(r)`` of a half-space for any ``(g, n)`` inside the grid.

    White Monte Carlo (module docstring): each node's table is scaled exactly to ``(sigma_a, sigma_s')``, ``log R``
    of the nodes is interpolated by cubic Hermite splines in ``g`` and in ``n`` (exact at the nodes, C1 between),
    then in ``r`` as in :func:`jaxsss.mc.white_mc_profile`. Normalisation: **per incident photon per mm^2** (specular
    excluded), normal incidence, air above (``eta = n``). Valid for every ``sigma_a >= 0`` (the diffusion tail
    covers the long paths). Jitted, differentiable in ``r``, ``sigma_a``, ``sigma_s_prime``, ``g`` and ``n``.

    Args:
        r: distance from the point of entry, mm, ``>= 0``.
        sigma_a: absorption coefficient, 1/mm, ``>= 0``.
        sigma_s_prime: reduced scattering coefficient, 1/mm, ``> 0``.
        g: Henyey-Greenstein anisotropy, in ``[G_NODES[0], G_NODES[-1]]`` (0 to 0.95).
        n: absolute refractive index of the medium under air, in ``[N_NODES[0], N_NODES[-1]]`` (1 to 1.6).
        family: a :class:`WhiteFamily` (default: the shipped one, :func:`load_white_family`).

    All arrays broadcast (NumPy rules).

    Returns:
        ``R(r)`` in 1/mm^2, of the broadcast shape.

    Raises:
        ValueError: an argument outside its range (naming it, its value and the range).
    """
    return _dispatch(_family_kernel, "white_family_profile", r, sigma_a, sigma_s_prime, g, n, family)


def _dispatch(kernel, owner, r, sigma_a, sigma_s_prime, g, n, family):
    """Check the arguments (errors name ``owner``) and run ``kernel`` with the Hermite weights: at a fixed scalar
    ``(g, n)``, as in fits, on the block of nodes around it only (:func:`_block`); otherwise on the whole grid."""
    fam = load_white_family() if family is None else family
    if not isinstance(fam, WhiteFamily):
        raise ValueError(f"{owner}(family={family!r}) must be a WhiteFamily (see load_white_family)")
    r = check_range(r, "r", 0.0, None, owner=owner)
    sigma_a = check_range(sigma_a, "sigma_a", 0.0, None, owner=owner)
    sigma_s_prime = check_range(sigma_s_prime, "sigma_s_prime", 0.0, None, lo_open=True, owner=owner)
    g = check_range(g, "g", fam.g_nodes[0], fam.g_nodes[-1], owner=owner)
    n = check_range(n, "n", fam.n_nodes[0], fam.n_nodes[-1], owner=owner)
    if is_concrete(g) and is_concrete(n) and np.ndim(g) == 0 and np.ndim(n) == 0:
        sub, wg, wn = _block(fam, float(g), float(n))
        return kernel(r, sigma_a, sigma_s_prime, wg, wn, sub)
    return kernel(r, sigma_a, sigma_s_prime, _hermite_weights(g, fam.g_nodes), _hermite_weights(n, fam.n_nodes), fam)


@eqx.filter_jit
def _family_stderr_kernel(r, sigma_a, sigma_s_prime, wg, wn, fam: WhiteFamily):
    shape = jnp.broadcast_shapes(jnp.shape(r), jnp.shape(sigma_a), jnp.shape(sigma_s_prime), wg.shape[:-1],
                                 wn.shape[:-1])
    y_sim, y_tail, rel = _node_parts(sigma_a / sigma_s_prime, fam, noise=True)
    # Each node's relative error: its simulated part's, times that part's share (the tail is taken as exact).
    rel_node = rel * jnp.exp(y_sim - jnp.logaddexp(y_sim, y_tail))
    # log R = sum_k w_k log R_k over independent nodes: var = sum_k w_k^2 var_k.
    rel_bin = jnp.sqrt(jnp.einsum("...gnm,...g,...n->...m", rel_node**2, wg**2, wn**2))
    rel_bin = jnp.broadcast_to(rel_bin, shape + rel_bin.shape[-1:])
    rho = jnp.broadcast_to(r * sigma_s_prime, shape)
    i = jnp.clip(jnp.searchsorted(fam.r_edges, rho, side="right") - 1, 0, rel_bin.shape[-1] - 1)
    return jnp.take_along_axis(rel_bin, i[..., None], axis=-1)[..., 0]


def white_family_profile_stderr(r, sigma_a, sigma_s_prime, g, n, family: WhiteFamily | None = None):
    """Relative standard error of :func:`white_family_profile` from the nodes' Monte Carlo noise: the annulus that
    holds ``r``, the nodes' errors combined with the interpolation weights (nodes and cells independent; the
    diffusion tail and the far-field shape taken as exact, the match of that shape to the simulation not).

    The model's own precision, to set beside the data's: it grows far from the source at weak absorption (few photons
    travel that far) and near the source at strong absorption (few short paths leave at that radius), where a fit can
    stop in a local minimum of the tables' noise. Same arguments and shapes as :func:`white_family_profile`; not
    differentiable in any useful sense."""
    return _dispatch(_family_stderr_kernel, "white_family_profile_stderr", r, sigma_a, sigma_s_prime, g, n, family)


def covers(g, n) -> bool:
    """Whether ``(g, n)`` lies inside the family's grid (``n``: absolute index under air, i.e. ``eta``)."""
    g, n = float(g), float(n)
    return G_NODES[0] <= g <= G_NODES[-1] and N_NODES[0] <= n <= N_NODES[-1]


def check_covered(g, n, owner: str = "white_family") -> None:
    """Raise ``ValueError`` naming ``g`` or ``eta`` (``= n``, ambient index 1), its value and the family's range when
    ``(g, n)`` is outside the grid (or NaN). ``owner`` prefixes the message, e.g. ``fit_profile(model='mc', ...)``."""
    for name, v, nodes in (("g", g, G_NODES), ("eta", n, N_NODES)):
        v = float(v)
        if not nodes[0] <= v <= nodes[-1]:
            raise ValueError(f"{owner}: {name}={v:g} is outside the white Monte Carlo family's range "
                             f"[{nodes[0]:g}, {nodes[-1]:g}] (grid nodes {', '.join(f'{x:g}' for x in nodes)})")
