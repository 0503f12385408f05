"""Run a policy over a suite: one row per episode, plus the driven traces for plots and videos.

Each episode is reset with the suite's start, heading, goal and seed, so every policy meets the same episodes
and the same noise. The shortest path for SPL is the planner's geodesic over the traversable grid
(:func:`diana_lab.planning.shortest_path_length`), computed on the cost map the episodes were sampled from.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd

from diana_lab.evaluation.metrics import spl
from diana_lab.evaluation.policies import Policy
from diana_lab.evaluation.suite import EpisodeSpec
from diana_lab.planning import shortest_path_length

__all__ = ["COLUMNS", "EpisodeTrace", "run_episodes", "run_suite"]

COLUMNS = (
    "episode",
    "start_x",
    "start_y",
    "start_yaw",
    "goal_x",
    "goal_y",
    "outcome",
    "success",
    "steps",
    "path_length_m",
    "sim_time_s",
    "straight_distance_m",
    "shortest_path_m",
    "spl",
    "speed_mps",
    "max_tilt_deg",
    "time_over_15deg_s",
    "final_distance_m",
    "return",
)


@dataclass
class EpisodeTrace:
    """The driven path of one episode: ``xy (K, 2)`` and ``tilt_deg (K,)``, and the waypoints sent."""

    xy: np.ndarray
    tilt_deg: np.ndarray
    waypoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    @property
    def distance(self) -> np.ndarray:
        """Cumulative distance (m) along the path at every sample."""
        steps = np.hypot(*np.diff(self.xy, axis=0).T) if len(self.xy) > 1 else np.zeros(0)
        return np.concatenate([[0.0], np.cumsum(steps)])


def _episode(
    policy: Policy,
    env: gym.Env,
    spec: EpisodeSpec,
    index: int,
    on_obs: Callable[[Any], None] | None = None,
) -> tuple[dict, EpisodeTrace]:
    """Run one episode; ``on_obs`` sees every observation (the video's frame hook)."""
    base = env.unwrapped
    obs, info = env.reset(seed=spec.seed, options=spec.reset_options())
    policy.reset(env)
    xy, tilt, wps = [np.asarray(info["position"][:2], dtype=np.float64)], [float(info["tilt_deg"])], []
    if on_obs is not None:
        on_obs(obs)
    total, done, limit = 0.0, False, base.episode_cfg.max_steps + 10
    while not done:
        action = policy.act(obs, env)
        obs, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        done = terminated or truncated or info["steps"] >= limit
        xy.extend(np.asarray(info["trace_xy"])[1:])
        tilt.extend(np.asarray(info["trace_tilt_deg"])[1:])
        wps.append(np.asarray(info["waypoint"], dtype=np.float64))
        if on_obs is not None:
            on_obs(obs)
    outcome = str(info.get("outcome", "timeout"))
    success = outcome == "success"
    straight = float(math.dist(spec.start, spec.goal))
    shortest = float(shortest_path_length(base.sampler.costmap, spec.start, spec.goal))
    path, sim_time = float(info["path_length"]), float(info["sim_time"])
    row = {
        "episode": index,
        "start_x": float(spec.start[0]),
        "start_y": float(spec.start[1]),
        "start_yaw": float(spec.yaw),
        "goal_x": float(spec.goal[0]),
        "goal_y": float(spec.goal[1]),
        "outcome": outcome,
        "success": success,
        "steps": int(info["steps"]),
        "path_length_m": path,
        "sim_time_s": sim_time,
        "straight_distance_m": straight,
        "shortest_path_m": shortest,
        "spl": float(spl([success], [shortest], [path])[0]),
        "speed_mps": straight / sim_time if success and sim_time > 0 else math.nan,
        "max_tilt_deg": float(info["max_tilt_deg"]),
        "time_over_15deg_s": float(info["time_over_15deg_s"]),
        "final_distance_m": float(info["distance_to_goal"]),
        "return": total,
    }
    if base.robot.tilt_guard_deg is not None:  # the rover's tilt guard: how many waypoints it halted
        row["halts"] = int(info["halts"])
    stats = getattr(policy, "episode_stats", None)  # a policy's own columns (the slope shield's vetoes)
    if stats is not None:
        row.update(stats())
    trace = EpisodeTrace(np.asarray(xy), np.asarray(tilt), np.asarray(wps).reshape(-1, 2))
    return row, trace


def _filmed_episode(
    policy: Policy, env: gym.Env, spec: EpisodeSpec, index: int, video_path: Path
) -> tuple[dict, EpisodeTrace]:
    from diana_lab.evaluation.video import FrameMaker, write_gif

    maker, frames = FrameMaker(env), []
    try:
        result = _episode(policy, env, spec, index, lambda obs: frames.append(maker.frame(obs)))
    finally:
        maker.close()
    write_gif(video_path, frames)
    return result


def run_episodes(
    policy: Policy, env: gym.Env, suite: list[EpisodeSpec], video_path: Path | str | None = None
) -> tuple[pd.DataFrame, list[EpisodeTrace]]:
    """Like :func:`run_suite`, also returning every episode's trace (for plots)."""
    rows, traces = [], []
    for i, spec in enumerate(suite):
        if i == 0 and video_path is not None:
            row, trace = _filmed_episode(policy, env, spec, i, Path(video_path))
        else:
            row, trace = _episode(policy, env, spec, i)
        rows.append(row)
        traces.append(trace)
    extra = [k for k in (rows[0] if rows else {}) if k not in COLUMNS]  # a policy's own (``episode_stats``)
    return pd.DataFrame(rows, columns=[*COLUMNS, *extra]), traces


def run_suite(
    policy: Policy, env: gym.Env, suite: list[EpisodeSpec], video_path: Path | str | None = None
) -> pd.DataFrame:
    """Run ``policy`` on every episode of ``suite``; one row per episode (columns: :data:`COLUMNS`, then any
    the policy adds through an ``episode_stats()`` method, e.g. ``shield_vetoes``).

    ``video_path``: write a GIF of the first episode there. ``path_length_m`` is the driven length,
    ``shortest_path_m`` the planner's geodesic, ``speed_mps`` the goal-directed speed (straight start-goal
    distance over simulated time; NaN unless the episode succeeded), ``spl`` the episode's SPL term.
    """
    return run_episodes(policy, env, suite, video_path)[0]
