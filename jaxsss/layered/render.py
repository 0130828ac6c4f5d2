"""Rendering a scene with the layered single-scattering method: geometry once in NumPy, the march in JAX.

:func:`prepare_layered` does everything that depends only on geometry: camera rays and their hits (Embree), the
texture coordinates and tangent frames at the hits, the per-vertex fitted planes (Eq. 8 radius from the first
layer's smallest ``sigma_t``), the march length from Eq. 15, shadow rays, and the image of whatever is not the
translucent object (background, grey Lambertian occluders). :meth:`LayeredPrepared.image` then evaluates the whole
frame in one jitted call, differentiable in the :class:`~jaxsss.layered.layers.LayerStack`.
:func:`render_layered` is the whole job with a report (the CLI's ``--method layered``).

Eq. 15 (``M_max = P - Depth_max / (NS_P . w_out) w_out``) makes the march reach the depth ``Depth_max`` measured
along the fitted plane's normal. At grazing angles ``NS_P . w_out`` goes to 0 and the march would be arbitrarily
long; we floor the cosine at :data:`COS_MIN` (the report counts the pixels where that happens) and, with
``clip_to_exit``, end the march where the view ray leaves the mesh (one extra ray per pixel; the paper's GPU version
could not, and marched through thin parts).
"""

from __future__ import annotations

import time
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxsss.layered.config import LayerSpec
from jaxsss.layered.layers import LayerStack, min_extinction
from jaxsss.layered.lighting import LightArrays, light_arrays
from jaxsss.layered.march import PixelGeometry, march_pixels
from jaxsss.layered.planes import fit_planes, neighbourhood_radius, planes_at
from jaxsss.layered.tangents import barycentric, frames_at, surface_frames, wrap_for
from jaxsss.medium import Medium
from jaxsss.render.camera import camera_rays
from jaxsss.render.lights import light_field
from jaxsss.render.rays import OBJECT_TRANSLUCENT, SceneGeometry

__all__ = ["COS_MIN", "LayeredPrepared", "LayeredRenderResult", "outer_layer_medium", "prepare_layered",
           "render_layered", "shading_geometry"]

COS_MIN = 0.05
"""Floor on ``NS_P . w_out`` in Eq. 15: the march is at most ``Depth_max / COS_MIN`` long."""


class LayeredPrepared(eqx.Module):
    """The geometry of one frame; ``image(stack)`` renders it (one jitted call; no retracing for a new stack).

    ``geom`` arrays are chunked ``(K, chunk, ...)``; ``pixel`` ``(Q,)`` maps shaded rays to flat pixels;
    ``constant`` ``(H * W, C)`` is the rest of the image (background, occluders).
    """

    boundaries: jnp.ndarray
    geom: PixelGeometry
    lights: LightArrays
    pixel: jnp.ndarray
    constant: jnp.ndarray
    n_samples: int = eqx.field(static=True)
    shape: tuple = eqx.field(static=True)
    spp: int = eqx.field(static=True)
    n_points: int = eqx.field(static=True)

    def radiance(self, stack: LayerStack, n_samples: int | None = None):
        """``(Q, C)`` single-scattered radiance at the shaded points, W/(mm^2 sr)."""
        return _radiance(self, stack, n_samples or self.n_samples)

    def single_scattering(self, stack: LayerStack, n_samples: int | None = None):
        """``(H, W, C)`` the layered single-scattering term alone (no background or occluders)."""
        return _to_image(self, _radiance(self, stack, n_samples or self.n_samples), with_constant=False)

    def image(self, stack: LayerStack, n_samples: int | None = None):
        """``(H, W, C)`` linear image: layered single scattering plus background and occluders."""
        return _to_image(self, _radiance(self, stack, n_samples or self.n_samples), with_constant=True)


@eqx.filter_jit
def _radiance(prepared: LayeredPrepared, stack: LayerStack, n_samples: int):
    if stack.n_layers != prepared.boundaries.shape[-1]:
        raise ValueError(f"LayeredPrepared.image(stack=...): {stack.n_layers} layers for a texture with "
                         f"{prepared.boundaries.shape[-1]}")
    out = march_pixels(stack, prepared.boundaries, prepared.geom, prepared.lights, n_samples)
    return out[: prepared.n_points]


