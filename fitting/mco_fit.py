"""Fitting an MCML run file (``.mco``) as it stands: the geometry, indices and photon count come from the file.

:func:`fit_mco` is what ``jaxsss fit RUN.mco`` calls. It fits the free layers' ``sigma_a`` and ``sigma_s'`` (default:
the deepest layer; the others stay at the file's values) to the run's ``Rd_r`` and, for a finite stack, ``Tt_r``:

- ``model="mc"`` (default), transport-accurate:
  - a half-space whose ``(g, n)`` has a shipped white Monte Carlo table: the white-MC model of
    :func:`fitting.fit_profile` (one compiled fit, ~0.1 s);
  - anything else (any other ``(g, n)``, slabs, layered stacks): replay (perturbation) Monte Carlo with a trust
    region, :func:`fitting.fit_replay` (seconds to minutes: each round simulates the file's geometry).
- ``model="dipole"`` / ``"multipole"``: the diffusion models (one layer only; multipole for slabs), for comparison.

The replay fit starts from a dipole fit of the same ``Rd_r`` (a data-driven start, never the file's own
coefficients, which are the answer); the trust region then walks from there. The file's layer coefficients are used
only for the fixed layers.

Values are listed per free layer, *deepest first* (the CLI's JSON convention).

:func:`fit_mc_slab` is the same transport-accurate path for a profile *file* of a slab (``jaxsss fit PROFILE.csv
--model mc --thickness D --g G --eta E``): a one-layer stack of that thickness, index and anisotropy between the
given outside indices, fitted by replay Monte Carlo from a dipole start. The profile must be bin averages with known
edges (the binned CSV layout, a ``.mco`` run) or centres of equal bins from ``r = 0`` (then the edges follow).
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import NamedTuple, Sequence

import numpy as np

from fitting.io import ProfileFileError
from fitting.mco import McoRun, read_mco

__all__ = ["McoFit", "MCO_MODELS", "fit_mc_slab", "fit_mco"]

MCO_MODELS = ("mc", "dipole", "multipole")
"""Models :func:`fit_mco` accepts."""

START_CLIP = (1e-4, 1e3)
"""The dipole start is clipped to this range (1/mm) before the replay fit (a diffusion fit of a thin slab can run
away)."""


class McoFit(NamedTuple):
    """Result of :func:`fit_mco`. Arrays are per free layer, deepest first (1/mm).

    ``method``: ``"white_mc"``, ``"replay"``, ``"dipole"`` or ``"multipole"``; ``free_layers``: indices, top layer 0,
    in the same order as the values; ``input_sigma_a``/``input_sigma_s_prime``: the run's input coefficients of those
    layers (MCML's input), for comparison only; ``start``: the replay fit's initial guess (``None`` otherwise);
    ``simulations``: Monte Carlo runs (0 for the tabulated and diffusion models); ``seconds``: wall time. For a
    profile file (:func:`fit_mc_slab`) the input coefficients are unknown: NaN.
    """

    source: str
    model: str
    method: str
    free_layers: tuple
    sigma_a: np.ndarray
    sigma_s_prime: np.ndarray
    sigma_a_stderr: np.ndarray
    sigma_s_prime_stderr: np.ndarray
    converged: bool
    status: str
    reduced_chi2: float
    simulations: int
    seconds: float
    input_sigma_a: np.ndarray
    input_sigma_s_prime: np.ndarray
    start: tuple | None
    warnings: tuple

    def to_dict(self) -> dict:
        """A JSON-ready dict (lists for arrays)."""
        d = self._asdict()
        for k, v in d.items():
            if isinstance(v, np.ndarray):
                d[k] = v.tolist()
        d["start"] = None if self.start is None else [list(map(float, s)) for s in self.start]
        d["warnings"] = list(self.warnings)
        d["free_layers"] = list(self.free_layers)
        return d


def _free_layers(run: McoRun, free_layers) -> list[int]:
    from fitting.replay_fit import layer_indices

    free = layer_indices((-1,) if free_layers is None else tuple(free_layers), len(run.layers), "fit_mco")
    return sorted(free, reverse=True)  # deepest first


def _diffusion_fit(run: McoRun, model: str):
    from fitting.profile_fit import fit_profile

    data = run.to_profile()
    thickness = None if run.semi_infinite else run.thickness
    if model == "dipole":  # the dipole sees a half-space: fit R only
        return fit_profile(data.r, data.R, R_stderr=data.R_stderr, eta=run.eta, model="dipole", warn=False)
    return fit_profile(data.r, data.R, R_stderr=data.R_stderr, T=data.T, T_stderr=data.T_stderr, eta=run.eta,
                       model="multipole", thickness=thickness, warn=False)


def _dipole_start(data) -> tuple[float, float]:
    """A data-driven start for a replay fit: the dipole fit of ``R`` (``data``: a ProfileData and its ``eta``),
    clipped to :data:`START_CLIP` (never the run's own coefficients, which are the answer)."""
    from fitting.profile_fit import fit_profile

    profile, eta = data
    dip = fit_profile(profile.r, profile.R, R_stderr=profile.R_stderr, eta=eta, model="dipole", warn=False)
    return tuple(float(np.clip(np.asarray(v, float).ravel()[0], *START_CLIP)) for v in (dip.sigma_a,
                                                                                      dip.sigma_s_prime))


def _replay_result(fit, free, start, common, warnings, t0) -> McoFit:
    order = [fit.free_layers.index(i) for i in free]
    if not fit.converged:
        warnings.append(f"the replay fit stopped with status {fit.status!r} after {fit.simulations} simulations")
    return McoFit(method="replay", sigma_a=fit.sigma_a[order], sigma_s_prime=fit.sigma_s_prime[order],
                  sigma_a_stderr=fit.sigma_a_stderr[order], sigma_s_prime_stderr=fit.sigma_s_prime_stderr[order],
                  converged=fit.converged, status=fit.status, reduced_chi2=fit.reduced_chi2,
                  simulations=fit.simulations, seconds=time.perf_counter() - t0,
                  start=tuple(start[i] for i in free), warnings=tuple(warnings), **common)


def _bin_edges(data, owner: str) -> np.ndarray:
    """The profile's annulus edges: recorded by the reader, or those of equal bins from 0 whose centres ``r`` are."""
    from fitting.io import equal_bin_edges

    if data.r_edges is not None:
        return np.asarray(data.r_edges, dtype=np.float64)
    edges = equal_bin_edges(data.r)
    if edges is not None:
        return edges
    raise ValueError(f"{owner}: {data.source} gives radii but no bin edges, and the radii are not centres of equal "
                     "bins from r = 0; replay Monte Carlo fits bin averages: use the binned CSV layout "
                     "(r_lo_mm, r_hi_mm, ...) or an MCML .mco file")


def fit_mc_slab(data, *, eta: float, g: float, thickness: float, n_outside: float = 1.0,
                n_below: float | None = None, photons: int = 100_000, seed: int = 0,
                max_simulations: int = 16) -> McoFit:
    """Fit ``sigma_a`` and ``sigma_s'`` of a slab to its radial profile(s) by replay Monte Carlo (module docstring).

    Args:
        data: a :class:`~fitting.io.ProfileData` with ``R`` (and ``T``: transmittance including the unscattered
            beam, MCML's convention) per incident photon per mm^2, with standard errors, as bin averages.
        eta: the slab's index relative to the medium above (``n_slab / n_outside``), > 0.
        g: Henyey-Greenstein anisotropy in (-1, 1).
        thickness: mm, > 0 and finite.
        n_outside: absolute index above the slab (default air); ``n_below``: below it (default ``n_outside``).
        photons, seed, max_simulations: as for :func:`fit_mco`.
    """
    from jaxsss.mc import Layer, Stack
    from jaxsss.validate import check_range

    from fitting.replay_fit import ReplayData, fit_replay

    t0 = time.perf_counter()
    check_range(eta, "eta", 0.0, None, lo_open=True, owner="fit_mc_slab")
    check_range(g, "g", -1.0, 1.0, lo_open=True, hi_open=True, owner="fit_mc_slab")
    check_range(thickness, "thickness", 0.0, None, lo_open=True, hi_open=True, owner="fit_mc_slab")
    if data.R is None or data.R_stderr is None or (data.T is not None and data.T_stderr is None):
        raise ValueError(f"fit_mc_slab: {data.source} needs R with standard errors (and T_stderr with T): replay "
                         "Monte Carlo weighs each bin by its error")
    edges = _bin_edges(data, "fit_mc_slab")
    start = {0: _dipole_start((data, eta))}
    n = float(eta) * n_outside
    sa, ssp = start[0]
    stack = Stack([Layer(sa, ssp / (1.0 - g), g, n, float(thickness))], n_above=n_outside,
                  n_below=n_outside if n_below is None else n_below)
    replay = ReplayData(r_edges=edges, R_r=data.R, R_r_stderr=data.R_stderr, T_r=data.T, T_r_stderr=data.T_stderr)
    fit = fit_replay(stack, replay, free_layers=(0,), photons=photons, seed=seed, max_simulations=max_simulations)
    nan = np.full(1, np.nan)
    common = dict(source=data.source, model="mc", free_layers=(0,), input_sigma_a=nan, input_sigma_s_prime=nan)
    return _replay_result(fit, [0], start, common, [], t0)


def _stack(run: McoRun, start: dict[int, tuple[float, float]]):
    from jaxsss.mc import Layer, Stack

    layers = []
    for i, layer in enumerate(run.layers):
        g = float(layer.g)
        sa, ssp = start.get(i, (layer.sigma_a, layer.sigma_s_prime))
        thickness = math.inf if layer.semi_infinite else float(layer.thickness)
        layers.append(Layer(sa, ssp / (1.0 - g), g, float(layer.n), thickness))
    return Stack(layers, n_above=run.n_above, n_below=run.n_below)


def fit_mco(run: McoRun | str | Path, *, model: str = "mc", free_layers: Sequence[int] | None = None,
            photons: int = 100_000, seed: int = 0, max_simulations: int = 16) -> McoFit:
    """Fit an MCML run: ``run`` is a :class:`~fitting.mco.McoRun` or a path to an ``.mco`` file.

    Args:
        model: one of :data:`MCO_MODELS` (module docstring).
        free_layers: indices of the layers to fit (top layer 0; negative from the bottom); default the deepest. The
            diffusion models fit one-layer runs only.
        photons: photons per replay simulation (``model="mc"`` without a table).
        seed, max_simulations: passed to :func:`fitting.fit_replay`.

    Returns:
        :class:`McoFit`.
    """
    t0 = time.perf_counter()
    if not isinstance(run, McoRun):
        run = read_mco(run)
    if model not in MCO_MODELS:
        raise ValueError(f"fit_mco(model={model!r}) is not one of: {', '.join(MCO_MODELS)}")
    free = _free_layers(run, free_layers)
    truth = np.array([(run.layers[i].sigma_a, run.layers[i].sigma_s_prime) for i in free])
    single = len(run.layers) == 1
    if model != "mc" and not single:
        raise ProfileFileError(f"{run.source}: the {model} model describes one layer; this run has "
                               f"{len(run.layers)} (use --model mc)")
    if model == "multipole" and run.semi_infinite:
        raise ProfileFileError(f"{run.source}: the multipole model needs a slab; this run is a half-space (use "
                               "--model dipole or mc)")
    warnings: list[str] = []
    common = dict(source=run.source, model=model, free_layers=tuple(free), input_sigma_a=truth[:, 0],
                  input_sigma_s_prime=truth[:, 1])

    def from_profile_fit(fit, method):
        warnings.extend(fit.warnings)
        converged = bool(np.all(fit.converged))
        return McoFit(method=method, sigma_a=np.atleast_1d(np.asarray(fit.sigma_a, float)),
                      sigma_s_prime=np.atleast_1d(np.asarray(fit.sigma_s_prime, float)),
                      sigma_a_stderr=np.atleast_1d(np.asarray(fit.sigma_a_stderr, float)),
                      sigma_s_prime_stderr=np.atleast_1d(np.asarray(fit.sigma_s_prime_stderr, float)),
                      converged=converged, status="converged" if converged else "not converged",
                      reduced_chi2=float(np.max(np.asarray(fit.reduced_chi2))),
                      simulations=0, seconds=time.perf_counter() - t0, start=None,
                      warnings=tuple(warnings), **common)

    if model in ("dipole", "multipole"):
        return from_profile_fit(_diffusion_fit(run, model), model)

    from fitting.models import has_white_table

    layer = run.layers[-1]
    if single and run.semi_infinite and has_white_table(layer.g, run.eta):
        from fitting.profile_fit import fit_profile

        data = run.to_profile()
        fit = fit_profile(data.r, data.R, R_stderr=data.R_stderr, eta=run.eta, model="mc", g=float(layer.g),
                          warn=False)
        return from_profile_fit(fit, "white_mc")

    from fitting.replay_fit import ReplayData, fit_replay

    # A data-driven start: the dipole fit of R for every free layer, clipped (never the file's own coefficients).
    guess = _dipole_start((run.to_profile(), run.eta))
    start = {i: guess for i in free}
    stack = _stack(run, start)
    data = ReplayData(r_edges=np.concatenate([run.r_lo, run.r_hi[-1:]]), R_r=run.Rd_r,
                      T_r=None if run.semi_infinite else run.Tt_r, photons=run.photons)
    fit = fit_replay(stack, data, free_layers=tuple(free), photons=photons, seed=seed,
                     max_simulations=max_simulations)
    return _replay_result(fit, free, start, common, warnings, t0)
