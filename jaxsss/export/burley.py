"""Christensen-Burley normalized diffusion (Cycles, RenderMan, many real-time renderers) fitted to transport.

Renderers with a fixed-profile subsurface model take a surface albedo ``A`` and a length per channel instead of
sigma_a, sigma_s'. For a fitted jaxsss medium this module gives the profile's parameters that best match *transport*
(jaxsss's white Monte Carlo profile, :func:`jaxsss.mc.white.white_mc_medium_profile`, normal incidence, half-space)
and that profile's error against it.

The profile (Christensen and Burley 2015, "Approximate Reflectance Profiles for Efficient Subsurface Scattering")::

    R(r) = A (exp(-r / d) + exp(-r / (3 d))) / (8 pi d r),      integral over the plane = A

Fit: per channel, ``A`` is the transport profile's total diffuse reflectance (so the colour, the energy, is
right), and ``d`` minimises the squared difference of the radial energy densities ``2 pi r R(r)`` on ``r`` in
``[0, R_MAX_LD l_d]`` (log-spaced nodes, trapezoid weights). Reported per channel: ``A`` and ``d`` (mm);
``mfp``, the mean free path the paper's searchlight fit ``s(A) = 1.85 - A + 7 |A - 0.8|^3`` maps ``d`` to
(``l = d s(A)``, the "radius"-style input of renderers that take a mean free path); and the error: the relative L2 norm of the energy-density difference
(``error_l2``) and the largest relative error of ``R(r)`` between ``0.1 l_d`` and ``5 l_d`` (``error_max``).

The transport profile is itself truncated for very low absorption (``sigma_a / sigma_s`` below the table's
``valid_mu_min``, e.g. marble): its far tail, beyond a few l_d, is then biased low. The Burley fit is dominated by
the near field, where most of the energy leaves; for marble its ``d`` (0.36-0.53 mm) misses the 8 mm diffusion
tail entirely (``error_max`` = 1).

Units: mm and 1/mm; profiles per incident photon per mm^2. Only the (g, eta) pairs with a shipped white table
(:func:`jaxsss.mc.white.available_white_tables`) are supported; others raise ``ValueError`` naming them.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.optimize import least_squares

from jaxsss.export.support import medium_arrays

__all__ = ["R_MAX_LD", "BurleyFit", "burley_profile", "burley_fit", "searchlight_s"]

R_MAX_LD = 10.0
"""The fit covers ``r`` up to this many diffusion lengths ``l_d = 1 / sigma_tr``."""
N_NODES = 400


class BurleyFit(NamedTuple):
    """Per-channel ``(3,)`` arrays; see the module docstring."""

    A: np.ndarray
    d: np.ndarray  # mm
    mfp: np.ndarray  # mm, l = d s(A)
    error_l2: np.ndarray
    error_max: np.ndarray
    g: float
    eta: float


def burley_profile(r, A, d):
    """Christensen-Burley ``R(r)`` (1/mm^2 per unit incident flux) at radii ``r`` (mm) for albedo ``A`` and shape
    length ``d`` (mm)."""
    r = np.asarray(r, dtype=np.float64)
    # R(r) = A (e^{-r/d} + e^{-r/(3d)}) / (8 pi d r)  (Christensen and Burley 2015, Eq. 2 with s = 1/d).
    return A * (np.exp(-r / d) + np.exp(-r / (3.0 * d))) / (8.0 * np.pi * d * r)


def searchlight_s(A):
    """The paper's scaling ``s(A) = 1.85 - A + 7 |A - 0.8|^3`` for a searchlight with the mean free path as length."""
    A = np.asarray(A, dtype=np.float64)
    return 1.85 - A + 7.0 * np.abs(A - 0.8) ** 3


def burley_fit(medium) -> BurleyFit:
    """Fit the Christensen-Burley profile to the transport profile of ``medium`` (RGB, 1/mm), per channel.

    Raises:
        ValueError: no white Monte Carlo table for the medium's (g, eta) (the message lists those available).
    """
    from jaxsss.mc.white import white_mc_medium_profile

    m = medium_arrays(medium)
    # sigma_tr = sqrt(3 sigma_a sigma_t'): the diffusion length l_d = 1 / sigma_tr sets the radial range.
    l_d = 1.0 / np.sqrt(3.0 * m["sigma_a"] * (m["sigma_a"] + m["sigma_s_prime"]))
    l_u = 1.0 / (m["sigma_a"] + m["sigma_s_prime"])
    fits = {k: np.zeros(3) for k in ("A", "d", "error_l2", "error_max")}
    for c in range(3):
        r = np.geomspace(1e-3 * l_u[c], R_MAX_LD * l_d[c], N_NODES)
        w = np.gradient(r)  # trapezoid-like weights on the log grid
        sub = type(medium)(np.full(1, m["sigma_a"][c]), np.full(1, m["sigma_s_prime"][c]), m["eta"],
                           None if medium.g is None else m["g"])
        ref = np.asarray(white_mc_medium_profile(r[:, None], sub), dtype=np.float64)[:, 0]
        energy = 2.0 * np.pi * r * ref
        # A = integral of 2 pi r R(r) dr: the transport profile's total diffuse reflectance.
        A = float(np.sum(energy * w))

        def resid(p, r=r, w=w, energy=energy, A=A):
            return (2.0 * np.pi * r * burley_profile(r, A, np.exp(p[0])) - energy) * np.sqrt(w)

        sol = least_squares(resid, x0=[np.log(l_d[c] / 2.0)], method="lm")
        d = float(np.exp(sol.x[0]))
        fitted = burley_profile(r, A, d)
        window = (r >= 0.1 * l_d[c]) & (r <= 5.0 * l_d[c])
        fits["A"][c], fits["d"][c] = A, d
        fits["error_l2"][c] = float(np.sqrt(np.sum(resid(sol.x) ** 2) / np.sum(energy**2 * w)))
        fits["error_max"][c] = float(np.max(np.abs(fitted[window] / ref[window] - 1.0)))
    return BurleyFit(fits["A"], fits["d"], fits["d"] * searchlight_s(fits["A"]), fits["error_l2"],
                     fits["error_max"], m["g"], m["eta"])
