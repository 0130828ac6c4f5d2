"""fitting: recover sigma_a and sigma_s' from measured or simulated radial profiles with Optimistix.

This package is installed with ``jaxsss`` and imports only its public API (``import jaxsss``).

- :func:`fit_profile` / :func:`fit_profiles`: least-squares fits of R(r) and/or T(r) (absolute per incident photon,
  or relative with a free scale), one compiled vmapped call for all channels and profiles, sharded over devices
  when there are several; :class:`ProfileFit` holds estimates, standard errors, correlation and solver status. Each
  fit is solved from three starts (the basins of a grid over albedo and ``l_d``), and a fit that may be wrong says
  so: ``ProfileFit.suspect`` (residuals above the given noise, another minimum as good, a smooth misfit),
  ``ProfileFit.reliable`` and a :class:`FitWarning`.
- :func:`fit_jacobian_wrt_data`: derivatives of the fitted parameters with respect to the data (implicit function
  theorem).
- Registries: :data:`FORWARD_MODELS` (``dipole``, ``multipole``; :func:`register_model` adds more) and
  :data:`SOLVERS` (``levenberg_marquardt``, ``gauss_newton``, ``dogleg``).
- I/O: :func:`read_profile_csv`, :func:`load_profile_npy`, :func:`read_profile` -> :class:`ProfileData`;
  :func:`read_mco` reads MCML 1.2.2's ``.mco`` output (:class:`McoRun`, in mm; ``read_profile`` dispatches ``.mco``);
  :func:`fit_mco` fits such a run as it stands (transport-accurate: white MC or replay Monte Carlo);
  :func:`fit_mc_slab` fits a slab's profile file by replay Monte Carlo (``jaxsss fit --model mc --thickness``).

The Rd -> alpha' inversion and the (Rd, l_d) reparameterisation are closed-form physics and live in
:mod:`jaxsss.reflectance` and :mod:`jaxsss.reparam`. - :func:`fit_image`: sigma_a and sigma_s' per channel from a rendered image (:class:`ImageFit`).
"""

import jaxsss  # noqa: F401  (float64 before anything else)
from fitting.image_fit import ImageFit, fit_image
from fitting.io import COLUMNS, ProfileData, ProfileFileError, load_profile_npy, read_profile, read_profile_csv
from fitting.mco import McoLayer, McoRun, read_mco
from fitting.mco_fit import MCO_MODELS, McoFit, fit_mc_slab, fit_mco
from fitting.models import FORWARD_MODELS, ForwardModel, entry_transmittance, register_model, resolve_model
from fitting.replay_fit import ReplayData, ReplayFit, fit_replay, fit_slab_totals
from fitting.profile_fit import FitWarning, fit_jacobian_wrt_data, fit_profile, fit_profiles
from fitting.result import (
    CONDITION_LIMIT,
    CORRELATION_LIMIT,
    SUSPECT_CHI2,
    SUSPECT_STRUCTURE,
    SUSPECT_TIE,
    ProfileFit,
)
from fitting.solvers import SOLVERS, LeastSquaresSolver, resolve_solver

__all__ = [
    "MCO_MODELS",
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
    "ProfileData",
    "ProfileFileError",
    "ProfileFit",
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
    "fit_mc_slab",
    "fit_mco",
    "fit_replay",
    "fit_slab_totals",
    "load_profile_npy",
    "read_profile",
    "read_mco",
    "read_profile_csv",
    "register_model",
    "resolve_model",
    "resolve_solver",
]
