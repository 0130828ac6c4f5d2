"""Tests of photon diffusion in meshes (jaxsss.photon)."""
