"""The per-layer coefficients of a layered material: :class:`LayerStack`, a small ``equinox.Module`` pytree.

Layer ``i`` (counting from the surface, 0 first) has a scattering coefficient ``sigma_s[i]`` and an extinction
coefficient ``sigma_t[i] = sigma_a[i] + sigma_s[i]`` (both 1/mm, per colour channel), an anisotropy ``g[i]`` and a
phase function ``phase[i]`` (``"hg"`` or ``"schlick"``, see :mod:`jaxsss.phase`). Where the layers sit is
the business of the subsurface texture (:mod:`jaxsss.layered.textures`): texture channel ``i`` holds the depth of
the bottom of layer ``i``. Below the deepest layer nothing scatters or attenuates (Francois et al., Eq. 12 sums the
path lengths of the textured layers only).

The arrays are the differentiable leaves; ``phase`` and ``names`` are static.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from jaxsss.validate import check_range, is_concrete, require
from jaxsss.phase import PHASE_FUNCTIONS, SCHLICK_G_MAX

__all__ = ["LayerStack"]


class LayerStack(eqx.Module):
    """Coefficients of ``n`` layers over ``C`` colour channels.

    Attributes:
        sigma_s: ``(n, C)`` scattering coefficients, 1/mm, ``>= 0``.
        sigma_t: ``(n, C)`` extinction coefficients, 1/mm, ``>= sigma_s`` (no negative absorption).
        g: ``(n, 1)`` or ``(n, C)`` phase anisotropy (Henyey-Greenstein mean cosine), ``(-1, 1)``.
        phase: one phase-function name per layer (static).
        names: one name per layer (static; for reports).

    Build with :meth:`create`, which broadcasts scalars and per-layer values and validates once.
    """

    sigma_s: Float[Array, "n C"]
    sigma_t: Float[Array, "n C"]
    g: Float[Array, "n c"]
    phase: tuple[str, ...] = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True)

    @classmethod
    def create(cls, sigma_s, sigma_t, g=0.0, phase="hg", names: Sequence[str] | None = None) -> LayerStack:
        """Validate and broadcast.

        Args:
            sigma_s: ``(n,)`` or ``(n, C)`` scattering coefficients, 1/mm (``(n,)`` means one channel).
            sigma_t: same shape rules; extinction, 1/mm, ``>= sigma_s``.
            g: scalar, ``(n,)`` or ``(n, C)`` anisotropy in ``(-1, 1)`` (``"schlick"`` layers:
                ``|g| < SCHLICK_G_MAX = 0.9381``, see :mod:`jaxsss.phase`).
            phase: one name for every layer or one per layer (``"hg"``, ``"schlick"``).
            names: optional layer names (default ``layer0``, ``layer1``, ...).

        Raises:
            ValueError: a value outside its range, naming ``LayerStack(arg=...)`` and the range; shapes that do not
                broadcast; an unknown phase name.
        """
        owner = "LayerStack"
        sigma_s = check_range(sigma_s, "sigma_s", 0.0, owner=owner)
        sigma_t = check_range(sigma_t, "sigma_t", 0.0, owner=owner)
        g = check_range(g, "g", -1.0, 1.0, lo_open=True, hi_open=True, owner=owner)
        sigma_s = sigma_s[:, None] if sigma_s.ndim == 1 else sigma_s
        sigma_t = sigma_t[:, None] if sigma_t.ndim == 1 else sigma_t
        if sigma_s.ndim != 2 or sigma_t.ndim != 2:
            raise ValueError(f"{owner}(sigma_s, sigma_t): expected (n,) or (n, C) arrays, got shapes "
                             f"{sigma_s.shape} and {sigma_t.shape}")
        try:
            shape = jnp.broadcast_shapes(sigma_s.shape, sigma_t.shape)
        except ValueError:
            raise ValueError(f"{owner}(sigma_s, sigma_t): shapes {sigma_s.shape} and {sigma_t.shape} do not "
                             "broadcast") from None
        n = shape[0]
        if n < 1:
            raise ValueError(f"{owner}(sigma_s=...): no layers; allowed: at least 1")
        sigma_s, sigma_t = jnp.broadcast_to(sigma_s, shape), jnp.broadcast_to(sigma_t, shape)
        sigma_t = require(sigma_t, sigma_t < sigma_s,
                          f"{owner}(sigma_t=...): below sigma_s in some layer and channel; allowed range "
                          "[sigma_s, inf) (sigma_a = sigma_t - sigma_s >= 0)")
        if g.ndim == 0:
            g = jnp.full((n, 1), g)
        elif g.ndim == 1:
            g = g[:, None]
        if g.shape[0] != n or g.shape[1] not in (1, shape[1]):
            raise ValueError(f"{owner}(g=...): shape {g.shape} does not match {n} layers x {shape[1]} channels")
        phases = (phase,) * n if isinstance(phase, str) else tuple(phase)
        if len(phases) != n:
            raise ValueError(f"{owner}(phase={phase!r}): {len(phases)} names for {n} layers")
        for p in phases:
            if p not in PHASE_FUNCTIONS:
                raise ValueError(f"{owner}(phase={p!r}): not known; valid: {', '.join(PHASE_FUNCTIONS)}")
        schlick = jnp.asarray([p == "schlick" for p in phases])[:, None]
        g = require(g, schlick & (jnp.abs(g) >= SCHLICK_G_MAX),
                    f"{owner}(g=...): a 'schlick' layer needs |g| < {SCHLICK_G_MAX} (allowed range "
                    f"(-{SCHLICK_G_MAX}, {SCHLICK_G_MAX})), where k = 1.55 g - 0.55 g^3 stays below 1")
        names = tuple(names) if names is not None else tuple(f"layer{i}" for i in range(n))
        if len(names) != n:
            raise ValueError(f"{owner}(names=...): {len(names)} names for {n} layers")
        return cls(sigma_s, sigma_t, g, phases, names)

    @property
    def n_layers(self) -> int:
        return self.sigma_s.shape[0]

    @property
    def n_channels(self) -> int:
        return self.sigma_s.shape[1]

    @property
    def sigma_a(self):
        """``(n, C)`` absorption coefficients ``sigma_t - sigma_s``, 1/mm."""
        return self.sigma_t - self.sigma_s

    def replace(self, **changes) -> LayerStack:
        """A copy with some arrays replaced (``sigma_s``, ``sigma_t``, ``g``), not re-validated (works under jit)."""
        return eqx.tree_at(lambda s: [getattr(s, k) for k in changes], self, list(changes.values()))

    def with_layer_sigma_s(self, layer: int, value) -> LayerStack:
        """A copy with layer ``layer``'s ``sigma_s`` set to ``value`` (scalar or ``(C,)``), ``sigma_t`` kept."""
        value = jnp.broadcast_to(jnp.asarray(value, dtype=self.sigma_s.dtype), (self.n_channels,))
        return self.replace(sigma_s=self.sigma_s.at[layer].set(value))


def min_extinction(stack: LayerStack, layer: int = 0) -> float:
    """The smallest extinction coefficient of one layer over the channels, 1/mm (a concrete float)."""
    if not is_concrete(stack.sigma_t):
        raise ValueError("min_extinction: needs concrete coefficients (call it outside jit)")
    return float(jnp.min(stack.sigma_t[layer]))
