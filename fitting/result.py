"""The result of a profile fit: estimates, standard errors, the solver's status, the range used; a table and JSON."""

from __future__ import annotations

import json

import equinox as eqx
import jax
import numpy as np
import optimistix as optx

import jaxsss

__all__ = ["CORRELATION_LIMIT", "CONDITION_LIMIT", "SUSPECT_CHI2", "SUSPECT_STRUCTURE", "SUSPECT_TIE", "ProfileFit"]

SUSPECT_CHI2 = 1
"""Bit of :attr:`ProfileFit.suspect`: the reduced chi^2 exceeds the noise level of the given standard errors."""
SUSPECT_TIE = 2
"""Bit of :attr:`ProfileFit.suspect`: another start reached a different minimum of about the same cost."""
SUSPECT_STRUCTURE = 4
"""Bit of :attr:`ProfileFit.suspect`: no standard errors, and the residuals are a smooth misfit rather than noise."""
CHI2_P = 1e-3
"""The chi^2 check fires when a chi^2 this large has a probability below ``CHI2_P`` for correct standard errors (one
false alarm in 1000 correct fits: a warning to read costs less than a wrong fit reported reliable). It was
``1 + 5 sqrt(2 / dof)`` (the normal approximation, p ~ 1e-5 to 1e-4), which at 37 degrees of freedom let a reduced
chi^2 of 2.0 (p = 3e-4) pass: a dipole fit of salt_powder (relative, 1.9% noise, r >= 1.9 l_d) in a wrong basin,
sigma_a 0.055 against 0.243, reported reliable (fit_sweep, 3000 dipole fits, issue 18)."""


def chi2_limit(dof):
    """The reduced chi^2 above which the check fires, for ``dof`` degrees of freedom (NumPy, host side)."""
    from scipy.stats import chi2

    return chi2.isf(CHI2_P, dof) / dof

CORRELATION_LIMIT = 0.999
"""``|corr(sigma_a, sigma_s')|`` above this: the data do not separate the two parameters. Well-posed fits of absolute
profiles with relative weights sit at about 0.95-0.995 (the far field fixes sigma_tr much better than the albedo), so
the limit is 0.999 rather than 0.99; relative far-field data reach 0.9999 and more."""
CONDITION_LIMIT = 1e5
"""Condition number of the normalised (unit-diagonal) ``J^T J`` above this: some combination of the free parameters
is not determined by the data (e.g. scale and albedo of relative far-field data). For two parameters it is about
``2 / (1 - |corr|)``."""


def _message(result, index) -> str:
    item = jax.tree_util.tree_map(lambda x: jax.numpy.asarray(np.asarray(x)[index]), result)
    if bool(item == optx.RESULTS.successful):
        return "converged"
    text = optx.RESULTS[item]
    return "converged" if not text else " ".join(text.split())


