"""Pinhole camera rays (NumPy).

Image convention: ``(H, W)`` with row 0 at the top; ``fov_deg`` is the vertical field of view. With ``spp > 1``
each pixel gets ``spp`` stratified jittered rays (deterministic for a seed) and the pixel is their mean (a box
filter, as the path tracer's references). :func:`camera_rays` can cast a subset of the pixels at another ``spp`` (the
renderer's extra rays at edges and dark pixels, :func:`jaxsss.render.shading.edge_pixels` and
:func:`~jaxsss.render.shading.dark_pixel_grid`), jittered or at the cells' centres; each ray carries its weight in
its pixel's mean.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxsss.render.strata import unit_square

__all__ = ["CameraRays", "camera_frame", "camera_rays"]


class CameraRays(NamedTuple):
    """``R`` primary rays (``H * W * spp`` for the whole image)."""

    origins: np.ndarray  # (R, 3) mm
    directions: np.ndarray  # (R, 3) unit
    pixel: np.ndarray  # (R,) int64 flat pixel index row * W + col
    shape: tuple  # (H, W)
    spp: int  # rays per pixel of the image's base sampling
    weight: np.ndarray  # (R,) each ray's weight in its pixel's mean (1 / rays of that pixel)

    def where(self, keep: np.ndarray) -> CameraRays:
        """The rays ``keep`` (bool or indices) only."""
        return self._replace(origins=self.origins[keep], directions=self.directions[keep], pixel=self.pixel[keep],
                             weight=self.weight[keep])

    def join(self, other: CameraRays) -> CameraRays:
        """These rays followed by ``other``'s (same image; ``spp`` stays this one's)."""
        return self._replace(**{k: np.concatenate([getattr(self, k), getattr(other, k)])
                                for k in ("origins", "directions", "pixel", "weight")})


def camera_frame(camera):
    """``(forward, right, up)`` orthonormal vectors of the camera."""
    forward = np.asarray(camera.look_at, dtype=np.float64) - np.asarray(camera.position, dtype=np.float64)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(camera.up, dtype=np.float64))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    return forward, right, up


def _jitter(spp: int, rng: np.random.Generator, n_pixels: int, jitter: bool = True) -> np.ndarray:
    """``(n_pixels, spp, 2)`` sub-pixel offsets in ``[0, 1)``: stratified on a grid of exactly ``spp`` cells
    (:func:`jaxsss.render.strata.unit_square`), jittered (or, with ``jitter=False``, at the cells' centres: the
    midpoint rule)."""
    if spp == 1:
        return np.full((n_pixels, 1, 2), 0.5)
    return unit_square(rng if jitter else None, n_pixels, spp)


def camera_rays(camera, resolution=None, seed: int = 0, pixels: np.ndarray | None = None,
                spp: int | None = None, jitter: bool = True) -> CameraRays:
    """Primary rays of a pinhole camera.

    Args:
        camera: a :class:`jaxsss.render.scene.Camera` (position, look_at, up in mm; ``fov_deg``; ``resolution``
            ``(W, H)``; ``spp``).
        resolution: optional ``(W, H)`` overriding the camera's.
        seed: jitter seed (only used when ``spp > 1``).
        pixels: optional flat pixel indices ``(P,)``: cast only these.
        spp: optional rays per pixel overriding the camera's.
        jitter: each ray at a random point of its cell of the pixel's stratified grid (default), or at the cell's
            centre (``False``: the midpoint rule, deterministic; the renderer's dark pixels,
            :func:`jaxsss.render.shading.dark_pixel_grid`).
    """
    width, height = (int(v) for v in (resolution or camera.resolution))
    spp = int(camera.spp if spp is None else spp)
    if spp < 1:
        raise ValueError(f"spp={spp!r} is outside the allowed range [1, inf)")
    forward, right, up = camera_frame(camera)
    half_h = np.tan(np.radians(camera.fov_deg) / 2.0)
    half_w = half_h * width / height
    index = np.arange(width * height) if pixels is None else np.asarray(pixels, dtype=np.int64)
    n_pix = len(index)
    offs = _jitter(spp, np.random.default_rng(seed), n_pix, jitter)
    rows, cols = np.divmod(index, width)
    px = (cols[:, None] + offs[..., 0]) / width  # (n_pix, spp) in [0, 1) left to right
    py = (rows[:, None] + offs[..., 1]) / height  # top to bottom
    sx = (2.0 * px - 1.0) * half_w
    sy = (1.0 - 2.0 * py) * half_h
    d = forward + sx[..., None] * right + sy[..., None] * up
    d = (d / np.linalg.norm(d, axis=-1, keepdims=True)).reshape(-1, 3)
    origins = np.broadcast_to(np.asarray(camera.position, dtype=np.float64), d.shape).copy()
    pixel = np.repeat(index, spp)
    return CameraRays(origins, d, pixel, (height, width), spp, np.full(len(pixel), 1.0 / spp))
