"""The overtake scenario as a gymnasium environment (Section 6.3).

Observation ``x = [v_ex, y_e, h, v_Lx]``, action ``u_e = [a_ex, v_ey]`` inside
``U_e`` (an action outside it is an error, never clipped). The lead car is the
closed-loop PWA system of the chosen intention model — the same definition the
RCIS library and the estimator use. Disturbances ``w = [w_ex, w_ey, w_Lx,
w_Delta]`` are drawn uniformly from their box (``"random"``) or chosen at the
box's vertices against the ego (``"adversarial"``: the lead brakes as hard as
its intention allows while the ego is behind and speeds up while it is ahead;
the ego's noise pushes it towards the lead and the right lane). An episode ends
(terminated) when the state leaves the safe set (6.8), or is truncated after
``max_steps``.
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np

from intention.models import intention_models, safe_set
from intention.params import OvertakeParams

DEFAULT_CONFIG = {
    "intention": "cautious",       # "aggressive" | "cautious"
    "disturbance": "random",       # "random" | "adversarial"
    "max_steps": 300,              # 30 s at dt = 0.1
    "initial_region": None,        # a rcis.Region: initial states are sampled inside it
    "initial_box": ((20.0, -0.2, 25.0, 15.0), (30.0, 0.2, 60.0, 25.0)),  # ego behind lead, right lane
    "params": OvertakeParams(),
}


DISTURBANCE_MODES = ("random", "adversarial")


def disturbance_box(p: OvertakeParams) -> tuple[np.ndarray, np.ndarray]:
    """The box of ``w = [w_ex, w_ey, w_Lx, w_Delta]`` (Table 6.1)."""
    return (np.array([p.w_ex_bounds[0], p.w_ey_bounds[0], p.w_Lx_bounds[0], p.w_delta_bounds[0]]),
            np.array([p.w_ex_bounds[1], p.w_ey_bounds[1], p.w_Lx_bounds[1], p.w_delta_bounds[1]]))


def draw_disturbance(p: OvertakeParams, mode: str, x, rng: np.random.Generator) -> np.ndarray:
    """One disturbance ``w``: uniform in its box, or the adversarial vertex at state ``x``.

    Adversarial: while the ego is behind (``h > 0``) the lead brakes as hard as its
    intention allows and the ego's noise speeds it up; once ahead, the reverse. The
    ego's lateral noise always pushes it towards the right lane.
    """
    lo, hi = disturbance_box(p)
    if mode == "random":
        return rng.uniform(lo, hi)
    if mode != "adversarial":
        raise ValueError(f"disturbance must be one of {DISTURBANCE_MODES}, got {mode!r}")
    behind = x[2] > 0
    return np.array([hi[0] if behind else lo[0], lo[1], lo[2] if behind else hi[2], lo[3] if behind else hi[3]])


def sample_initial_state(box, region, rng: np.random.Generator, who: str) -> np.ndarray:
    """A state uniform in ``box`` (and inside ``region``, a ``rcis.Region``, when given)."""
    lo, hi = (np.asarray(v, dtype=float) for v in box)
    for _ in range(10_000):
        x = rng.uniform(lo, hi)
        if region is None or region.contains(x):
            return x
    raise RuntimeError(f"{who}: no initial state of initial_box lies in initial_region")


class OvertakeEnv(gym.Env):
    """``guardian/Overtake-v0``: the ego behind a lead of one intention, dynamics (6.3)-(6.4).

    Parameters
    ----------
    config : dict, optional
        Overrides of ``DEFAULT_CONFIG`` (documented there, key by key); an unknown key raises.
    """

    metadata = {"render_modes": []}

    def __init__(self, config: dict | None = None):
        unknown = set(config or {}) - set(DEFAULT_CONFIG)
        if unknown:
            raise ValueError(f"OvertakeEnv: unknown config keys {sorted(unknown)}")
        self.config = {**DEFAULT_CONFIG, **(config or {})}
        p = self.config["params"]
        self.params = p
        name = self.config["intention"]
        models = intention_models(p)
        if name not in ("aggressive", "cautious"):
            raise ValueError(f"OvertakeEnv: intention must be 'aggressive' or 'cautious', got {name!r}")
        if self.config["disturbance"] not in DISTURBANCE_MODES:
            raise ValueError(f"OvertakeEnv: disturbance must be 'random' or 'adversarial', "
                             f"got {self.config['disturbance']!r}")
        self.model = models[name]
        self.safe = safe_set(p)
        self.action_space = gym.spaces.Box(np.array([p.a_ex_bounds[0], p.v_ey_bounds[0]]),
                                           np.array([p.a_ex_bounds[1], p.v_ey_bounds[1]]), dtype=np.float64)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(4,), dtype=np.float64)
        self.state = None
        self.steps = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        options = options or {}
        if "state" in options:
            x = np.asarray(options["state"], dtype=float)
            if x.shape != (4,) or not np.all(np.isfinite(x)):
                raise ValueError(f"OvertakeEnv.reset: state must be 4 finite numbers, got {options['state']}")
        else:
            x = sample_initial_state(self.config["initial_box"], self.config["initial_region"],
                                     self.np_random, "OvertakeEnv")
        self.state = x
        self.steps = 0
        return x.copy(), {"intention": self.model.name, "unsafe": not self.safe.contains(x)}

    def step(self, action):
        if self.state is None:
            raise RuntimeError("OvertakeEnv.step called before reset")
        u = np.asarray(action, dtype=float)
        if u.shape != (2,) or not np.all(np.isfinite(u)):
            raise ValueError(f"OvertakeEnv.step: action must be 2 finite numbers, got {action}")
        if not self.action_space.contains(u):
            raise ValueError(f"OvertakeEnv.step: action {u.tolist()} is outside U_e "
                             f"[{self.action_space.low.tolist()}, {self.action_space.high.tolist()}]")
        w = draw_disturbance(self.params, self.config["disturbance"], self.state, self.np_random)
        x = self.model.system.step(self.state, u, w)
        self.state = x
        self.steps += 1
        unsafe = not self.safe.contains(x)
        reward = float(x[0] * self.params.dt / 36.0) - (10.0 if unsafe else 0.0)
        info = {"intention": self.model.name, "unsafe": unsafe, "disturbance": w.tolist()}
        return x.copy(), reward, unsafe, self.steps >= self.config["max_steps"], info
