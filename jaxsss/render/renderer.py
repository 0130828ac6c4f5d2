"""The renderer: geometry once in NumPy, then ``image = prepared.image(medium)``, a JAX function of the material.

:func:`prepare` runs everything that depends only on geometry and lights -- pass 1 (irradiance samples), camera rays
and the lighting at the shaded points, the octree and the interaction lists -- and returns a :class:`Prepared`
(an ``equinox.Module`` of arrays). :meth:`Prepared.image` is pass 2 plus radiance: jitted, differentiable in the
medium, and chunked so memory stays bounded. :func:`render` is the whole forward job with progress bars, timings
(compilation apart) and the report the CLI writes.
"""

from __future__ import annotations

import math
import time
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from jaxsss.medium import Medium
from jaxsss.render import radiance as rad
from jaxsss.render.camera import camera_frame, camera_rays
from jaxsss.render.interactions import build_interactions
from jaxsss.render.lights import light_field
from jaxsss.render.octree import build_octree
from jaxsss.render.plan import ScenePlan, make_plan
from jaxsss.render.rays import OBJECT_TRANSLUCENT, SceneGeometry
from jaxsss.render.samples import irradiance_samples

__all__ = ["BLOCK_PAIRS", "Prepared", "RenderResult", "ShadedPoints", "prepare", "render", "shaded_fields"]

BLOCK_PAIRS = 1 << 16
"""Pairs per block of the hierarchical sum (one ``lax.scan`` step)."""

NEAR_RADIUS_IN_SAMPLES = 4.0
"""The near-field radius ``rho_0`` in sample radii ``sqrt(A_p / pi)`` (about 16 samples inside; see
:mod:`jaxsss.render.radiance`). On a uniformly lit plane at the paper's density (stratified samples) 2 gives 3-4%
pixel noise, 3 gives 1.4-2.4%, 4 gives 0.8-1.4% and 6 gives 0.4-0.7%, at the price of smoothing the irradiance over
a larger neighbourhood (about ``rho_0 / 2``)."""


class ShadedPoints(eqx.Module):
    """The shaded points of an image (camera-ray hits on the translucent object) and the material-free rest of it:
    what turns an exitance ``(Q, C)`` into the image. Every method's prepared state extends it."""

    query_pos: jax.Array  # (Q, 3)
    query_normal: jax.Array  # (Q, 3)
    to_eye: jax.Array  # (Q, 3)
    query_to_light: jax.Array | None  # (Q, L, 3) (single scattering and specular only)
    query_irradiance: jax.Array | None  # (Q, L, C)
    query_pixel: jax.Array  # (Q,) flat pixel index
    constant: jax.Array  # (H * W, C): background and occluders, already divided by spp
    shape: tuple = eqx.field(static=True)  # (H, W)
    spp: int = eqx.field(static=True)
    single_scattering: bool = eqx.field(static=True)
    specular_roughness: float | None = eqx.field(static=True)

    @property
    def n_queries(self) -> int:
        return self.query_pos.shape[0]

    def radiance_from_exitance(self, medium: Medium, exitance):
        """Radiance towards the eye at the shaded points, ``(Q, C)`` W/(mm^2 sr): diffusion plus the optional
        single-scattering and specular terms."""
        cos_o = jnp.clip(jnp.sum(self.query_normal * self.to_eye, axis=-1), 0.0, 1.0)
        out = rad.exit_radiance(medium, exitance, cos_o)
        if self.single_scattering:
            out = out + rad.single_scattering(medium, self.query_normal, self.to_eye, self.query_to_light,
                                              self.query_irradiance)
        if self.specular_roughness is not None:
            out = out + rad.specular_ggx(medium, self.query_normal, self.to_eye, self.query_to_light,
                                         self.query_irradiance, self.specular_roughness)
        return out

    def image_from_radiance(self, radiance):
        """``(H, W, C)`` linear image: the mean over each pixel's rays plus the constant part."""
        h, w = self.shape
        img = jax.ops.segment_sum(radiance / self.spp, self.query_pixel, num_segments=h * w)
        return (img + self.constant).reshape(h, w, -1)


