"""Scene files: a TOML description of one translucent mesh, its material, lights, camera and opaque occluders.

:func:`load_scene` reads a file, :func:`parse_scene` a dict (as from :mod:`tomllib`); both validate everything once
and return a frozen :class:`Scene`. Bad input raises :class:`SceneError` (a ``ValueError``) naming the file, the
dotted key and, for values, the value and the allowed range, e.g.::

    examples/x.toml: [material.sigma_a] -0.1 (element 0) is outside the allowed range [0, inf)

Relative file paths (meshes, textures, the environment map) resolve against the scene file's directory.

Schema (units: mm, 1/mm, degrees; "3 values" means ``[x, y, z]`` or ``[r, g, b]``; colours may be one number)::

    [mesh]                    # exactly one of builtin / file
    builtin = "teapot"        # sphere | box | slab | torus | teapot (jaxsss.render.meshes.BUILTIN_MESHES)
    size = 60.0               # that builtin's parameters: radius, subdivisions (sphere); extents, subdivisions
                              # (box); width, depth, thickness, subdivisions (slab); major_radius, minor_radius,
                              # major_sections, minor_sections (torus); size, resolution (teapot)
    file = "bunny.ply"        # any mesh file trimesh reads, relative to the scene file
    scale = 1.0               # > 0; one number or 3 values
    rotate_deg = [0, 0, 0]    # about x, then y, then z (degrees)
    translate = [0, 0, 0]     # mm, applied last
    require_watertight = false

    [material]                # exactly one of: name | sigma_a + sigma_s_prime | rd + ld
    name = "marble"           # a measured material (jaxsss.list_materials(); case-insensitive)
    sigma_a = [0.0021, 0.0041, 0.0071]   # absorption, 1/mm, >= 0; one number or 3 values (R, G, B)
    sigma_s_prime = [2.19, 2.62, 3.00]   # reduced scattering, 1/mm, >= 0
    rd = [0.8, 0.6, 0.5]      # total diffuse reflectance in (0, 1) (jaxsss.from_rd_ld)
    ld = [5.0, 3.0, 2.0]      # diffuse mean free path, mm, > 0
    eta = 1.3                 # n_inside / n_outside, > 0; default: the table's value for name, else 1.3
    g = 0.0                   # optional Henyey-Greenstein anisotropy in (-1, 1)
    texture = "face.png"      # optional 8-bit (or 16-bit grey) sRGB image; decoded to a linear multiplier
    specular_roughness = 0.3  # optional GGX alpha in (0, 1]; absent = no specular highlight

    [[light]]                 # at least one (or an [environment]); light[i] in messages counts from 0 in file order
    type = "point"            # point (position) | directional (direction) | spot (position, direction, cone_deg)
                              # | sphere (position, radius, radiance) | rectangle (position, direction, size,
                              # radiance): area lights (jaxsss.render.lights)
    position = [x, y, z]      # mm
    direction = [x, y, z]     # the direction the light travels (spot: the cone axis); normalised; not zero
    intensity = 1.0e4         # >= 0, one number or 3 values: W/sr (point, spot) or W/mm^2 (directional,
                              # irradiance on a surface facing the light)
    cone_deg = 30.0           # spot: half-angle where the intensity reaches zero, in (0, 180]
    falloff_deg = 5.0         # spot: width of the linear falloff inside cone_deg, in [0, cone_deg] (default 0)
    radiance = 2.0            # sphere, rectangle: emitted radiance W/(mm^2 sr), >= 0, one number or 3 values
    radius = 5.0              # sphere: mm, > 0 (position is its centre)
    size = [20.0, 10.0]       # rectangle: [width, height] in mm, > 0; position is its centre, direction the normal
                              # of its emitting (front) side
    up = [0, 0, 1]            # rectangle: the direction of its height edge (orthogonalised against direction; width
                              # runs along up x direction, as Mitsuba's look_at); default z, or y if direction is
                              # within 25 degrees of z
    samples = 16              # sphere, rectangle: shadow rays per surface point in pass 1, >= 1

    [camera]
    position = [...]          # mm (required)
    look_at = [...]           # mm (required; not equal to position)
    up = [0, 0, 1]            # not parallel to the view direction
    fov_deg = 40              # vertical field of view, in (0, 180)
    resolution = [512, 512]   # [width, height] in pixels, positive integers
    spp = 1                   # samples per pixel, >= 1
    edge_spp = 9              # samples per pixel at creases, and at terminators and shadow edges where the surface
                              # turns, when above spp, >= 1 (1: none; jaxsss.render.shading.edge_pixels); also the
                              # most a dark pixel's grid gets (jaxsss.render.shading.dark_pixel_grid)

    [[occluder]]              # optional opaque objects (e.g. a floor): cast shadows, rendered grey Lambertian
    builtin = "slab"          # the same mesh keys as [mesh]
    albedo = 0.5              # in [0, 1], one number or 3 values (default 0.5)

    [[blocker]]               # optional absorbing meshes inside the translucent object (bones in a hand): they end
    builtin = "box"           # photons and cast volumetric shadows in --method photon; the other methods ignore
                              # them (the plan says so). The same mesh keys as [mesh].

    [render]                  # keys of RenderSettings (defaults there)
    method = "hierarchical"   # hierarchical | direct
    eps = 0.05                # solid-angle threshold (steradians), > 0; absent: the plan's (0.1 for the white
                              # kernels, 0.05 otherwise: jaxsss.render.plan.EPS_WHITE, EPS_DEFAULT)
    density = 1.0             # multiplier on the sample density A / (pi l_u^2) (x2 for the white kernels), > 0
    max_samples = 200000      # >= 1
    photons = 200000          # photons traced by --method photon, >= 1
    tolerance = 1e-3          # relative tolerance for leaving terms out, in [0, 1)
    single_scattering = "auto"   # auto | on | off (true / false mean on / off)
    indirect = "auto"         # auto | on | off: one bounce off the occluders and off the object itself
    shadows = "auto"
    exit_current = "auto"     # auto | on | off: the exit's current, the light's flow over the surface (auto: the
                              # plan's, by the object's size in transport lengths; jaxsss.render.plan)
    seed = 0                  # >= 0

    [output]
    exposure = 1.0            # > 0, linear scale before sRGB encoding
    background = [0, 0, 0]    # linear radiance of pixels that miss everything, >= 0

    environment = "sky.hdr"   # optional top-level key: shorthand for [environment] file = "sky.hdr"

    [environment]             # optional: light from infinitely far away (jaxsss.render.environment has the
                              # lat-long orientation, Mitsuba's envmap)
    file = "sky.hdr"          # lat-long radiance map W/(mm^2 sr): .hdr, .exr or .npy (H, W, 3); or instead:
    radiance = [1, 1, 1]      # a constant environment, W/(mm^2 sr), >= 0
    scale = 1.0               # multiplier, >= 0, one number or 3 values
    rotate_deg = [90, 0, 0]   # the map's to_world rotation about x, then y, then z (default [0, 0, 0]: the map's
                              # top row is +y; [90, 0, 0] puts it at +z)
    samples = 64              # directions per surface point in pass 1 (importance-sampled, shadow rays), >= 1

    [layers]                  # optional: subsurface texture layers for `--method layered` (schema in
                              # jaxsss.layered.config, which registers the section; Scene.layers, a LayerSpec)

Sections beyond these are registered by the packages that use them (:func:`register_section`; the layered package
registers ``[layers]``), so this module imports nothing above the scene floor. Their parsers validate with the same
:class:`SceneKeys` as the sections here; their values are in ``Scene.sections`` (``Scene.layers`` for ``[layers]``).

The dataclasses are frozen with ``eq=False`` (they hold arrays and meshes, so comparison is by identity); their
arrays are made read-only.
"""

