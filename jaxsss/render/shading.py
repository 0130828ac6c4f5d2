"""Shading points: where the camera's rays hit the translucent object, and the material-free rest of the image.

Every render method shades the same points and turns an exitance (or radiance) at them into an image the same way,
so this module is the renderer's shared interface for it:

- :func:`shading_points` casts the camera rays (:func:`~jaxsss.render.camera.camera_rays`) against the scene's
  geometry and returns a :class:`ShadingPoints` (NumPy): positions, normals (flipped towards the eye at
  silhouettes), directions to the eye, flat pixel indices and weights, lighting at the points (when single
  scattering or specular need it) and the ``constant`` image of everything that is not the translucent object;
- :func:`edge_pixels` finds the pixels whose centre misrepresents them (creases, and terminators or shadow edges on
  a turning surface): :func:`shading_points` casts the camera's ``edge_spp`` rays there instead of ``spp``;
  :func:`dark_pixel_grid` finds the unlit pixels across which the light that crept past a terminator falls off
  steeply, and those get a grid of rays at its cells' centres (at most ``edge_spp``);
- :func:`see_through` continues the camera's rays through thin walls at ``eta = 1`` (the part of the object behind a
  wall is seen through it);
- :func:`point_shading` is the same for given surface points (validation against Monte Carlo);
- :func:`constant_image` is the background and the grey Lambertian occluders;
- :class:`ShadedPoints` is the JAX side (an ``equinox.Module`` every method's state extends): exit radiance from an
  exitance (:meth:`~ShadedPoints.radiance_from_exitance`) and the image from radiance
  (:meth:`~ShadedPoints.image_from_radiance`); :func:`shaded_fields` fills its fields from a :class:`ShadingPoints`;
- :func:`image_stats` is the report's image summary.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxsss._config import to_device
from jaxsss.medium import Medium
from jaxsss.render import radiance as rad
from jaxsss.render.bssrdf import exit_model_for, exit_radiance_nodes
from jaxsss.render.camera import camera_rays
from jaxsss.render.exit_direction import azimuth_harmonics
from jaxsss.render.lights import light_field
from jaxsss.render.rays import OBJECT_TRANSLUCENT, Hits

__all__ = ["CREASE_DEG", "DARK_CELL_FALLOFF", "DARK_REACH", "EDGE_CONTRAST", "EDGE_TURN_DEG", "MIN_COS_VIEW",
           "VIEW_REENTRIES", "CentreLight", "SeenThrough", "ShadedPoints", "ShadingPoints", "centre_light",
           "constant_image", "dark_pixel_grid", "edge_pixels", "exit_azimuth", "face_the_eye", "image_stats",
           "mirror_direction", "point_shading", "see_through", "seen_in_mirror", "shaded_fields", "shading_points"]


class ShadingPoints(NamedTuple):
    """The shaded points (camera-ray hits on the translucent object) and the material-free part of the image, in
    NumPy (``Q`` points, ``C`` channels)."""

    pos: np.ndarray  # (Q, 3) mm
    normal: np.ndarray  # (Q, 3) unit, facing the eye
    to_eye: np.ndarray  # (Q, 3) unit
    pixel: np.ndarray  # (Q,) flat pixel index row * W + col
    light: Any  # LightField at the points (single scattering, specular), or None
    constant: np.ndarray  # (H * W, C) background and occluders, already weighted per ray
    shape: tuple  # (H, W)
    spp: int
    n_rays: int
    weight: np.ndarray  # (Q,) each point's weight in its pixel's mean (1 / that pixel's rays)
    # The first order's march (jaxsss.render.first_order.FirstOrderPaths), or None
    first_order: Any = None
    # (Q,) mm: the object's chord in front of each point along its camera ray (see_through), or None (all 0)
    through: np.ndarray | None = None
    # (Q,) mm: the view ray's chord inside where the object is seen through it behind (see_through), 0 elsewhere
    veil: np.ndarray | None = None
    # (Q,) the cosine to the eye of the point whose smooth boundary mirrors this one (seen_in_mirror), 0 where the
    # point is seen directly, or None (none mirrored)
    mirrored: np.ndarray | None = None

    def subset(self, idx: np.ndarray) -> ShadingPoints:
        """The points ``idx`` only (the image part is unchanged)."""
        light = None if self.light is None else type(self.light)(*(a[idx] for a in self.light))
        march = None if self.first_order is None else jax.tree.map(lambda a: a[idx], self.first_order)
        through, veil, mirrored = (None if a is None else a[idx] for a in (self.through, self.veil, self.mirrored))
        return self._replace(pos=self.pos[idx], normal=self.normal[idx], to_eye=self.to_eye[idx],
                             pixel=self.pixel[idx], light=light, weight=self.weight[idx], first_order=march,
                             through=through, veil=veil, mirrored=mirrored)


def face_the_eye(normal: np.ndarray, to_eye: np.ndarray) -> np.ndarray:
    """Smooth normals can face away from the eye at silhouettes: reflect those about the view direction, ``(Q, 3)``
    (a new array)."""
    normal = np.array(normal, dtype=np.float64)
    back = np.einsum("ij,ij->i", normal, to_eye) < 0
    normal[back] = normal[back] - 2 * np.einsum("ij,ij->i", normal[back], to_eye[back])[:, None] * to_eye[back]
    return normal


def constant_image(scene, geometry, rays, ray_idx: np.ndarray, hits, n_channels: int) -> np.ndarray:
    """``(H * W, C)`` the image of whatever is not the translucent object: the background where the rays ``ray_idx``
    miss (``hits`` are theirs) and grey Lambertian occluders (``albedo / pi * E``), each ray times its weight."""
    h, w = rays.shape
    constant = np.zeros((h * w, n_channels))
    background = np.broadcast_to(np.asarray(scene.output.background, dtype=np.float64), (n_channels,))
    missed = ray_idx[~hits.hit]
    np.add.at(constant, rays.pixel[missed], background[None, :] * rays.weight[missed, None])
    on_occ = np.flatnonzero(hits.obj >= 1)
    if on_occ.size:
        y = hits.position[on_occ]
        ny = geometry.shading_normals(hits.face[on_occ], y)
        ny = np.where(np.einsum("ij,ij->i", ny, rays.directions[ray_idx[on_occ]])[:, None] > 0, -ny, ny)
        direct = light_field(scene.lights, y, ny, geometry).irradiance.sum(axis=1)
        albedo = np.stack([scene.occluders[k - 1].albedo for k in hits.obj[on_occ]])
        # Lambertian occluder: L = albedo / pi * E.
        np.add.at(constant, rays.pixel[ray_idx[on_occ]], albedo / np.pi * direct * rays.weight[ray_idx[on_occ], None])
    return constant


EDGE_CONTRAST = 0.25
""":func:`edge_pixels`: a terminator or shadow edge runs through a pixel's neighbourhood when some object pixel of it
receives less than this fraction of the largest direct irradiance there."""
EDGE_TURN_DEG = 10.0
""":func:`edge_pixels`: the surface turns inside a pixel's neighbourhood when some object pixel's normal is more than
this many degrees from the centre's (a smooth 20 mm sphere at 0.8 mm per pixel turns 2.3 degrees per pixel)."""
CREASE_DEG = 30.0
""":func:`edge_pixels`: a crease (edge, rim, spout) runs through a pixel's neighbourhood when some object pixel's normal
is more than this many degrees from the centre's."""
DARK_CELL_FALLOFF = 1.0
""":func:`dark_pixel_grid`: the most e-folds of the light's fall-off past a terminator that one cell of a dark pixel's
grid may span. The midpoint rule then misses at most ``sinh(0.5) / 0.5 - 1 = 4%`` of an exponential's mean along it
(at a cell that spans the whole e-fold; most span less). Chosen on error against time (docs/path_tracer.md, "Dark
pixels are areas too"): on the back-lit skin1 sphere 0.7 / 1.0 / 1.4 / 2.0 gave green and blue 0.074 / 0.060, 0.077 /
0.060, 0.086 / 0.071 and 0.092 / 0.077 at 1.49 / 1.32 / 1.12 / 1.10 times the time without grids (0.148 / 0.184)."""
DARK_REACH = 4.6
""":func:`dark_pixel_grid`: a channel's light past the lit surface counts while ``sigma_tr d`` is under this (it has
fallen to 1% of what it was at the lit edge, ``exp(-4.6)``)."""
MIN_COS_VIEW = 0.2
""":func:`dark_pixel_grid`: the view's slant is counted at most ``1 / MIN_COS_VIEW`` (nearer the limb the footprint
grows without bound; those pixels get the largest grid)."""


