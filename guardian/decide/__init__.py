"""The decision objects: given a state and a scene, the input to apply and why (no simulator).

Every decision object answers the one interface ``DecisionObject`` (``guardian.decide.interface``):
``reset()``, ``step(state, scene, proposed) -> (applied, Decision)`` and ``inside(state, scene)``.

* ``bicycle.BicycleGuardian``: highway-env's kinematic bicycle among traffic (ITHA, Chapter 7);
* ``overtake.PointMassGuardian``: the overtake ego of Chapter 6 among traffic (the lead part composed
  with ITHA);
* ``lead.IntentionAwareGuardian``: the two-car guardian of Chapter 6 (the RCIS library and the intention
  estimator); ``lead_following.LeadFollowing``: ``F_R`` grown by the intentions not yet ruled out;
* ``traffic.TrafficSupervisor``: the traffic rules, self-safety (7.4) and responsibility (7.5), in next
  speeds; ``kinematics``: each ego model turning next speeds and lanes into inputs.

May import ``guardian.model``, ``guardian.config``, ``guardian.errors`` and the science packages (``rcis``,
``intention``, ``itha``); never a simulator, a wrapper or the evaluation (import-linter checks it).
"""
