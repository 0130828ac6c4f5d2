"""The mirror image of area and environment lights in a smooth boundary.

Delta lights (point, spot, directional) have no visible mirror image (the image of a point is a point), so the
renderer never needed one; area and environment lights do. :func:`mirror_radiance` finds, in NumPy, the radiance of
the extended lights seen along each shaded point's mirror direction ``r = 2 (n . v) n - v`` (shadowed by the scene),
and :func:`mirror_reflection` multiplies it by the exact Fresnel reflectance ``F(eta, cos_o)`` in JAX, so an image
stays differentiable in eta. :class:`ReflectingPoints` is the shaded-points state that adds it to the radiance; the
hierarchical, direct and cached states extend it. Occluders seen in the mirror add nothing (their reflection is not
modelled); the object's own parts seen in it are shaded as points of their own where the scene plan says so
(:func:`jaxsss.render.shading.seen_in_mirror`); a rough boundary (``specular_roughness``) uses the GGX term instead.

Checked against Mitsuba: the reflection off a smooth dielectric sphere (eta 1.4) under the ``skin1_sphere_env`` sky
is within 1.5% of Mitsuba's (``docs/benchmarks.md``).
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import numpy as np

from jaxsss._config import to_device
from jaxsss.medium import Medium
from jaxsss.render.lights import EXTENDED_KINDS, light_channels
from jaxsss.render.shading import ShadedPoints, mirror_direction

__all__ = ["ReflectingPoints", "mirror_field", "mirror_radiance", "mirror_reflection"]


class ReflectingPoints(ShadedPoints):
    """:class:`~jaxsss.render.shading.ShadedPoints` plus the mirror image of the extended lights (``mirror``
    ``(Q, C)`` from :func:`mirror_radiance`, or ``None``)."""

    mirror: jax.Array | None = eqx.field(default=None, kw_only=True)

    def boundary_reflection(self, medium: Medium):
        """:func:`mirror_reflection` where the state holds a mirror image, else None (added to the radiance by
        :meth:`~jaxsss.render.shading.ShadedPoints.radiance_from_diffusion`, before the attenuation of points seen
        through a wall or in the mirror)."""
        if self.mirror is None:
            return None
        return mirror_reflection(medium, self.query_normal, self.to_eye, self.mirror)


def mirror_field(scene, shading, geometry=None):
    """``mirror`` for a :class:`ReflectingPoints` of ``shading`` (a :class:`~jaxsss.render.shading.ShadingPoints`):
    a JAX ``(Q, C)`` array when the scene has area or environment lights and a smooth boundary (no
    ``specular_roughness``), else ``None``. ``geometry`` shadows the mirror rays (built when ``None``)."""
    if scene.material.specular_roughness is not None or not any(
            light.kind in EXTENDED_KINDS for light in scene.lights):
        return None
    if geometry is None:
        from jaxsss.render.rays import scene_geometry

        geometry = scene_geometry(scene.mesh, [o.mesh for o in scene.occluders])
    return to_device(mirror_radiance(scene.lights, shading.pos, shading.normal, shading.to_eye, geometry))


def mirror_radiance(lights: Sequence, points: np.ndarray, normals: np.ndarray, to_eye: np.ndarray,
                    geometry=None) -> np.ndarray | None:
    """Radiance of the area and environment lights seen along each point's mirror direction, ``(Q, C)``
    W/(mm^2 sr), or ``None`` when the scene has no extended light.

    Args:
        points, normals, to_eye: ``(Q, 3)`` shaded points (mm), unit normals facing the eye and unit directions to it.
        geometry: a :class:`~jaxsss.render.rays.SceneGeometry`: a mirror ray that hits the scene first sees nothing
            (``None``: nothing blocks).
    """
    extended = [light for light in lights if light.kind in EXTENDED_KINDS]
    if not extended:
        return None
    points, normals, to_eye = (np.asarray(a, dtype=np.float64) for a in (points, normals, to_eye))
    n_channels = light_channels(lights)
    r = mirror_direction(normals, to_eye)
    blocked_at = np.full(len(points), np.inf)
    if geometry is not None and len(points):
        hits = geometry.first_hit(points + geometry.offset * normals, r)
        blocked_at = np.where(hits.hit, hits.t, np.inf)
    out = np.zeros((len(points), n_channels))
    for light in extended:
        radiance = np.asarray(light.intensity, dtype=np.float64)
        if light.kind == "environment":
            out += np.where(np.isinf(blocked_at)[:, None], light.environment.radiance(r) * radiance, 0.0)
            continue
        if light.kind == "sphere":
            # Ray-sphere: t = b - sqrt(b^2 - c) with b = (c - p) . r, c = |c - p|^2 - R^2 (the near side).
            oc = np.asarray(light.position, dtype=np.float64) - points
            b = np.einsum("ij,ij->i", oc, r)
            disc = b * b - (np.einsum("ij,ij->i", oc, oc) - float(light.radius) ** 2)
            t = b - np.sqrt(np.clip(disc, 0.0, None))
            hit = (disc > 0) & (t > 0)
        else:
            # Ray-plane, then inside the rectangle and on its front side (r . n < 0).
            n = np.asarray(light.direction, dtype=np.float64)
            e_v = np.asarray(light.up, dtype=np.float64)
            e_u = np.cross(e_v, n)
            denom = r @ n
            t = np.einsum("ij,j->i", np.asarray(light.position, dtype=np.float64) - points, n) / np.where(
                denom < 0, denom, -1.0)
            y = points + t[:, None] * r - np.asarray(light.position, dtype=np.float64)
            hit = (denom < 0) & (t > 0) & (np.abs(y @ e_u) <= light.size[0] / 2) & (np.abs(y @ e_v) <= light.size[1] / 2)
        out += np.where((hit & (t < blocked_at))[:, None], radiance, 0.0)
    return out


def mirror_reflection(medium, normal, to_eye, mirror):
    """The mirror image of the extended lights in a smooth boundary, ``(Q, C)`` W/(mm^2 sr): ``F(eta, cos_o) L_m``
    with the exact unpolarised Fresnel reflectance for light arriving from outside (eta = n_inside / n_outside) and
    ``L_m`` from :func:`mirror_radiance` (JAX: differentiable in eta)."""
    import jax.numpy as jnp

    from jaxsss.fresnel import fresnel_unpolarised

    cos_o = jnp.clip(jnp.sum(normal * to_eye, axis=-1), 0.0, 1.0)
    # Reflection at a smooth dielectric: L = F_r(eta, cos_o) L(r).
    return fresnel_unpolarised(cos_o, medium.eta)[:, None] * mirror
