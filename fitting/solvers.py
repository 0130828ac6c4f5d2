"""Least-squares solvers for the fits, chosen by name from a validated registry (:data:`SOLVERS`).

All are Optimistix solvers run through :func:`optimistix.least_squares` with the implicit adjoint, so fitted
parameters are differentiable in the data by the implicit function theorem (:func:`fitting.fit_jacobian_wrt_data`).

- ``levenberg_marquardt`` (default): :class:`optimistix.LevenbergMarquardt` -- a trust region on the Gauss-Newton
  step; robust from a rough start.
- ``gauss_newton``: :class:`optimistix.GaussNewton` -- undamped; fastest from a good start, may fail from a bad one.
- ``dogleg``: :class:`optimistix.Dogleg` -- trust region mixing the Gauss-Newton and steepest-descent steps.

Termination (Optimistix's Cauchy test): successive iterates and residual norms change by less than
``atol + rtol * |value|`` in the max norm.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import optimistix as optx

__all__ = ["SOLVERS", "LeastSquaresSolver", "resolve_solver"]


class LeastSquaresSolver(NamedTuple):
    """A registered solver: ``make(rtol, atol)`` returns the Optimistix solver."""

    name: str
    summary: str
    make: Callable


SOLVERS: dict[str, LeastSquaresSolver] = {
    s.name: s
    for s in (
        LeastSquaresSolver("levenberg_marquardt", "Levenberg-Marquardt (optimistix; default)", optx.LevenbergMarquardt),
        LeastSquaresSolver("gauss_newton", "Gauss-Newton (optimistix)", optx.GaussNewton),
        LeastSquaresSolver("dogleg", "Dogleg trust region (optimistix)", optx.Dogleg),
    )
}
"""Registry of least-squares solvers by name."""


def resolve_solver(name) -> LeastSquaresSolver:
    """The registered :class:`LeastSquaresSolver` called ``name``; unknown names raise ``ValueError`` listing the valid
    names."""
    try:
        return SOLVERS[name]
    except (KeyError, TypeError):
        valid = ", ".join(repr(k) for k in SOLVERS)
        raise ValueError(f"fit_profile(solver={name!r}) is not a registered solver; valid names: {valid}") from None
