"""Evaluation: running episodes and counting what happened, by written rules.

``episodes``: the rollout loop and its ``Observer``; ``rollouts``: supervised rollouts of the highway-env
environments; ``tally``: the counts of a rollout (``HighwayTally.result`` is the rule book); ``judge``: who
caused a collision, from geometry alone (it knows nothing of the guardian); ``campaign``: the falsification
campaign over a matrix of environments and adversarial agents.
"""

MAX_SECONDS = 300.0   # a rollout's default time cap [simulated s]: merge-v0 never ends an episode itself
