"""Tests of the Monte Carlo transport engine (jaxsss.mc)."""
