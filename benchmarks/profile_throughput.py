"""Profile throughput: dipole and multipole evaluations per second, JAX (float64, float32) against plain NumPy.

What is measured. One call evaluates a profile at ``N`` radii x 3 channels (``r`` of shape ``(N, 1)`` against a
Medium with RGB arrays), the way a renderer or a fitter fills a table; "evaluations" are output values (for the
multipole one evaluation yields both ``R`` and ``T``). Variants:

- ``dipole``: :func:`jaxsss.profiles.dipole.dipole_profile` (already ``eqx.filter_jit``-ed), one medium;
- ``dipole-media``: the same, ``jax.vmap``-ed over ``M`` media (``M x N_r x 3`` outputs in one call);
- ``multipole``: :func:`jaxsss.profiles.multipole.multipole_profile` for a slab, a fixed ``n_pairs``.

Each runs in float64 and float32 (Medium and ``r`` built from float32 arrays; the output dtype is checked), and
against a vectorised NumPy float64 twin of the same formula written here, on the same inputs and output shape.

Threads. XLA may spread a large fused loop over every usable core; NumPy uses one. For a per-core comparison run
``taskset -c 0 python -m benchmarks.profile_throughput --tag _1core`` (the JSON records ``usable_cores``).

Error. ``max |x - x64| / |x64|`` against the JAX float64 result, over the entries where ``|x64|`` exceeds
``1e-30`` of its maximum (deep tail values below that are excluded; for float32 they underflow). For NumPy this
checks the formula (expect ~1e-15); for float32 it is the float32 error; JAX float64 is the reference (error 0).
"""

from __future__ import annotations

import os
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from benchmarks._harness import make_row, parse_args, time_interleaved, write_results
from jaxsss import _config  # noqa: F401  (float64)
from jaxsss.medium import Medium
from jaxsss.profiles.dipole import dipole_profile

NAME = "profile_throughput"
REL_FLOOR = 1e-30  # relative errors are taken where |reference| > REL_FLOOR * max|reference|
ERROR_METRIC = f"max rel err vs JAX float64 where |ref| > {REL_FLOOR:g} max|ref|"

# Jensen et al. 2001, Table 1, skin 1 (1/mm), eta = 1.3.
SKIN1 = {"sigma_a": (0.032, 0.17, 0.48), "sigma_s_prime": (0.74, 0.88, 1.01), "eta": 1.3}
R_MAX_MM = 20.0  # radii uniform in [0, R_MAX_MM]: the skin profile falls by ~1e-13 over it
SLAB_THICKNESS_MM = 2.0  # multipole slab thickness (about 1.5 mean free paths of skin 1)


# --- The NumPy twin (float64): the same formulas as jaxsss.fresnel, medium, profiles._sources -----------------------
def np_F_dr_poly(eta):
    """Groenhuis et al. 1983 (eta >= 1) / Egan and Hilgeman 1973 (eta < 1), as in jaxsss.fresnel.F_dr_poly."""
    inv = 1.0 / eta
    above = -1.4399 * inv * inv + 0.7099 * inv + 0.6681 + 0.0636 * eta
    below = -0.4399 + 0.7099 * inv - 0.3319 * inv * inv + 0.0636 * inv * inv * inv
    return np.where(eta >= 1.0, above, below)


def np_medium(sigma_a, sigma_s_prime, eta):
    """Derived quantities: ``(alpha', sigma_tr, l_u, z_b)``."""
    sigma_t_prime = sigma_a + sigma_s_prime
    F = np_F_dr_poly(eta)
    A = (1.0 + F) / (1.0 - F)
    D = 1.0 / (3.0 * sigma_t_prime)
    return sigma_s_prime / sigma_t_prime, np.sqrt(3.0 * sigma_a * sigma_t_prime), 1.0 / sigma_t_prime, 2.0 * A * D