class Prepared(ShadedPoints):
    """Everything an image needs except the material. Arrays are sorted for the sums; see :func:`prepare`.

    ``Q`` shaded points (camera-ray hits on the translucent object), ``N`` samples in octree order, ``E`` octree
    entities (samples then internal nodes), ``L`` lights, ``C`` channels.
    """

    # Irradiance samples (octree order).
    sample_pos: jax.Array  # (N, 3)
    areas: jax.Array  # (N,)
    light_cos: jax.Array  # (N, L)
    light_irradiance: jax.Array  # (N, L, C)
    indirect: jax.Array | None  # (N, C)
    texture: jax.Array | None  # (N, C)
    # Octree.
    ent_pos: jax.Array  # (E, 3)
    ent_start: jax.Array  # (E,)
    ent_stop: jax.Array  # (E,)
    # Interaction list in blocks (far field).
    pair_query: jax.Array | None  # (B, K) int32
    pair_entity: jax.Array | None  # (B, K) int32
    # Near field: (query, sample) pairs closer than rho0 (sorted by query), and rho0 (mm).
    near_query: jax.Array | None  # (K2,) int32
    near_sample: jax.Array | None  # (K2,) int32
    rho0: jax.Array  # ()
    method: str = eqx.field(static=True)
    shared_channel: bool = eqx.field(static=True)

    def sample_flux(self, medium: Medium):
        """``(N, C)`` flux entering the medium at each sample, W."""
        return rad.transmitted_flux(medium, self.areas, self.light_cos, self.light_irradiance, self.indirect,
                                    self.texture)

    def exitance(self, medium: Medium, blocks: slice | None = None):
        """Radiant exitance ``M_o`` at the shaded points, ``(Q, C)`` W/mm^2 (``blocks``: part of the pair list)."""
        flux = self.sample_flux(medium)
        if self.method == "direct":
            return rad.exitance_direct(medium, self.query_pos, self.sample_pos, flux, self.areas, self.rho0,
                                       shared_channel=self.shared_channel)
        ent_flux = rad.entity_flux(flux, self.ent_start, self.ent_stop)
        pq, pe = self.pair_query, self.pair_entity
        if blocks is not None:
            pq, pe = pq[blocks], pe[blocks]
        far = rad.exitance_pairs(medium, self.query_pos, self.ent_pos, ent_flux, pq, pe,
                                 shared_channel=self.shared_channel)
        return far + self.exitance_near(medium, flux)

    def exitance_gradient(self, medium: Medium, *, near: bool = True):
        """Analytic gradient of ``M_o`` with respect to the shaded point's position, ``(Q, 3, C)`` W/mm^3 (caching
        paper Eq. 9 through the same interaction list; hierarchical method only).

        ``near=False`` leaves out the near-field disc term (within ``rho0`` of the point): the far-field part alone,
        which the cached method interpolates with (:mod:`jaxsss.render.cache`, "Which gradient")."""
        flux = self.sample_flux(medium)
        ent_flux = rad.entity_flux(flux, self.ent_start, self.ent_stop)
        far = rad.exitance_gradient_pairs(medium, self.query_pos, self.ent_pos, ent_flux, self.pair_query,
                                          self.pair_entity)
        if not near:
            return far
        return far + rad.exitance_near_gradient(medium, self.query_pos, self.sample_pos, self.areas, flux,
                                                self.near_query, self.near_sample, self.rho0)

    def exitance_gradient_autodiff(self, medium: Medium):
        """The same gradient by forward-mode autodiff of :meth:`exitance` in the query positions (three JVPs: each
        point's exitance depends on its own position only), ``(Q, 3, C)``."""

        def at(query_pos):
            return eqx.tree_at(lambda p: p.query_pos, self, query_pos).exitance(medium)

        cols = [jax.jvp(at, (self.query_pos,), (jnp.zeros_like(self.query_pos).at[:, j].set(1.0),))[1]
                for j in range(3)]
        return jnp.stack(cols, axis=1)

    def exitance_near(self, medium: Medium, flux):
        """The near-field disc part of ``M_o`` (hierarchical method), ``(Q, C)``."""
        return rad.exitance_near(medium, self.query_pos, self.sample_pos, self.areas, flux, self.near_query,
                                 self.near_sample, self.rho0, shared_channel=self.shared_channel)

    def image(self, medium: Medium):
        """The linear radiance image ``(H, W, C)`` as a JAX function of the medium (differentiable; jitted, with
        this ``Prepared``'s arrays as arguments, so a second call with the same shapes does not recompile)."""
        return _image(self, medium)


