"""The scene model: what a decision reads and what it answers, as plain values.

The road (``roads``: one straight road, or a corridor with on-ramps and exits), the lane numberings and
their one converter (``lanes``), a body's extent on the road (``body``), the ego and the other cars as ITHA
agents (``scene``), the cover for traffic driving backwards (``reversing``), and a decision's record
(``decision``). No simulator, no decision logic: every other room builds or reads these values, and this
package imports nothing of guardian but ``guardian.config`` and ``guardian.errors``.
"""
