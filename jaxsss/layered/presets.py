"""Layer presets: published per-layer coefficients, with units and citation.

``fish``: Table 1 of G. Francois, S. Pattanaik, K. Bouatouch and G. Breton, "Subsurface Texture Mapping", INRIA
research report (also IEEE CG&A 28(1), 2008). The fish model's three layers, 1/mm, channels R, G, B; the paper uses
its Schlick phase function with the listed ``g`` (here read as the Henyey-Greenstein anisotropy and converted to
Schlick's ``k``, see :mod:`jaxsss.phase`).

=========  ==================  ==================  ====
layer      sigma_s (R, G, B)   sigma_t (R, G, B)   g
=========  ==================  ==================  ====
dermis     2.0, 1.0, 1.0       2.6, 1.6, 1.6       0.25
blood      6.0, 3.0, 2.0       6.6, 3.6, 2.6       0.40
organs     1.0, 1.0, 2.0       1.5, 1.5, 2.5       0.80
=========  ==================  ==================  ====
"""

from __future__ import annotations

import numpy as np

from jaxsss.layered.layers import LayerStack

__all__ = ["LAYER_PRESETS", "FISH_TABLE1", "layer_preset"]

#: Francois et al., Table 1 ("Scattering coefficients used for the fish model"); 1/mm, (R, G, B).
FISH_TABLE1 = {
    "names": ("dermis", "blood", "organs"),
    "sigma_s": np.array([[2.0, 1.0, 1.0], [6.0, 3.0, 2.0], [1.0, 1.0, 2.0]]),
    "sigma_t": np.array([[2.6, 1.6, 1.6], [6.6, 3.6, 2.6], [1.5, 1.5, 2.5]]),
    "g": np.array([0.25, 0.40, 0.80]),
    "phase": "schlick",
    "citation": "Francois, Pattanaik, Bouatouch, Breton: Subsurface Texture Mapping, Table 1",
}

#: name -> table with ``names``, ``sigma_s``, ``sigma_t`` (1/mm), ``g``, ``phase``, ``citation``.
LAYER_PRESETS = {"fish": FISH_TABLE1}


def layer_preset(name: str, phase: str | None = None) -> LayerStack:
    """The :class:`LayerStack` of a preset (``"fish"``); ``phase`` overrides the preset's phase function.

    Raises:
        ValueError: unknown preset (the message lists the valid ones).
    """
    if name not in LAYER_PRESETS:
        raise ValueError(f"layer preset {name!r} is not known; valid: {', '.join(LAYER_PRESETS)}")
    t = LAYER_PRESETS[name]
    return LayerStack.create(t["sigma_s"], t["sigma_t"], t["g"], phase or t["phase"], t["names"])
