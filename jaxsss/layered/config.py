"""The ``[layers]`` table of a scene file, and a loader for scene files that carry one.

:func:`parse_layers` validates the table (as a dict, from :mod:`tomllib`) and returns a :class:`LayerSpec`;
errors are :class:`jaxsss.render.scene.SceneError` naming the file and the dotted key, e.g.
``examples/x.toml: [layers.layer[1].sigma_t] 0.5 (element 0) is below sigma_s = 1; allowed range [sigma_s, inf)``.
The section is registered with the scene floor (:func:`jaxsss.render.scene.register_section`), so
:func:`jaxsss.render.load_scene` parses it with the same validator (:class:`~jaxsss.render.scene.SceneKeys`) as
the rest of the file; :func:`load_layered_scene` also checks that the table is there.

Schema (units mm and 1/mm)::

    [layers]
    preset = "fish"             # a preset (jaxsss.layered.LAYER_PRESETS) -- or [[layers.layer]] tables, not both
    phase = "schlick"           # optional: override every layer's phase function (hg | schlick)
    samples = 50                # N samples per view ray, integer >= 1 (default 50)
    depth_max = 2.0             # Depth_max of Eq. 15, mm, > 0 (default: the texture's deepest layer bottom)
    plane_eps = 0.01            # plane-fit radius r = -log(plane_eps) / sigma_t (Eq. 8), in (0, 1)
    tile = [4.0, 2.0]           # texture repeats over the mesh's UV range, > 0; one number or [u, v]
    wrap = "auto"               # which UV coordinates wrap on the mesh: auto | none | u | v | uv
    clip_to_exit = true         # stop the march where the view ray leaves the mesh
    shadows = true              # shadow rays from the visible point towards each light
    chunk = 16384               # pixels per chunk of the jitted march, >= 1
    diffusion = "auto"          # the outer layer's multiple scattering by the hierarchical dipole with [material]:
                                # auto (the scene plan decides, jaxsss.layered.plan) | on | off

    [[layers.layer]]            # one per layer, from the surface down (at least one)
    name = "dermis"
    sigma_s = [2.0, 1.0, 1.0]   # scattering, 1/mm, >= 0; one number or 3 values (R, G, B)
    sigma_t = [2.6, 1.6, 1.6]   # extinction, 1/mm, >= sigma_s
    g = 0.25                    # anisotropy in (-1, 1) (default 0)
    phase = "schlick"           # hg | schlick (default hg)

    [layers.texture]            # exactly one of files | procedural
    files = ["skin.png"]        # PNGs, relative to the scene file; channels stacked in order (RGBA = 4 layers)
    depth_scale_mm = 1.0        # depth of a black pixel (white = 0); one number or one per layer
    procedural = "veins"        # constant | veins | blobs, with that generator's keys, e.g.
    size = 256                  #   size, seed, thickness = [...] (mm per layer), vein_layer, vein_depth (mm),
    seed = 0                    #   vein_width (texture widths), n_veins, branches; blob_layer, blob_depth, n_blobs,
                                #   radius = [min, max]
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from jaxsss.validate import check_integer
from jaxsss.layered.layers import LayerStack
from jaxsss.phase import PHASE_FUNCTIONS
from jaxsss.layered.presets import LAYER_PRESETS, layer_preset
from jaxsss.layered.textures import PROCEDURAL_TEXTURES, SubsurfaceTexture, load_texture_png, procedural_texture
from jaxsss.render.scene import Scene, SceneError, SceneKeys, register_section

__all__ = ["DIFFUSION_CHOICES", "LayerSpec", "WRAP_CHOICES", "layer_spec", "load_layered_scene", "parse_layers"]

WRAP_CHOICES = {"auto": None, "none": (False, False), "u": (True, False), "v": (False, True), "uv": (True, True)}
_TOP = ("preset", "phase", "samples", "depth_max", "plane_eps", "tile", "wrap", "clip_to_exit", "shadows", "chunk",
        "diffusion", "layer", "texture")
DIFFUSION_CHOICES = ("auto", "on", "off")
_LAYER_KEYS = ("name", "sigma_s", "sigma_t", "g", "phase")


@dataclass(frozen=True, eq=False)
class LayerSpec:
    """Everything the layered method needs beyond the scene: coefficients, texture and knobs (see the schema)."""

    stack: LayerStack
    texture: SubsurfaceTexture
    samples: int = 50
    depth_max: float | None = None
    plane_eps: float = 0.01
    tile: tuple[float, float] = (1.0, 1.0)
    wrap: tuple[bool, bool] | None = None
    clip_to_exit: bool = True
    shadows: bool = True
    chunk: int = 16384
    diffusion: str = "auto"  # the outer layer's diffusion term: auto (the plan decides) | on | off

    @property
    def effective_depth_max(self) -> float:
        """``Depth_max`` in mm: the given value, else the texture's deepest layer bottom."""
        return self.texture.depth_max if self.depth_max is None else float(self.depth_max)


