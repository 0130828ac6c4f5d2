"""The result of a Monte Carlo run: totals, profiles and histograms with standard errors, and run metadata.

All values are per *incident* photon (incident weight 1, before the specular reflection). Profiles are per mm^2 of
exit surface: a bin's weight divided by its area (annulus ``pi (r_{i+1}^2 - r_i^2)`` or rectangle ``dx dy``).

Standard errors come from per-photon second moments: for a tally ``X = (1/N) sum_k x_k`` over the ``N`` photons
(``x_k`` = photon ``k``'s contribution, zero for most), ``stderr = sqrt((mean(x^2) - mean(x)^2) / (N - 1))``. Each
photon exits at most once, so its contribution to any exit tally is one weight; absorption is summed per photon in
the engine before squaring. These errors are exact for the estimator (no batching assumption). The Russian
roulette's net weight and the step-cap losses are reported separately, so that the bookkeeping
``R_specular + R_diffuse + T + A + roulette_balance + step_cap_weight = 1`` holds to rounding for every run.
With radial splitting (``simulate(split_length=...)``) one photon's copies are correlated, so errors come instead from
the spread of independent batch means (``stderr_method == "batches"``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["MCResult"]


def stderr_of_mean(s1, s2, n):
    """Standard error of the mean of ``n`` samples with sums ``s1`` (values) and ``s2`` (squares)."""
    s1, s2 = np.asarray(s1, dtype=np.float64), np.asarray(s2, dtype=np.float64)
    if n < 2:
        return np.full(np.shape(s1), np.inf)
    mean = s1 / n
    var = np.maximum(s2 / n - mean * mean, 0.0) * n / (n - 1)
    return np.sqrt(var / n)


@dataclasses.dataclass(frozen=True, eq=False)
class MCResult:
    """Tallies of :func:`jaxsss.mc.simulate` (NumPy float64 arrays; shapes below; units in the module docstring).

    Totals (fractions of the incident light, dimensionless):
        R_specular: reflection at the first surface, ``F(theta_i)`` (deterministic, no error).
        R_diffuse, R_diffuse_stderr: all light leaving the top face after entering (specular excluded); includes
            the order-0 light that re-emerges after reflecting off a lower interface.
        R_order, R_order_stderr: ``(3,)`` -- R_diffuse split by scattering order 0, 1 and >= 2.
        R_single, R_multiple (+ ``_stderr``): order 1 and order >= 2 (views of ``R_order``).
        T, T_stderr: all light leaving the bottom face (unscattered included; 0 for a half-space).
        T_order, T_order_stderr: ``(3,)`` by order; ``T_unscattered = T_order[0]``.
        A, A_stderr: absorbed; ``A_layer`` ``(L,)`` per layer.
        roulette_balance: weight removed by Russian roulette minus weight given to survivors (expected value 0).
        step_cap_hits, step_cap_weight: photons killed by the step cap, and their weight.
        mean_exit_radius, mean_exit_radius_stderr: weight-averaged exit distance of R_diffuse from the entry point,
            mm (ratio estimator, delta-method error).

    Profiles (``None`` when the grid was not requested):
        r_edges ``(M + 1,)`` mm; R_r, T_r ``(M,)`` and their ``_stderr``, per incident photon per mm^2; R_r_order,
            T_r_order ``(3, M)`` by scattering order (0, 1, >= 2), with ``_stderr``.
        x_edges ``(X + 1,)``, y_edges ``(Y + 1,)`` mm; R_xy ``(X, Y)`` (diffuse reflectance per mm^2; x along the
            oblique beam's in-plane direction) with ``R_xy_stderr``; R_xy_order ``(3, X, Y)`` by scattering order
            (0, 1, >= 2), with ``R_xy_order_stderr``.
        pathlength_edges ``(P + 1,)`` mm; R_r_path ``(M, P)``: diffuse reflectance per mm^2 of the annulus, for
            photons whose total pathlength inside the medium falls in each bin (not divided by the bin width), with
            ``R_r_path_stderr``. Photons outside the pathlength range are left out, so ``R_r_path.sum(1) <= R_r``.
        exit_mu_edges ``(U + 1,)``; R_mu_phi ``(U, H)``: the direction of the diffuse reflectance, per incident photon:
            ``sum w cos(m phi) / N`` over the photons leaving the top face with exit cosine ``mu_o`` in bin ``u``
            (``m = 0 .. H - 1``; ``phi`` the azimuth from the oblique beam's plane, +x). Column 0 is the reflectance
            per bin; the radiance relative to a Lambertian exit of the same total ``R`` is ``X(mu_o, phi) =
            (R_mu_phi[u, 0] + 2 sum_m R_mu_phi[u, m] cos(m phi)) / (2 R mu_o d mu_o)``. With ``R_mu_phi_stderr``.

    Metadata: photons, seed, angle_deg (incidence in air, degrees), seconds (wall time of the whole run),
    compile_seconds (0 when the kernel was already compiled), events (lane events of live photons: interactions +
    interface hits), batches, lanes, batch_size, max_steps; stderr_method (``"photons"``: per-photon second
    moments; ``"batches"``: the spread of independent batch means, used with radial splitting), split_length,
    split_start and split_stop (mm; None, 0 and None without splitting); devices (the number of devices the photons
    were split over); iterations (loop iterations, summed over batches and devices; see ``lane_occupancy``).
    """

    photons: int
    seed: int
    angle_deg: float
    seconds: float
    compile_seconds: float
    events: int
    batches: int
    lanes: int
    batch_size: int
    max_steps: int
    R_specular: float
    R_diffuse: float
    R_diffuse_stderr: float
    R_order: np.ndarray
    R_order_stderr: np.ndarray
    T: float
    T_stderr: float
    T_order: np.ndarray
    T_order_stderr: np.ndarray
    A: float
    A_stderr: float
    A_layer: np.ndarray
    roulette_balance: float
    step_cap_hits: int
    step_cap_weight: float
    mean_exit_radius: float
    mean_exit_radius_stderr: float
    r_edges: np.ndarray | None = None
    R_r: np.ndarray | None = None
    R_r_stderr: np.ndarray | None = None
    R_r_order: np.ndarray | None = None
    R_r_order_stderr: np.ndarray | None = None
    T_r: np.ndarray | None = None
    T_r_stderr: np.ndarray | None = None
    T_r_order: np.ndarray | None = None
    T_r_order_stderr: np.ndarray | None = None
    x_edges: np.ndarray | None = None
    y_edges: np.ndarray | None = None
    R_xy: np.ndarray | None = None
    R_xy_stderr: np.ndarray | None = None
    R_xy_order: np.ndarray | None = None
    R_xy_order_stderr: np.ndarray | None = None
    pathlength_edges: np.ndarray | None = None
    R_r_path: np.ndarray | None = None
    R_r_path_stderr: np.ndarray | None = None
    exit_mu_edges: np.ndarray | None = None
    R_mu_phi: np.ndarray | None = None
    R_mu_phi_stderr: np.ndarray | None = None
    stderr_method: str = "photons"
    split_length: float | None = None
    split_start: float = 0.0
    split_stop: float | None = None
    devices: int = 1
    iterations: int = 0

    # --- Views -----------------------------------------------------------------------------------------------------
    @property
    def R_single(self) -> float:
        return float(self.R_order[1])

    @property
    def R_single_stderr(self) -> float:
        return float(self.R_order_stderr[1])

    @property
    def R_multiple(self) -> float:
        return float(self.R_order[2])

    @property
    def R_multiple_stderr(self) -> float:
        return float(self.R_order_stderr[2])

    @property
    def T_unscattered(self) -> float:
        return float(self.T_order[0])

    @property
    def T_unscattered_stderr(self) -> float:
        return float(self.T_order_stderr[0])

    @property
    def R_total(self) -> float:
        """``R_specular + R_diffuse``."""
        return self.R_specular + self.R_diffuse

    @property
    def weight_balance(self) -> float:
        """``R_specular + R_diffuse + T + A + roulette_balance + step_cap_weight``: 1 to rounding, by construction."""
        return self.R_specular + self.R_diffuse + self.T + self.A + self.roulette_balance + self.step_cap_weight

    @property
    def r_centres(self) -> np.ndarray | None:
        """Bin centres of ``r_edges`` (mm)."""
        return None if self.r_edges is None else 0.5 * (self.r_edges[1:] + self.r_edges[:-1])

    @property
    def annulus_areas(self) -> np.ndarray | None:
        """``pi (r_{i+1}^2 - r_i^2)`` (mm^2)."""
        return None if self.r_edges is None else np.pi * np.diff(self.r_edges**2)

    @property
    def lane_occupancy(self) -> float:
        """Fraction of lane slots that advanced a live photon: ``events / (iterations * lanes)`` (iterations summed
        over devices); below 1 by the batches' tails, where only the longest walks still run."""
        return self.events / (self.iterations * self.lanes) if self.iterations else float("nan")

    @property
    def photons_per_second(self) -> float:
        return self.photons / self.seconds if self.seconds > 0 else float("inf")

    def summary(self) -> dict:
        """The scalar results as a plain dict (JSON-ready floats and ints)."""
        keys = ("R_specular", "R_diffuse", "R_diffuse_stderr", "T", "T_stderr", "A", "A_stderr", "roulette_balance",
                "step_cap_hits", "step_cap_weight", "mean_exit_radius", "mean_exit_radius_stderr", "photons", "seed",
                "angle_deg", "seconds", "compile_seconds", "events")
        out = {k: getattr(self, k) for k in keys}
        out.update(R_single=self.R_single, R_single_stderr=self.R_single_stderr, R_multiple=self.R_multiple,
                   R_multiple_stderr=self.R_multiple_stderr, T_unscattered=self.T_unscattered,
                   T_unscattered_stderr=self.T_unscattered_stderr)
        return {k: (int(v) if isinstance(v, (int, np.integer)) else float(v)) for k, v in out.items()}