from __future__ import annotations

import dataclasses
import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from jaxsss.validate import bound_text
from jaxsss.data.materials import material as _measured_material
from jaxsss.medium import Medium
from jaxsss.render.meshes import (
    BUILTIN_MESHES,
    MeshParamError,
    builtin_mesh,
    load_mesh_file,
    transform_matrix,
)
from jaxsss.reparam import from_rd_ld

__all__ = [
    "Blocker",
    "Camera",
    "EDGE_SPP",
    "Light",
    "Material",
    "Occluder",
    "Output",
    "RenderSettings",
    "Scene",
    "SceneError",
    "SceneKeys",
    "SECTIONS",
    "SECTION_MODULES",
    "load_scene",
    "parse_scene",
    "register_section",
    "scene_with",
]

DEFAULT_ETA = 1.3
LIGHT_KINDS = ("point", "directional", "spot", "sphere", "rectangle")
AREA_LIGHT_SAMPLES = 16
ENVIRONMENT_SAMPLES = 64
EDGE_SPP = 9
"""The camera's default ``edge_spp``: rays per pixel where the image has an edge the pixel centre misrepresents
(:func:`jaxsss.render.shading.edge_pixels`; docs/path_tracer.md, "Pixels are areas"), and the most rays of a dark
pixel's grid (:func:`jaxsss.render.shading.dark_pixel_grid`: 3 x 3)."""
SWITCH_VALUES = ("auto", "on", "off")


class SceneError(ValueError):
    """A bad scene file or dict: ``str(err)`` is ``"{path}: [{key}] {message}"``.

    Attributes:
        path: the scene file (or ``"<scene>"`` for a dict).
        key: the dotted key, e.g. ``"material.sigma_a"`` or ``"light[1].direction"``; ``None`` for file-level
            errors (unreadable file, TOML syntax).
        message: the message without the path and key.
    """

    def __init__(self, path: str, key: str | None, message: str):
        self.path, self.key, self.message = str(path), key, message
        super().__init__(f"{self.path}: {message}" if key is None else f"{self.path}: [{key}] {message}")


