"""Per-pixel comparison of a linear radiance image against a reference, and the pixel masks it needs.

Metrics (per channel, on ``(H, W, 3)`` linear radiance images of the same camera):

- ``mare_lit``: mean absolute relative error ``|test - ref| / ref`` over *lit* pixels: fully covered by the
  translucent object and with reference radiance above ``lit_fraction`` (1%) of the channel's peak over covered
  pixels.
- ``mare_band``: the same over the lit pixels of the *terminator band*, where the cosine between the surface normal
  and the direction to a light lies in ``[-0.1, 0.1]`` (any light), computed from the geometry at the pixel centre.
- ``sum_ratio``: summed test radiance over summed reference radiance, over fully covered pixels.
- ``mare_binned``: ``mare_lit`` of ``BIN x BIN`` pixel sums, over the blocks all of whose pixels are lit. A
  reference's per-pixel noise shrinks ``BIN`` times in such a block while an error of the model that is smooth over
  ``BIN`` pixels does not, so it estimates the model's own error when the reference is noisy (a path-traced
  reference of forward scattering at 24,576 spp still has 5% noise per pixel). It is a diagnostic beside
  ``mare_lit``, not a replacement: it also averages away an error that changes sign from pixel to pixel.

"Fully covered" means Mitsuba's coverage (or any other box-filtered mask) is 1 within ``coverage_tol`` and jaxsss's
pixel-centre camera ray hits the object: silhouette pixels are left out because jaxsss at one sample per pixel
point-samples them while a path tracer averages them.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from jaxsss.render.camera import camera_rays
from jaxsss.render.rays import OBJECT_TRANSLUCENT, SceneGeometry, scene_geometry

__all__ = ["BAND_COS", "BIN", "COS_BINS", "LIT_FRACTION", "PixelGeometry", "compare_images", "error_by_cos",
           "error_map", "jaxsss_coverage", "pixel_geometry", "pixel_light_cosines"]

BAND_COS = 0.1
"""The terminator band is ``|cos(normal, to light)| <= BAND_COS``."""
COS_BINS = (-0.3, -0.1, 0.1, 0.3, 0.5, 0.7, 0.85, 1.0)
"""Edges of the bins of cos(normal, to the light) in :func:`error_by_cos`."""
LIT_FRACTION = 0.01
"""Lit pixels have reference radiance above this fraction of the channel's peak."""
BIN = 4
"""Side, in pixels, of the blocks of ``mare_binned``."""


class PixelGeometry(NamedTuple):
    """What the metrics need from the scene at each pixel centre (``(H, W)`` image).

    Attributes:
        hit: ``(H, W)`` bool: the pixel-centre ray's first hit is the translucent object.
        cos: ``(H, W, L)`` cosine between the shading normal and the direction to each light (NaN off the object).
        coverage: ``(H, W)`` fraction of ``sub`` x jittered rays per pixel whose first hit is the object.
    """

    hit: np.ndarray
    cos: np.ndarray
    coverage: np.ndarray


def _geometry(scene) -> SceneGeometry:
    return scene_geometry(scene.mesh, [o.mesh for o in scene.occluders])


def jaxsss_coverage(scene, spp: int = 64, seed: int = 0, geometry=None) -> np.ndarray:
    """``(H, W)`` fraction of each pixel covered by the translucent object, from ``spp`` stratified jittered camera
    rays per pixel (jaxsss's camera, :func:`jaxsss.render.camera.camera_rays`) and their first hits."""
    geometry = geometry or _geometry(scene)
    rays = camera_rays(dataclasses.replace(scene.camera, spp=int(spp)), seed=seed)
    hits = geometry.first_hit(rays.origins, rays.directions)
    h, w = rays.shape
    on = (hits.obj == OBJECT_TRANSLUCENT).astype(np.float64)
    return np.bincount(rays.pixel, weights=on, minlength=h * w).reshape(h, w) / rays.spp


