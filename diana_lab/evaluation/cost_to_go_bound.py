"""``policy=cost_to_go_bound``: the ``cost_to_go`` network's planner fed the expert's own cost map.

Why: the ``cost_to_go`` encoder (:mod:`diana_lab.agents.cost_to_go`) splits a policy into a learnt part (a CNN
from the elevation map to a per-cell cost) and a fixed part (the shortest-path backup, the candidates'
features and the head's starting arg-min). This baseline replaces the learnt part by what it is taught to
be -- the ``astar_memory`` expert's cost map, labelled as in imitation
(:func:`~diana_lab.training.imitation.expert_cost_label`) and pooled to the planning grid -- so its success
is the bound a perfectly learnt cost CNN would reach with the recipe's grid, candidates and head. It reads the
network's settings from ``algo.extractor.cost_to_go`` and needs the run's ``action_space=discrete`` and
``sensor.encoding=elevation_map`` (e.g. ``+experiment=reference_ctg``). It is privileged: it reads the map.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch
from omegaconf import DictConfig

from diana_lab.agents.cost_to_go import CostToGoNet, init_policy_head
from diana_lab.config import ConfigError, to_object
from diana_lab.evaluation.oracle import AStarOracle

__all__ = ["CostToGoBound"]


class CostToGoBound:
    """See the module docstring. ``settings``: ``algo.extractor.cost_to_go`` (a ``CostToGoConfig``)."""

    name = "cost_to_go_bound"

    def __init__(self, settings: Any, knowledge_radius: float = 12.0) -> None:
        self.settings = settings
        self.expert = AStarOracle(spacing=0.8, knowledge_radius=knowledge_radius, knowledge_memory=True)
        self._net: CostToGoNet | None = None
        self._head: torch.nn.Linear | None = None
        self._offsets: np.ndarray | None = None

    @classmethod
    def from_config(cls, cfg: DictConfig) -> CostToGoBound:
        if cfg.action_space.shape != "discrete" or cfg.sensor.encoding != "elevation_map":
            raise ConfigError(
                "policy=cost_to_go_bound scores a discrete action space's candidates on an elevation map: it needs "
                f"action_space=discrete and sensor.encoding=elevation_map, got action_space.shape="
                f"{cfg.action_space.shape!r} and sensor.encoding={cfg.sensor.encoding!r} "
                "(e.g. +experiment=reference_ctg)"
            )
        settings = to_object("algo", cfg.algo).extractor.cost_to_go
        settings.geometry()  # the map's geometry must be set: a ConfigError naming the missing keys
        return cls(settings)

    def _build(self, env: gym.Env) -> None:
        from diana_lab.training.imitation import cost_label_offsets

        base = env.unwrapped
        space = base.observation_space["elevation_map"]
        c = self.settings
        self._net = CostToGoNet(
            *space.shape,
            candidates=base.mapping.candidates,
            pool=c.pool,
            hidden=c.hidden,
            iterations=c.iterations,
            grad_iterations=0,
            max_cost=c.max_cost,
            **c.geometry(),
        )
        self._head = torch.nn.Linear(self._net.out_dim, self._net.n)
        init_policy_head(self._head, 0, self._net.n, c.beta, c.progress)
        self._offsets = cost_label_offsets(
            {
                "cell_size": c.cell_size,
                "extent_forward": c.extent_forward,
                "extent_back": space.shape[1] * c.cell_size - c.extent_forward,
                "extent_side": c.extent_side,
            }
        )

    def reset(self, env: gym.Env) -> None:
        if self._net is None:
            self._build(env)
        self.expert.reset(env)

    def log_cost(self, env: gym.Env) -> torch.Tensor:
        """``(1, h, w)``: the expert's log cost round the rover, the least over each planning cell."""
        from diana_lab.training.imitation import expert_cost_label

        shape = env.unwrapped.observation_space["elevation_map"].shape[1:]
        label = torch.as_tensor(expert_cost_label(self.expert, env, self._offsets, shape), dtype=torch.float32)
        pooled = -torch.nn.functional.max_pool2d(-label[None, None], self._net.pool)[0]
        return torch.clamp(pooled, max=self._net.log_max)

    @torch.no_grad()
    def act(self, obs: Any, env: gym.Env) -> np.ndarray:
        self.expert.act(obs, env)  # the expert's map of what it knows now
        cost = torch.exp(self.log_cost(env))
        goal = torch.as_tensor(np.asarray(obs["goal"], dtype=np.float32))[None]
        return np.int64(int(self._head(self._net.features(cost, goal)).argmax()))
