"""Monte Carlo photon transport (MCML family) in JAX: the transport reference of the toolkit.

- :class:`Layer`, :class:`Stack` -- the medium (1/mm, mm, absolute indices; :meth:`Stack.half_space`,
  :meth:`Stack.slab`);
- :func:`simulate` -- run photons, return an :class:`MCResult` (totals, profiles, histograms, standard errors);
  the photons are split over ``jax.devices()`` (:func:`use_cpu_devices` asks JAX for one CPU device per core);
- :func:`simulate_edge` -- a pencil beam near a right-angled edge (quarter-space), for the quadpole
  (:mod:`jaxsss.mc.edge`, :class:`EdgeResult`);
- :func:`white_mc_profile` -- the white ("scaled") Monte Carlo radial profile, transport-accurate and differentiable,
  from the shipped tables (:func:`load_white_table`, :func:`available_white_tables`; :mod:`jaxsss.mc.white`);
- :func:`white_family_profile` -- the same for any ``(g, n)`` in ``[0, 0.95] x [1, 1.6]``, interpolated over a family of
  tables (:func:`load_white_family`; :mod:`jaxsss.mc.white_family`), differentiable in ``g`` too.
"""

from jaxsss.mc.edge import EdgeResult, simulate_edge
from jaxsss.mc.engine import simulate, use_cpu_devices
from jaxsss.mc.result import MCResult
from jaxsss.mc.stack import Layer, Stack
from jaxsss.mc.white import (
    WhiteTable,
    available_white_tables,
    load_white_table,
    white_mc_medium_profile,
    white_mc_profile,
    white_mc_profile_stderr,
)
from jaxsss.mc.white_family import WhiteFamily, load_white_family, white_family_profile

__all__ = [
    "EdgeResult",
    "Layer",
    "MCResult",
    "Stack",
    "WhiteFamily",
    "WhiteTable",
    "available_white_tables",
    "load_white_family",
    "load_white_table",
    "simulate",
    "simulate_edge",
    "use_cpu_devices",
    "white_family_profile",
    "white_mc_medium_profile",
    "white_mc_profile",
    "white_mc_profile_stderr",
]
