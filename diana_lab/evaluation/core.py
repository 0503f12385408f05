"""``evaluate``: one policy on the fixed suite -> ``episodes.csv``, ``summary.json``, plots and a GIF.

The training runner calls :func:`evaluate` for its periodic and final evaluations and
``python -m diana_lab.evaluate`` calls it for any policy. Conditions that differ from the env given --
``eval.dynamics`` (e.g. a kinematic-trained policy in physics) and, through :func:`sweep_sensor_noise`,
``eval.sensor_noise`` -- get a new env that shares the world (and so the terrain and obstacles) with it.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import gymnasium as gym
import pandas as pd

from diana_lab.config import to_object
from diana_lab.config.evaluation import EvalConfig
from diana_lab.evaluation.metrics import summarize, to_json
from diana_lab.evaluation.policies import Policy
from diana_lab.evaluation.runner import run_episodes
from diana_lab.evaluation.suite import make_suite

__all__ = ["TABLE_KEYS", "eval_env", "evaluate", "noise_sensor", "summary_table", "sweep_sensor_noise"]

TABLE_KEYS = (
    "episodes",
    "success_rate",
    "spl",
    "collision_rate",
    "tipover_rate",
    "stuck_rate",
    "timeout_rate",
    "mean_path_length_m",
    "mean_speed_mps",
    "slow_successes",
    "mean_max_tilt_deg",
    "time_over_15deg_frac",
)
NOISY_PRESET = "realistic"  # the preset a sweep uses when the configured sensor is noiseless


def _eval_config(cfg: Any) -> EvalConfig:
    return cfg if isinstance(cfg, EvalConfig) else to_object("eval", cfg)


def noise_sensor(sensor: Any, level: float) -> Any:
    """The sensor config at noise ``level``: the configured preset scaled by ``level``; a noiseless sensor
    (preset ``none``) takes the ``realistic`` preset, since scaling nothing would sweep nothing."""
    preset = NOISY_PRESET if sensor.noise == "none" else sensor.noise
    return dataclasses.replace(sensor, noise=preset, noise_level=float(level))


def eval_env(env: gym.Env, cfg: EvalConfig, noise_level: float | None = None) -> gym.Env:
    """``env`` itself when it already matches ``cfg``, else a new env on the same world with the evaluation's
    dynamics (the option's own config, ``conf/dynamics/<name>.yaml``, as the training runner's evaluation
    env uses) and/or the sensor at ``noise_level``."""
    from diana_lab.envs.rover_nav import RoverNavEnv

    base = env.unwrapped
    groups = dict(base.cfg)
    changed = False
    if cfg.dynamics is not None and groups["dynamics"].name != cfg.dynamics:
        groups["dynamics"], changed = to_object("dynamics", cfg.dynamics), True
    if noise_level is not None:
        sensor = noise_sensor(groups["sensor"], noise_level)
        if sensor != groups["sensor"]:
            groups["sensor"], changed = sensor, True
    if not changed:
        return env
    return RoverNavEnv(**groups, world_instance=base.world)


def evaluate(policy: Policy, env: gym.Env, cfg: EvalConfig | Any, out_dir: Path | str) -> dict[str, Any]:
    """Run ``policy`` on the suite of ``cfg`` and write the results into ``out_dir``; returns the summary.

    Writes ``episodes.csv`` (one row per episode), ``summary.json`` (see
    :func:`~diana_lab.evaluation.metrics.summarize`), ``trajectories.png`` and ``tilt.png`` (``cfg.plots``)
    and ``episode_0.gif`` (``cfg.video``). ``env`` is the unwrapped ``RoverNavEnv`` (or a wrapper of it that
    leaves observations alone); ``cfg.dynamics`` is applied here, ``cfg.sensor_noise`` is not (see
    :func:`sweep_sensor_noise`). The same ``cfg.seed`` gives a byte-identical ``summary.json``.
    """
    cfg = _eval_config(cfg)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    run_env = eval_env(env, cfg)
    try:
        suite = make_suite(run_env, cfg.episodes, cfg.seed, cfg.min_distance, cfg.max_distance)
        df, traces = run_episodes(policy, run_env, suite, out / "episode_0.gif" if cfg.video else None)
        summary = summarize(df, cfg.min_goal_speed)
        df.to_csv(out / "episodes.csv", index=False)
        (out / "summary.json").write_text(to_json(summary))
        if cfg.plots:
            from diana_lab.evaluation.plots import plot_tilt, plot_trajectories

            base = run_env.unwrapped
            name = getattr(policy, "name", type(policy).__name__)
            title = (
                f"{name} on {base.world.name} ({base.cfg['dynamics'].name}): "
                f"{summary['success_rate']:.0%} success, SPL {summary['spl']:.2f}"
            )
            plot_trajectories(base.world, df, traces, out / "trajectories.png", title)
            plot_tilt(df, traces, out / "tilt.png", base.robot.tipover_deg, f"tilt along the path: {name}")
    finally:
        if run_env is not env:
            run_env.close()
    return summary


def sweep_sensor_noise(
    policy: Policy, env: gym.Env, cfg: EvalConfig | Any, out_dir: Path | str
) -> dict[float, dict[str, Any]]:
    """:func:`evaluate` at every level of ``cfg.sensor_noise`` (in ``out_dir/noise_<level>/``); also writes
    ``sensor_noise.csv`` (one row per level). Returns ``{level: summary}``."""
    cfg = _eval_config(cfg)
    out = Path(out_dir)
    results: dict[float, dict[str, Any]] = {}
    for level in cfg.sensor_noise:
        level_env = eval_env(env, cfg, noise_level=level)
        try:
            results[float(level)] = evaluate(policy, level_env, cfg, out / f"noise_{level:g}")
        finally:
            if level_env is not env:
                level_env.close()
    out.mkdir(parents=True, exist_ok=True)
    summary_table(results, "noise_level").to_csv(out / "sensor_noise.csv")
    return results


def summary_table(summaries: dict[Any, dict[str, Any]], index_name: str = "policy") -> pd.DataFrame:
    """The main figures of several summaries side by side (what the CLI prints)."""
    table = pd.DataFrame({k: {m: s.get(m) for m in TABLE_KEYS} for k, s in summaries.items()}).T.astype(float)
    table.index.name = index_name
    return table
