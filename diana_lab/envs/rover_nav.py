"""``diana_lab/RoverNav-v0``: drive a rover to goal coordinates across rough terrain, one waypoint per step.

One step hands the agent's waypoint to the turn-then-drive position controller and runs it to the end
(reached, given up, or a failure). The observation is a dict: ``goal`` (the goal relative to the rover's pose
estimate, plus its attitude) and the sensor encoding under the encoding's name (``depth_image``,
``elevation_map`` or ``points``). The action names the waypoint (:mod:`diana_lab.envs.action_spaces`): a
``Box(-1, 1, (2,))`` point of the square or disc, or with ``action_space=discrete`` a ``Discrete(n)`` index into
a table of candidate waypoints.

Episode outcomes (``info["outcome"]`` on the last step): ``success``, ``collision``, ``tipover``,
``out_of_bounds``, ``sim_error`` (terminated); ``timeout`` (step or time limit) and ``stuck`` (no net progress
for ``episode.stuck_steps`` waypoints) are truncations.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from diana_lab import config as C
from diana_lab.envs.action_spaces import WaypointMapping
from diana_lab.envs.episodes import Episode, EpisodeSampler
from diana_lab.envs.rewards import RewardContext, RewardManager
from diana_lab.planning.goal_distance import GoalDistance
from diana_lab.sim.controller import TurnThenDrive, wrap_angle
from diana_lab.sim.pose import PoseEstimate, PoseService
from diana_lab.sim.state import WaypointResult
from diana_lab.sim.world import World

TERMINAL = {"collision", "tipover", "out_of_bounds", "sim_error"}
TILT_LIMIT_DEG = 15.0  # for the time-over-15-degrees statistic


class RoverNavEnv(gym.Env):
    """See the module docstring. Every part is a config (an option name, a mapping or a typed dataclass).

    Args:
        world, robot, dynamics, sensor, action_space, reward, episode: one group each, as in ``conf/``.
            Omitted groups take the defaults of ``conf/config.yaml``.
        config: a whole composed config (``DictConfig``); its groups fill those not given explicitly.
        world_instance: a ready :class:`World` to share between envs of one process (skips the build).
        render_mode: ``"rgb_array"`` (top-down map beside a third-person view) or ``"human"`` (PyBullet GUI).
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 4}

    def __init__(
        self,
        world: Any = None,
        robot: Any = None,
        dynamics: Any = None,
        sensor: Any = None,
        action_space: Any = None,
        reward: Any = None,
        episode: Any = None,
        config: Any = None,
        world_instance: World | None = None,
        render_mode: str | None = None,
    ) -> None:
        super().__init__()
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode: expected one of {self.metadata['render_modes']}, got {render_mode!r}")
        given = {
            "world": world,
            "robot": robot,
            "dynamics": dynamics,
            "sensor": sensor,
            "action_space": action_space,
            "reward": reward,
            "episode": episode,
        }
        missing = [g for g, v in given.items() if v is None and (config is None or g not in config)]
        defaults = C.compose() if missing else None
        cfgs = {
            g: C.to_object(
                g, v if v is not None else (config[g] if config is not None and g in config else defaults[g])
            )
            for g, v in given.items()
        }
        self.cfg = cfgs
        self.world: World = world_instance if world_instance is not None else C.build(cfgs["world"])
        self.robot = cfgs["robot"]
        self.dynamics = C.build(cfgs["dynamics"], self.world, self.robot)
        self.controller = TurnThenDrive(cfgs["dynamics"].controller, self.robot)
        self.pose_service = PoseService(cfgs["dynamics"].pose_noise)
        self.sensor = C.build(cfgs["sensor"], self.world)
        self.mapping = WaypointMapping(cfgs["action_space"])
        self.rewards = RewardManager(cfgs["reward"])
        self.episode_cfg = cfgs["episode"]
        self.sampler = EpisodeSampler(self.episode_cfg, self.world, self.robot)
        field = self.rewards.goal_field  # (stride, untraversable_cost) when a reward term reads the path to the goal
        self.goal_distance = GoalDistance(self.sampler.costmap, *field) if field is not None else None
        self._goal_field: np.ndarray | None = None
        self._path_to_goal = math.nan
        self.render_mode = render_mode
        self._renderer = None

        self.sensor_key = cfgs["sensor"].encoding
        diag = math.hypot(self.world.terrain.size_x, self.world.terrain.size_y) / self.episode_cfg.distance_scale
        goal_high = np.array([max(diag, 1.0), 1, 1, 1, 1, 1, 1], dtype=np.float32)
        goal_low = np.array([0, -1, -1, -1, -1, -1, -1], dtype=np.float32)
        self.observation_space = spaces.Dict(
            {
                "goal": spaces.Box(goal_low, goal_high, dtype=np.float32),
                self.sensor_key: self.sensor.observation_space,
            }
        )
        self.action_space = self.mapping.space  # Box(-1, 1, (2,)), or Discrete(n) over the candidate waypoints
        self._episode: Episode | None = None
        self.last_waypoint: WaypointResult | None = None
        # per-env constants of the step path (looked up once: the step runs ~1,000 times a second)
        self._goal_low = goal_low.astype(np.float64)
        self._goal_high = goal_high.astype(np.float64)
        margin = self.robot.radius + self.episode_cfg.map_margin
        x0, x1, y0, y1 = self.world.bounds
        self._waypoint_box = (x0 + margin, x1 - margin, y0 + margin, y1 - margin)

    # ------------------------------------------------------------------ helpers
    @property
    def goal(self) -> np.ndarray:
        assert self._episode is not None, "call reset() first"
        return self._episode.goal

    @property
    def pose_estimate(self) -> PoseEstimate:
        """The pose the agent's last observation was computed from (what a baseline may use too)."""
        return self._estimate

    def _goal_vector(self, est: PoseEstimate) -> tuple[np.ndarray, float, float]:
        goal = self.goal
        dx, dy = float(goal[0] - est.xy[0]), float(goal[1] - est.xy[1])
        distance = math.hypot(dx, dy)
        error = float(wrap_angle(math.atan2(dy, dx) - est.yaw))
        g = np.array(
            [
                distance / self.episode_cfg.distance_scale,
                math.sin(error),
                math.cos(error),
                est.roll / (math.pi / 2),
                est.pitch / (math.pi / 2),
                math.sin(est.yaw),
                math.cos(est.yaw),
            ]
        )
        np.minimum(np.maximum(g, self._goal_low, out=g), self._goal_high, out=g)  # np.clip, minus its wrapper
        return g.astype(np.float32), distance, error

    def _observe(self) -> dict[str, np.ndarray]:
        st = self.dynamics.state
        self._estimate = self.pose_service.estimate(st)
        goal, self._distance, self._heading_error = self._goal_vector(self._estimate)
        return {"goal": goal, self.sensor_key: self.sensor.observe(st.position, st.rpy)}

    def _clamp(self, waypoint: np.ndarray) -> np.ndarray:
        x0, x1, y0, y1 = self._waypoint_box  # the map, shrunk by the rover's radius and the margin
        x, y = float(waypoint[0]), float(waypoint[1])  # scalar min/max: np.clip costs ~10 us per call here
        return np.array([min(max(x, x0), x1), min(max(y, y0), y1)])

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        options = options or {}
        unknown = set(options) - {"start", "goal", "yaw"}
        if unknown:
            raise ValueError(f"reset options: unknown key(s) {sorted(unknown)}; expected 'start', 'goal', 'yaw'")
        ep = self.sampler.sample(self.np_random)
        if "start" in options or "goal" in options:
            start = np.asarray(options.get("start", ep.start), dtype=np.float64)[:2]
            goal = np.asarray(options.get("goal", ep.goal), dtype=np.float64)[:2]
            self.sampler.check_point(start, "start")
            self.sampler.check_point(goal, "goal")
            ep = Episode(start, float(options.get("yaw", ep.yaw)), goal)
        self._episode = ep
        self.pose_service.reset(self.np_random)
        self.sensor.reset(self.np_random)
        self.dynamics.reset(ep.start, ep.yaw, self.np_random)
        self._steps, self._path_length, self._max_tilt, self._time_over_tilt = 0, 0.0, 0.0, 0.0
        self._halts = 0
        self.last_waypoint = None  # what the controller reported for the last step (hazards felt: the shield)
        self._recent_xy = [self.dynamics.state.xy.copy()]
        self._trail = [self.dynamics.state.xy[None].copy()]  # (K, 2) pieces, joined by the trail property
        obs = self._observe()
        self._start_distance = self._distance
        if self.goal_distance is not None:
            self._goal_field = self.goal_distance.field(ep.goal, out=self._goal_field)
            self._path_to_goal = self.goal_distance.at(self._goal_field, *self.dynamics.state.xy)
        return obs, self._info(None, None, None, {})

    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        if self._episode is None:
            raise RuntimeError("step() called before reset()")
        est, prev_distance, prev_path = self._estimate, self._distance, self._path_to_goal
        waypoint = self._clamp(est.xy + self.mapping.offset(action, est.yaw))
        self.controller.start()
        result = self.dynamics.execute(waypoint, self.controller, self.pose_service.xy_yaw)
        self._steps += 1
        self._path_length += result.path_length
        self._halts += result.outcome == "halted"
        self.last_waypoint = result
        max_tilt = result.max_tilt_deg
        self._max_tilt = max(self._max_tilt, max_tilt)
        if max_tilt > TILT_LIMIT_DEG:
            self._time_over_tilt += float(result.sample_durations()[result.trace_tilt_deg > TILT_LIMIT_DEG].sum())
        self._trail.append(result.trace_xy[1:])
        if result.hazard_xy is not None:
            self.sensor.mark_hazard(result.hazard_xy)
        obs = self._observe()
        outcome = self._outcome(result)
        terminated = outcome is not None and outcome not in ("timeout", "stuck")
        truncated = outcome in ("timeout", "stuck")
        if self.goal_distance is not None:
            self._path_to_goal = self.goal_distance.at(self._goal_field, *self.dynamics.state.xy)
        ctx = RewardContext(
            prev_distance, self._distance, self._heading_error, result, outcome, self._steps, self._path_length,
            self._start_distance, prev_path, self._path_to_goal,
        )  # fmt: skip
        reward, terms = self.rewards(ctx)
        info = self._info(waypoint, result, outcome, terms)
        if self.render_mode == "human":
            self.render()
        return obs, reward, terminated, truncated, info

    def _outcome(self, result: WaypointResult) -> str | None:
        # success counts if the rover passed within tolerance anywhere along the step (before any failure)
        offset = result.trace_xy - self.goal
        if np.hypot(offset[:, 0], offset[:, 1]).min() <= self.episode_cfg.goal_tolerance:
            return "success"
        if result.outcome in TERMINAL:
            return result.outcome
        xy = self.dynamics.state.xy
        self._recent_xy.append(xy.copy())
        n = self.episode_cfg.stuck_steps
        if len(self._recent_xy) > n and math.dist(self._recent_xy[-1 - n], xy) < self.episode_cfg.stuck_distance:
            return "stuck"
        if self._steps >= self.episode_cfg.max_steps or self.dynamics.state.time >= self.episode_cfg.max_time_s:
            return "timeout"
        return None

    def _info(
        self,
        waypoint: np.ndarray | None,
        result: WaypointResult | None,
        outcome: str | None,
        terms: dict[str, float],
    ) -> dict[str, Any]:
        st = self.dynamics.state
        tilt = st.tilt_deg
        info: dict[str, Any] = {
            "start": self._episode.start.copy(),
            "goal": self._episode.goal.copy(),
            "position": st.position.copy(),
            "yaw": st.yaw,
            "distance_to_goal": self._distance,
            "start_distance": self._start_distance,
            "steps": self._steps,
            "sim_time": st.time,
            "path_length": self._path_length,
            "tilt_deg": tilt,
            "roll_deg": math.degrees(st.rpy[0]),
            "pitch_deg": math.degrees(st.rpy[1]),
            "max_tilt_deg": max(self._max_tilt, tilt),
            "time_over_15deg_s": self._time_over_tilt,
            "halts": self._halts,  # waypoints the tilt guard (robot.tilt_guard_deg) halted this episode
            "reward_terms": terms,
        }
        if result is not None:
            info.update(
                waypoint=waypoint,
                waypoint_outcome=result.outcome,
                waypoint_reached=result.reached,
                hazard_xy=result.hazard_xy,
                trace_xy=result.trace_xy,
                trace_tilt_deg=result.trace_tilt_deg,
            )
        if outcome is not None:
            info["outcome"] = outcome
            info["is_success"] = outcome == "success"  # SB3 logs rollout/success_rate from this key
        return info

    # ------------------------------------------------------------------ rendering
    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' to the env")
            return None
        from diana_lab.envs.render import EnvRenderer

        if self._renderer is None:
            self._renderer = EnvRenderer(self, gui=self.render_mode == "human")
        return self._renderer.render()

    @property
    def trail(self) -> np.ndarray:
        """The driven path of the current episode, (K, 2)."""
        return np.concatenate(self._trail)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self.dynamics.close()
        super().close()
