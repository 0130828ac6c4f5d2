"""Test-suite settings: float64 and strict dtype promotion (DESIGN.md, "Precision"); compiled programs released after
each module; the heavy modules first."""

import gc
import os
from pathlib import Path

# XLA:CPU's fusion emitters off for the suite (set before the first backend starts, so xdist workers and the
# notebooks' kernels inherit it). The suite is mostly compilation, and these emitters cost about a quarter of it: the
# mc fit's program compiles in 11.4 s without them against 15.9 s, `jaxsss run` takes 57 s against 75 s, and the cold
# suite ran in 9m10s against 12m52s (docs/architecture.md, "Compilation in the test suite"). Code generation only: the
# Monte Carlo engine's results were bit-identical, fits and renders equal to rounding.
FAST_COMPILE_FLAG = "--xla_cpu_use_fusion_emitters=false"
if "xla_cpu_use_fusion_emitters" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {FAST_COMPILE_FLAG}".strip()

import jax  # noqa: E402
import pytest  # noqa: E402

import jaxsss  # noqa: E402,F401  (enables float64)

jax.config.update("jax_numpy_dtype_promotion", "strict")
# One CPU device, whatever runs first (`jaxsss mc` in-process would otherwise ask for one per core); the sharded
# Monte Carlo path is tested on 2 devices in a subprocess (tests/mc/test_sharding.py).
jax.config.update("jax_num_cpu_devices", 1)


@pytest.fixture(autouse=True)
def _float64():
    assert jax.config.jax_enable_x64


def _mapped_regions() -> int | None:
    """This process's memory mappings (lines of /proc/self/maps), or None where there is no such file."""
    try:
        with open("/proc/self/maps", "rb") as f:
            return sum(1 for _ in f)
    except OSError:
        return None


def _map_limit() -> int:
    try:
        return int(Path("/proc/sys/vm/max_map_count").read_text())
    except (OSError, ValueError):
        return 65530


RELEASE_AT = 0.6
"""Fraction of vm.max_map_count past which a module's end drops every compiled program. One module adds at most
~11,000 mappings (measured 2026-11-30: tests/render/test_bssrdf.py 10,136, the next 5,723), so a worker peaks below
0.6 x 65,530 + 11,000 = 50,300. At 0.4 each worker dropped its programs three times a run, 4-8.5 s a drop
(jax.clear_caches and gc.collect), and recompiled the ones later modules share."""


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop every compiled program when a module ends with the process past :data:`RELEASE_AT` of its mapping limit.
    Each XLA:CPU executable holds its own memory mappings (about 3 for a small program, hundreds for a fit or a
    render), and a test worker that keeps them all reaches Linux's vm.max_map_count (65530) after a few hundred
    tests: the next mmap fails inside XLA and the worker dies with a segmentation fault or "Failed to materialize
    symbols" (measured: one process running the suite in order crashed at 64,962 mappings, 7 GB resident). Below the
    threshold, programs that several modules share stay compiled (dropping after every module, with the persistent
    cache off, took the cold suite from 12m23s to 14m19s on 2 cores)."""
    yield
    n = _mapped_regions()
    if n is not None and n > RELEASE_AT * _map_limit():
        jax.clear_caches()
        gc.collect()


# Scopes (modules, or a notebook's class) that take longest on a cold start (mostly compilation), heaviest first:
# `make test` runs the suite on two xdist workers with `--dist loadscope --no-loadscope-reorder` (a module's tests and
# its module-scoped fixtures stay on one worker; xdist's own reorder, by test count, put the notebooks last), and a
# heavy scope scheduled last leaves the other worker idle. Cold seconds of each scope's tests under the two-worker
# load (`--durations=0`, 2026-11-27, 2 cores, fusion emitters off; 1269 s in all).
HEAVY_FIRST = (
    "tests/test_notebooks.py::TestNotebook_render_and_fit",  # 107
    "tests/fitting/test_profile_fit.py",  # 91
    "tests/cli/test_run.py",  # 81: the `jaxsss run` job (render, fit_image, Monte Carlo, mc fit)
    "tests/fitting/test_robust.py",  # 76: the randomised sweep subsets
    "tests/render/test_cache.py",  # 57
    "tests/test_notebooks.py::TestNotebook_fit_measured_materials",  # 53
    "tests/render/test_bssrdf.py",  # 52
    # Warm seconds (2026-11-30): last in collection order, test_stability left the other worker idle for the run's
    # final 34 s (per-worker timeline of a `make test`-like run); test_passage ran fourth from the end.
    "tests/render/test_passage.py",  # 47 warm
    "tests/test_stability.py",  # 38 warm
    "tests/test_benchmarks_render.py",  # 45
    "tests/fitting/test_mc_model.py",  # 38
    "tests/mc/test_white.py",  # 37
    "tests/mc/test_white_family.py",  # 36
    "tests/fitting/test_image_fit.py",  # 35
    "tests/render/test_renderer.py",  # 31
    "tests/fitting/test_g_fit.py",  # 31
    "tests/fitting/test_mco_fit.py",  # 29
    "tests/export/test_compare_bssrdf.py",  # 24
)


@pytest.hookimpl(tryfirst=True)
def pytest_unconfigure(config):
    """An xdist worker ends here, without the interpreter's teardown. Its results and exit status went to the main
    process at the end of its ``pytest_sessionfinish`` (xdist's hook wrapper sends "workerfinished" after every other
    implementation; ending there lost it, and the main process reported "node down: Not properly terminated"). What
    follows, pytest's last garbage collections and the destruction of every compiled program, MLIR context and
    JIT-linked object the worker made, took 10-12 s after a heavy module (py-spy, 2026-11-30) while the main process
    waited (xdist gives a worker 10 s to exit, then kills it): the suite's last test ended 14 s before the run did.
    Standard streams are flushed first. A plain ``pytest`` run (no workers) ends as usual."""
    if os.environ.get("PYTEST_XDIST_WORKER") is None:
        return
    import sys

    for stream in (sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__):
        try:
            stream.flush()
        except (AttributeError, OSError, ValueError):
            pass
    os._exit(0)


def pytest_collection_modifyitems(config, items):
    """Run the heavy scopes first (:data:`HEAVY_FIRST`, matched as prefixes of the test ids), the rest in collection
    order."""

    def rank(item):
        return next((i for i, scope in enumerate(HEAVY_FIRST) if item.nodeid.startswith(scope + "::")),
                    len(HEAVY_FIRST))

    items.sort(key=rank)  # stable: collection order within a module and among the rest
