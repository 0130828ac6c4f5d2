"""Boundary validation shared by every public constructor and function (public: the renderer, the Monte Carlo
engine, the fitting layer and user extensions such as new render methods or forward models use the same checks).

Errors name the argument, the offending value and the allowed range (DESIGN.md, "Bad input"). Concrete inputs are
checked eagerly in NumPy and raise :class:`ValueError`; traced inputs (inside ``jit``/``vmap``/``grad``) are checked
with :func:`equinox.error_if`, which survives compilation and raises at run time.
"""

from __future__ import annotations

import contextlib
import math
import threading

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["as_float", "bound_text", "check_integer", "check_range", "is_concrete", "require", "trusted_traces"]

_TRUSTED = threading.local()


@contextlib.contextmanager
def trusted_traces():
    """Within this block, traced values are not checked (no :func:`equinox.error_if`); concrete ones still are.

    For callers that validated their inputs on the host and trace kernels whose values are valid by construction
    (the profile fits: ``exp`` of log-parameters, radii checked before tracing). ``error_if`` is a host callback, and
    JAX's persistent compilation cache does not store programs with host callbacks (issue 18)."""
    old = getattr(_TRUSTED, "on", False)
    _TRUSTED.on = True
    try:
        yield
    finally:
        _TRUSTED.on = old


def is_concrete(x) -> bool:
    """True when ``x`` holds values now (not a tracer inside a transformation)."""
    return not isinstance(x, jax.core.Tracer)


def as_float(x, name: str):
    """Convert ``x`` to a floating JAX array (float64 when x64 is enabled), rejecting non-numeric input."""
    if isinstance(x, jax.Array) and jnp.issubdtype(x.dtype, jnp.floating):
        return x
    try:
        arr = np.asarray(x)
    except Exception as err:  # pragma: no cover - exotic inputs
        raise TypeError(f"{name}={x!r} is not a number or array of numbers") from err
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"{name}={x!r} is not a number or array of numbers (dtype {arr.dtype})")
    if arr.dtype.kind != "f":
        arr = arr.astype(jnp.result_type(float))
    return jnp.asarray(arr)


def bound_text(lo, hi, lo_open, hi_open) -> str:
    """The interval ``[lo, hi]`` as text, with ``(``/``)`` for open or missing bounds, e.g. ``(0, inf)``."""
    left = "(" if (lo_open or lo is None) else "["
    right = ")" if (hi_open or hi is None) else "]"
    lo_s = "-inf" if lo is None else f"{lo:g}"
    hi_s = "inf" if hi is None else f"{hi:g}"
    return f"{left}{lo_s}, {hi_s}{right}"


def check_range(x, name: str, lo=None, hi=None, *, lo_open=False, hi_open=False, owner: str | None = None):
    """Return ``x`` after checking every element lies in the interval and is not NaN.

    Args:
        x: array-like value.
        name: argument name used in the message.
        lo, hi: bounds (``None`` for unbounded).
        lo_open, hi_open: whether each bound is excluded.
        owner: optional ``Class`` or function name, giving messages like ``Medium(sigma_a=-1.0): ...``.

    Infinite values are rejected unless the corresponding bound is ``None`` *and* the side is closed; NaN is always
    rejected.
    """
    x = as_float(x, name)
    label = f"{owner}({name}=" if owner else f"{name}="
    allowed = bound_text(lo, hi, lo_open, hi_open)

    def bad_mask(xp, v):
        bad = xp.isnan(v)
        if lo is not None:
            bad = bad | ((v <= lo) if lo_open else (v < lo))
        else:
            bad = bad | (v == -xp.inf)
        if hi is not None:
            bad = bad | ((v >= hi) if hi_open else (v > hi))
        else:
            bad = bad | (v == xp.inf)
        return bad

    if is_concrete(x):
        v = np.asarray(x)
        bad = bad_mask(np, v)
        if np.any(bad):
            first = v[bad].flat[0] if v.ndim else v.item()
            shown = "nan" if math.isnan(first) else f"{first:g}"
            where = "" if v.ndim == 0 else f" (element {tuple(int(i) for i in np.argwhere(bad)[0])} of shape {v.shape})"
            close = ")" if owner else ""
            raise ValueError(f"{label}{shown}{close}{where} is outside the allowed range {allowed}")
        return x
    if getattr(_TRUSTED, "on", False):
        return x
    close = ")" if owner else ""
    return eqx.error_if(x, bad_mask(jnp, x), f"{label}...{close} is outside the allowed range {allowed}")


def require(x, bad, message: str):
    """Return ``x``; raise ``ValueError(message)`` where ``bad`` holds (eagerly, or at run time under ``jit``)."""
    if is_concrete(x) and is_concrete(bad):
        if np.any(np.asarray(bad)):
            raise ValueError(message)
        return x
    if getattr(_TRUSTED, "on", False):
        return x
    return eqx.error_if(x, bad, message)


def check_integer(value, name: str, lo: int, hi: int | None = None, *, owner: str | None = None) -> int:
    """Return ``value`` as an ``int`` after checking it is an integer (not a bool; a NumPy integer is fine) in
    ``[lo, hi]`` (``hi=None``: no upper bound). For static arguments: sizes, counts, seeds, chunk lengths.

    Raises:
        ValueError: ``owner(name=value) must be an integer in the allowed range [lo, hi]``.
    """
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo or (
            hi is not None and value > hi):
        label = f"{owner}({name}={value!r})" if owner else f"{name}={value!r}"
        raise ValueError(f"{label} must be an integer in the allowed range [{lo}, {'inf)' if hi is None else f'{hi}]'}")
    return int(value)
