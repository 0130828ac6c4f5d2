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

import dataclasses
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
from jaxsss.layered.plan import layered_plan
from jaxsss.layered.planes import fit_planes, neighbourhood_radius, planes_at
from jaxsss.layered.tangents import barycentric, frames_at, surface_frames, wrap_for
from jaxsss.validate import check_integer
from jaxsss.medium import Medium
from jaxsss.render.plan import make_plan
from jaxsss.render.renderer import prepare as prepare_diffusion
from jaxsss.render.camera import camera_rays
from jaxsss.render.methods import Preparation, register_method, render
from jaxsss.render.lights import refuse_lights
from jaxsss.render.rays import OBJECT_TRANSLUCENT, SceneGeometry, scene_geometry
from jaxsss.render.scene import scene_with
from jaxsss.render.shading import constant_image, face_the_eye

__all__ = ["COS_MIN", "LayeredMethodState", "LayeredPrepared", "LayeredRenderResult", "layered_medium",
           "outer_layer_medium", "prepare_layered", "prepare_layered_method", "render_layered", "shading_geometry",
           "with_outer_layer"]

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
    n = face_the_eye(n, w_out)
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
    refuse_lights(scene, "layered", why="its ray marcher attenuates the light of point, spot and directional lights "
                  "along one direction per light (jaxsss.layered.lighting)")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    geometry = scene_geometry(scene.mesh, [o.mesh for o in scene.occluders])
    rays = camera_rays(scene.camera, resolution, seed=scene.render.seed)
    keep = np.ones(len(rays.pixel), bool) if pixel_mask is None else np.asarray(pixel_mask).reshape(-1)[rays.pixel]
    hits = geometry.first_hit(rays.origins, rays.directions)
    n_channels = spec.stack.n_channels
    constant = constant_image(scene, geometry, rays, np.arange(len(rays.pixel)), hits, n_channels)
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


class LayeredMethodState(eqx.Module):
    """The registered ``layered`` method's state: the march and, where the plan keeps it, the outer layer's
    hierarchical diffusion. ``image(medium)`` takes the outer layer from ``medium`` (:func:`with_outer_layer`; the
    scene's ``[material]`` describes that layer) and keeps the layers below from the spec."""

    march: LayeredPrepared
    stack: LayerStack
    diffusion: Any  # jaxsss.render.Prepared of the outer layer's dipole sum, or None

    shape = property(lambda self: self.march.shape, doc="``(H, W)`` of the image.")
    spp = property(lambda self: self.march.spp, doc="Camera rays per pixel.")

    def single_scattering(self, medium: Medium):
        """``(H, W, C)`` the layered single-scattering term alone."""
        return self.march.single_scattering(with_outer_layer(self.stack, medium))

    def image(self, medium: Medium):
        """``(H, W, C)`` linear image: single scattering, plus the outer layer's diffusion (which carries the
        background and occluders) or else the constant image."""
        ss = self.single_scattering(medium)
        if self.diffusion is None:
            return ss + self.march.constant.reshape(ss.shape)
        return ss + self.diffusion.image(medium)


def with_outer_layer(stack: LayerStack, medium: Medium) -> LayerStack:
    """``stack`` with its first layer from ``medium`` (the inverse of :func:`outer_layer_medium`): ``sigma_s =
    sigma_s' / (1 - g)`` with the layer's own ``g`` and ``sigma_t = sigma_a + sigma_s``; a JAX function of the
    medium."""
    g = jnp.broadcast_to(stack.g[0], (stack.n_channels,))
    sigma_s = medium.sigma_s_prime / (1.0 - g)
    return stack.replace(sigma_s=stack.sigma_s.at[0].set(sigma_s),
                         sigma_t=stack.sigma_t.at[0].set(medium.sigma_a + sigma_s))


def _layer_spec(scene, spec, samples=None):
    if samples is not None:
        check_integer(samples, "samples", 1, owner="render(method='layered')")
    spec = scene.layers if spec is None else spec
    if spec is None:
        where = scene.path or "the scene"
        raise ValueError(f"{where}: the layered method needs a [layers] table (see examples/layered_veins.toml)")
    return spec


