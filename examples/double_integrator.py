"""An RCIS for a double integrator with a bounded disturbance, using only ``rcis``."""
import numpy as np

from rcis import Polyhedron, PWAPiece, PWASystem, Region, falsify, outside_in

dt = 0.1  # x = (position, velocity); u = (throttle, brake), each in [0, 2]; w = acceleration noise in [-0.5, 0.5]
A, B, E = np.array([[1.0, dt], [0.0, 1.0]]), np.array([[0.5 * dt**2, -0.5 * dt**2], [dt, -dt]]), np.array([[0.5 * dt**2], [dt]])
piece = PWAPiece(Polyhedron.universe(2), A, B, np.zeros(2), E, Polyhedron.from_box([-0.5], [0.5]))
system = PWASystem([piece], Polyhedron.from_box([0.0, 0.0], [2.0, 2.0]), Polyhedron.universe(2), name="double integrator")
safe = Region([Polyhedron.from_box([-1.0, -1.0], [1.0, 1.0])])  # |position| <= 1, |velocity| <= 1
result = outside_in(system, safe, max_iterations=200)            # C_{k+1} = Pre(C_k) ∩ safe (2.11)
check = falsify(system, result.region, 2000, seed=0)             # sampled states x every vertex of W
print(f"converged={result.converged} iterations={result.iterations} pieces={len(result.region)} "
      f"counterexamples={len(check.counterexamples)} (0.9, 0.5) in C: {bool(result.region.contains([0.9, 0.5]))} "
      f"(0.95, 0.9) in C: {bool(result.region.contains([0.95, 0.9]))}")