class ProfileFit(eqx.Module):
    """Result of :func:`fitting.fit_profile` / :func:`fitting.fit_profiles`.

    Arrays have the fit's batch shape: ``()`` for one single-channel profile, ``(C,)`` for ``C`` channels, ``(B,)`` or
    ``(B, C)`` for a batch. Units: 1/mm for coefficients, mm for radii.

    Attributes:
        sigma_a, sigma_s_prime: estimates (1/mm).
        sigma_a_stderr, sigma_s_prime_stderr: standard errors from ``J^T J`` at the solution scaled by the residual
            variance ``SSR / (n - p)``, mapped from the log-parameters (``se(x) = x se(log x)``); ``inf`` when
            ``J^T J`` is singular.
        correlation: correlation of the ``sigma_a`` and ``sigma_s'`` estimates (in log-parameters).
        scale, scale_stderr: the free scale of relative data (1 and 0 for absolute data).
        eta, eta_stderr: relative index (fixed: the given value and 0).
        residual_norm: ``sqrt(SSR)`` of the weighted residuals in the fit range; ``reduced_chi2 = SSR / (n - p)``.
        n_points: points in the fit range; ``r_min``, ``r_max``: the smallest and largest radius fitted (mm).
        r_cut: the threshold ``r >= r_cut`` applied (``l_u`` at the initial guess by default, else the user's r_min).
        iterations: solver steps; ``result``: ``optimistix.RESULTS`` per fit (see :attr:`converged`, :meth:`messages`).
        condition_number: of the normalised ``J^T J``; ``identifiable``: ``|correlation| <= CORRELATION_LIMIT`` and
            ``condition_number <= CONDITION_LIMIT``.
        guess_sigma_a, guess_sigma_s_prime: the initial guess.
        thickness: slab thickness (mm) or ``None``.
        model, solver, outputs, relative, free_eta, range_reason, notes, seconds, static: what was run (static);
            ``static`` is the model's static setting (the multipole's pair count, the ``mc`` model's ``(g, eta)``).
        model_warnings: warnings about the model's validity at the solution (e.g. the ``mc`` model's table range),
            included in :attr:`warnings`.
        suspect: the suspect-fit checks per fit, a bit field (0: none fired): ``SUSPECT_CHI2`` (1) -- standard errors
            were given and the reduced chi^2 is above ``1 + 5 sqrt(2 / dof)``: the residuals exceed the noise (a
            wrong minimum or a model that does not describe the data); ``SUSPECT_TIE`` (2) -- another start converged
            to a different minimum that fits as well (within 4 units of chi^2 in the fit's residual variance): the
            data do not single out one answer; ``SUSPECT_STRUCTURE`` (4) -- no standard errors were given and the
            residuals are a smooth misfit (lag-1 autocorrelation along r above 0.5, rms above 1e-6), not noise. A
            suspect fit may still report ``converged``; :attr:`warnings` says
            why it may be wrong and :attr:`reliable` is ``False``.
        alt_sigma_a, alt_sigma_s_prime, alt_cost_ratio: the best solution among the other starts (the fit solves
            from three starts of different albedo, :mod:`fitting._kernel`) and its cost over the chosen one's
            (``>= 1``; 1 when both found the same minimum, ``inf`` if it did not converge).
        residual_autocorrelation: lag-1 autocorrelation of the weighted residuals along r.
    """

    sigma_a: jax.Array
    sigma_s_prime: jax.Array
    sigma_a_stderr: jax.Array
    sigma_s_prime_stderr: jax.Array
    correlation: jax.Array
    scale: jax.Array
    scale_stderr: jax.Array
    eta: jax.Array
    eta_stderr: jax.Array
    residual_norm: jax.Array
    reduced_chi2: jax.Array
    n_points: jax.Array
    r_min: jax.Array
    r_max: jax.Array
    r_cut: jax.Array
    iterations: jax.Array
    result: optx.RESULTS
    condition_number: jax.Array
    identifiable: jax.Array
    guess_sigma_a: jax.Array
    guess_sigma_s_prime: jax.Array
    thickness: jax.Array | None
    model: str = eqx.field(static=True)
    solver: str = eqx.field(static=True)
    outputs: tuple = eqx.field(static=True)
    relative: bool = eqx.field(static=True)
    free_eta: bool = eqx.field(static=True)
    range_reason: str = eqx.field(static=True)
    notes: tuple = eqx.field(static=True)
    seconds: float = eqx.field(static=True)
    static: object = eqx.field(static=True, default=None)
    fresnel: str = eqx.field(static=True, default="poly")
    model_warnings: tuple = eqx.field(static=True, default=())
    suspect: jax.Array | None = None
    alt_sigma_a: jax.Array | None = None
    alt_sigma_s_prime: jax.Array | None = None
    alt_cost_ratio: jax.Array | None = None
    residual_autocorrelation: jax.Array | None = None

    @property
    def shape(self) -> tuple:
        return tuple(np.shape(self.sigma_a))

    @property
    def converged(self):
        """Boolean array: the solver reported success for each fit."""
        return np.asarray(self.result == optx.RESULTS.successful)

    @property
    def reliable(self):
        """Boolean array: converged, identifiable, not suspect and inside the model's validity range (a fit to trust
        without reading its warnings)."""
        ok = self.converged & np.asarray(self.identifiable)
        if self.suspect is not None:
            ok = ok & (np.asarray(self.suspect) == 0)
        return ok & (not self.model_warnings)

    def _rho1(self, i):
        return float("nan") if self.residual_autocorrelation is None else float(
            np.asarray(self.residual_autocorrelation).reshape(-1)[i])

    def messages(self) -> list[str]:
        """The solver's status message per fit (flattened), ``"converged"`` on success."""
        return [_message(self.result, idx) for idx in np.ndindex(self.shape)]

    @property
    def warnings(self) -> list[str]:
        """Human-readable warnings: fits that did not converge, parameters the data cannot separate."""
        out = []
        conv = self.converged.reshape(-1)
        if not conv.all():
            msgs = self.messages()
            bad = [i for i in range(conv.size) if not conv[i]]
            out.append(f"{len(bad)} of {conv.size} fits did not converge (first: fit {bad[0]}: {msgs[bad[0]]})")
        ident = np.asarray(self.identifiable).reshape(-1)
        if not ident.all():
            corr = np.asarray(self.correlation).reshape(-1)
            cond = np.asarray(self.condition_number).reshape(-1)
            i = int(np.argmin(ident))
            out.append(
                f"{int((~ident).sum())} of {ident.size} fits cannot separate the parameters (first: fit {i}: "
                f"corr(sigma_a, sigma_s') = {corr[i]:.4f}, cond(J^T J) = {cond[i]:.3g}); the data fix only a "
                "combination such as sigma_tr -- add absolute calibration, near-field radii, or fix a parameter"
            )
        if self.suspect is not None:
            sus = np.asarray(self.suspect).reshape(-1)
            chi2 = np.asarray(self.reduced_chi2).reshape(-1)
            n = np.asarray(self.n_points).reshape(-1)
            for bit, what in ((SUSPECT_CHI2, "chi2"), (SUSPECT_TIE, "tie"), (SUSPECT_STRUCTURE, "structure")):
                hit = (sus & bit) != 0
                if not hit.any():
                    continue
                i = int(np.argmax(hit))
                if what == "chi2":
                    # The same degrees of freedom as the check (fitting._kernel.finish): n minus every free parameter.
                    n_par = 2 + int(self.relative) + int(self.free_eta)
                    lim = chi2_limit(max(n[i] - n_par, 1))
                    out.append(
                        f"{int(hit.sum())} of {hit.size} fits are suspect: the residuals exceed the given standard "
                        f"errors (first: fit {i}: reduced chi^2 = {chi2[i]:.3g} > {lim:.3g}); the solution may be a "
                        "wrong minimum, or the model does not describe the data")
                elif what == "structure":
                    out.append(
                        f"{int(hit.sum())} of {hit.size} fits are suspect: the residuals are a smooth misfit, not "
                        f"noise (first: fit {i}: lag-1 autocorrelation {self._rho1(i):.2f}, rms relative misfit "
                        f"{np.sqrt(chi2[i]):.2g}); the solution may be a wrong minimum, or the model does not describe "
                        "the data -- give standard errors to test the fit against the noise")
                else:
                    alt_a = np.asarray(self.alt_sigma_a).reshape(-1)[i]
                    alt_s = np.asarray(self.alt_sigma_s_prime).reshape(-1)[i]
                    ratio = np.asarray(self.alt_cost_ratio).reshape(-1)[i]
                    out.append(
                        f"{int(hit.sum())} of {hit.size} fits are suspect: another start reached a different minimum "
                        f"that fits as well (first: fit {i}: sigma_a = {alt_a:.4g}, sigma_s' = {alt_s:.4g} 1/mm at "
                        f"{ratio:.4g}x the cost); the data do not single out one answer -- widen the radius range or "
                        "add standard errors")
        out.extend(self.model_warnings)
        return out

    def predict(self, r):
        """The fitted model at radii ``r`` (mm, 1-D): ``{"R": ..., "T": ...}`` with the scale applied, each of shape
        ``(*self.shape, len(r))``, per incident photon (or in the data's units for relative fits)."""
        import jax.numpy as jnp

        from fitting.models import model_profiles, resolve_model

        model = resolve_model(self.model)
        r = jnp.asarray(np.asarray(r, dtype=np.float64))
        flat = lambda x: jnp.reshape(jnp.broadcast_to(jnp.asarray(x), self.shape), (-1,))  # noqa: E731
        d = flat(1.0 if self.thickness is None else self.thickness)

        def one(sa, ss, eta, dd, scale):
            prof = model_profiles(model, r, sa, ss, eta, dd, self.static, fresnel=self.fresnel)
            return {k: scale * v for k, v in prof.items()}

        out = jax.vmap(one)(flat(self.sigma_a), flat(self.sigma_s_prime), flat(self.eta), d, flat(self.scale))
        return {k: np.asarray(v).reshape(self.shape + (len(r),)) for k, v in out.items()}

    # --- Output -------------------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-ready dict: arrays as (nested) lists of the batch shape, scalars for a single fit; non-finite -> None."""

        def ints(x):
            return np.asarray(x).astype(int).tolist()

        d = {
            "model": self.model,
            "solver": self.solver,
            "outputs": list(self.outputs),
            "relative": self.relative,
            "sigma_a": jaxsss.json_ready(self.sigma_a),
            "sigma_s_prime": jaxsss.json_ready(self.sigma_s_prime),
            "sigma_a_stderr": jaxsss.json_ready(self.sigma_a_stderr),
            "sigma_s_prime_stderr": jaxsss.json_ready(self.sigma_s_prime_stderr),
            "correlation": jaxsss.json_ready(self.correlation),
            "converged": np.asarray(self.converged).tolist(),
            "message": self.messages() if self.shape else self.messages()[0],
            "iterations": ints(self.iterations),
            "seconds": float(self.seconds),
            "identifiable": np.asarray(self.identifiable).tolist(),
            "condition_number": jaxsss.json_ready(self.condition_number),
            "residual_norm": jaxsss.json_ready(self.residual_norm),
            "reduced_chi2": jaxsss.json_ready(self.reduced_chi2),
            "n_points": ints(self.n_points),
            "r_min": jaxsss.json_ready(self.r_min),
            "r_max": jaxsss.json_ready(self.r_max),
            "r_cut": jaxsss.json_ready(self.r_cut),
            "range_reason": self.range_reason,
            "eta": jaxsss.json_ready(self.eta),
            "guess_sigma_a": jaxsss.json_ready(self.guess_sigma_a),
            "guess_sigma_s_prime": jaxsss.json_ready(self.guess_sigma_s_prime),
            "notes": list(self.notes),
            "warnings": self.warnings,
        }
        if self.suspect is not None:
            d["suspect"] = ints(self.suspect)
            d["reliable"] = np.asarray(self.reliable).tolist()
            d["alt_sigma_a"] = jaxsss.json_ready(self.alt_sigma_a)
            d["alt_sigma_s_prime"] = jaxsss.json_ready(self.alt_sigma_s_prime)
            d["alt_cost_ratio"] = jaxsss.json_ready(self.alt_cost_ratio)
            d["residual_autocorrelation"] = jaxsss.json_ready(self.residual_autocorrelation)
        if self.relative:
            d["scale"], d["scale_stderr"] = jaxsss.json_ready(self.scale), jaxsss.json_ready(self.scale_stderr)
        if self.free_eta:
            d["eta_stderr"] = jaxsss.json_ready(self.eta_stderr)
        if self.thickness is not None:
            d["thickness"] = jaxsss.json_ready(self.thickness)
        if self.static is not None:
            d["model_static"] = list(self.static) if isinstance(self.static, tuple) else self.static
        if self.model == "mc" and isinstance(self.static, tuple):
            d["g"] = float(self.static[0])
        return d

    def to_json(self, **kwargs) -> str:
        """Strict JSON (no NaN/Infinity tokens) of :meth:`to_dict`."""
        return json.dumps(self.to_dict(), allow_nan=False, **kwargs)

    def __str__(self) -> str:
        shape = self.shape
        flat = {k: np.asarray(getattr(self, k)).reshape(-1) for k in (
            "sigma_a", "sigma_a_stderr", "sigma_s_prime", "sigma_s_prime_stderr", "correlation", "scale", "eta",
            "iterations", "r_min", "r_max", "n_points", "reduced_chi2")}
        conv = self.converged.reshape(-1)
        n = conv.size
        sus = np.zeros(n, int) if self.suspect is None else np.asarray(self.suspect).reshape(-1)
        header = ["fit", "sigma_a [1/mm]", "+-", "sigma_s' [1/mm]", "+-", "corr"]
        if self.relative:
            header.append("scale")
        if self.free_eta:
            header.append("eta")
        header += ["r range [mm]", "points", "iters", "status"]
        labels = [",".join(map(str, idx)) if idx else "-" for idx in np.ndindex(shape)] if shape else ["-"]
        rows = []
        shown = list(range(min(n, 20)))
        for i in shown:
            row = [labels[i], f"{flat['sigma_a'][i]:.6g}", f"{flat['sigma_a_stderr'][i]:.2g}",
                   f"{flat['sigma_s_prime'][i]:.6g}", f"{flat['sigma_s_prime_stderr'][i]:.2g}",
                   f"{flat['correlation'][i]:+.3f}"]
            if self.relative:
                row.append(f"{flat['scale'][i]:.5g}")
            if self.free_eta:
                row.append(f"{flat['eta'][i]:.5g}")
            row += [f"{flat['r_min'][i]:.4g}-{flat['r_max'][i]:.4g}", str(int(flat["n_points"][i])),
                    str(int(flat["iterations"][i])), "NOT CONVERGED" if not conv[i] else (
                        "converged, SUSPECT" if sus[i] else "converged")]
            rows.append(row)
        widths = [max(len(h), *(len(r[j]) for r in rows)) for j, h in enumerate(header)]
        lines = [
            f"profile fit: model {self.model}, solver {self.solver}, data {'+'.join(self.outputs)}"
            f" ({'relative, free scale' if self.relative else 'absolute, per incident photon'}), "
            f"{n} fit{'s' if n != 1 else ''} in {self.seconds:.3g} s",
            f"fit range: {self.range_reason}",
            "  ".join(h.rjust(w) if j else h.ljust(w) for j, (h, w) in enumerate(zip(header, widths))),
        ]
        lines += ["  ".join(c.rjust(w) if j else c.ljust(w) for j, (c, w) in enumerate(zip(r, widths))) for r in rows]
        if n > len(shown):
            lines.append(f"... ({n - len(shown)} more)")
        lines += [f"note: {t}" for t in self.notes]
        lines += [f"warning: {t}" for t in self.warnings]
        return "\n".join(lines)
