"""DAgger from the planner oracle: a warm start for reinforcement learning (``train.imitation``).

Why: a rover policy trained from scratch spends most of a CPU budget discovering that steep ground tips it
over, and the last few per cent of tip-overs are the slowest to go. The receding-horizon A* oracle
(:class:`~diana_lab.evaluation.oracle.AStarOracle` with ``receding=True``) knows the map and the robot and
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
  picks one of them. With ``label_temperature`` > 0 the categorical head is fitted to soft labels instead:
  a softmax over every candidate's cost to the goal as the expert reckons it (:func:`soft_targets`), so that
  of two near-tied candidates neither is taught as wrong.

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
from diana_lab.config.validation import ConfigError
from diana_lab.tracking.mlflow_run import Tracker
from diana_lab.training.signals import raise_pending

__all__ = [
    "ExpertLabels",
    "ImitationResult",
    "cost_label_offsets",
    "expert_cost_label",
    "imitate",
    "make_expert",
    "soft_targets",
]

LABEL_KEY = "expert_action"
COST_KEY = "expert_cost"
CANDIDATES_KEY = "expert_candidate_costs"


def make_expert(cfg: ImitationConfig) -> Any:
    """The expert named by ``train.imitation.expert`` (a :class:`~diana_lab.evaluation.Policy`)."""
    from diana_lab.evaluation.oracle import AStarOracle

    # spacing 0.8 of the action space's reach: the spacing with no tip-overs on the Mars-yard suite
    if cfg.expert == "astar":
        return AStarOracle(receding=True, spacing=0.8)
    if cfg.expert == "astar_memory":
        return AStarOracle(spacing=0.8, knowledge_radius=cfg.knowledge_radius, knowledge_memory=True)
    if cfg.expert == "astar_seen":
        from diana_lab.evaluation.perceived import SeenMapOracle

        return SeenMapOracle(knowledge_radius=cfg.knowledge_radius)
    raise ValueError(
        f"train.imitation.expert: unknown expert {cfg.expert!r}; expected one of 'astar', 'astar_memory', 'astar_seen'"
    )


def cost_label_offsets(map_cfg: dict[str, Any]) -> np.ndarray:
    """``(rows * cols * 4, 2)`` rover-frame points, four per cell of an ``elevation_map`` grid (row-major, the
    cell's quarter points): where :class:`ExpertLabels` reads the expert's cost map for ``info["expert_cost"]``."""
    cell = float(map_cfg["cell_size"])
    rows = max(1, round((map_cfg["extent_forward"] + map_cfg["extent_back"]) / cell))
    cols = max(1, round(2.0 * map_cfg["extent_side"] / cell))
    ahead = map_cfg["extent_forward"] - (np.arange(rows) + 0.5) * cell
    left = map_cfg["extent_side"] - (np.arange(cols) + 0.5) * cell
    quarter = np.array([(-1, -1), (-1, 1), (1, -1), (1, 1)]) * (cell / 4.0)
    centres = np.stack(np.meshgrid(ahead, left, indexing="ij"), axis=-1).reshape(-1, 1, 2)
    return (centres + quarter).reshape(-1, 2)


MAX_COST = 1.0e4  # the cost an expert's label gives a banned cell (``inf``)


def expert_cost_label(expert: Any, env: gym.Env, offsets: np.ndarray, shape: tuple) -> np.ndarray:
    """The log of the cost the expert last planned on (``expert.known``; ``inf`` read as :data:`MAX_COST`),
    the least over each map cell's quarter points ``offsets`` (:func:`cost_label_offsets`), ``shape``
    ``(rows, cols)`` float16 in the observation's map frame round the rover's current pose.

    Why the least: the expert's map (0.2 m on the Mars yard) is speckled with banned cells it threads between;
    a coarser planner fed the cells' mean or worst cost gets stuck where the expert drives on. Beyond the world's
    edge the map holds no terrain for the sensor to see: there the label is the expert's fill for ground it does
    not know (the cheapest cost), all a policy could learn.
    """
    state = env.unwrapped.dynamics.state
    c, s = math.cos(state.rpy[2]), math.sin(state.rpy[2])
    dx, dy = offsets[:, 0], offsets[:, 1]
    known = expert.known
    x, y = state.position[0] + c * dx - s * dy, state.position[1] + s * dx + c * dy
    cheapest = float(np.min(known.cost[np.isfinite(known.cost)], initial=1.0))
    cost = np.where(known.inside(*known.world_to_cell(x, y)), known.cost_at(x, y), cheapest)
    log_cost = np.log(np.clip(cost, 1.0, MAX_COST)).reshape(-1, 4).min(1)
    return log_cost.reshape(shape).astype(np.float16)


class ExpertLabels(gym.Wrapper):
    """Adds the expert's action for the observation just returned as ``info["expert_action"]``.

    Labelling costs about a millisecond per step (the expert's path query), so :meth:`set_labelling` turns
    it off for the RL stage that follows imitation. Given ``cost_offsets`` (:func:`cost_label_offsets`), it
    also adds ``info["expert_cost"]`` (:func:`expert_cost_label`); with ``candidate_costs``, every candidate's
    cost as the expert reckoned it for that choice (``info["expert_candidate_costs"]``, float32 ``(n,)``, ``inf``
    where it saw no way: all ``inf`` when it had no plan), the material of soft labels.
    """

    def __init__(
        self, env: gym.Env, expert: Any, cost_offsets: np.ndarray | None = None, candidate_costs: bool = False
    ) -> None:
        super().__init__(env)
        self.expert = expert
        self.labelling = True
        self.cost_offsets = cost_offsets
        self.candidate_costs = bool(candidate_costs)
        if self.candidate_costs and not isinstance(env.action_space, gym.spaces.Discrete):
            raise ValueError(
                "train.imitation.label_temperature: soft labels spread over a discrete action space's candidates; "
                f"set action_space=discrete (or train.imitation.label_temperature=0), got {env.action_space}"
            )
        if cost_offsets is not None:
            space = env.observation_space["elevation_map"] if "elevation_map" in env.observation_space.spaces else None
            if space is None or space.shape[1] * space.shape[2] * 4 != len(cost_offsets):
                raise ValueError(
                    "train.imitation.cost_weight: the expert's cost labels need an elevation_map observation of the "
                    f"grid they were laid out for ({len(cost_offsets) // 4} cells), got {space}"
                )
            self._cost_shape = space.shape[1:]

    def set_labelling(self, on: bool) -> None:
        self.labelling = bool(on)

    def _label(self, obs: Any) -> np.ndarray:
        """The expert's action in the env's action dtype: float32 ``(2,)``, or an int64 candidate index."""
        return np.asarray(self.expert.act(obs, self.env), dtype=_label_dtype(self.action_space))

    def _cost_label(self) -> np.ndarray:
        return expert_cost_label(self.expert, self.env, self.cost_offsets, self._cost_shape)

    def _candidate_costs(self) -> np.ndarray:
        costs = getattr(self.expert, "candidate_costs", None)
        if costs is None:
            return np.full(self.action_space.n, np.inf, dtype=np.float32)
        return np.asarray(costs, dtype=np.float32)

    def _add_labels(self, obs: Any, info: dict) -> None:
        info[LABEL_KEY] = self._label(obs)  # the expert chooses here, and so sets its candidate costs
        if self.cost_offsets is not None:
            info[COST_KEY] = self._cost_label()
        if self.candidate_costs:
            info[CANDIDATES_KEY] = self._candidate_costs()

    def reset(self, **kwargs: Any) -> tuple[Any, dict]:
        obs, info = self.env.reset(**kwargs)
        if self.labelling:
            self.expert.reset(self.env)
            self._add_labels(obs, info)
        return obs, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self.labelling and not (terminated or truncated):
            self._add_labels(obs, info)
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
    """The aggregated (raw observation, expert action) pairs, preallocated for every iteration's steps; with
    them the expert's cost-map labels (``cost_shape``) and its candidates' costs (``candidates``), if asked."""

    def __init__(
        self,
        space: gym.spaces.Dict,
        capacity: int,
        action_space: gym.Space,
        cost_shape: tuple | None = None,
        candidates: int = 0,
    ) -> None:
        self.obs = {k: np.zeros((capacity, *s.shape), dtype=np.float32) for k, s in space.spaces.items()}
        self.actions = np.zeros((capacity, *action_space.shape), dtype=_label_dtype(action_space))
        self.costs = None if cost_shape is None else np.zeros((capacity, *cost_shape), dtype=np.float16)
        self.candidate_costs = np.zeros((capacity, candidates), dtype=np.float32) if candidates else None
        self.size = 0

    def add(
        self,
        obs: dict[str, np.ndarray],
        actions: np.ndarray,
        costs: np.ndarray | None = None,
        candidate_costs: np.ndarray | None = None,
    ) -> None:
        n = min(len(actions), len(self.actions) - self.size)
        for k, buf in self.obs.items():
            buf[self.size : self.size + n] = obs[k][:n]
        self.actions[self.size : self.size + n] = actions[:n]
        if self.costs is not None:
            self.costs[self.size : self.size + n] = costs[:n]
        if self.candidate_costs is not None:
            self.candidate_costs[self.size : self.size + n] = candidate_costs[:n]
        self.size += n

    def batch(self, idx: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray | None, np.ndarray | None]:
        costs = None if self.costs is None else self.costs[idx].astype(np.float32)
        candidate_costs = None if self.candidate_costs is None else self.candidate_costs[idx]
        return {k: v[idx] for k, v in self.obs.items()}, self.actions[idx], costs, candidate_costs


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


def _costs(infos: Any, shape: tuple, key: str = COST_KEY, dtype: type = np.float16) -> np.ndarray:
    """The expert's cost-map labels of a VecEnv step, ``(n, rows, cols)`` float16 (or, with ``key``
    :data:`CANDIDATES_KEY`, its candidates' costs, ``(n, candidates)``)."""
    out = np.zeros((len(infos), *shape), dtype=dtype)
    for i, info in enumerate(infos):
        out[i] = info[key]
    return out


def _candidate_costs(infos: Any, n: int) -> np.ndarray:
    return _costs(infos, (n,), CANDIDATES_KEY, np.float32)


def soft_targets(candidate_costs: np.ndarray, actions: np.ndarray, temperature: float) -> np.ndarray:
    """Soft labels ``(batch, n)``: ``softmax(-(c - min c) / temperature)`` over each row's candidate costs ``c``,
    nothing on a candidate with no way (``inf``); a row with no finite cost (the expert had no plan and headed
    straight for the goal) is the expert's action ``actions`` alone.

    Why: the expert's one choice among 96 candidates is hard to predict from the map (low top-1 agreement in
    the offline probe of docs/reference_policy.md, many of them near-ties: the 1, 2 and 3 m drives along one
    bearing reach the same cost to go), and a hard label teaches every near-tie but one as wrong. Its costs say
    how much worse each candidate is, in the units of the path.
    """
    c = np.asarray(candidate_costs, dtype=np.float64)
    finite = np.isfinite(c)
    has_any = finite.any(axis=1)
    least = np.where(has_any, np.min(np.where(finite, c, np.inf), axis=1), 0.0)[:, None]
    logits = np.where(finite, -(c - least) / temperature, -np.inf)
    logits[~has_any] = -np.inf
    logits[~has_any, np.asarray(actions, dtype=np.int64)[~has_any]] = 0.0
    weights = np.exp(logits - logits.max(axis=1, keepdims=True))
    return (weights / weights.sum(axis=1, keepdims=True)).astype(np.float32)


def _cost_net(policy: Any) -> Any:
    """The policy's :class:`~diana_lab.agents.cost_to_go.CostToGoNet` (what ``cost_weight`` teaches)."""
    from diana_lab.agents.cost_to_go import CostToGoNet

    net = dict(getattr(policy.features_extractor, "encoders", {})).get("elevation_map")
    if not isinstance(net, CostToGoNet):
        raise ConfigError(
            "train.imitation.cost_weight: the expert's cost map teaches a cost_to_go encoder; set "
            "algo.extractor.elevation_encoder=cost_to_go (or train.imitation.cost_weight=0)"
        )
    return net


def _cost_loss(net: Any, elevation: torch.Tensor, target: np.ndarray) -> torch.Tensor:
    """MSE between the net's log cost per planning cell and the expert's, the least over each planning cell
    (see :class:`ExpertLabels`)."""
    t = torch.as_tensor(target, device=elevation.device).unsqueeze(1)
    t = -torch.nn.functional.max_pool2d(-t, net.pool).squeeze(1) if net.pool > 1 else t.squeeze(1)
    return torch.nn.functional.mse_loss(net.log_cost(elevation), torch.clamp(t, max=net.log_max))


def _loss(policy: Any, obs: dict[str, torch.Tensor], target: np.ndarray) -> torch.Tensor:
    """Cross-entropy of the action logits on candidate indices or on soft labels (:func:`soft_targets`; a
    categorical policy), else the MSE of the deterministic action (the Gaussian mean, or tanh of it) on the
    expert's actions."""
    if isinstance(policy.action_space, gym.spaces.Discrete):
        logits = policy.get_distribution(obs).distribution.logits
        return torch.nn.functional.cross_entropy(logits, torch.as_tensor(target, device=logits.device))
    pred = policy._predict(obs, deterministic=True)  # differentiable
    return torch.nn.functional.mse_loss(pred, torch.as_tensor(target, device=pred.device))


def _fit(model: BaseAlgorithm, data: _Dataset, cfg: ImitationConfig, rng: np.random.Generator) -> tuple[float, float]:
    """Fit the policy to the labels (see :func:`_loss`, and :func:`_cost_loss` with ``cost_weight``); the mean
    action loss and cost loss (NaN without) of the last epoch."""
    threads = torch.get_num_threads()
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    torch.set_num_threads(cfg.fit_threads or usable)
    try:
        return _fit_epochs(model, data, cfg, rng)
    finally:
        torch.set_num_threads(threads)


def _fit_epochs(
    model: BaseAlgorithm, data: _Dataset, cfg: ImitationConfig, rng: np.random.Generator
) -> tuple[float, float]:
    policy = model.policy
    vecnorm = model.get_vec_normalize_env()
    net = _cost_net(policy) if data.costs is not None else None
    optimizer = torch.optim.Adam(policy.parameters(), lr=cfg.learning_rate)
    policy.set_training_mode(True)
    last = (math.nan, math.nan)
    for _ in range(cfg.epochs):
        order = rng.permutation(data.size)
        losses, cost_losses = [], []
        for start in range(0, data.size, cfg.batch_size):
            obs, target, costs, candidate_costs = data.batch(np.sort(order[start : start + cfg.batch_size]))
            if candidate_costs is not None:
                target = soft_targets(candidate_costs, target, cfg.label_temperature)
            if vecnorm is not None:
                obs = vecnorm.normalize_obs(obs)
            obs_t, _ = policy.obs_to_tensor(obs)
            loss = _loss(policy, obs_t, target)
            losses.append(loss.item())
            if net is not None:
                cost_loss = _cost_loss(net, obs_t["elevation_map"], costs)
                cost_losses.append(cost_loss.item())
                loss = loss + cfg.cost_weight * cost_loss
            optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(policy.parameters(), 1.0)
            optimizer.step()
        last = (float(np.mean(losses)), float(np.mean(cost_losses)) if cost_losses else math.nan)
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
    cost_shape = space["elevation_map"].shape[1:] if cfg.cost_weight > 0 and "elevation_map" in space.spaces else None
    if cfg.cost_weight > 0:
        if cost_shape is None:
            raise ConfigError("train.imitation.cost_weight: cost labels need an elevation_map observation")
        _cost_net(model.policy)  # fail before the first step, not after an iteration of labelling
    soft = cfg.label_temperature > 0  # the envs' ExpertLabels refuse a continuous action space
    candidates = int(venv.action_space.n) if soft else 0
    data = _Dataset(space, cfg.iterations * per_env * n_envs, venv.action_space, cost_shape, candidates)
    rng = np.random.default_rng(seed)
    vecnorm = model.get_vec_normalize_env()
    result = ImitationResult()
    t0 = time.perf_counter()
    obs = venv.reset()
    base = venv.unwrapped  # VecEnvWrappers (VecNormalize) keep a reset_infos of their own that stays empty
    labels = _labels(base.reset_infos, venv.action_space)
    costs = _costs(base.reset_infos, cost_shape) if cost_shape else None
    candidate_costs = _candidate_costs(base.reset_infos, candidates) if soft else None
    for it in range(cfg.iterations):
        beta = cfg.beta * cfg.beta_decay**it
        outcomes: dict[str, int] = {}
        learner_steps = 0
        for _ in range(per_env):
            raw = vecnorm.get_original_obs() if vecnorm is not None else obs
            data.add(raw, labels, costs, candidate_costs)
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
            costs = _costs(next_labels, cost_shape) if cost_shape else None
            candidate_costs = _candidate_costs(next_labels, candidates) if soft else None
        loss, cost_loss = _fit(model, data, cfg, rng)
        episodes = sum(outcomes.values())
        row = {
            "beta": beta,
            "loss": loss,
            "cost_loss": cost_loss,
            "dataset": float(data.size),
            "episodes": float(episodes),
            "success_rate": outcomes.get("success", 0) / episodes if episodes else math.nan,
            "tipover_rate": outcomes.get("tipover", 0) / episodes if episodes else math.nan,
            "learner_fraction": learner_steps / (per_env * n_envs),
            "wall_time_s": time.perf_counter() - t0,
        }
        result.history.append(row)
        tracker.log_metrics({f"imitation/{k}": v for k, v in row.items() if math.isfinite(v)}, it)
        cost = f"cost loss {cost_loss:.4f}, " if math.isfinite(cost_loss) else ""  # only with the cost loss on
        print(
            f"imitation {it + 1}/{cfg.iterations}: beta {beta:.3f}, loss {loss:.4f}, {cost}"
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
