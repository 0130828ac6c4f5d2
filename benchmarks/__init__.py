"""Benchmarks: error against run time for every method that trades accuracy for speed (DESIGN.md, "Benchmarks").

Each benchmark is a module with ``main(argv)`` taking ``--quick`` and ``--out DIR``; it writes ``DIR/<name>.json``
(rows, summary, date and machine) and ``DIR/<name>.png`` (log-log error against seconds). Run them all with
``python -m benchmarks.run_all [--quick]``. The shared timing, row schema and writers live in
:mod:`benchmarks._harness`.
"""

from benchmarks._harness import (
    ROW_KEYS,
    Timing,
    machine_info,
    make_row,
    parse_args,
    plot_rows,
    time_call,
    time_interleaved,
    write_results,
)

BENCHMARKS = ("profile_throughput", "rd_inversion", "mc_throughput", "transport_error", "fit_speed", "fit_accuracy",
              "fit_sweep", "render_eps", "render_density", "render_bssrdf_sampling", "render_cache", "photon_diffusion",
              "layered", "photon_render", "white_far_field", "render_vs_path_tracer", "mcml_fits", "replay_fits",
              "white_interpolation", "fit_path_traced", "curvature_transport", "sphere_transport", "render_materials")
"""Module names under :mod:`benchmarks` run by :mod:`benchmarks.run_all`, in order."""

__all__ = [
    "BENCHMARKS",
    "ROW_KEYS",
    "Timing",
    "machine_info",
    "make_row",
    "parse_args",
    "plot_rows",
    "time_call",
    "time_interleaved",
    "write_results",
]
