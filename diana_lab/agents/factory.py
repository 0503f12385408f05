"""Build or load an SB3 model from the typed ``algo`` config with ``hydra.utils.instantiate``.

The ``algo`` node names the class (``_target_: stable_baselines3.PPO``) and holds its hyperparameters; the
keys in :data:`~diana_lab.config.algo.NON_SB3_KEYS` are ours (network sizes, VecNormalize, the extractor)
and become ``policy_kwargs`` and the like here. Instantiating a ``_partial_`` first and then adding the
run-time objects (env, seed, action noise) keeps the YAML pure data.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from hydra.utils import get_class, instantiate
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.utils import LinearSchedule
from stable_baselines3.common.vec_env import VecEnv

from diana_lab.agents.extractors import RoverExtractor
from diana_lab.agents.overlap import overlapped
from diana_lab.agents.strips import init_logit_head
from diana_lab.config.algo import NON_SB3_KEYS, AlgoConfig, check_action_space
from diana_lab.core.validation import ConfigError

__all__ = ["algo_class", "build_model", "load_model", "policy_kwargs"]


def policy_kwargs(cfg: AlgoConfig, env_cfg: dict[str, Any] | None = None) -> dict[str, Any]:
    """``MultiInputPolicy`` kwargs: our extractor, the head sizes and any extra ``algo.policy_kwargs``.

    ``env_cfg``: the env's typed groups, whose map and candidates the ``strips`` encoder reads."""
    ext = cfg.extractor
    kwargs: dict[str, Any] = {
        "features_extractor_class": RoverExtractor,
        "features_extractor_kwargs": {
            "goal_hidden": list(ext.goal_hidden),
            "cnn_channels": list(ext.cnn_channels),
            "cnn_pool": list(ext.cnn_pool),
            "sensor_features": ext.sensor_features,
            "elevation_encoder": ext.elevation_encoder,
            "point_hidden": list(ext.point_hidden),
        },
        "net_arch": list(cfg.net_arch),
        "normalize_images": False,  # depth images are already in [0, 1] (float32, not uint8)
    }
    if ext.elevation_encoder == "strips":
        kwargs["features_extractor_kwargs"]["strips"] = strips_kwargs(cfg, env_cfg)
        # the logits are the encoder's (init_logit_head); the value head keeps algo.net_arch
        kwargs["net_arch"] = {"pi": [], "vf": list(cfg.net_arch)}
    kwargs.update(dict(cfg.policy_kwargs))
    return kwargs


def env_groups_of(env: VecEnv) -> dict[str, Any] | None:
    """The typed env groups of a VecEnv's first env (``RoverNavEnv.cfg``), or ``None`` for an env without them."""
    try:
        return env.get_attr("cfg", [0])[0]
    except AttributeError:
        return None


def resolve_encoder(cfg: AlgoConfig, env_cfg: dict[str, Any] | None) -> AlgoConfig:
    """``cfg`` with ``algo.extractor.elevation_encoder: auto`` decided for the env: ``strips`` where an
    ``elevation_map`` meets a discrete action space in the rover's frame (what it scores), ``cnn`` otherwise."""
    if cfg.extractor.elevation_encoder != "auto":
        return cfg
    strips = False
    if env_cfg is not None:
        actions, sensor = env_cfg["action_space"], env_cfg["sensor"]
        strips = actions.shape == "discrete" and actions.frame == "rover" and sensor.encoding == "elevation_map"
    if strips and cfg.normalize and "goal" in cfg.norm_obs_keys:
        raise ConfigError(
            "algo.normalize: algo.extractor.elevation_encoder=auto picks the strips encoder here, which turns the raw "
            "goal vector's bearing onto every heading; set algo.normalize=false, drop 'goal' from "
            "algo.norm_obs_keys, or choose algo.extractor.elevation_encoder=cnn"
        )
    extractor = dataclasses.replace(cfg.extractor, elevation_encoder="strips" if strips else "cnn")
    return dataclasses.replace(cfg, extractor=extractor)


