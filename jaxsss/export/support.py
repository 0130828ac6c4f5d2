"""What the exporters can represent: a scene is checked once, and anything they cannot carry over is refused.

A refused key raises :class:`ExportError` (a ``ValueError``) naming the scene key, its value and why, e.g.::

    [blocker[0]] blockers (absorbing meshes inside the object) cannot be exported to mitsuba: ...

Shared by :mod:`jaxsss.export.mitsuba` and :mod:`jaxsss.export.pbrt`; reads only public attributes of
:class:`jaxsss.render.scene.Scene`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["ENVIRONMENT_ID", "TARGETS", "ExportError", "check_exportable", "environment_light", "equal_area_directions",
           "medium_arrays", "write_environment"]

ENVIRONMENT_ID = "environment"
"""The environment map's file stem in an export directory (``environment.exr``)."""

TARGETS = ("mitsuba", "pbrt-v4")
"""Export targets (``jaxsss export --to``)."""


class ExportError(ValueError):
    """A scene the target renderer cannot represent: ``str(err)`` is ``"[{key}] {message}"``.

    Attributes:
        key: the dotted scene key (``"blocker[0]"``, ``"material.texture"``, ``"environment"``, ...).
        message: the reason, without the key.
    """

    def __init__(self, key: str, message: str):
        self.key, self.message = key, message
        super().__init__(f"[{key}] {message}")


def check_exportable(scene, target: str) -> None:
    """Refuse what ``target`` (one of :data:`TARGETS`) cannot represent.

    Refused for every target: blockers (``[[blocker]]``), layer textures (``[layers]``), a material texture
    (``material.texture``), an ``environment`` file that does not exist (a scene changed after it was parsed), and a
    non-black ``output.background`` (a constant background in a path tracer is a light that would also illuminate the
    object). Environment maps and area lights are exported (:func:`write_environment`).

    Raises:
        ExportError: naming the first refused key.
        ValueError: ``target`` is not one of :data:`TARGETS`.
    """
    if target not in TARGETS:
        raise ValueError(f"target={target!r} is not one of: {', '.join(TARGETS)}")
    for i, _ in enumerate(scene.blockers):
        raise ExportError(f"blocker[{i}]", f"blockers (absorbing meshes inside the object) cannot be exported to "
                          f"{target}: only --method photon models them; remove the [[blocker]] tables")
    for name, value in scene.sections.items():  # registered scene sections, e.g. [layers] (layer textures)
        if value is not None:
            raise ExportError(name, f"the [{name}] section (a registered extension such as the layer textures of "
                              f"--method layered) cannot be exported to {target}: the exporters write one "
                              "homogeneous medium")
    if scene.material.texture is not None:
        raise ExportError("material.texture", f"{scene.material.texture_path!r}: a texture multiplies jaxsss's "
                          f"irradiance samples and has no equivalent in a homogeneous {target} medium")
    if scene.environment is not None and not Path(scene.environment).is_file():
        raise ExportError("environment", f"{scene.environment!r} does not exist")
    background = np.asarray(scene.output.background, dtype=np.float64)
    if np.any(background != 0.0):
        raise ExportError("output.background", f"{background.tolist()} is not black: a constant background in "
                          f"{target} is a light that would also illuminate the object; allowed: 0")
    if len(scene.lights) == 0:
        raise ExportError("light", "the scene has no light")


def medium_arrays(medium) -> dict[str, np.ndarray | float]:
    """The material as plain NumPy: ``sigma_a``, ``sigma_s_prime``, ``sigma_s = sigma_s' / (1 - g)``,
    ``sigma_t = sigma_a + sigma_s`` (``(3,)``, 1/mm), ``g`` (0 when the medium has none) and ``eta``.

    Raises:
        ExportError: the medium is not three channels (R, G, B).
    """
    def rgb(value, name):
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
        if arr.size not in (1, 3):
            raise ExportError(f"material.{name}", f"has {arr.size} channels: the exporters write RGB; allowed: 1 or 3")
        return np.broadcast_to(arr, (3,)).copy()

    sigma_a, sigma_sp = rgb(medium.sigma_a, "sigma_a"), rgb(medium.sigma_s_prime, "sigma_s_prime")
    g = 0.0 if medium.g is None else float(np.asarray(medium.g))
    # sigma_s = sigma_s' / (1 - g): the scattering coefficient of the Henyey-Greenstein medium.
    sigma_s = sigma_sp / (1.0 - g)
    return {"sigma_a": sigma_a, "sigma_s_prime": sigma_sp, "sigma_s": sigma_s, "sigma_t": sigma_a + sigma_s, "g": g,
            "eta": float(np.asarray(medium.eta))}


def environment_light(scene):
    """The scene's environment light (``kind == "environment"``), or ``None``."""
    return next((light for light in scene.lights if light.kind == "environment"), None)


def equal_area_directions(n: int) -> np.ndarray:
    """``(n, n, 3)`` unit directions at the pixel centres of an ``n x n`` equal-area octahedral map, pbrt-v4's
    ``EqualAreaSquareToSphere`` (Clarberg 2008): row ``y`` of the image is ``v = (y + 1/2) / n``, ``+z`` is the centre
    of the square and ``-z`` its corners."""
    c = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(2.0 * c - 1.0, 2.0 * c - 1.0)  # u along a row (x), v down the rows (y)
    up, vp = np.abs(u), np.abs(v)
    # Signed distance from the diagonal |u| + |v| = 1, the radius r and the angle phi in the quadrant.
    signed = 1.0 - (up + vp)
    r = 1.0 - np.abs(signed)
    phi = np.where(r == 0, 1.0, (vp - up) / np.where(r == 0, 1.0, r) + 1.0) * np.pi / 4.0
    z = np.copysign(1.0 - r * r, signed)
    cos_phi, sin_phi = np.copysign(np.cos(phi), u), np.copysign(np.sin(phi), v)
    s = r * np.sqrt(np.clip(2.0 - r * r, 0.0, None))
    return np.stack([cos_phi * s, sin_phi * s, z], axis=-1)


def write_environment(scene, directory, *, mapping: str = "latlong", size: int | None = None) -> str | None:
    """Write the scene's environment map as ``directory/environment.exr`` (linear float32 RGB, the scene's ``scale``
    multiplied in) and return its file name, or ``None`` when there is no environment map (none, or a constant one).

    Args:
        mapping: ``"latlong"``: the map as jaxsss reads it (Mitsuba's ``envmap`` convention, rotated by
            ``to_world``); ``"equal_area"``: resampled (bilinear, jaxsss's lookup) onto pbrt-v4's square equal-area
            octahedral map, in world coordinates (the rotation baked in).
        size: the side of the equal-area map (default: the lat-long height, at least 64).
    """
    from jaxsss.render.output import write_exr

    light = environment_light(scene)
    if light is None or light.environment.path is None:
        return None
    env = light.environment
    scale = np.asarray(light.intensity, dtype=np.float64)
    if mapping == "latlong":
        image = env.image * scale
    elif mapping == "equal_area":
        n = int(size or max(env.shape[0], 64))
        image = env.radiance(equal_area_directions(n)) * scale
    else:
        raise ValueError(f"write_environment(mapping={mapping!r}) is not one of: latlong, equal_area")
    path = Path(directory) / f"{ENVIRONMENT_ID}.exr"
    write_exr(path, image)
    return path.name