def pixel_light_cosines(scene, geometry=None) -> tuple[np.ndarray, np.ndarray]:
    """``(hit (H, W), cos (H, W, L))``: whether each pixel-centre ray's first hit is the translucent object, and there
    the cosine between the shading normal and the direction to each light (NaN off the object, and for an environment
    light, which has no terminator). Area lights and spots count from their centre."""
    geometry = geometry or _geometry(scene)
    rays = camera_rays(dataclasses.replace(scene.camera, spp=1))
    hits = geometry.first_hit(rays.origins, rays.directions)
    h, w = rays.shape
    on = hits.obj == OBJECT_TRANSLUCENT
    cos = np.full((h * w, len(scene.lights)), np.nan)
    if on.any():
        idx = np.flatnonzero(on)
        p = hits.position[idx]
        n = geometry.shading_normals(hits.face[idx], p)
        for k, light in enumerate(scene.lights):
            if light.kind == "environment":  # light from every direction: no terminator (the column stays NaN)
                continue
            if light.kind == "directional":
                to = np.broadcast_to(-np.asarray(light.direction, dtype=np.float64), p.shape)
            else:
                to = np.asarray(light.position, dtype=np.float64) - p
                to = to / np.linalg.norm(to, axis=1, keepdims=True)
            cos[idx, k] = np.einsum("ij,ij->i", n, to)
    return on.reshape(h, w), cos.reshape(h, w, -1)


def pixel_geometry(scene, coverage_spp: int = 64) -> PixelGeometry:
    """Pixel-centre hits, light cosines (:func:`pixel_light_cosines`) and jaxsss's coverage for ``scene``'s camera."""
    geometry = _geometry(scene)
    hit, cos = pixel_light_cosines(scene, geometry)
    return PixelGeometry(hit, cos, jaxsss_coverage(scene, coverage_spp, geometry=geometry))


def _masks(ref: np.ndarray, pixels: PixelGeometry, coverage, coverage_tol: float, lit_fraction: float,
           band_cos: float):
    cov = pixels.coverage if coverage is None else np.asarray(coverage, dtype=np.float64)
    covered = pixels.hit & (cov >= 1.0 - coverage_tol)
    if not covered.any():
        raise ValueError("no pixel is fully covered by the object: nothing to compare")
    peak = np.max(np.where(covered[..., None], ref, -np.inf), axis=(0, 1))  # (C,)
    lit = covered[..., None] & (ref > lit_fraction * peak)
    with np.errstate(invalid="ignore"):
        band_any = np.any(np.abs(pixels.cos) <= band_cos, axis=-1)
    band = lit & band_any[..., None]
    return covered, lit, band


def compare_images(test: np.ndarray, ref: np.ndarray, pixels: PixelGeometry, *, coverage=None,
                   coverage_tol: float = 1e-3, lit_fraction: float = LIT_FRACTION, band_cos: float = BAND_COS) -> dict:
    """Error of ``test`` against ``ref`` (both ``(H, W, C)`` linear radiance), per channel.

    Args:
        test, ref: images of the same camera, W/(mm^2 sr).
        pixels: :func:`pixel_geometry` of the scene.
        coverage: optional ``(H, W)`` box-filtered coverage (e.g. :func:`jaxsss.export.mitsuba.object_coverage`);
            default jaxsss's own (``pixels.coverage``).
        coverage_tol: a pixel is fully covered when its coverage is at least ``1 - coverage_tol``.
        lit_fraction, band_cos: see the module docstring.

    Returns:
        ``{"mare_lit", "mare_band", "sum_ratio", "bias_lit", "mare_binned", "n_lit", "n_band", "n_binned",
        "n_covered"}``; the first five are lists of ``C`` floats (``bias_lit`` is the mean signed relative error
        ``(test - ref) / ref`` over lit pixels; ``mare_band`` is NaN for a channel without band pixels, ``mare_binned``
        for one without a block of ``BIN x BIN`` lit pixels).
    """
    test, ref = np.asarray(test, dtype=np.float64), np.asarray(ref, dtype=np.float64)
    if test.shape != ref.shape or test.ndim != 3:
        raise ValueError(f"test {test.shape} and ref {ref.shape}: allowed: the same (H, W, C)")
    if ref.shape[:2] != pixels.hit.shape:
        raise ValueError(f"images are {ref.shape[:2]} but the pixel geometry is {pixels.hit.shape}; allowed: equal")
    covered, lit, band = _masks(ref, pixels, coverage, coverage_tol, lit_fraction, band_cos)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = (test - ref) / ref
    out = {"mare_lit": [], "mare_band": [], "bias_lit": [], "sum_ratio": [], "mare_binned": [], "n_lit": [],
           "n_band": [], "n_binned": []}
    blocks = _binned(lit.astype(np.float64)) == BIN * BIN  # (H / BIN, W / BIN, C): blocks whose pixels are all lit
    with np.errstate(divide="ignore", invalid="ignore"):
        rel_binned = _binned(np.where(lit, test, 0.0)) / _binned(np.where(lit, ref, 0.0)) - 1.0
    for c in range(ref.shape[-1]):
        r_lit, r_band = rel[..., c][lit[..., c]], rel[..., c][band[..., c]]
        out["mare_lit"].append(float(np.mean(np.abs(r_lit))))
        out["bias_lit"].append(float(np.mean(r_lit)))
        out["mare_band"].append(float(np.mean(np.abs(r_band))) if r_band.size else float("nan"))
        out["sum_ratio"].append(float(test[..., c][covered].sum() / ref[..., c][covered].sum()))
        out["n_lit"].append(int(lit[..., c].sum()))
        out["n_band"].append(int(band[..., c].sum()))
        r_binned = rel_binned[..., c][blocks[..., c]]
        out["mare_binned"].append(float(np.mean(np.abs(r_binned))) if r_binned.size else float("nan"))
        out["n_binned"].append(int(r_binned.size))
    out["n_covered"] = int(covered.sum())
    return out


