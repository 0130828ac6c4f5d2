"""Process-wide JAX settings: float64 by default and a persistent compilation cache.

Precision (DESIGN.md, "Precision"): importing :mod:`jaxsss` enables ``jax_enable_x64`` (at once if JAX is already
imported, else right after JAX's first import: :class:`_ConfigureOnImport`). Float32 still works: pass
float32 arrays explicitly; the documented float32 error bounds are in ``docs/architecture.md`` and checked by
``tests/test_stability.py``.

Compilation cache: a fit, a Monte Carlo run or a render compiles its XLA programs once per process, which costs
seconds; JAX's persistent cache stores them on disk so that the next process loads them instead. It is on by
default in ``$XDG_CACHE_HOME/jaxsss/jax`` (``~/.cache/jaxsss/jax``). The environment variable
``JAXSSS_COMPILATION_CACHE`` chooses another root directory, or turns the cache off with ``0``, ``off``, ``false`` or
``no``. A cache directory that the user has already given JAX (``JAX_COMPILATION_CACHE_DIR`` or
``jax.config.update("jax_compilation_cache_dir", ...)`` before importing jaxsss) is left as it is.

Compiled CPU programs are machine code for the CPU that compiled them, and JAX's cache key does not name that CPU
(jaxlib 0.10: the platform is "cpu" and the topology fingerprint ignores instruction-set extensions). A home
directory shared by machines with different CPUs (a cluster's network home, a CI runner pool with a persistent
cache) would hand one machine's AVX-512 code to another: the loader rejects it at best, and the code faults at worst. So
the cache lives in a subdirectory per CPU, :func:`host_key`: the architecture and a digest of the model name and
instruction-set flags. (A CI run that died in ``backend.deserialize_executable`` first suggested the cache; the cause
was the process's memory mappings, docs/architecture.md "Long processes and memory mappings": the same worker died
in serialisation and in plain compilation with the cache off.)
"""

from __future__ import annotations

import hashlib
import importlib.abc
import importlib.util
import os
import platform
import sys
from functools import lru_cache
from pathlib import Path

CACHE_ENV = "JAXSSS_COMPILATION_CACHE"
"""Environment variable: a directory for the compilation cache, or 0/off/false/no to disable it."""

_OFF = {"0", "off", "false", "no", "none", ""}
MIN_COMPILE_SECONDS = 0.05
"""Programs that compile faster than this are not written to the cache (loading them would not pay)."""


COMPILE_BOUND_OPTIONS = {"xla_cpu_use_fusion_emitters": False}
"""XLA compiler options for the programs that compile for far longer than they run: the fits (a profile fit runs in
milliseconds after a compilation of seconds). XLA:CPU's fusion emitters cost about a quarter of the compilation
(measured 2026-11-27 on 2 shared cores, whose timings vary by ~30% between runs: the white-MC fit's program 11.4 s
without them against 15.9 s back to back; `jaxsss fit` cold 5.2-5.5 s against 6.3 s for the dipole and 22-23 s
against 28.5 s for mc) and gave no speed to these programs (1000 dipole fits: 0.18 s against 0.21 s). Not used for
the Monte Carlo engine, which runs 36% slower without them (docs/architecture.md, "Compilation in the test
suite")."""


def compile_bound_options() -> dict | None:
    """:data:`COMPILE_BOUND_OPTIONS` for ``jax.jit(..., compiler_options=...)`` on the CPU backend (they are XLA:CPU
    options), else ``None``."""
    import jax

    return dict(COMPILE_BOUND_OPTIONS) if jax.default_backend() == "cpu" else None


RENDER_COMPILER_OPTIONS = {"xla_cpu_experimental_ynn_fusion_type": ""}
"""XLA compiler options of the renderer's image programs (``eqx.filter_jit(..., compiler_options=...)``): no YNNPACK
fusions. XLA:CPU (jaxlib 0.10) hands reductions and the elementwise work around them to YNNPACK; in the white
kernels' pair sums (gathers, a sum over a few nodes, float64) that took 10-20x as long as XLA's own loops: the eye's
cut-beam factor 81 -> 4 ms per block of 2^16 pairs, the skin1 sphere's image 0.77 -> 0.54 s (measured 2026-11-28,
docs/benchmarks.md). Not set process-wide: the Monte Carlo engine was not faster without them. The option is a field
of XLA's DebugOptions, which every backend accepts; only XLA:CPU reads it. :func:`render_jit` applies them."""


def render_jit(fun):
    """``eqx.filter_jit(fun)`` compiled with :data:`RENDER_COMPILER_OPTIONS` when called at top level, and without
    them inside another trace (a user's ``jax.jit``, a fit's residuals), where JAX refuses compiler options on a
    nested jit: the outer program's options apply there. ``.lower`` is the top-level one's."""
    import functools

    import equinox as eqx
    import jax

    plain = eqx.filter_jit(fun)
    tuned = eqx.filter_jit(fun, compiler_options=RENDER_COMPILER_OPTIONS)

    @functools.wraps(fun)
    def call(*args, **kwargs):
        if any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves((args, kwargs))):
            return plain(*args, **kwargs)
        try:
            return tuned(*args, **kwargs)
        except ValueError as e:  # traced after all (the arguments were closed-over constants): nested
            if "top-level" not in str(e):
                raise
            return plain(*args, **kwargs)

    call.lower = tuned.lower
    call.compiler_options = RENDER_COMPILER_OPTIONS  # (for jaxsss._exported.compiled_program)
    return call


