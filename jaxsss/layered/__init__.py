"""Layered single scattering with subsurface texture maps (Francois, Pattanaik, Bouatouch and Breton).

Layers of variable thickness under a mesh's surface are described by textures whose channels hold the depth (mm)
of each layer's bottom; the single-scattered radiance is found by marching along each view ray, locating every
sample in the texture (Algorithm 1) and estimating the light's path through the layers with planar approximations
of the surface (Algorithm 2, Eqs. 9-12). Geometry is NumPy/trimesh/Embree, done once; the march is one jitted JAX
call per frame, differentiable in the per-layer coefficients. See ``docs/layered.md``.

- Coefficients: :class:`LayerStack`; presets :func:`layer_preset` (``"fish"``: the paper's Table 1).
- Phase functions: :func:`hg_phase`, :func:`schlick_phase`, :func:`schlick_k_from_g` (convention in
  :mod:`jaxsss.phase`).
- Textures: :class:`SubsurfaceTexture`, :func:`load_texture_png`, :func:`procedural_texture` (constant, veins,
  blobs).
- Scenes: :func:`load_layered_scene` (a scene file with a ``[layers]`` table), :func:`parse_layers`,
  :class:`LayerSpec`.
- Rendering: :func:`render_layered` (``jaxsss render --method layered``), :func:`prepare_layered` ->
  :class:`LayeredPrepared` with ``image(stack)``.
- Reference: :func:`prepare_reference`, :func:`reference_radiance` (true entry points, exact layer crossings).
"""

from jaxsss import _config  # noqa: F401  (float64)
from jaxsss.layered.config import LayerSpec, layer_spec, load_layered_scene, parse_layers
from jaxsss.layered.layers import LayerStack
from jaxsss.layered.lighting import LightArrays, light_arrays
from jaxsss.layered.march import PixelGeometry, march, march_pixels, reduced_intensity
from jaxsss.phase import (
    PHASE_FUNCTIONS,
    hg_phase,
    phase_value,
    schlick_k_from_g,
    schlick_mean_cosine,
    schlick_phase,
)
from jaxsss.layered.planes import fit_planes, neighbourhood_radius
from jaxsss.layered.presets import FISH_TABLE1, LAYER_PRESETS, layer_preset
from jaxsss.layered.reference import ReferenceData, exact_entry, prepare_reference, reference_radiance
from jaxsss.layered.render import (
    LayeredPrepared,
    LayeredRenderResult,
    outer_layer_medium,
    prepare_layered,
    render_layered,
)
from jaxsss.layered.tangents import surface_frames
from jaxsss.layered.textures import (
    PROCEDURAL_TEXTURES,
    SubsurfaceTexture,
    blob_texture,
    constant_texture,
    load_texture_png,
    procedural_texture,
    vein_texture,
)

__all__ = [
    "FISH_TABLE1",
    "LAYER_PRESETS",
    "LayerSpec",
    "LayerStack",
    "LayeredPrepared",
    "LayeredRenderResult",
    "LightArrays",
    "PHASE_FUNCTIONS",
    "PROCEDURAL_TEXTURES",
    "PixelGeometry",
    "ReferenceData",
    "SubsurfaceTexture",
    "blob_texture",
    "constant_texture",
    "exact_entry",
    "fit_planes",
    "hg_phase",
    "layer_preset",
    "layer_spec",
    "light_arrays",
    "load_layered_scene",
    "load_texture_png",
    "march",
    "march_pixels",
    "neighbourhood_radius",
    "outer_layer_medium",
    "parse_layers",
    "phase_value",
    "prepare_layered",
    "prepare_reference",
    "procedural_texture",
    "reduced_intensity",
    "reference_radiance",
    "render_layered",
    "schlick_k_from_g",
    "schlick_mean_cosine",
    "schlick_phase",
    "surface_frames",
    "vein_texture",
]