class CentreLight(NamedTuple):
    """What the pixel tests need from the pixel centres' rays (:func:`centre_light`; ``H W`` pixels)."""

    shape: tuple  # (H, W)
    on: np.ndarray  # (H W,) bool: the centre's first hit is the translucent object
    position: np.ndarray  # (H W, 3) mm, the hit (NaN off the object)
    normal: np.ndarray  # (H W, 3) shading normal facing the eye (NaN off the object)
    direct: np.ndarray  # (H W,) W/mm^2: irradiance from the lights other than an environment (0 off the object)
    distance: np.ndarray  # (H W,) mm from the camera to the hit (inf off the object)
    cos_view: np.ndarray  # (H W,) cosine between the normal and the way to the eye (0 off the object)


def centre_light(scene, geometry, resolution=None, shadows: bool = True, centre_hits=None) -> CentreLight:
    """The pixel centres' hits, normals and direct irradiance, for :func:`edge_pixels` and :func:`dark_pixel_grid`.

    Args:
        scene: the :class:`~jaxsss.render.scene.Scene`.
        geometry: its :class:`~jaxsss.render.rays.SceneGeometry`.
        resolution: ``(W, H)`` overriding the camera's, or None.
        shadows: trace shadow rays for the irradiance (the plan's ``shadows``).
        centre_hits: the :class:`~jaxsss.render.rays.Hits` of the pixel centres' rays (``camera_rays(...,
            spp=1)``, every pixel) when the caller has traced them already; else they are traced here.
    """
    rays = camera_rays(scene.camera, resolution, spp=1)
    h, w = rays.shape
    hits = geometry.first_hit(rays.origins, rays.directions) if centre_hits is None else centre_hits
    on = hits.obj == OBJECT_TRANSLUCENT
    direct = np.zeros(h * w)
    position = np.full((h * w, 3), np.nan)
    normal = np.full((h * w, 3), np.nan)
    distance = np.full(h * w, np.inf)
    cos_view = np.zeros(h * w)
    idx = np.flatnonzero(on)
    if idx.size:
        to_eye = -rays.directions[idx]
        position[idx] = hits.position[idx]
        normal[idx] = face_the_eye(geometry.shading_normals(hits.face[idx], hits.position[idx]), to_eye)
        distance[idx] = hits.t[idx]
        cos_view[idx] = np.einsum("ij,ij->i", normal[idx], to_eye)
    lights = [light for light in scene.lights if light.kind != "environment"]
    if lights and idx.size:
        direct[idx] = light_field(lights, hits.position[idx], normal[idx], geometry if shadows else None
                                  ).irradiance.sum(axis=(1, 2))
    return CentreLight((h, w), on, position, normal, direct, distance, cos_view)


