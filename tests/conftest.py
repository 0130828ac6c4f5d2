"""Test-suite settings: float64 and strict dtype promotion (DESIGN.md, "Precision")."""

import jax
import pytest

import jaxsss  # noqa: F401  (enables float64)

jax.config.update("jax_numpy_dtype_promotion", "strict")


@pytest.fixture(autouse=True)
def _float64():
    assert jax.config.jax_enable_x64
