"""Simulator adapters: the code that reads a simulator into the scene model and applies decisions to it.

``highway_env``: highway-env's roads, vehicles and configurations. The simulators' own packages are imported
here and by the rooms that drive a simulator (the wrapper, the evaluation, the command line), never by the
scene model or the decision objects.
"""