def np_E(z, r, sigma_tr):
    """Point-source exitance E(z, r) (photon-diffusion Eq. 6); the sources here are never in the plane."""
    d2 = r * r + z * z
    d = np.sqrt(d2)
    return (z / d) * (1.0 + sigma_tr * d) * np.exp(-sigma_tr * d) / (4.0 * np.pi * d2)


def np_dipole(r, sigma_a, sigma_s_prime, eta):
    alpha, sigma_tr, l_u, z_b = np_medium(sigma_a, sigma_s_prime, eta)
    # Real source at z_r = l_u; image at height z_v = l_u + 2 z_b (E is odd in z).
    return alpha * (np_E(l_u, r, sigma_tr) + np_E(l_u + 2.0 * z_b, r, sigma_tr))


def np_multipole(r, sigma_a, sigma_s_prime, eta, d, n_pairs):
    """Slab multipole: z_r,i = 2iL + l_u, z_v,i = 2iL - l_u - 2 z_b, L = d + 2 z_b, i = -n..n; returns (R, T)."""
    alpha, sigma_tr, l_u, z_b = np_medium(sigma_a, sigma_s_prime, eta)
    L = d + 2.0 * z_b
    R = np.zeros(np.broadcast_shapes(np.shape(r), np.shape(sigma_a)))
    T = np.zeros_like(R)
    for i in range(-n_pairs, n_pairs + 1):
        z_r = 2.0 * i * L + l_u
        z_v = 2.0 * i * L - l_u - 2.0 * z_b
        R += np_E(z_r, r, sigma_tr) - np_E(z_v, r, sigma_tr)
        T += np_E(d - z_r, r, sigma_tr) - np_E(d - z_v, r, sigma_tr)
    return alpha * R, alpha * T


