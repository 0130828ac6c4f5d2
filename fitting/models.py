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

A later transport model (the white-Monte-Carlo model, issue 4) registers itself with :func:`register_model`.
This module imports only jaxsss's public API.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

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
    """

    name: str
    summary: str
    outputs: tuple[str, ...]
    needs_thickness: bool
    evaluate: Callable
    prepare: Callable | None = None
    guess_static: object = None
    static_cap: object = None


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


def model_profiles(model: ForwardModel, r, sigma_a, sigma_s_prime, eta, thickness, static, *, fresnel="poly"):
    """Evaluate ``model`` for one channel: a :class:`jaxsss.Medium` is built from the scalars (traceable)."""
    medium = jaxsss.Medium(sigma_a, sigma_s_prime, eta, fresnel=fresnel)
    out = model.evaluate(r, medium, thickness, static)
    return {k: jnp.asarray(v) for k, v in out.items()}
