"""Robust controlled invariant sets for PWA systems over unions of polyhedra."""
from rcis.polyhedron import ChebyshevBall, Polyhedron
from rcis.pwa import PWAPiece, PWASystem
from rcis.region import Region

__all__ = ["Polyhedron", "ChebyshevBall", "Region", "PWAPiece", "PWASystem"]
