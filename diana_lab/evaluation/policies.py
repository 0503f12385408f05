"""Policies the evaluation can run: two classical baselines and a wrapper around Stable-Baselines3 models.

Every policy turns an observation into the env's action (a normalised point, or a candidate index with
``action_space=discrete``); the baselines read what a classical stack would know instead (the pose estimate
and the goal; the oracle also the whole cost map) and express their waypoint through
``env.mapping.action_for``, so they drive through exactly the same action space, controller and dynamics as
the learnt policies.

* :class:`StraightLine` -- a blind position controller: the next waypoint lies on the straight line to the
  goal, as far as the action space reaches. It collides with, tips over on or gets stuck at whatever lies
  in between; its success rate is how much of the suite needs no perception at all.
* :class:`~diana_lab.experts.oracle.AStarOracle` (in :mod:`diana_lab.experts`) -- knows the
  map: plans over the traversability cost map and hands out the path's waypoints. Its success rate is the
  suite's practical ceiling.
* :class:`GoalBearing` -- a ranking of a discrete action space's candidates that knows only the goal's bearing:
  behind the slope shield (``policy=bearing``) it is the non-learnt baseline a learnt ranking must beat there.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import gymnasium as gym
import numpy as np

from diana_lab.envs import GOAL_KEYS
from diana_lab.experts.actions import waypoint_action

__all__ = [
    "GoalBearing",
    "Policy",
    "SB3Policy",
    "ShieldedPolicy",
    "StraightLine",
    "sb3_policy",
    "waypoint_action",
]


@runtime_checkable
class Policy(Protocol):
    """What :func:`~diana_lab.evaluation.runner.run_suite` drives: called once per episode, then per step."""

    def reset(self, env: gym.Env) -> None: ...

    def act(self, obs: Any, env: gym.Env) -> np.ndarray: ...


class StraightLine:
    """Waypoints along the straight line to the goal, each as far as the action space reaches."""

    name = "straight"

    def reset(self, env: gym.Env) -> None:
        pass

    def act(self, obs: Any, env: gym.Env) -> np.ndarray:
        return waypoint_action(env, env.unwrapped.goal)


class GoalBearing:
    """A discrete action space's candidates ranked by the goal's bearing alone: the nearest bearing first, the
    longer drive first among equal bearings; its first is driven.

    Why: behind the slope shield (:class:`ShieldedPolicy`), whose checks, detour and route rule do much of the
    navigating, the network's ranking is one part among many; this ranking, which knows nothing of the terrain,
    is what that part must beat for the network to earn its place (``python -m diana_lab.evaluate
    policy=bearing +experiment=reference``: the same shield, the same rover, the network replaced). It reads
    the goal from the observation's ``goal`` vector (sine and cosine of the bearing error; the rover's yaw too
    for ``action_space.frame=world``), as a network would.
    """

    name = "bearing"
    discrete = True
    vecnormalize = None  # no statistics to apply (what ShieldedPolicy and the exporter ask a ranking for)

    def __init__(self) -> None:
        self._bearings: np.ndarray | None = None
        self._lengths: np.ndarray | None = None
        self._world_frame = False

    def reset(self, env: gym.Env) -> None:
        mapping = env.unwrapped.mapping
        if not mapping.discrete:
            raise ValueError(
                f"policy=bearing ranks a discrete action space's candidates; action_space.shape={mapping.cfg.shape} "
                "has none (use action_space=discrete)"
            )
        table = mapping.candidates
        self._bearings, self._lengths = np.arctan2(table[:, 1], table[:, 0]), np.hypot(table[:, 0], table[:, 1])
        self._world_frame = mapping.cfg.frame == "world"

    def ranking(self, obs: Any) -> np.ndarray:
        """Every candidate index, the nearest to the goal's bearing first (ties: the longer drive, then the
        lower index)."""
        if self._bearings is None:
            raise RuntimeError("GoalBearing.ranking: call reset(env) first (every episode), as the evaluation does")
        g = dict(zip(GOAL_KEYS, np.asarray(obs["goal"], dtype=np.float64).reshape(-1), strict=True))
        bearing = np.arctan2(g["sin_heading_error"], g["cos_heading_error"])
        if self._world_frame:
            bearing += np.arctan2(g["sin_yaw"], g["cos_yaw"])
        gap = np.abs(np.angle(np.exp(1j * (self._bearings - bearing))))
        return np.lexsort((-self._lengths, np.round(gap, 9))).astype(np.int64)

    def act(self, obs: Any, env: gym.Env) -> np.ndarray:
        return np.asarray(self.ranking(obs)[0], dtype=np.int64).reshape(())


class SB3Policy:
    """A Stable-Baselines3 model as a :class:`Policy`.

    ``vecnormalize`` is the training run's saved ``VecNormalize`` (unpickled; no env needed): its observation
    statistics are applied before ``model.predict``, since the network only ever saw normalised inputs.
    Stochastic evaluation (``deterministic=False``) seeds torch per episode from ``seed``, so it repeats.
    """

    name = "sb3"

    def __init__(self, model: Any, vecnormalize: Any = None, deterministic: bool = True, seed: int = 0) -> None:
        self.model, self.vecnormalize = model, vecnormalize
        self.deterministic, self.seed = deterministic, seed
        self.discrete = isinstance(getattr(model, "action_space", None), gym.spaces.Discrete)
        self._episodes = 0

    def reset(self, env: gym.Env) -> None:
        if not self.deterministic:
            import torch

            torch.manual_seed(self.seed + self._episodes)
        self._episodes += 1

    def _normalized(self, obs: Any) -> Any:
        if self.vecnormalize is not None and getattr(self.vecnormalize, "norm_obs", False):
            return self.vecnormalize.normalize_obs(obs)
        return obs

    def act(self, obs: Any, env: gym.Env) -> np.ndarray:
        action, _ = self.model.predict(self._normalized(obs), deterministic=self.deterministic)
        if self.discrete:
            return np.asarray(action, dtype=np.int64).reshape(())  # a candidate index, never a float
        return np.asarray(action, dtype=np.float32).reshape(-1)

    def ranking(self, obs: Any) -> np.ndarray:
        """A discrete policy's candidates, its choice first: the most probable (deterministic) or a sample,
        then the others by decreasing probability (ties: lower index first, as ``predict``'s argmax)."""
        import torch

        if not self.discrete:
            raise TypeError("SB3Policy.ranking: only a discrete action space has candidates to rank")
        obs_t, _ = self.model.policy.obs_to_tensor(self._normalized(obs))
        with torch.no_grad():
            dist = self.model.policy.get_distribution(obs_t).distribution
            probs = dist.probs[0].cpu().numpy()
            first = int(probs.argmax()) if self.deterministic else int(dist.sample()[0])
        order = np.argsort(-probs, kind="stable")
        return np.concatenate([[first], order[order != first]]).astype(np.int64)


class ShieldedPolicy:
    """A discrete learnt policy (or another ranking of the candidates: :class:`GoalBearing`) behind the slope shield
    (:mod:`diana_lab.shield.slope_shield`): the first of its ``top_k`` most probable candidates whose drive the
    rover's own fine height map does not call too steep.

    The shield's map is fed every sensor frame the env takes (``env.unwrapped.sensor.last_frame``): one per
    reset and per step, the frame the observation was encoded from; and, with ``eval.shield.cameras``, a frame
    of each hazard camera taken from the same pose (:mod:`diana_lab.evaluation.shield_cameras`), whose noise
    draws from a generator seeded by ``seed`` and the episode's number in the suite."""

    def __init__(self, policy: SB3Policy | GoalBearing, cfg: Any, seed: int = 0) -> None:
        if not policy.discrete:
            from diana_lab.config import ConfigError

            raise ConfigError(
                "eval.shield.enabled: the slope shield picks among a discrete action space's candidates; this "
                "policy's actions are continuous (use action_space=discrete, or eval.shield.enabled=false)"
            )
        self.policy, self.cfg, self.seed = policy, cfg, int(seed)
        self.shield: Any = None  # built on the first reset, from the env's robot
        self.cameras: Any = None  # the hazard cameras (ShieldCameras), built on the first reset of a world
        self._episode = -1  # episodes reset so far, less one: the cameras' noise seed
        self._before: dict[str, int] = {}  # the shield's counters at the episode's start
        self._site: tuple[Any, Any] | None = None  # (world, its SiteMap) with eval.shield.site_map_cell

    @property
    def name(self) -> str:
        return self.policy.name

    @name.setter
    def name(self, value: str) -> None:
        self.policy.name = value

    @property
    def vecnormalize(self) -> Any:
        """The inner policy's observation statistics (what the exporter bakes into the graph)."""
        return self.policy.vecnormalize

    def reset(self, env: gym.Env) -> None:
        from diana_lab.shield import ShieldSettings, SlopeShield

        self.policy.reset(env)
        if self.shield is None:
            self.shield = SlopeShield(ShieldSettings.from_config(self.cfg, env.unwrapped.robot))
        self.shield.reset()
        if self.cfg.site_map_cell > 0:
            self.shield.use_site_map(self._site_map(env.unwrapped.world))
        self._before = self._counters()
        self._episode += 1
        if self.cfg.cameras:
            base = env.unwrapped
            if self.cameras is None or self.cameras.world is not base.world:
                from diana_lab.evaluation.shield_cameras import ShieldCameras

                self.cameras = ShieldCameras(self.cfg.cameras, base.sensor.cfg, base.world)
            self.cameras.reset(np.random.default_rng([self.seed, self._episode]))

    def _site_map(self, world: Any) -> Any:
        """The site map of ``world`` (``eval.shield.site_map_cell``), built once per world."""
        if self._site is None or self._site[0] is not world:
            from diana_lab.shield.site_map import SiteMap

            try:
                site = SiteMap.from_terrain(world.terrain, float(self.cfg.site_map_cell))
            except ValueError as exc:
                from diana_lab.config import ConfigError

                raise ConfigError(f"eval.shield.site_map_cell={self.cfg.site_map_cell}: {exc}") from exc
            self._site = (world, site)
        return self._site[1]

    def _counters(self) -> dict[str, int]:
        """The shield's running counters (over the suite) under their column names."""
        from diana_lab.shield import VETO_CHECKS

        shield = self.shield
        counts = {
            "shield_vetoes": shield.vetoes,
            "shield_revisits": shield.revisits,
            "shield_fallbacks": shield.fallbacks,
            "shield_approaches": shield.approaches,
            "shield_detours": shield.detours,
            "shield_routes": shield.routes,
        }
        counts.update({f"shield_{check}_vetoes": shield.vetoed_by[check] for check in VETO_CHECKS})
        return counts

    def episode_stats(self) -> dict[str, int]:
        """The evaluation's extra columns for the episode just run: ``shield_vetoes``, the decisions the shield
        changed (each step is one decision), and ``shield_revisits``, those of them its place rule alone changed
        (``eval.shield.revisit_radius``: the first allowed candidate ended where the rover had stood), and
        ``shield_fallbacks``, the decisions that found no candidate allowed (its tilt check then dropped), and
        ``shield_approaches``, those its final approach made (``eval.shield.approach_radius``: the goal in reach,
        the straight drive for it allowed; not counted as vetoes), and ``shield_detours``, those its detour made
        (``eval.shield.detour_after``: no progress for that many decisions; not counted as vetoes), and
        ``shield_routes``, those its route rule turned from the policy's choice (``eval.shield.route``; not counted
        as vetoes); and per check,
        ``shield_<check>_vetoes``, the vetoes whose policy's choice failed that check (``tilt``, ``hazard``,
        ``obstacle``, ``peak``; ``place``: it passed them all and the place rule turned from it), one veto counting
        under each check it failed."""
        return {name: count - self._before[name] for name, count in self._counters().items()}

    def act(self, obs: Any, env: gym.Env) -> np.ndarray:
        if self.shield is None:
            raise RuntimeError("ShieldedPolicy.act: call reset(env) first (every episode), as the evaluation does")
        base = env.unwrapped
        frame = base.sensor.last_frame
        if frame is not None:
            self.shield.observe_rover(frame.points, frame.position, frame.rpy, base.sensor.mount)
            if self.cameras is not None:
                self.cameras.feed(self.shield, frame.position, frame.rpy)
        last = getattr(base, "last_waypoint", None)
        if last is not None:  # where the wheels met ground they could not drive (the tilt guard, a slope)
            self.shield.mark_hazard(last.hazard_xy)
        est = base.pose_estimate
        k = self.shield.choose(self.policy.ranking(obs), base.mapping.world_offsets(est.yaw), est.xy, base.goal)
        return np.asarray(k, dtype=np.int64).reshape(())


def sb3_policy(model: Any, vecnormalize: Any, eval_cfg: Any) -> SB3Policy | ShieldedPolicy:
    """The evaluation's policy for an SB3 model: :class:`SB3Policy`, behind the slope shield when
    ``eval.shield.enabled`` (``eval_cfg`` an ``EvalConfig``)."""
    policy = SB3Policy(model, vecnormalize, deterministic=eval_cfg.deterministic, seed=eval_cfg.seed)
    return ShieldedPolicy(policy, eval_cfg.shield, eval_cfg.seed) if eval_cfg.shield.enabled else policy