class RenderResult(NamedTuple):
    """The image (linear, ``(H, W, C)`` NumPy), the report (JSON-ready dict) and the :class:`Prepared` state."""

    image: np.ndarray
    report: dict[str, Any]
    prepared: Prepared
    plan: ScenePlan


def _to_eye(camera, points):
    d = np.asarray(camera.position, dtype=np.float64) - points
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _blocks(values: np.ndarray, fill: int, block: int) -> np.ndarray:
    pad = (-len(values)) % block
    if len(values) == 0:
        pad = block
    return np.concatenate([values, np.full(pad, fill, dtype=values.dtype)]).reshape(-1, block)


def _split_near(inter, q_pos, tree, sorted_pos, rho0, chunk: int = 1 << 22):
    """Split an interaction list into far pairs (summed point by point) and near (query, sample) pairs closer than
    ``rho0``. Returns ``(far_mask, near_query, near_sample, nodes_inside)`` where ``nodes_inside``
    counts accepted octree nodes whose centroid lies within ``rho0`` (0 unless eps is very large: a node there
    subtends a solid angle far above any sensible eps)."""
    n = tree.n_samples
    far = np.ones(len(inter.query), dtype=bool)
    nodes_inside = 0
    for s in range(0, len(far), chunk):
        q, e = inter.query[s:s + chunk], inter.entity[s:s + chunk]
        pos = np.where((e < n)[:, None], sorted_pos[np.minimum(e, n - 1)], tree.centroid[e])
        close = np.einsum("ij,ij->i", pos - q_pos[q], pos - q_pos[q]) < rho0 * rho0
        far[s:s + chunk] = ~(close & (e < n))
        nodes_inside += int(np.count_nonzero(close & (e >= n)))
    near_q = inter.query[~far].astype(np.int32)
    near_s = inter.entity[~far].astype(np.int32)
    return far, near_q, near_s, nodes_inside


class _Shading(NamedTuple):
    """The shaded points (camera-ray hits on the translucent object) and the material-free part of the image."""

    pos: np.ndarray  # (Q, 3)
    normal: np.ndarray  # (Q, 3)
    to_eye: np.ndarray  # (Q, 3)
    pixel: np.ndarray  # (Q,)
    light: Any  # LightField at the points, or None
    constant: np.ndarray  # (H * W, C)
    shape: tuple
    spp: int
    n_rays: int

    def subset(self, idx: np.ndarray) -> _Shading:
        light = None if self.light is None else type(self.light)(*(a[idx] for a in self.light))
        return self._replace(pos=self.pos[idx], normal=self.normal[idx], to_eye=self.to_eye[idx],
                             pixel=self.pixel[idx], light=light)


def _pass1(scene, plan: ScenePlan):
    """``(geometry, samples, tree, octree_seconds)``: the ray-casting scene, pass-1 irradiance samples and their
    octree (centroids weighted by the channel-mean direct plus indirect flux)."""
    geometry = SceneGeometry(scene.mesh, [o.mesh for o in scene.occluders])
    samples = irradiance_samples(scene, geometry, plan.n_samples, shadows=plan.shadows, indirect=plan.indirect,
                                 seed=scene.render.seed)
    t0 = time.perf_counter()
    weight = samples.areas * samples.light.irradiance.sum(axis=1).mean(axis=-1)
    if samples.indirect is not None:
        weight = weight + samples.areas * samples.indirect.mean(axis=-1)
    tree = build_octree(samples.positions, samples.areas, weight)
    return geometry, samples, tree, time.perf_counter() - t0


