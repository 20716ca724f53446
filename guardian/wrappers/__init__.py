"""The gymnasium wrapper: ``Guardian`` reads the simulation, asks the decision objects, applies their answer
and records it (``info["guardian"]``).

``guardian``: the wrapper; ``cars``: the guarded cars and the hooks that let the wrapper decide every
simulation step; ``record``: what the wrapper reports per policy step, as a typed object; ``panel``: the
guardian's panel under a rendered frame. May import the adapters, the decision objects and the scene model.
"""
