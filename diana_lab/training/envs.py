"""Training and evaluation envs built from plain config dicts, so env factories pickle for subprocesses.

A factory carries only the resolved env groups (a ``dict``); each process builds its own ``World`` from it
once and shares it between the envs it hosts (:func:`shared_world`), so four envs in one DummyVecEnv cost
one terrain and one cost map, and a SubprocVecEnv worker never receives a built world over a pipe.
"""

from __future__ import annotations

import functools
import json
import multiprocessing
import signal
from typing import Any

import gymnasium as gym
from hydra.errors import HydraException
from omegaconf import DictConfig, OmegaConf
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv, VecNormalize

from diana_lab import config as C
from diana_lab.config.algo import AlgoConfig
from diana_lab.config.evaluation import EvalConfig
from diana_lab.config.run import ImitationConfig, TrainConfig
from diana_lab.envs.rover_nav import RoverNavEnv
from diana_lab.sim.world import World

__all__ = [
    "check_env",
    "env_config",
    "eval_env_config",
    "make_env",
    "make_training_env",
    "shared_world",
    "training_worlds",
    "wrap_normalize",
]

MONITOR_KEYWORDS = ("outcome",)  # copied from the last step's info into Monitor's episode record
_WORLDS: dict[str, World] = {}


def env_config(cfg: DictConfig) -> dict[str, Any]:
    """The resolved env groups of a composed config as plain data (what a factory carries)."""
    return {g: OmegaConf.to_container(cfg[g], resolve=True) for g in C.GROUPS if g in cfg}


def eval_env_config(cfg: DictConfig, eval_cfg: EvalConfig) -> dict[str, Any]:
    """The env groups for evaluation: training's, with ``eval.dynamics`` swapped in when it is set."""
    groups = env_config(cfg)
    if eval_cfg.dynamics is not None and eval_cfg.dynamics != groups["dynamics"].get("name"):
        node = C.compose([], config_name=f"dynamics/{eval_cfg.dynamics}").dynamics
        groups["dynamics"] = OmegaConf.to_container(node, resolve=True)
    return groups


def training_worlds(cfg: DictConfig, train: TrainConfig) -> list[dict[str, Any]]:
    """The world groups the training envs cycle through: ``world``, then each of ``train.worlds`` composed from
    ``conf/world/<name>.yaml`` with its overrides and validated against its schema (errors name the entry)."""
    worlds = [env_config(cfg)["world"]]
    for i, entry in enumerate(train.worlds):
        name, *overrides = str(entry).split()
        if not (C.CONF_DIR / "world" / f"{name}.yaml").is_file():
            options = sorted(p.stem for p in (C.CONF_DIR / "world").glob("*.yaml"))
            raise C.ConfigError(f"train.worlds[{i}]: no world option {name!r}; expected one of {', '.join(options)}")
        try:
            node = C.compose(overrides, config_name=f"world/{name}").world
        except HydraException as exc:
            raise C.ConfigError(f"train.worlds[{i}] ({entry!r}): {str(exc).splitlines()[0]}") from exc
        world = OmegaConf.to_container(node, resolve=True)
        try:
            C.to_object("world", world)  # the schema's checks, now
        except C.ConfigError as exc:
            raise C.ConfigError(f"train.worlds[{i}] ({entry!r}): {exc}") from exc
        worlds.append(world)
    return worlds


def shared_world(world_cfg: dict[str, Any]) -> World:
    """This process's World for ``world_cfg`` (built on first use; worlds are read-only after building)."""
    key = json.dumps(world_cfg, sort_keys=True, default=str)
    if key not in _WORLDS:
        _WORLDS[key] = C.build(C.to_object("world", world_cfg))
    return _WORLDS[key]


def make_env(groups: dict[str, Any], render_mode: str | None = None, expert: ImitationConfig | None = None) -> gym.Env:
    """One env from plain env groups (module-level, so ``functools.partial(make_env, groups)`` pickles).

    ``expert`` (the ``train.imitation`` config naming the expert) wraps it in
    :class:`~diana_lab.training.imitation.ExpertLabels`.

    In a SubprocVecEnv worker, Ctrl-C is ignored: the main process handles it (checkpoint, then closing the
    workers); a worker that died of it first would turn the interrupt into a broken pipe in the main process.
    """
    if multiprocessing.parent_process() is not None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    env = RoverNavEnv(config=groups, world_instance=shared_world(groups["world"]), render_mode=render_mode)
    if expert is None:
        return env
    from diana_lab.training.imitation import ExpertLabels, make_expert

    return ExpertLabels(env, make_expert(expert))