@eqx.filter_jit
def _to_image(prepared: LayeredPrepared, radiance, with_constant: bool):
    h, w = prepared.shape
    img = jax.ops.segment_sum(radiance / prepared.spp, prepared.pixel, num_segments=h * w)
    if with_constant:
        img = img + prepared.constant
    return img.reshape(h, w, -1)


class ShadingGeometry(NamedTuple):
    """NumPy per-point geometry before chunking (see :class:`~jaxsss.layered.march.PixelGeometry`), plus
    ``face`` ``(Q,)`` and ``t_exit`` ``(Q,)`` (where the view ray leaves the mesh; inf if it never does)."""

    P: np.ndarray
    w_out: np.ndarray
    normal: np.ndarray
    plane_normal: np.ndarray
    plane_point: np.ndarray
    T: np.ndarray
    B: np.ndarray
    uv: np.ndarray
    length: np.ndarray
    visible: np.ndarray
    face: np.ndarray
    t_exit: np.ndarray


def shading_geometry(scene, spec: LayerSpec, geometry: SceneGeometry, points, faces, w_out, *, frames=None,
                     planes=None) -> tuple[ShadingGeometry, dict]:
    """Geometry of shaded points on the translucent mesh: frames, fitted planes, march length, visibility.

    Args:
        scene: the :class:`~jaxsss.render.scene.Scene` (mesh and lights).
        spec: the :class:`~jaxsss.layered.config.LayerSpec`.
        geometry: the scene's ray-casting geometry.
        points, faces, w_out: ``(Q, 3)`` hit points, ``(Q,)`` faces of the translucent mesh, ``(Q, 3)`` unit
            directions towards the eye.
        frames, planes: precomputed :func:`~jaxsss.layered.tangents.surface_frames` and
            :func:`~jaxsss.layered.planes.fit_planes` (else computed here).

    Returns:
        ``(ShadingGeometry, info)``; ``info`` has the plane radius, fitted fraction and clamp counts.
    """
    mesh = scene.mesh
    wrap = spec.wrap if spec.wrap is not None else wrap_for(scene.mesh_description)
    frames = frames if frames is not None else surface_frames(mesh, wrap, spec.tile)
    radius = neighbourhood_radius(min_extinction(spec.stack, 0), spec.plane_eps)
    planes = planes if planes is not None else fit_planes(mesh, frames.normal, radius)
    uv, n, T, B = frames_at(frames, mesh, faces, points)
    # A smooth normal can face away from the eye at silhouettes: reflect it about the view direction.
    back = np.einsum("ij,ij->i", n, w_out) < 0
    n[back] = n[back] - 2 * np.einsum("ij,ij->i", n[back], w_out[back])[:, None] * w_out[back]
    T = T - np.einsum("ij,ij->i", T, n)[:, None] * n
    B = B - np.einsum("ij,ij->i", B, n)[:, None] * n
    bary = barycentric(mesh, faces, points)
    ns, ps = planes_at(planes, bary, faces)
    # Eq. 15: |P M_max| = Depth_max / (NS_P . w_out), the cosine floored at COS_MIN.
    cos_s = np.einsum("ij,ij->i", ns, w_out)
    clamped = cos_s < COS_MIN
    length = spec.effective_depth_max / np.maximum(cos_s, COS_MIN)
    inward = -w_out
    hits = geometry.first_hit(points - geometry.offset * n, inward)
    t_exit = np.where(hits.hit, hits.t, np.inf)
    if spec.clip_to_exit:
        length = np.minimum(length, np.maximum(t_exit, 0.0))
    visible = np.ones((len(points), len(scene.lights)))
    if spec.shadows and len(points):
        for k, light in enumerate(scene.lights):
            if light.kind == "directional":
                to_light, dist = np.broadcast_to(-light.direction, points.shape), None
            else:
                delta = np.asarray(light.position) - points
                dist = np.linalg.norm(delta, axis=1)
                to_light = delta / np.maximum(dist, 1e-300)[:, None]
            facing = np.einsum("ij,ij->i", n, to_light) > 0
            vis = np.zeros(len(points))
            idx = np.flatnonzero(facing)
            if idx.size:
                vis[idx] = geometry.visible(points[idx], n[idx], to_light[idx], None if dist is None else dist[idx])
            visible[:, k] = vis
    info = {"plane_radius_mm": radius, "planes_fitted_fraction": float(np.mean(planes.fitted)),
            "eq15_cos_clamped_points": int(clamped.sum()), "wrap": list(wrap), "tile": list(spec.tile),
            "depth_max_mm": spec.effective_depth_max}
    return ShadingGeometry(points, w_out, n, ns, ps, T, B, uv, length, visible, faces, t_exit), info


