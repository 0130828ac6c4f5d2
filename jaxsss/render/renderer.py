"""The hierarchical and direct methods: geometry once in NumPy, then ``image = prepared.image(medium)``, a JAX
function of the material.

:func:`prepare` runs everything that depends only on geometry and lights -- pass 1 (irradiance samples), camera rays
and the lighting at the shaded points (:mod:`jaxsss.render.shading`), the octree and the interaction lists
(:mod:`jaxsss.render.pairs`) -- and returns a :class:`Prepared` (an ``equinox.Module`` of arrays).
:meth:`Prepared.image` is pass 2 plus radiance: jitted, differentiable in the medium, and summed block by block so
memory stays bounded. The methods ``hierarchical`` and ``direct`` are registered here
(:mod:`jaxsss.render.methods`); :func:`jaxsss.render.render` is the driver that times and reports them.
"""

from __future__ import annotations

import dataclasses
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from jaxsss._config import render_jit, to_device
from jaxsss.medium import Medium
from jaxsss.render import radiance as rad
from jaxsss.render.bssrdf import (CURRENT_EXITS, LIGHTS_BEHIND_MUS, albedo_correction, current_radiance, exit_model_for,
                                  exit_weights, incident_flux, shift_reach, surface_tangents, white_kernel,
                                  white_tables)
from jaxsss.render.passage import PASSAGE_FLOOR, cut_matters, interaction_probability, truncated_travel, view_chords
from jaxsss.render.camera import camera_frame
from jaxsss.render.first_order import diffuse_first_order_restore, first_order_radiance
from jaxsss.render.lights import light_columns
from jaxsss.render.methods import Preparation, register_method
from jaxsss.render.octree import build_octree
from jaxsss.render.pairs import BLOCK_PAIRS, PairLists, near_radius, pair_info, pair_lists
from jaxsss.render.plan import ScenePlan, make_plan
from jaxsss.render.rays import scene_geometry
from jaxsss.render.mirror import ReflectingPoints, mirror_field
from jaxsss.render.samples import irradiance_samples, lit_positions
from jaxsss.render.shading import ShadingPoints, point_shading, shaded_fields, shading_points

__all__ = ["EXIT_ROWS", "MARCHED_EXITS", "Prepared", "assemble_prepared", "irradiance_pass", "prepare"]

MARCHED_EXITS = ("multiple", "multiple-curved", "multiple-current")
"""The white kernels' exit models with the first order marched apart (the kernel holds the orders >= 2)."""
EXIT_ROWS = {"distance": 2, "multiple-curved": 2, "multiple-current": 5, "refracted-current": 4}
"""The sums' rows per incidence node of each exit model (1 for the others): the exitance, a second exit's part, and
the current's three components (:attr:`jaxsss.render.bssrdf.WhiteKernel.rows_per_node`)."""