def check_env(groups: dict[str, Any], seed: int) -> tuple[gym.Space, gym.Space]:
    """Build one env from ``groups`` and reset it once, then close it; return its observation and action spaces
    (what a resumed model is checked against).

    The runner calls this before it opens an MLflow run: every mistake that only shows when the env is built
    or draws its first episode (a DEM that cannot be read, a reward term that cannot be imported or evaluated,
    a URDF that is not there, goal distances the world cannot hold) then fails with no run left behind. The
    world and its cost map are cached in this process, so the envs built next reuse them.
    """
    env = make_env(groups)
    try:
        env.reset(seed=seed)
        return env.observation_space, env.action_space
    finally:
        env.close()


def make_training_env(cfg: DictConfig, train: TrainConfig, seed: int, expert: ImitationConfig | None = None) -> VecEnv:
    """``train.n_envs`` Monitor-wrapped envs; env ``i`` is seeded ``seed + i`` at its first reset.

    ``expert``: label every step for imitation (see :func:`make_env`). With ``train.worlds``, env ``i`` drives in
    world ``i % (1 + len(train.worlds))`` of :func:`training_worlds`."""
    groups = env_config(cfg)
    worlds = training_worlds(cfg, train)
    if resolved_vec_env(train, groups) == "batched":
        from diana_lab.envs.batched import BatchedRoverEnv

        make = None
        if expert is not None:
            from diana_lab.training.imitation import make_expert

            make = functools.partial(make_expert, expert)
        venv = BatchedRoverEnv(groups, train.n_envs, worlds, [shared_world(w) for w in worlds], expert=make)
        venv.seed(seed)
        return venv
    vec_cls = SubprocVecEnv if train.vec_env == "subproc" else DummyVecEnv
    factories = [
        functools.partial(_monitored, {**groups, "world": worlds[i % len(worlds)]}, expert, seed + i)
        for i in range(train.n_envs)
    ]
    # what SB3's make_vec_env does, with a world per env: env i's action space seeded seed + i now, the env
    # itself at its first reset
    venv = vec_cls(factories)
    venv.seed(seed)
    return venv


MAX_ENVS_IN_ONE_PROCESS = 16  # RoverNavEnvs that train.vec_env=auto steps one after another before it refuses


def resolved_vec_env(train: TrainConfig, groups: dict[str, Any]) -> str:
    """``train.vec_env`` with ``auto`` decided: ``batched`` for kinematic dynamics, ``dummy`` otherwise (refused,
    naming the keys, for more envs than one process should step one after another)."""
    if train.vec_env != "auto":
        return train.vec_env
    dynamics = groups["dynamics"].get("name")
    if dynamics == "kinematic":
        return "batched"
    if train.n_envs > MAX_ENVS_IN_ONE_PROCESS:
        raise C.ConfigError(
            f"train.vec_env=auto with dynamics={dynamics}: the batched env steps the kinematic model only, so "
            f"{train.n_envs} envs (train.n_envs) would be stepped one after another in one process; set "
            "train.n_envs (e.g. 4) and train.vec_env=subproc or dummy"
        )
    return "dummy"


def _monitored(groups: dict[str, Any], expert: ImitationConfig | None, action_seed: int) -> gym.Env:
    env = make_env(groups, expert=expert)
    env.action_space.seed(action_seed)
    return Monitor(env, info_keywords=MONITOR_KEYWORDS)


def wrap_normalize(venv: VecEnv, algo: AlgoConfig, gamma: float) -> VecEnv:
    """VecNormalize over the keys in ``algo.norm_obs_keys`` (images and point masks must stay raw)."""
    keys = [k for k in algo.norm_obs_keys if k in venv.observation_space.spaces]
    return VecNormalize(
        venv, norm_obs=bool(keys), norm_reward=algo.norm_reward, norm_obs_keys=keys or None, gamma=gamma
    )
