"""The scene plan for the layered method: the ray march, and whether the outer layer gets a diffusion term.

The layered method (Francois et al.) computes single scattering in every layer. Multiple scattering in the outer
layer can be added with the hierarchical dipole of the scene's ``[material]`` (the renderer of
:mod:`jaxsss.render`). The plan decides (``[layers].diffusion = "auto"``) and says why:

- left out when ``[material]``'s total diffuse reflectance ``Rd`` is below the scene's tolerance (nothing to add);
- left out when the outer layer is thinner than :data:`DIFFUSION_MIN_OPTICAL_DEPTH` reduced mean free paths on
  average over the texture (``tau' = mean thickness x sigma_t'``): light reaches the layers below before it has
  diffused, and the dipole's half-space would count scattering that the layers below already account for;
- kept otherwise.

``"on"`` / ``"off"`` force it, and the reason says so.
"""

from __future__ import annotations

import numpy as np

from jaxsss.reflectance import medium_total_diffuse_reflectance
from jaxsss.render.plan import PlanItem

__all__ = ["DIFFUSION_MIN_OPTICAL_DEPTH", "layered_plan"]

DIFFUSION_MIN_OPTICAL_DEPTH = 1.0
"""The outer layer must be at least this many reduced mean free paths thick (texture mean) for the diffusion term."""


def layered_plan(scene, spec, *, samples: int | None = None) -> tuple[bool, tuple[PlanItem, ...]]:
    """``(diffusion, items)``: whether to add the outer layer's diffusion term, and the plan lines.

    Args:
        scene: the :class:`~jaxsss.render.Scene` (its ``[material]`` is the outer layer's diffusion medium; its
            ``[render].tolerance`` is the threshold on ``Rd``).
        spec: the :class:`~jaxsss.layered.LayerSpec`.
        samples: ``N`` samples per view ray (default ``spec.samples``).
    """
    n = int(samples or spec.samples)
    stack = spec.stack
    items = [PlanItem("ray marching", True,
                      f"{stack.n_layers} layers ({', '.join(stack.names)}) from a {spec.texture.shape[0]}x"
                      f"{spec.texture.shape[1]} subsurface texture: {n} samples per view ray (Algorithm 2)")]
    medium = scene.material.medium
    rd = float(np.max(np.asarray(medium_total_diffuse_reflectance(medium))))
    thickness = float(np.mean(spec.texture.boundaries[..., 0]))
    tau = thickness * float(np.min(np.asarray(medium.sigma_t_prime)))
    tol = float(scene.render.tolerance)
    facts = f"[material] Rd = {rd:.3g}, outer layer {thickness:.3g} mm = {tau:.3g} reduced mean free paths (mean)"
    if spec.diffusion == "on":
        return True, tuple(items + [PlanItem("outer-layer diffusion", True, f"forced on by [layers].diffusion; "
                                                                            f"{facts}")])
    if spec.diffusion == "off":
        return False, tuple(items + [PlanItem("outer-layer diffusion", False, f"forced off by [layers].diffusion; "
                                                                              f"{facts}")])
    if rd < tol:
        diffusion, why = False, f"{facts}: Rd < tolerance {tol:g}, multiple scattering is negligible"
    elif tau < DIFFUSION_MIN_OPTICAL_DEPTH:
        diffusion, why = False, (f"{facts} < {DIFFUSION_MIN_OPTICAL_DEPTH:g}: light reaches the layers below before "
                                 "it diffuses, so a half-space dipole does not describe the outer layer")
    else:
        diffusion, why = True, f"{facts}: the hierarchical dipole adds the outer layer's multiple scattering"
    return diffusion, tuple(items + [PlanItem("outer-layer diffusion", diffusion, why)])