def to_device(a):
    """The host array ``a`` (NumPy, or None) as a JAX array on the default device, for the geometry a render or fit
    hands to its compiled programs.

    ``jax.device_put`` copies. ``jnp.asarray`` of a host array binds ``lax.stage``, which under JAX 0.10 compiles
    and runs an identity program for every new shape and dtype (17 ms each against 0.2 ms; a scene's ``prepare``
    moves about 25 arrays whose shapes change with the resolution and the samples)."""
    import jax
    import numpy as np

    return None if a is None else jax.device_put(np.asarray(a))


def host_jit(fun):
    """``numba.njit(fun, cache=True, nogil=True)``: the renderer's compiled host loops (the octree traversal, the
    near-field split, the refinement of Embree's hits), their machine code cached on disk beside the module or in
    the user's cache directory. Where Numba can write to neither (a read-only install and home), ``cache=True`` is
    refused when the function is decorated; the function is then compiled in each process (the traversal in about
    6 s), and a warning says so."""
    import warnings

    import numba

    try:
        return numba.njit(cache=True, nogil=True)(fun)
    except RuntimeError as e:
        if "no locator available" not in str(e):
            raise
        warnings.warn(f"Numba cannot cache {fun.__qualname__} (no writable cache directory; NUMBA_CACHE_DIR chooses "
                      "one): it is compiled in each process", stacklevel=2)
        return numba.njit(nogil=True)(fun)


_CPU_FIELDS = ("vendor_id", "model name", "flags", "cpu family", "model", "Features", "CPU implementer",
               "CPU architecture", "CPU variant", "CPU part", "isa", "cpu")
"""/proc/cpuinfo fields (x86, arm64, riscv, power) that name the CPU and its instruction-set extensions."""


@lru_cache(maxsize=None)
def host_key(cpuinfo: str | None = None) -> str:
    """This machine's CPU as a directory name: ``<architecture>-<12 hex digits>``, the digits a SHA-256 of the first
    processor's model and instruction-set fields in ``/proc/cpuinfo`` (``platform.processor()`` where there is no
    such file). Two machines share compiled programs only when the key matches. ``cpuinfo``: the file's text, for
    tests."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text(errors="replace")
        except OSError:
            cpuinfo = ""
    first = cpuinfo.strip().split("\n\n")[0]  # the first processor's block
    fields = sorted(line.strip() for line in first.splitlines() if line.split(":")[0].strip() in _CPU_FIELDS)
    text = "\n".join(fields) if fields else f"{platform.processor()}\n{platform.platform()}"
    return f"{platform.machine() or 'unknown'}-{hashlib.sha256(text.encode()).hexdigest()[:12]}"


def compilation_cache_dir() -> Path | None:
    """The directory jaxsss asks JAX to cache compiled programs in, ``<root>/<host_key()>``, or None when the cache is
    turned off. The root is ``$JAXSSS_COMPILATION_CACHE`` when set, else ``$XDG_CACHE_HOME/jaxsss/jax``."""
    value = os.environ.get(CACHE_ENV)
    if value is not None:
        if value.strip().lower() in _OFF:
            return None
        root = Path(value).expanduser()
    else:
        root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "jaxsss" / "jax"
    return root / host_key()


def enable_compilation_cache(path: str | os.PathLike | None = None) -> Path | None:
    """Turn on JAX's persistent compilation cache in ``path`` (default :func:`compilation_cache_dir`).

    Returns the directory in use, or None when the cache is off (``JAXSSS_COMPILATION_CACHE=0``) or the directory
    cannot be created (a read-only home, say: the cache is an optimisation, never a reason to fail).
    """
    import jax

    if jax.config.jax_compilation_cache_dir and path is None:  # the user configured JAX directly
        return Path(jax.config.jax_compilation_cache_dir)
    directory = Path(path) if path is not None else compilation_cache_dir()
    if directory is None:
        return None
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(directory))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return directory


def _configure_jax(jax) -> None:
    jax.config.update("jax_enable_x64", True)
    enable_compilation_cache()


class _ConfigureOnImport(importlib.abc.MetaPathFinder):
    """Configures JAX right after its first import (float64, the cache), so that importing :mod:`jaxsss` does not
    import JAX itself: a command that needs no JAX (``jaxsss reparam`` of one value, ``--help``) starts in a
    fraction of a second (issue 18). Every jaxsss module that uses JAX imports it, which runs this first."""

    def find_spec(self, name, path=None, target=None):
        if name != "jax":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec("jax")
        if spec is None or spec.loader is None:
            return spec
        run = spec.loader.exec_module

        def exec_module(module):
            run(module)
            _configure_jax(module)

        spec.loader.exec_module = exec_module
        return spec


if "jax" in sys.modules:  # imported before jaxsss
    _configure_jax(sys.modules["jax"])
elif not any(isinstance(f, _ConfigureOnImport) for f in sys.meta_path):
    sys.meta_path.insert(0, _ConfigureOnImport())
