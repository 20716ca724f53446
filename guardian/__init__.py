"""guardian: a correct-by-construction safety supervisor for highway driving."""
__version__ = "0.1.0"
