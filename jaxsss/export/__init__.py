"""Export a jaxsss scene to production and reference renderers, and compare their images with jaxsss's.

- :mod:`jaxsss.export.mitsuba`: a Mitsuba 3 scene dict (render in-process) and an XML + PLY export; the object
  coverage mask Mitsuba sees.
- :mod:`jaxsss.export.pbrt`: a pbrt-v4 ``.pbrt`` file with the ``subsurface`` material.
- :mod:`jaxsss.export.burley`: Christensen-Burley normalized diffusion (Cycles, RenderMan) fitted to the medium's
  transport profile, with its error against it.
- :mod:`jaxsss.export.ply`: the PLY meshes both exporters reference (jaxsss's shading normals).
- :mod:`jaxsss.export.compare`: per-pixel error of a linear image against a reference (lit pixels, the terminator
  band, summed radiance) and the pixel masks it needs from the scene geometry.
- :mod:`jaxsss.export.exact`: exact transport references that need no path tracer (Chandrasekhar's reflection of a
  point-lit flat face of an isotropic half-space), for the renderer and for the exported scenes alike.
- :mod:`jaxsss.export.support`: what an exporter can represent; everything else is refused with an
  :class:`ExportError` naming the scene key.

``mitsuba`` is an optional dependency (``pip install jaxsss[validate]``); it is imported only when a Mitsuba scene
is built or rendered, never by ``import jaxsss.export``.
"""

from jaxsss.export.support import TARGETS, ExportError, check_exportable

__all__ = ["TARGETS", "ExportError", "check_exportable"]
