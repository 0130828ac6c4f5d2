"""Traced programs kept on disk (:mod:`jax.export`), so that a new process skips tracing and lowering a fit or a
render.

JAX's persistent compilation cache stores compiled programs, but every process still traces and lowers each jitted
function before it can look one up: for an image fit on the white kernel that is 8-10 s of a warm first fit (the
solve's trace alone 6 s), for a white-kernel render about 2 s, paid again by every notebook restart.
:func:`exported_program` serialises the traced and lowered program next to the compilation cache, keyed by

- the caller's description of everything the trace baked in (its configuration, its static arguments),
- the arguments' tree structure, shapes and dtypes,
- :func:`source_digest`: the code and data files of ``jaxsss`` and ``fitting`` and the versions of the libraries that
  trace (a changed table or solver release is a new key),

and the compilation cache then serves the compiled program. A key's file that cannot be read is exported again; for a
function that cannot be exported (custom calls without a compatibility guarantee) :func:`exported_program` returns
None for the rest of the process and the caller compiles as before. Without a cache directory
(``JAXSSS_COMPILATION_CACHE=off``) nothing is written.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import importlib.util
import os
from functools import lru_cache
from pathlib import Path

import jax
import numpy as np

__all__ = ["compiled_program", "export_dir", "exported_program", "source_digest"]

DIGEST_SUFFIXES = (".py", ".npz", ".csv", ".txt", ".json")
"""The files of ``jaxsss`` and ``fitting`` that a trace can read: code and the shipped tables."""
TRACING_LIBRARIES = ("jax", "jaxlib", "equinox", "optimistix", "lineax")

PINNED_CUSTOM_CALLS = ("lapack_sormqr_ffi", "lapack_dormqr_ffi", "lapack_cunmqr_ffi", "lapack_zunmqr_ffi")
"""LAPACK calls that JAX's export does not guarantee across jaxlib releases (``Q^T b`` of lineax's QR solve, in the
image fit's Levenberg-Marquardt steps). They are allowed here because :func:`source_digest` covers the jaxlib version:
a stored program is only read back by the jaxlib that wrote it."""
_PINNED_CUSTOM_CALLS = [jax.export.DisabledSafetyCheck.custom_call(t) for t in PINNED_CUSTOM_CALLS]
_LOADED: dict = {}
"""Full key -> the compiled program, or False (not exportable: the caller compiles as before)."""


def _package_dirs() -> list[Path]:
    """The directories of ``jaxsss`` and ``fitting`` (found, not imported: jaxsss does not depend on fitting)."""
    dirs = []
    for name in ("jaxsss", "fitting"):
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.submodule_search_locations:
            dirs.extend(Path(p) for p in spec.submodule_search_locations)
    return dirs


def source_digest() -> str:
    """A digest of what a trace can depend on beyond its arguments: the code and data files of ``jaxsss`` and
    ``fitting`` and the versions of :data:`TRACING_LIBRARIES`. An exported program is reused only by the code, tables
    and libraries that made it."""
    h = hashlib.sha256()
    for name in TRACING_LIBRARIES:
        try:
            h.update(f"{name}=={importlib.metadata.version(name)};".encode())
        except importlib.metadata.PackageNotFoundError:
            h.update(f"{name} absent;".encode())
    for pkg in _package_dirs():
        for f in sorted(p for p in pkg.rglob("*") if p.suffix in DIGEST_SUFFIXES and "__pycache__" not in p.parts):
            h.update(str(f.relative_to(pkg)).encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:16]


@lru_cache(maxsize=None)
def export_dir() -> Path | None:
    """``<compilation cache>/exported/<source_digest>``, created; None when the cache is off or cannot be written."""
    from jaxsss._config import compilation_cache_dir

    d = compilation_cache_dir()
    if d is None:
        return None
    d = d / "exported" / source_digest()
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    return d


def _config_key() -> str:
    """The JAX settings that change what a trace produces, and the platform the program is for."""
    return repr((jax.default_backend(), jax.config.jax_enable_x64, jax.config.jax_numpy_dtype_promotion,
                 jax.config.jax_default_matmul_precision))


def exported_program(name: str, key: str, fun, args: tuple, compiler_options=None):
    """The compiled program of ``jax.jit(fun)`` for ``args``' shapes, through a serialised export (module docstring);
    None when there is no export directory or ``fun`` cannot be exported (the caller then compiles as before).

    Args:
        name: the file name's prefix (``"fit"``, ``"image-solve"``).
        key: everything ``fun``'s trace depends on besides the arguments' structure, shapes and dtypes (a
            configuration's repr, static arguments). Two calls with equal keys and shapes must trace to the same
            program; a key holding an elided array repr (``...``) is refused (None).
        fun: a function of pytrees of arrays returning a pytree of arrays.
        args: example arguments (a tuple of pytrees of arrays); the program is compiled for their shapes.
        compiler_options: XLA options for the compilation.

    Returns:
        The compiled program, called as ``program(*args)`` with arguments of the same structure and shapes.
    """
    directory = export_dir()
    if directory is None or "..." in key or importlib.util.find_spec("flatbuffers") is None:
        return None  # (export's serialisation needs flatbuffers)
    leaves, treedef = jax.tree_util.tree_flatten(args)
    shapes = [(np.shape(x), str(x.dtype if hasattr(x, "dtype") else np.asarray(x).dtype)) for x in leaves]
    full = hashlib.sha256(repr((name, key, _config_key(), str(treedef), shapes)).encode()).hexdigest()[:24]
    program = _LOADED.get(full)
    if program is False:
        return None
    if program is None:
        program = _LOADED[full] = _load_or_export(directory / f"{name}-{full}.bin", fun, treedef, leaves,
                                                  compiler_options)
        if program is False:
            return None
    return lambda *args: program(*jax.tree_util.tree_leaves(args))


def _load_or_export(path: Path, fun, treedef, leaves, compiler_options):
    """The compiled program of ``fun`` over the flat ``leaves`` (export serialises only standard containers, not the
    callers' modules), read from ``path`` or exported and written there; False when ``fun`` cannot be exported."""
    exp = None
    if path.exists():
        try:
            exp = jax.export.deserialize(bytearray(path.read_bytes()))
        except Exception:  # a damaged or foreign file: export again
            exp = None
    if exp is None:
        def flat(*leaves):
            return fun(*jax.tree_util.tree_unflatten(treedef, leaves))

        try:
            exp = jax.export.export(jax.jit(flat), disabled_checks=_PINNED_CUSTOM_CALLS)(*leaves)
            data = exp.serialize()
        except ValueError:  # e.g. custom calls with no compatibility guarantee, or an output it cannot serialise
            return False
        try:
            tmp = path.with_suffix(f".{os.getpid()}.tmp")
            tmp.write_bytes(data)
            tmp.replace(path)
        except OSError:
            pass
    return jax.jit(exp.call).lower(*leaves).compile(compiler_options)


def compiled_program(name: str, jitted, args: tuple, static: tuple = (), compiler_options=None):
    """``jitted(*args, *static)`` compiled for ``args``' shapes, called as ``program(*args)``: through
    :func:`exported_program` where it can be (a new process skips tracing and lowering), else lowered and compiled.

    ``jitted`` is a module-level jitted function (``eqx.filter_jit``, :func:`jaxsss._config.render_jit`) that reads
    nothing but its arguments, the package's code and its data files. The export's key is everything in ``args``
    that is not an array (the static fields of modules, Python scalars and strings) and ``static``; a key that shows
    an object's address (`` at 0x``) is refused, since it would differ in every process. ``compiler_options`` are
    added to the jitted function's own (``jitted.compiler_options``, as :func:`~jaxsss._config.render_jit` sets),
    as ``Lowered.compile`` adds them."""
    import equinox as eqx

    dyn, rest = eqx.partition(args, eqx.is_array)
    key = repr((getattr(jitted, "__qualname__", repr(jitted)), str(jax.tree_util.tree_structure(rest)),
                jax.tree_util.tree_leaves(rest), static))

    def pure(dyn):
        return jitted(*eqx.combine(dyn, rest), *static)

    options = {**(getattr(jitted, "compiler_options", None) or {}), **(compiler_options or {})} or None
    program = None if " at 0x" in key else exported_program(name, key, pure, (dyn,), options)
    if program is None:
        compiled = jitted.lower(*args, *static).compile(compiler_options)
        return (lambda *a: compiled(*a, *static)) if static else compiled
    return lambda *a: program(eqx.partition(a, eqx.is_array)[0])