def edge_pixels(scene, geometry, resolution=None, shadows: bool = True, centre_hits=None,
                centre: CentreLight | None = None) -> np.ndarray:
    """``(H, W)`` bool: the translucent pixels whose centre misrepresents them, from the pixel centres' geometry (no
    material: the shaded points are the same for every medium).

    A pixel is an area; its value is the mean over it (what a path tracer's box filter measures). The centre's
    radiance is far from that mean where the surface turns inside the pixel: at a crease (some object pixel of the 3
    x 3 neighbourhood has a normal more than :data:`CREASE_DEG` from the centre's), and where a terminator or shadow
    edge meets a turning surface (some object pixel of the neighbourhood receives under :data:`EDGE_CONTRAST` of its
    largest direct irradiance from the lights other than an environment, and some normal is more than
    :data:`EDGE_TURN_DEG` from the centre's). On a smooth surface diffusion blurs a lit terminator over more than a
    pixel and the centre stands for the pixel (past the terminator it may not: :func:`dark_pixel_grid`). Measured
    against Mitsuba (docs/path_tracer.md, "Pixels are areas"): on the marble teapot (64 x 64) the centres above the
    base were 0.23-0.55 of the pixels' means, and these pixels' nine rays take its terminator band from 0.16-0.21 to
    0.11; on the smooth skin1 sphere they flag 15 pixels and change nothing. Silhouettes are left to the camera's
    ``spp`` (partly covered pixels, which the comparisons leave out).

    Args:
        scene, geometry, resolution, shadows, centre_hits: as :func:`centre_light`.
        centre: :func:`centre_light`'s result when the caller has it (the other arguments but ``scene`` are then
            unused).
    """
    centre = centre_light(scene, geometry, resolution, shadows, centre_hits) if centre is None else centre
    h, w = centre.shape
    on, normal, direct = centre.on, centre.normal, centre.direct

    def neighbourhood(a):
        """``(9, H, W, ...)``: each pixel's 3 x 3 neighbours (the image's border repeated outside it)."""
        a = a.reshape((h, w) + a.shape[1:])
        p = np.pad(a, ((1, 1), (1, 1)) + ((0, 0),) * (a.ndim - 2), mode="edge")
        return np.stack([p[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)])

    # The largest turn of the surface: the smallest cosine between a neighbour's normal and the centre's.
    n = neighbourhood(normal)
    cos_turn = np.min(np.nan_to_num(np.einsum("khwc,hwc->khw", n, n[4]), nan=1.0), axis=0)
    # A terminator or shadow edge: a translucent neighbour lit under EDGE_CONTRAST of the brightest one.
    e = neighbourhood(np.where(on, direct, np.nan))
    e_max = np.max(np.where(np.isnan(e), -np.inf, e), axis=0)
    e_min = np.min(np.where(np.isnan(e), np.inf, e), axis=0)
    edge = (e_max > 0.0) & (e_min < EDGE_CONTRAST * e_max)
    crease = cos_turn < np.cos(np.radians(CREASE_DEG))
    turning = cos_turn < np.cos(np.radians(EDGE_TURN_DEG))
    return on.reshape(h, w) & (crease | (edge & turning))


