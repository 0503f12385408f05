"""DAgger from the planner oracle: a warm start for reinforcement learning (``train.imitation``).

Why: a rover policy trained from scratch spends most of a CPU budget discovering that steep ground tips it
over, and the last few per cent of tip-overs are the slowest to go. The receding-horizon A* oracle
(:class:`~diana_lab.experts.oracle.AStarOracle` with ``receding=True``) knows the map and the robot and
can say, from *any* state, which waypoint it would send next. DAgger (Ross et al., 2011) turns that into a
policy over the learner's own observations:

* iteration ``k`` drives the training envs with the expert's action with probability
  ``beta * beta_decay**k`` and the learner's otherwise (``k = 0`` is plain behaviour cloning), recording the
  expert's label for every observation the learner saw;
* after each iteration the policy is fitted to every label gathered so far (the aggregated data set),
  through the same VecNormalize statistics RL will use: by regression of its deterministic action (MSE) for
  a continuous action space, by cross-entropy of its action logits for ``action_space=discrete``, whose
  labels are the candidates nearest to the expert's waypoints (the expert speaks through
  ``WaypointMapping.action_for``). Regression averages a multimodal expert's choices; a categorical head
  picks one of them.

The labels travel in ``info["expert_action"]`` from :class:`ExpertLabels`, a wrapper inside each training
env, so imitation runs through the very VecEnv (and subprocesses) that RL uses next. The expert is
privileged (it reads the cost map); the learner only ever sees its observation, so what it learns is what
the sensor can support -- RL then adapts it. Why not the ``imitation`` package: its DAgger asks an expert
*policy* for actions given observations, and this expert needs the simulator state instead.
"""

from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecEnv

from diana_lab.config.run import ImitationConfig
from diana_lab.experts.oracle import AStarOracle
from diana_lab.experts.perceived import SeenMapOracle
from diana_lab.tracking.mlflow_run import Tracker
from diana_lab.training.signals import raise_pending

__all__ = ["ExpertLabels", "ImitationResult", "imitate", "make_expert"]

LABEL_KEY = "expert_action"


def make_expert(cfg: ImitationConfig) -> Any:
    """The expert named by ``train.imitation.expert`` (a :class:`~diana_lab.evaluation.Policy`)."""

    # spacing 0.8 of the action space's reach: the spacing with no tip-overs on the Mars-yard suite
    if cfg.expert == "astar":
        return AStarOracle(receding=True, spacing=0.8)
    if cfg.expert == "astar_memory":
        return AStarOracle(spacing=0.8, knowledge_radius=cfg.knowledge_radius, knowledge_memory=True)
    if cfg.expert == "astar_seen":
        return SeenMapOracle(knowledge_radius=cfg.knowledge_radius)
    raise ValueError(
        f"train.imitation.expert: unknown expert {cfg.expert!r}; expected one of 'astar', 'astar_memory', 'astar_seen'"
    )


class ExpertLabels(gym.Wrapper):
    """Adds the expert's action for the observation just returned as ``info["expert_action"]``.

    Labelling costs about a millisecond per step (the expert's path query), so :meth:`set_labelling` turns
    it off for the RL stage that follows imitation.
    """

    def __init__(self, env: gym.Env, expert: Any) -> None:
        super().__init__(env)
        self.expert = expert
        self.labelling = True

    def set_labelling(self, on: bool) -> None:
        self.labelling = bool(on)

    def _label(self, obs: Any) -> np.ndarray:
        """The expert's action in the env's action dtype: float32 ``(2,)``, or an int64 candidate index."""
        return np.asarray(self.expert.act(obs, self.env), dtype=_label_dtype(self.action_space))

    def reset(self, **kwargs: Any) -> tuple[Any, dict]:
        obs, info = self.env.reset(**kwargs)
        if self.labelling:
            self.expert.reset(self.env)
            info[LABEL_KEY] = self._label(obs)
        return obs, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self.labelling and not (terminated or truncated):
            info[LABEL_KEY] = self._label(obs)
        return obs, reward, terminated, truncated, info


