"""Eclipse SUMO read as the scene model, and guarded vehicles driven in it (``pip install 'guardian[sumo]'``).

``network``: the road network (``netconvert``) and SUMO's traffic; ``scene``: SUMO's vehicles as bodies in the
road model's frame, the scene, and a guarded vehicle moved by the ego model. ``libsumo`` is imported by the rooms
that run SUMO (``guardian.evaluation.sumo``), never here at import time.
"""
