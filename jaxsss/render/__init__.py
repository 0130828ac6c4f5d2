"""Two-pass hierarchical rendering of translucent meshes (Jensen and Buhler 2002), differentiable in the material.

Geometry (sampling, rays, octree, interaction lists) is NumPy with trimesh and embreex; everything that depends on
the material is a JAX function of arrays, so ``prepared.image(medium)`` is differentiable. See
``docs/architecture.md`` ("Renderer").

- Scenes: :func:`load_scene` / :func:`parse_scene` (TOML, ``examples/*.toml``) -> :class:`Scene`; bad files raise
  :class:`SceneError` naming the file and key. Built-in meshes: :func:`builtin_mesh` (sphere, box, slab, torus,
  teapot).
- The plan: :func:`make_plan` -> :class:`ScenePlan` (terms kept and left out, one reason each).
- Rendering: :func:`prepare` (geometry once) -> :class:`Prepared` with ``image(medium)``; :func:`render` (the whole
  job with timings and report) -> :class:`RenderResult`; :func:`write_outputs` (PNG, NPY, EXR, JSON).
- Irradiance caching with gradients (Keng et al. 2006): :func:`prepare_cached`, :func:`render_cached`
  (``jaxsss render --method cached``), :func:`explain_cached` (the plan with the cache ratio), :data:`GRADIENTS`.
- Pieces: :func:`build_octree`, :func:`build_interactions`, :mod:`jaxsss.render.radiance`.
"""

from jaxsss.render.cache import (
    GRADIENTS,
    CachedPrepared,
    explain_cached,
    place_caches,
    prepare_cached,
    render_cached,
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
from jaxsss.render.renderer import Prepared, RenderResult, prepare, render
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
    "render_cached",
    "scene_with",
    "transform_matrix",
    "uv_at",
    "write_outputs",
]