def prepare_layered_method(scene, *, resolution=None, pixel_mask=None, fit=False, progress=False, samples=None,
                           eps=None, spec: LayerSpec | None = None) -> Preparation:
    """The registered ``layered`` method's preparation: :func:`prepare_layered` and, where
    :func:`~jaxsss.layered.plan.layered_plan` keeps it, the outer layer's hierarchical diffusion
    (:func:`jaxsss.render.prepare` with ``eps``).

    Raises:
        ValueError: the scene has no ``[layers]`` table and no ``spec`` is given; ``samples < 1``.
    """
    spec = _layer_spec(scene, spec, samples)
    diffusion, items = layered_plan(scene, spec, samples=samples)
    march, _, info = prepare_layered(scene, spec, resolution=resolution, samples=samples, pixel_mask=pixel_mask)
    info.pop("geometry")
    timings = info.pop("timings")
    diffuse = None
    if diffusion:
        # The march casts the camera's spp rays everywhere: the diffusion term shades the same pixels (no edge rays,
        # jaxsss.render.shading.edge_pixels), so that both terms cover each pixel alike.
        centres = scene_with(scene, camera=dataclasses.replace(scene.camera, edge_spp=1))
        diffuse, plan, dinfo = prepare_diffusion(centres, method="hierarchical", eps=eps, resolution=resolution,
                                                 progress=progress, pixel_mask=pixel_mask, cutoff=not fit,
                                                 share_channels=not fit)
        for key, value in dinfo["timings"].items():
            timings[key] = timings.get(key, 0.0) + value
        info["diffusion"] = {k: dinfo[k] for k in ("n_samples", "n_interactions", "interactions_per_point_mean")}
    else:
        plan = make_plan(scene, eps=eps)
    stack = spec.stack
    plan = plan._replace(method="layered", items=items)
    diagnostics = {"samples": march.n_samples, "layers": list(stack.names), "phase": list(stack.phase),
                   "texture": spec.texture.source, "texture_shape": list(spec.texture.shape),
                   "n_lights": march.lights.n_lights, **info}
    return Preparation("layered", LayeredMethodState(march, stack, diffuse), plan, diagnostics, timings)


def layered_medium(scene) -> Medium:
    """The layered method's default material: the scene's ``[material]`` (the outer layer)."""
    return scene.material.medium


def _explain_registered(scene, *, resolution=None, samples=None, eps=None, spec=None):
    spec = _layer_spec(scene, spec, samples)
    _, items = layered_plan(scene, spec, samples=samples)
    return make_plan(scene, eps=eps)._replace(method="layered", items=items)


register_method("layered", prepare_layered_method,
                "single scattering ray-marched through the scene's [layers] subsurface textures (Francois et al.), "
                "plus the outer layer's diffusion where the plan says so", options=("samples", "eps", "spec"),
                params=layered_medium, explain=_explain_registered)


class LayeredRenderResult(NamedTuple):
    """``image`` ``(H, W, C)`` linear (what ``jaxsss render --method layered`` writes); ``single_scattering`` the
    layered term alone; ``report`` the render report; ``prepared`` the registry's
    :class:`~jaxsss.render.methods.Preparation` (state: :class:`LayeredMethodState`)."""

    image: np.ndarray
    single_scattering: np.ndarray
    report: dict[str, Any]
    prepared: Preparation


def render_layered(scene, spec: LayerSpec | None = None, *, samples: int | None = None, resolution=None,
                   stack: LayerStack | None = None) -> LayeredRenderResult:
    """Render ``scene`` with the layered method (``jaxsss render --method layered``, through the registry's driver
    :func:`jaxsss.render.render`): single scattering plus the outer layer's diffusion where the plan keeps it.

    Args:
        scene: the loaded scene (mesh with UVs, lights, camera, occluders, output).
        spec: the ``[layers]`` description (default ``scene.layers``).
        samples: ``N`` samples per view ray (default ``spec.samples``).
        resolution: ``(W, H)`` overriding the camera's.
        stack: coefficients overriding ``spec.stack`` (same number of layers); its outer layer then also gives
            the diffusion term's material (:func:`outer_layer_medium` with the scene's eta and the layer's g).
    """
    spec = scene.layers if spec is None else spec
    medium = None
    if stack is not None:
        spec = dataclasses.replace(spec, stack=stack)
        eta = scene.material.medium.eta
        medium = outer_layer_medium(stack, eta)
    result = render(scene, "layered", resolution=resolution, medium=medium, samples=samples, spec=spec)
    medium = layered_medium(scene) if medium is None else medium
    ss = np.asarray(result.prepared.state.single_scattering(medium))
    return LayeredRenderResult(result.image, ss, result.report, result.prepared)


def outer_layer_medium(stack: LayerStack, eta: float = 1.3) -> Medium:
    """The first layer as a :class:`jaxsss.Medium` (``sigma_a = sigma_t - sigma_s``, ``sigma_s' = (1 - g) sigma_s``,
    the layer's ``g``), for a diffusion term of the outer layer from the hierarchical renderer."""
    g = jnp.broadcast_to(stack.g[0], (stack.n_channels,))
    return Medium(stack.sigma_a[0], stack.sigma_s[0] * (1.0 - g), eta, g)