@dataclass
class ImitationResult:
    """What imitation did, for the run summary and the model card."""

    steps: int = 0  # env steps taken during imitation (not counted in the RL step counter)
    wall_time_s: float = 0.0
    history: list[dict[str, float]] = field(default_factory=list)  # one row per iteration


def _label_dtype(space: gym.Space) -> type:
    return np.int64 if isinstance(space, gym.spaces.Discrete) else np.float32


class _Dataset:
    """The aggregated (raw observation, expert action) pairs, preallocated for every iteration's steps."""

    def __init__(self, space: gym.spaces.Dict, capacity: int, action_space: gym.Space) -> None:
        self.obs = {k: np.zeros((capacity, *s.shape), dtype=np.float32) for k, s in space.spaces.items()}
        self.actions = np.zeros((capacity, *action_space.shape), dtype=_label_dtype(action_space))
        self.size = 0

    def add(self, obs: dict[str, np.ndarray], actions: np.ndarray) -> None:
        n = min(len(actions), len(self.actions) - self.size)
        for k, buf in self.obs.items():
            buf[self.size : self.size + n] = obs[k][:n]
        self.actions[self.size : self.size + n] = actions[:n]
        self.size += n

    def batch(self, idx: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray]:
        return {k: v[idx] for k, v in self.obs.items()}, self.actions[idx]


def _labels(infos: Any, space: gym.Space) -> np.ndarray:
    """The expert labels of a VecEnv step: ``(n, 2)`` float32 actions, or ``(n,)`` int64 candidate indices."""
    out = np.zeros((len(infos), *space.shape), dtype=_label_dtype(space))
    for i, info in enumerate(infos):
        if LABEL_KEY not in info:
            raise RuntimeError(
                "train.imitation: a training env returned no expert label; the envs must be built with "
                "make_training_env(..., expert=...) so that ExpertLabels wraps them"
            )
        out[i] = info[LABEL_KEY]
    return out


def _loss(policy: Any, obs: dict[str, torch.Tensor], target: np.ndarray) -> torch.Tensor:
    """Cross-entropy of the action logits on candidate indices (a categorical policy), else the MSE of the
    deterministic action (the Gaussian mean, or tanh of it) on the expert's actions."""
    if isinstance(policy.action_space, gym.spaces.Discrete):
        logits = policy.get_distribution(obs).distribution.logits
        return torch.nn.functional.cross_entropy(logits, torch.as_tensor(target, device=logits.device))
    pred = policy._predict(obs, deterministic=True)  # differentiable
    return torch.nn.functional.mse_loss(pred, torch.as_tensor(target, device=pred.device))


def _fit(model: BaseAlgorithm, data: _Dataset, cfg: ImitationConfig, rng: np.random.Generator) -> float:
    """Fit the policy to the labels (:func:`_loss`); the mean loss of the last epoch."""
    threads = torch.get_num_threads()
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    torch.set_num_threads(cfg.fit_threads or usable)
    try:
        return _fit_epochs(model, data, cfg, rng)
    finally:
        torch.set_num_threads(threads)


def _fit_epochs(model: BaseAlgorithm, data: _Dataset, cfg: ImitationConfig, rng: np.random.Generator) -> float:
    policy = model.policy
    vecnorm = model.get_vec_normalize_env()
    optimizer = torch.optim.Adam(policy.parameters(), lr=cfg.learning_rate)
    policy.set_training_mode(True)
    last = math.nan
    for _ in range(cfg.epochs):
        order = rng.permutation(data.size)
        losses = []
        for start in range(0, data.size, cfg.batch_size):
            obs, target = data.batch(np.sort(order[start : start + cfg.batch_size]))
            if vecnorm is not None:
                obs = vecnorm.normalize_obs(obs)
            obs_t, _ = policy.obs_to_tensor(obs)
            loss = _loss(policy, obs_t, target)
            losses.append(loss.item())
            optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(policy.parameters(), 1.0)
            optimizer.step()
        last = float(np.mean(losses))
    policy.set_training_mode(False)
    return last


