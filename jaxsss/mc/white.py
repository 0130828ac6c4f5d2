"""White ("scaled") Monte Carlo: a transport-accurate, differentiable radial reflectance model (Kienle and Patterson 1996).

One *non-absorbing* run of :func:`jaxsss.mc.simulate` per ``(g, n)`` records the reflectance histogram
``Rtab(rho, L)`` over exit radius ``rho`` and total pathlength ``L`` inside the medium, in **optical units** (the run
uses ``sigma_s = 1/mm``, so ``rho`` and ``L`` are in units of ``1/sigma_s``). Half-space, index ``n`` under air,
normal incidence. Any ``(sigma_a, sigma_s')`` with the same ``g`` and ``n`` then follows exactly by scaling: with
``sigma_s = sigma_s' / (1 - g)`` and ``mu = sigma_a / sigma_s``,

    R(r; sigma_a, sigma_s') = sigma_s^2 * sum_L Rtab(r sigma_s, L) * <exp(-mu L)>_bin(L),

because absorption along a path of optical length ``L`` multiplies the photon's weight by ``exp(-mu L)`` and
lengths scale with ``1/sigma_s`` (areas with ``1/sigma_s^2``).

Numerical choices (docs/architecture.md, "Monte Carlo"):

- Pathlength bins: 0, then 40 log-spaced bins per decade from 1e-2 to ``path_max`` (1e4 for g = 0, 3e4 for
  g = 0.9). ``<exp(-mu L)>_bin`` is the exact average of ``exp(-mu L)`` over the bin for a uniform density of ``L``
  within it: ``exp(-mu L_0) (1 - exp(-mu dL)) / (mu dL)``. The true density falls like ``L^-1.5`` inside a bin;
  at 40 bins per decade the resulting bias is below 0.1% for ``mu L < 1``, about 0.4% at ``mu L = 10``.
- Radii: a first bin ``[0, 1e-2)``, then 20 log-spaced bins per decade to 10^3.5 optical units, trimmed where the
  bin holds fewer than ~100 photons (shipped: out to 200-224 optical units for g = 0, i.e. 200 l_u; 1259 for
  g = 0.9, i.e. 126 l_u). Leading bins with < ~100 photons are merged into the first (g = 0.9 sends almost
  nothing back near the source: its first bin is [0, 0.05) for n = 1 and [0, 0.07) for n = 1.4, i.e. < 0.01 l_u,
  with the 1e6-photon tables).
  Between bin centres (geometric centres; ``r_1 / 2`` for the first) the model
  interpolates ``log R`` with a cubic Hermite spline in ``log r`` (centred-difference slopes): smooth in ``r`` and in
  the coefficients. **Below the first centre** ``R`` is held constant (the disk average over ``r < 1e-2 / sigma_s``,
  finite at ``r = 0``). **Beyond the last centre** ``log R`` continues linearly in ``r`` with the slope of the last
  two centres (clipped at <= 0): an exponential tail, a documented extrapolation, not transport.
- Bin values are annulus averages, not point values: the node values are corrected (three fixed-point iterations
  in log space, differentiable) so that the interpolant's average over every annulus reproduces the table; used
  as point values at the geometric centres they would put the plane integral 0.5-1.3% low.
- Truncation: photons with ``L > path_max`` (or killed by the step cap) are not in the table; each table records
  that weight (``lost_weight``: 1.7% / 2.6% / 2.8% for g = 0, n = 1 / 1.33 / 1.4; 3.1% / 5.1% for g = 0.9, n = 1
  / 1.4). This biases R low
  where paths that long still carry weight: at radius ``r`` the dominant paths have ``mu L ~ r / (2 l_d)``, so the
  model is valid (bias < ~1%) up to ``r ~ 10 l_d`` for ``mu >= table.valid_mu_min = 20 / path_max``: 2e-3 for
  g = 0 and 6.7e-4 for g = 0.9 (``sigma_a / sigma_s' >= 2e-3`` and ``>= 6.7e-3``). The bound is conservative: at
  half of it (g = 0, alpha' = 0.999) totals still agree with direct runs to 0.2% (docs/transport_error.md).

Normalisation: **per incident photon per mm^2**, the engine's convention -- the specular reflection of the first
surface is excluded, so the profile integrates over the plane to ``R_diffuse`` (per incident photon, not per photon
entering). The diffusion profiles of :mod:`jaxsss.profiles` are per unit flux *entering*; multiply those by
``1 - fresnel_reflectance(eta, 1.0)`` to compare.

Regenerate the shipped tables with ``python -m jaxsss.mc.make_white_tables --regenerate`` (``--help`` for options).
"""

