"""Shared benchmark machinery: timing after compilation, the row schema, and the JSON and PNG writers.

Timing rule (DESIGN.md): the first call (tracing + XLA compilation + one run) is timed on its own and reported as
``compile_seconds``; it is never part of ``seconds``. Then ``repeats`` further calls are timed, each ended by
:func:`jax.block_until_ready` so that JAX's asynchronous dispatch cannot hide work. ``seconds`` is their minimum and
``median_seconds`` their median: the benchmark machine is shared (2 cores, other jobs running), and other load only
ever adds time, so the minimum is the least load-sensitive estimate of a call's own cost. :func:`time_interleaved`
times several methods round-robin, so that load that comes and goes hits every method alike.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import platform
import statistics
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import jax
import numpy as np

__all__ = [
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

ROW_KEYS = ("benchmark", "method", "setting", "error", "error_metric", "seconds", "compile_seconds")
"""Keys every row carries, in this order; benchmarks add their own extra keys after them."""

DEFAULT_OUT = Path(__file__).resolve().parent / "results"


@dataclass(frozen=True)
class Timing:
    """Result of :func:`time_call`: seconds are wall-clock, after ``block_until_ready``."""

    compile_seconds: float  # first call: trace + compile + one run
    seconds: float  # minimum of the timed repeats (see the module docstring)
    median_seconds: float
    repeats: int
    output: Any  # output of the last call, for error measurement


def _timed(fn, args, kwargs):
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args, **kwargs))
    return time.perf_counter() - t0, out


def time_interleaved(calls: dict, repeats: int = 5) -> dict:
    """Time several calls round-robin: ``calls`` maps a label to ``(fn, args)`` or ``(fn, args, kwargs)``.

    Each call's first run is timed alone (``compile_seconds``); then ``repeats`` rounds run every call once.
    Works for JAX and NumPy callables alike (``block_until_ready`` passes NumPy arrays through). For NumPy the first
    call is a warm-up (page faults, caches); rows for methods that do not compile report ``None`` instead.
    """
    if repeats < 1:
        raise ValueError(f"time_interleaved(repeats={repeats}): allowed range [1, inf)")
    norm = {k: (c[0], tuple(c[1]), dict(c[2]) if len(c) > 2 else {}) for k, c in calls.items()}
    first, outs, times = {}, {}, {k: [] for k in norm}
    for k, (fn, args, kwargs) in norm.items():
        first[k], outs[k] = _timed(fn, args, kwargs)
    for _ in range(repeats):
        for k, (fn, args, kwargs) in norm.items():
            t, outs[k] = _timed(fn, args, kwargs)
            times[k].append(t)
    return {k: Timing(first[k], min(times[k]), statistics.median(times[k]), repeats, outs[k]) for k in norm}


def time_call(fn: Callable, *args, repeats: int = 5, **kwargs) -> Timing:
    """Time ``fn(*args, **kwargs)``: the first call separately, then ``repeats`` calls (see :class:`Timing`)."""
    if repeats < 1:
        raise ValueError(f"time_call(repeats={repeats}): allowed range [1, inf)")
    return time_interleaved({"call": (fn, args, kwargs)}, repeats)["call"]


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_info() -> dict:
    """Platform, CPU, core count and library versions, for the JSON header."""
    import jaxlib

    return {
        "platform": platform.platform(),
        "cpu": _cpu_model(),
        "cpu_count": os.cpu_count(),
        # Cores this process may run on (fewer under `taskset`); XLA sizes its CPU thread pool from this.
        "usable_cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "numpy": np.__version__,
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "x64": bool(jax.config.jax_enable_x64),
        # The machine is shared: the 1-minute load average at write time says how busy it was.
        "loadavg_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
    }


def _clean(value):
    """JSON-safe scalars: NumPy/JAX scalars to Python, non-finite floats to ``None`` (strict JSON has no NaN)."""
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, (np.ndarray, jax.Array)):
        arr = np.asarray(value)
        if arr.size > 16:
            raise ValueError(f"row value of shape {arr.shape}: keep JSON small, no raw arrays")
        return _clean(arr.tolist() if arr.ndim else arr.item())
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return v if math.isfinite(v) else None
    return value


def make_row(benchmark: str, method: str, setting, error, error_metric: str, seconds, compile_seconds, **extra) -> dict:
    """One result row with the schema :data:`ROW_KEYS` plus ``extra`` keys; validates and converts to JSON scalars.

    ``error`` is a float >= 0 (``None`` if it could not be measured); ``seconds`` > 0; ``compile_seconds`` >= 0 or
    ``None`` (no compilation, e.g. NumPy).
    """
    if not (isinstance(benchmark, str) and isinstance(method, str) and isinstance(error_metric, str)):
        raise TypeError("make_row: benchmark, method and error_metric must be strings")
    seconds = float(seconds)
    if not (seconds > 0 and math.isfinite(seconds)):
        raise ValueError(f"make_row(seconds={seconds}): allowed range (0, inf)")
    if compile_seconds is not None:
        compile_seconds = float(compile_seconds)
        if not compile_seconds >= 0:
            raise ValueError(f"make_row(compile_seconds={compile_seconds}): allowed range [0, inf) or None")
    if error is not None:
        error = float(error)
        if error < 0:
            raise ValueError(f"make_row(error={error}): allowed range [0, inf] or None")
    row = {
        "benchmark": benchmark,
        "method": method,
        "setting": setting,
        "error": error,
        "error_metric": error_metric,
        "seconds": seconds,
        "compile_seconds": compile_seconds,
    }
    row.update(extra)
    return _clean(row)


def plot_rows(rows: Sequence[dict], path, title: str, error_floor: float = 1e-17, connect: bool = True) -> Path:
    """Log-log PNG of error against seconds, one marker series per method, each point labelled by its setting.

    Errors below ``error_floor`` (an exact 0, e.g. the reference itself) are drawn at the floor, with open markers.
    ``connect`` joins a method's points in row order (for a sweep of one knob); ``False`` draws markers only.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    fig, ax = plt.subplots(figsize=(7.5, 5.0))
    markers = "osD^v<>phX*"
    methods = list(dict.fromkeys(r["method"] for r in rows))
    for k, method in enumerate(methods):
        pts = [r for r in rows if r["method"] == method and r["error"] is not None]
        if not pts:
            continue
        x = np.array([r["seconds"] for r in pts])
        y = np.array([max(r["error"], error_floor) for r in pts])
        floored = np.array([r["error"] < error_floor for r in pts])
        line = ax.plot(x, y, marker=markers[k % len(markers)], linestyle="-" if connect else "none", label=method,
                       alpha=0.85)[0]
        if floored.any():
            ax.plot(x[floored], y[floored], marker=markers[k % len(markers)], linestyle="none", markersize=11,
                    markerfacecolor="none", color=line.get_color())
        for xi, yi, r in zip(x, y, pts):
            ax.annotate(str(r["setting"]), (xi, yi), textcoords="offset points", xytext=(4, 3), fontsize=7)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("seconds per call (min of repeats, after compilation)")
    metrics = sorted({r["error_metric"] for r in rows})
    ax.set_ylabel("error" if len(metrics) != 1 else f"error: {metrics[0]}", fontsize=8)
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_results(name: str, rows: Sequence[dict], out_dir, *, quick: bool, summary: dict | None = None,
                  notes: Sequence[str] = (), title: str | None = None, connect: bool = True) -> tuple[Path, Path]:
    """Write ``out_dir/<name>.json`` (header, summary, notes, rows) and ``out_dir/<name>.png``; return both paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    for r in rows:
        missing = [k for k in ROW_KEYS if k not in r]
        if missing:
            raise ValueError(f"write_results({name!r}): a row lacks {missing}; build rows with make_row")
    doc = {
        "benchmark": name,
        "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "quick": bool(quick),
        "machine": machine_info(),
        "summary": _clean(summary or {}),
        "notes": list(notes),
        "rows": [_clean(r) for r in rows],
    }
    json_path = out_dir / f"{name}.json"
    json_path.write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n")
    png_path = plot_rows(rows, out_dir / f"{name}.png", title or f"{name} ({'quick' if quick else 'full'})",
                         connect=connect)
    return json_path, png_path


def parse_args(argv, description: str) -> argparse.Namespace:
    """The common command line: ``--quick`` and ``--out DIR`` (default ``benchmarks/results``)."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--quick", action="store_true", help="small sizes; finishes in well under a minute")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="directory for <name>.json and <name>.png")
    p.add_argument("--tag", default="", help="suffix for the file names, e.g. _1core for a `taskset -c 0` run")
    return p.parse_args(list(argv) if argv is not None else None)
