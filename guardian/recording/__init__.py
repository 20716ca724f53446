"""Recordings for the rerun viewer: supervised rollouts, the ITHA highway experiment and HighD replays."""
