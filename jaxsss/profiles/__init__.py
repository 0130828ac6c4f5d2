"""Diffusion profiles: radial exitance per unit flux entering the medium, in 1/mm^2.

- :mod:`~jaxsss.profiles.dipole`, :mod:`~jaxsss.profiles.multipole`: the classical half-space and slab profiles;
- :mod:`~jaxsss.profiles.oblique`: sources spread along an oblique refracted beam (photon diffusion Eq. 8) and the
  attenuation kernel (Eq. 9);
- :mod:`~jaxsss.profiles.point_sources`, :mod:`~jaxsss.profiles.quadpole`, :mod:`~jaxsss.profiles.blend`: one
  source at any depth (dipole, multipole), at a right-angled edge (quadpole, Eq. 14) and the geometry-aware blend of
  the three (Eq. 15), per unit source power.
"""

from jaxsss.profiles.blend import blend_profiles, blend_weights, blended_exitance
from jaxsss.profiles.dipole import dipole_depths, dipole_profile
from jaxsss.profiles.multipole import (
    multipole_depths,
    multipole_n_pairs,
    multipole_profile,
    multipole_totals,
)
from jaxsss.profiles.oblique import (
    DEFAULT_KAPPA,
    KAPPA_COEFFICIENTS,
    attenuated_dipole_profile,
    attenuation_kernel,
    beam_integral,
    oblique_profile,
    oblique_profile_sampled,
    oblique_total,
    refracted_direction,
    sample_beam_sources,
)
from jaxsss.profiles.point_sources import dipole_exitance, multipole_exitance
from jaxsss.profiles.quadpole import (
    quadpole_exitance,
    quadpole_profile,
    quadpole_sources,
)

__all__ = [
    "DEFAULT_KAPPA",
    "KAPPA_COEFFICIENTS",
    "attenuated_dipole_profile",
    "attenuation_kernel",
    "beam_integral",
    "blend_profiles",
    "blend_weights",
    "blended_exitance",
    "dipole_depths",
    "dipole_exitance",
    "dipole_profile",
    "multipole_depths",
    "multipole_exitance",
    "multipole_n_pairs",
    "multipole_profile",
    "multipole_totals",
    "oblique_profile",
    "oblique_profile_sampled",
    "oblique_total",
    "quadpole_exitance",
    "quadpole_profile",
    "quadpole_sources",
    "refracted_direction",
    "sample_beam_sources",
]