def point_shading(points, n_channels: int, owner: str = "prepare") -> _Shading:
    """Shading state for given surface points instead of the camera's (validation against Monte Carlo): one "pixel"
    per point, viewed along its normal, nothing else in the image; ``points`` is ``(positions (Q, 3) mm, outward
    normals (Q, 3))``."""
    pos, normal = (np.asarray(a, dtype=np.float64) for a in points)
    if pos.ndim != 2 or pos.shape[1] != 3 or normal.shape != pos.shape:
        raise ValueError(f"{owner}(points=...) needs two (Q, 3) arrays; got {pos.shape} and {normal.shape}")
    normal = normal / np.linalg.norm(normal, axis=1, keepdims=True)
    q = len(pos)
    return _Shading(pos, normal, normal, np.arange(q), None, np.zeros((q, n_channels)), (1, q), 1, q)


def _shading_points(scene, geometry, plan: ScenePlan, resolution, pixel_mask, n_channels: int) -> _Shading:
    """Camera rays, their hits, the occluders' and background's constant image, and lighting at the shaded points."""
    rays = camera_rays(scene.camera, resolution, seed=scene.render.seed)
    h, w = rays.shape
    keep = np.ones(len(rays.pixel), dtype=bool) if pixel_mask is None else np.asarray(pixel_mask).reshape(-1)[
        rays.pixel]
    hits = geometry.first_hit(rays.origins[keep], rays.directions[keep])
    ray_idx = np.flatnonzero(keep)
    constant = np.zeros((h * w, n_channels))
    background = np.broadcast_to(np.asarray(scene.output.background, dtype=np.float64), (n_channels,))
    missed = ray_idx[~hits.hit]
    np.add.at(constant, rays.pixel[missed], background / rays.spp)
    on_occ = hits.obj >= 1
    if on_occ.any():
        idx = np.flatnonzero(on_occ)
        y = hits.position[idx]
        ny = geometry.shading_normals(hits.face[idx], y)
        ny = np.where(np.einsum("ij,ij->i", ny, rays.directions[ray_idx[idx]])[:, None] > 0, -ny, ny)
        direct = light_field(scene.lights, y, ny, geometry).irradiance.sum(axis=1)
        albedo = np.stack([scene.occluders[k - 1].albedo for k in hits.obj[idx]])
        # Lambertian occluder: L = albedo / pi * E.
        np.add.at(constant, rays.pixel[ray_idx[idx]], albedo / np.pi * direct / rays.spp)
    on_obj = np.flatnonzero(hits.obj == OBJECT_TRANSLUCENT)
    q_pos = hits.position[on_obj]
    q_normal = geometry.shading_normals(hits.face[on_obj], q_pos)
    to_eye = -rays.directions[ray_idx[on_obj]]
    # A smooth normal can face away from the eye at silhouettes; shade with the normal flipped towards the eye.
    back = np.einsum("ij,ij->i", q_normal, to_eye) < 0
    q_normal[back] = q_normal[back] - 2 * np.einsum("ij,ij->i", q_normal[back], to_eye[back])[:, None] * to_eye[back]
    q_light = None
    if plan.single_scattering or plan.specular:
        q_light = light_field(scene.lights, q_pos, q_normal, geometry if plan.shadows else None)
    return _Shading(q_pos, q_normal, to_eye, rays.pixel[ray_idx[on_obj]], q_light, constant, (h, w), rays.spp,
                    len(rays.pixel))


def near_radius(samples) -> float:
    """The near-field radius ``rho_0`` (mm) for these samples: :data:`NEAR_RADIUS_IN_SAMPLES` sample radii."""
    return NEAR_RADIUS_IN_SAMPLES * math.sqrt(float(np.mean(samples.areas)) / math.pi)


