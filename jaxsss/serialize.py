"""JSON-ready values: what the CLI and the fitting results print (strict JSON, no NaN or Infinity tokens)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["json_ready"]


def json_ready(x):
    """A float, or nested lists of floats, for ``json.dumps(..., allow_nan=False)``.

    Non-finite values become ``None`` (JSON ``null``): an infinite ``l_d`` of a non-absorbing medium, or a standard
    error that does not exist. Callers that must never emit NaN check for it before (``jaxsss.cli._common``).
    """
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim == 0:
        v = float(arr)
        return v if math.isfinite(v) else None
    return [json_ready(a) for a in arr]
