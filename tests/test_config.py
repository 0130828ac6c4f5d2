"""Process-wide settings (jaxsss._config): float64 and the persistent compilation cache."""

import os
import subprocess
import sys
from pathlib import Path

import jax

import jaxsss
from jaxsss._config import CACHE_ENV


def test_float64_is_default():
    assert jax.numpy.asarray(1.0).dtype == jax.numpy.float64


def test_cache_dir_follows_environment(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "c"))
    assert jaxsss.compilation_cache_dir() == tmp_path / "c"
    for off in ("0", "off", "False", "no"):
        monkeypatch.setenv(CACHE_ENV, off)
        assert jaxsss.compilation_cache_dir() is None
    monkeypatch.delenv(CACHE_ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert jaxsss.compilation_cache_dir() == tmp_path / "jaxsss" / "jax"


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
    assert _run(env) == str(cache)
    entries = sorted(p.name for p in Path(cache).rglob("*") if p.is_file())
    assert entries, "the first process wrote nothing to the compilation cache"
    _run(env)  # the second process loads (and must not duplicate) the entry
    assert sorted(p.name for p in Path(cache).rglob("*") if p.is_file()) == entries


def test_cache_can_be_turned_off(tmp_path):
    env = {**os.environ, CACHE_ENV: "off", "XDG_CACHE_HOME": str(tmp_path), "JAX_PLATFORMS": "cpu"}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    assert _run(env) in ("None", "")
    assert not (tmp_path / "jaxsss").exists()
