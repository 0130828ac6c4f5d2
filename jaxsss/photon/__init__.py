"""Photon diffusion in meshes (Donner and Jensen 2007, Section 5).

Photons traced into the object (:mod:`~jaxsss.photon.trace`) store diffusion sources at their first scattering; a
volumetric octree (:mod:`~jaxsss.photon.tree`) sums them hierarchically with the blended dipole, quadpole and
multipole of Eq. 15 (:mod:`~jaxsss.photon.render`, registered as the render method ``photon``: ``jaxsss render --method photon``); the same walks continued to
their exits are the mesh Monte Carlo reference (:mod:`~jaxsss.photon.reference`).
"""

from jaxsss.photon.emit import PhotonRays, emit_photons
from jaxsss.photon.reference import SurfaceExitance, mesh_monte_carlo, surface_exitance
from jaxsss.photon.render import (
    DEFAULT_EPS,
    PhotonPrepared,
    photon_geometry,
    prepare_photon,
    source_power,
    trace_scene,
)
from jaxsss.photon.trace import TALLIES, Exits, PhotonTrace, Sources, trace_photons
from jaxsss.photon.tree import PairLists, SourceTree, pair_lists, source_tree

__all__ = [
    "DEFAULT_EPS",
    "TALLIES",
    "Exits",
    "PairLists",
    "PhotonPrepared",
    "PhotonRays",
    "PhotonTrace",
    "SourceTree",
    "Sources",
    "SurfaceExitance",
    "emit_photons",
    "mesh_monte_carlo",
    "pair_lists",
    "photon_geometry",
    "prepare_photon",
    "source_power",
    "source_tree",
    "surface_exitance",
    "trace_photons",
    "trace_scene",
]
