"""Evaluate the policy being trained every ``eval.every`` steps on the fixed suite; keep the best by SPL.

One plain (non-vectorised) env with the training config -- and the evaluation's dynamics, through
:func:`diana_lab.evaluation.core.eval_env` -- runs the same :func:`~diana_lab.evaluation.make_suite` episodes
each time, so the ``eval_*`` curves compare like with like. The policy sees observations normalised with the
training VecNormalize's current statistics (``normalize_obs`` reads them without updating them).
Metrics go to MLflow as ``eval_<key>`` at step = timesteps (the names of :mod:`diana_lab.tracking.names`,
shared with the final and the CLI's evaluations); the console table shows the main ones under ``eval/``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
from stable_baselines3.common.callbacks import BaseCallback

from diana_lab.config.evaluation import EvalConfig
from diana_lab.evaluation import eval_env, make_suite, run_suite, summarize
from diana_lab.evaluation.policies import sb3_policy
from diana_lab.tracking.mlflow_run import Tracker
from diana_lab.tracking.names import eval_metrics
from diana_lab.training.context import EvalHook

__all__ = ["PeriodicEvaluation", "save_model"]

CONSOLE_KEYS = ("success_rate", "spl", "collision_rate")


def save_model(model: Any, directory: Path) -> list[Path]:
    """``model.zip`` (+ ``vecnormalize.pkl`` when the run normalises) in ``directory``; the files written."""
    directory.mkdir(parents=True, exist_ok=True)
    model.save(str(directory / "model.zip"))
    files = [directory / "model.zip"]
    vecnorm = model.get_vec_normalize_env()
    if vecnorm is not None:
        vecnorm.save(str(directory / "vecnormalize.pkl"))
        files.append(directory / "vecnormalize.pkl")
    return files


class PeriodicEvaluation(BaseCallback):
    """Args:
    make_env: builds the evaluation env on first use (so a run without evaluations never builds it).
    eval_cfg: episodes, seed, distance range and dynamics of the suite; ``eval_cfg.every`` the period.
    tracker: where ``eval_*`` metrics and the ``best/`` model go.
    best_dir: local folder of the best model so far.
    on_eval: called with ``(timesteps, summary)`` after each evaluation is recorded; may raise to stop.
    final_follows: a final evaluation runs on the same suite when training ends, so an evaluation due in the
        last rollout (at the budget, one update before the final model) is skipped: it would cost a suite's
        time, and hand a pruner a value the final evaluation replaces moments later.
    """

    def __init__(
        self,
        make_env: Callable[[], gym.Env],
        eval_cfg: EvalConfig,
        tracker: Tracker,
        best_dir: Path,
        on_eval: EvalHook | None = None,
        final_follows: bool = False,
    ) -> None:
        super().__init__()
        self.make_env, self.cfg, self.tracker, self.best_dir = make_env, eval_cfg, tracker, best_dir
        self.on_eval, self.final_follows = on_eval, final_follows
        self.end_step: int | None = None  # where this learn() call stops (SB3's total, a resumed run's included)
        self.every = eval_cfg.every
        self.best_spl = -math.inf
        self.last_step: int | None = None
        self.last_summary: dict[str, Any] | None = None
        self._env: gym.Env | None = None
        self._run_env: gym.Env | None = None
        self._suite: list | None = None

    def _on_training_start(self) -> None:
        if self.last_step is None:
            self.last_step = self.model.num_timesteps  # a resumed run counts from where it stopped
        total = self.locals.get("total_timesteps")
        self.end_step = int(total) if isinstance(total, int) else None

    def _on_step(self) -> bool:
        if self.every > 0 and self.num_timesteps - (self.last_step or 0) >= self.every and not self._final_next():
            self.evaluate()
        return True

    def _final_next(self) -> bool:
        """The budget is reached in this rollout and the final evaluation follows it."""
        return self.final_follows and self.end_step is not None and self.num_timesteps >= self.end_step

    def env(self) -> gym.Env:

        if self._run_env is None:
            self._env = self.make_env()
            self._run_env = eval_env(self._env, self.cfg)
            c = self.cfg
            self._suite = make_suite(self._run_env, c.episodes, c.seed, c.min_distance, c.max_distance)
        return self._run_env

    def evaluate(self) -> dict[str, Any]:

        env = self.env()
        policy = sb3_policy(self.model, self.model.get_vec_normalize_env(), self.cfg)
        summary = summarize(run_suite(policy, env, self._suite), self.cfg.min_goal_speed)
        step = self.model.num_timesteps
        self.last_step, self.last_summary = step, summary
        self.tracker.log_metrics(eval_metrics(summary), step)
        for key in CONSOLE_KEYS:
            value = summary.get(key)
            if isinstance(value, int | float):
                self.logger.record(f"eval/{key}", float(value), exclude="mlflow")
        spl = float(summary.get("spl", 0.0))
        if math.isfinite(spl) and spl > self.best_spl:
            self.best_spl = spl
            for path in save_model(self.model, self.best_dir):
                self.tracker.log_artifact(path, "best")
            self.tracker.set_tags({"best_spl": f"{spl:.4f}", "best_step": step})
        if self.on_eval is not None:
            self.on_eval(step, summary)
        return summary

    def close(self) -> None:
        for env in {id(e): e for e in (self._run_env, self._env) if e is not None}.values():
            env.close()
        self._env = self._run_env = None