def imitate(
    model: BaseAlgorithm,
    venv: VecEnv,
    cfg: ImitationConfig,
    seed: int,
    tracker: Tracker,
) -> ImitationResult:
    """Run DAgger on ``model``'s policy through ``venv`` (built with expert labels); see the module docstring.

    Metrics go to the tracker as ``imitation/<name>`` with the iteration as the step; the labels are switched
    off in ``venv`` when done.
    """
    n_envs = venv.num_envs
    per_env = math.ceil(cfg.steps_per_iteration / n_envs)
    space = venv.observation_space
    if not isinstance(space, gym.spaces.Dict):
        raise TypeError(f"train.imitation: expected a Dict observation space, got {space}")
    data = _Dataset(space, cfg.iterations * per_env * n_envs, venv.action_space)
    rng = np.random.default_rng(seed)
    vecnorm = model.get_vec_normalize_env()
    result = ImitationResult()
    t0 = time.perf_counter()
    obs = venv.reset()
    base = venv.unwrapped  # VecEnvWrappers (VecNormalize) keep a reset_infos of their own that stays empty
    labels = _labels(base.reset_infos, venv.action_space)
    for it in range(cfg.iterations):
        beta = cfg.beta * cfg.beta_decay**it
        outcomes: dict[str, int] = {}
        learner_steps = 0
        for _ in range(per_env):
            raw = vecnorm.get_original_obs() if vecnorm is not None else obs
            data.add(raw, labels)
            use_expert = rng.random(n_envs) < beta
            actions = labels.copy()
            if not use_expert.all():
                learner, _ = model.predict(obs, deterministic=True)
                actions[~use_expert] = learner[~use_expert]
                learner_steps += int((~use_expert).sum())
            obs, _, dones, infos = venv.step(actions)
            raise_pending()  # a safe point for Ctrl-C / SIGTERM, as every RL step is (training.signals)
            result.steps += n_envs
            next_labels = []
            for i, done in enumerate(dones):
                if done:
                    outcome = str(infos[i].get("outcome"))
                    outcomes[outcome] = outcomes.get(outcome, 0) + 1
                next_labels.append(base.reset_infos[i] if done else infos[i])
            labels = _labels(next_labels, venv.action_space)
        loss = _fit(model, data, cfg, rng)
        episodes = sum(outcomes.values())
        row = {
            "beta": beta,
            "loss": loss,
            "dataset": float(data.size),
            "episodes": float(episodes),
            "success_rate": outcomes.get("success", 0) / episodes if episodes else math.nan,
            "tipover_rate": outcomes.get("tipover", 0) / episodes if episodes else math.nan,
            "learner_fraction": learner_steps / (per_env * n_envs),
            "wall_time_s": time.perf_counter() - t0,
        }
        result.history.append(row)
        tracker.log_metrics({f"imitation/{k}": v for k, v in row.items() if math.isfinite(v)}, it)
        print(
            f"imitation {it + 1}/{cfg.iterations}: beta {beta:.3f}, loss {loss:.4f}, "
            f"{data.size} labels, "
            f"{episodes} episodes ({row['success_rate']:.0%} success, {row['learner_fraction']:.0%} learner steps)",
            file=sys.stderr,
            flush=True,
        )
    venv.env_method("set_labelling", False)
    log_std = getattr(model.policy, "log_std", None)
    if cfg.log_std is not None and isinstance(log_std, torch.nn.Parameter):
        with torch.no_grad():
            log_std.fill_(cfg.log_std)
    elif cfg.log_std is not None and isinstance(venv.action_space, gym.spaces.Box):
        print(
            f"note: train.imitation.log_std={cfg.log_std} is not applied: {type(model).__name__}'s policy has no "
            "state-independent log std (it applies to PPO/A2C Gaussian policies)",
            file=sys.stderr,
        )
    result.wall_time_s = time.perf_counter() - t0
    return result
