"""Two-pass hierarchical rendering of translucent meshes (Jensen and Buhler 2002), differentiable in the material.

Geometry (sampling, rays, octree, interaction lists) is NumPy with trimesh and embreex; everything that depends on
the material is a JAX function of arrays. See ``docs/architecture.md``.
"""
