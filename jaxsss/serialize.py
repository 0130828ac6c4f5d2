"""JSON-ready values: what the CLI and the fitting results print (strict JSON, no NaN or Infinity tokens)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["json_ready"]


def json_ready(x):
    """A float, or nested lists of floats, for ``json.dumps(..., allow_nan=False)``; dicts, strings, booleans, ints
    and ``None`` pass through (recursively), so whole reports convert in one call.

    Non-finite values become ``None`` (JSON ``null``): an infinite ``l_d`` of a non-absorbing medium, or a standard
    error that does not exist. Callers that must never emit NaN check for it before (``jaxsss.cli._common``).
    """
    if x is None or isinstance(x, (str, bool, np.bool_)):
        return bool(x) if isinstance(x, np.bool_) else x
    if isinstance(x, dict):
        return {str(k): json_ready(v) for k, v in x.items()}
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (list, tuple)) and x and all(isinstance(v, (int, np.integer)) and not isinstance(v, bool)
                                                  for v in x):
        return [int(v) for v in x]
    if isinstance(x, (list, tuple)) and any(isinstance(v, (dict, str, list, tuple)) or v is None for v in x):
        return [json_ready(v) for v in x]
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim == 0:
        v = float(arr)
        return v if math.isfinite(v) else None
    return [json_ready(a) for a in arr]
