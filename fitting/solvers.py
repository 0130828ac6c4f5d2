"""Least-squares solvers for the fits, chosen by name from a validated registry (:data:`SOLVERS`).

``gauss_newton`` and ``dogleg`` are Optimistix solvers run through :func:`optimistix.least_squares`; fitted parameters
are differentiable in the data by the implicit function theorem at the solution, whichever solver found it
(:func:`fitting.fit_jacobian_wrt_data`).

- ``levenberg_marquardt`` (default): a small Levenberg-Marquardt loop of the fitting kernel
  (:func:`fitting._kernel.lm_step`: Marquardt scaling, Nielsen damping, stop when the undamped Gauss-Newton step is
  below ``atol + rtol |theta|``). It is a few array operations per iteration, so it compiles in a fraction of
  Optimistix's time, and batches run it in blocks that retire converged problems (no waiting for the slowest).
- ``gauss_newton``: :class:`optimistix.GaussNewton` -- undamped; fastest from a good start, may fail from a bad one.
- ``dogleg``: :class:`optimistix.Dogleg` -- trust region mixing the Gauss-Newton and steepest-descent steps.

Termination of the Optimistix solvers (their Cauchy test): successive iterates and residual norms change by less
than ``atol + rtol * |value|`` in the max norm.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import optimistix as optx

__all__ = ["SOLVERS", "LeastSquaresSolver", "resolve_solver", "results_from_code"]


class LeastSquaresSolver(NamedTuple):
    """A registered solver: ``make(rtol, atol)`` returns the Optimistix solver."""

    name: str
    summary: str
    make: Callable
    native: bool = False  # fits run fitting._kernel's batched LM loop; ``make`` serves fit_jacobian_wrt_data


SOLVERS: dict[str, LeastSquaresSolver] = {
    s.name: s
    for s in (
        LeastSquaresSolver("levenberg_marquardt", "Levenberg-Marquardt (jaxsss's batched loop; default)",
                           optx.LevenbergMarquardt, native=True),
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


def results_from_code(code) -> optx.RESULTS:
    """The ``optimistix.RESULTS`` whose integer code is ``code`` (``RESULTS.<member>._value``, any shape): the status
    of a program whose outputs are plain arrays (the fits' slot blocks, the exported fits)."""
    return optx.RESULTS.successful.__class__(code, optx.RESULTS)