def _chunked(sg: ShadingGeometry, chunk: int) -> PixelGeometry:
    q = len(sg.P)
    # Balanced chunks: as few as ``chunk`` allows, equal sizes (padding less than one per chunk).
    n_chunks = max(1, -(-q // max(chunk, 1)))
    chunk = max(1, -(-q // n_chunks))
    pad = (-q) % chunk if q else chunk

    def prep(a):
        a = np.asarray(a, dtype=np.float64)
        if pad:
            filler = np.repeat(a[:1], pad, axis=0) if q else np.zeros((pad,) + a.shape[1:])
            a = np.concatenate([a, filler])
        return jnp.asarray(a.reshape((-1, chunk) + a.shape[1:]))

    length = sg.length.copy()
    return PixelGeometry(prep(sg.P), prep(sg.w_out), prep(sg.normal), prep(sg.plane_normal), prep(sg.plane_point),
                         prep(sg.T), prep(sg.B), prep(sg.uv), prep(length), prep(sg.visible))


def _constant_image(scene, geometry, rays, hits, n_channels):
    """Background for missed rays and grey Lambertian occluders (``albedo / pi * E``), ``(H * W, C)``."""
    h, w = rays.shape
    constant = np.zeros((h * w, n_channels))
    background = np.broadcast_to(np.asarray(scene.output.background, dtype=np.float64), (n_channels,))
    np.add.at(constant, rays.pixel[~hits.hit], background / rays.spp)
    on_occ = np.flatnonzero(hits.obj >= 1)
    if on_occ.size:
        y = hits.position[on_occ]
        ny = geometry.shading_normals(hits.face[on_occ], y)
        ny = np.where(np.einsum("ij,ij->i", ny, rays.directions[on_occ])[:, None] > 0, -ny, ny)
        direct = light_field(scene.lights, y, ny, geometry).irradiance.sum(axis=1)
        albedo = np.stack([scene.occluders[k - 1].albedo for k in hits.obj[on_occ]])
        np.add.at(constant, rays.pixel[on_occ], albedo / np.pi * direct / rays.spp)
    return constant


def prepare_layered(scene, spec: LayerSpec, *, resolution=None, samples: int | None = None,
                    pixel_mask=None) -> tuple[LayeredPrepared, ShadingGeometry, dict]:
    """Geometry-only work for a frame.

    Args:
        scene: a :class:`~jaxsss.render.scene.Scene` (its mesh needs UVs).
        spec: the layers (:func:`~jaxsss.layered.config.parse_layers`).
        resolution: ``(W, H)`` overriding the camera's.
        samples: ``N`` (default ``spec.samples``).
        pixel_mask: optional ``(H, W)`` bool; only these pixels are shaded.

    Returns:
        ``(prepared, shading_geometry, info)``.
    """
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    geometry = SceneGeometry(scene.mesh, [o.mesh for o in scene.occluders])
    rays = camera_rays(scene.camera, resolution, seed=scene.render.seed)
    keep = np.ones(len(rays.pixel), bool) if pixel_mask is None else np.asarray(pixel_mask).reshape(-1)[rays.pixel]
    hits = geometry.first_hit(rays.origins, rays.directions)
    n_channels = spec.stack.n_channels
    constant = _constant_image(scene, geometry, rays, hits, n_channels)
    timings["camera_rays"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    on_obj = np.flatnonzero((hits.obj == OBJECT_TRANSLUCENT) & keep)
    points = hits.position[on_obj]
    faces = hits.face[on_obj]
    sg, info = shading_geometry(scene, spec, geometry, points, faces, -rays.directions[on_obj])
    timings["surface_geometry"] = time.perf_counter() - t0
    lights = light_arrays(scene.lights, n_channels)
    prepared = LayeredPrepared(jnp.asarray(spec.texture.boundaries), _chunked(sg, spec.chunk), lights,
                               jnp.asarray(rays.pixel[on_obj]), jnp.asarray(constant),
                               int(samples or spec.samples), tuple(rays.shape), int(rays.spp), len(on_obj))
    info = {**info, "timings": timings, "n_shaded_points": len(on_obj), "n_rays": len(rays.pixel),
            "n_pixels": int(rays.shape[0] * rays.shape[1]), "geometry": geometry}
    return prepared, sg, info


class LayeredRenderResult(NamedTuple):
    """``image`` ``(H, W, C)`` linear (single scattering + background/occluders); ``single_scattering`` the layered
    term alone (add a diffusion image to it); ``report`` JSON-ready; ``prepared`` for re-rendering."""

    image: np.ndarray
    single_scattering: np.ndarray
    report: dict[str, Any]
    prepared: LayeredPrepared


def render_layered(scene, spec: LayerSpec, *, samples: int | None = None, resolution=None,
                   stack: LayerStack | None = None) -> LayeredRenderResult:
    """Render ``scene`` with the layered single-scattering method (``jaxsss render --method layered``).

    Args:
        scene: the loaded scene (mesh with UVs, lights, camera, occluders, output).
        spec: the ``[layers]`` description (:func:`~jaxsss.layered.config.load_layered_scene`).
        samples: ``N`` samples per view ray (default ``spec.samples``).
        resolution: ``(W, H)`` overriding the camera's.
        stack: coefficients overriding ``spec.stack`` (same number of layers).
    """
    t_all = time.perf_counter()
    prepared, _, info = prepare_layered(scene, spec, resolution=resolution, samples=samples)
    stack = stack if stack is not None else spec.stack
    # Compile apart (ahead of time), then one timed run: the frame is marched once.
    t0 = time.perf_counter()
    march = _radiance.lower(prepared, stack, prepared.n_samples).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    ss = jax.block_until_ready(_to_image(prepared, march(prepared, stack, prepared.n_samples), with_constant=False))
    march_s = time.perf_counter() - t0
    image = np.asarray(ss) + np.asarray(prepared.constant).reshape(ss.shape)
    timings = {**info.pop("timings"), "march_compile": compile_s, "march": march_s}
    info.pop("geometry")
    report = {
        "method": "layered",
        "samples": prepared.n_samples,
        "layers": list(stack.names),
        "phase": list(stack.phase),
        "texture": spec.texture.source,
        "texture_shape": list(spec.texture.shape),
        "n_lights": prepared.lights.n_lights,
        **info,
        "timings": timings,
        "seconds_total": time.perf_counter() - t_all,
        "frames_per_second_after_compile": 1.0 / march_s if march_s > 0 else None,
        "image_max": float(image.max()) if image.size else 0.0,
        "image_mean": float(image.mean()) if image.size else 0.0,
    }
    return LayeredRenderResult(image, np.asarray(ss), report, prepared)


def outer_layer_medium(stack: LayerStack, eta: float = 1.3) -> Medium:
    """The first layer as a :class:`jaxsss.Medium` (``sigma_a = sigma_t - sigma_s``, ``sigma_s' = (1 - g) sigma_s``),
    for a diffusion term of the outer layer from the hierarchical renderer."""
    g = jnp.broadcast_to(stack.g[0], (stack.n_channels,))
    return Medium(stack.sigma_a[0], stack.sigma_s[0] * (1.0 - g), eta)
