"""Forward models for profile fits, chosen by name from a validated registry (:data:`FORWARD_MODELS`).

Normalisation (issue 4, item 6). Every forward model returns profiles per *incident* photon, in 1/mm^2: the
jaxsss profiles are per unit flux *entering* the medium (``alpha'/(4 pi)`` kept, DESIGN.md trap 1), so the models
multiply them by the entry transmittance of a collimated beam at normal incidence,
``T_entry = 1 - fresnel_reflectance(eta, 1.0)``. Light lost to specular reflection at entry therefore counts, as in
the Monte Carlo engine's convention. A measured absolute profile must use the same convention.

Registered models:

- ``dipole``: semi-infinite medium (Jensen et al. 2001), :func:`jaxsss.dipole_profile`; gives ``R`` only.
- ``multipole``: slab of known thickness (Donner and Jensen 2005), :func:`jaxsss.multipole_profile`; gives ``R``
  and ``T``. The number of image pairs is static under ``jit``: :meth:`ForwardModel.prepare` chooses it on the host
  with :func:`jaxsss.multipole_n_pairs` from concrete parameter values.

- ``mc``: the white ("scaled") Monte Carlo model of a half-space (Kienle and Patterson 1996) for any ``(g, n)`` in
  the family's grid, :func:`jaxsss.mc.white_family.white_family_profile` (``g`` in [0, 0.95], ``eta`` in [1, 1.6]);
  gives ``R`` only. ``g`` and ``eta`` are fixed by the fit (``g=...``, ``eta=...``); outside the grid is a
  ``ValueError`` naming the value and the range. The profile is **already per incident photon** (specular excluded:
  the engine's convention), so this model does *not* multiply by ``T_entry``. Its default fit range starts at
  ``0.1 l_u`` (see :data:`MC_R_MIN_LU`); it is valid for every ``sigma_a >= 0`` (a diffusion tail continues the
  tables' long paths).

Other models register themselves with :func:`register_model`. This module imports only jaxsss's public API.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import jaxsss

__all__ = ["FORWARD_MODELS", "ForwardModel", "entry_transmittance", "register_model", "resolve_model"]


def entry_transmittance(eta):
    """``1 - F(eta, cos = 1)``: the fraction of a normally incident collimated beam entering the medium."""
    return 1.0 - jaxsss.fresnel_reflectance(eta, 1.0)


class ForwardModel(NamedTuple):
    """A registered forward model.

    Attributes:
        name: registry key (the CLI's ``--model``).
        summary: one line for listings and ``--help``.
        outputs: the profiles it predicts, a subset of ``("R", "T")`` in that order.
        needs_thickness: the model needs the slab thickness (mm).
        evaluate: ``evaluate(r, medium, thickness, static) -> {"R": ..., "T": ...}`` per *incident* photon
            (1/mm^2), traceable; ``r`` has shape ``(N,)`` and the medium is scalar (one channel). ``static`` is the
            hashable value that :attr:`prepare` returned.
        prepare: host-side ``prepare(r, medium, thickness) -> static`` from concrete values (e.g. the multipole's
            pair count), or ``None``. May raise ``ValueError`` when no setting up to ``static_cap`` suffices.
        guess_static: the fixed static setting used to rank the initial-guess candidates (models with ``prepare``).
        static_cap: the largest static setting a fit uses (recorded in the fit's notes when it is reached).
        configure: host-side ``configure(owner, eta, g) -> static`` for models whose static setting is fixed by the
            fit's settings rather than by the parameters (the ``mc`` model's ``(g, n)`` table), or ``None``. ``eta``
            is the per-problem array of relative indices, ``g`` the user's anisotropy (``None`` if not given).
            Raises ``ValueError`` naming the arguments and the allowed values.
        uses_g: the model takes the anisotropy ``g`` (others reject ``g=...``).
        r_min_lu: the default fit range is ``r >= r_min_lu * l_u`` at the initial guess.
        range_reason: why that default (recorded in the result).
        ratio_min: host-side ``ratio_min(static) -> float``: the smallest ``sigma_a / sigma_s'`` where the model is
            valid, or ``None`` (no limit). The start is clamped into the range (with a note) and a solution below it
            is a warning of the result.
        noise: host-side ``noise(r, sigma_a, sigma_s_prime, static) -> relative standard error`` of the model's own
            values (a Monte Carlo table's noise), or ``None`` (exact). A fit whose range has a median above
            :data:`MODEL_NOISE_LIMIT` at the solution gets a model warning.
        rough: the model is tabulated Monte Carlo whose noise makes shallow local minima along the fit's valley
            (the ``mc`` family: ~0.5-3% per annulus far out); fits add valley scans and their starts, take the
            covariance from a secant Jacobian, and report relative far-field fits as not identifiable
            (``fitting._kernel.with_valley``, :data:`ROUGH_RELATIVE_R_MIN_LD`).
        operands: host-side ``operands(static) -> (key, arrays)`` for a static setting that is data rather than code,
            or ``None``. The compiled fit then takes ``arrays`` (a pytree) as runtime arguments and is cached under
            the hashable ``key``; inside it, ``evaluate`` receives ``arrays`` as its ``static``. One compilation then
            serves every setting of one ``key`` (the ``mc`` model: every ``(g, n)``; ~20 s of compilation each on
            this machine). ``evaluate`` must accept both forms (the host evaluates fitted profiles with ``static``).
    """

    name: str
    summary: str
    outputs: tuple[str, ...]
    needs_thickness: bool
    evaluate: Callable
    prepare: Callable | None = None
    guess_static: object = None
    static_cap: object = None
    configure: Callable | None = None
    uses_g: bool = False
    r_min_lu: float = 1.0
    range_reason: str = ("r >= l_u = 1/sigma_t' at the initial guess (diffusion is 10-20x off within half a "
                         "transport mean free path of the source)")
    ratio_min: Callable | None = None
    r_max_ld: float | None = None  # the model is valid up to r_max_ld * l_d (default r_max at the start; warned past)
    noise: Callable | None = None
    rough: bool = False
    operands: Callable | None = None


def _dipole(r, medium, thickness, static):
    return {"R": entry_transmittance(medium.eta) * jaxsss.dipole_profile(r, medium)}


def _multipole(r, medium, thickness, n_pairs):
    R, T = jaxsss.multipole_profile(r, medium, thickness, n_pairs=n_pairs)
    t_entry = entry_transmittance(medium.eta)
    return {"R": t_entry * R, "T": t_entry * T}


# Pair counts are rounded up to a power of two (few distinct static values -> few compilations) and the profile is
# converged to 1e-12 relative, well below the 1e-8 recovery target for noise-free data.
MULTIPOLE_RTOL = 1e-12


# Ranking the start candidates needs no precision: 64 pairs cover radii up to ~64 slab thicknesses.
MULTIPOLE_GUESS_PAIRS = 64
MULTIPOLE_MAX_PAIRS = 1 << 12


def _multipole_prepare(r, medium, thickness) -> int:
    n = jaxsss.multipole_n_pairs(np.asarray(r)[..., None], medium, thickness, rtol=MULTIPOLE_RTOL,
                                 max_pairs=MULTIPOLE_MAX_PAIRS)
    return 1 << max(0, int(n) - 1).bit_length()


FORWARD_MODELS: dict[str, ForwardModel] = {}
"""Registry of forward models by name. Add models with :func:`register_model`; look them up with
:func:`resolve_model`."""


def register_model(model: ForwardModel) -> ForwardModel:
    """Add ``model`` to :data:`FORWARD_MODELS` (an existing name is an error); return it."""
    if not isinstance(model, ForwardModel):
        raise TypeError(f"register_model(model={model!r}): expected a ForwardModel")
    if model.name in FORWARD_MODELS:
        raise ValueError(f"register_model(name={model.name!r}): a forward model of that name is already registered")
    bad = [o for o in model.outputs if o not in ("R", "T")]
    if bad or not model.outputs:
        raise ValueError(f"register_model(outputs={model.outputs!r}): allowed outputs are 'R' and 'T'")
    FORWARD_MODELS[model.name] = model
    return model


def resolve_model(name) -> ForwardModel:
    """The registered :class:`ForwardModel` called ``name``; an unknown name raises ``ValueError`` listing the valid
    names."""
    if isinstance(name, ForwardModel):
        return name
    try:
        return FORWARD_MODELS[name]
    except (KeyError, TypeError):
        valid = ", ".join(repr(k) for k in FORWARD_MODELS)
        raise ValueError(f"fit_profile(model={name!r}) is not a registered forward model; valid names: {valid}") from None


register_model(ForwardModel("dipole", "semi-infinite medium (Jensen et al. 2001); R only", ("R",), False, _dipole))
register_model(
    ForwardModel(
        "multipole",
        "slab of known thickness (Donner and Jensen 2005); R and T",
        ("R", "T"),
        True,
        _multipole,
        _multipole_prepare,
        guess_static=MULTIPOLE_GUESS_PAIRS,
        static_cap=MULTIPOLE_MAX_PAIRS,
    )
)


# --- The white Monte Carlo model ----------------------------------------------------------------------------------
MC_R_MIN_LU = 0.1
"""Default fit range of the ``mc`` model: ``r >= 0.1 l_u`` at the initial guess. The white-MC model is transport
(exact for its ``g`` and ``n`` up to table noise) near the source too, so most of the near field can be fitted -- it
carries most of the information on the albedo. 0.1 l_u lies beyond the table's merged first radial bin (below
0.09 l_u for g = 0.9), where the model is a constant disk average rather than a profile."""


MC_R_MAX_LD = 10.0
ROUGH_RELATIVE_R_MIN_LD = 0.5
"""Relative data (a free scale) fitted with a tabulated (rough) model from ``r_min`` beyond this many ``l_d`` (at the
solution): reported as not identifiable. Beyond the near field the shape of a relative profile separates sigma_a
from sigma_s' only through percent-level departures from the diffusion far field, the size of the tables' noise
there; in the mc sweep every relative fit that started at 0.79-1.84 ``l_d`` and sat 25-100% off along the valley
reported standard errors of 1-6% (benchmarks/fit_sweep.py). Absolute data, or radii nearer the source, separate them."""
MODEL_NOISE_LIMIT = 0.03
"""A model whose own Monte Carlo noise over the fit range (median relative standard error per annulus, at the
solution) exceeds this cannot place a fit: its noise makes local minima deeper than the data's information (the mc
sweep: a low-albedo fit, 0.2-5 l_u from the source at g = 0.9, sat 34% off with the model's noise at 8-15%; fits
inside the family's measured range see 0.3-2%)."""
"""The ``mc`` model's range ends at ``r <= 10 l_d`` (jaxsss.mc.white: bias < ~1% up to 10 l_d). Beyond it the
table's far bins hold few photons: their noise makes local minima (issue 18: noise-free relative data of wholemilk
to 14 l_d gave sigma_a +54% at a misfit that looked like noise, reported reliable; the same data to 10 l_d: exact)."""


def has_white_table(g, eta) -> bool:
    """Whether the white Monte Carlo family covers ``(g, eta)`` (the ``mc`` model's range; ambient index 1)."""
    from jaxsss.mc import white_family as wf

    return wf.covers(g, eta)


@lru_cache(maxsize=1)
def _mc_family():
    from jaxsss.mc.white_family import load_white_family

    # Concrete arrays even when first called inside a trace (a cached tracer would leak out of it).
    with jax.ensure_compile_time_eval():
        return load_white_family()


def mc_table(g: float, n: float):
    """The white Monte Carlo family that serves ``(g, n)`` (loaded once per process); raises outside its range."""
    _mc_configure("mc_table", n, g)
    return _mc_family()


def _mc_configure(owner, eta, g):
    from jaxsss.mc import white_family as wf

    if g is None:
        raise ValueError(f"{owner}(model='mc') needs g=... (the Henyey-Greenstein anisotropy; the white Monte Carlo "
                         f"family covers g in [{wf.G_NODES[0]:g}, {wf.G_NODES[-1]:g}])")
    etas = np.unique(np.asarray(eta, dtype=np.float64))
    if etas.size != 1:
        raise ValueError(f"{owner}(model='mc', eta={etas.tolist()}): one eta per fit; fit each eta apart")
    wf.check_covered(g, etas[0], owner=f"{owner}(model='mc', ...)")
    _mc_family()  # load on the host, before any tracing
    return float(g), float(etas[0])


@jax.custom_jvp
def mc_R(r, sigma_a, sigma_s_prime, block):
    """:func:`jaxsss.mc.white_family.white_family_block_profile`, per incident photon; ``block`` is
    :func:`jaxsss.mc.white_family.block_operands` of the fit's ``(g, n)`` (arrays: a runtime argument of the fit).

    Its JVP rule forms the ``(N, 2)`` Jacobian in ``(sigma_a, sigma_s')`` once with :func:`jax.jacfwd` and applies it
    to the tangents. The result is the same derivative, but the solver's linearisation, its materialised Jacobian and
    its transposition then see a matrix product instead of the table's spline and node correction: the compiled fit
    is about half the size (compile time is what a single fit costs). ``block`` is not differentiated (its tangent
    is dropped: ``g`` and ``n`` are fixed in these fits; :mod:`fitting.g_fit` frees ``g`` on the whole grid)."""
    from jaxsss.mc.white_family import white_family_block_profile

    return white_family_block_profile(r, sigma_a, sigma_s_prime, block)


def _mc_R_jvp(primals, tangents):
    from jaxsss.mc.white_family import white_family_block_profile

    r, sa, ss, block = primals
    tr, tsa, tss, _ = tangents

    def f(p):
        y = white_family_block_profile(r, p[0], p[1], block)
        return y, y

    p = jnp.stack(jnp.broadcast_arrays(sa, ss))
    jac, val = jax.jacfwd(f, has_aux=True)(p)  # (..., 2)
    zero = jax.custom_derivatives.SymbolicZero
    out = jnp.zeros_like(val)
    if not isinstance(tsa, zero):
        out = out + jac[..., 0] * tsa
    if not isinstance(tss, zero):
        out = out + jac[..., 1] * tss
    if not isinstance(tr, zero):
        out = out + jax.jvp(lambda rr: white_family_block_profile(rr, sa, ss, block), (r,), (tr,))[1]
    return val, out


mc_R.defjvp(_mc_R_jvp, symbolic_zeros=True)


def _mc_operands(static):
    """``(g, n)`` -> the compile key and :func:`jaxsss.mc.white_family.block_operands` (see
    :attr:`ForwardModel.operands`)."""
    from jaxsss.mc.white_family import STENCIL, block_operands

    return ("white family block", STENCIL), block_operands(*static, _mc_family())


def mc_R_stderr(r, sigma_a, sigma_s_prime, static):
    """:func:`jaxsss.mc.white_family.white_family_profile_stderr` at ``static = (g, n)``: the family's relative noise."""
    from jaxsss.mc.white_family import white_family_profile_stderr

    return white_family_profile_stderr(r, sigma_a, sigma_s_prime, *static, _mc_family())


def _mc(r, medium, thickness, static):
    # ``static``: (g, n) on the host, or its block operands inside a compiled fit (ForwardModel.operands).
    on_host = isinstance(static, tuple) and all(isinstance(x, (int, float)) for x in static)
    block = _mc_operands(static)[1] if on_host else static
    # Per incident photon already (specular excluded): no entry transmittance here, unlike the diffusion models.
    return {"R": mc_R(r, medium.sigma_a, medium.sigma_s_prime, block)}


register_model(
    ForwardModel(
        "mc",
        "white Monte Carlo half-space (Kienle and Patterson 1996), transport-accurate for g in [0, 0.95] and eta in "
        "[1, 1.6] (a table family, interpolated); R only",
        ("R",),
        False,
        _mc,
        configure=_mc_configure,
        uses_g=True,
        r_min_lu=MC_R_MIN_LU,
        range_reason=("r >= 0.1 l_u at the initial guess (the white-MC model is transport near the source; 0.1 l_u "
                      "is beyond the table's merged first radial bin)"),
        r_max_ld=MC_R_MAX_LD,
        noise=mc_R_stderr,
        rough=True,
        operands=_mc_operands,
    )
)


def model_profiles(model: ForwardModel, r, sigma_a, sigma_s_prime, eta, thickness, static, *, fresnel="poly"):
    """Evaluate ``model`` for one channel: a :class:`jaxsss.Medium` is built from the scalars (traceable)."""
    medium = jaxsss.Medium(sigma_a, sigma_s_prime, eta, fresnel=fresnel)
    out = model.evaluate(r, medium, thickness, static)
    return {k: jnp.asarray(v) for k, v in out.items()}