def _frozen(a) -> np.ndarray:
    arr = np.array(a, dtype=np.float64)
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True, eq=False)
class Light:
    """One light. ``kind`` is ``"point"``, ``"directional"``, ``"spot"``, ``"sphere"``, ``"rectangle"`` or
    ``"environment"`` (the scene's ``[environment]``, appended after the ``[[light]]`` tables).

    Attributes:
        intensity: ``(3,)`` RGB; radiant intensity W/sr (point, spot), irradiance W/mm^2 on a surface facing the
            light (directional), emitted radiance W/(mm^2 sr) (sphere, rectangle), or the environment's ``scale``.
        position: ``(3,)`` mm (point, spot; sphere and rectangle: the centre), else ``None``.
        direction: ``(3,)`` unit vector the light travels along (directional; spot: the cone axis; rectangle: the
            normal of its emitting side), else ``None``.
        cone_deg: spot: the half-angle where the intensity reaches zero.
        falloff_deg: spot: full intensity inside ``cone_deg - falloff_deg``, linear in the angle to zero at
            ``cone_deg``.
        radius: sphere: mm.
        size: rectangle: ``(width, height)`` mm.
        up: rectangle: ``(3,)`` unit direction of the height edge, orthogonal to ``direction``.
        samples: sphere, rectangle, environment: samples per surface point in pass 1.
        environment: environment: the :class:`~jaxsss.render.environment.EnvironmentMap`.
        key: the scene key that made it (``"light[0]"``, ``"environment"``), for messages.
    """

    kind: str
    intensity: np.ndarray
    position: np.ndarray | None = None
    direction: np.ndarray | None = None
    cone_deg: float = 180.0
    falloff_deg: float = 0.0
    radius: float = 0.0
    size: tuple[float, float] | None = None
    up: np.ndarray | None = None
    samples: int = 0
    environment: Any = None
    key: str = ""


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera: ``fov_deg`` is vertical; ``resolution`` is ``(width, height)``; ``up`` is a unit vector;
    ``spp`` rays per pixel, ``edge_spp`` at the pixels of :func:`jaxsss.render.shading.edge_pixels` when larger, and
    up to ``edge_spp`` (a square grid) at those of :func:`jaxsss.render.shading.dark_pixel_grid`."""

    position: np.ndarray
    look_at: np.ndarray
    up: np.ndarray = field(default_factory=lambda: _frozen([0.0, 0.0, 1.0]))
    fov_deg: float = 40.0
    resolution: tuple[int, int] = (512, 512)
    spp: int = 1
    edge_spp: int = EDGE_SPP


@dataclass(frozen=True, eq=False)
class Material:
    """The translucent material.

    Attributes:
        medium: :class:`jaxsss.Medium` with ``(3,)`` RGB ``sigma_a``, ``sigma_s_prime`` (1/mm), scalar ``eta``,
            ``g`` or ``None``.
        name: the measured material's name when given by name, else ``None``.
        texture: ``(H, W, 3)`` linear multiplier (sRGB-decoded image) on the irradiance samples, or ``None``.
        texture_path: the resolved texture file, or ``None``.
        specular_roughness: GGX alpha in ``(0, 1]``, or ``None`` for no specular highlight.
    """

    medium: Medium
    name: str | None = None
    texture: np.ndarray | None = None
    texture_path: str | None = None
    specular_roughness: float | None = None


@dataclass(frozen=True, eq=False)
class Occluder:
    """An opaque object that casts shadows and renders as grey Lambertian with ``albedo`` ``(3,)``."""

    mesh: trimesh.Trimesh
    albedo: np.ndarray
    description: str


@dataclass(frozen=True, eq=False)
class Blocker:
    """An absorbing mesh inside the translucent object: it ends the photons that reach it and shadows the diffusion
    sources behind it (``--method photon``; Donner and Jensen 2007, the hand and its bones)."""

    mesh: trimesh.Trimesh
    description: str


@dataclass(frozen=True, eq=False)
class RenderSettings:
    """Renderer knobs (see the module schema for ranges)."""

    method: str = "hierarchical"
    eps: float | None = None  # None: the plan's (jaxsss.render.plan.EPS_WHITE, EPS_DEFAULT)
    density: float = 1.0
    max_samples: int = 200_000
    photons: int = 200_000
    tolerance: float = 1e-3
    single_scattering: str = "auto"
    indirect: str = "auto"
    shadows: str = "auto"
    exit_current: str = "auto"
    seed: int = 0


@dataclass(frozen=True, eq=False)
class Output:
    """Image output: linear ``exposure`` before sRGB encoding; ``background`` ``(3,)`` linear radiance."""

    exposure: float = 1.0
    background: np.ndarray = field(default_factory=lambda: _frozen(np.zeros(3)))


@dataclass(frozen=True, eq=False)
class Scene:
    """A validated scene; ``mesh`` is already placed in world coordinates (mm)."""

    path: str | None
    mesh: trimesh.Trimesh
    mesh_description: str
    material: Material
    lights: tuple[Light, ...]
    camera: Camera
    occluders: tuple[Occluder, ...] = ()
    blockers: tuple[Blocker, ...] = ()
    render: RenderSettings = field(default_factory=RenderSettings)
    output: Output = field(default_factory=Output)
    environment: str | None = None  # the environment map's file (None: none, or a constant [environment].radiance)
    sections: dict = field(default_factory=dict)  # registered sections' values (register_section), by name

    @property
    def layers(self) -> Any:
        """The ``[layers]`` table as a :class:`jaxsss.layered.LayerSpec` (the layered method), else None."""
        return self.sections.get("layers")


# --- value checks -----------------------------------------------------------------------------------------------
class SceneKeys:
    """The one TOML validator of scene files: each check returns the value or raises :class:`SceneError` naming the
    file (``path``), the dotted key and, for values, the value and the allowed range. ``base_dir`` is where relative
    file paths resolve. Registered sections (:func:`register_section`) get one to validate their table with."""

    def __init__(self, path: str, base_dir):
        self.path = path
        self.base_dir = Path(base_dir) if base_dir is not None else Path.cwd()

    def error(self, key: str | None, message: str) -> SceneError:
        return SceneError(self.path, key, message)

    def file(self, value, key: str) -> Path:
        name = self.string(value, key)
        p = Path(name).expanduser()
        p = p if p.is_absolute() else self.base_dir / p
        if not p.is_file():
            raise self.error(key, f"file {name!r} does not exist (looked for {p})")
        return p

    def string(self, value, key: str) -> str:
        if not isinstance(value, str):
            raise self.error(key, f"{value!r} is not a string")
        return value

    def boolean(self, value, key: str) -> bool:
        if not isinstance(value, bool):
            raise self.error(key, f"{value!r} is not true or false")
        return value

    def number(self, value, key: str, lo=None, hi=None, *, lo_open=False, hi_open=False, where: str = "") -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(key, f"{value!r}{where} is not a number")
        v = float(value)
        bad = math.isnan(v) or math.isinf(v)
        if lo is not None:
            bad = bad or (v <= lo if lo_open else v < lo)
        if hi is not None:
            bad = bad or (v >= hi if hi_open else v > hi)
        if bad:
            raise self.error(key, f"{v:g}{where} is outside the allowed range {bound_text(lo, hi, lo_open, hi_open)}")
        return v

    def integer(self, value, key: str, lo: int, hi: int | None = None) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, f"{value!r} is not an integer")
        if value < lo or (hi is not None and value > hi):
            raise self.error(key, f"{value} is outside the allowed range [{lo}, {'inf)' if hi is None else f'{hi}]'}")
        return value

    def vector(self, value, key: str, *, scalar_ok: bool = False, **bounds) -> np.ndarray:
        """Three numbers (or one, broadcast, when ``scalar_ok``) -> read-only ``(3,)`` float64."""
        if scalar_ok and not isinstance(value, (list, tuple)):
            return _frozen([self.number(value, key, **bounds)] * 3)
        if not isinstance(value, (list, tuple)) or len(value) != 3:
            shape = "3 values or one number" if scalar_ok else "3 values [x, y, z]"
            raise self.error(key, f"{value!r} is not {shape}")
        return _frozen([self.number(v, key, where=f" (element {i})", **bounds) for i, v in enumerate(value)])

    def choice(self, value, key: str, choices) -> str:
        if not isinstance(value, str) or value not in choices:
            raise self.error(key, f"{value!r} is not one of: {', '.join(choices)}")
        return value

    def table(self, data: dict, name: str, key: str) -> dict:
        value = data[name]
        if not isinstance(value, dict):
            raise self.error(key, f"must be a table [{key}], not {type(value).__name__}")
        return value

    def values(self, value, key: str, n: int | None = None, **bounds) -> np.ndarray:
        """One number or a non-empty list of numbers (of length ``n`` when given) -> ``(k,)`` float64."""
        if not isinstance(value, (list, tuple)):
            return np.array([self.number(value, key, **bounds)])
        if len(value) == 0 or (n is not None and len(value) != n):
            raise self.error(key, f"{value!r} is not one number or {n if n else 'a list of'} values")
        return np.array([self.number(x, key, where=f" (element {i})", **bounds) for i, x in enumerate(value)])

    def only(self, table, key: str, allowed):
        """``table`` must be a table whose keys are all in ``allowed``."""
        if not isinstance(table, dict):
            raise self.error(key, f"must be a table [{key}], not {type(table).__name__}")
        self.only_keys(table, key, allowed)

    def only_keys(self, table: dict, key: str, allowed, what: str | None = None):
        for k in table:
            if k not in allowed:
                where = f"{key}.{k}" if key else k
                raise self.error(where, f"unknown key; allowed{what or ''}: {', '.join(sorted(allowed))}")


# --- sections ---------------------------------------------------------------------------------------------------
_BUILTIN_PARAMS = sorted({p for _, params in BUILTIN_MESHES.values() for p in params})
_MESH_KEYS = {"builtin", "file", "scale", "rotate_deg", "translate", "require_watertight", *_BUILTIN_PARAMS}


def _fmt(v) -> str:
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return f"{v:g}" if isinstance(v, float) else str(v)


def _builtin_param(ctx: SceneKeys, value, key: str, default):
    """Type-check a builtin parameter by its default's type; the range is checked by ``builtin_mesh``."""
    if isinstance(default, list):
        return list(ctx.vector(value, key, lo=0.0, lo_open=True))
    if isinstance(default, int):
        return ctx.integer(value, key, 0)
    return ctx.number(value, key)


