"""Two-pass hierarchical rendering of translucent meshes (Jensen and Buhler 2002), differentiable in the material.

Geometry (sampling, rays, octree, interaction lists) is NumPy with trimesh and embreex; everything that depends on
the material is a JAX function of arrays, so ``prepared.image(medium)`` is differentiable. See
``docs/architecture.md`` ("Renderer").

- Scenes: :func:`load_scene` / :func:`parse_scene` (TOML, ``examples/*.toml``) -> :class:`Scene`; bad files raise
  :class:`SceneError` naming the file and key. Built-in meshes: :func:`builtin_mesh` (sphere, box, slab, torus,
  teapot).
- The plan: :func:`make_plan` -> :class:`ScenePlan` (terms kept and left out, one reason each).
- Render methods (:mod:`jaxsss.render.methods`): every method is registered (:func:`register_method`,
  :func:`method_names`: hierarchical, direct, cached, photon, layered); :func:`prepare_method` does a method's
  geometry once -> :class:`Preparation` with ``image(medium)``; :func:`render` is the one driver (compile apart,
  the one report with the time split by stage) -> :class:`RenderResult`; :func:`write_outputs` (PNG, NPY, EXR,
  JSON).
- The hierarchical and direct methods' own builder: :func:`prepare` -> :class:`Prepared`. Irradiance caching with
  gradients (Keng et al. 2006): :func:`prepare_cached`, :func:`explain_cached` (the plan with the cache ratio),
  :data:`GRADIENTS`.
- Shared pieces: :mod:`jaxsss.render.shading` (shaded points, the constant image), :mod:`jaxsss.render.pairs`
  (interaction lists in blocks), :func:`build_octree`, :func:`build_interactions`, :mod:`jaxsss.render.radiance`;
  the profile kernels :mod:`jaxsss.render.bssrdf` and their curvature ratio :mod:`jaxsss.render.curvature`.
"""

from jaxsss.render.cache import (
    GRADIENTS,
    CachedPrepared,
    explain_cached,
    place_caches,
    prepare_cached,
)
from jaxsss.render.interactions import (
    Interactions,
    build_interactions,
    direct_interactions,
)
from jaxsss.render.meshes import (
    BUILTIN_MESHES,
    builtin_mesh,
    load_mesh_file,
    transform_matrix,
    uv_at,
)
from jaxsss.render.octree import Octree, build_octree
from jaxsss.render.output import encode_srgb, write_outputs
from jaxsss.render.plan import PlanItem, ScenePlan, make_plan
from jaxsss.render.methods import (
    METHODS,
    REPORT_KEYS,
    STAGES,
    Preparation,
    RenderMethod,
    RenderResult,
    explain_method,
    method_names,
    prepare_method,
    register_method,
    render,
    resolve_method,
)
from jaxsss.render.renderer import Prepared, prepare
from jaxsss.render.scene import (
    Camera,
    Light,
    Material,
    Occluder,
    Output,
    RenderSettings,
    Scene,
    SceneError,
    load_scene,
    parse_scene,
    scene_with,
)

__all__ = [
    "BUILTIN_MESHES",
    "METHODS",
    "Preparation",
    "REPORT_KEYS",
    "RenderMethod",
    "STAGES",
    "explain_method",
    "method_names",
    "prepare_method",
    "register_method",
    "resolve_method",
    "CachedPrepared",
    "Camera",
    "GRADIENTS",
    "Interactions",
    "Light",
    "Material",
    "Occluder",
    "Octree",
    "Output",
    "PlanItem",
    "Prepared",
    "RenderResult",
    "RenderSettings",
    "Scene",
    "SceneError",
    "ScenePlan",
    "build_interactions",
    "build_octree",
    "builtin_mesh",
    "direct_interactions",
    "encode_srgb",
    "load_mesh_file",
    "load_scene",
    "make_plan",
    "parse_scene",
    "explain_cached",
    "place_caches",
    "prepare_cached",
    "prepare",
    "render",
    "scene_with",
    "transform_matrix",
    "uv_at",
    "write_outputs",
]