def _binned(a: np.ndarray) -> np.ndarray:
    """``(H // BIN, W // BIN, C)`` sums of ``BIN x BIN`` blocks of ``a`` ``(H, W, C)`` (a ragged edge is dropped)."""
    h, w = a.shape[0] // BIN * BIN, a.shape[1] // BIN * BIN
    return a[:h, :w].reshape(h // BIN, BIN, w // BIN, BIN, -1).sum(axis=(1, 3))


def error_map(test: np.ndarray, ref: np.ndarray, pixels: PixelGeometry, *, coverage=None,
              coverage_tol: float = 1e-3) -> np.ndarray:
    """``(H, W, C)`` signed relative error ``(test - ref) / ref`` on fully covered pixels, NaN elsewhere."""
    test, ref = np.asarray(test, dtype=np.float64), np.asarray(ref, dtype=np.float64)
    cov = pixels.coverage if coverage is None else np.asarray(coverage, dtype=np.float64)
    covered = pixels.hit & (cov >= 1.0 - coverage_tol)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = (test - ref) / ref
    return np.where(covered[..., None] & (ref > 0), rel, np.nan)


def error_by_cos(test: np.ndarray, ref: np.ndarray, pixels: PixelGeometry, *, light: int = 0, coverage=None,
                 coverage_tol: float = 1e-3, lit_fraction: float = LIT_FRACTION, edges=COS_BINS) -> list[dict]:
    """Where the error is: the mean signed relative error ``(test - ref) / ref`` per channel over lit, fully covered
    pixels, in bins of the cosine between the normal and the direction to light ``light`` (``edges``).

    Returns:
        One dict per bin: ``{"cos": [lo, hi], "n": pixels, "bias": [C floats], "mare": [C floats]}`` (NaN where a
        bin is empty for a channel).
    """
    test, ref = np.asarray(test, dtype=np.float64), np.asarray(ref, dtype=np.float64)
    _, lit, _ = _masks(ref, pixels, coverage, coverage_tol, lit_fraction, BAND_COS)
    cos = pixels.cos[..., light]
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = (test - ref) / ref
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        in_bin = (cos >= lo) & (cos < hi) if hi < edges[-1] else (cos >= lo) & (cos <= hi)
        bias, mare, n = [], [], 0
        for c in range(ref.shape[-1]):
            r = rel[..., c][lit[..., c] & in_bin]
            n = max(n, r.size)
            bias.append(float(np.mean(r)) if r.size else float("nan"))
            mare.append(float(np.mean(np.abs(r))) if r.size else float("nan"))
        out.append({"cos": [float(lo), float(hi)], "n": int(n), "bias": bias, "mare": mare})
    return out
