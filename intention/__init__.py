"""Intention models of the lead car (dissertation Section 6.3.2) and their estimation."""
from intention.models import (IntentionModel, aggressive, bounded_velocity, cautious,
                              intention_models)
from intention.params import INPUT_NAMES, STATE_NAMES, OvertakeParams

__all__ = ["IntentionModel", "OvertakeParams", "STATE_NAMES", "INPUT_NAMES",
           "aggressive", "cautious", "bounded_velocity", "intention_models"]