def _pair_lists(tree, samples, q_pos, plan: ScenePlan, *, progress: bool, block_pairs: int):
    """Interaction lists for the points ``q_pos``: far pairs in blocks, near pairs, and counts."""
    rho0 = near_radius(samples)
    if plan.method == "direct" or len(q_pos) == 0:
        return {"pq": None, "pe": None, "near_q": None, "near_s": None, "rho0": rho0, "counts": np.full(len(q_pos), samples.n),
                    "nodes_inside": 0}
    inter = build_interactions(tree, q_pos, plan.eps, r_cut=plan.r_cut, progress=progress)
    counts = inter.counts()
    far, near_q, near_s, nodes_inside = _split_near(inter, q_pos, tree, samples.positions[tree.order], rho0)
    pq = jnp.asarray(_blocks(inter.query[far].astype(np.int32), len(q_pos), block_pairs))
    pe = jnp.asarray(_blocks(inter.entity[far].astype(np.int32), 0, block_pairs))
    return {"pq": pq, "pe": pe, "near_q": near_q, "near_s": near_s, "rho0": rho0, "counts": counts, "nodes_inside": nodes_inside}


def shaded_fields(scene, plan: ScenePlan, shading: _Shading) -> dict[str, Any]:
    """The :class:`ShadedPoints` fields of ``shading`` as JAX arrays (keyword arguments for any method's state)."""
    light = shading.light
    return {
        "query_pos": jnp.asarray(shading.pos),
        "query_normal": jnp.asarray(shading.normal),
        "to_eye": jnp.asarray(shading.to_eye),
        "query_to_light": None if light is None else jnp.asarray(light.to_light),
        "query_irradiance": None if light is None else jnp.asarray(light.irradiance),
        "query_pixel": jnp.asarray(shading.pixel),
        "constant": jnp.asarray(shading.constant),
        "shape": shading.shape,
        "spp": shading.spp,
        "single_scattering": plan.single_scattering,
        "specular_roughness": scene.material.specular_roughness if plan.specular else None,
    }


def _assemble(scene, plan: ScenePlan, samples, tree, shading: _Shading, pairs: dict | None) -> Prepared:
    def opt(a):
        return None if a is None else jnp.asarray(a)

    order = tree.order
    pairs = pairs or {"pq": None, "pe": None, "near_q": None, "near_s": None, "rho0": near_radius(samples)}
    return Prepared(
        **shaded_fields(scene, plan, shading),
        sample_pos=jnp.asarray(samples.positions[order]),
        areas=jnp.asarray(samples.areas[order]),
        light_cos=jnp.asarray(samples.light.cos[order]),
        light_irradiance=jnp.asarray(samples.light.irradiance[order]),
        indirect=opt(None if samples.indirect is None else samples.indirect[order]),
        texture=opt(None if samples.texture is None else samples.texture[order]),
        ent_pos=jnp.asarray(tree.centroid),
        ent_start=jnp.asarray(tree.start),
        ent_stop=jnp.asarray(tree.stop),
        pair_query=pairs["pq"],
        pair_entity=pairs["pe"],
        near_query=opt(pairs["near_q"]),
        near_sample=opt(pairs["near_s"]),
        rho0=jnp.asarray(pairs["rho0"]),
        method=plan.method,
        shared_channel=plan.shared_channel,
    )


def _pair_info(pairs: dict, n_points: int) -> dict[str, Any]:
    counts = pairs["counts"]
    return {
        "n_interactions": int(np.sum(counts)),
        "interactions_per_point_mean": float(np.mean(counts)) if len(counts) else 0.0,
        "interactions_per_point_max": int(np.max(counts)) if len(counts) else 0,
        "near_radius_mm": pairs["rho0"],
        "near_samples_per_point_mean": (float(len(pairs["near_q"]) / max(n_points, 1))
                                        if pairs["near_q"] is not None else None),
        "octree_nodes_accepted_inside_near_radius": int(pairs["nodes_inside"]),
    }


