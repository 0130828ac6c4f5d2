"""Environment maps: a lat-long HDR image of the radiance arriving from infinitely far away (NumPy).

Orientation (Mitsuba 3's ``envmap``, checked against Mitsuba 3.9's own ``eval`` in ``tests/render/test_lights.py``).
In the map's *local* frame, ``+y`` is up and the image coordinates ``(u, v)`` in ``[0, 1]^2`` (``u`` along a row,
``v = 0`` at the top row) name the direction the light comes *from*::

    phi = 2 pi u,  theta = pi v
    d_local = (sin(theta) sin(phi), cos(theta), -sin(theta) cos(phi))

so the top row is the ``+y`` pole, ``u = 0`` looks along ``-z``, ``u = 1/4`` along ``+x``, ``u = 1/2`` along ``+z``.
The world direction is ``d = R d_local`` with ``R`` from ``[environment].rotate_deg`` (about x, then y, then z, as a
mesh's ``rotate_deg``; Mitsuba's ``to_world``). jaxsss scenes are usually z-up: ``rotate_deg = [90, 0, 0]`` puts the
map's top at ``+z``.

Lookup (Mitsuba's bilinear filter): column ``j``'s centre is at ``u = (j + 1/2) / W`` and wraps around; row ``i`` sits
at ``v = i / (H - 1)`` (clamped), so the first and last rows are the poles.

Importance sampling (:class:`EnvironmentMap`): the map is cut into ``H x W`` cells of equal ``(u, v)`` extent. A cell
is drawn with probability proportional to its solid angle ``(2 pi / W)(cos theta_i - cos theta_{i+1})`` times the
largest luminance in its 3 x 3 neighbourhood (every texel the bilinear lookup can reach from it, so the PDF is
positive wherever the radiance is), then a direction uniformly in solid angle inside the cell (uniform in ``phi`` and
``cos theta``). A constant map is sampled uniformly over the sphere.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["ENV_FORMATS", "EnvironmentMap", "direction_to_uv", "load_environment_image", "uv_to_direction"]

ENV_FORMATS = (".hdr", ".exr", ".npy")
"""Environment image files: Radiance RGBE (imagecodecs), OpenEXR (OpenEXR), NumPy ``(H, W, 3)`` float arrays."""

_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 / sRGB primaries


def uv_to_direction(uv: np.ndarray) -> np.ndarray:
    """``(..., 3)`` local unit directions for ``(..., 2)`` map coordinates (module docstring)."""
    phi, theta = 2.0 * np.pi * uv[..., 0], np.pi * uv[..., 1]
    s = np.sin(theta)
    return np.stack([s * np.sin(phi), np.cos(theta), -s * np.cos(phi)], axis=-1)


def direction_to_uv(d: np.ndarray) -> np.ndarray:
    """``(..., 2)`` map coordinates in ``[0, 1)`` x ``[0, 1]`` of ``(..., 3)`` local unit directions."""
    u = np.arctan2(d[..., 0], -d[..., 2]) / (2.0 * np.pi)
    v = np.arccos(np.clip(d[..., 1], -1.0, 1.0)) / np.pi
    return np.stack([u % 1.0, v], axis=-1)


def _read_npy(path: Path) -> np.ndarray:
    return np.load(path, allow_pickle=False)


def _read_hdr(path: Path) -> np.ndarray:
    import imagecodecs

    return imagecodecs.rgbe_decode(path.read_bytes())


def _read_exr(path: Path) -> np.ndarray:
    import OpenEXR

    with OpenEXR.File(str(path)) as f:
        channels = f.channels()
        for name in ("RGB", "RGBA"):
            if name in channels:
                return np.array(channels[name].pixels)
        if not {"R", "G", "B"} <= set(channels):
            raise ValueError(f"it has channels {sorted(channels)}; need R, G, B")
        return np.stack([np.array(channels[c].pixels) for c in "RGB"], axis=-1)


_READERS = {".npy": _read_npy, ".hdr": _read_hdr, ".exr": _read_exr}


def load_environment_image(path) -> np.ndarray:
    """``(H, W, 3)`` float64 linear radiance from a ``.hdr``, ``.exr`` or ``.npy`` file.

    Raises:
        ValueError: an unknown extension, an unreadable file, not 3 (or 1, or 4: alpha dropped) channels, or
            negative, NaN or infinite values (naming the file).
    """
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in ENV_FORMATS:
        raise ValueError(f"environment map {str(path)!r} has extension {ext!r}; allowed: {', '.join(ENV_FORMATS)}")
    try:
        image = _READERS[ext](path)
    except Exception as err:  # the readers raise several types for unreadable files
        raise ValueError(f"environment map {str(path)!r} could not be read: {err}") from None
    image = np.asarray(image, dtype=np.float64)
    if image.ndim == 2:
        image = image[..., None]
    if image.ndim != 3 or image.shape[-1] not in (1, 3, 4) or image.shape[0] < 1 or image.shape[1] < 1:
        raise ValueError(f"environment map {str(path)!r} has shape {image.shape}; need (H, W, 3) (or 1 or 4 channels)")
    image = np.broadcast_to(image[..., :3], (*image.shape[:2], 3)) if image.shape[-1] != 4 else image[..., :3]
    if not np.isfinite(image).all() or (image < 0).any():
        raise ValueError(f"environment map {str(path)!r} has negative, NaN or infinite values; allowed: [0, inf)")
    return np.ascontiguousarray(image)


def _dilate(lum: np.ndarray) -> np.ndarray:
    """3 x 3 maximum filter, wrapping in u (columns) and clamping in v (rows)."""
    out = lum.copy()
    for dj in (-1, 1):
        out = np.maximum(out, np.roll(lum, dj, axis=1))
    rows = out.copy()
    rows[1:] = np.maximum(rows[1:], out[:-1])
    rows[:-1] = np.maximum(rows[:-1], out[1:])
    return rows


@dataclass(frozen=True, eq=False)
class EnvironmentMap:
    """A lat-long environment: ``image`` ``(H, W, 3)`` radiance in W/(mm^2 sr), ``rotation`` ``(3, 3)``
    local-to-world, and its sampling tables (built by :meth:`build`). The scene's ``scale`` is the environment
    light's ``intensity`` (:class:`jaxsss.render.scene.Light`), applied by the callers.

    Attributes:
        image: ``(H, W, 3)`` linear radiance as read from the file (or the constant radiance as ``(1, 1, 3)``).
        rotation: ``(3, 3)`` the map's ``to_world`` rotation.
        path: the file it came from, or ``None`` for a constant environment.
        cell_cdf: ``(H * W,)`` cumulative probability of the cells (row-major).
        cell_pdf: ``(H, W)`` probability of each cell.
    """

    image: np.ndarray
    rotation: np.ndarray
    path: str | None
    cell_cdf: np.ndarray
    cell_pdf: np.ndarray

    @classmethod
    def build(cls, image, rotation=None, path: str | None = None) -> EnvironmentMap:
        image = np.asarray(image, dtype=np.float64)
        rotation = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
        h, w = image.shape[:2]
        lum = _dilate(np.maximum(image @ _LUMINANCE, image.max(axis=-1) * 1e-3))
        # Solid angle of a cell: (2 pi / W)(cos theta_i - cos theta_{i+1}).
        edges = np.cos(np.pi * np.arange(h + 1) / h)
        omega = (2.0 * np.pi / w) * (edges[:-1] - edges[1:])
        weight = lum * omega[:, None]
        total = weight.sum()
        if not total > 0:  # a black map: sample uniformly (the radiance is zero anyway)
            weight, total = np.broadcast_to(omega[:, None], (h, w)).copy(), 4.0 * np.pi
        pdf = weight / total
        cdf = np.cumsum(pdf.ravel())
        cdf[-1] = 1.0
        for a in (image, rotation, pdf, cdf):
            a.flags.writeable = False
        return cls(image, rotation, path, cdf, pdf)

    @property
    def shape(self) -> tuple[int, int]:
        return self.image.shape[:2]

    def radiance(self, directions: np.ndarray) -> np.ndarray:
        """``(..., 3)`` radiance arriving from world unit ``directions`` ``(..., 3)`` (bilinear, Mitsuba's texel
        positions; module docstring)."""
        h, w = self.shape
        uv = direction_to_uv(directions @ self.rotation)  # world -> local is R^T, i.e. d @ R
        x = uv[..., 0] * w - 0.5
        y = uv[..., 1] * (h - 1)
        x0, y0 = np.floor(x).astype(np.int64), np.clip(np.floor(y).astype(np.int64), 0, max(h - 2, 0))
        fx, fy = (x - x0)[..., None], np.clip(y - y0, 0.0, 1.0)[..., None]
        y1 = np.minimum(y0 + 1, h - 1)
        img = self.image
        top = img[y0, x0 % w] * (1 - fx) + img[y0, (x0 + 1) % w] * fx
        bottom = img[y1, x0 % w] * (1 - fx) + img[y1, (x0 + 1) % w] * fx
        return top * (1 - fy) + bottom * fy

    def pdf(self, directions: np.ndarray) -> np.ndarray:
        """``(...)`` the sampling density of world unit ``directions``, per steradian."""
        h, w = self.shape
        uv = direction_to_uv(directions @ self.rotation)
        i = np.clip((uv[..., 1] * h).astype(np.int64), 0, h - 1)
        j = np.clip((uv[..., 0] * w).astype(np.int64), 0, w - 1)
        edges = np.cos(np.pi * np.arange(h + 1) / h)
        omega = (2.0 * np.pi / w) * (edges[:-1] - edges[1:])
        return self.cell_pdf[i, j] / omega[i]

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(directions (..., 3), pdf (...))``: directions drawn from ``(..., 3)`` uniform numbers (one picks the
        cell, two place the direction uniformly in solid angle inside it)."""
        h, w = self.shape
        cell = np.minimum(np.searchsorted(self.cell_cdf, u[..., 0], side="right"), h * w - 1)
        i, j = np.divmod(cell, w)
        # Uniform in solid angle inside the cell: phi uniform, cos(theta) uniform between the cell's edges.
        c_top, c_bottom = np.cos(np.pi * i / h), np.cos(np.pi * (i + 1) / h)
        cos_t = c_top + (c_bottom - c_top) * u[..., 2]
        v = np.arccos(np.clip(cos_t, -1.0, 1.0)) / np.pi
        uu = (j + u[..., 1]) / w
        local = uv_to_direction(np.stack([uu, v], axis=-1))
        omega = (2.0 * np.pi / w) * (c_top - c_bottom)
        return local @ self.rotation.T, self.cell_pdf[i, j] / omega
