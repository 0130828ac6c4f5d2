"""Randomised profile fits: no fit that is wrong may report success without a warning (issue 18).

What is run. ``n`` profiles of 3 channels (``--quick``: 40; full: 1000, i.e. 3000 channel fits per model), each:

- a material of the Jensen 2001 or Narasimhan 2006 table (:mod:`jaxsss.data`), its ``sigma_a`` and ``sigma_s'``
  each scaled by an independent log-uniform factor in [0.3, 3];
- ``eta`` 1.3 (the ``mc`` model: its table's, 1.4 with ``g`` = 0.9);
- 100 radii ``geomspace(0.02, 10) * max l_d`` of the three channels (so every channel has near and far field);
- the model's own profile (``dipole``, ``multipole`` with a slab of 2-10 ``l_d`` of the first channel, ``mc``) with
  multiplicative Gaussian noise of 0 (a third of the profiles) or 0.3-3%, passed as ``R_stderr`` on half of the
  noisy profiles (the others use relative weights);
- ``r_min`` = 0 (the default range) or 0-2 ``l_d`` per channel; absolute or relative (a free scale) data.

A channel fit is **wrong** when ``sigma_a`` or ``sigma_s'`` is more than ``k`` standard errors from the truth
(noisy data; ``k`` = 3 and 5 are both reported) or more than 1% (noise-free data). It **reports success** when
:attr:`fitting.ProfileFit.reliable` holds (converged, identifiable, not suspect, inside the model's range): no
warning. The goal is no wrong fit that reports success; at ``k = 3`` about 0.5% of correct noisy fits are expected
beyond 3 standard errors by chance (two parameters), so ``k = 5`` is the hard check and the 3-sigma count is
reported next to its expectation.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from benchmarks._harness import make_row, parse_args, write_results

NAME = "fit_sweep"
ETA = 1.3
MC_G, MC_ETA = 0.9, 1.4
N_R = 100


def _materials():
    from jaxsss.data import list_materials, material

    out = []
    for name in list_materials():
        m = material(name)
        sa, ss = np.asarray(m.sigma_a, float), np.asarray(m.sigma_s_prime, float)
        if np.all(sa > 0) and np.all(ss > 0):  # a non-absorbing channel has no l_d (and no far field to fit)
            out.append((name, sa, ss))
    return out


def make_case(rng, model: str, materials):
    """One randomised profile: dict with the truth, the data and the fit's keyword arguments. For the ``mc`` model,
    drawn again until the model is precise at the truth (:func:`mc_precise`)."""
    while True:
        case = _draw_case(rng, model, materials)
        if model != "mc" or mc_precise(case):
            return case


def mc_precise(case) -> bool:
    """Whether the ``mc`` model's own Monte Carlo noise at the truth, over the radii a fit would use (``r >=
    max(r_min, 0.1 l_u)`` and ``<= 10 l_d``), has a median within :data:`fitting.models.MODEL_NOISE_LIMIT` in every
    channel. Outside, data drawn from the model are as rough as its tables (8-25% at albedo 0.1 and g = 0.9 near the
    source), which no measured profile is: such a truth is outside the model's validity, and a fit whose solution
    lies there is warned about (the same rule as the lower albedo limit above)."""
    import jaxsss
    from fitting.models import MC_R_MAX_LD, MC_R_MIN_LU, MODEL_NOISE_LIMIT, mc_R_stderr

    sa, ss, r = case["sa"], case["ss"], case["r"]
    ld = np.asarray(jaxsss.Medium(sa, ss, MC_ETA).l_d)
    lo = np.maximum(np.asarray(case["kw"].get("r_min", 0.0)), MC_R_MIN_LU / (sa + ss))
    # One evaluation on the whole grid (a fixed shape: no recompilation per case), then each channel's range.
    rel = np.asarray(mc_R_stderr(r[:, None], sa, ss, (MC_G, MC_ETA)))  # (N, 3)
    for c in range(3):
        m = (r >= lo[c]) & (r <= MC_R_MAX_LD * ld[c])
        if m.sum() > 2 and np.median(rel[m, c]) > MODEL_NOISE_LIMIT:
            return False
    return True


def _draw_case(rng, model: str, materials):
    import fitting
    import jaxsss
    from jaxsss.mc.white_family import white_family_profile

    name, sa0, ss0 = materials[rng.integers(len(materials))]
    sa = sa0 * np.exp(rng.uniform(np.log(0.3), np.log(3.0), 3))
    ss = ss0 * np.exp(rng.uniform(np.log(0.3), np.log(3.0), 3))
    eta = MC_ETA if model == "mc" else ETA
    kw = {"eta": eta, "model": model}
    if model == "mc":
        kw["g"] = MC_G
        # The table's validity range (sigma_a / sigma_s >= valid_mu_min): stay inside it; outside is a warning.
        lo = fitting.models.mc_table(MC_G, MC_ETA).valid_mu_min / (1 - MC_G)
        sa = np.maximum(sa, 2.0 * lo * ss)
    med = jaxsss.Medium(sa, ss, eta)
    ld = np.asarray(med.l_d)
    r = np.geomspace(0.02, 10.0, N_R) * ld.max()
    if model == "multipole":
        kw["thickness"] = float(rng.uniform(2.0, 10.0) * ld[0])
        n = jaxsss.multipole_n_pairs(r[:, None], med, kw["thickness"], rtol=1e-13)
        R, _ = jaxsss.multipole_profile(r[:, None], med, kw["thickness"], n_pairs=n)
        R = np.asarray(fitting.entry_transmittance(eta) * R)
    elif model == "mc":
        R = np.asarray(white_family_profile(r[:, None], sa, ss, MC_G, MC_ETA))
    else:
        R = np.asarray(fitting.entry_transmittance(eta) * jaxsss.dipole_profile(r[:, None], med))
    noise = 0.0 if rng.random() < 1 / 3 else float(np.exp(rng.uniform(np.log(0.003), np.log(0.03))))
    y = R * (1.0 + noise * rng.standard_normal(R.shape))
    if noise and rng.random() < 0.5:
        kw["R_stderr"] = noise * R
    if rng.random() < 0.5:
        kw["r_min"] = rng.uniform(0.0, 2.0, 3) * ld
    relative = bool(rng.random() < 0.5)
    if relative:
        c = float(np.exp(rng.uniform(-3, 3)))
        y = c * y
        if "R_stderr" in kw:
            kw["R_stderr"] = c * kw["R_stderr"]
        kw["relative"] = True
    return {"material": name, "sa": sa, "ss": ss, "noise": noise, "r": r, "R": y, "kw": kw}


def judge(case, fit, k):
    """Per channel: (wrong, reliable) for ``k`` standard errors (or 1% without noise)."""
    est = np.stack([np.asarray(fit.sigma_a), np.asarray(fit.sigma_s_prime)])
    se = np.stack([np.asarray(fit.sigma_a_stderr), np.asarray(fit.sigma_s_prime_stderr)])
    truth = np.stack([case["sa"], case["ss"]])
    if case["noise"] == 0:
        wrong = np.any(np.abs(est / truth - 1) > 0.01, axis=0)
    else:
        wrong = np.any(np.abs(est - truth) > k * se, axis=0)
    return wrong, np.asarray(fit.reliable)


def run(models, n, seed=0, progress=None):
    """Fit ``n`` random profiles per model; returns {model: stats dict}."""
    import fitting

    materials = _materials()
    stats = {}
    for model in models:
        rng = np.random.default_rng([seed, sum(map(ord, model))])
        counts = {"fits": 0, "reliable": 0, "wrong3": 0, "wrong5": 0, "wrong3_reliable": 0, "wrong5_reliable": 0,
                  "noise_free_wrong_reliable": 0, "seconds": 0.0, "examples": []}
        for i in range(n):
            case = make_case(rng, model, materials)
            t0 = time.perf_counter()
            fit = fitting.fit_profile(case["r"], case["R"], warn=False, **case["kw"])
            counts["seconds"] += time.perf_counter() - t0
            w3, ok = judge(case, fit, 3.0)
            w5, _ = judge(case, fit, 5.0)
            counts["fits"] += 3
            counts["reliable"] += int(ok.sum())
            counts["wrong3"] += int(w3.sum())
            counts["wrong5"] += int(w5.sum())
            counts["wrong3_reliable"] += int((w3 & ok).sum())
            counts["wrong5_reliable"] += int((w5 & ok).sum())
            if case["noise"] == 0:
                counts["noise_free_wrong_reliable"] += int((w5 & ok).sum())
            if np.any(w5 & ok) and len(counts["examples"]) < 5:
                c = int(np.argmax(w5 & ok))
                counts["examples"].append({
                    "material": case["material"], "channel": c, "sigma_a": float(case["sa"][c]),
                    "sigma_s_prime": float(case["ss"][c]), "fit_sigma_a": float(np.asarray(fit.sigma_a)[c]),
                    "fit_sigma_s_prime": float(np.asarray(fit.sigma_s_prime)[c]), "noise": case["noise"],
                    "kw": {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in case["kw"].items()
                           if k != "R_stderr"}})
            if progress and (i + 1) % progress == 0:
                print(f"  {model}: {i + 1}/{n}: {counts['fits']} fits, reliable {counts['reliable']}, wrong(5se) "
                      f"{counts['wrong5']} of which reliable {counts['wrong5_reliable']}, {counts['seconds']:.0f} s",
                      flush=True)
        stats[model] = counts
    return stats


def main(argv=None) -> int:
    import argparse

    extra = argparse.ArgumentParser(add_help=False)
    extra.add_argument("--models", default=None, help="comma-separated model names (default: every registered one)")
    extra.add_argument("--n", type=int, default=None, help="profiles per model (default 40 with --quick, else 1000)")
    own, rest = extra.parse_known_args(argv)
    args = parse_args(rest, __doc__.splitlines()[0])
    import fitting

    n = own.n or (40 if args.quick else 1000)
    models = tuple(own.models.split(",")) if own.models else tuple(fitting.FORWARD_MODELS)
    # Compile every model's configurations outside the timing (one small sweep first).
    run(models, 2, seed=99)
    stats = run(models, n, seed=1, progress=max(1, n // 10))
    rows = []
    for model, s in stats.items():
        frac = s["wrong5_reliable"] / s["fits"]
        rows.append(make_row(NAME, f"fit_profile ({model})", n, frac,
                             "fraction of channel fits > 5 se (1% noise-free) from truth and reliable",
                             s["seconds"], None, **{k: v for k, v in s.items() if k != "seconds"}))
        print(f"{model}: {s['fits']} fits, reliable {s['reliable']}, wrong(5se) {s['wrong5']} of which reliable "
              f"{s['wrong5_reliable']}; wrong(3se) {s['wrong3']} of which reliable {s['wrong3_reliable']} "
              f"(chance ~{0.0054 * s['fits'] * 2 / 3:.0f}); {s['seconds']:.1f} s", flush=True)
    summary = {m: {k: v for k, v in s.items() if k != "examples"} for m, s in stats.items()}
    notes = ["wrong: > k standard errors (noisy) or > 1% (noise-free) in sigma_a or sigma_s'; reliable: converged, "
             "identifiable, not suspect, no model warning", "goal: wrong5_reliable = 0 for every model"]
    json_path, png_path = write_results(NAME + args.tag, rows, args.out, quick=args.quick, summary=summary,
                                        notes=notes, title=f"{NAME}: wrong-and-reliable fraction vs seconds",
                                        connect=False)
    print(f"wrote {json_path} and {png_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
