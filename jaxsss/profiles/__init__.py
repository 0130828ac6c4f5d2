"""Diffusion profiles: radial exitance per unit flux entering the medium, in 1/mm^2."""

from jaxsss.profiles.dipole import dipole_depths, dipole_profile

__all__ = ["dipole_depths", "dipole_profile"]