# --- Helpers ----------------------------------------------------------------------------------------------------------
def max_rel_error(x, ref, floor=REL_FLOOR) -> float:
    x = np.asarray(x, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    mask = np.abs(ref) > floor * np.max(np.abs(ref))
    return float(np.max(np.abs(x[mask] - ref[mask]) / np.abs(ref[mask])))


def _error(out, ref):
    """Max relative error over one output or over the (R, T) pair."""
    if isinstance(ref, tuple):
        return max(max_rel_error(o, f) for o, f in zip(out, ref))
    return max_rel_error(out, ref)


def _dtype_of(out):
    leaves = jax.tree_util.tree_leaves(out)
    return str(leaves[0].dtype)


def skin_media(M, dtype, seed=0):
    """``M`` media around skin 1 (absorption and scattering scaled by log-uniform factors in [1/3, 3])."""
    rng = np.random.default_rng(seed)
    fa = np.exp(rng.uniform(-np.log(3), np.log(3), size=(M, 1)))
    fs = np.exp(rng.uniform(-np.log(3), np.log(3), size=(M, 1)))
    sa = (fa * np.asarray(SKIN1["sigma_a"])).astype(dtype)
    ss = (fs * np.asarray(SKIN1["sigma_s_prime"])).astype(dtype)
    eta = np.full((M, 3), SKIN1["eta"], dtype=dtype)
    return sa, ss, eta


def _multipole_api():
    """``(multipole_profile, multipole_n_pairs)`` or ``None`` while jaxsss.profiles.multipole does not exist yet."""
    try:
        from jaxsss.profiles.multipole import multipole_n_pairs, multipole_profile
    except ImportError:
        return None
    return multipole_profile, multipole_n_pairs


# --- The cases --------------------------------------------------------------------------------------------------------
# Sizes per mode (a test shrinks "quick" further): N radii for the dipole, M media x N_r radii, N_multi radii.
CONFIG = {
    "quick": {"N": 100_000, "M": 100, "N_r": 1000, "N_multi": 20_000, "repeats": 5},
    "full": {"N": 1_000_000, "M": 1000, "N_r": 1000, "N_multi": 100_000, "repeats": 9},
}


def _cases(cfg: dict):
    """Yield ``(setting, n_evals, {impl: callable-with-args})`` for each profile variant."""
    N, M, N_r, N_multi = cfg["N"], cfg["M"], cfg["N_r"], cfg["N_multi"]

    # One medium, N radii x 3 channels.
    r64 = np.linspace(0.0, R_MAX_MM, N)[:, None]
    sa64 = np.asarray(SKIN1["sigma_a"], np.float64)
    ss64 = np.asarray(SKIN1["sigma_s_prime"], np.float64)
    eta64 = np.full(3, SKIN1["eta"])
    mediums = {
        dt: Medium(sa64.astype(dt), ss64.astype(dt), eta64.astype(dt)) for dt in (np.float64, np.float32)
    }
    rs = {dt: jnp.asarray(r64.astype(dt)) for dt in (np.float64, np.float32)}
    yield (
        f"dipole {N:.0e}x3".replace("e+0", "e"),
        N * 3,
        {
            "jax f64": (dipole_profile, rs[np.float64], mediums[np.float64]),
            "jax f32": (dipole_profile, rs[np.float32], mediums[np.float32]),
            "numpy f64": (np_dipole, r64, sa64, ss64, eta64),
        },
    )

    # M media x N_r radii x 3 channels, vmapped over the media.
    rm64 = np.linspace(0.0, R_MAX_MM, N_r)[:, None]
    many = jax.jit(jax.vmap(dipole_profile, in_axes=(None, 0)))
    impls = {}
    for dt, label in ((np.float64, "jax f64"), (np.float32, "jax f32")):
        sa, ss, eta = skin_media(M, dt)
        impls[label] = (many, jnp.asarray(rm64.astype(dt)), Medium(sa, ss, eta))
    sa, ss, eta = skin_media(M, np.float64)
    impls["numpy f64"] = (np_dipole, rm64[None], sa[:, None, :], ss[:, None, :], eta[:, None, :])
    yield f"dipole-media {M}x{N_r}x3", M * N_r * 3, impls

    api = _multipole_api()
    if api is None:
        return
    multipole_profile, multipole_n_pairs = api
    rM64 = np.linspace(0.0, R_MAX_MM, N_multi)[:, None]
    n_pairs = int(multipole_n_pairs(jnp.asarray(rM64), mediums[np.float64], SLAB_THICKNESS_MM, rtol=1e-8))
    d = SLAB_THICKNESS_MM
    # The thickness goes in as a (traced) array argument, like the radii and the medium.
    jitted = eqx.filter_jit(lambda r, m, d_: multipole_profile(r, m, d_, n_pairs=n_pairs))
    yield (
        f"multipole {N_multi:.0e}x3 n_pairs={n_pairs}".replace("e+0", "e"),
        N_multi * 3,
        {
            "jax f64": (jitted, jnp.asarray(rM64), mediums[np.float64], jnp.asarray(d)),
            "jax f32": (jitted, jnp.asarray(rM64.astype(np.float32)), mediums[np.float32], jnp.float32(d)),
            "numpy f64": (np_multipole, rM64, sa64, ss64, eta64, d, n_pairs),
        },
    )


def run(quick: bool) -> tuple[list[dict], dict, list[str]]:
    cfg = CONFIG["quick" if quick else "full"]
    repeats = cfg["repeats"]
    rows, summary, notes = [], {}, []
    if _multipole_api() is None:
        notes.append("jaxsss.profiles.multipole not importable at run time: multipole rows skipped")
    for setting, n_evals, impls in _cases(cfg):
        # Round-robin over the three implementations, so that other load on the machine hits them alike.
        timings = time_interleaved({label: (fn, args) for label, (fn, *args) in impls.items()}, repeats)
        for label, t in timings.items():
            print(f"  {setting:34s} {label:9s} {t.seconds * 1e3:9.2f} ms (median {t.median_seconds * 1e3:9.2f}; "
                  f"compile {t.compile_seconds:.2f} s)", flush=True)
        ref = jax.tree_util.tree_map(np.asarray, timings["jax f64"].output)
        out32 = timings["jax f32"].output
        if _dtype_of(out32) != "float32":
            raise AssertionError(f"{setting}: float32 inputs gave {_dtype_of(out32)} output")
        for label, t in timings.items():
            rows.append(make_row(
                NAME, label, setting,
                error=_error(t.output, ref), error_metric=ERROR_METRIC,
                seconds=t.seconds, compile_seconds=None if label.startswith("numpy") else t.compile_seconds,
                evals_per_second=n_evals / t.seconds, n_evals=n_evals, median_seconds=t.median_seconds,
                repeats=t.repeats, output_dtype=_dtype_of(t.output),
            ))
        kind = setting.split()[0]
        t64, t32, tnp = timings["jax f64"], timings["jax f32"], timings["numpy f64"]
        summary[kind] = {
            "setting": setting,
            # Throughput ratios from the minimum times (``seconds``), and from the medians.
            "jax_f64_over_numpy": tnp.seconds / t64.seconds,
            "jax_f32_over_jax_f64": t64.seconds / t32.seconds,
            "jax_f64_over_numpy_median": tnp.median_seconds / t64.median_seconds,
            "jax_f32_over_jax_f64_median": t64.median_seconds / t32.median_seconds,
            "jax_f64_evals_per_second": n_evals / t64.seconds,
        }
    d = summary["dipole"]
    summary["goals"] = {
        "dipole f64 >= 10x NumPy": bool(d["jax_f64_over_numpy"] >= 10.0),
        "dipole f32 >= 2.5x f64": bool(d["jax_f32_over_jax_f64"] >= 2.5),
    }
    summary["why"] = exp_diagnostic(summary["dipole"], 2 * 3 * cfg["N"], repeats)
    summary["xla_flags"] = os.environ.get("XLA_FLAGS", "")
    return rows, summary, notes


def exp_diagnostic(dipole_summary, n: int, repeats: int) -> dict:
    """Time ``exp`` alone on as many elements as the dipole call evaluates (two sources: two exps per value).

    The fused JAX dipole cannot beat NumPy by more than NumPy's ``exp`` is slower than XLA's, plus NumPy's
    temporaries; and float32 gains over float64 mostly what XLA's float32 ``exp`` gains over its float64 one.
    """
    x64 = np.linspace(-30.0, 0.0, n)
    out = {"n_elements": n}
    exp_jit = jax.jit(jnp.exp)
    timings = time_interleaved({
        "jax_f64_exp_seconds": (exp_jit, (jnp.asarray(x64),)),
        "jax_f32_exp_seconds": (exp_jit, (jnp.asarray(x64.astype(np.float32)),)),
        "numpy_f64_exp_seconds": (np.exp, (x64,)),
    }, repeats)
    out.update({label: t.seconds for label, t in timings.items()})
    out["dipole_jax_f64_seconds_over_its_exps"] = (
        dipole_summary["jax_f64_evals_per_second"] ** -1 * n / 2 / out["jax_f64_exp_seconds"]
    )
    return out


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv, __doc__.splitlines()[0])
    load_at_start = os.getloadavg()[0]  # the machine may be shared; recorded next to the end-of-run load
    rows, summary, notes = run(args.quick)
    notes.append("seconds: min of the repeats after compilation (median in median_seconds), methods timed "
                 "round-robin; compile_seconds: first call (None for NumPy)")
    notes.append(f"error: {ERROR_METRIC}; JAX float64 is the reference (0 drawn at the plot floor)")
    summary["loadavg_1min_at_start"] = load_at_start
    json_path, png_path = write_results(NAME + args.tag, rows, args.out, quick=args.quick, summary=summary, notes=notes,
                                        title="profile throughput: error vs seconds per call", connect=False)
    for k, v in summary.items():
        print(f"  {k}: {v}")
    print(f"wrote {json_path} and {png_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