def strips_kwargs(cfg: AlgoConfig, env_cfg: dict[str, Any] | None) -> dict[str, Any]:
    """:class:`~diana_lab.agents.strips.CandidateStrips` arguments: ``algo.extractor.strips`` and the geometry of
    the env's map and candidates (``env_cfg``: the env's typed groups)."""
    actions = env_cfg["action_space"] if env_cfg else None
    sensor = env_cfg["sensor"] if env_cfg else None
    if actions is None or actions.shape != "discrete" or actions.frame != "rover":
        raise ConfigError(
            "algo.extractor.elevation_encoder=strips scores a discrete action space's candidates in the rover's "
            "frame: use action_space=discrete with action_space.frame=rover"
        )
    if sensor is None or sensor.encoding != "elevation_map":
        raise ConfigError("algo.extractor.elevation_encoder=strips reads sensor.encoding=elevation_map")
    m, s = sensor.elevation_map, cfg.extractor.strips
    return {
        "cell_size": float(m.cell_size),
        "extent_forward": float(m.extent_forward),
        "extent_side": float(m.extent_side),
        "headings": int(actions.headings),
        "distances": [float(d) for d in actions.distances],
        "lateral": [float(v) for v in s.lateral],
        "step": float(s.step),
        "reach": float(s.reach),
        "hidden": int(s.hidden),
        "context": int(s.context),
    }


def _action_noise(cfg: AlgoConfig, n_actions: int) -> NormalActionNoise | None:
    std = float(getattr(cfg, "action_noise_std", 0.0))
    if std <= 0:
        return None
    return NormalActionNoise(mean=np.zeros(n_actions), sigma=std * np.ones(n_actions))


def algo_class(cfg: AlgoConfig, overlap: bool = False) -> type[BaseAlgorithm]:
    """``cfg``'s class; with ``overlap``, its :func:`~diana_lab.agents.overlap.overlapped` form (``train.overlap``)."""
    cls = get_class(cfg._target_)
    return overlapped(cls) if overlap else cls


def build_model(
    cfg: AlgoConfig, env: VecEnv, seed: int, device: str = "cpu", verbose: int = 0, overlap: bool = False
) -> BaseAlgorithm:
    """A fresh model of ``cfg``'s class on ``env`` (each non-runner key of ``cfg`` is a constructor kwarg);
    ``overlap``: one that collects its next rollout during each update (:mod:`diana_lab.agents.overlap`).

    A ``Discrete`` env (``action_space=discrete``) with an algorithm that needs a ``Box`` raises
    :class:`~diana_lab.config.ConfigError` naming both, before SB3's constructor asserts on it.
    """
    if isinstance(env.action_space, spaces.Discrete):
        check_action_space(cfg, "discrete")
    env_cfg = env_groups_of(env)
    cfg = resolve_encoder(cfg, env_cfg)
    node = {k: v for k, v in dataclasses.asdict(cfg).items() if k not in NON_SB3_KEYS}
    node.update({"_target_": cfg._target_, "_partial_": True, "_convert_": "all"})
    made = instantiate(node)
    make = functools.partial(algo_class(cfg, overlap), *made.args, **made.keywords)
    extra: dict[str, Any] = {}
    if cfg.learning_rate_end is not None:
        extra["learning_rate"] = LinearSchedule(cfg.learning_rate, cfg.learning_rate_end, end_fraction=1.0)
    noise = _action_noise(cfg, int(np.prod(env.action_space.shape)))
    if noise is not None:
        extra["action_noise"] = noise
    kwargs = policy_kwargs(cfg, env_cfg)
    model = make(env=env, policy_kwargs=kwargs, seed=seed, device=device, verbose=verbose, **extra)
    if cfg.extractor.elevation_encoder == "strips":
        extractor = model.policy.features_extractor
        init_logit_head(model.policy.action_net, extractor.offset("elevation_map"), int(env.action_space.n))
    return model


def load_model(
    cfg: AlgoConfig, path: Path, env: VecEnv | None, device: str = "cpu", overlap: bool = False
) -> BaseAlgorithm:
    """Load a saved model of ``cfg``'s class (its saved hyperparameters win; the env is re-attached)."""
    return algo_class(cfg, overlap).load(str(path), env=env, device=device)