def dark_pixel_grid(scene, geometry, resolution=None, shadows: bool = True, centre_hits=None,
                    centre: CentreLight | None = None, max_side: int | None = None,
                    lit: np.ndarray | None = None) -> np.ndarray:
    """``(H, W)`` int ``n >= 1``: the side of the ``n x n`` grid of rays (at the cells' centres) that a dark pixel
    needs for its mean, 1 elsewhere.

    Where no light but an environment reaches the surface (past a terminator, in a shadow) the light there has
    crept in from the lit parts and falls off with the distance about as ``exp(-sigma_tr d)``. Across a pixel whose
    footprint on the surface, ``Delta / cos_view`` (``Delta`` the pixel's width at the hit's distance), spans ``k =
    sigma_tr Delta / cos_view`` e-folds of it, the centre gives ``sinh(k / 2) / (k / 2)`` less than the pixel's mean
    (convexity): 4% at ``k = 1``, 42% at ``k = 3``. skin1's blue (``l_d = 0.68`` mm) past the terminator of a 20 mm
    sphere seen at 0.8 mm per pixel is there (docs/path_tracer.md, "Dark pixels are areas too"). An ``n x n`` grid at
    the cells' centres leaves ``sinh(k / 2n) / (k / 2n) - 1``; ``n`` is the smallest with ``k / n`` under
    :data:`DARK_CELL_FALLOFF`, at most ``max_side``, for the fastest channel that still has light there: with the
    directly lit surface points ``lit``, a channel counts at a pixel whose distance ``d`` from the nearest of them is
    under :data:`DARK_REACH` ``/ sigma_tr`` (ketchup's green and blue have faded 2-3 mm past the terminator, its red
    after 20 mm). Not with an environment light: a sky lights the dark side itself, smoothly.

    The grid depends on the scene's material (``sigma_tr``): a fit keeps the grid of the material it was prepared
    with, which only decides where rays are spent.

    Args:
        scene, geometry, resolution, shadows, centre_hits, centre: as :func:`edge_pixels`.
        max_side: the largest grid's side (default ``floor(sqrt(edge_spp))`` of the camera: 3 for its default 9
            rays; 1 turns the grid off).
        lit: ``(M, 3)`` mm, points of the object's surface that a light other than an environment reaches directly
            (the pass-1 irradiance samples it lights), or None (every channel counts everywhere).
    """
    centre = centre_light(scene, geometry, resolution, shadows, centre_hits) if centre is None else centre
    h, w = centre.shape
    max_side = int(np.sqrt(scene.camera.edge_spp) + 1e-9) if max_side is None else int(max_side)
    kinds = {light.kind for light in scene.lights}
    medium = scene.material.medium
    sigma_tr = np.atleast_1d(np.asarray(medium.sigma_tr, dtype=np.float64))  # (C,)
    dark = np.flatnonzero(centre.on & (centre.direct <= 0.0))
    side = np.ones(h * w, dtype=np.int64)
    if max_side < 2 or "environment" in kinds or not kinds or not np.any(sigma_tr > 0.0) or not dark.size:
        return side.reshape(h, w)
    if lit is not None and not len(lit):
        return side.reshape(h, w)  # nothing is lit: no light crept anywhere
    # The pixel's width at the hit's distance (pinhole: 2 tan(fov / 2) / H per unit distance).
    width = centre.distance[dark] * 2.0 * np.tan(np.radians(scene.camera.fov_deg) / 2.0) / h
    # e-folds of exp(-sigma_tr d) across the pixel's footprint (its long side, at the view's slant), per channel.
    k = (width / np.maximum(centre.cos_view[dark], MIN_COS_VIEW))[:, None] * sigma_tr[None, :]
    if lit is not None:
        from scipy.spatial import cKDTree

        d, _ = cKDTree(np.asarray(lit, dtype=np.float64)).query(centre.position[dark])
        # Only the channels whose light has not faded out on the way from the lit surface.
        k = np.where(sigma_tr[None, :] * d[:, None] < DARK_REACH, k, 0.0)
    side[dark] = np.clip(np.ceil(np.max(k, axis=1) / DARK_CELL_FALLOFF), 1, max_side)
    return side.reshape(h, w)


