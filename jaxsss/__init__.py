"""jaxsss: a differentiable JAX toolkit for translucent materials.

Units are mm and 1/mm; ``eta = n_inside / n_outside``; float64 by default; every function broadcasts over a trailing
channel axis. See ``docs/architecture.md``.
"""

from jaxsss import _config  # noqa: F401  (enables float64 and the compilation cache before anything else)
from jaxsss._config import compilation_cache_dir, enable_compilation_cache
from jaxsss.data import MATERIAL_TABLES, MeasuredMaterial, list_materials, material, material_medium
from jaxsss.fresnel import F_DR_METHODS, A_coefficient, F_dr, F_dr_exact, F_dr_poly, F_dt, fresnel_reflectance
from jaxsss.medium import Medium
from jaxsss.profiles import (
    attenuated_dipole_profile,
    attenuation_kernel,
    blend_profiles,
    blend_weights,
    blended_exitance,
    dipole_depths,
    dipole_exitance,
    dipole_profile,
    multipole_depths,
    multipole_exitance,
    multipole_n_pairs,
    multipole_profile,
    multipole_totals,
    oblique_profile,
    oblique_profile_sampled,
    oblique_total,
    quadpole_exitance,
    quadpole_profile,
    quadpole_sources,
)
from jaxsss.reflectance import (
    RdInversion,
    alpha_prime_from_rd,
    invert_rd,
    medium_total_diffuse_reflectance,
    total_diffuse_reflectance,
)
from jaxsss.reparam import Reparameterisation, from_rd_ld, to_rd_ld
from jaxsss.serialize import json_ready

from jaxsss import mc  # noqa: E402  (Monte Carlo transport reference: jaxsss.mc.simulate, Stack, Layer, MCResult)

__version__ = "0.1.0"

__all__ = [
    "A_coefficient",
    "F_DR_METHODS",
    "F_dr",
    "F_dr_exact",
    "F_dr_poly",
    "F_dt",
    "MATERIAL_TABLES",
    "MeasuredMaterial",
    "Medium",
    "RdInversion",
    "Reparameterisation",
    "alpha_prime_from_rd",
    "attenuated_dipole_profile",
    "attenuation_kernel",
    "blend_profiles",
    "blend_weights",
    "blended_exitance",
    "compilation_cache_dir",
    "dipole_depths",
    "dipole_exitance",
    "dipole_profile",
    "enable_compilation_cache",
    "fresnel_reflectance",
    "from_rd_ld",
    "invert_rd",
    "json_ready",
    "list_materials",
    "material",
    "material_medium",
    "mc",
    "medium_total_diffuse_reflectance",
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
    "to_rd_ld",
    "total_diffuse_reflectance",
]
