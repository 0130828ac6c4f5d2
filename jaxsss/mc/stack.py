"""Layered media for the Monte Carlo engine: a :class:`Layer` and a :class:`Stack` of layers (pytrees).

Geometry (MCML convention, Wang, Jacques and Zheng 1995). The stack fills ``0 <= z < z_L``; ``z`` grows *into* the
medium, so the lit face is ``z = 0`` and light arrives from ``z < 0``. Layer ``i`` spans
``[z_i, z_{i+1})`` with ``z_0 = 0`` and ``z_{i+1} = z_i + thickness_i``. Above the stack is an ambient medium of index
``n_above`` and below it one of index ``n_below`` (both 1 by default). The last layer may be infinitely thick (a
half-space); no other layer may.

Units: coefficients in 1/mm, thicknesses in mm. ``n`` are *absolute* refractive indices; the relative index of a
layer against its surroundings (the ``eta`` of the rest of the toolkit) is ``n / n_above``.
"""

from __future__ import annotations

import math
from typing import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jaxsss import _config  # noqa: F401  (float64)
from jaxsss.validate import check_range

__all__ = ["Layer", "Stack"]


def _scalar(x, name: str, owner: str, lo=None, hi=None, *, lo_open=False, hi_open=False, allow_inf=False) -> float:
    """A concrete float, range-checked with the toolkit's error text (``Owner(name=value) is outside ...``)."""
    arr = np.asarray(x, dtype=np.float64) if not isinstance(x, (str, bytes)) else None
    if arr is None or arr.ndim != 0:
        raise ValueError(f"{owner}({name}={x!r}) must be a single number")
    v = float(arr)
    if allow_inf and v == math.inf:
        return v
    check_range(v, name, lo, hi, lo_open=lo_open, hi_open=hi_open, owner=owner)
    return v


class Layer(eqx.Module):
    """One homogeneous layer.

    Args:
        sigma_a: absorption coefficient, 1/mm, ``>= 0``.
        sigma_s: scattering coefficient (not reduced), 1/mm, ``>= 0``. A layer with ``sigma_a + sigma_s = 0`` is a
            clear layer (e.g. a glass cover) and is allowed.
        g: Henyey-Greenstein anisotropy, ``(-1, 1)``.
        n: absolute refractive index, ``> 0``.
        thickness: mm, ``> 0``; ``inf`` (the default) for a half-space, allowed for the last layer of a stack only.
    """

    sigma_a: float
    sigma_s: float
    g: float
    n: float
    thickness: float

    def __init__(self, sigma_a, sigma_s, g=0.0, n=1.0, thickness=math.inf):
        self.sigma_a = _scalar(sigma_a, "sigma_a", "Layer", 0.0, None)
        self.sigma_s = _scalar(sigma_s, "sigma_s", "Layer", 0.0, None)
        self.g = _scalar(g, "g", "Layer", -1.0, 1.0, lo_open=True, hi_open=True)
        self.n = _scalar(n, "n", "Layer", 0.0, None, lo_open=True)
        self.thickness = _scalar(thickness, "thickness", "Layer", 0.0, None, lo_open=True, allow_inf=True)

    @property
    def sigma_t(self) -> float:
        """Extinction ``sigma_a + sigma_s`` (1/mm)."""
        return self.sigma_a + self.sigma_s

    @property
    def albedo(self) -> float:
        """Single-scattering albedo ``sigma_s / sigma_t`` (0 for a clear layer)."""
        return self.sigma_s / self.sigma_t if self.sigma_t > 0 else 0.0


class Stack(eqx.Module):
    """Layers stacked from the lit face down, between ambient media of index ``n_above`` and ``n_below``.

    The per-layer values are stored as float64 arrays of shape ``(L,)`` (the engine's input); the number of layers
    ``L`` is part of the compiled structure, the values are not (a new stack with the same ``L`` reuses the
    compiled kernel).

    Example:
        >>> Stack.slab(sigma_a=0.1, sigma_s=0.9, g=0.75, n=1.0, thickness=2.0).num_layers
        1
    """

    sigma_a: Float[Array, " L"]
    sigma_s: Float[Array, " L"]
    g: Float[Array, " L"]
    n: Float[Array, " L"]
    thickness: Float[Array, " L"]
    n_above: float
    n_below: float

    def __init__(self, layers: Sequence[Layer], n_above=1.0, n_below=1.0):
        layers = list(layers)
        if not layers or not all(isinstance(layer, Layer) for layer in layers):
            raise ValueError(f"Stack(layers={layers!r}) must be a non-empty sequence of Layer")
        for i, layer in enumerate(layers[:-1]):
            if math.isinf(layer.thickness):
                raise ValueError(
                    f"Stack(layers[{i}].thickness=inf) is outside the allowed range (0, inf): only the last layer "
                    "may be a half-space"
                )
        self.n_above = _scalar(n_above, "n_above", "Stack", 0.0, None, lo_open=True)
        self.n_below = _scalar(n_below, "n_below", "Stack", 0.0, None, lo_open=True)
        self.sigma_a = jnp.asarray([layer.sigma_a for layer in layers], dtype=jnp.float64)
        self.sigma_s = jnp.asarray([layer.sigma_s for layer in layers], dtype=jnp.float64)
        self.g = jnp.asarray([layer.g for layer in layers], dtype=jnp.float64)
        self.n = jnp.asarray([layer.n for layer in layers], dtype=jnp.float64)
        self.thickness = jnp.asarray([layer.thickness for layer in layers], dtype=jnp.float64)

    # --- Convenience constructors ------------------------------------------------------------------------------
    @classmethod
    def half_space(cls, sigma_a, sigma_s, g=0.0, n=1.0, *, n_above=1.0) -> "Stack":
        """A semi-infinite medium (1/mm; absolute index ``n`` below an ambient of index ``n_above``)."""
        return cls([Layer(sigma_a, sigma_s, g, n, math.inf)], n_above=n_above, n_below=1.0)

    @classmethod
    def slab(cls, sigma_a, sigma_s, g=0.0, n=1.0, thickness=1.0, *, n_above=1.0, n_below=None) -> "Stack":
        """A slab of ``thickness`` mm; ambient ``n_above`` on top and ``n_below`` (default: ``n_above``) beneath."""
        _scalar(thickness, "thickness", "Stack.slab", 0.0, None, lo_open=True)
        n_below = n_above if n_below is None else n_below
        return cls([Layer(sigma_a, sigma_s, g, n, thickness)], n_above=n_above, n_below=n_below)

    # --- Derived ------------------------------------------------------------------------------------------------
    @property
    def num_layers(self) -> int:
        return int(self.sigma_a.shape[0])

    @property
    def is_half_space(self) -> bool:
        """True when the last layer is infinitely thick (no transmittance)."""
        return bool(np.isinf(np.asarray(self.thickness)[-1]))

    @property
    def layers(self) -> list[Layer]:
        """The layers as :class:`Layer` objects."""
        cols = [np.asarray(a) for a in (self.sigma_a, self.sigma_s, self.g, self.n, self.thickness)]
        return [Layer(*(float(c[i]) for c in cols)) for i in range(self.num_layers)]

    def boundaries(self) -> np.ndarray:
        """Depths of the ``L + 1`` interfaces, mm: ``[0, z_1, ..., z_L]`` (``z_L = inf`` for a half-space)."""
        return np.concatenate([[0.0], np.cumsum(np.asarray(self.thickness))])