def shading_points(scene, geometry, plan, resolution, pixel_mask, n_channels: int,
                   lit: np.ndarray | None = None) -> ShadingPoints:
    """Camera rays, their hits, the constant image, and the lighting at the shaded points.

    Args:
        scene: the :class:`~jaxsss.render.scene.Scene`.
        geometry: its :class:`~jaxsss.render.rays.SceneGeometry` (translucent mesh first).
        plan: the :class:`~jaxsss.render.plan.ScenePlan` (``shadows``, ``single_scattering``, ``specular``).
        resolution: ``(W, H)`` overriding the camera's, or None.
        pixel_mask: optional ``(H, W)`` bool: only these pixels are shaded (the rest stay 0).
        n_channels: ``C``.
        lit: ``(M, 3)`` mm, directly lit points of the surface, for :func:`dark_pixel_grid`, or None.
    """
    rays = camera_rays(scene.camera, resolution, seed=scene.render.seed)
    traced = None  # (rays, their hits) already traced, when the edge test traced the pixel centres
    if scene.camera.edge_spp > rays.spp:
        # At one ray per pixel the camera's rays are the centres the pixel tests trace: trace them once.
        centre = geometry.first_hit(rays.origins, rays.directions) if rays.spp == 1 else None
        light = centre_light(scene, geometry, resolution, plan.shadows, centre_hits=centre)
        # Edge pixels: edge_spp jittered rays instead of spp (edge_pixels).
        edges = edge_pixels(scene, geometry, centre=light).reshape(-1)
        # Dark pixels: an n x n grid at the cells' centres where it has more rays than spp (dark_pixel_grid).
        side = np.where(edges, 1, dark_pixel_grid(scene, geometry, centre=light, lit=lit).reshape(-1))
        side = np.where(side * side > rays.spp, side, 1)
        if centre is not None:
            traced = len(rays.pixel), centre
        more = edges | (side > 1)
        if more.any():
            stay = ~more[rays.pixel]
            rays = rays.where(stay)
            if edges.any():
                rays = rays.join(camera_rays(scene.camera, resolution, seed=scene.render.seed + 1,
                                             pixels=np.flatnonzero(edges), spp=scene.camera.edge_spp))
            for n in np.unique(side[side > 1]):
                rays = rays.join(camera_rays(scene.camera, resolution, pixels=np.flatnonzero(side == n),
                                             spp=int(n * n), jitter=False))
            if traced is not None:
                traced = int(stay.sum()), Hits(*(a[stay] for a in centre))
    h, w = rays.shape
    keep = np.ones(len(rays.pixel), dtype=bool) if pixel_mask is None else np.asarray(pixel_mask).reshape(-1)[
        rays.pixel]
    ray_idx = np.flatnonzero(keep)
    if traced is None:
        hits = geometry.first_hit(rays.origins[keep], rays.directions[keep])
    else:
        # The first n_done rays are traced: their kept hits, then the kept rest (the edge pixels' rays) traced.
        n_done, done = traced
        more = n_done + np.flatnonzero(keep[n_done:])
        rest = geometry.first_hit(rays.origins[more], rays.directions[more])
        hits = Hits(*(np.concatenate([a[keep[:n_done]], b]) for a, b in zip(done, rest)))
    constant = constant_image(scene, geometry, rays, ray_idx, hits, n_channels)
    on_obj = np.flatnonzero(hits.obj == OBJECT_TRANSLUCENT)
    q_pos = hits.position[on_obj]
    to_eye = -rays.directions[ray_idx[on_obj]]
    q_normal = face_the_eye(geometry.shading_normals(hits.face[on_obj], q_pos), to_eye)
    q_pixel, q_weight = rays.pixel[ray_idx[on_obj]], rays.weight[ray_idx[on_obj]]
    through = veil = None
    if plan.see_through:
        # eta = 1: the camera's rays run straight on through thin walls (see_through).
        parent, chord, more = see_through(geometry, q_pos, q_normal, to_eye)
        if len(parent):
            veil = np.zeros(len(q_pos) + len(parent))
            veil[parent] = chord
            through = np.concatenate([np.zeros(len(q_pos)), more.through])
            q_pos, q_normal, to_eye = (np.concatenate([a, b]) for a, b in
                                       ((q_pos, more.pos), (q_normal, more.normal), (to_eye, more.to_eye)))
            q_pixel, q_weight = np.concatenate([q_pixel, q_pixel[more.root]]), np.concatenate(
                [q_weight, q_weight[more.root]])
    mirrored = None
    if plan.self_mirror:
        # A smooth dielectric boundary mirrors the object's other parts (the teapot's body shows its spout).
        parent, more = seen_in_mirror(geometry, q_pos, q_normal, to_eye)
        if len(parent):
            cos_parent = np.einsum("ij,ij->i", q_normal[parent], to_eye[parent])
            mirrored = np.concatenate([np.zeros(len(q_pos)), np.clip(cos_parent, 1e-6, 1.0)])
            q_pos, q_normal, to_eye = (np.concatenate([a, b]) for a, b in
                                       ((q_pos, more[0]), (q_normal, more[1]), (to_eye, more[2])))
            q_pixel, q_weight = np.concatenate([q_pixel, q_pixel[parent]]), np.concatenate([q_weight, q_weight[parent]])
            through, veil = (None if a is None else np.concatenate([a, np.zeros(len(parent))]) for a in (through, veil))
    q_light = None
    if plan.single_scattering or plan.specular:
        q_light = light_field(scene.lights, q_pos, q_normal, geometry if plan.shadows else None)
    march = None
    if plan.first_order:
        from jaxsss.render.first_order import first_order_paths

        march = first_order_paths(scene, geometry, q_pos, q_normal, to_eye, n_channels, seed=scene.render.seed)
    return ShadingPoints(q_pos, q_normal, to_eye, q_pixel, q_light, constant, (h, w), rays.spp, len(rays.pixel),
                         q_weight, march, through, veil, mirrored)


def mirror_direction(normal: np.ndarray, to_eye: np.ndarray) -> np.ndarray:
    """``(Q, 3)`` unit mirror directions of unit ``to_eye`` about unit ``normal`` (both ``(Q, 3)``)."""
    # Mirror direction: r = 2 (n . v) n - v.
    r = 2.0 * np.einsum("ij,ij->i", normal, to_eye)[:, None] * normal - to_eye
    return r / np.maximum(np.linalg.norm(r, axis=1, keepdims=True), 1e-300)