class Prepared(ReflectingPoints):
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
    # The BSSRDF kernel (jaxsss.render.bssrdf): its oblique sources (white_tables; None: the dipole).
    bssrdf_tables: tuple | None = None
    light_tangent: jax.Array | None = None  # (N, L, 3) travel direction inside, on the surface (white-oblique)
    # (N, L) mm: each light column's refracted path inside the object (white kernels; jaxsss.render.passage)
    light_chord: jax.Array | None = None
    # (E, 3) unit area-weighted mean normal of each entity (white kernels: the pairs' curvature; None: flat)
    ent_normal: jax.Array | None = None
    # (Q, 4): each shaded point's refracted view ray inside, its chord (mm; 1e9 where it never leaves) and inward
    # tangent (length sin theta_t): the eye's side of the cut beam (white-oblique; None: off)
    view_chord: jax.Array | None = None
    # The cut beam at both ends is on (white-oblique, and only where it matters: jaxsss.render.passage.cut_matters)
    passage_cut: bool = eqx.field(static=True, default=False)
    bssrdf: str = eqx.field(static=True, default="dipole")
    bssrdf_mus: tuple = eqx.field(static=True, default=(1.0,))
    bssrdf_exit: str = eqx.field(static=True, default="fresnel")
    # (N, C) W/mm^2: the object's own lit surface seen from each sample (jaxsss.render.samples.self_irradiance), or None
    self_indirect: jax.Array | None = None
    # The light columns summed with the exit's current where lights on both sides of the object are summed apart
    # (ScenePlan.current_lights; exit model "multiple-current"); None: every column has this Prepared's exit model
    current_columns: tuple | None = eqx.field(static=True, default=None)

    def indirect_irradiance(self, medium: Medium):
        """``(N, C)`` diffuse indirect irradiance at the samples, W/mm^2, or None: the occluders' bounce plus the
        object's own, ``rho E_self`` with the surface's diffuse albedo ``rho = F_dt,ext Rd`` (Eq. 15's total diffuse
        reflectance of the medium, entered through the boundary's hemispherical transmittance)."""
        if self.self_indirect is None:
            return self.indirect
        # One bounce off the object itself: its exitance is rho times the irradiance it receives (local).
        own = rad.diffuse_albedo(medium) * self.self_indirect
        return own if self.indirect is None else self.indirect + own

    def sample_flux(self, medium: Medium):
        """Flux at each sample, W: ``(N, C)`` entering the medium (dipole), or ``(N, K, C)`` incident per incidence
        node (white kernels; :func:`jaxsss.render.bssrdf.incident_flux`)."""
        indirect = self.indirect_irradiance(medium)
        if self.bssrdf != "dipole":
            irradiance = self.light_irradiance
            travel = None
            chord_rows = None
            if self.light_chord is not None:
                sigma_t_prime = medium.sigma_a + medium.sigma_s_prime
                if self.light_tangent is not None:
                    # The oblique profiles' forward shift, shortened where the chord ends before the half-space's
                    # mean travel (grazing light on a curved or thin part).
                    travel = truncated_travel(self.light_chord, sigma_t_prime)
                if self.passage_cut:
                    # Cut beam: the flux of columns with a finite chord, and times the chord (the kernel's loss).
                    finite = jnp.isfinite(self.light_chord)[..., None]
                    t = jnp.where(finite, self.light_chord[..., None], 0.0)
                    chord_rows = [incident_flux(self.bssrdf_mus, self.areas, self.light_cos,
                                                jnp.where(finite, irradiance, 0.0) * t**p, None, self.texture)
                                  for p in (0, 1)]
                else:
                    # Uncollided passage: only the light that interacts before its chord ends enters the profile
                    # (the "white" kernel, and scenes where the cut beam changes too little to pay for it).
                    g = 0.0 if medium.g is None else medium.g
                    irradiance = irradiance * interaction_probability(
                        self.light_chord, medium.sigma_a + medium.sigma_s_prime / (1.0 - g))
            if self.bssrdf_tables is not None and len(self.bssrdf_mus) > 1:
                # The node mix reflects the exact total at every incidence cosine: Chandrasekhar's index-matched; for
                # g > 0 the HG medium's by adding-doubling, whose curve in mu is not the isotropic equivalent's; behind
                # a dielectric boundary the share the boundary lets in and the half-space sends back, concave in mu
                # (jaxsss.render.anisotropic_albedo). With the first order marched apart the same factor (the orders
                # >= 2's own, A - A_1, measured worse: docs/path_tracer.md, "The first order in the object's
                # geometry").
                albedo = jnp.broadcast_to(medium.alpha_prime, irradiance.shape[-1:])
                g, eta = self.bssrdf_tables.g, self.bssrdf_tables.n
                irradiance = irradiance * albedo_correction(self.light_cos, self.bssrdf_mus, albedo, g, eta)
                if indirect is not None:
                    indirect = indirect * albedo_correction(None, self.bssrdf_mus, albedo, g, eta)
                    if self.bssrdf_exit in MARCHED_EXITS:
                        # Diffuse light is not marched: the orders >= 2 carry its first order's share too.
                        indirect = indirect * diffuse_first_order_restore(albedo)
            flux = incident_flux(self.bssrdf_mus, self.areas, self.light_cos, irradiance, indirect,
                                 self.texture, self.light_tangent, travel)
            if chord_rows is None:
                return flux
            return jnp.concatenate([flux] + [row[:, None] for row in chord_rows], axis=1)
        return rad.transmitted_flux(medium, self.areas, self.light_cos, self.light_irradiance, indirect,
                                    self.texture)

    @property
    def exit_nodes(self):
        """``(mus, exit model)`` of a white kernel, None for the dipole (:meth:`ShadedPoints.radiance_from_exitance`)."""
        return None if self.bssrdf == "dipole" else (self.bssrdf_mus, self.bssrdf_exit)

    def kernel(self, medium: Medium):
        """The sums' kernel for ``medium``: None (the dipole) or a :class:`~jaxsss.render.bssrdf.WhiteKernel`."""
        if self.bssrdf == "dipole":
            return None
        shift = self.light_tangent is not None
        return white_kernel(medium, self.bssrdf_tables, self.bssrdf_mus, shift=shift,
                            curvature=self.ent_normal is not None,
                            passage=PASSAGE_FLOOR * self.rho0 if self.passage_cut else None,
                            exit_split=self.bssrdf_exit == "distance",
                            first_order=self.bssrdf_exit in MARCHED_EXITS,
                            exit_curved=self.bssrdf_exit in ("multiple-curved", "multiple-current"),
                            exit_current=self.bssrdf_exit in CURRENT_EXITS,
                            curvature_transport=(self.bssrdf_exit == "multiple-current"
                                                 and self.ent_normal is not None),
                            oblique_azimuth=(self.bssrdf_exit == "multiple-current" and self.ent_normal is not None
                                             and shift))

    @property
    def normals(self):
        """``(query normals, entity normals)`` for the pairs' curvature, or None (:mod:`jaxsss.render.curvature`)."""
        if self.ent_normal is None:
            return None
        if self.view_chord is None:
            return self.query_normal, self.ent_normal
        return jnp.concatenate([self.query_normal, self.view_chord], axis=1), self.ent_normal

    def exitance(self, medium: Medium, blocks: slice | None = None, weights=None):
        """Radiant exitance ``M_o`` at the shaded points, ``(Q, C)`` W/mm^2 (``(Q, J, C)`` per node row of a white
        kernel; ``blocks``: part of the pair list). With exit ``weights`` ``(Q, J, C)`` (:meth:`exit_weights`), the
        diffusion radiance ``(Q, C)`` W/(mm^2 sr) instead (:meth:`diffusion_radiance`)."""
        if self.current_columns is not None:
            return self._exitance_apart(medium, blocks, weights)
        flux = self.sample_flux(medium)
        kernel = self.kernel(medium)
        if self.method == "direct":
            return rad.exitance_direct(medium, self.query_pos, self.sample_pos, flux, self.areas, self.rho0,
                                       shared_channel=self.shared_channel, kernel=kernel, normals=self.normals,
                                       weights=weights)
        ent_flux = rad.entity_flux(flux, self.ent_start, self.ent_stop)
        pq, pe = self.pair_query, self.pair_entity
        if blocks is not None:
            pq, pe = pq[blocks], pe[blocks]
        far = rad.exitance_pairs(medium, self.query_pos, self.ent_pos, ent_flux, pq, pe,
                                 shared_channel=self.shared_channel, kernel=kernel, normals=self.normals,
                                 weights=weights)
        return far + self.exitance_near(medium, flux, kernel, weights)

    def light_sides(self):
        """``(behind, front)``: this ``Prepared`` with only the light columns behind the object (exit model
        ``"multiple-current"``) and with only the others (``"multiple-curved"``, with the indirect light), where the
        plan sums lights on both sides apart (:attr:`current_columns`)."""
        behind = np.asarray(self.current_columns, dtype=int)
        front = np.setdiff1d(np.arange(self.light_cos.shape[1]), behind)

        def side(cols, exit_model, indirect):
            def take(a):
                return None if a is None else a[:, cols]

            return dataclasses.replace(
                self, light_cos=take(self.light_cos), light_irradiance=take(self.light_irradiance),
                light_tangent=take(self.light_tangent), light_chord=take(self.light_chord), bssrdf_exit=exit_model,
                current_columns=None, indirect=self.indirect if indirect else None,
                self_indirect=self.self_indirect if indirect else None)

        return side(behind, "multiple-current", False), side(front, "multiple-curved", True)

    def _exitance_apart(self, medium: Medium, blocks, weights):
        """:meth:`exitance` with lights on both sides of the object: the lights behind summed with the exit's current
        and the far field's correction, the others without (that kernel's rows are the first ``2K`` of the current's,
        whose current rows get nothing from them), in two sums (:attr:`current_columns`)."""
        behind, front = self.light_sides()
        n = len(self.bssrdf_mus) * EXIT_ROWS["multiple-curved"]
        out = behind.exitance(medium, blocks, weights)
        rest = front.exitance(medium, blocks, None if weights is None else weights[:, :n])
        return out.at[:, :n].add(rest) if weights is None else out.at[:, 0].add(rest)

    def exit_weights(self, medium: Medium):
        """``(Q, J, C)``: the radiance towards the eye per unit exitance of each node row of the white kernel at the
        shaded points (:func:`jaxsss.render.bssrdf.exit_weights`), or None for the dipole."""
        if self.exit_nodes is None:
            return None
        n_nodes = len(self.bssrdf_mus) * EXIT_ROWS.get(self.bssrdf_exit, 1)
        n_channels = jnp.broadcast_shapes(self.light_irradiance.shape[-1:], jnp.shape(medium.sigma_a)[-1:])[0]
        return exit_weights(medium, self.cos_o, *self.exit_nodes, n_nodes, n_channels, self.exit_azimuth,
                            self.view_tangent)

    def diffusion_radiance(self, medium: Medium):
        """The diffusion radiance towards the eye at the shaded points, ``(Q, C)`` W/(mm^2 sr). A white kernel's
        sums add each pair's nodes as radiance by the shaded point's exit weights (:meth:`exit_weights`): the same
        as :meth:`exitance` then :func:`jaxsss.render.bssrdf.exit_radiance_nodes`, with one value per pair instead of
        ``J`` (skin1's image took 1.7x as long with the nodes kept apart, docs/benchmarks.md)."""
        weights = self.exit_weights(medium)
        if weights is None:
            return rad.exit_radiance(medium, self.exitance(medium), self.cos_o)
        out = self.exitance(medium, weights=weights)
        if self.bssrdf_exit in CURRENT_EXITS:
            # The sums keep the exitance's part and the current's apart, (Q, 2, C): at eta = 1 the current is kept
            # along the flow only (its sign per shaded point: jaxsss.render.bssrdf.current_radiance).
            return current_radiance(out[:, 0], out[:, 1], along_only=self.bssrdf_exit == "multiple-current")
        return out

    def exitance_gradient(self, medium: Medium, *, near: bool = True):
        """Analytic gradient of ``M_o`` with respect to the shaded point's position, ``(Q, 3, C)`` W/mm^3 (caching
        paper Eq. 9 through the same interaction list; hierarchical method only).

        ``near=False`` leaves out the near-field disc term (within ``rho0`` of the point): the far-field part alone,
        which the cached method interpolates with (:mod:`jaxsss.render.cache`, "Which gradient"). The analytic
        gradient is the dipole's: a white kernel takes :meth:`exitance_gradient_autodiff` (near and far)."""
        if self.bssrdf != "dipole":
            return self.exitance_gradient_autodiff(medium)
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

    def exitance_near(self, medium: Medium, flux, kernel=None, weights=None):
        """The near-field disc part of ``M_o`` (hierarchical method), ``(Q, C)`` (radiance with exit ``weights``, as
        :meth:`exitance`)."""
        return rad.exitance_near(medium, self.query_pos, self.sample_pos, self.areas, flux, self.near_query,
                                 self.near_sample, self.rho0, shared_channel=self.shared_channel, kernel=kernel,
                                 normals=self.normals, weights=weights)

    def image(self, medium: Medium):
        """The linear radiance image ``(H, W, C)`` as a JAX function of the medium (differentiable; jitted, with
        this ``Prepared``'s arrays as arguments, so a second call with the same shapes does not recompile)."""
        return _image(self, medium)

    def first_order_image(self, medium: Medium):
        """The first scattering order marched in the object (:mod:`jaxsss.render.first_order`) alone, plus the
        constant image (background and occluders), ``(H, W, C)``; ``None`` when the plan did not march it
        (:attr:`jaxsss.render.plan.ScenePlan.first_order`). Its path-traced counterpart is Mitsuba at ``max_depth =
        2`` (:func:`jaxsss.export.mitsuba.render_mitsuba`)."""
        if self.first_order is None:
            return None
        return _first_order_image(self, medium)



