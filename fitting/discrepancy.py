"""The renderer's error against real light transport, stated for an image fit: a model discrepancy.

A fit to an image the renderer did not make (a photograph, a path-traced reference) lands where the renderer's own
error pulls it, however many pixels it has. Pixel noise and the cluster-robust standard errors of
:func:`fitting.fit_image` do not see the part of that error the parameters absorb. Following Kennedy and O'Hagan
(2001), the fit states the renderer's error as a random relative discrepancy with a few known shapes ("modes") and
adds each mode's effect on the estimates to their covariance: a mode ``d_j`` (the model image in residual units
times the mode's shape, one value per residual row) with standard deviation ``e_j`` moves ``theta`` by ``-(J^T
J)^+ J^T d_j e_j``, so ``Cov += sum_j e_j^2 s_j s_j^T`` with ``s_j = (J^T J)^+ J^T d_j``.

The modes (:class:`ModelError`):

- **level**: alike over every pixel and view, one per channel (the renderer's summed radiance is within 2-3% of the
  path tracer's on the validated scenes).
- **bands**: alike over the pixels whose cosine to a light lies in ``[lo, hi)``, one per band, light and channel.
  The renderer's error is not uniform: against Mitsuba it is largest around the terminator and past it, exactly where
  the blur that separates ``sigma_a`` from ``sigma_s'`` is seen. A light is the same in every view where it has the
  same kind, position and direction, so its bands are shared by those views.

:data:`RENDER_MODEL_ERROR` holds the values measured against Mitsuba (its docstring cites them).
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["ModelError", "RENDER_MODEL_ERROR", "discrepancy_modes", "light_key"]


@dataclasses.dataclass(frozen=True)
class ModelError:
    """A render method's relative error against real light transport (module docstring).

    Attributes:
        level: relative brightness error alike over the image, per channel, in ``[0, 1)``.
        bands: ``((lo, hi, error), ...)``: a relative error alike over the pixels whose cosine to a light lies in
            ``[lo, hi)`` (``-1 <= lo < hi <= 1``; ``error`` in ``[0, 2]``), independent between bands and lights.
    """

    level: float = 0.0
    bands: tuple[tuple[float, float, float], ...] = ()

    def __post_init__(self):
        if not (np.isfinite(self.level) and 0.0 <= self.level < 1.0):
            raise ValueError(f"ModelError(level={self.level}) is outside the allowed range [0, 1) (a relative error)")
        bands = tuple(tuple(float(x) for x in band) for band in self.bands)
        for band in bands:
            if len(band) != 3:
                raise ValueError(f"ModelError(bands=...) entry {band} must be (lo, hi, error)")
            lo, hi, err = band
            if not (-1.0 <= lo < hi <= 1.0):
                raise ValueError(f"ModelError band ({lo}, {hi}, ...) needs -1 <= lo < hi <= 1 (cosines to a light)")
            if not (np.isfinite(err) and 0.0 <= err <= 2.0):
                raise ValueError(f"ModelError band ({lo}, {hi}, {err}): the error {err} is outside [0, 2]")
        object.__setattr__(self, "bands", bands)

    @property
    def stated(self) -> bool:
        """Whether any error is stated (a zero ModelError leaves the covariance as the residuals give it)."""
        return self.level > 0.0 or any(err > 0.0 for _, _, err in self.bands)

    @classmethod
    def coerce(cls, value, where: str = "fit_image") -> ModelError:
        """A :class:`ModelError` from itself or from a number (the level alone); errors name ``where``'s
        ``model_error`` argument."""
        if isinstance(value, cls):
            return value
        try:
            level = float(value)
        except (TypeError, ValueError):
            raise TypeError(f"{where}(model_error={value!r}) must be a number (a relative error) or a "
                            "fitting.ModelError") from None
        if not (np.isfinite(level) and 0.0 <= level < 1.0):
            raise ValueError(f"{where}(model_error={value}) is outside the allowed range [0, 1) (a relative error)")
        return cls(level=level)


RENDER_MODEL_ERROR = ModelError(level=0.03, bands=((-1.0, -0.3, 0.36), (-0.3, -0.1, 0.15), (-0.1, 0.1, 0.041),
                                                   (0.1, 0.3, 0.027)))
"""The default render method's error against Mitsuba's volumetric path tracer, for ``fit_image(model_error=...)``.

``level``: the summed radiance is within 2-3% on the validated scenes (skin1 sphere under a point light and under
skies, the marble teapot, ketchup; docs/path_tracer.md). ``bands``: the root mean square of the signed error per band
of the cosine to the light (hierarchical, auto; per channel, bands with at least 10 lit pixels) over the committed
point-lit references (skin1 and ketchup spheres, the marble teapot, the 24576-spp g = 0.9 sphere) and five held-out
spheres of the Jensen et al. 2001 materials (apple, marble, potato, skimmilk, chicken1; docs/path_tracer.md, "The
held-out spheres, re-rendered with the late roulette"), measured after the cut beam and the exit by distance ("The
cut beam and the exit by distance"): 2.7% in ``[0.1, 0.3)`` (largest 7.6%), 4.1% in the terminator band ``[-0.1,
0.1)`` (10.4%), 15% in ``[-0.3, -0.1)`` (29%) and 36% below (-68% to +10%: the far dark side, now mostly too dark
where ``l_u`` is short and the curvature ratio understates the sphere's far field). From 0.3 up it is 1.4%, within
the level. (Before those two changes: 2.2%, 4.3%, 14% and 41%.)"""


def light_key(light) -> tuple:
    """What makes two views' lights the same light: kind, position and direction (rounded to 1e-6 mm)."""
    def rounded(v):
        return None if v is None else tuple(np.round(np.asarray(v, dtype=np.float64), 6).tolist())

    return (light.kind, rounded(getattr(light, "position", None)), rounded(getattr(light, "direction", None)))


def discrepancy_modes(model_rows: np.ndarray, n_channels: int, cosines: np.ndarray, error: ModelError):
    """The discrepancy's modes and their standard deviations (module docstring).

    Args:
        model_rows: ``(m,)`` the model image in residual units on the fitted rows (0 elsewhere); row ``i`` is channel
            ``i % n_channels`` of pixel ``i // n_channels``.
        n_channels: ``C``.
        cosines: ``(m / C, L)`` each pixel's cosine to each of ``L`` distinct lights (NaN: that light has no terminator
            there, or is not in the pixel's view).
        error: the stated :class:`ModelError`.

    Returns:
        ``(modes (m, M), sigma (M,))``: ``M = C`` level modes, then ``C`` per (band, light) that has fitted rows.
    """
    m = len(model_rows)
    channel = np.arange(m) % n_channels
    columns, sigma = [], []
    if error.level > 0.0:
        for c in range(n_channels):
            columns.append(np.where(channel == c, model_rows, 0.0))
            sigma.append(error.level)
    cos_rows = np.repeat(np.asarray(cosines, dtype=np.float64), n_channels, axis=0)  # (m, L)
    for lo, hi, err in error.bands:
        if err <= 0.0:
            continue
        inside = (cos_rows >= lo) & ((cos_rows < hi) | ((hi == 1.0) & (cos_rows <= hi)))
        for k in range(cos_rows.shape[1]):
            for c in range(n_channels):
                col = np.where(inside[:, k] & (channel == c), model_rows, 0.0)
                if np.any(col != 0.0):
                    columns.append(col)
                    sigma.append(err)
    if not columns:
        return np.zeros((m, 0)), np.zeros(0)
    return np.stack(columns, axis=1), np.asarray(sigma)
