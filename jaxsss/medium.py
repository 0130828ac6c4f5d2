"""The homogeneous scattering medium: a small parameter pytree with its derived diffusion quantities.

Symbols follow Jensen and Buhler 2002 (hierarchical paper, Section 2) and Donner and Jensen 2007:

=====================  ===========================================  =======
symbol                 meaning                                      unit
=====================  ===========================================  =======
``sigma_a``            absorption coefficient                       1/mm
``sigma_s_prime``      reduced scattering coefficient (1-g) sigma_s 1/mm
``sigma_t_prime``      reduced extinction sigma_a + sigma_s'        1/mm
``alpha_prime``        reduced albedo sigma_s' / sigma_t'           --
``sigma_tr``           effective transport extinction               1/mm
                       sqrt(3 sigma_a sigma_t')
``D``                  diffusion constant 1 / (3 sigma_t')          mm
``l_u``                mean free path 1 / sigma_t'                  mm
``l_d``                diffuse mean free path 1 / sigma_tr          mm
``F_dr``, ``F_dt``     diffuse Fresnel reflectance, transmittance   --
``A``                  boundary coefficient (1+F_dr)/(1-F_dr)       --
``z_b``                extrapolation distance 2 A D                 mm
=====================  ===========================================  =======

``eta = n_inside / n_outside``. Every array broadcasts: give RGB or spectral channels as a trailing axis.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from jaxsss import _config  # noqa: F401  (float64)
from jaxsss.validate import check_range, require
from jaxsss.fresnel import resolve_fresnel_method

__all__ = ["Medium"]


class Medium(eqx.Module):
    """Optical properties of a homogeneous translucent medium (a pytree; derived quantities are properties).

    Args:
        sigma_a: absorption coefficient, 1/mm, ``>= 0``.
        sigma_s_prime: reduced scattering coefficient, 1/mm, ``>= 0``; ``sigma_a + sigma_s_prime > 0``.
        eta: relative index ``n_inside / n_outside``, ``> 0``.
        g: optional Henyey-Greenstein anisotropy in ``(-1, 1)``; needed only for ``sigma_s`` and ``sigma_t``.
        fresnel: ``F_dr`` method used for ``F_dr``, ``F_dt`` and ``A``: ``"poly"`` (default, the papers' fits) or
            ``"exact"`` (see :mod:`jaxsss.fresnel`). Static: it selects code, not values.

    Values are validated when the medium is built. Concrete bad values raise ``ValueError`` naming the argument,
    value and allowed range; traced values are checked with :func:`equinox.error_if`.

    Example:
        >>> m = Medium(sigma_a=[0.0021, 0.0041, 0.0071], sigma_s_prime=[2.19, 2.62, 3.00], eta=1.5)
        >>> m.l_d.shape
        (3,)
    """

    sigma_a: Float[Array, "*channels"]
    sigma_s_prime: Float[Array, "*channels"]
    eta: Float[Array, "*channels"]
    g: Float[Array, "*channels"] | None = None
    fresnel: str = eqx.field(static=True, default="poly")

    def __init__(self, sigma_a, sigma_s_prime, eta=1.0, g=None, fresnel: str = "poly"):
        resolve_fresnel_method(fresnel)
        self.sigma_a = check_range(sigma_a, "sigma_a", 0.0, None, owner="Medium")
        self.sigma_s_prime = check_range(sigma_s_prime, "sigma_s_prime", 0.0, None, owner="Medium")
        # A medium that neither absorbs nor scatters has no mean free path.
        self.sigma_a = require(
            self.sigma_a,
            self.sigma_a + self.sigma_s_prime <= 0,
            "Medium(sigma_a + sigma_s_prime=0): the medium must absorb or scatter; allowed range (0, inf)",
        )
        self.eta = check_range(eta, "eta", 0.0, None, lo_open=True, owner="Medium")
        self.g = None if g is None else check_range(g, "g", -1.0, 1.0, lo_open=True, hi_open=True, owner="Medium")
        self.fresnel = fresnel

    # --- Section 2 of the hierarchical paper: reduced coefficients ---------------------------------------------
    @property
    def sigma_t_prime(self):
        """Reduced extinction coefficient ``sigma_t' = sigma_a + sigma_s'`` (1/mm)."""
        return self.sigma_a + self.sigma_s_prime

    @property
    def alpha_prime(self):
        """Reduced albedo ``alpha' = sigma_s' / sigma_t'``."""
        return self.sigma_s_prime / self.sigma_t_prime

    @property
    def one_minus_alpha_prime(self):
        """``1 - alpha' = sigma_a / sigma_t'``, computed without cancellation near ``alpha' -> 1``."""
        return self.sigma_a / self.sigma_t_prime

    @property
    def sigma_tr(self):
        """Effective transport extinction ``sigma_tr = sqrt(3 sigma_a sigma_t')`` (1/mm; hierarchical Eq. 9)."""
        return jnp.sqrt(3.0 * self.sigma_a * self.sigma_t_prime)

    @property
    def sigma_tr_sq(self):
        """``sigma_tr^2 = 3 sigma_a sigma_t'`` (1/mm^2): unlike ``sigma_tr`` its derivative in ``sigma_a`` is finite at
        ``sigma_a = 0`` (``3 sigma_s'``), so the profiles are written in it (:mod:`jaxsss.profiles._sources`)."""
        return 3.0 * self.sigma_a * self.sigma_t_prime

    @property
    def D(self):
        """Diffusion constant ``D = 1 / (3 sigma_t')`` (mm)."""
        return 1.0 / (3.0 * self.sigma_t_prime)

    @property
    def l_u(self):
        """Mean free path ``l_u = 1 / sigma_t'`` (mm); also the depth ``z_r`` of the dipole's real source."""
        return 1.0 / self.sigma_t_prime

    @property
    def l_d(self):
        """Diffuse mean free path ``l_d = 1 / sigma_tr`` (mm); infinite when ``sigma_a = 0``."""
        return 1.0 / self.sigma_tr

    # --- Boundary ---------------------------------------------------------------------------------------------
    @property
    def F_dr(self):
        """Diffuse Fresnel reflectance of the boundary seen from inside (method ``self.fresnel``)."""
        # eta was validated when the medium was built: call the method directly, with no second run-time check.
        return resolve_fresnel_method(self.fresnel)(self.eta)

    @property
    def F_dt(self):
        """Diffuse Fresnel transmittance ``1 - F_dr``."""
        return 1.0 - self.F_dr

    @property
    def A(self):
        """Boundary coefficient ``A = (1 + F_dr) / (1 - F_dr)``."""
        F_dr = self.F_dr
        return (1.0 + F_dr) / (1.0 - F_dr)

    @property
    def z_b(self):
        """Extrapolated-boundary distance ``z_b = 2 A D`` (mm; photon-diffusion Eq. 12)."""
        return 2.0 * self.A * self.D

    # --- With the anisotropy g --------------------------------------------------------------------------------
    @property
    def sigma_s(self):
        """Scattering coefficient ``sigma_s = sigma_s' / (1 - g)`` (1/mm); requires ``g``."""
        return self.sigma_s_prime / (1.0 - self._require_g())

    @property
    def sigma_t(self):
        """Extinction coefficient ``sigma_t = sigma_a + sigma_s`` (1/mm); requires ``g``."""
        return self.sigma_a + self.sigma_s

    def _require_g(self):
        if self.g is None:
            raise ValueError("Medium(g=None): sigma_s and sigma_t need the anisotropy g; build the Medium with g=...")
        return self.g