def irradiance_pass(scene, plan: ScenePlan):
    """``(geometry, samples, tree, octree_seconds)``: the ray-casting scene, pass-1 irradiance samples and their
    octree (centroids weighted by the channel-mean direct plus indirect flux)."""
    geometry = scene_geometry(scene.mesh, [o.mesh for o in scene.occluders])
    samples = irradiance_samples(scene, geometry, plan.n_samples, shadows=plan.shadows, indirect=plan.indirect,
                                 seed=scene.render.seed, chords=plan.bssrdf != "dipole", self_bounce=plan.self_bounce)
    t0 = time.perf_counter()
    weight = samples.areas * samples.light.irradiance.sum(axis=1).mean(axis=-1)
    if samples.indirect is not None:
        weight = weight + samples.areas * samples.indirect.mean(axis=-1)
    tree = build_octree(samples.positions, samples.areas, weight)
    return geometry, samples, tree, time.perf_counter() - t0


def entity_normals(weighted_normals: np.ndarray, tree) -> np.ndarray:
    """``(E, 3)`` unit mean normal of every octree entity (samples, then nodes) from the samples' area-weighted
    normals ``(N, 3)`` in octree order (a node: the sum over its range of samples, normalised)."""
    n = len(weighted_normals)
    cs = np.concatenate([np.zeros((1, 3)), np.cumsum(weighted_normals, axis=0)])
    out = np.concatenate([weighted_normals, cs[tree.stop[n:]] - cs[tree.start[n:]]])
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return out / np.where(norm > 0, norm, 1.0)