from __future__ import annotations

import math
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxsss import _config  # noqa: F401  (float64)
from jaxsss.validate import check_range

__all__ = [
    "WhiteTable",
    "available_white_tables",
    "generate_white_table",
    "load_white_table",
    "white_mc_medium_profile",
    "white_mc_profile",
    "white_mc_profile_stderr",
    "white_table_profile",
]

TABLE_DIR = Path(__file__).resolve().parent / "data"
STANDARD_PAIRS = ((0.0, 1.0), (0.0, 1.33), (0.0, 1.4), (0.9, 1.0), (0.9, 1.33), (0.9, 1.4))
"""The ``(g, n)`` pairs shipped in ``jaxsss/mc/data`` (n = 1.33: water-based media such as milk); others with
``python -m jaxsss.mc.make_white_tables --regenerate --g G --n N``."""
# Photons, pathlength cap (optical units) and lanes per g; the seed is fixed per pair (see _seed).
GENERATION = {0.0: {"photons": 1_000_000, "path_max": 1e4, "lanes": 4096},
              0.9: {"photons": 1_000_000, "path_max": 3e4, "lanes": 2048}}
R_FIRST_EDGE = 1e-2
R_PER_DECADE = 20
R_LOG_MAX = 3.5
PATH_FIRST_EDGE = 1e-2
PATH_PER_DECADE = 40
MIN_COUNTS = 100.0  # r bins with fewer (estimated) photons than this at the far end are trimmed


def _file_name(g: float, n: float) -> str:
    return f"white_g{g:.2f}_n{n:.2f}.npz"


def _seed(g: float, n: float) -> int:
    return 1000 + round(100 * g) * 1000 + round(100 * n)


