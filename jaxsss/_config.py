"""Process-wide numerics: float64 by default (DESIGN.md, "Precision").

Importing :mod:`jaxsss` enables ``jax_enable_x64``. Float32 still works: pass float32 arrays explicitly; the
documented float32 error bounds are in ``docs/architecture.md`` and checked by ``tests/test_stability.py``.
"""

import jax

jax.config.update("jax_enable_x64", True)