def layer_spec(stack: LayerStack, texture: SubsurfaceTexture, **knobs) -> LayerSpec:
    """A :class:`LayerSpec` from Python objects, with the same checks as the TOML table."""
    if texture.n_layers < stack.n_layers:
        raise ValueError(f"layer_spec(texture=...): {texture.n_layers} texture channels for {stack.n_layers} layers")
    texture = texture.layers(stack.n_layers) if texture.n_layers > stack.n_layers else texture
    spec = LayerSpec(stack, texture, **knobs)
    check_integer(spec.samples, "samples", 1, owner="layer_spec")
    if not 0.0 < spec.plane_eps < 1.0:
        raise ValueError(f"layer_spec(plane_eps={spec.plane_eps!r}): allowed range (0, 1)")
    if spec.depth_max is not None and not (spec.depth_max > 0 and math.isfinite(spec.depth_max)):
        raise ValueError(f"layer_spec(depth_max={spec.depth_max!r}): allowed range (0, inf) mm")
    if not spec.effective_depth_max > 0:
        raise ValueError("layer_spec(texture=...): every layer has zero thickness everywhere (Depth_max = 0)")
    return spec


def _parse_layer(k: SceneKeys, table, key: str) -> dict:
    k.only(table, key, _LAYER_KEYS)
    for name in ("sigma_s", "sigma_t"):
        if name not in table:
            raise k.error(f"{key}.{name}", "missing (1/mm, one number or 3 values)")
    s = k.values(table["sigma_s"], f"{key}.sigma_s", lo=0.0)
    t = k.values(table["sigma_t"], f"{key}.sigma_t", lo=0.0)
    if s.size != t.size and 1 not in (s.size, t.size):
        raise k.error(f"{key}.sigma_t", f"{t.size} values but sigma_s has {s.size}")
    s, t = np.broadcast_arrays(s, t)
    below = np.flatnonzero(t < s)
    if below.size:
        i = int(below[0])
        raise k.error(f"{key}.sigma_t", f"{t[i]:g} (element {i}) is below sigma_s = {s[i]:g}; allowed range "
                                        "[sigma_s, inf) (sigma_a = sigma_t - sigma_s >= 0)")
    g = k.number(table.get("g", 0.0), f"{key}.g", -1.0, 1.0, lo_open=True, hi_open=True)
    phase = k.choice(table.get("phase", "hg"), f"{key}.phase", tuple(PHASE_FUNCTIONS))
    return dict(name=str(table.get("name", key)), sigma_s=s, sigma_t=t, g=g, phase=phase)


def _parse_texture(k: SceneKeys, table, n_layers: int) -> SubsurfaceTexture:
    key = "layers.texture"
    if not isinstance(table, dict):
        raise k.error(key, "must be a table [layers.texture]")
    has_files, has_proc = "files" in table, "procedural" in table
    if has_files == has_proc:
        raise k.error(key, "give exactly one of files (PNG paths) or procedural (" +
                      ", ".join(PROCEDURAL_TEXTURES) + ")")
    if has_files:
        k.only(table, key, ("files", "depth_scale_mm"))
        files = table["files"]
        files = [files] if isinstance(files, str) else files
        if not isinstance(files, list) or not files or not all(isinstance(f, str) for f in files):
            raise k.error(f"{key}.files", f"{table['files']!r} is not a path or a list of paths")
        paths = [k.file(f, f"{key}.files") for f in files]
        if "depth_scale_mm" not in table:
            raise k.error(f"{key}.depth_scale_mm", "missing: the depth of a black pixel, mm (white = 0)")
        scale = k.values(table["depth_scale_mm"], f"{key}.depth_scale_mm", lo=0.0, lo_open=True)
        try:
            tex = load_texture_png(paths, scale, None)
        except (ValueError, OSError) as err:
            raise k.error(f"{key}.files", str(err)) from None
    else:
        kind = k.choice(table["procedural"], f"{key}.procedural", tuple(PROCEDURAL_TEXTURES))
        params = {name: value for name, value in table.items() if name != "procedural"}
        params.setdefault("thickness", None)
        if params["thickness"] is None:
            raise k.error(f"{key}.thickness", f"missing: one thickness per layer ({n_layers}), mm")
        params["thickness"] = k.values(params["thickness"], f"{key}.thickness", n=n_layers, lo=0.0)
        try:
            tex = procedural_texture(kind, **params)
        except (ValueError, TypeError) as err:
            raise k.error(key, str(err)) from None
    if tex.n_layers < n_layers:
        raise k.error(key, f"the texture has {tex.n_layers} channels for {n_layers} layers; give more files")
    return tex.layers(n_layers) if tex.n_layers > n_layers else tex