def prepare(scene, *, method: str | None = None, eps: float | None = None, resolution=None,
            plan: ScenePlan | None = None, progress: bool = False, pixel_mask: np.ndarray | None = None,
            cutoff: bool = True, share_channels: bool = True, block_pairs: int = BLOCK_PAIRS, points=None):
    """Geometry-only work: pass 1, camera rays, octree and interaction lists.

    Args:
        scene: a :class:`~jaxsss.render.scene.Scene`.
        method: ``"hierarchical"`` (default from the scene) or ``"direct"``.
        eps: solid-angle threshold (sr) of Eq. 12.
        resolution: ``(W, H)`` overriding the camera's.
        plan: a plan made earlier (else :func:`~jaxsss.render.plan.make_plan`).
        progress: show progress bars.
        pixel_mask: optional ``(H, W)`` bool: shade only these pixels (the rest are 0) -- fitting on a subset and
            measuring the direct sum on part of an image use it.
        cutoff, share_channels: passed to the plan (fitting turns both off).
        points: optional ``(positions (Q, 3), normals (Q, 3))`` to shade instead of the camera's pixels (the image is
            then ``(1, Q, C)``, diffusion only; validation against the mesh Monte Carlo uses it).

    Returns:
        ``(prepared, plan, info)`` where ``info`` holds timings (s) and counts.
    """
    t_all = time.perf_counter()
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    plan = plan or make_plan(scene, method=method, eps=eps, cutoff=cutoff, share_channels=share_channels)
    timings["plan"] = time.perf_counter() - t0
    bar = tqdm(total=3, desc="render: geometry", disable=not progress, leave=False)

    # Pass 1: irradiance samples and their octree.
    t0 = time.perf_counter()
    geometry, samples, tree, timings["octree"] = _pass1(scene, plan)
    timings["pass1_irradiance"] = time.perf_counter() - t0 - timings["octree"]
    bar.set_postfix_str(f"{samples.n} samples")
    bar.update()

    # Camera rays and lighting at the shaded points.
    t0 = time.perf_counter()
    if points is None:
        shading = _shading_points(scene, geometry, plan, resolution, pixel_mask, samples.light.irradiance.shape[-1])
    else:
        shading = point_shading(points, samples.light.irradiance.shape[-1])
        plan = plan._replace(single_scattering=False, specular=False)
    timings["camera_rays"] = time.perf_counter() - t0
    bar.set_postfix_str(f"{len(shading.pos)} shaded points")
    bar.update()

    t0 = time.perf_counter()
    pairs = _pair_lists(tree, samples, shading.pos, plan, progress=progress, block_pairs=block_pairs)
    timings["interactions"] = time.perf_counter() - t0
    bar.update()
    bar.close()

    prepared = _assemble(scene, plan, samples, tree, shading, pairs)
    info = {
        "timings": timings,
        "seconds_geometry": time.perf_counter() - t_all,
        "n_samples": int(samples.n),
        "n_shaded_points": len(shading.pos),
        "n_pixels": int(shading.shape[0] * shading.shape[1]),
        "n_rays": shading.n_rays,
        "n_octree_entities": len(tree.start),
        **_pair_info(pairs, len(shading.pos)),
        "camera_forward": camera_frame(scene.camera)[0].tolist(),
    }
    return prepared, plan, info


@eqx.filter_jit
def _image(prepared: Prepared, medium: Medium):
    return prepared.image_from_radiance(prepared.radiance_from_exitance(medium, prepared.exitance(medium)))


@eqx.filter_jit
def _exitance_blocks(prepared: Prepared, medium: Medium, pq, pe):
    flux = prepared.sample_flux(medium)
    ent_flux = rad.entity_flux(flux, prepared.ent_start, prepared.ent_stop)
    return rad.exitance_pairs(medium, prepared.query_pos, prepared.ent_pos, ent_flux, pq, pe,
                              shared_channel=prepared.shared_channel)


@eqx.filter_jit
def _exitance_near(prepared: Prepared, medium: Medium):
    return prepared.exitance_near(medium, prepared.sample_flux(medium))


@eqx.filter_jit
def _finish(prepared: Prepared, medium: Medium, exitance):
    return prepared.image_from_radiance(prepared.radiance_from_exitance(medium, exitance))