def seen_in_mirror(geometry, pos: np.ndarray, normal: np.ndarray, to_eye: np.ndarray):
    """The object's own parts seen in its smooth boundary: the points where the shaded points' mirror rays ``r = 2
    (n . v) n - v`` meet the translucent object first.

    The mirror image of the lights (:func:`jaxsss.render.mirror.mirror_radiance`) stops where a mirror ray meets the
    scene. On a non-convex object it meets the object itself: the teapot's body mirrors its spout and handle, its lid
    the knob, and a path tracer shows there ``F(eta, cos_o)`` times the radiance of the part it meets (against Mitsuba
    under a sky at ``eta`` 1.33-1.4: 0.8% of the teapot's light, 2.5% of its handle's and 4-5% of its lid's;
    docs/path_tracer.md, "The object in its own mirror"). Each such point is shaded like a camera's hit, seen along
    ``-r``; its own mirror rays are not followed further.

    Args:
        geometry: the scene's :class:`~jaxsss.render.rays.SceneGeometry` (translucent mesh first).
        pos, normal, to_eye: ``(Q, 3)`` the shaded points (mm), their normals facing the eye, unit directions to it.

    Returns:
        ``(parent, (pos, normal, to_eye))``: ``parent`` ``(M,)`` the index of the mirroring point of each added one,
        and the added points' positions (mm), normals facing ``-r`` and directions to the mirror ``-r``, ``(M, 3)``.
    """
    pos, normal, to_eye = (np.asarray(a, dtype=np.float64) for a in (pos, normal, to_eye))
    r = mirror_direction(normal, to_eye)
    hits = geometry.first_hit(pos + geometry.offset * normal, r)
    parent = np.flatnonzero(hits.hit & (hits.obj == OBJECT_TRANSLUCENT))
    new_pos = hits.position[parent]
    new_eye = -r[parent]
    new_normal = face_the_eye(geometry.shading_normals(hits.face[parent], new_pos), new_eye)
    return parent, (new_pos, new_normal, new_eye)


VIEW_REENTRIES = 2
"""How many times :func:`see_through` follows a camera ray back into the object."""


class SeenThrough(NamedTuple):
    """The points :func:`see_through` adds behind thin walls (``M`` of them)."""

    pos: np.ndarray  # (M, 3) mm: where the camera's ray enters the object again
    normal: np.ndarray  # (M, 3) unit, facing the eye
    to_eye: np.ndarray  # (M, 3) unit: the ray's, reversed
    through: np.ndarray  # (M,) mm: the object's chords in front of the point along the ray, summed
    root: np.ndarray  # (M,) index of the first hit (of the given points) on the same ray


def see_through(geometry, pos: np.ndarray, normal: np.ndarray, to_eye: np.ndarray,
                reentries: int = VIEW_REENTRIES) -> tuple[np.ndarray, np.ndarray, SeenThrough]:
    """Follow camera rays on through the object where the boundary does not bend them (``eta = 1``).

    Past its first hit a ray runs inside for a chord ``c`` and leaves. Where it then meets the object again (a thin
    wall in front of more of it: the teapot's rim before its lid, 1.3 mm thick where ketchup's red travels 4 mm
    between interactions), the path tracer sees the part behind through the wall, attenuated by ``exp(-sigma_t
    c)``, and the wall's own diffuse light only from its chord: with a uniform source along it, ``1 - exp(-sigma_t
    c)`` of a deep wall's (:meth:`ShadedPoints.radiance_from_diffusion`; a marched first order is marched along the
    chord as it is; ``sigma_t'`` stands for ``sigma_t`` where ``g > 0``, forward scattering's similarity). Rendered
    as one point, the teapot's rim row was 0.3-0.8 of Mitsuba's in every channel. A ray that leaves towards anything
    else (the background, an occluder) is left as it was: the exit's curvature model
    (:mod:`jaxsss.render.exit_curvature`) already holds the short chords of a convex object's limb. The scene plan
    turns it on at ``eta = 1`` with the white kernels and a non-convex mesh (its ``see-through`` line).

    Args:
        geometry: the scene's :class:`~jaxsss.render.rays.SceneGeometry` (translucent mesh first).
        pos, normal, to_eye: ``(Q, 3)`` the first hits (mm), their normals facing the eye, unit directions to it.
        reentries: how many times a ray is followed back in (:data:`VIEW_REENTRIES`).

    Returns:
        ``(parent, chord, more)``: ``parent`` ``(M,)`` the index, among the given points and then ``more``'s, of the
        point in front of each added one, ``chord`` ``(M,)`` mm its chord inside, and ``more`` the added points
        (:class:`SeenThrough`).
    """
    parents, chords, parts = [], [], []
    n = len(pos)
    at = np.arange(n)  # the current points' indices among the given points and the added ones
    root, through = np.arange(n), np.zeros(n)
    cur_pos, cur_normal, cur_eye = (np.asarray(a, dtype=np.float64) for a in (pos, normal, to_eye))
    for _ in range(reentries):
        if not len(at):
            break
        inward = -cur_eye
        out = geometry.first_hit(cur_pos - geometry.offset * cur_normal, inward)
        inside = out.hit & (out.obj == OBJECT_TRANSLUCENT)
        chord = np.where(inside, out.t + geometry.offset, 0.0)
        left = np.flatnonzero(inside)
        on = geometry.first_hit(out.position[left] + geometry.offset * inward[left], inward[left])
        again = on.hit & (on.obj == OBJECT_TRANSLUCENT)
        back = left[again]
        if not len(back):
            break
        new_pos = on.position[again]
        new_eye = cur_eye[back]
        new_normal = face_the_eye(geometry.shading_normals(on.face[again], new_pos), new_eye)
        new_through = through[back] + chord[back]
        parents.append(at[back])
        chords.append(chord[back])
        parts.append(SeenThrough(new_pos, new_normal, new_eye, new_through, root[back]))
        start = n + sum(len(p.pos) for p in parts[:-1])
        at, root, through = start + np.arange(len(back)), root[back], new_through
        cur_pos, cur_normal, cur_eye = new_pos, new_normal, new_eye
    if not parts:
        empty = np.zeros((0, 3))
        return (np.zeros(0, dtype=np.int64), np.zeros(0),
                SeenThrough(empty, empty, empty, np.zeros(0), np.zeros(0, dtype=np.int64)))
    more = SeenThrough(*(np.concatenate(a) for a in zip(*parts)))
    return np.concatenate(parents), np.concatenate(chords), more


