"""The scene plan: which passes and terms a scene needs, decided before rendering, with one line of reason each.

The plan is what ``jaxsss render --explain`` prints and what the JSON report records. Each decision is a
:class:`PlanItem`; the flags the renderer acts on are fields of :class:`ScenePlan`. A scene's ``[render]`` table can
force a term ``"on"`` or ``"off"``; ``"auto"`` lets the plan decide:

- **shadow rays**: left out for a convex mesh alone in the scene (a light is then blocked exactly when it is below
  the horizon, which the cosine already handles);
- **indirect bounce**: one bounce off opaque occluders, left out for a lone object;
- **self inter-reflection**: one bounce of the light the object sends out back onto itself, left out for a convex
  object (no ray leaving it meets it again); ``[render].indirect`` forces both bounces;
- **BSSRDF** (when the caller asks, ``bssrdf=``; the hierarchical and direct methods do): the transport-accurate white
  Monte Carlo family's profiles with their incidence-angle dependence for ``g < 0.5`` and ``eta`` in [1, 1.6], or the
  dipole (:func:`~jaxsss.render.bssrdf.choose_bssrdf`);
- **see-through**: at an index-matched boundary (``eta = 1``) with the white kernels, a camera ray that leaves a
  non-convex object and meets it again is followed (:func:`jaxsss.render.shading.see_through`); a convex object
  has nothing behind its walls;
- **the object in its own mirror**: behind a smooth dielectric boundary under extended lights, where a shaded point's
  mirror ray meets the object's other parts, that part is shaded too (:func:`jaxsss.render.shading.seen_in_mirror`);
  a convex object never mirrors itself;
- **single scattering**: left out when the BSSRDF already holds it (the white profiles hold every order) or when its
  estimated share of the exitance (:func:`~jaxsss.render.radiance.single_scattering_share`) is below the tolerance;
- **cut-off radius**: pairs farther than ``ln(1/tol) / sigma_tr`` are dropped when that radius is smaller than the
  object;
- **shared channel**: the profile is evaluated once when all channels have identical coefficients;
- **multipole**: not needed where the object is many ``l_d`` thick (the renderer evaluates the dipole; a thin object
  gets a warning).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from jaxsss.render.samples import sample_count

__all__ = ["EPS_DEFAULT", "EPS_WHITE", "THICK_IN_LD", "PlanItem", "ScenePlan", "explain_items", "make_plan"]

EPS_DEFAULT = 0.05
"""The solid-angle threshold (sr) of Eq. 12 when the scene gives none: the dipole and the photon method. Against the
direct sum (512 x 512, 150,000 samples; docs/benchmarks.md, "eps sweep"): 0.17% relative RMS, 26x faster."""
EPS_WHITE = 0.1
"""The same for the white kernels: 0.41% relative RMS against the direct sum (mean dE00 0.09), 40x faster. Their
error against path-traced transport is 3-5% per pixel, so eps 0.05 buys nothing: on every Mitsuba reference
(docs/path_tracer.md, "The white kernels' eps") mare_lit, band and sums moved by at most 0.005, and the render took
1.3-1.6x less time (eps 0.2: another 1.3-1.6x, but ketchup's red 0.084 -> 0.089, band 0.099 -> 0.115)."""

THICK_IN_LD = 10.0
"""An object at least this many diffuse mean free paths thick is treated as semi-infinite (no multipole)."""


class PlanItem(NamedTuple):
    """One decision: ``name``, whether the term or pass is ``included``, and the one-line ``reason``."""

    name: str
    included: bool
    reason: str


def explain_items(items) -> str:
    """Plan items as text, one line per decision: ``+`` kept / ``-`` left out, the name and the reason."""
    width = max(len(i.name) for i in items)
    return "\n".join(f"{'+' if i.included else '-'} {i.name:<{width}}  {i.reason}" for i in items)


class ScenePlan(NamedTuple):
    """The decisions for one scene (see the module docstring)."""

    method: str
    eps: float
    n_samples: int
    shadows: bool
    indirect: bool
    single_scattering: bool
    specular: bool
    r_cut: float | None
    shared_channel: bool
    items: tuple[PlanItem, ...]
    bssrdf: str = "dipole"
    self_bounce: bool = False
    first_order: bool = False
    exit_current: bool = False
    current_lights: tuple = ()
    """Per light of the scene, whether its light is summed with the exit's current (:attr:`exit_current`: any of
    them). Lights on both sides of the object are summed apart, each side with its own kernel."""
    see_through: bool = False
    """Camera rays are followed on through thin walls into the object behind (:func:`jaxsss.render.shading.
    see_through`; ``eta = 1``, the white kernels, a non-convex mesh)."""
    self_mirror: bool = False
    """The object's own parts seen in its smooth boundary are shaded (:func:`jaxsss.render.shading.seen_in_mirror`;
    ``eta != 1``, no ``specular_roughness``, an extended light, a non-convex mesh)."""

    def explain(self) -> str:
        """The plan as text, one line per decision."""
        return explain_items(self.items)

    def to_dict(self) -> dict[str, Any]:
        out = {k: getattr(self, k) for k in self._fields if k != "items"}
        out["items"] = [i._asdict() for i in self.items]
        return out


def _forced(setting: str, name: str):
    if setting == "on":
        return True, f"forced on by [render].{name}"
    if setting == "off":
        return False, f"forced off by [render].{name}"
    return None, ""


def make_plan(scene, *, method: str | None = None, eps: float | None = None, cutoff: bool = True,
              share_channels: bool = True, bssrdf: str | None = None) -> ScenePlan:
    """Decide the passes and terms for ``scene``.

    Args:
        scene: a :class:`~jaxsss.render.scene.Scene`.
        method: ``"hierarchical"`` or ``"direct"``; defaults to the scene's.
        eps: the solid-angle threshold of Eq. 12; defaults to the scene's.
        cutoff: allow the cut-off radius (fitting turns it off: it depends on the material being fitted).
        share_channels: allow evaluating one channel for identical channels (fitting turns it off).
        bssrdf: the profile kernel to decide (:data:`jaxsss.render.bssrdf.BSSRDFS`; ``"auto"`` chooses); None
            (methods with their own transport model) leaves the dipole and adds no plan line.
    """
    from jaxsss.render.bssrdf import KINKED_LIGHTS, WHITE_DENSITY, WHITE_DENSITY_KINKED, choose_bssrdf
    from jaxsss.render.radiance import single_scattering_share

    settings = scene.render
    medium = scene.material.medium
    tol = float(settings.tolerance)
    method = method or settings.method
    items: list[PlanItem] = []

    kernel = "dipole"
    if bssrdf is not None:
        kernel, kernel_why = choose_bssrdf(medium, bssrdf)
    eps_why = ""
    if eps is None and settings.eps is None:
        # The hierarchical sum's own error well below the kernel's against transport (EPS_WHITE).
        eps = EPS_DEFAULT if kernel == "dipole" else EPS_WHITE
        eps_why = (f" (the {kernel} kernel's: its error against transport, 3-5%, is ten times the sum's 0.4%)"
                   if kernel != "dipole" else " (the default)")
    eps = float(settings.eps if eps is None else eps)
    if method == "direct":
        items.append(PlanItem("method", True, "direct sum over every sample (the reference; O(pixels x samples))"))
    else:
        items.append(PlanItem("method", True, f"hierarchical sum, solid-angle threshold eps = {eps:g} sr (Eq. 12)"
                              + eps_why))
    # The white kernels sample twice as densely as the paper's dipole (WHITE_DENSITY: measured against Mitsuba), three
    # times under a light with a sharp terminator (WHITE_DENSITY_KINKED).
    kinked = [light.kind for light in scene.lights if light.kind in KINKED_LIGHTS]
    base = 1.0 if kernel == "dipole" else (WHITE_DENSITY_KINKED if kinked else WHITE_DENSITY)
    l_u = float(np.min(np.asarray(medium.l_u)))
    n_samples, why = sample_count(float(scene.mesh.area), l_u, base * settings.density, settings.max_samples)
    if base != 1.0:
        light_why = (f"; a {kinked[0]} light's sharp terminator" if kinked else
                     "; no light with a sharp terminator")
        why += f" (the {kernel} kernel's {base:g}{light_why} x the scene's density {settings.density:g})"
    items.append(PlanItem("irradiance samples", True, f"{n_samples} samples: {why}"))

    lone = len(scene.occluders) == 0
    shadows, why = _forced(settings.shadows, "shadows")
    if shadows is None:
        convex = bool(scene.mesh.is_convex)
        shadows = not (convex and lone)
        why = ("convex mesh alone in the scene: n.l > 0 decides visibility exactly" if not shadows else
               ("the mesh is not convex: it can shadow itself" if lone else "occluders can cast shadows"))
    items.append(PlanItem("shadow rays", shadows, why))

    forced_indirect, forced_why = _forced(settings.indirect, "indirect")
    indirect, why = forced_indirect, forced_why
    if indirect is None:
        indirect = not lone
        why = ("lone object in an empty scene: nothing to bounce off" if lone else
               f"{len(scene.occluders)} occluder(s) reflect light onto the object (one bounce)")
    items.append(PlanItem("indirect bounce", indirect, why))
    self_bounce, why = forced_indirect, forced_why
    if self_bounce is None:
        self_bounce = not bool(scene.mesh.is_convex)
        why = ("the mesh is not convex: light it sends out reaches it again (one bounce, local diffuse albedo "
               "F_dt Rd)" if self_bounce else "convex mesh: no light it sends out reaches it again")
    items.append(PlanItem("self inter-reflection", self_bounce, why))

    if bssrdf is not None:
        items.append(PlanItem(f"bssrdf: {kernel}", True, kernel_why))

    share = float(np.max(np.asarray(single_scattering_share(medium))))
    single, why = _forced(settings.single_scattering, "single_scattering")
    if single is None and kernel != "dipole":
        single, why = False, "already in the white Monte Carlo profile (every scattering order): counted once"
    elif single is None:
        single = share >= tol
        why = f"estimated share of the exitance {share:.2g} {'>=' if single else '<'} tolerance {tol:g}"
    elif single and kernel != "dipole":
        why = f"{why}: WARNING, the white profile holds single scattering already (counted twice)"
    else:
        why = f"{why} (estimated share {share:.2g})"
    items.append(PlanItem("single scattering", single, why))
    first_order, why = _first_order(scene, kernel, indirect or self_bounce)
    if kernel != "dipole":
        items.append(PlanItem("first order in the object's geometry", first_order, why))
        see_through, why = _see_through(scene)
        items.append(PlanItem("see-through", see_through, why))
    else:
        see_through = False
    self_mirror, why = _self_mirror(scene)
    items.append(PlanItem("object in its own mirror", self_mirror, why))
    current_lights = ()
    forced, forced_why = _forced(settings.exit_current, "exit_current")
    if bssrdf is not None:
        dielectric = kernel != "dipole" and float(np.max(np.asarray(medium.eta))) != 1.0
        if forced is not None:
            azimuth, current_lights = _forced_current(scene, forced, forced_why, kernel, first_order)
        else:
            azimuth, current_lights = _dielectric_current(scene) if dielectric else _exit_azimuth(scene, first_order)
        if azimuth is not None:
            items.append(azimuth)
    elif forced is not None:
        items.append(PlanItem("exit azimuth", False, f"{forced_why}, which does not apply here: this evaluation has "
                                                     "its own transport model, not the profile kernels"))

    specular = scene.material.specular_roughness is not None
    items.append(PlanItem("specular highlights", specular,
                          f"GGX, roughness {scene.material.specular_roughness:g}" if specular
                          else "the material has no specular_roughness"))

    sigma_tr = float(np.min(np.asarray(medium.sigma_tr)))
    size = float(np.linalg.norm(scene.mesh.extents))
    r_cut = math.log(1.0 / tol) / sigma_tr if sigma_tr > 0 else math.inf
    if not cutoff or method == "direct":
        items.append(PlanItem("cut-off radius", False, "not used for this evaluation (every pair is summed)"))
        r_cut = None
    elif r_cut < size:
        items.append(PlanItem("cut-off radius", True,
                              f"exp(-sigma_tr r) < {tol:g} beyond r = {r_cut:.4g} mm (object {size:.4g} mm across)"))
    else:
        items.append(PlanItem("cut-off radius", False,
                              f"ln(1/tol)/sigma_tr = {r_cut:.4g} mm exceeds the object ({size:.4g} mm): nothing to cut"))
        r_cut = None

    sa, ss = np.atleast_1d(np.asarray(medium.sigma_a)), np.atleast_1d(np.asarray(medium.sigma_s_prime))
    identical = sa.size > 1 and bool(np.all(sa == sa[0]) and np.all(ss == ss[0]))
    shared = share_channels and identical
    items.append(PlanItem("shared channel", shared,
                          "all channels have identical coefficients: the profile is evaluated once" if shared else
                          ("channels differ: one profile per channel" if not identical else
                           "identical channels, but this evaluation keeps them separate (fitting)")))

    l_d = float(np.max(np.asarray(medium.l_d)))
    thickness = float(np.min(scene.mesh.extents))
    ratio = thickness / l_d
    if ratio >= THICK_IN_LD:
        items.append(PlanItem("multipole", False,
                              f"the object is {ratio:.3g} l_d thick (>= {THICK_IN_LD:g}): the half-space profile "
                              "holds"))
    else:
        items.append(PlanItem("multipole", False,
                              f"WARNING: the object is only {ratio:.3g} l_d thick; a second boundary matters but this "
                              f"renderer evaluates a half-space profile ({kernel}), which overestimates the "
                              "reflectance of thin parts"))

    layers = getattr(scene, "layers", None)
    items.append(PlanItem("ray marching", False,
                          "no [layers] table: no subsurface texture layers to march" if layers is None else
                          "the scene's [layers] are marched by --method layered only"))
    if scene.material.texture is not None:
        items.append(PlanItem("texture", True, "the texture scales the irradiance samples (the paper's face example)"))
    blockers = getattr(scene, "blockers", ())
    if blockers:
        items.append(PlanItem("blockers", False, f"{len(blockers)} [[blocker]] mesh(es) inside the object: only "
                                                 "--method photon traces them (volumetric shadows)"))
    if scene.occluders:
        items.append(PlanItem("occluders", True, f"{len(scene.occluders)} opaque Lambertian object(s) shaded "
                                                 "directly"))
    return ScenePlan(method, eps, n_samples, shadows, indirect, single, specular, r_cut, shared, tuple(items),
                     kernel, self_bounce, first_order, any(current_lights), current_lights, see_through, self_mirror)


EXIT_AZIMUTH_BEHIND_DEG = 90.0
"""A light further than this from the camera, as seen from the object's centre, lights the side the camera does not
see: the camera then looks at the terminator from the dark side, along the light's flow over the surface."""


def _forced_current(scene, on: bool, why: str, kernel: str, first_order: bool) -> tuple[PlanItem, tuple]:
    """The plan's line on the exit's azimuth and :attr:`ScenePlan.current_lights` under the ``[render].exit_current``
    switch (``why``: :func:`_forced`'s reason): every light's current or none. On needs a white kernel, and at ``eta =
    1`` its first order marched (the index-matched current is the orders >= 2's); both are refused by name."""
    if on and kernel == "dipole":
        raise ValueError("[render].exit_current = 'on' needs a white kernel (the exit's current is tabulated for the "
                         "white Monte Carlo profiles); this scene's kernel is 'dipole' (`jaxsss render --explain` says "
                         "why)")
    dielectric = float(np.max(np.asarray(scene.material.medium.eta))) != 1.0
    if on and not dielectric and not first_order:
        raise ValueError("[render].exit_current = 'on' at eta = 1 needs the white kernel's first order marched in the "
                         "object's geometry (eta = 1, g = 0, point, spot or directional lights, no texture); the plan "
                         "does not march it for this scene (see `jaxsss render --explain`)")
    what = ("every light's exit current" + (", both signs (jaxsss.render.dielectric_current)" if dielectric else
                                            ", along the flow only (jaxsss.render.exit_current)")) if on else \
        "the exit's current is left out"
    return PlanItem("exit azimuth", on, f"{why}: {what}"), tuple(on for _ in scene.lights)


def _exit_azimuth(scene, first_order: bool) -> tuple[PlanItem | None, tuple]:
    """The plan's line on the exit's azimuth (None without a light that has a position or a direction), and per light
    whether its light is summed with the exit's current (:attr:`ScenePlan.current_lights`).

    Transport leaves a surface brighter along the light's flow over it than against it (the first azimuthal harmonic
    of the exit radiance is 0.2-0.6 at a point-lit sphere's terminator). With a light on the camera's side the camera
    looks against its flow at the terminator, and the kernels' short exitance there stands in for the azimuth's loss;
    with a light behind the object it looks along the flow. The light of every light behind is summed with the exit's
    current (:mod:`jaxsss.render.exit_current`; the orders >= 2 of a marched first order only), along the flow only,
    with the curvature ratio's far field corrected by transport (:mod:`jaxsss.render.curvature_correction`) and the
    oblique beams' light ahead of their entry (:mod:`jaxsss.render.oblique_azimuth`). The light
    of a light on the camera's side is summed without them: the far field would undo its terminator's cancellation
    (chicken1 lit from the camera's side: 0.034 -> 0.156 per pixel in red). With lights on both sides the two are
    summed apart, each with its own kernel. The angle is the one between the camera and each light about the centre
    of the object's bounding box."""
    centre = np.asarray(scene.mesh.bounds, dtype=float).mean(axis=0)
    view = np.asarray(scene.camera.position, dtype=float) - centre
    angles = []
    for light in scene.lights:
        if light.position is not None:
            to_light = np.asarray(light.position, dtype=float) - centre
        elif light.direction is not None:
            to_light = -np.asarray(light.direction, dtype=float)
        else:  # an environment lights every side
            angles.append(None)
            continue
        cos = float(to_light @ view / max(np.linalg.norm(to_light) * np.linalg.norm(view), 1e-300))
        angles.append(math.degrees(math.acos(min(max(cos, -1.0), 1.0))))
    keys = [light.key or f"light[{i}]" for i, light in enumerate(scene.lights)]
    behind = [a is not None and a > EXIT_AZIMUTH_BEHIND_DEG for a in angles]
    placed = [a for a in angles if a is not None]
    if not placed:
        return None, ()
    worst = max(placed)
    key = keys[angles.index(worst)]
    if not any(behind):
        return PlanItem("exit azimuth", False,
                        f"not modelled; every light is within {EXIT_AZIMUTH_BEHIND_DEG:g} degrees of the camera about "
                        f"the object (at most {worst:.0f}), where its error cancels the terminator's short exitance "
                        "(docs/path_tracer.md)"), ()
    seen = (f"WARNING: {key} is {worst:.0f} degrees from the camera about the object, so the camera sees the "
            "terminator")
    if not first_order:
        return PlanItem("exit azimuth", False,
                        f"{seen} from its dark side; the exit has no azimuth there (transport leaves brighter along "
                        "the light's flow; not modelled: the exit's current needs the first order marched) and the "
                        "terminator's exitance is short: these add up there (skin1 lit from 138 degrees: 31-51% too "
                        "dark per pixel; docs/path_tracer.md)"), ()
    front = [k for k, b in zip(keys, behind) if not b]
    apart = (f"; the light of {', '.join(front)} (on the camera's side) is summed apart without them (a second sum: "
             "the image took 2.3-3.0x as long as with one)" if front else "")
    return PlanItem("exit azimuth", True,
                    f"{seen} along the light's flow: the exit's current is added where the view looks along it "
                    "(jaxsss.render.exit_current; 1.7-1.9x the sums' time), the curvature ratio's far field is "
                    "corrected by transport (jaxsss.render.curvature_correction) and oblique beams keep their light "
                    f"ahead of the entry (jaxsss.render.oblique_azimuth) for the lights behind{apart}, with a fourth "
                    "incidence node at 0.75 (jaxsss.render.bssrdf.LIGHTS_BEHIND_MUS); still 8-18% per pixel off on "
                    "back-lit spheres (worst channel) and 13-14% on teapots, up to 16-23% too dark past the "
                    "terminator in blue (docs/path_tracer.md)"), \
        tuple(behind)


EXIT_CURRENT_MAX_RADIUS = 30.0
"""Behind a dielectric boundary the exit's current is kept for objects less than this many transport lengths ``l_u``
(the largest of the channels') in radius, half the bounding box's smallest extent. The current's light lies in a band
about each terminator and shadow edge, about ``l_d`` wide, where it is about ``l_u / l_d`` of the exitance: its share
of the image goes as ``l_u / R``. Measured (the image with and without it, mean |relative change| per lit pixel, red):
0.028 on skin1's 20 mm sphere under a sky (``R = 15 l_u``), 0.054-0.083 at 3-6 ``l_u``, 0.017 on the marble teapot
(66 ``l_u``; 0.5% in its sums). Against Mitsuba under a sky at eta 1.4-1.5 it took skin1's sphere (15 ``l_u``) from
0.024 to 0.015 per 4 x 4 bin in red, and marble's 20 mm sphere (44 ``l_u``) from 0.032 to 0.040: there the fitted
current, made at 1-15 ``l_u`` from the entry, adds more error than it removes. The sums take 1.5-2.3x as long with it
(the marble teapot at 512 x 512: pass 2 35-37 s without, 82-84 s with; docs/path_tracer.md, "The exit's current by
the object's size")."""


def _dielectric_current(scene) -> tuple[PlanItem, tuple]:
    """The plan's line on the exit's azimuth behind a dielectric boundary (a white kernel, every order), and per light
    whether its light is summed with the exit's current (:attr:`ScenePlan.current_lights`;
    :mod:`jaxsss.render.dielectric_current`): every light's for objects under :data:`EXIT_CURRENT_MAX_RADIUS`
    transport lengths in radius, none above."""
    l_u = float(np.max(np.asarray(scene.material.medium.l_u)))
    radius = 0.5 * float(np.min(scene.mesh.extents))
    size = radius / l_u
    on = size < EXIT_CURRENT_MAX_RADIUS
    why = (f"the object is {size:.3g} l_u in radius (half its smallest extent, {radius:.3g} mm; l_u = {l_u:.3g} mm) "
           f"{'<' if on else '>='} {EXIT_CURRENT_MAX_RADIUS:g} (jaxsss.render.plan.EXIT_CURRENT_MAX_RADIUS)")
    if not on:
        return PlanItem("exit azimuth", False,
                        f"{why}: the exit's current is left out (its share of the image goes as l_u / radius: 1.7% per "
                        "pixel and 0.5% in the sums on the 66 l_u marble teapot, whose sums take 2.3x as long with it; "
                        "marble's 44 l_u sphere under a sky is closer to Mitsuba without it)"), \
            tuple(False for _ in scene.lights)
    return (PlanItem("exit azimuth", True,
                     f"{why}: behind the dielectric boundary the light leaves brighter along its flow over the surface "
                     "and darker against it: every light's exit current, both signs (jaxsss.render.dielectric_current, "
                     "Fresnel walks; the shadowed side of spheres under a sky was 10-30% too bright per pixel without "
                     "it; the sums take 1.5-2.3x as long)"),
            tuple(True for _ in scene.lights))


def _see_through(scene) -> tuple[bool, str]:
    """Whether the camera's rays are followed through thin walls (:func:`jaxsss.render.shading.see_through`), and
    why."""
    eta = float(np.max(np.asarray(scene.material.medium.eta)))
    if eta != 1.0:
        return False, f"eta = {eta:g}: the boundary bends the camera's rays (followed only at eta = 1)"
    if bool(scene.mesh.is_convex):
        return False, "convex mesh: a camera ray that leaves it never meets it again"
    return True, ("a camera ray that leaves a thin wall and meets the object again sees the part behind through it, "
                  "exp(-sigma_t' c) (eta = 1); the wall keeps 1 - exp(-sigma_t' c) of its diffuse light")


def _self_mirror(scene) -> tuple[bool, str]:
    """Whether the object's parts seen in its own smooth boundary are shaded
    (:func:`jaxsss.render.shading.seen_in_mirror`), and why."""
    from jaxsss.render.lights import EXTENDED_KINDS

    eta = float(np.max(np.asarray(scene.material.medium.eta)))
    if eta == 1.0:
        return False, "eta = 1: the boundary reflects nothing"
    if scene.material.specular_roughness is not None:
        return False, "a rough boundary (specular_roughness): its GGX highlights stand for the reflection"
    if not any(light.kind in EXTENDED_KINDS for light in scene.lights):
        return False, "no environment or area light: a point's mirror image is a point, never seen"
    if bool(scene.mesh.is_convex):
        return False, "convex mesh: no mirror ray meets the object again"
    return True, ("where a shaded point's mirror ray meets the object (the body mirroring its spout), that part is "
                  "shaded too and seen with F(eta, cos_o) of it (under a sky: 0.8% of a teapot's light, 4-5% of its "
                  "lid's)")


def _first_order(scene, kernel: str, indirect: bool) -> tuple[bool, str]:
    """Whether the white kernel's first order is marched in the object's geometry (:mod:`jaxsss.render.first_order`),
    and why (the plan's line; ``indirect``: the scene has indirect light, which enters the profiles only)."""
    from jaxsss.render.first_order import FIRST_ORDER_LIGHTS

    medium = scene.material.medium
    g = 0.0 if medium.g is None else float(np.max(np.asarray(medium.g)))
    eta = float(np.max(np.asarray(medium.eta)))
    other = [light.kind for light in scene.lights if light.kind not in FIRST_ORDER_LIGHTS]
    kept = "the white profile's half-space first order is kept"
    if kernel != "white-oblique":
        return False, f"the {kernel} kernel keeps the half-space's first order"
    if eta != 1.0 or g != 0.0:
        return False, (f"eta = {eta:g}, g = {g:g}: marched only at an index-matched boundary with isotropic "
                       f"scattering (eta = 1, g = 0); {kept}")
    if other:
        return False, f"a {other[0]} light is not marched; {kept}"
    if scene.material.texture is not None:
        return False, f"the texture scales the profiles' entry only; {kept}"
    why = ("marched along each view ray inside, the light's path to each point traced (eta = 1, g = 0); the white "
           "profiles keep orders >= 2 and leave by Chandrasekhar's multiple-scattering exit, less grazing where the "
           "surface curves (jaxsss.render.exit_curvature), with the curvature ratio corrected by transport "
           "(jaxsss.render.curvature_correction: from the light's side its near part, to 5 l_u)")
    if indirect:
        why += ("; the indirect light (occluders' or the object's own bounce) is not marched: it enters the orders "
                ">= 2 with its first order's share of the light "
                "(jaxsss.render.first_order.diffuse_first_order_restore)")
    return True, why