def _parse_mesh(ctx: SceneKeys, table: dict, key: str, extra_keys=()) -> tuple[trimesh.Trimesh, str]:
    ctx.only_keys(table, key, _MESH_KEYS | set(extra_keys))
    has_builtin, has_file = "builtin" in table, "file" in table
    if has_builtin == has_file:
        raise ctx.error(key, "give exactly one of builtin (" + ", ".join(BUILTIN_MESHES) + ") or file")
    params = {k: v for k, v in table.items() if k in _BUILTIN_PARAMS}
    if has_builtin:
        name = ctx.choice(table["builtin"], f"{key}.builtin", tuple(BUILTIN_MESHES))
        defaults = BUILTIN_MESHES[name][1]
        for k in params:
            if k not in defaults:
                raise ctx.error(f"{key}.{k}", f"not a parameter of builtin {name!r}; valid: {', '.join(defaults)}")
        values = {k: _builtin_param(ctx, v, f"{key}.{k}", defaults[k]) for k, v in params.items()}
        try:
            mesh = builtin_mesh(name, **values)
        except MeshParamError as err:
            raise ctx.error(f"{key}.{err.param}" if err.param else f"{key}.builtin", str(err)) from None
        description = f"builtin {name}" + (
            f" ({', '.join(f'{k}={_fmt(v)}' for k, v in params.items())})" if params else ""
        )
    else:
        if params:
            first = next(iter(params))
            raise ctx.error(f"{key}.{first}", "builtin mesh parameters need builtin = ...; a mesh file takes none")
        file_key = f"{key}.file"
        path = ctx.file(table["file"], file_key)
        try:
            mesh = load_mesh_file(path)
        except (ValueError, OSError) as err:
            raise ctx.error(file_key, str(err)) from None
        description = f"file {table['file']}"

    scale = table.get("scale", 1.0)
    if isinstance(scale, (list, tuple)):
        scale_v = ctx.vector(scale, f"{key}.scale", lo=0.0, lo_open=True)
    else:
        scale_v = ctx.number(scale, f"{key}.scale", 0.0, lo_open=True)
    rotate = ctx.vector(table.get("rotate_deg", [0.0, 0.0, 0.0]), f"{key}.rotate_deg")
    translate = ctx.vector(table.get("translate", [0.0, 0.0, 0.0]), f"{key}.translate")
    placed = [k for k in ("scale", "rotate_deg", "translate") if k in table]
    if placed:
        mesh.apply_transform(transform_matrix(scale_v, rotate, translate))
        description += ", " + ", ".join(f"{k}={_fmt(table[k])}" for k in placed)

    if ctx.boolean(table.get("require_watertight", False), f"{key}.require_watertight") and not mesh.is_watertight:
        raise ctx.error(
            f"{key}.require_watertight",
            f"the mesh ({description}) is not watertight; repair it or set require_watertight = false",
        )
    return mesh, description


