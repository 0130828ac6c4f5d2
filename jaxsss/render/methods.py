"""The render-method registry and the one driver every method renders through.

A render method is one :func:`register_method` call: a name, a ``prepare(scene, **options)`` that does the geometry
once and returns a :class:`Preparation` (whose :meth:`~Preparation.image` is a JAX function of the material), the
options it takes, and the material it renders by default. Everything else is shared:

- :func:`prepare_method` looks a method up and runs its ``prepare`` (unknown names and options are errors that name
  the allowed ones);
- :func:`render` is the driver: prepare, compile the image function (timed apart), evaluate it once, and write
  the one report (:data:`REPORT_KEYS`, :func:`render_report`) with the end-to-end time split by stage
  (:data:`STAGES`);
- ``jaxsss render --method NAME`` and :func:`fitting.fit_image` ``(..., method=NAME)`` are lookups here.

The built-in methods register when their module is imported: ``hierarchical`` and ``direct``
(:mod:`jaxsss.render.renderer`), ``cached`` (:mod:`jaxsss.render.cache`), ``photon`` (:mod:`jaxsss.photon`) and
``layered`` (:mod:`jaxsss.layered`). The last two stand on this package, so it cannot import them; they are named
in :data:`METHOD_MODULES` and imported by name on the first lookup (as entry points are), which keeps the import
graph free of cycles. See ``docs/architecture.md`` ("Render methods") for how to add one.
"""

from __future__ import annotations

import dataclasses
import importlib
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import numpy as np

from jaxsss._config import render_jit
from jaxsss._exported import compiled_program
from jaxsss.render.plan import ScenePlan
from jaxsss.render.shading import image_stats

__all__ = ["METHODS", "METHOD_MODULES", "REPORT_KEYS", "STAGES", "Preparation", "RenderMethod", "RenderResult",
           "explain_method", "method_names", "prepare_method", "register_method", "render", "render_report", "resolve_method"]

METHOD_MODULES = ("jaxsss.render.renderer", "jaxsss.render.cache", "jaxsss.photon", "jaxsss.layered")
"""Modules that register the built-in methods, imported on the first lookup."""

STAGES = ("plan", "pass1", "tree", "geometry", "compile", "pass2")
"""The stages of the end-to-end time in every report (``report["seconds"]``): the scene plan; pass 1 (irradiance
samples, or photon tracing); the octree; the rest of the geometry (camera rays, lighting at the shaded points,
interaction lists, cache placement, surface frames); compiling the image function; pass 2 (the material-dependent
evaluation: the sums, radiance and the image). ``other`` is what the driver spends outside them."""

STAGE_OF = {
    "plan": "plan",
    "pass1_irradiance": "pass1",
    "photon_tracing": "pass1",
    "octree": "tree",
    "pass2_compile": "compile",
    "pass2_sum": "pass2",
}
"""A method's detailed timing -> its stage; any other detail (camera rays, interactions, ...) is ``geometry``."""

REPORT_KEYS = ("method", "resolution", "spp", "n_pixels", "n_shaded_points", "seconds_total",
               "seconds_total_excluding_compile", "seconds", "timings", "plan", "image")
"""The keys every method's report has (a method adds its own counts beside them)."""


@dataclasses.dataclass(frozen=True, eq=False)
class Preparation:
    """What a method's ``prepare`` returns: the geometry done once.

    Attributes:
        method: the method's name.
        state: an ``equinox.Module`` with ``image(medium) -> (H, W, C)`` (a JAX function of the material) and
            ``shape`` ``(H, W)`` and ``spp``.
        plan: the :class:`~jaxsss.render.plan.ScenePlan` (its items say what was kept and left out, and why).
        diagnostics: JSON-ready counts for the report (samples, interactions, caches, photons, ...).
        timings: seconds per detailed step of the geometry (keys mapped to :data:`STAGES` by :data:`STAGE_OF`).
        extras: anything else the method's callers may use (not in the report), e.g. the cache placement.
    """

    method: str
    state: Any
    plan: ScenePlan
    diagnostics: dict
    timings: dict
    extras: dict = dataclasses.field(default_factory=dict)

    def image(self, medium):
        """The linear radiance image ``(H, W, C)``, W/(mm^2 sr): jitted, differentiable in ``medium`` (a
        :class:`jaxsss.Medium`)."""
        return image_of(self.state, medium)


class RenderMethod(NamedTuple):
    """A registered method (see :func:`register_method`)."""

    name: str
    prepare: Callable[..., Preparation]
    summary: str
    options: tuple[str, ...]
    params: Callable[[Any], Any]
    explain: Callable[..., ScenePlan] | None


METHODS: dict[str, RenderMethod] = {}
"""The registry: name -> :class:`RenderMethod` (complete after :func:`method_names` or any lookup)."""


def _scene_medium(scene):
    return scene.material.medium


def register_method(name: str, prepare: Callable[..., Preparation], summary: str, *, options=(),
                    params: Callable[[Any], Any] = _scene_medium,
                    explain: Callable[..., ScenePlan] | None = None) -> RenderMethod:
    """Add a render method.

    Args:
        name: the ``--method`` name.
        prepare: ``prepare(scene, *, resolution=None, pixel_mask=None, fit=False, progress=False, **options)`` ->
            :class:`Preparation`. ``resolution`` is ``(W, H)`` overriding the camera's; ``pixel_mask`` an optional
            ``(H, W)`` bool of the pixels to shade; ``fit=True`` asks for an image whose shortcuts do not depend on
            the scene's material (fitting varies it).
        summary: one line for ``--help``.
        options: the method's own keyword options (e.g. ``("eps",)``), each with a default.
        params: ``params(scene)`` -> the :class:`jaxsss.Medium` the image is rendered with by default.
        explain: ``explain(scene, *, resolution=None, **options)`` -> the plan without the whole preparation
            (``--explain``); default: ``prepare(...).plan``.
    """
    method = RenderMethod(name, prepare, summary, tuple(options), params, explain)
    METHODS[name] = method
    return method