def parse_layers(table: dict, *, path: str = "<scene>", base_dir=None) -> LayerSpec:
    """Validate a ``[layers]`` table (the module schema) and build the :class:`LayerSpec`.

    Args:
        table: the ``layers`` table of a parsed scene file.
        path: file name for messages. base_dir: where relative texture paths resolve (default: working directory).

    Raises:
        SceneError: a bad or missing entry, naming the file and the dotted key ``layers....``.
    """
    return _parse_layers(table, SceneKeys(str(path), base_dir))


def _parse_layers(table: dict, k: SceneKeys) -> LayerSpec:
    k.only(table, "layers", _TOP)
    has_preset, has_layers = "preset" in table, "layer" in table
    if has_preset == has_layers:
        raise k.error("layers", "give exactly one of preset (" + ", ".join(LAYER_PRESETS) +
                      ") or [[layers.layer]] tables")
    phase = k.choice(table["phase"], "layers.phase", tuple(PHASE_FUNCTIONS)) if "phase" in table else None
    if has_preset:
        stack = layer_preset(k.choice(table["preset"], "layers.preset", tuple(LAYER_PRESETS)), phase)
    else:
        rows = table["layer"]
        rows = [rows] if isinstance(rows, dict) else rows
        if not isinstance(rows, list) or not rows:
            raise k.error("layers.layer", "must be an array of tables [[layers.layer]] (at least one)")
        parsed = [_parse_layer(k, r, f"layers.layer[{i}]") for i, r in enumerate(rows)]
        c = max(p["sigma_s"].size for p in parsed)
        stack = LayerStack.create(np.stack([np.broadcast_to(p["sigma_s"], (c,)) for p in parsed]),
                                  np.stack([np.broadcast_to(p["sigma_t"], (c,)) for p in parsed]),
                                  np.array([p["g"] for p in parsed]),
                                  tuple(phase or p["phase"] for p in parsed), tuple(p["name"] for p in parsed))
    if "texture" not in table:
        raise k.error("layers.texture", "missing section [layers.texture]")
    texture = _parse_texture(k, table["texture"], stack.n_layers)
    knobs = {}
    if "samples" in table:
        knobs["samples"] = k.integer(table["samples"], "layers.samples", 1)
    if "depth_max" in table:
        knobs["depth_max"] = k.number(table["depth_max"], "layers.depth_max", 0.0, lo_open=True)
    if "plane_eps" in table:
        knobs["plane_eps"] = k.number(table["plane_eps"], "layers.plane_eps", 0.0, 1.0, lo_open=True, hi_open=True)
    if "tile" in table:
        tile = k.values(table["tile"], "layers.tile", lo=0.0, lo_open=True)
        if tile.size > 2:
            raise k.error("layers.tile", f"{table['tile']!r} is not one number or [u, v]")
        knobs["tile"] = tuple(float(x) for x in np.broadcast_to(tile, (2,)))
    if "wrap" in table:
        knobs["wrap"] = WRAP_CHOICES[k.choice(table["wrap"], "layers.wrap", tuple(WRAP_CHOICES))]
    for name in ("clip_to_exit", "shadows"):
        if name in table:
            knobs[name] = k.boolean(table[name], f"layers.{name}")
    if "chunk" in table:
        knobs["chunk"] = k.integer(table["chunk"], "layers.chunk", 1)
    if "diffusion" in table:
        value = table["diffusion"]
        value = {True: "on", False: "off"}.get(value, value) if isinstance(value, bool) else value
        knobs["diffusion"] = k.choice(value, "layers.diffusion", DIFFUSION_CHOICES)
    try:
        return layer_spec(stack, texture, **knobs)
    except ValueError as err:
        raise k.error("layers", str(err)) from None


register_section("layers", _parse_layers)


def load_layered_scene(path) -> tuple[Scene, LayerSpec]:
    """Read a scene file with a ``[layers]`` table: ``(scene, layer_spec)`` (``scene.layers`` is the same spec).

    :func:`jaxsss.render.load_scene` parses ``[layers]`` with :func:`parse_layers`; this adds the check that the
    table is there.

    Raises:
        SceneError: unreadable file, TOML syntax error, a missing ``[layers]`` table, or any bad entry.
    """
    from jaxsss.render.scene import load_scene

    scene = load_scene(path)
    if scene.layers is None:
        raise SceneError(os.fspath(path), "layers", "missing section [layers] (the layered method needs one)")
    return scene, scene.layers