_MATERIAL_KEYS = (
    "name", "sigma_a", "sigma_s_prime", "rd", "ld", "eta", "g", "texture", "specular_roughness",
)  # fmt: skip
_MATERIAL_GROUPS = {"name": ("name",), "sigma_a + sigma_s_prime": ("sigma_a", "sigma_s_prime"), "rd + ld": ("rd", "ld")}


def _load_texture(ctx: SceneKeys, path: Path, key: str) -> np.ndarray:
    """An image file -> ``(H, W, 3)`` linear float64 (sRGB decoded with colour.cctf_decoding)."""
    import colour
    from PIL import Image

    try:
        with Image.open(path) as image:
            image.load()
            if image.mode in ("I;16", "I;16B", "I;16L", "I"):
                grey = np.asarray(image, dtype=np.float64) / 65535.0
                encoded = np.repeat(grey[..., None], 3, axis=-1)
            else:
                encoded = np.asarray(image.convert("RGB"), dtype=np.float64) / 255.0
    except Exception as err:  # PIL raises several types for unreadable images
        raise ctx.error(key, f"could not read image {str(path)!r}: {err}") from err
    if encoded.ndim != 3 or encoded.shape[0] == 0 or encoded.shape[1] == 0:
        raise ctx.error(key, f"image {str(path)!r} is empty")
    return _frozen(colour.cctf_decoding(np.clip(encoded, 0.0, 1.0), function="sRGB"))


def _parse_material(ctx: SceneKeys, table: dict) -> Material:
    key = "material"
    ctx.only_keys(table, key, _MATERIAL_KEYS)
    given = [g for g, keys in _MATERIAL_GROUPS.items() if any(k in table for k in keys)]
    if len(given) != 1:
        found = "none" if not given else ", ".join(given)
        raise ctx.error(key, f"give exactly one of: {' | '.join(_MATERIAL_GROUPS)}; found: {found}")
    for k in _MATERIAL_GROUPS[given[0]]:
        if k not in table:
            raise ctx.error(f"{key}.{k}", f"missing: {given[0]} go together")

    eta = None if "eta" not in table else ctx.number(table["eta"], f"{key}.eta", 0.0, lo_open=True)
    g = None if "g" not in table else ctx.number(table["g"], f"{key}.g", -1.0, 1.0, lo_open=True, hi_open=True)
    name = None
    if given[0] == "name":
        try:
            record = _measured_material(ctx.string(table["name"], f"{key}.name"))
        except ValueError as err:
            if isinstance(err, SceneError):
                raise
            raise ctx.error(f"{key}.name", str(err)) from None
        name = record.name
        eta = eta if eta is not None else (record.eta if record.eta is not None else DEFAULT_ETA)
        sigma_a, sigma_s_prime = record.sigma_a, record.sigma_s_prime
    elif given[0] == "rd + ld":
        eta = DEFAULT_ETA if eta is None else eta
        rd = ctx.vector(table["rd"], f"{key}.rd", scalar_ok=True, lo=0.0, hi=1.0, lo_open=True, hi_open=True)
        ld = ctx.vector(table["ld"], f"{key}.ld", scalar_ok=True, lo=0.0, lo_open=True)
        try:
            rep = from_rd_ld(rd, ld, eta, g)
        except ValueError as err:
            raise ctx.error(key, str(err)) from None
        converged = np.asarray(rep.converged)
        if not np.all(converged):
            channels = ", ".join("RGB"[i] for i in np.flatnonzero(~converged))
            raise ctx.error(f"{key}.rd", f"the Rd inversion did not converge for channel(s) {channels}")
        sigma_a, sigma_s_prime = np.asarray(rep.medium.sigma_a), np.asarray(rep.medium.sigma_s_prime)
    else:
        eta = DEFAULT_ETA if eta is None else eta
        sigma_a = ctx.vector(table["sigma_a"], f"{key}.sigma_a", scalar_ok=True, lo=0.0)
        sigma_s_prime = ctx.vector(table["sigma_s_prime"], f"{key}.sigma_s_prime", scalar_ok=True, lo=0.0)
    try:
        medium = Medium(np.asarray(sigma_a, dtype=np.float64), np.asarray(sigma_s_prime, dtype=np.float64), eta, g)
    except ValueError as err:
        raise ctx.error(key, str(err)) from None

    texture = texture_path = None
    if "texture" in table:
        path = ctx.file(table["texture"], f"{key}.texture")
        texture, texture_path = _load_texture(ctx, path, f"{key}.texture"), str(path)
    roughness = None
    if "specular_roughness" in table:
        roughness = ctx.number(table["specular_roughness"], f"{key}.specular_roughness", 0.0, 1.0, lo_open=True)
    return Material(medium, name, texture, texture_path, roughness)


