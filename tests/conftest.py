"""Test-suite settings: float64 and strict dtype promotion (DESIGN.md, "Precision")."""

import jax
import pytest

import jaxsss  # noqa: F401  (enables float64)

jax.config.update("jax_numpy_dtype_promotion", "strict")
# One CPU device, whatever runs first (`jaxsss mc` in-process would otherwise ask for one per core); the sharded
# Monte Carlo path is tested on 2 devices in a subprocess (tests/mc/test_sharding.py).
jax.config.update("jax_num_cpu_devices", 1)


@pytest.fixture(autouse=True)
def _float64():
    assert jax.config.jax_enable_x64
