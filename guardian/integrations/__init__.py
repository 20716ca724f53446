"""Integrations with learning libraries: ``sb3``, training stable-baselines3 agents under the guardian."""