def assemble_prepared(scene, plan: ScenePlan, samples, tree, shading: ShadingPoints, pairs: PairLists | None,
                      geometry=None, mirror: bool = True) -> Prepared:
    """The :class:`Prepared` state from pass 1 (``samples``, ``tree``), the shaded points and their pair lists
    (``None``: no lists, for radiance and image assembly only). ``mirror``: add the mirror image of area and
    environment lights when the boundary is smooth (``geometry`` shadows it; built here when ``None``)."""
    reflect = mirror_field(scene, shading, geometry) if mirror else None
    order = tree.order
    pairs = pairs or PairLists(None, None, None, None, near_radius(samples), np.zeros(0, int), 0)
    mus, tables, exit_model, tangent, ent_normal, view_chord = (1.0,), None, "fresnel", None, None, None
    passage_cut = False
    current_columns = None
    if plan.bssrdf != "dipole":
        ent_normal = to_device(entity_normals(samples.normals[order] * samples.areas[order, None], tree))
        medium = scene.material.medium
        # Lights behind an index-matched object: a third oblique node (their light crosses it; LIGHTS_BEHIND_MUS).
        behind = plan.exit_current and float(medium.eta) == 1.0 and shading.first_order is not None
        mus, tables = white_tables(0.0 if medium.g is None else float(medium.g), float(medium.eta),
                                   oblique=plan.bssrdf == "white-oblique", mus=LIGHTS_BEHIND_MUS if behind else None)
        # The first order marched in the geometry (plan.first_order): the profiles keep orders >= 2 and leave by
        # their own exit distribution, less grazing on a curved surface (jaxsss.render.exit_curvature), and brighter
        # along the light's flow where the plan keeps the current (jaxsss.render.exit_current).
        exit_model = (("multiple-current" if plan.exit_current else "multiple-curved")
                      if shading.first_order is not None else exit_model_for(medium))
        if exit_model == "refracted" and plan.exit_current:
            # Behind a dielectric boundary: every order, with the exit's current of every light.
            exit_model = "refracted-current"
        if exit_model == "multiple-current" and not all(plan.current_lights):
            # Lights on both sides of the object: those behind are summed with the current, the others apart.
            columns = np.repeat(plan.current_lights, [light_columns(light) for light in scene.lights])
            current_columns = tuple(int(c) for c in np.flatnonzero(columns))
        if plan.bssrdf == "white-oblique":
            tangent = to_device(surface_tangents(samples.light.to_light[order], samples.normals[order],
                                                 float(medium.eta)))
            view = None
            if mirror:  # camera rays (not the validation's free points, nor the cached method's cache points)
                geometry = geometry or scene_geometry(scene.mesh, [o.mesh for o in scene.occluders])
                view = view_chords(geometry, shading, float(medium.eta))
            passage_cut = samples.chord is not None and cut_matters(medium, samples, view)
            view_chord = to_device(view) if passage_cut and view is not None else None
    return Prepared(
        **shaded_fields(scene, plan, shading),
        sample_pos=to_device(samples.positions[order]),
        areas=to_device(samples.areas[order]),
        light_cos=to_device(samples.light.cos[order]),
        light_irradiance=to_device(samples.light.irradiance[order]),
        indirect=to_device(None if samples.indirect is None else samples.indirect[order]),
        texture=to_device(None if samples.texture is None else samples.texture[order]),
        ent_pos=to_device(tree.centroid),
        ent_start=to_device(tree.start),
        ent_stop=to_device(tree.stop),
        pair_query=pairs.far_query,
        pair_entity=pairs.far_entity,
        near_query=to_device(pairs.near_query),
        near_sample=to_device(pairs.near_sample),
        rho0=to_device(pairs.rho0),
        method=plan.method,
        shared_channel=plan.shared_channel,
        mirror=reflect,
        bssrdf_tables=tables,
        light_tangent=tangent,
        light_chord=to_device(None if samples.chord is None else samples.chord[order]),  # traced for white kernels only
        ent_normal=ent_normal,
        view_chord=view_chord,
        passage_cut=passage_cut,
        bssrdf=plan.bssrdf,
        bssrdf_mus=tuple(mus),
        bssrdf_exit=exit_model,
        self_indirect=to_device(None if samples.self_indirect is None else samples.self_indirect[order]),
        current_columns=current_columns,
    )


