"""Stratified points in the unit square: ``n`` per row, one in each cell of an ``a x b`` grid with ``a b = n``.

The camera's rays within a pixel (:func:`jaxsss.render.camera.camera_rays`) and the bounce rays' directions about a
normal (:func:`jaxsss.render.samples.self_irradiance`) use them. The grid always has exactly ``n`` cells (``a`` the
largest divisor of ``n`` up to ``sqrt(n)``): a near-square grid with its last row partly used leaves a corner of the
square unsampled, which biases the mean of anything that varies over it (8 bounce rays per point on a 3 x 3 grid
left out a ninth of the hemisphere: the marble teapot's terminator band 0.09-0.11 -> 0.18-0.23).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["grid_shape", "unit_square"]


def grid_shape(n: int) -> tuple[int, int]:
    """``(a, b)`` with ``a b = n`` and ``a <= b``, ``a`` as large as possible (``8 -> (2, 4)``, ``9 -> (3, 3)``, a
    prime ``p -> (1, p)``)."""
    if n < 1:
        raise ValueError(f"grid_shape(n={n!r}) is outside the allowed range [1, inf)")
    a = next(d for d in range(math.isqrt(n), 0, -1) if n % d == 0)
    return a, n // a


def unit_square(rng: np.random.Generator | None, n_rows: int, n: int) -> np.ndarray:
    """``(n_rows, n, 2)`` points in ``[0, 1)^2``: per row one in each cell of the :func:`grid_shape` grid (``x`` over
    its ``b`` columns, ``y`` over its ``a`` rows), at a uniform place in its cell, or at the cell's centre when
    ``rng`` is None (the midpoint rule, deterministic)."""
    a, b = grid_shape(n)
    cells = np.arange(n)
    u = np.full((n_rows, n, 2), 0.5) if rng is None else rng.random((n_rows, n, 2))
    return np.stack([(cells % b + u[..., 0]) / b, (cells // b + u[..., 1]) / a], axis=-1)
