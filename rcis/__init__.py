"""Robust controlled invariant sets for PWA systems over unions of polyhedra.

A generic engine: it imports no scenario (``intention``, ``itha``, ``envs``, ``guardian``); a test
enforces it. ``examples/double_integrator.py`` builds an RCIS for a system that is not ours.
"""
from rcis.admissible import AdmissibleInputs
from rcis.cache import RegionCache
from rcis.certify import falsify
from rcis.invariant import inside_out, outside_in
from rcis.polyhedron import ChebyshevBall, Polyhedron
from rcis.pwa import PWAPiece, PWASystem
from rcis.region import Region

__all__ = ["AdmissibleInputs", "ChebyshevBall", "Polyhedron", "PWAPiece", "PWASystem", "Region", "RegionCache",
           "falsify", "inside_out", "outside_in"]
