"""A white kernel's pair terms, compiled, for tests that call them outside any trace.

Op by op, JAX traces, lowers and compiles each of a pair's ~150 primitives on its own for every new shape (the
persistent cache keeps the compiled code, not the lowering), which took 4-12 s a test in the suite's workers
(``jax.monitoring`` durations per test, 2026-12-01). One small program per kernel layout compiles in under a second.
"""

import equinox as eqx


@eqx.filter_jit
def kernel_pair(kernel, delta, sources, normals=None, weights=None):
    """:meth:`jaxsss.render.bssrdf.WhiteKernel.pair`, compiled."""
    return kernel.pair(delta, sources, normals, weights)


@eqx.filter_jit
def kernel_sources(kernel, flux):
    """:meth:`jaxsss.render.bssrdf.WhiteKernel.sources`, compiled."""
    return kernel.sources(flux)
