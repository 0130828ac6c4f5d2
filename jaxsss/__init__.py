"""jaxsss: a differentiable JAX toolkit for translucent materials.

Units are mm and 1/mm; ``eta = n_inside / n_outside``; float64 by default; every function broadcasts over a trailing
channel axis. See ``docs/architecture.md``.
"""

from jaxsss import _config  # noqa: F401  (enables float64 and the compilation cache before anything else)
from jaxsss._config import compilation_cache_dir, enable_compilation_cache

# Lazy attributes (PEP 562): ``import jaxsss`` (and ``jaxsss mc``, which needs none of these) does not pay for
# optimistix and the diffusion models until a name is used; ``from jaxsss import X`` works as before.
_LAZY = {
    "MATERIAL_TABLES": "jaxsss.data", "MeasuredMaterial": "jaxsss.data", "list_materials": "jaxsss.data",
    "material": "jaxsss.data", "material_medium": "jaxsss.data",
    "A_coefficient": "jaxsss.fresnel", "F_DR_METHODS": "jaxsss.fresnel", "F_dr": "jaxsss.fresnel",
    "F_dr_exact": "jaxsss.fresnel", "F_dr_poly": "jaxsss.fresnel", "F_dt": "jaxsss.fresnel",
    "fresnel_reflectance": "jaxsss.fresnel",
    "Medium": "jaxsss.medium",
    "attenuated_dipole_profile": "jaxsss.profiles", "attenuation_kernel": "jaxsss.profiles",
    "blend_profiles": "jaxsss.profiles", "blend_weights": "jaxsss.profiles", "blended_exitance": "jaxsss.profiles",
    "dipole_depths": "jaxsss.profiles", "dipole_exitance": "jaxsss.profiles", "dipole_profile": "jaxsss.profiles",
    "multipole_depths": "jaxsss.profiles", "multipole_exitance": "jaxsss.profiles",
    "multipole_n_pairs": "jaxsss.profiles", "multipole_profile": "jaxsss.profiles",
    "multipole_totals": "jaxsss.profiles", "oblique_profile": "jaxsss.profiles",
    "oblique_profile_sampled": "jaxsss.profiles", "oblique_total": "jaxsss.profiles",
    "quadpole_exitance": "jaxsss.profiles", "quadpole_profile": "jaxsss.profiles",
    "quadpole_sources": "jaxsss.profiles",
    "RdInversion": "jaxsss.reflectance", "alpha_prime_from_rd": "jaxsss.reflectance",
    "invert_rd": "jaxsss.reflectance", "medium_total_diffuse_reflectance": "jaxsss.reflectance",
    "total_diffuse_reflectance": "jaxsss.reflectance",
    "Reparameterisation": "jaxsss.reparam", "from_rd_ld": "jaxsss.reparam", "to_rd_ld": "jaxsss.reparam",
    "json_ready": "jaxsss.serialize",
}


def __getattr__(name: str):
    import importlib
    import importlib.util

    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
    elif not name.startswith("_") and importlib.util.find_spec(f"jaxsss.{name}") is not None:
        value = importlib.import_module(f"jaxsss.{name}")  # a submodule, e.g. jaxsss.mc (Monte Carlo transport)
    else:
        raise AttributeError(f"module 'jaxsss' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY) | {"mc"})


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
