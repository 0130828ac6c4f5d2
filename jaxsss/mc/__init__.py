"""Monte Carlo photon transport (MCML family) in JAX: the transport reference of the toolkit.

- :class:`Layer`, :class:`Stack` -- the medium (1/mm, mm, absolute indices; :meth:`Stack.half_space`,
  :meth:`Stack.slab`);
- :func:`simulate` -- run photons, return an :class:`MCResult` (totals, profiles, histograms, standard errors).
"""

from jaxsss.mc.result import MCResult
from jaxsss.mc.engine import simulate
from jaxsss.mc.stack import Layer, Stack

__all__ = ["Layer", "MCResult", "Stack", "simulate"]