def method_names() -> tuple[str, ...]:
    """The registered methods' names (importing :data:`METHOD_MODULES` first)."""
    for module in METHOD_MODULES:
        importlib.import_module(module)
    return tuple(METHODS)


def resolve_method(name: str) -> RenderMethod:
    """The :class:`RenderMethod` called ``name``; ``ValueError`` naming the registered ones otherwise."""
    names = method_names()
    if name not in METHODS:
        raise ValueError(f"method={name!r} is not a render method; registered: {', '.join(names)}")
    return METHODS[name]


def prepare_method(scene, method: str | None = None, *, resolution=None, pixel_mask=None, fit: bool = False,
                   progress: bool = False, **options) -> Preparation:
    """Run ``method``'s ``prepare`` (default: the scene's ``[render].method``) with its options.

    Raises:
        ValueError: an unknown method, or an option the method does not take (the message lists those it does).
    """
    entry = resolve_method(method or scene.render.method)
    _check_options(entry, options)
    return entry.prepare(scene, resolution=resolution, pixel_mask=pixel_mask, fit=fit, progress=progress,
                         **options)


def explain_method(scene, method: str | None = None, *, resolution=None, **options) -> ScenePlan:
    """The plan of ``method`` for ``scene`` (what ``--explain`` prints): the method's ``explain`` where it has one
    (cheaper than preparing), else its preparation's plan."""
    entry = resolve_method(method or scene.render.method)
    if entry.explain is None:
        return prepare_method(scene, entry.name, resolution=resolution, **options).plan
    _check_options(entry, options)
    return entry.explain(scene, resolution=resolution, **options)


def _check_options(entry: RenderMethod, options: dict):
    unknown = sorted(set(options) - set(entry.options))
    if unknown:
        raise ValueError(f"method {entry.name!r} takes no option(s) {', '.join(unknown)}; its options: "
                         f"{', '.join(entry.options) or 'none'}")


@render_jit
def image_of(state, medium):
    """``state.image(medium)``, jitted (the state's arrays are arguments, so equal shapes compile once)."""
    return state.image(medium)


class RenderResult(NamedTuple):
    """The image (linear, ``(H, W, C)`` NumPy), the report (JSON-ready dict, :data:`REPORT_KEYS`) and the
    :class:`Preparation`."""

    image: np.ndarray
    report: dict[str, Any]
    prepared: Preparation

    @property
    def plan(self) -> ScenePlan:
        return self.prepared.plan


def stage_seconds(timings: dict, seconds_total: float) -> dict[str, float]:
    """``timings`` summed by stage (:data:`STAGES`), with ``other`` = the rest of ``seconds_total``."""
    out = dict.fromkeys(STAGES, 0.0)
    for key, value in timings.items():
        out[STAGE_OF.get(key, "geometry")] += float(value)
    out["other"] = max(seconds_total - sum(out.values()), 0.0)
    return out


def render_report(prepared: Preparation, image: np.ndarray, timings: dict, seconds_total: float) -> dict[str, Any]:
    """The JSON-ready report every method returns: :data:`REPORT_KEYS` (totals, compilation apart, the stage split,
    detailed timings, the plan, image statistics) plus the method's own diagnostics."""
    state = prepared.state
    return {
        "method": prepared.method,
        "resolution": [int(state.shape[1]), int(state.shape[0])],
        "spp": int(state.spp),
        "seconds_total": seconds_total,
        "seconds_total_excluding_compile": seconds_total - timings.get("pass2_compile", 0.0),
        "seconds": stage_seconds(timings, seconds_total),
        "timings": timings,
        **prepared.diagnostics,
        "plan": prepared.plan.to_dict(),
        "image": image_stats(image),
    }


def render(scene, method: str | None = None, *, resolution=None, pixel_mask=None, medium=None,
           progress: bool = False, **options) -> RenderResult:
    """Render ``scene`` with a registered method: prepare (geometry once), compile the image function, evaluate it.

    Args:
        scene: a :class:`~jaxsss.render.scene.Scene`.
        method: a registered name (:func:`method_names`); default the scene's ``[render].method``.
        resolution: ``(W, H)`` overriding the camera's.
        pixel_mask: optional ``(H, W)`` bool: shade only these pixels.
        medium: the material to render (default: the method's, normally the scene's ``[material]``).
        progress: progress bars for the long geometry steps.
        **options: the method's options (e.g. ``eps``, ``error_bound``, ``n_photons``, ``samples``).

    Returns:
        A :class:`RenderResult`; its report has the end-to-end time split by stage and compilation apart.
    """
    t_all = time.perf_counter()
    entry = resolve_method(method or scene.render.method)
    prepared = prepare_method(scene, entry.name, resolution=resolution, pixel_mask=pixel_mask, progress=progress,
                              **options)
    medium = entry.params(scene) if medium is None else medium
    timings = dict(prepared.timings)
    t0 = time.perf_counter()
    # From disk where it was exported before (jaxsss._exported): a new process skips tracing and lowering.
    compiled = compiled_program("render", image_of, (prepared.state, medium))
    timings["pass2_compile"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    image = np.asarray(jax.block_until_ready(compiled(prepared.state, medium)))
    timings["pass2_sum"] = time.perf_counter() - t0
    report = render_report(prepared, image, timings, time.perf_counter() - t_all)
    return RenderResult(image, report, prepared)