def point_shading(points, n_channels: int, owner: str = "prepare") -> ShadingPoints:
    """Shading state for given surface points instead of the camera's (validation against Monte Carlo): one "pixel"
    per point, viewed along its normal, nothing else in the image; ``points`` is ``(positions (Q, 3) mm, outward
    normals (Q, 3))``."""
    pos, normal = (np.asarray(a, dtype=np.float64) for a in points)
    if pos.ndim != 2 or pos.shape[1] != 3 or normal.shape != pos.shape:
        raise ValueError(f"{owner}(points=...) needs two (Q, 3) arrays; got {pos.shape} and {normal.shape}")
    normal = normal / np.linalg.norm(normal, axis=1, keepdims=True)
    q = len(pos)
    return ShadingPoints(pos, normal, normal, np.arange(q), None, np.zeros((q, n_channels)), (1, q), 1, q, np.ones(q))


class ShadedPoints(eqx.Module):
    """The shaded points of an image and the material-free rest of it, as JAX arrays: what turns an exitance
    ``(Q, C)`` into the image. Every diffusion method's state extends it."""

    query_pos: jax.Array  # (Q, 3)
    query_normal: jax.Array  # (Q, 3)
    to_eye: jax.Array  # (Q, 3)
    query_to_light: jax.Array | None  # (Q, L, 3) (single scattering and specular only)
    query_irradiance: jax.Array | None  # (Q, L, C)
    query_pixel: jax.Array  # (Q,) flat pixel index
    query_weight: jax.Array  # (Q,) each point's weight in its pixel's mean
    # (Q, H - 1) the light's azimuth to the view, cos(m phi) (white kernels with g > 0 at eta = 1), or None
    exit_azimuth: jax.Array | None
    constant: jax.Array  # (H * W, C): background and occluders, already weighted
    # The first order marched in the object's geometry (jaxsss.render.first_order.FirstOrderPaths), or None
    first_order: Any
    shape: tuple = eqx.field(static=True)  # (H, W)
    spp: int = eqx.field(static=True)
    single_scattering: bool = eqx.field(static=True)
    specular_roughness: float | None = eqx.field(static=True)
    # (Q,) mm: the object's chord in front of each point along its camera ray (see_through), or None (all 0)
    query_through: jax.Array | None = eqx.field(default=None, kw_only=True)
    # (Q,) mm: the view's chord inside where more of the object is seen through it (see_through; 0: none), or None
    query_veil: jax.Array | None = eqx.field(default=None, kw_only=True)
    # (Q,) the cosine to the eye at the boundary that mirrors each point (seen_in_mirror; 0: seen directly), or None
    query_mirrored: jax.Array | None = eqx.field(default=None, kw_only=True)

    @property
    def n_queries(self) -> int:
        return self.query_pos.shape[0]

    @property
    def cos_o(self):
        """``(Q,)``: the cosine between each shaded point's normal and the direction to the eye (clipped to [0, 1])."""
        return jnp.clip(jnp.sum(self.query_normal * self.to_eye, axis=-1), 0.0, 1.0)

    @property
    def view_tangent(self):
        """``(Q, 3)``: the unit tangential part of the direction to the eye at each shaded point (0 along the
        normal; the exit's current, :mod:`jaxsss.render.exit_current`)."""
        from jaxsss.render.exit_current import tangential_unit

        return tangential_unit(self.to_eye, self.query_normal)

    def radiance_from_exitance(self, medium: Medium, exitance, exit_nodes=None):
        """Radiance towards the eye at the shaded points, ``(Q, C)`` W/(mm^2 sr): diffusion plus the optional
        single-scattering and specular terms.

        ``exitance`` is ``(Q, C)``, or ``(Q, K, C)`` per incidence node of a white kernel with ``exit_nodes = (mus,
        model)`` (:func:`jaxsss.render.bssrdf.exit_radiance_nodes`)."""
        if exit_nodes is None:
            out = rad.exit_radiance(medium, exitance, self.cos_o)
        else:
            out = exit_radiance_nodes(medium, exitance, self.cos_o, *exit_nodes, azimuth=self.exit_azimuth,
                                      view_tangent=self.view_tangent)
        return self.radiance_from_diffusion(medium, out)

    def radiance_from_diffusion(self, medium: Medium, diffusion):
        """Radiance towards the eye at the shaded points, ``(Q, C)`` W/(mm^2 sr): the diffusion radiance
        ``diffusion`` ``(Q, C)`` plus the optional first-order, single-scattering and specular terms."""
        if self.query_veil is not None:
            # A thin wall's diffuse light from its chord c only (see_through): 1 - exp(-sigma_t' c) of a deep one's.
            c = self.query_veil[:, None]
            veiled = c > 0.0
            wall = -jnp.expm1(-medium.sigma_t_prime * jnp.where(veiled, c, 1.0))
            diffusion = jnp.where(veiled, wall, 1.0) * diffusion
        out = diffusion
        if self.first_order is not None:
            from jaxsss.render.first_order import first_order_radiance

            out = out + first_order_radiance(medium, self.first_order)
        if self.single_scattering:
            out = out + rad.single_scattering(medium, self.query_normal, self.to_eye, self.query_to_light,
                                              self.query_irradiance)
        if self.specular_roughness is not None:
            out = out + rad.specular_ggx(medium, self.query_normal, self.to_eye, self.query_to_light,
                                         self.query_irradiance, self.specular_roughness)
        reflected = self.boundary_reflection(medium)
        return self.seen_through(medium, out if reflected is None else out + reflected)

    def boundary_reflection(self, medium: Medium):
        """``(Q, C)`` radiance the smooth boundary reflects towards the eye beyond the lights' highlights, or None
        (here: none; :class:`jaxsss.render.mirror.ReflectingPoints` adds the mirror image of extended lights)."""

    def seen_through(self, medium: Medium, radiance):
        """``radiance`` ``(Q, C)`` at the shaded points as the eye receives it: attenuated by ``exp(-sigma_t' c)``
        over the object's chords in front of the points seen through thin walls (:func:`see_through`), and by the
        Fresnel reflectance ``F(eta, cos_o)`` of the boundary that mirrors points seen in it
        (:func:`seen_in_mirror`)."""
        if self.query_through is not None:
            # L_eye = exp(-sigma_t' c_front) L.
            radiance = jnp.exp(-medium.sigma_t_prime * self.query_through[:, None]) * radiance
        if self.query_mirrored is not None:
            from jaxsss.fresnel import fresnel_unpolarised

            cos_m = self.query_mirrored
            mirrored = cos_m > 0.0
            # Reflection at a smooth dielectric: L_eye = F_r(eta, cos_o) L(r).
            f = fresnel_unpolarised(jnp.where(mirrored, cos_m, 1.0), medium.eta)
            radiance = jnp.where(mirrored, f, 1.0)[:, None] * radiance
        return radiance

    def image_from_radiance(self, radiance):
        """``(H, W, C)`` linear image: the mean over each pixel's rays plus the constant part."""
        h, w = self.shape
        img = jax.ops.segment_sum(radiance * self.query_weight[:, None], self.query_pixel, num_segments=h * w)
        return (img + self.constant).reshape(h, w, -1)


