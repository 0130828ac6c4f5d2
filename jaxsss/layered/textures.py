"""Subsurface textures: per-texel depths (mm, along the surface normal) of the bottom of each layer.

Convention (Francois et al., Sec. 2.1 and Fig. 5): channel ``i`` of a texture is the depth below the surface of the
bottom of layer ``i``; layer 0 starts at the surface, layer ``i`` spans ``[b_{i-1}, b_i)``, and below the deepest
boundary nothing scatters. A channel shallower than the one before it means layer ``i`` is absent there: the
boundaries used are the running maximum over the channels (:attr:`SubsurfaceTexture.boundaries`), so every thickness
is ``>= 0``. One RGBA texture holds 4 layers; ``N`` textures (same resolution) hold ``4 N`` layers, channels in file
order.

Texture space: ``(u, v)`` in ``[0, 1)`` repeating (wrap-around); ``v = 0`` is the *bottom* row of the image (the
OpenGL convention, so a PNG opened in an image viewer shows ``v`` growing upwards).

PNG depth scale (:func:`load_texture_png`): the paper's textures are grey images "where the intensity of a pixel is
inversely proportional to the thickness [...] a high intensity corresponds to a low thickness". We read that as the
linear map ``depth = depth_scale_mm * (1 - value)``, with ``value`` the raw pixel value over its maximum (255 or
65535, no sRGB decoding): white is at the surface, black is ``depth_scale_mm`` deep.

Procedural textures (:func:`procedural_texture`): ``constant`` layers, ``veins`` (a layer that thickens along
random branching curves with a round cross-section) and ``blobs`` (a layer that thickens in periodic Gaussian
bumps). All tile seamlessly.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from jaxsss.validate import check_integer
from scipy import ndimage

__all__ = [
    "PROCEDURAL_TEXTURES",
    "SubsurfaceTexture",
    "blob_texture",
    "constant_texture",
    "load_texture_png",
    "procedural_texture",
    "vein_texture",
]


@dataclass(frozen=True, eq=False)
class SubsurfaceTexture:
    """Layer depths on a texel grid.

    Attributes:
        depth: ``(H, W, n)`` depth of the bottom of each layer, mm, ``>= 0`` (row 0 is the top of the image).
        source: a one-line description for reports.
    """

    depth: np.ndarray
    source: str = "array"

    def __post_init__(self):
        d = np.asarray(self.depth, dtype=np.float64)
        if d.ndim != 3 or d.shape[0] < 1 or d.shape[1] < 1 or d.shape[2] < 1:
            raise ValueError(f"SubsurfaceTexture(depth=...): shape {d.shape}; expected (H, W, n_layers) with all >= 1")
        if not np.all(np.isfinite(d)) or np.any(d < 0):
            bad = d[~(np.isfinite(d) & (d >= 0))].flat[0]
            raise ValueError(f"SubsurfaceTexture(depth={bad:g}): outside the allowed range [0, inf) mm")
        d = d.copy()
        d.flags.writeable = False
        object.__setattr__(self, "depth", d)

    @property
    def n_layers(self) -> int:
        return self.depth.shape[2]

    @property
    def shape(self) -> tuple[int, int]:
        return self.depth.shape[:2]

    @property
    def boundaries(self) -> np.ndarray:
        """``(H, W, n)`` running maximum of the depths over the channels (non-decreasing with the layer), mm."""
        return np.maximum.accumulate(self.depth, axis=2)

    @property
    def depth_max(self) -> float:
        """The deepest layer bottom anywhere, mm: below it nothing scatters (the default ``Depth_max`` of Eq. 15)."""
        return float(self.boundaries[..., -1].max())

    def layers(self, n: int) -> SubsurfaceTexture:
        """The first ``n`` channels (e.g. RGB of an RGBA file for three layers)."""
        if not 1 <= n <= self.n_layers:
            raise ValueError(f"SubsurfaceTexture.layers(n={n}): allowed range [1, {self.n_layers}]")
        return SubsurfaceTexture(self.depth[..., :n], f"{self.source} (first {n} channels)")


def load_texture_png(paths, depth_scale_mm, n_layers: int | None = None) -> SubsurfaceTexture:
    """Load one or more PNG (any Pillow-readable) images as a subsurface texture.

    Args:
        paths: a path or a list of paths; their channels are stacked in order (grey = 1 channel, grey + alpha = 2,
            RGB = 3, RGBA = 4). All must have the same resolution.
        depth_scale_mm: depth of a black pixel, mm, ``> 0``: one number or one per channel used
            (``depth = scale * (1 - value)``, module docstring).
        n_layers: use the first ``n_layers`` channels (default all).

    Raises:
        FileNotFoundError: a missing file. ValueError: unreadable file, mismatched resolutions, bad scale or count
            (the message names the file or argument).
    """
    from PIL import Image

    paths = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    if not paths:
        raise ValueError("load_texture_png(paths=[]): give at least one image")
    channels = []
    for p in paths:
        p = os.fspath(p)
        if not os.path.isfile(p):
            raise FileNotFoundError(f"texture file {p!r} does not exist")
        try:
            with Image.open(p) as im:
                mode = im.mode
                if mode in ("I;16", "I;16B", "I;16L", "I"):
                    arr, top = np.asarray(im, dtype=np.float64), 65535.0
                else:
                    if mode not in ("L", "LA", "RGB", "RGBA"):
                        im = im.convert("RGBA" if "A" in mode else "RGB")
                    arr, top = np.asarray(im, dtype=np.float64), 255.0
        except OSError as err:
            raise ValueError(f"texture file {p!r} could not be read: {err}") from err
        arr = arr[..., None] if arr.ndim == 2 else arr
        if channels and arr.shape[:2] != channels[0].shape[:2]:
            raise ValueError(f"texture file {p!r} is {arr.shape[1]}x{arr.shape[0]}; the first texture is "
                             f"{channels[0].shape[1]}x{channels[0].shape[0]} (all must match)")
        channels.append(np.clip(arr / top, 0.0, 1.0))
    value = np.concatenate(channels, axis=2)
    n = value.shape[2] if n_layers is None else int(n_layers)
    if not 1 <= n <= value.shape[2]:
        raise ValueError(f"load_texture_png(n_layers={n_layers}): the files hold {value.shape[2]} channels; "
                         f"allowed range [1, {value.shape[2]}]")
    scale = np.broadcast_to(np.asarray(depth_scale_mm, dtype=np.float64).reshape(-1), (n,)) \
        if np.size(depth_scale_mm) in (1, n) else None
    if scale is None:
        raise ValueError(f"load_texture_png(depth_scale_mm={depth_scale_mm!r}): give one number or {n} (one per layer)")
    if not np.all(np.isfinite(scale) & (scale > 0)):
        raise ValueError(f"load_texture_png(depth_scale_mm={depth_scale_mm!r}): outside the allowed range (0, inf) mm")
    # Brighter = thinner: depth = scale * (1 - value).
    depth = scale * (1.0 - value[..., :n])
    names = ", ".join(os.path.basename(os.fspath(p)) for p in paths)
    return SubsurfaceTexture(depth, f"png {names} (depth scale {', '.join(f'{s:g}' for s in scale)} mm)")


# --- procedural ---------------------------------------------------------------------------------------------------
def _thicknesses(thickness, name: str) -> np.ndarray:
    t = np.asarray(thickness, dtype=np.float64).reshape(-1)
    if t.size < 1 or not np.all(np.isfinite(t) & (t >= 0)):
        raise ValueError(f"{name}(thickness={thickness!r}): each layer thickness must be in [0, inf) mm")
    return t


def _size(size, name: str) -> int:
    return check_integer(size, "size", 1, 8192, owner=name)  # texels per side


def _stack(thick: np.ndarray) -> np.ndarray:
    """``(H, W, n)`` per-texel layer thicknesses -> depths of the layer bottoms."""
    return np.cumsum(thick, axis=2)


def constant_texture(thickness, size: int = 4) -> SubsurfaceTexture:
    """Layers of constant thickness (mm, one per layer), on a ``size x size`` grid."""
    t = _thicknesses(thickness, "constant_texture")
    size = _size(size, "constant_texture")
    thick = np.broadcast_to(t, (size, size, t.size))
    return SubsurfaceTexture(_stack(thick), f"constant layers {', '.join(f'{x:g}' for x in t)} mm")


def _periodic_distance(mask: np.ndarray) -> np.ndarray:
    """Distance (texels) to the nearest True texel on a torus (the texture repeats)."""
    h, w = mask.shape
    tiled = np.tile(~mask, (3, 3))
    return ndimage.distance_transform_edt(tiled)[h:2 * h, w:2 * w]


def _vein_masks(size: int, n_veins: int, rng: np.random.Generator, branches: int) -> tuple[np.ndarray, np.ndarray]:
    """Rasterised centre lines ``(main, branch)`` of smooth random curves (main veins 0.5-0.9 texture widths long,
    side branches 0.1-0.35) that bend with a slowly drifting turning rate."""
    main = np.zeros((size, size), dtype=bool)
    branch = np.zeros((size, size), dtype=bool)
    step = 0.25 / size

    def walk(mask, start, heading, length):
        n = max(int(length / step), 2)
        rate = np.cumsum(rng.normal(0.0, 1.0, n)) * (0.3 * step) ** 1.5 * 40.0  # turning rate (rad per step)
        angle = heading + np.cumsum(rate)
        pts = start + np.cumsum(np.stack([np.cos(angle), np.sin(angle)], 1) * step, axis=0)
        ij = np.mod(np.floor(pts * size).astype(np.int64), size)
        mask[ij[:, 1], ij[:, 0]] = True
        return pts, angle

    for _ in range(n_veins):
        pts, angle = walk(main, rng.random(2), rng.uniform(0, 2 * np.pi), rng.uniform(0.5, 0.9))
        for _ in range(branches):
            k = rng.integers(len(pts) // 5, len(pts))
            walk(branch, pts[k], angle[k] + rng.choice([-1.0, 1.0]) * rng.uniform(0.4, 1.0), rng.uniform(0.1, 0.35))
    return main, branch


def vein_texture(size: int = 256, thickness=(0.15, 0.1, 0.6), vein_layer: int = 1, vein_depth: float = 0.5,
                 vein_width: float = 0.02, n_veins: int = 5, branches: int = 3, seed: int = 0) -> SubsurfaceTexture:
    """Constant layers where one layer thickens along branching veins (round cross-section).

    Args:
        size: texels per side.
        thickness: base thickness of each layer, mm.
        vein_layer: the layer that thickens (the layers below move down with it).
        vein_depth: extra thickness at a vein's centre line, mm.
        vein_width: vein half-width as a fraction of the texture width.
        n_veins, branches: number of main veins and of side branches per vein.
        seed: random seed (the texture is deterministic for a seed).
    """
    t = _thicknesses(thickness, "vein_texture")
    size = _size(size, "vein_texture")
    if not 0 <= vein_layer < t.size:
        raise ValueError(f"vein_texture(vein_layer={vein_layer}): allowed range [0, {t.size - 1}]")
    if not (np.isfinite(vein_depth) and vein_depth >= 0):
        raise ValueError(f"vein_texture(vein_depth={vein_depth}): allowed range [0, inf) mm")
    if not 0 < vein_width < 0.5:
        raise ValueError(f"vein_texture(vein_width={vein_width}): allowed range (0, 0.5) (fraction of the texture)")
    rng = np.random.default_rng(seed)
    main, branch = _vein_masks(size, int(n_veins), rng, int(branches))
    # Round cross-section: extra thickness vein_depth * sqrt(1 - (d / w)^2) inside the half-width w (branches: 0.6 w
    # wide and 0.7 as deep).
    profile = np.zeros((size, size))
    for mask, w, a in ((main, vein_width, 1.0), (branch, 0.6 * vein_width, 0.7)):
        if mask.any():
            dist = _periodic_distance(mask) / size
            profile = np.maximum(profile, a * np.sqrt(np.clip(1.0 - (dist / w) ** 2, 0.0, 1.0)))
    thick = np.broadcast_to(t, (size, size, t.size)).copy()
    thick[..., vein_layer] += vein_depth * profile
    return SubsurfaceTexture(_stack(thick), f"veins (seed {seed}, {n_veins} veins, layer {vein_layer} +{vein_depth:g} mm)")


def blob_texture(size: int = 256, thickness=(0.15, 0.1, 0.6), blob_layer: int = 1, blob_depth: float = 0.5,
                 n_blobs: int = 12, radius=(0.03, 0.1), seed: int = 0) -> SubsurfaceTexture:
    """Constant layers where one layer thickens in Gaussian bumps (radii in texture widths; periodic)."""
    t = _thicknesses(thickness, "blob_texture")
    size = _size(size, "blob_texture")
    if not 0 <= blob_layer < t.size:
        raise ValueError(f"blob_texture(blob_layer={blob_layer}): allowed range [0, {t.size - 1}]")
    r_lo, r_hi = (float(x) for x in radius)
    if not 0 < r_lo <= r_hi < 0.5:
        raise ValueError(f"blob_texture(radius={radius!r}): need 0 < min <= max < 0.5 (texture widths)")
    rng = np.random.default_rng(seed)
    x = (np.arange(size) + 0.5) / size
    bump = np.zeros((size, size))
    for _ in range(int(n_blobs)):
        c, r = rng.random(2), rng.uniform(r_lo, r_hi)
        dx = np.abs(x - c[0])
        dy = np.abs(x - c[1])
        dx, dy = np.minimum(dx, 1 - dx), np.minimum(dy, 1 - dy)  # periodic distance
        bump += np.exp(-(dy[:, None] ** 2 + dx[None, :] ** 2) / (2 * r * r))
    thick = np.broadcast_to(t, (size, size, t.size)).copy()
    thick[..., blob_layer] += blob_depth * np.clip(bump, 0.0, 1.0)
    return SubsurfaceTexture(_stack(thick), f"blobs (seed {seed}, {n_blobs} blobs, layer {blob_layer} +{blob_depth:g} mm)")


#: name -> generator; keyword arguments as in each function.
PROCEDURAL_TEXTURES = {"constant": constant_texture, "veins": vein_texture, "blobs": blob_texture}


def procedural_texture(kind: str, **params) -> SubsurfaceTexture:
    """Generate a texture by name (``constant``, ``veins``, ``blobs``) with that generator's keyword arguments.

    Raises:
        ValueError: unknown kind or parameter (the message lists the valid ones), or a bad value.
    """
    import inspect

    if kind not in PROCEDURAL_TEXTURES:
        raise ValueError(f"procedural texture {kind!r} is not known; valid: {', '.join(PROCEDURAL_TEXTURES)}")
    fn = PROCEDURAL_TEXTURES[kind]
    valid = list(inspect.signature(fn).parameters)
    unknown = sorted(set(params) - set(valid))
    if unknown:
        raise ValueError(f"procedural texture {kind!r}: unknown parameter(s) {', '.join(unknown)}; valid: "
                         f"{', '.join(valid)}")
    return fn(**params)


def texture_from_layers(thicknesses: Sequence[np.ndarray], source: str = "array") -> SubsurfaceTexture:
    """A texture from per-layer thickness maps ``(H, W)`` each (mm), stacked from the surface down."""
    thick = np.stack([np.asarray(t, dtype=np.float64) for t in thicknesses], axis=2)
    return SubsurfaceTexture(_stack(thick), source)
