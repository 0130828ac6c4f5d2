"""Data sets shipped with jaxsss, each beside its citation (see :mod:`jaxsss.data.materials`)."""

from jaxsss.data.materials import (
    MATERIAL_TABLES,
    MeasuredMaterial,
    list_materials,
    material,
    material_medium,
)

__all__ = ["MATERIAL_TABLES", "MeasuredMaterial", "list_materials", "material", "material_medium"]