def table_edges(path_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Default ``(r_edges, pathlength_edges)`` in optical units (see the module docstring)."""
    n_r = round((R_LOG_MAX - math.log10(R_FIRST_EDGE)) * R_PER_DECADE)
    r_edges = np.concatenate([[0.0], np.logspace(math.log10(R_FIRST_EDGE), R_LOG_MAX, n_r + 1)])
    n_p = math.ceil((math.log10(path_max) - math.log10(PATH_FIRST_EDGE)) * PATH_PER_DECADE)
    p_edges = np.concatenate([[0.0], np.logspace(math.log10(PATH_FIRST_EDGE), math.log10(path_max), n_p + 1)])
    return r_edges, p_edges


def generate_white_table(g: float, n: float, photons: int, *, path_max: float = 1e4, seed: int = 0,
                         lanes: int | None = None, max_steps: int | None = None, angle_deg: float = 0.0) -> dict:
    """Run the non-absorbing half-space (``sigma_s = 1``, anisotropy ``g``, index ``n`` under air) and return the
    table as a dict of NumPy arrays and scalars (what :func:`save` writes). ``angle_deg``: incidence from the normal
    (degrees, in air); the radial bins are then about the point of entry, averaged over azimuth."""
    from jaxsss.mc.engine import simulate
    from jaxsss.mc.stack import Stack

    r_edges, p_edges = table_edges(path_max)
    # A step is ~1 optical unit on average, so a walk reaching L = path_max takes ~path_max events (+ surface hits).
    max_steps = int(1.2 * path_max) if max_steps is None else max_steps
    res = simulate(Stack.half_space(0.0, 1.0, g, n), photons, seed=seed, r_edges=r_edges, pathlength_edges=p_edges,
                   batch_size=photons, lanes=lanes, max_steps=max_steps, progress=False, angle_deg=angle_deg)
    R, R_err, area = res.R_r_path, res.R_r_path_stderr, res.annulus_areas
    # Leading bins with few photons (g = 0.9 sends almost nothing back within 1e-2 of the source) are merged into
    # the first bin [0, r_k): area-weighted averages, errors added in quadrature.
    R_r = R.sum(axis=1)
    err_r = np.sqrt((R_err**2).sum(axis=1))  # one photon falls in one cell: cell variances add (to O(1/N))
    with np.errstate(divide="ignore", invalid="ignore"):
        counts = np.where(err_r > 0, (R_r / err_r) ** 2, 0.0)
    half = len(R_r) // 2
    sparse = np.nonzero(counts[:half] < MIN_COUNTS)[0]
    k = int(sparse.max()) + 1 if sparse.size else 1
    if k > 1:
        a = area[:k, None]
        R = np.concatenate([(R[:k] * a).sum(0, keepdims=True) / a.sum(), R[k:]])
        R_err = np.concatenate([np.sqrt(((R_err[:k] * a) ** 2).sum(0, keepdims=True)) / a.sum(), R_err[k:]])
        r_edges = np.concatenate([[0.0], r_edges[k:]])
        area = np.pi * np.diff(r_edges**2)
        R_r = R.sum(axis=1)
        err_r = np.sqrt((R_err**2).sum(axis=1))
        with np.errstate(divide="ignore", invalid="ignore"):
            counts = np.where(err_r > 0, (R_r / err_r) ** 2, 0.0)
    # Trim the far end where bins hold fewer than MIN_COUNTS photons.
    keep = len(R_r)
    few = np.nonzero(counts < MIN_COUNTS)[0]
    few = few[few > len(R_r) // 2]
    if few.size:
        keep = int(few[0])
    if np.any(R_r[:keep] <= 0):
        raise RuntimeError(f"generate_white_table: empty radial bins {np.nonzero(R_r[:keep] <= 0)[0].tolist()}; "
                           "use more photons")
    in_table = float((R_r[:keep] * area[:keep]).sum())
    return {
        "g": g, "n": n, "angle_deg": angle_deg, "photons": photons, "seed": seed, "path_max": path_max, "max_steps": max_steps,
        "lanes": res.lanes, "seconds": res.seconds, "events": res.events,
        "r_edges": r_edges[: keep + 1], "pathlength_edges": p_edges,
        "R": R[:keep].astype(np.float32), "R_stderr": R_err[:keep].astype(np.float32), "R_r": R_r[:keep], "R_r_stderr": err_r[:keep],
        "R_diffuse": res.R_diffuse, "R_diffuse_stderr": res.R_diffuse_stderr, "R_in_table": in_table,
        "step_cap_weight": res.step_cap_weight, "lost_weight": 1.0 - res.R_specular - in_table,
        "R_specular": res.R_specular,
    }


def save(table: dict, directory: Path) -> Path:
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / _file_name(table["g"], table["n"])
    np.savez_compressed(path, **{k: np.asarray(v) for k, v in table.items()})
    return path


class WhiteTable(eqx.Module):
    """A white Monte Carlo table ``Rtab(rho, L)`` (optical units) for one ``(g, n)``; load with
    :func:`load_white_table`.

    Attributes:
        r_edges: ``(M + 1,)`` radial edges, units of ``1/sigma_s``.
        pathlength_edges: ``(P + 1,)`` pathlength edges, units of ``1/sigma_s``.
        R: ``(M, P)`` diffuse reflectance per incident photon per unit area (``sigma_s^2``), per pathlength bin
            (not divided by its width); R_stderr: its per-cell standard error (per-photon second moments).
        g, n: anisotropy and absolute index of the medium (ambient index 1: ``eta = n``). Static.
        photons: photons of the generating run; lost_weight: incident weight that exited beyond the last
            pathlength bin, was killed by the step cap or fell outside the radial range (non-absorbing, so
            ``R_specular + R_in_table + lost_weight = 1``). Static.
    """

    r_edges: jax.Array
    pathlength_edges: jax.Array
    R: jax.Array
    R_stderr: jax.Array
    g: float = eqx.field(static=True)
    n: float = eqx.field(static=True)
    photons: int = eqx.field(static=True)
    path_max: float = eqx.field(static=True)
    lost_weight: float = eqx.field(static=True)

    @property
    def log_r_centres(self):
        return log_r_centres(self.r_edges)

    @property
    def valid_mu_min(self) -> float:
        """Smallest ``sigma_a / sigma_s`` for which the truncation bias stays below ~1% up to ``r = 10 l_d``."""
        return 20.0 / self.path_max


def log_r_centres(r_edges):
    """``log`` of the radial bins' centres: geometric centres, ``r_1 / 2`` for the first bin ``[0, r_1)``."""
    c = jnp.sqrt(r_edges[1:] * r_edges[:-1])
    return jnp.log(c.at[0].set(0.5 * r_edges[1]))


def available_white_tables(directory=None) -> list[tuple[float, float]]:
    """The ``(g, n)`` pairs with a table in ``directory`` (default: the package's ``jaxsss/mc/data``)."""
    directory = TABLE_DIR if directory is None else Path(directory)
    out = []
    for p in sorted(directory.glob("white_g*_n*.npz")):
        stem = p.stem[len("white_g"):]
        g, n = stem.split("_n")
        out.append((float(g), float(n)))
    return out


def load_white_table(g: float, n: float, directory=None) -> WhiteTable:
    """Load the shipped table for anisotropy ``g`` and absolute index ``n`` (ambient 1).

    Raises:
        ValueError: no table for ``(g, n)``; the message lists the available pairs and the regeneration command.
    """
    directory = TABLE_DIR if directory is None else Path(directory)
    path = directory / _file_name(float(g), float(n))
    if not path.exists():
        pairs = ", ".join(f"(g={a:g}, n={b:g})" for a, b in available_white_tables(directory)) or "none"
        raise ValueError(f"load_white_table(g={g!r}, n={n!r}): no white Monte Carlo table for this pair; available: "
                         f"{pairs}. Generate one with `python -m jaxsss.mc.make_white_tables --regenerate --g {g} --n {n}`")
    with np.load(path) as z:
        return WhiteTable(r_edges=jnp.asarray(z["r_edges"], jnp.float64),
                          pathlength_edges=jnp.asarray(z["pathlength_edges"], jnp.float64),
                          R=jnp.asarray(z["R"], jnp.float64), R_stderr=jnp.asarray(z["R_stderr"], jnp.float64), g=float(z["g"]), n=float(z["n"]),
                          photons=int(z["photons"]), path_max=float(z["path_max"]),
                          lost_weight=float(z["lost_weight"]))


def table_info(g: float, n: float, directory=None) -> dict:
    """The generation metadata of a table (photons, seconds, R_diffuse, lost weight, ...), as plain Python values."""
    directory = TABLE_DIR if directory is None else Path(directory)
    load_white_table(g, n, directory)  # the error message for a missing pair
    with np.load(directory / _file_name(float(g), float(n))) as z:
        return {k: z[k].item() for k in z.files if z[k].ndim == 0}


# --- The model ----------------------------------------------------------------------------------------------------
def _log_mean_exp(mu, L0, dL):
    """``log <exp(-mu L)>`` over ``[L0, L0 + dL]`` (uniform in L): ``-mu L0 + log((1 - e^-x) / x)``, ``x = mu dL``."""
    x = mu * dL
    small = x < 1e-3
    xs = jnp.where(small, 1.0, x)
    big = jnp.log(-jnp.expm1(-xs)) - jnp.log(xs)
    series = -0.5 * x + x * x / 24.0
    return -mu * L0 + jnp.where(small, series, big)


def _log_profile_nodes(mu, table: WhiteTable):
    """``log R`` at the table's radial centres (optical units), shape ``mu.shape + (M,)``."""
    L0 = table.pathlength_edges[:-1]
    dL = jnp.diff(table.pathlength_edges)
    logw = _log_mean_exp(mu[..., None], L0, dL)  # (..., P)
    return jax.nn.logsumexp(logw[..., None, :], axis=-1, b=table.R)  # (..., M)


def _hermite(x, xs, ys):
    """Cubic Hermite interpolation of ``ys`` (``(..., M)``) at ``x`` (``(..., K)``), centred-difference slopes;
    constant below ``xs[0]`` and above ``xs[-1]`` (the caller handles the tail)."""
    M = xs.shape[0]
    dx = jnp.diff(xs)
    sec = jnp.diff(ys, axis=-1) / dx
    m_inner = (ys[..., 2:] - ys[..., :-2]) / (xs[2:] - xs[:-2])
    m = jnp.concatenate([sec[..., :1], m_inner, sec[..., -1:]], axis=-1)
    xc = jnp.clip(x, xs[0], xs[-1])
    # A comparison with every node where that is small (jnp.searchsorted's default traces a binary-search scan).
    method = "compare_all" if int(np.prod(jnp.shape(xc))) * M <= 1 << 20 else "scan"
    i = jnp.clip(jnp.searchsorted(xs, xc, side="right", method=method) - 1, 0, M - 2)
    h = dx[i]
    t = (xc - xs[i]) / h
    y0, y1 = jnp.take_along_axis(ys, i, axis=-1), jnp.take_along_axis(ys, i + 1, axis=-1)
    m0, m1 = jnp.take_along_axis(m, i, axis=-1), jnp.take_along_axis(m, i + 1, axis=-1)
    t2, t3 = t * t, t * t * t
    return (2 * t3 - 3 * t2 + 1) * y0 + (t3 - 2 * t2 + t) * h * m0 + (-2 * t3 + 3 * t2) * y1 + (t3 - t2) * h * m1


def _log_eval(rho, xs, ys):
    """``log R`` at optical radii ``rho`` (``(..., K)``) from node values ``ys`` (``(..., M)``) at ``exp(xs)``:
    held constant below the first node, Hermite inside, linear in ``rho`` beyond the last node (slope <= 0)."""
    batch = jnp.broadcast_shapes(rho.shape[:-1], ys.shape[:-1])
    rho = jnp.broadcast_to(rho, batch + rho.shape[-1:])
    ys = jnp.broadcast_to(ys, batch + ys.shape[-1:])
    x = jnp.log(jnp.maximum(rho, jnp.exp(xs[0])))
    inner = _hermite(x, xs, ys)
    c1, c2 = jnp.exp(xs[-2]), jnp.exp(xs[-1])
    slope = jnp.minimum((ys[..., -1:] - ys[..., -2:-1]) / (c2 - c1), 0.0)
    beyond = rho > c2
    tail = ys[..., -1:] + slope * (jnp.where(beyond, rho, c2) - c2)
    return jnp.where(beyond, tail, inner)


_GL_X, _GL_W = (np.asarray(a) for a in np.polynomial.legendre.leggauss(8))
N_CORRECTIONS = 3


def _node_values(log_bin_avg, table: WhiteTable):
    """Node values whose interpolant reproduces the table's *annulus averages* (fixed-point iterations in log space).

    The table holds the average of R over each annulus; using it as the point value at the geometric centre would
    shift a steep profile inwards (plane integral ~0.5-1.3% low). Each iteration averages the current interpolant over
    every annulus (8-point Gauss-Legendre in r, weight r) and corrects the node by the log ratio; three iterations
    bring the annulus averages to ~1e-4. Unrolled, hence differentiable."""
    e = table.r_edges
    a, b = e[:-1, None], e[1:, None]
    rq = (0.5 * (b - a) * _GL_X + 0.5 * (b + a)).reshape(-1)  # (M * 8,)
    wq = (rq.reshape(a.shape[0], -1) * _GL_W) / (0.5 * (b * b - a * a)) * (0.5 * (b - a))  # (M, 8), rows sum to 1
    xs = table.log_r_centres

    def correct(_, ys):
        # Ratios to the target average (no underflow where R itself is ~exp(-700)).
        logv = _log_eval(rq, xs, ys).reshape(ys.shape[:-1] + wq.shape)
        ratio = jnp.sum(jnp.exp(jnp.clip(logv - log_bin_avg[..., None], -50.0, 50.0)) * wq, axis=-1)
        return ys - jnp.log(ratio)

    return jax.lax.fori_loop(0, N_CORRECTIONS, correct, log_bin_avg)


@eqx.filter_jit
def _white_kernel(r, sigma_a, sigma_s_prime, table: WhiteTable):
    sigma_s = sigma_s_prime / (1.0 - table.g)
    mu = sigma_a / sigma_s
    ys = _node_values(_log_profile_nodes(mu, table), table)  # b + (M,)
    shape = jnp.broadcast_shapes(jnp.shape(r), jnp.shape(sigma_a), jnp.shape(sigma_s_prime))
    ys = jnp.broadcast_to(ys, shape + ys.shape[-1:])
    rho = jnp.broadcast_to(r * sigma_s, shape)
    y = _log_eval(rho[..., None], table.log_r_centres, ys)[..., 0]
    return sigma_s * sigma_s * jnp.exp(y)


def white_mc_profile(r, sigma_a, sigma_s_prime, table: WhiteTable):
    """Transport-accurate radial diffuse reflectance ``R(r)`` of a half-space, from a white Monte Carlo table.

    Normalisation: **per incident photon per mm^2** (specular reflection excluded; the engine's convention), so
    its plane integral is ``R_diffuse`` of :func:`jaxsss.mc.simulate` for the same medium. Normal incidence, a
    half-space of absolute index ``table.n`` under air (``eta = table.n``), anisotropy ``table.g``. Exact scaling of
    the table for every ``(sigma_a, sigma_s')`` (see the module docstring for the discretisation, the behaviour
    below the first / beyond the last radial bin, and the validity range ``sigma_a / sigma_s >=
    table.valid_mu_min``). Jitted, differentiable in ``sigma_a`` and ``sigma_s_prime`` (and ``r``).

    Args:
        r: distance from the point of entry, mm, ``>= 0``.
        sigma_a: absorption coefficient, 1/mm, ``>= 0``.
        sigma_s_prime: reduced scattering coefficient ``(1 - g) sigma_s``, 1/mm, ``> 0``.
        table: a :class:`WhiteTable` (:func:`load_white_table`).

    All three arrays broadcast (NumPy rules): for ``N`` radii and ``C`` channels pass ``r`` of shape ``(N, 1)``.

    Returns:
        ``R(r)`` in 1/mm^2, of the broadcast shape.
    """
    if not isinstance(table, WhiteTable):
        raise ValueError(f"white_mc_profile(table={table!r}) must be a WhiteTable (see load_white_table)")
    owner = "white_mc_profile"
    r = check_range(r, "r", 0.0, None, owner=owner)
    sigma_a = check_range(sigma_a, "sigma_a", 0.0, None, owner=owner)
    sigma_s_prime = check_range(sigma_s_prime, "sigma_s_prime", 0.0, None, lo_open=True, owner=owner)
    return _white_kernel(r, sigma_a, sigma_s_prime, table)


def white_table_profile(r, sigma_a, sigma_s_prime, table: WhiteTable):
    """:func:`white_mc_profile` without its argument checks (traceable; the checks are the caller's). For kernels
    whose inputs are valid by construction: a traced check is a host callback, which keeps the compiled program out
    of JAX's persistent cache (the renderer's white kernels)."""
    return _white_kernel(r, sigma_a, sigma_s_prime, table)


@eqx.filter_jit
def _white_stderr_kernel(r, sigma_a, sigma_s_prime, table: WhiteTable):
    sigma_s = sigma_s_prime / (1.0 - table.g)
    mu = sigma_a / sigma_s
    L0 = table.pathlength_edges[:-1]
    dL = jnp.diff(table.pathlength_edges)
    w = jnp.exp(_log_mean_exp(mu[..., None], L0, dL))  # (..., P)
    R = jnp.einsum("...p,mp->...m", w, table.R)
    var = jnp.einsum("...p,mp->...m", w * w, table.R_stderr**2)
    rel = jnp.sqrt(var) / R
    shape = jnp.broadcast_shapes(jnp.shape(r), jnp.shape(sigma_a), jnp.shape(sigma_s_prime))
    rel = jnp.broadcast_to(rel, shape + rel.shape[-1:])
    x = jnp.log(jnp.broadcast_to(r * sigma_s, shape))
    xs = table.log_r_centres
    i = jnp.clip(jnp.searchsorted(xs, x, side="right") - 1, 0, xs.shape[0] - 1)
    return jnp.take_along_axis(rel, i[..., None], axis=-1)[..., 0]


def white_mc_profile_stderr(r, sigma_a, sigma_s_prime, table: WhiteTable):
    """Relative standard error of :func:`white_mc_profile` from the table's Monte Carlo noise (the bin holding
    ``r``; cells treated as independent). Not differentiable in any useful sense; for error bars and tests."""
    owner = "white_mc_profile_stderr"
    r = check_range(r, "r", 0.0, None, owner=owner)
    sigma_a = check_range(sigma_a, "sigma_a", 0.0, None, owner=owner)
    sigma_s_prime = check_range(sigma_s_prime, "sigma_s_prime", 0.0, None, lo_open=True, owner=owner)
    return _white_stderr_kernel(r, sigma_a, sigma_s_prime, table)


def white_mc_medium_profile(r, medium, table: WhiteTable | None = None):
    """:func:`white_mc_profile` for a :class:`~jaxsss.medium.Medium` (its ``eta`` and ``g`` pick the table when
    ``table`` is None; ``g`` defaults to 0). Scalar ``eta`` and ``g`` only: one table per call."""
    if table is None:
        eta = np.asarray(medium.eta)
        g = 0.0 if medium.g is None else np.asarray(medium.g)
        if eta.ndim or np.ndim(g):
            raise ValueError("white_mc_medium_profile(medium=...): eta and g must be scalars (one table per call)")
        table = load_white_table(round(float(g), 2), round(float(eta), 2))
    return white_mc_profile(r, medium.sigma_a, medium.sigma_s_prime, table)
