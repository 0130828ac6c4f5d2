"""Photon diffusion in meshes (Donner and Jensen 2007, Section 5): photons traced into the object store diffusion
sources at their first scattering; a volumetric octree sums them hierarchically with the blended dipole, quadpole
and multipole (Eq. 15); the same walks, continued, are the mesh Monte Carlo reference."""

from jaxsss.photon.emit import PhotonRays, emit_photons
from jaxsss.photon.trace import TALLIES, Exits, PhotonTrace, Sources, trace_photons

__all__ = ["TALLIES", "Exits", "PhotonRays", "PhotonTrace", "Sources", "emit_photons", "trace_photons"]