def shaded_fields(scene, plan, shading: ShadingPoints) -> dict[str, Any]:
    """The :class:`ShadedPoints` fields of ``shading`` as JAX arrays (keyword arguments for any method's state)."""
    light = shading.light
    return {
        "query_pos": to_device(shading.pos),
        "query_normal": to_device(shading.normal),
        "to_eye": to_device(shading.to_eye),
        "query_to_light": None if light is None else to_device(light.to_light),
        "query_irradiance": None if light is None else to_device(light.irradiance),
        "query_pixel": to_device(shading.pixel),
        "query_weight": to_device(shading.weight),
        "exit_azimuth": exit_azimuth(scene, plan, shading),
        "constant": to_device(shading.constant),
        "first_order": shading.first_order,
        "query_through": None if shading.through is None else to_device(shading.through),
        "query_veil": None if shading.veil is None else to_device(shading.veil),
        "query_mirrored": None if shading.mirrored is None else to_device(shading.mirrored),
        "shape": shading.shape,
        "spp": shading.spp,
        "single_scattering": plan.single_scattering,
        "specular_roughness": scene.material.specular_roughness if plan.specular else None,
    }


def exit_azimuth(scene, plan, shading: ShadingPoints):
    """``(Q, H - 1)`` :func:`jaxsss.render.exit_direction.azimuth_harmonics` at the shaded points when the plan's
    white kernel exits through the anisotropic model (``g > 0``, ``eta = 1``), else None."""
    if plan.bssrdf == "dipole" or exit_model_for(scene.material.medium) != "anisotropic":
        return None
    return to_device(azimuth_harmonics(scene.lights, shading.pos, shading.normal, shading.to_eye))


def image_stats(image: np.ndarray) -> dict[str, Any]:
    """The report's summary of a linear ``(H, W, C)`` image: per-channel min, max and mean, and whether it is
    finite."""
    return {
        "min": image.min(axis=(0, 1)).tolist(),
        "max": image.max(axis=(0, 1)).tolist(),
        "mean": image.mean(axis=(0, 1)).tolist(),
        "finite": bool(np.isfinite(image).all()),
    }