def prepare(scene, *, method: str | None = None, eps: float | None = None, resolution=None,
            plan: ScenePlan | None = None, progress: bool = False, pixel_mask: np.ndarray | None = None,
            cutoff: bool = True, share_channels: bool = True, block_pairs: int = BLOCK_PAIRS, points=None,
            bssrdf: str = "auto"):
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
        bssrdf: the profile kernel, one of :data:`jaxsss.render.bssrdf.BSSRDFS` (``"auto"``: the plan picks the
            most accurate one with tables for the material).

    Returns:
        ``(prepared, plan, info)`` where ``info`` holds timings (s) and counts.
    """
    t_all = time.perf_counter()
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    plan = plan or make_plan(scene, method=method, eps=eps, cutoff=cutoff, share_channels=share_channels,
                             bssrdf=bssrdf)
    timings["plan"] = time.perf_counter() - t0
    bar = tqdm(total=3, desc="render: geometry", disable=not progress, leave=False)

    # Pass 1: irradiance samples and their octree.
    t0 = time.perf_counter()
    geometry, samples, tree, timings["octree"] = irradiance_pass(scene, plan)
    timings["pass1_irradiance"] = time.perf_counter() - t0 - timings["octree"]
    bar.set_postfix_str(f"{samples.n} samples")
    bar.update()

    # Camera rays and lighting at the shaded points.
    t0 = time.perf_counter()
    if points is None:
        shading = shading_points(scene, geometry, plan, resolution, pixel_mask, samples.light.irradiance.shape[-1],
                                 lit=lit_positions(samples))
    else:
        shading = point_shading(points, samples.light.irradiance.shape[-1])
        plan = plan._replace(single_scattering=False, specular=False)
    timings["camera_rays"] = time.perf_counter() - t0
    bar.set_postfix_str(f"{len(shading.pos)} shaded points")
    bar.update()

    t0 = time.perf_counter()
    pairs = pair_lists(tree, samples, shading.pos, plan, progress=progress, block_pairs=block_pairs,
                       near_margin=shift_reach(scene.material.medium, plan.bssrdf))
    timings["interactions"] = time.perf_counter() - t0
    bar.update()
    bar.close()

    prepared = assemble_prepared(scene, plan, samples, tree, shading, pairs, geometry, mirror=points is None)
    info = {
        "timings": timings,
        "seconds_geometry": time.perf_counter() - t_all,
        "n_samples": int(samples.n),
        "n_shaded_points": len(shading.pos),
        "n_pixels": int(shading.shape[0] * shading.shape[1]),
        "n_rays": shading.n_rays,
        "n_octree_entities": len(tree.start),
        **pair_info(pairs, len(shading.pos)),
        "camera_forward": camera_frame(scene.camera)[0].tolist(),
    }
    return prepared, plan, info



@render_jit
def _image(prepared: Prepared, medium: Medium):
    return prepared.image_from_radiance(prepared.radiance_from_diffusion(medium, prepared.diffusion_radiance(medium)))


@render_jit
def _first_order_image(prepared: Prepared, medium: Medium):
    radiance = first_order_radiance(medium, prepared.first_order)
    return prepared.image_from_radiance(prepared.seen_through(medium, radiance))


def _registered(method: str):
    def prepare_registered(scene, *, resolution=None, pixel_mask=None, fit=False, progress=False, eps=None,
                           bssrdf="auto"):
        prepared, plan, info = prepare(scene, method=method, eps=eps, resolution=resolution, progress=progress,
                                       pixel_mask=pixel_mask, cutoff=not fit, share_channels=not fit, bssrdf=bssrdf)
        timings = info.pop("timings")
        info.pop("seconds_geometry")
        return Preparation(method, prepared, plan, {"eps": plan.eps, **info}, timings)

    return prepare_registered


def _explain(method: str):
    def explain(scene, *, resolution=None, eps=None, bssrdf="auto"):
        return make_plan(scene, method=method, eps=eps, bssrdf=bssrdf)

    return explain


register_method("hierarchical", _registered("hierarchical"),
                "the hierarchical dipole sum over an octree of irradiance samples (Jensen and Buhler 2002)",
                options=("eps", "bssrdf"), explain=_explain("hierarchical"))
register_method("direct", _registered("direct"), "the direct O(pixels x samples) dipole sum (the reference)",
                options=("eps", "bssrdf"), explain=_explain("direct"))
