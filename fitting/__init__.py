"""fitting: recover sigma_a and sigma_s' from measured or rendered data with Optimistix.

This package is installed with ``jaxsss`` and imports only its public API. The profile fits (issue 4) and the
image fits (issue 5) land here; until then it exports nothing. The Rd -> alpha' inversion and the (Rd, l_d)
reparameterisation are closed-form physics and live in :mod:`jaxsss.reflectance` and :mod:`jaxsss.reparam`.
"""

__all__: list[str] = []
