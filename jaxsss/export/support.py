"""What the exporters can represent: a scene is checked once, and anything they cannot carry over is refused.

A refused key raises :class:`ExportError` (a ``ValueError``) naming the scene key, its value and why, e.g.::

    [blocker[0]] blockers (absorbing meshes inside the object) cannot be exported to mitsuba: ...

Shared by :mod:`jaxsss.export.mitsuba` and :mod:`jaxsss.export.pbrt`; reads only public attributes of
:class:`jaxsss.render.scene.Scene`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["TARGETS", "ExportError", "check_exportable", "medium_arrays"]

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
    (``material.texture``), an environment map (``environment``: jaxsss has no lat-long orientation convention for it
    yet, and a file that does not exist is refused as such), and a non-black ``output.background`` (a constant
    background in a path tracer is a light that would also illuminate the object).

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
    if scene.environment is not None:
        env = Path(scene.environment)
        why = ("does not exist" if not env.is_file() else
               "is not exported: jaxsss defines no orientation for environment maps yet, so the export would not "
               "match what jaxsss means by it")
        raise ExportError("environment", f"{scene.environment!r} {why}")
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
