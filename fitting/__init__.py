"""fitting: recover sigma_a and sigma_s' from measured or simulated radial profiles with Optimistix.

This package is installed with ``jaxsss`` and imports only its public API (``import jaxsss``).

- :func:`fit_profile` / :func:`fit_profiles`: least-squares fits of R(r) and/or T(r) (absolute per incident photon,
  or relative with a free scale), one compiled vmapped call for all channels and profiles, sharded over devices
  when there are several; :class:`ProfileFit` holds estimates, standard errors, correlation and solver status. Each
  fit is solved from three starts (the basins of a grid over albedo and ``l_d``), and a fit that may be wrong says
  so: ``ProfileFit.suspect`` (residuals above the given noise, another minimum as good, a smooth misfit),
  ``ProfileFit.reliable`` and a :class:`FitWarning`. Tabulated (rough) models, the ``mc`` family, get more: valley
  scans from the solution (their noise makes local minima along it), a secant Jacobian for the standard errors, a
  warning where the table's own noise exceeds 3% on the fit range, and relative far-field data (beyond 0.5 ``l_d``)
  reported as not identifiable.
- :func:`fit_jacobian_wrt_data`: derivatives of the fitted parameters with respect to the data (implicit function
  theorem).
- Registries: :data:`FORWARD_MODELS` (``dipole``, ``multipole``, ``mc``; :func:`register_model` adds more) and
  :data:`SOLVERS` (``levenberg_marquardt``, ``gauss_newton``, ``dogleg``).
- I/O: :func:`read_profile_csv`, :func:`load_profile_npy`, :func:`read_profile` -> :class:`ProfileData`;
  :func:`read_mco` reads MCML 1.2.2's ``.mco`` output (:class:`McoRun`, in mm; ``read_profile`` dispatches ``.mco``);
  :func:`fit_mco` fits such a run as it stands (transport-accurate: white MC or replay Monte Carlo);
  :func:`fit_free_g` fits ``g`` too, from near-source data of a half-space (white-MC family);
  :func:`fit_mc_slab` fits a slab's profile file by replay Monte Carlo (``jaxsss fit --model mc --thickness``).

The Rd -> alpha' inversion and the (Rd, l_d) reparameterisation are closed-form physics and live in
:mod:`jaxsss.reflectance` and :mod:`jaxsss.reparam`. - :func:`fit_image`: sigma_a and sigma_s' per channel from a rendered image (:class:`ImageFit`); a channel whose
``l_d`` the views do not resolve (under :data:`RESOLVED_LD_PIXELS` pixels, :func:`pixel_footprint`) is reported as
fixing ``Rd`` only; ``model_error=RENDER_MODEL_ERROR`` (a :class:`ModelError`, :mod:`fitting.discrepancy`) states
the renderer's accuracy against real transport, per band of the cosine to each light, for a target it did not make.
"""

import jaxsss  # noqa: F401  (float64 before anything else)

# The public names are imported on first use (PEP 562, as in jaxsss/__init__): `jaxsss fit PROFILE.csv` needs the
# profile fits only, not the image, replay and Monte Carlo fits (~1 s of imports on this machine).
_LAZY = {
    "ImageFit": "fitting.image_fit", "fit_image": "fitting.image_fit", "pixel_footprint": "fitting.image_fit",
    "RESOLVED_LD_PIXELS": "fitting.image_fit", "RENDER_MODEL_ERROR": "fitting.discrepancy",
    "ModelError": "fitting.discrepancy",
    "COLUMNS": "fitting.io", "ProfileData": "fitting.io", "ProfileFileError": "fitting.io",
    "load_profile_npy": "fitting.io", "read_profile": "fitting.io", "read_profile_csv": "fitting.io",
    "McoLayer": "fitting.mco", "McoRun": "fitting.mco", "read_mco": "fitting.mco",
    "MCO_MODELS": "fitting.mco_fit", "McoFit": "fitting.mco_fit", "fit_mco": "fitting.mco_fit",
    "fit_mc_slab": "fitting.mco_fit",
    "FreeGFit": "fitting.g_fit", "fit_free_g": "fitting.g_fit",
    "FORWARD_MODELS": "fitting.models", "ForwardModel": "fitting.models", "entry_transmittance": "fitting.models",
    "register_model": "fitting.models", "resolve_model": "fitting.models",
    "ReplayData": "fitting.replay_fit", "ReplayFit": "fitting.replay_fit", "fit_replay": "fitting.replay_fit",
    "fit_slab_totals": "fitting.replay_fit",
    "FitWarning": "fitting.profile_fit", "fit_jacobian_wrt_data": "fitting.profile_fit",
    "fit_profile": "fitting.profile_fit", "fit_profiles": "fitting.profile_fit",
    "CONDITION_LIMIT": "fitting.result", "CORRELATION_LIMIT": "fitting.result", "SUSPECT_CHI2": "fitting.result",
    "SUSPECT_STRUCTURE": "fitting.result", "SUSPECT_TIE": "fitting.result", "ProfileFit": "fitting.result",
    "SOLVERS": "fitting.solvers", "LeastSquaresSolver": "fitting.solvers", "resolve_solver": "fitting.solvers",
}


def __getattr__(name: str):
    import importlib
    import importlib.util

    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
    elif not name.startswith("_") and importlib.util.find_spec(f"fitting.{name}") is not None:
        value = importlib.import_module(f"fitting.{name}")  # a submodule, e.g. fitting.models
    else:
        raise AttributeError(f"module 'fitting' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "MCO_MODELS",
    "FreeGFit",
    "McoFit",
    "COLUMNS",
    "CONDITION_LIMIT",
    "CORRELATION_LIMIT",
    "FORWARD_MODELS",
    "FitWarning",
    "ImageFit",
    "ForwardModel",
    "LeastSquaresSolver",
    "McoLayer",
    "McoRun",
    "ModelError",
    "ProfileData",
    "ProfileFileError",
    "ProfileFit",
    "RENDER_MODEL_ERROR",
    "RESOLVED_LD_PIXELS",
    "ReplayData",
    "ReplayFit",
    "SOLVERS",
    "SUSPECT_CHI2",
    "SUSPECT_STRUCTURE",
    "SUSPECT_TIE",
    "entry_transmittance",
    "fit_image",
    "fit_jacobian_wrt_data",
    "fit_profile",
    "fit_profiles",
    "fit_free_g",
    "fit_mc_slab",
    "fit_mco",
    "fit_replay",
    "fit_slab_totals",
    "load_profile_npy",
    "pixel_footprint",
    "read_profile",
    "read_mco",
    "read_profile_csv",
    "register_model",
    "resolve_model",
    "resolve_solver",
]
