"""HighwayOvertake's video a person can read: frames at the env's real rate, ego, lead and traffic in
distinct colours with a legend, a panel of labelled fields, and no SDL error on stderr.

Before: 20 fps for a 10 Hz env (highway-env doubles the rate), ego and lead the same colour, the
panel's words run together, ``Error: XDG_RUNTIME_DIR is invalid`` on every run.
"""
import os
import subprocess
import sys

import gymnasium as gym
import numpy as np

import envs  # noqa: F401 - registers guardian/HighwayOvertake-v0
from envs.vehicles import COLOURS
from guardian.wrappers.panel import PANEL_HEIGHT, _font, with_panel

ENV = "guardian/HighwayOvertake-v0"


def _count(img, rgb):
    return int(np.sum(np.all(img[..., :3] == np.asarray(rgb, dtype=img.dtype), axis=-1)))


def test_the_video_plays_at_the_policy_frequency(tmp_path):
    from moviepy import VideoFileClip  # a stock reader of the file written

    env = gym.make(ENV, render_mode="rgb_array", config={"duration": 2, "traffic_count": 0, "traffic_from_behind": 0})
    assert env.unwrapped.metadata["render_fps"] == env.unwrapped.config["policy_frequency"] == 10
    env = gym.wrappers.RecordVideo(env, str(tmp_path / "video"), episode_trigger=lambda e: True, disable_logger=True)
    env.reset(seed=0)
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(np.array([0.0, 0.0]))
        done = terminated or truncated
    env.close()
    (mp4,) = (tmp_path / "video").glob("*.mp4")
    clip = VideoFileClip(str(mp4))
    assert clip.fps == 10
    assert abs(clip.duration - 2.1) < 0.15  # 21 frames (reset + 20 steps) of 0.1 s: real time
    clip.close()


def test_ego_lead_and_traffic_have_distinct_colours_in_the_frame():
    assert len({tuple(c) for c in COLOURS.values()}) == 4
    env = gym.make(ENV, render_mode="rgb_array",
                   config={"traffic_count": 2, "traffic_from_behind": 0, "initial_box": [[25.0, 0.0, 20.0, 20.0],
                                                                                        [25.0, 0.0, 20.0, 20.0]]})
    env.reset(seed=1)
    u = env.unwrapped
    assert u.vehicle.color == COLOURS["ego"] and u.lead.color == COLOURS["lead"]
    others = [v for v in u.road.vehicles if v is not u.vehicle and v is not u.lead]
    assert others and all(v.color == COLOURS["traffic"] for v in others)
    frame = env.render()
    for role in ("ego", "lead"):
        assert _count(frame, COLOURS[role]) > 20, role  # drawn, not only declared
    env.close()


def test_a_crashed_car_turns_red():
    env = gym.make(ENV, config={"traffic_count": 0, "traffic_from_behind": 0})
    env.reset(seed=0)
    env.unwrapped.vehicle.crashed = True
    assert env.unwrapped.vehicle.color == COLOURS["crashed"]
    env.close()


def test_the_panel_has_labelled_fields_and_the_colour_legend():
    assert _font().getlength(" ") >= 3  # a real space between words (the bitmap font's words ran together)
    assert _font().getlength("set: cautious") > _font().getlength("set:cautious")
    frame = np.full((50, 900, 3), 100, dtype=np.uint8)
    record = {"active_set": "cautious", "valid_intentions": ["aggressive", "cautious"], "overridden": True,
              "changed": "throttle", "admissible_acceleration": [[0.5, 3.0]], "proposed_input": [-2.0, 0.0],
              "applied_input": [0.5, 0.0], "reasons": ["throttle outside S(x)"]}
    out = with_panel(frame, record, (-3.0, 3.0))
    panel = out[-PANEL_HEIGHT:]
    assert out.shape == (50 + PANEL_HEIGHT, 900, 3)
    for role in ("ego", "lead", "traffic", "crashed"):
        assert _count(panel, COLOURS[role]) > 50, role  # the legend's swatches
    assert _count(panel, (60, 180, 80)) > 200 and _count(panel, (220, 40, 40)) > 20  # band, proposed tick


def test_rendering_prints_no_sdl_error(tmp_path):
    code = ("import gymnasium as gym, envs\n"
            "env = gym.make('guardian/HighwayOvertake-v0', render_mode='rgb_array')\n"
            "env.reset(seed=0); f = env.render(); assert f.std() > 0, 'blank frame'; env.close()\n")
    env = {k: v for k, v in os.environ.items() if k not in ("XDG_RUNTIME_DIR", "SDL_VIDEODRIVER", "DISPLAY",
                                                              "WAYLAND_DISPLAY")}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "XDG_RUNTIME_DIR" not in r.stderr and "error" not in r.stderr.lower(), r.stderr


def test_highway_v0_videos_from_the_rollout_play_at_the_policy_frequency_without_sdl_errors(tmp_path):
    """highway-env's own metadata doubles the rate (``video_real_time_ratio`` 2); the rollout sets it to 1."""
    from moviepy import VideoFileClip

    code = ("from guardian.evaluation.rollouts import Rollout, highway_rollouts; "
            f"highway_rollouts(Rollout('highway-fast-v0', 'random', action='meta', guarded=False, "
            f"env_config={{'duration': 2}}), 1, 0, video_dir={str(tmp_path / 'video')!r})")
    env = {k: v for k, v in os.environ.items() if k not in ("SDL_VIDEODRIVER", "XDG_RUNTIME_DIR")}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "XDG_RUNTIME_DIR" not in done.stderr
    (mp4,) = (tmp_path / "video").glob("*.mp4")
    clip = VideoFileClip(str(mp4))
    assert clip.fps == 1  # highway-fast-v0: policy_frequency 1
    clip.close()


def test_the_panel_names_a_meta_override_by_its_actions():
    """A refused lane change on merge-v0 read "OVERRIDE (throttle)"; the panel now says what was asked and done."""
    from guardian.wrappers.panel import _verdict

    meta = {"proposed": "LANE_RIGHT", "applied": "SLOWER", "changed": "throttle", "refused_lane_change": True}
    assert _verdict(meta) == "OVERRIDE: LANE_RIGHT -> SLOWER (lane change refused)"
    assert _verdict({"proposed": [1.0, 0.1], "applied": [0.5, 0.1], "changed": "throttle"}) == "OVERRIDE (throttle)"


def test_a_steering_override_shows_on_the_steering_axis():
    """The second input has its own axis: proposed and applied steering ticks where they are, apart."""
    frame = np.full((50, 900, 3), 100, dtype=np.uint8)
    record = {"active_set": "itha", "overridden": True, "changed": "steering", "admissible_acceleration": [[-5, 5]],
              "proposed_input": [0.0, 0.6], "applied_input": [0.0, -0.6], "reasons": ["steering into lane 2"]}
    without = with_panel(frame, record, (-5.0, 5.0))[-PANEL_HEIGHT:]
    panel = with_panel(frame, record, (-5.0, 5.0), ("steering [rad]", (-0.785, 0.785)))[-PANEL_HEIGHT:]
    steering_row = panel[2 * 22 + 3:3 * 22 + 3]
    reds = np.nonzero((steering_row == (220, 40, 40)).all(axis=2))[1]
    blacks = np.nonzero((steering_row == (0, 0, 0)).all(axis=2))[1]
    assert len(reds) and len(blacks) and reds.mean() > blacks.mean() + 100   # +0.6 right of -0.6
    assert _count(panel, (220, 40, 40)) > _count(without, (220, 40, 40))     # a second proposed tick
