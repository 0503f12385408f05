"""``train.vec_env=batched``: many rovers as arrays, stepped by compiled calls, behind SB3's ``VecEnv`` API.

Every rover does what one :class:`~diana_lab.envs.rover_nav.RoverNavEnv` with kinematic dynamics does, and the
scalar env stays the reference (``tests/envs/test_batched_parity.py`` drives both from the same seeds, episodes
and actions and compares observations, per-term rewards, outcomes and episode lengths). A step of the batch:

1. the actions become waypoints (every action space, both frames; clamped to the map), vectorised;
2. one compiled call runs every rover's waypoint (:mod:`~diana_lab.envs.batched.kinematics`);
3. one compiled call casts every rover's sensor frame and one encodes them (:mod:`~diana_lab.envs.batched.sensing`);
4. outcomes, rewards (:mod:`~diana_lab.envs.batched.rewards`) and episode statistics, vectorised;
5. the rovers whose episode ended are reset (a new episode from their own generator) and observed again, their
   last observation kept in ``info["terminal_observation"]`` (SB3's auto-reset contract).

Randomness: rover ``i`` owns a generator, seeded ``seed + i`` at the first :meth:`reset` after :meth:`seed`, as
a ``DummyVecEnv`` seeds env ``i``; it draws what the scalar env would (episodes, pose noise, sensor noise) in the
same order. What stays per rover in Python: episode sampling at resets, pose and sensor noise, the ``points``
encoding and a reward term of the user's own (:attr:`slow_paths` names those in use).

Per-step ``infos`` are empty dicts except at an episode's end, where they hold what SB3 and the training
callbacks read: ``outcome``, ``is_success``, ``episode`` (Monitor's ``r``, ``l``, ``t`` and the outcome),
``episode_reward_terms`` (the episode's sum of each weighted term), ``terminal_observation`` and
``TimeLimit.truncated``. :attr:`last_reward_terms` holds the last step's weighted terms of every rover.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from gymnasium.utils import seeding
from stable_baselines3.common.vec_env import VecEnv

from diana_lab.core.validation import ConfigError
from diana_lab.envs import ActionError
from diana_lab.envs.action_spaces import square_to_disc
from diana_lab.envs.batched.geometry import goal_vectors, moved, place_waypoints
from diana_lab.envs.batched.kinematics import (
    OUTCOME_CODES,
    R_COLLISION,
    R_HALTED,
    R_OOB,
    R_TIPOVER,
    KinematicsArrays,
)
from diana_lab.envs.batched.rewards import BatchContext, BatchedRewards, waypoint_result
from diana_lab.envs.batched.sensing import BatchedSensor
from diana_lab.envs.batched.stats import trace_stats
from diana_lab.envs.batched.views import RoverView
from diana_lab.envs.rewards import RewardContext
from diana_lab.envs.rover_nav import RoverNavEnv
from diana_lab.sim.kinematic import KinematicDynamics

__all__ = ["BatchedRoverEnv"]

TERMINAL_CODES = {R_TIPOVER: "tipover", R_COLLISION: "collision", R_OOB: "out_of_bounds"}
_NAMES = np.array(OUTCOME_CODES)


class _World:
    """One world's share of the batch: a scalar env as the template of its parts, and its rovers' rows."""

    def __init__(self, env: RoverNavEnv, rows: np.ndarray, n: int) -> None:
        if not isinstance(env.dynamics, KinematicDynamics):
            raise ConfigError(
                f"dynamics={env.cfg['dynamics'].name}: the batched env (train.vec_env=batched) steps the kinematic "
                "model only; use train.vec_env=dummy or subproc for dynamics=physics (a batched-trained policy is "
                "evaluated in physics unchanged: eval.dynamics=physics)"
            )
        self.env, self.rows = env, rows
        self.kinematics = KinematicsArrays(env.dynamics, env.controller)
        self.sensor = BatchedSensor(env.sensor, n)
        self.goal_low = env._goal_low
        self.goal_high = env._goal_high
        self.box = np.array(env._waypoint_box)  # x0, x1, y0, y1
        self.goal_distance = env.goal_distance  # the goal-distance field a reward term reads (None: none does)
        self.goal_fields = np.zeros((n, *env.goal_distance.shape)) if env.goal_distance is not None else None

    def path_to_goal(self, xy: np.ndarray, out: np.ndarray, rows: np.ndarray | None = None) -> None:
        """``out[r]``: the path distance from this world's rover ``r`` (at ``xy[r]``) to its goal, for its rovers
        among ``rows`` (default: all of them); nothing when no reward term reads it."""
        if self.goal_distance is not None:
            mine = self.rows if rows is None else rows[np.isin(rows, self.rows)]
            out[mine] = self.goal_distance.at_rows(self.goal_fields, mine, xy)


class BatchedRoverEnv(VecEnv):
    """``n_envs`` rovers; rover ``i`` drives in ``worlds[i % len(worlds)]`` (each an env group ``world``).

    Args:
        groups: the env groups (``world``, ``robot``, ``dynamics``, ``sensor``, ``action_space``, ``reward``,
            ``episode``) as plain data or typed configs, as :func:`diana_lab.training.envs.env_config` gives them.
        n_envs: the number of rovers.
        worlds: the world groups the rovers are split across (default: ``groups["world"]`` alone).
        world_instances: ready :class:`World` objects for ``worlds`` (shared with other envs of the process).
        expert: makes one expert policy (``act(obs, env)``, ``reset(env)``; the DAgger oracles) per rover:
            every step's ``infos[i]["expert_action"]`` (and ``reset_infos[i]``'s, at a new episode) is then its
            label for the observation returned, read through a :class:`~diana_lab.envs.batched.views.RoverView`;
            ``env_method("set_labelling", False)`` stops the labelling.
    """

    def __init__(
        self,
        groups: dict[str, Any],
        n_envs: int,
        worlds: Sequence[dict[str, Any]] | None = None,
        world_instances: Sequence[Any] | None = None,
        expert: Callable[[], Any] | None = None,
    ) -> None:
        if n_envs < 1:
            raise ConfigError(f"train.n_envs: expected at least one rover, got {n_envs}")
        worlds = list(worlds) if worlds else [groups["world"]]
        if n_envs < len(worlds):
            raise ConfigError(f"train.n_envs={n_envs}: fewer rovers than the {len(worlds)} worlds to train in")
        self.n = n_envs
        self.world_of = np.arange(n_envs) % len(worlds)
        self.parts: list[_World] = []
        for w, world_cfg in enumerate(worlds):
            inst = world_instances[w] if world_instances is not None else None
            env = RoverNavEnv(config={**groups, "world": world_cfg}, world_instance=inst)
            self.parts.append(_World(env, np.flatnonzero(self.world_of == w), n_envs))
        first = self.parts[0].env
        self.template = first
        self.mapping = first.mapping
        self.sensor_key = first.sensor_key
        self.episode_cfg = first.episode_cfg
        self.robot = first.robot
        self.cfg = first.cfg
        self.render_mode = None
        self.rewards = BatchedRewards(first.rewards)
        for part in self.parts[1:]:
            if part.env.observation_space[self.sensor_key] != first.observation_space[self.sensor_key]:
                raise ConfigError("train.worlds: every world must give the same sensor observation space")
        pose = first.cfg["dynamics"].pose_noise
        self._pose_noise = (pose.position_std, math.radians(pose.yaw_std_deg), math.radians(pose.tilt_std_deg))
        self._noisy_pose = first.pose_service._noisy
        self.slow_paths = [f"reward.terms.{t}" for t in self.rewards.slow] + self.parts[0].sensor.slow_paths
        self.box = np.empty((n_envs, 4))  # each rover's waypoint box and goal-vector bounds (its world's)
        self.goal_low, self.goal_high = np.empty((n_envs, 7)), np.empty((n_envs, 7))
        for part in self.parts:
            self.box[part.rows] = part.box
            self.goal_low[part.rows], self.goal_high[part.rows] = part.goal_low, part.goal_high
        super().__init__(n_envs, first.observation_space, first.action_space)
        self._allocate()
        self._actions: np.ndarray | None = None
        self._rngs: list[np.random.Generator | None] = [None] * n_envs
        self.experts = [expert() for _ in range(n_envs)] if expert is not None else None
        self.views = [RoverView(self, i) for i in range(n_envs)] if expert is not None else None
        self.labelling = expert is not None

    # ------------------------------------------------------------------ state
    def _allocate(self) -> None:
        n = self.n
        self.state = np.zeros((n, 7))  # x, y, z, roll, pitch, yaw, time
        self.est = np.zeros((n, 5))  # the agent's pose estimate: x, y, yaw, roll, pitch
        self.ctrl_est = np.zeros((n, 3))  # the controller's: x, y, yaw
        self.start = np.zeros((n, 2))
        self.goal = np.zeros((n, 2))
        self.distance = np.zeros(n)
        self.heading_error = np.zeros(n)
        self.start_distance = np.zeros(n)
        self.path_to_goal = np.full(n, np.nan)
        self.steps = np.zeros(n, dtype=np.int64)
        self.path_length = np.zeros(n)
        self.max_tilt = np.zeros(n)
        self.time_over_tilt = np.zeros(n)
        self.halts = np.zeros(n, dtype=np.int64)
        k = self.episode_cfg.stuck_steps
        self.recent = np.zeros((n, k + 1, 2))  # ring of the positions the stuck rule compares
        self.n_recent = np.zeros(n, dtype=np.int64)
        self.drawn = np.zeros(n, dtype=np.int64)  # episodes drawn per rover (the curriculum's counter)
        self.ep_return = np.zeros(n)
        self.ep_terms = np.zeros((n, len(self.rewards.names)))
        self.ep_start = np.zeros(n)
        self.last_reward_terms = np.zeros((n, len(self.rewards.names)))
        self.goal_obs = np.zeros((n, *self.observation_space["goal"].shape), dtype=np.float32)
        self.waypoint = np.zeros((n, 2))
        self.code = np.zeros(n, dtype=np.int64)
        self.duration = np.zeros(n)
        self.length = np.zeros(n)
        self.hazard = np.zeros((n, 2))
        self.n_trace = np.zeros(n, dtype=np.int64)
        extent = self.mapping.extent * math.sqrt(2.0) + 1.0
        self.trace = np.zeros((n, self._capacity(extent), 7))

    def _capacity(self, distance: float) -> int:
        return max(part.kinematics.capacity(distance) for part in self.parts)

    @property
    def reward_names(self) -> list[str]:
        return list(self.rewards.names)

    # ------------------------------------------------------------------ VecEnv API
    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        if seed is None:
            seed = int(np.random.SeedSequence().entropy % (2**31))
        self.action_space.seed(seed)
        self._seeds = [seed + i for i in range(self.n)]
        return self._seeds

    def reset(self) -> dict[str, np.ndarray]:
        for i in range(self.n):
            s = self._seeds[i]
            if s is not None or self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(s)
        self._reset_seeds()
        self._reset_options()
        self._reset_rovers(np.arange(self.n))
        obs = self._obs()
        self.reset_infos = [{} for _ in range(self.n)]
        self._label(obs, np.arange(self.n), self.reset_infos, new_episode=True)
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, list[dict]]:
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async()")
        if self._rngs[0] is None:
            raise RuntimeError("step() called before reset()")
        actions, self._actions = self._actions, None
        n, rows = self.n, np.arange(self.n)
        self.waypoint[:] = self._waypoints(actions)
        prev_distance, prev_path = self.distance.copy(), self.path_to_goal.copy()
        self._controller_estimates()
        max_wp = float(np.hypot(*(self.waypoint - self.ctrl_est[:, :2]).T).max())
        if self._capacity(max_wp) > self.trace.shape[1]:
            self.trace = np.zeros((n, self._capacity(max_wp) * 2, 7))
        for part in self.parts:
            part.kinematics.execute(
                part.rows, self.state, self.waypoint, self.ctrl_est, self.trace, self.n_trace, self.code,
                self.duration, self.length, self.hazard,
            )  # fmt: skip
        stats = trace_stats(self.trace, self.n_trace, self.goal)  # nearest approach, max tilt/roll/pitch, time over 15
        self.steps += 1
        self.path_length += self.length
        self.halts += self.code == R_HALTED
        self.max_tilt = np.maximum(self.max_tilt, stats[:, 1])
        self.time_over_tilt += stats[:, 4]
        self._mark_hazards()
        self._observe(rows)
        for part in self.parts:
            part.path_to_goal(self.state, self.path_to_goal)
        outcome = self._outcomes(stats[:, 0])
        truncated = np.isin(outcome, ("timeout", "stuck"))
        terminated = (outcome != "") & ~truncated
        batch = BatchContext(
            prev_distance, self.distance.copy(), self.heading_error.copy(), stats[:, 2], stats[:, 3],
            self.duration.copy(), _NAMES[self.code], outcome, self.steps.copy(), self.path_length.copy(),
            self.start_distance.copy(), lambda k: self._context(k, prev_distance, prev_path, outcome), prev_path,
            self.path_to_goal.copy(),
        )  # fmt: skip
        reward, terms = self.rewards(batch)
        self.last_reward_terms = terms
        self.ep_return += reward
        self.ep_terms += terms
        dones = terminated | truncated
        infos: list[dict[str, Any]] = [{} for _ in range(n)]
        done_rows = np.flatnonzero(dones)
        if done_rows.size:
            terminal = self._obs(done_rows)
            now = time.time()
            for j, i in enumerate(done_rows):
                info = infos[i]
                info["outcome"] = str(outcome[i])
                info["is_success"] = bool(outcome[i] == "success")
                info["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
                info["terminal_observation"] = {k: v[j] for k, v in terminal.items()}
                info["episode"] = {
                    "r": round(float(self.ep_return[i]), 6),
                    "l": int(self.steps[i]),
                    "t": round(now - self.ep_start[i], 6),
                    "outcome": str(outcome[i]),
                }
                info["episode_reward_terms"] = dict(zip(self.rewards.names, self.ep_terms[i].tolist()))
            self._reset_rovers(done_rows)
        obs = self._obs()
        if self.labelling:
            self._label(obs, np.flatnonzero(~dones), infos, new_episode=False)
            for i in done_rows:
                self.reset_infos[i] = {}
            self._label(obs, done_rows, self.reset_infos, new_episode=True)
        return obs, reward.astype(np.float32), dones, infos

    def close(self) -> None:
        for part in self.parts:
            part.env.close()

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        """An attribute every rover shares (``render_mode``, ``mapping``, ``cfg``, ...), once per index; the
        rovers' own state lives in this env's arrays, not in per-rover objects."""
        shared = {"render_mode", "mapping", "cfg", "sensor_key", "episode_cfg", "robot", "observation_space"}
        if attr_name not in shared:
            raise AttributeError(
                f"BatchedRoverEnv has no per-rover attribute {attr_name!r}; the shared ones are {sorted(shared)}"
            )
        return [getattr(self, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        raise AttributeError(f"BatchedRoverEnv: setting {attr_name!r} per rover is not supported")

    def env_method(self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any) -> list[Any]:
        """``set_labelling(on)``: the expert labels on or off (what DAgger's ``ExpertLabels`` wrapper offers)."""
        if method_name == "set_labelling" and self.experts is not None:
            self.labelling = bool(method_args[0] if method_args else method_kwargs["on"])
            return [None for _ in self._get_indices(indices)]
        raise AttributeError(f"BatchedRoverEnv: no per-rover method {method_name!r}")

    def _label(self, obs: dict[str, np.ndarray], rows: np.ndarray, infos: list[dict], new_episode: bool) -> None:
        """The experts' labels for the observations of ``rows`` into ``infos[i]["expert_action"]``."""
        if not self.labelling or self.experts is None or self.views is None:
            return
        dtype = np.int64 if self.mapping.discrete else np.float32
        for i in rows:
            view, expert = self.views[i], self.experts[i]
            if new_episode:
                expert.reset(view)
            infos[i]["expert_action"] = np.asarray(expert.act({k: v[i] for k, v in obs.items()}, view), dtype=dtype)

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    # ------------------------------------------------------------------ the step's parts
    def _waypoints(self, actions: np.ndarray) -> np.ndarray:
        """Every rover's waypoint (``RoverNavEnv.step``: estimate + the mapped offset, clamped to its map)."""
        cfg = self.mapping.cfg
        if self.mapping.discrete:
            a = np.asarray(actions)
            if not np.issubdtype(a.dtype, np.integer):
                raise ActionError(
                    f"action: expected integer candidate indices (action_space.shape=discrete), got dtype {a.dtype}"
                )
            a = a.reshape(self.n)
            table = self.mapping.candidates
            if a.min() < 0 or a.max() >= len(table):
                bad = int(a[(a < 0) | (a >= len(table))][0])
                raise ActionError(
                    f"action: candidate index {bad} is outside [0, {len(table)}) (action_space.shape=discrete)"
                )
            x, y = table[a, 0], table[a, 1]
        else:
            a = np.asarray(actions, dtype=np.float64).reshape(self.n, -1)
            if a.shape[1] != 2:
                raise ActionError(f"action: expected shape (2,) per rover, got {a.shape[1:]}")
            if not np.isfinite(a).all():
                raise ActionError(
                    f"action: expected finite values in [-1, 1], got {a[~np.isfinite(a).all(1)][0].tolist()}"
                )
            a = np.minimum(np.maximum(a, -1.0), 1.0)
            if cfg.shape == "circle":
                a = square_to_disc(a)
            x, y = a[:, 0] * self.mapping.extent, a[:, 1] * self.mapping.extent
            d = cfg.min_distance
            if d > 0:
                norm = np.hypot(x, y)
                near = norm < d
                safe = np.where(norm > 1e-9, norm, 1.0)
                x = np.where(near, np.where(norm > 1e-9, x / safe * d, d), x)
                y = np.where(near, np.where(norm > 1e-9, y / safe * d, 0.0), y)
        wp = np.empty((self.n, 2))
        place_waypoints(
            np.ascontiguousarray(x, dtype=np.float64), np.ascontiguousarray(y, dtype=np.float64), self.est,
            cfg.frame == "rover", self.box, wp,
        )  # fmt: skip
        return wp

    def _draw_estimate(self, i: int) -> tuple[float, float, float, float, float]:
        """``PoseService.estimate`` of rover ``i`` (x, y, yaw, roll, pitch), drawing from its generator."""
        s = self.state[i]
        x, y, roll, pitch, yaw = float(s[0]), float(s[1]), float(s[3]), float(s[4]), float(s[5])
        if self._noisy_pose:
            rng, (pos, yaw_std, tilt) = self._rngs[i], self._pose_noise
            dxy = rng.normal(0.0, pos, 2)
            x, y = float(x + dxy[0]), float(y + dxy[1])
            yaw += rng.normal(0.0, yaw_std)
            roll += rng.normal(0.0, tilt)
            pitch += rng.normal(0.0, tilt)
        return x, y, float(yaw), float(roll), float(pitch)

    def _controller_estimates(self) -> None:
        if not self._noisy_pose:
            self.ctrl_est[:, :2] = self.state[:, :2]
            self.ctrl_est[:, 2] = self.state[:, 5]
            return
        for i in range(self.n):
            x, y, yaw, _, _ = self._draw_estimate(i)
            self.ctrl_est[i] = x, y, yaw

    def _observe(self, rows: np.ndarray) -> None:
        """The pose estimates, goal vectors and sensor encodings of ``rows`` (``RoverNavEnv._observe``)."""
        if self._noisy_pose:
            for i in rows:
                self.est[i] = self._draw_estimate(i)
        else:
            self.est[rows, 0:2] = self.state[rows, 0:2]
            self.est[rows, 2] = self.state[rows, 5]
            self.est[rows, 3:5] = self.state[rows, 3:5]
        goal_vectors(
            rows, self.est, self.goal, self.episode_cfg.distance_scale, self.goal_low, self.goal_high, self.goal_obs,
            self.distance, self.heading_error,
        )  # fmt: skip
        for w, part in enumerate(self.parts):
            sel = rows[self.world_of[rows] == w]
            if sel.size:
                part.sensor.observe(sel, self.state)

    def _mark_hazards(self) -> None:
        """Where this step stopped a drive, into the sensors' stopped-drive channel (``RoverNavEnv.step``)."""
        stopped = np.flatnonzero(np.isfinite(self.hazard[:, 0]))
        for w, part in enumerate(self.parts):
            sel = stopped[self.world_of[stopped] == w]
            if sel.size:
                part.sensor.mark_hazards(sel, self.hazard[sel])

    def _outcomes(self, nearest: np.ndarray) -> np.ndarray:
        """Each rover's episode outcome after this step (``""``: it goes on), as ``RoverNavEnv._outcome``."""
        ep = self.episode_cfg
        outcome = np.full(self.n, "", dtype=object)
        success = nearest <= ep.goal_tolerance
        outcome[success] = "success"
        for code, name in TERMINAL_CODES.items():
            outcome[(self.code == code) & ~success] = name
        going = outcome == ""
        idx = np.flatnonzero(going)
        k = ep.stuck_steps
        slot = self.n_recent[idx] % (k + 1)
        self.recent[idx, slot] = self.state[idx, :2]
        self.n_recent[idx] += 1
        full = self.n_recent[idx] > k
        old = self.recent[idx, self.n_recent[idx] % (k + 1)]  # the entry k waypoints before the newest
        stuck = full & (moved(old, self.state[idx, :2]) < ep.stuck_distance)
        outcome[idx[stuck]] = "stuck"
        late = (self.steps[idx] >= ep.max_steps) | (self.state[idx, 6] >= ep.max_time_s)
        outcome[idx[~stuck & late]] = "timeout"
        return outcome

    def _context(self, k: int, prev_distance: np.ndarray, prev_path: np.ndarray, outcome: np.ndarray) -> RewardContext:
        """Rover ``k``'s scalar reward context (for a term that is not built in)."""
        result = waypoint_result(
            OUTCOME_CODES[self.code[k]],
            self.duration[k],
            self.length[k],
            self.trace[k, : self.n_trace[k]],
            self.hazard[k],
        )
        return RewardContext(
            float(prev_distance[k]),
            float(self.distance[k]),
            float(self.heading_error[k]),
            result,
            str(outcome[k]) or None,
            int(self.steps[k]),
            float(self.path_length[k]),
            float(self.start_distance[k]),
            float(prev_path[k]),
            float(self.path_to_goal[k]),
        )

    def _reset_rovers(self, rows: np.ndarray) -> None:
        """New episodes for ``rows`` (``RoverNavEnv.reset``: the same draws from each rover's generator)."""
        now = time.time()
        for i in rows:
            part = self.parts[self.world_of[i]]
            rng = self._rngs[i]
            sampler = part.env.sampler
            sampler.episodes_drawn = int(self.drawn[i])
            ep = sampler.sample(rng)
            self.drawn[i] = sampler.episodes_drawn
            self.start[i], self.goal[i] = ep.start, ep.goal
            if part.goal_fields is not None:
                part.goal_distance.field(ep.goal, out=part.goal_fields[i])
            part.sensor.reset(i, rng)
            z, rp = part.env.dynamics._poses(ep.start[None, :], np.array([ep.yaw]))
            self.state[i] = (
                ep.start[0],
                ep.start[1],
                z[0],
                rp[0, 0],
                rp[0, 1],
                (ep.yaw + math.pi) % (2 * math.pi) - math.pi,
                0.0,
            )
        self.steps[rows] = 0
        self.path_length[rows] = 0.0
        self.time_over_tilt[rows] = 0.0
        self.halts[rows] = 0
        self.recent[rows, 0] = self.state[rows, :2]
        self.n_recent[rows] = 1
        self.ep_return[rows] = 0.0
        self.ep_terms[rows] = 0.0
        self.ep_start[rows] = now
        self._observe(rows)
        self.max_tilt[rows] = 0.0
        self.start_distance[rows] = self.distance[rows]
        for part in self.parts:
            part.path_to_goal(self.state, self.path_to_goal, rows)

    def _obs(self, rows: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """The observation dict of ``rows`` (every rover: copies of the buffers)."""
        sel = slice(None) if rows is None else rows
        return {
            "goal": self.goal_obs[sel].copy(),
            self.sensor_key: self.parts_obs()[sel].copy(),
        }

    def parts_obs(self) -> np.ndarray:
        """The sensor encodings of every rover (each world's rovers from its own sensor's buffer)."""
        if len(self.parts) == 1:
            return self.parts[0].sensor.obs
        out = np.empty_like(self.parts[0].sensor.obs)
        for part in self.parts:
            out[part.rows] = part.sensor.obs[part.rows]
        return out