@eqx.filter_jit
def _direct_exitance(prepared: Prepared, medium: Medium):
    return prepared.exitance(medium)


def _image_stats(image: np.ndarray) -> dict[str, Any]:
    return {
        "min": image.min(axis=(0, 1)).tolist(),
        "max": image.max(axis=(0, 1)).tolist(),
        "mean": image.mean(axis=(0, 1)).tolist(),
        "finite": bool(np.isfinite(image).all()),
    }


def render_report(seconds_total: float, timings: dict, method: str, plan: ScenePlan, prepared: Prepared, info: dict,
                  image: np.ndarray) -> dict[str, Any]:
    """The JSON-ready render report shared by every method: totals (compilation apart), per-pass timings, counts,
    the plan and image statistics. ``prepared`` gives the image shape and samples per pixel."""
    return {
        "seconds_total": seconds_total,
        "seconds_total_excluding_compile": seconds_total - timings["pass2_compile"],
        "timings": timings,
        "method": method,
        "eps": plan.eps,
        "resolution": [prepared.shape[1], prepared.shape[0]],
        "spp": prepared.spp,
        **{k: v for k, v in info.items() if k != "timings"},
        "plan": plan.to_dict(),
        "image": _image_stats(image),
    }


def render(scene, *, method: str | None = None, eps: float | None = None, resolution=None, progress: bool = False,
           pixel_mask=None, calls: int = 16) -> RenderResult:
    """Render a scene: :func:`prepare`, then pass 2 in ``calls`` jitted calls over the pair list (for a progress
    bar; each call has the same shapes, so it compiles once), then radiance and the image.

    Returns:
        A :class:`RenderResult`; ``report`` holds ``seconds_total``, per-pass timings with compilation apart, the
        sample count, interactions per shaded point, the plan and image statistics.
    """
    t_all = time.perf_counter()
    prepared, plan, info = prepare(scene, method=method, eps=eps, resolution=resolution, progress=progress,
                                   pixel_mask=pixel_mask)
    medium = scene.material.medium
    timings = dict(info["timings"])
    n_c = prepared.constant.shape[-1]
    # Compile every pass-2 function first (timed apart), then run them.
    t0 = time.perf_counter()
    exitance0 = jnp.zeros((prepared.n_queries, n_c))
    finish = _finish.lower(prepared, medium, exitance0).compile()
    if prepared.n_queries == 0:
        compiled = None
    elif prepared.method == "direct":
        compiled = _direct_exitance.lower(prepared, medium).compile()
    else:
        n_blocks = prepared.pair_query.shape[0]
        per_call = max(1, math.ceil(n_blocks / calls))
        pad = (-n_blocks) % per_call
        pq = jnp.concatenate([prepared.pair_query,
                              jnp.full((pad, prepared.pair_query.shape[1]), prepared.n_queries, jnp.int32)])
        pe = jnp.concatenate([prepared.pair_entity, jnp.zeros((pad, prepared.pair_entity.shape[1]), jnp.int32)])
        compiled = _exitance_blocks.lower(prepared, medium, pq[:per_call], pe[:per_call]).compile()
        near = _exitance_near.lower(prepared, medium).compile()
    timings["pass2_compile"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if compiled is None:
        exitance = exitance0
    elif prepared.method == "direct":
        exitance = jax.block_until_ready(compiled(prepared, medium))
    else:
        exitance = near(prepared, medium)
        for s in tqdm(range(0, n_blocks + pad, per_call), desc="render: pass 2 (hierarchical sum)",
                      disable=not progress, leave=False):
            exitance = exitance + compiled(prepared, medium, pq[s:s + per_call], pe[s:s + per_call])
        exitance = jax.block_until_ready(exitance)
    timings["pass2_sum"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    image = np.asarray(finish(prepared, medium, exitance))
    timings["radiance_and_image"] = time.perf_counter() - t0
    report = render_report(time.perf_counter() - t_all, timings, plan.method, plan, prepared, info, image)
    return RenderResult(image, report, prepared, plan)
