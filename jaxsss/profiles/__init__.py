"""Diffusion profiles: radial exitance per unit flux entering the medium, in 1/mm^2."""

from jaxsss.profiles.dipole import dipole_depths, dipole_profile
from jaxsss.profiles.multipole import multipole_depths, multipole_n_pairs, multipole_profile, multipole_totals

__all__ = [
    "dipole_depths",
    "dipole_profile",
    "multipole_depths",
    "multipole_n_pairs",
    "multipole_profile",
    "multipole_totals",
]
