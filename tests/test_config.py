"""Process-wide settings (jaxsss._config): float64 and the persistent compilation cache."""

import os
import subprocess
import sys
from pathlib import Path

import jax
import pytest

import jaxsss
from jaxsss._config import CACHE_ENV, host_key


def test_float64_is_default():
    assert jax.numpy.asarray(1.0).dtype == jax.numpy.float64


def test_cache_dir_follows_environment(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "c"))
    assert jaxsss.compilation_cache_dir() == tmp_path / "c" / host_key()
    for off in ("0", "off", "False", "no", ""):
        monkeypatch.setenv(CACHE_ENV, off)
        assert jaxsss.compilation_cache_dir() is None
    monkeypatch.delenv(CACHE_ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert jaxsss.compilation_cache_dir() == tmp_path / "jaxsss" / "jax" / host_key()


_X86 = """processor\t: 0
vendor_id\t: AuthenticAMD
cpu family\t: 25
model\t\t: 1
model name\t: AMD EPYC 7B13
cpu MHz\t\t: {mhz}
flags\t\t: fpu sse2 avx avx2{extra}
bogomips\t: 4900.00

processor\t: 1
vendor_id\t: AuthenticAMD
flags\t\t: fpu sse2 avx avx2 avx512f
"""


def test_host_key_names_the_cpu_and_its_instruction_sets():
    """Compiled CPU programs are not shared between CPUs with different instruction sets (a CI pool or a cluster home
    with one cache): the key changes with the flags and the model, not with the clock or other processors' lines."""
    base = host_key.__wrapped__(_X86.format(mhz="2450.0", extra=""))
    assert base == host_key.__wrapped__(_X86.format(mhz="3100.5", extra=""))  # the clock does not matter
    assert base != host_key.__wrapped__(_X86.format(mhz="2450.0", extra=" avx512f"))
    assert base != host_key.__wrapped__(_X86.format(mhz="2450.0", extra="").replace("7B13", "9654"))
    arch, digest = base.rsplit("-", 1)
    assert arch and len(digest) == 12 and int(digest, 16) >= 0
    no_cpuinfo = host_key.__wrapped__("")  # no /proc/cpuinfo (macOS, Windows): the platform's description
    assert no_cpuinfo.startswith(arch + "-") and no_cpuinfo != base


_PROGRAM = """
import jax, jax.numpy as jnp, jaxsss, time
f = jax.jit(lambda x: jnp.sum(jnp.sin(x) ** 2 + jnp.cumsum(jnp.exp(-x)) @ jnp.ones((64, 64))))
print(jax.config.jax_compilation_cache_dir)
f(jnp.ones(64)).block_until_ready()
"""


def _run(env):
    out = subprocess.run([sys.executable, "-c", _PROGRAM], env=env, capture_output=True, text=True, check=True)
    return out.stdout.strip()


def test_compiled_programs_persist_across_processes(tmp_path):
    cache = tmp_path / "cache"
    env = {**os.environ, CACHE_ENV: str(cache), "JAX_PLATFORMS": "cpu"}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    assert _run(env) == str(cache / host_key())

    def program_entries():  # the jitted lambda's cache files and their modification times
        return {p.name: p.stat().st_mtime_ns for p in Path(cache).rglob("jit__lambda*") if p.is_file()}

    first = program_entries()
    assert len(first) == 1, f"the first process wrote {sorted(first)} for the program (expected one entry)"
    # The second process loads the entry: no new key and no rewrite. (Small helper programs such as a broadcast may
    # or may not be written, depending on whether their compile time crossed MIN_COMPILE_SECONDS on a loaded machine.)
    _run(env)
    assert program_entries() == first


def test_cache_can_be_turned_off(tmp_path):
    env = {**os.environ, CACHE_ENV: "off", "XDG_CACHE_HOME": str(tmp_path), "JAX_PLATFORMS": "cpu"}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    assert _run(env) in ("None", "")
    assert not (tmp_path / "jaxsss").exists()


def test_compile_bound_options_are_xla_options_that_change_nothing_but_compilation():
    """The fits' compiler options (jaxsss._config.COMPILE_BOUND_OPTIONS) name real XLA options (XLA refuses an unknown
    name: "No such compile option") and give the same numbers as the default code generation."""
    import jax
    import jax.numpy as jnp

    from jaxsss._config import COMPILE_BOUND_OPTIONS, compile_bound_options

    opts = compile_bound_options()
    assert opts == COMPILE_BOUND_OPTIONS and opts is not COMPILE_BOUND_OPTIONS  # a copy: callers cannot alter it
    x = jnp.linspace(0.1, 3.0, 257)

    def f(x):
        return jnp.sum(jnp.exp(-x) * jnp.sin(3.0 * x) / x)

    assert float(jax.jit(f, compiler_options=opts)(x)) == pytest.approx(float(jax.jit(f)(x)), rel=1e-14)
    with pytest.raises(jax.errors.JaxRuntimeError, match="No such compile option"):
        jax.jit(f, compiler_options={**opts, "xla_not_an_option": True})(x)


def test_render_jit_takes_its_options_at_top_level_and_none_when_nested():
    """jaxsss._config.render_jit: the options are real XLA options (the top-level program has no YNNPACK fusion and the
    same numbers), and the function still runs inside a user's jit, with the argument traced or closed over (JAX
    refuses compiler options on a nested jit)."""
    import jax
    import jax.numpy as jnp

    from jaxsss._config import RENDER_COMPILER_OPTIONS, render_jit

    def f(x):
        return jnp.sum(jnp.exp(-x) * x, axis=-1)

    g = render_jit(f)
    x = jnp.linspace(0.1, 3.0, 4096 * 8).reshape(4096, 8)
    expected = jax.jit(f)(x)
    assert "ynn" not in g.lower(x).compile().compiled.as_text()
    assert "ynn" not in jax.jit(f, compiler_options=RENDER_COMPILER_OPTIONS).lower(x).compile().as_text()
    assert jnp.allclose(g(x), expected, rtol=1e-14)
    assert jnp.allclose(jax.jit(lambda y: g(y) * 2.0)(x), 2.0 * expected, rtol=1e-14)  # traced argument
    assert jnp.allclose(jax.jit(lambda s: g(x) * s)(2.0), 2.0 * expected, rtol=1e-14)  # closed over
    assert jnp.allclose(jax.jvp(g, (x,), (jnp.ones_like(x),))[0], expected, rtol=1e-14)


def _add(a, b):
    return a + b


def test_host_jit_caches_on_disk_and_compiles_without_a_place_to_cache(monkeypatch):
    """The renderer's Numba loops cache their machine code; where Numba finds no writable place for it (every cache
    locator declines, as on a read-only install and home), the loop still compiles, uncached, with a warning."""
    import numba.core.caching as caching

    from jaxsss._config import host_jit

    cached = host_jit(_add)
    assert cached(2, 3) == 5 and isinstance(cached._cache, caching.FunctionCache)
    monkeypatch.setattr(caching.CacheImpl, "_locator_classes", [])
    with pytest.warns(UserWarning, match="Numba cannot cache _add"):
        uncached = host_jit(_add)
    assert uncached(2, 3) == 5 and isinstance(uncached._cache, caching.NullCache)


_HOST_LOOPS = """
import numpy as np, trimesh
from jaxsss.render import interactions, pairs, rays
from jaxsss.render.octree import build_octree
rng = np.random.default_rng(0)
p = rng.normal(size=(500, 3))
tree = build_octree(p, np.full(500, 0.01), np.ones(500))
inter = interactions.build_interactions(tree, p[:50], 0.1)
pairs.split_near(inter, p[:50], tree, 0.5)
rays.SceneGeometry(trimesh.creation.icosphere(2)).first_hit(np.zeros((4, 3)), np.eye(3)[[0, 1, 2, 0]])
loops = (interactions._compiled_traversal(), pairs._compiled_split(), rays._compiled_refine())
print([sum(f.stats.cache_misses.values()) for f in loops], [sum(f.stats.cache_hits.values()) for f in loops])
"""


def test_host_loops_load_their_machine_code_in_a_new_process():
    """The renderer's Numba loops compile once per machine: a second process finds every one in the disk cache
    (a loop that closes over a jitted helper gets a new cache key in every process, and compiles every time)."""
    run = [sys.executable, "-c", _HOST_LOOPS]
    subprocess.run(run, check=True, capture_output=True, text=True, timeout=600)
    out = subprocess.run(run, check=True, capture_output=True, text=True, timeout=600).stdout.split("\n")[-2]
    assert out == "[0, 0, 0] [1, 1, 1]", out