_LIGHT_KEYS = {
    "point": ("type", "intensity", "position"),
    "directional": ("type", "intensity", "direction"),
    "spot": ("type", "intensity", "position", "direction", "cone_deg", "falloff_deg"),
    "sphere": ("type", "radiance", "position", "radius", "samples"),
    "rectangle": ("type", "radiance", "position", "direction", "size", "up", "samples"),
}
_OPTIONAL_LIGHT_KEYS = ("falloff_deg", "samples", "up")
_ALL_LIGHT_KEYS = {k for keys in _LIGHT_KEYS.values() for k in keys}


def _parse_light(ctx: SceneKeys, table, key: str) -> Light:
    if not isinstance(table, dict):
        raise ctx.error(key, "must be a table ([[light]])")
    ctx.only_keys(table, key, _ALL_LIGHT_KEYS)
    if "type" not in table:
        raise ctx.error(f"{key}.type", f"missing; one of: {', '.join(LIGHT_KINDS)}")
    kind = ctx.choice(table["type"], f"{key}.type", LIGHT_KINDS)
    allowed = _LIGHT_KEYS[kind]
    for k in table:
        if k not in allowed:
            raise ctx.error(f"{key}.{k}", f"not used by a {kind} light; allowed for {kind}: {', '.join(allowed)}")
    required = [k for k in allowed if k not in _OPTIONAL_LIGHT_KEYS]
    for k in required:
        if k not in table:
            raise ctx.error(f"{key}.{k}", f"missing; a {kind} light needs {', '.join(required[1:])}")
    power = "radiance" if "radiance" in allowed else "intensity"
    intensity = ctx.vector(table[power], f"{key}.{power}", scalar_ok=True, lo=0.0)
    position = ctx.vector(table["position"], f"{key}.position") if "position" in table else None
    direction = None
    if "direction" in table:
        d = ctx.vector(table["direction"], f"{key}.direction")
        norm = float(np.linalg.norm(d))
        if norm == 0.0:
            raise ctx.error(f"{key}.direction", f"{_fmt(list(d))} is the zero vector and has no direction")
        direction = _frozen(d / norm)
    cone_deg, falloff_deg = 180.0, 0.0
    if kind == "spot":
        cone_deg = ctx.number(table["cone_deg"], f"{key}.cone_deg", 0.0, 180.0, lo_open=True)
        falloff_deg = ctx.number(table.get("falloff_deg", 0.0), f"{key}.falloff_deg", 0.0, cone_deg)
    if kind not in ("sphere", "rectangle"):
        return Light(kind, intensity, position, direction, cone_deg, falloff_deg, key=key)
    samples = ctx.integer(table.get("samples", AREA_LIGHT_SAMPLES), f"{key}.samples", 1)
    if kind == "sphere":
        radius = ctx.number(table["radius"], f"{key}.radius", 0.0, lo_open=True)
        return Light(kind, intensity, position, radius=radius, samples=samples, key=key)
    size = table["size"]
    if not isinstance(size, (list, tuple)) or len(size) != 2:
        raise ctx.error(f"{key}.size", f"{size!r} is not [width, height]")
    size = tuple(ctx.number(v, f"{key}.size", 0.0, lo_open=True, where=f" (element {i})") for i, v in enumerate(size))
    if "up" in table:
        up = ctx.vector(table["up"], f"{key}.up")
    else:  # z, or y when the normal is within about 25 degrees of z
        up = np.array([0.0, 0.0, 1.0]) if abs(direction[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    # Orthogonalise against the normal (Mitsuba's look_at): up' = up - (up . n) n.
    up = up - float(up @ direction) * direction
    norm = float(np.linalg.norm(up))
    if norm < 1e-6:
        raise ctx.error(f"{key}.up", f"{_fmt(list(table['up']))} is parallel to direction; it must fix the "
                        "rectangle's height edge")
    return Light(kind, intensity, position, direction, radius=0.0, size=size, up=_frozen(up / norm),
                 samples=samples, key=key)


_ENVIRONMENT_KEYS = ("file", "radiance", "scale", "rotate_deg", "samples")


def _parse_environment(ctx: SceneKeys, value) -> tuple[Light, str | None]:
    """``[environment]`` (or ``environment = "file"``) -> ``(Light(kind="environment"), file or None)``."""
    from jaxsss.render.environment import EnvironmentMap, load_environment_image

    key = "environment"
    table = {"file": value} if isinstance(value, str) else value
    if not isinstance(table, dict):
        raise ctx.error(key, f"{value!r} is neither a file name nor a table [environment]")
    ctx.only_keys(table, key, _ENVIRONMENT_KEYS)
    if ("file" in table) == ("radiance" in table):
        raise ctx.error(key, "give exactly one of: file (a lat-long map) | radiance (a constant environment)")
    path = None
    if "file" in table:
        path = ctx.file(table["file"], f"{key}.file")
        try:
            image = load_environment_image(path)
        except ValueError as err:
            raise ctx.error(f"{key}.file", str(err)) from None
    else:
        image = np.asarray(ctx.vector(table["radiance"], f"{key}.radiance", scalar_ok=True, lo=0.0)).reshape(1, 1, 3)
    scale = ctx.vector(table.get("scale", 1.0), f"{key}.scale", scalar_ok=True, lo=0.0)
    rotate = ctx.vector(table.get("rotate_deg", [0.0, 0.0, 0.0]), f"{key}.rotate_deg")
    samples = ctx.integer(table.get("samples", ENVIRONMENT_SAMPLES), f"{key}.samples", 1)
    env = EnvironmentMap.build(image, transform_matrix(rotate_deg=rotate)[:3, :3], None if path is None else str(path))
    return Light("environment", scale, samples=samples, environment=env, key=key), None if path is None else str(path)


_CAMERA_KEYS = ("position", "look_at", "up", "fov_deg", "resolution", "spp", "edge_spp")


def _parse_camera(ctx: SceneKeys, table: dict) -> Camera:
    key = "camera"
    ctx.only_keys(table, key, _CAMERA_KEYS)
    for k in ("position", "look_at"):
        if k not in table:
            raise ctx.error(f"{key}.{k}", "missing")
    position = ctx.vector(table["position"], f"{key}.position")
    look_at = ctx.vector(table["look_at"], f"{key}.look_at")
    up = ctx.vector(table.get("up", [0.0, 0.0, 1.0]), f"{key}.up")
    view = look_at - position
    if np.linalg.norm(view) == 0.0:
        raise ctx.error(f"{key}.look_at", f"{_fmt(list(look_at))} equals camera.position; the view has no direction")
    if np.linalg.norm(up) == 0.0:
        raise ctx.error(f"{key}.up", "the zero vector has no direction")
    sin_angle = np.linalg.norm(np.cross(view, up)) / (np.linalg.norm(view) * np.linalg.norm(up))
    if sin_angle < 1e-6:
        raise ctx.error(f"{key}.up", f"{_fmt(list(up))} is parallel to the view direction look_at - position")
    fov = ctx.number(table.get("fov_deg", 40.0), f"{key}.fov_deg", 0.0, 180.0, lo_open=True, hi_open=True)
    res = table.get("resolution", [512, 512])
    if not isinstance(res, (list, tuple)) or len(res) != 2:
        raise ctx.error(f"{key}.resolution", f"{res!r} is not [width, height]")
    resolution = tuple(ctx.integer(v, f"{key}.resolution", 1) for v in res)
    spp = ctx.integer(table.get("spp", 1), f"{key}.spp", 1)
    edge_spp = ctx.integer(table.get("edge_spp", EDGE_SPP), f"{key}.edge_spp", 1)
    return Camera(position, look_at, _frozen(up / np.linalg.norm(up)), fov, resolution, spp, edge_spp)


def _parse_occluder(ctx: SceneKeys, table, key: str) -> Occluder:
    if not isinstance(table, dict):
        raise ctx.error(key, "must be a table ([[occluder]])")
    mesh, description = _parse_mesh(ctx, table, key, extra_keys=("albedo",))
    albedo = ctx.vector(table.get("albedo", 0.5), f"{key}.albedo", scalar_ok=True, lo=0.0, hi=1.0)
    return Occluder(mesh, albedo, description)


def _parse_blocker(ctx: SceneKeys, table, key: str) -> Blocker:
    if not isinstance(table, dict):
        raise ctx.error(key, "must be a table ([[blocker]])")
    return Blocker(*_parse_mesh(ctx, table, key))


def _parse_render(ctx: SceneKeys, table: dict) -> RenderSettings:
    key = "render"
    names = [f.name for f in dataclasses.fields(RenderSettings)]
    ctx.only_keys(table, key, names)
    values = {}
    for k, v in table.items():
        kk = f"{key}.{k}"
        if k == "method":
            from jaxsss.render.methods import method_names  # the registry (the floor's own module)

            values[k] = ctx.choice(v, kk, method_names())
        elif k in ("eps", "density"):
            values[k] = ctx.number(v, kk, 0.0, lo_open=True)
        elif k == "tolerance":
            values[k] = ctx.number(v, kk, 0.0, 1.0, hi_open=True)
        elif k in ("max_samples", "photons"):
            values[k] = ctx.integer(v, kk, 1)
        elif k == "seed":
            values[k] = ctx.integer(v, kk, 0)
        else:  # the auto | on | off switches
            values[k] = ("on" if v else "off") if isinstance(v, bool) else ctx.choice(v, kk, SWITCH_VALUES)
    return RenderSettings(**values)


def _parse_output(ctx: SceneKeys, table: dict) -> Output:
    key = "output"
    ctx.only_keys(table, key, ("exposure", "background"))
    exposure = ctx.number(table.get("exposure", 1.0), f"{key}.exposure", 0.0, lo_open=True)
    background = ctx.vector(table.get("background", 0.0), f"{key}.background", scalar_ok=True, lo=0.0)
    return Output(exposure, background)


def _array_of_tables(ctx: SceneKeys, data: dict, name: str) -> list:
    value = data.get(name, [])
    if isinstance(value, dict):  # a single [name] table
        return [value]
    if not isinstance(value, list):
        raise ctx.error(name, f"must be an array of tables [[{name}]]")
    return value


_TOP_KEYS = ("mesh", "material", "light", "camera", "occluder", "blocker", "render", "output", "environment")

SECTIONS: dict = {}
"""Registered top-level sections: name -> ``parse(table, keys: SceneKeys)`` (see :func:`register_section`)."""
SECTION_MODULES = ("jaxsss.layered",)
"""Packages that register sections, imported by name when a scene is parsed (they build on this module, so it
cannot import them)."""


def register_section(name: str, parse) -> None:
    """Accept a top-level ``[name]`` table in scene files: ``parse(table, keys)`` validates it with the
    :class:`SceneKeys` ``keys`` (raising :class:`SceneError` through it) and returns the value stored in
    ``Scene.sections[name]``."""
    if name in _TOP_KEYS:
        raise ValueError(f"register_section(name={name!r}): a core section of the scene file")
    SECTIONS[name] = parse


def _registered_sections() -> dict:
    import importlib

    for module in SECTION_MODULES:
        importlib.import_module(module)
    return SECTIONS


def parse_scene(data: dict, *, path: str = "<scene>", base_dir=None) -> Scene:
    """Validate a scene dict (the schema in the module docstring) and build the :class:`Scene`.

    Args:
        data: the parsed TOML (``tomllib.load``).
        path: the name used in error messages (and stored as ``Scene.path`` unless it is ``"<scene>"``).
        base_dir: directory that relative file paths resolve against (default: the working directory).

    Raises:
        SceneError: any invalid or missing entry, naming ``path`` and the dotted key.
    """
    ctx = SceneKeys(str(path), base_dir)
    if not isinstance(data, dict):
        raise ctx.error(None, "a scene must be a TOML table")
    sections = _registered_sections()
    ctx.only_keys(data, "", (*_TOP_KEYS, *sections))
    for section in ("mesh", "material", "camera"):
        if section not in data:
            raise ctx.error(section, f"missing section [{section}]")
    mesh, description = _parse_mesh(ctx, ctx.table(data, "mesh", "mesh"), "mesh")
    material = _parse_material(ctx, ctx.table(data, "material", "material"))
    lights = _array_of_tables(ctx, data, "light")
    if not lights and "environment" not in data:
        raise ctx.error("light", "missing: give at least one [[light]] or an [environment]")
    lights = tuple(_parse_light(ctx, t, f"light[{i}]") for i, t in enumerate(lights))
    environment = None
    if "environment" in data:
        env_light, environment = _parse_environment(ctx, data["environment"])
        lights = (*lights, env_light)
    camera = _parse_camera(ctx, ctx.table(data, "camera", "camera"))
    occluders = tuple(
        _parse_occluder(ctx, t, f"occluder[{i}]") for i, t in enumerate(_array_of_tables(ctx, data, "occluder"))
    )
    blockers = tuple(
        _parse_blocker(ctx, t, f"blocker[{i}]") for i, t in enumerate(_array_of_tables(ctx, data, "blocker"))
    )
    render = _parse_render(ctx, ctx.table(data, "render", "render")) if "render" in data else RenderSettings()
    output = _parse_output(ctx, ctx.table(data, "output", "output")) if "output" in data else Output()
    extra = {name: parse(data[name], ctx) for name, parse in sections.items() if name in data}
    return Scene(
        path=None if path == "<scene>" else str(path),
        mesh=mesh,
        mesh_description=description,
        material=material,
        lights=lights,
        camera=camera,
        occluders=occluders,
        blockers=blockers,
        render=render,
        output=output,
        environment=environment,
        sections=extra,
    )


def load_scene(path) -> Scene:
    """Read and validate a TOML scene file; relative paths in it resolve against its directory.

    Raises:
        SceneError: the file is missing or unreadable, has a TOML syntax error (with line and column), or any
            entry is invalid.
    """
    name = os.fspath(path)
    try:
        with open(name, "rb") as f:
            data = tomllib.load(f)
    except FileNotFoundError:
        raise SceneError(name, None, "scene file does not exist") from None
    except tomllib.TOMLDecodeError as err:
        raise SceneError(name, None, f"TOML syntax error: {err}") from None
    except (OSError, UnicodeDecodeError) as err:
        raise SceneError(name, None, f"could not read the scene file: {err}") from None
    return parse_scene(data, path=name, base_dir=Path(name).resolve().parent)


def scene_with(scene: Scene, **changes) -> Scene:
    """A copy of ``scene`` with top-level fields replaced (``dataclasses.replace``), e.g. ``render=RenderSettings(...)``.

    The replaced values are not re-validated.
    """
    valid = [f.name for f in dataclasses.fields(Scene)]
    unknown = sorted(set(changes) - set(valid))
    if unknown:
        raise ValueError(f"scene_with: unknown field(s) {', '.join(unknown)}; valid: {', '.join(valid)}")
    return dataclasses.replace(scene, **changes)
