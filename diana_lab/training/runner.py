"""Train one agent from a composed config: envs, model, callbacks, MLflow run, final evaluation, summary.

:func:`train` is the whole of ``python -m diana_lab``. Its order matters for users:

1. every group is validated, and one env is built and reset (:func:`check_env`), before anything starts, so a
   bad value or file fails in seconds with no MLflow run;
2. the MLflow run is opened (or reopened, for ``train.resume``) and always ended -- FINISHED, FAILED on an
   exception, KILLED on Ctrl-C or SIGTERM -- never left RUNNING;
3. an interrupt saves a checkpoint first, so ``train.resume`` can continue with the same step counter.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import math
import sys
import time
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.logger import HumanOutputFormat, Logger
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from diana_lab import config as C
from diana_lab.agents.factory import build_model, load_model
from diana_lab.config.algo import AlgoConfig
from diana_lab.config.evaluation import EvalConfig
from diana_lab.config.run import TrackingConfig, TrainConfig
from diana_lab.core.validation import check_seed
from diana_lab.errors import UserError
from diana_lab.evaluation import evaluate
from diana_lab.evaluation.core import sweep_sensor_noise
from diana_lab.evaluation.policies import sb3_policy
from diana_lab.experts.perceived import check_perceivable
from diana_lab.tracking import MLflowOutputFormat, MlflowTracker, Tracker, resolve_uri
from diana_lab.tracking.atomic import uninterrupted
from diana_lab.tracking.git import git_commit, git_dirty
from diana_lab.tracking.host import HOST_TAG, cpu_model
from diana_lab.tracking.names import eval_metrics
from diana_lab.tracking.params import flatten, truncate
from diana_lab.training.checkpoints import TrackedCheckpoints
from diana_lab.training.context import TAG_GROUPS, RunContext, StopRun
from diana_lab.training.envs import (
    check_env,
    env_config,
    make_env,
    make_training_env,
    training_worlds,
    wrap_normalize,
)
from diana_lab.training.episode_stats import EpisodeStats
from diana_lab.training.imitation import ImitationResult, imitate
from diana_lab.training.periodic_eval import PeriodicEvaluation, save_model
from diana_lab.training.progress import ProgressWithStats
from diana_lab.training.resume import (
    ResumePoint,
    check_resumable,
    find_resume_point,
    newest_checkpoint_steps,
    write_run_info,
)
from diana_lab.training.signals import InterruptCheck, interrupts_as_exceptions, unwrapped_interrupts
from diana_lab.training.summary import TrainResult
from diana_lab.training.threads import check_overlap, phase_threads

__all__ = ["RUN_GROUPS", "train"]

RUN_GROUPS = (*C.GROUPS, "algo", "train", "eval", "tracking")


def _checked_resume(
    resume: ResumePoint, cfg: DictConfig, observation_space: Any, action_space: Any, overrides: Sequence[str] = ()
) -> ResumePoint:
    """``resume`` with the env settings that differ from its training's, printed: continuing on a new world or
    reward is allowed (fine-tuning), but said; another observation or action space is an error (naming the
    training's overrides that ``overrides``, the command line's, lacks)."""
    changes = check_resumable(resume, cfg, observation_space, action_space, overrides)
    if changes:
        listed = "\n  ".join(changes)
        print(f"train.resume: {resume.source} continues with other settings than it was trained with:\n  {listed}")
    return dataclasses.replace(resume, changes=tuple(changes))


def _saved_timesteps(model_zip: Path) -> int:
    """``num_timesteps`` stored in an SB3 archive (to seed the envs of a resumed run before loading it)."""
    try:
        with zipfile.ZipFile(model_zip) as zf:
            return int(json.loads(zf.read("data")).get("num_timesteps", 0))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
        raise UserError(f"train.resume: '{model_zip}' is not a Stable-Baselines3 model archive ({exc})") from exc


def _resumed_steps(resume: ResumePoint) -> int:
    """The steps the resumed model has trained (its checkpoint's name, else the archive's counter)."""
    ckpt = resume.checkpoint
    return ckpt.steps if ckpt.steps >= 0 else _saved_timesteps(ckpt.model)


def _branch_if_stale(resume: ResumePoint, uri: str | None) -> ResumePoint:
    """A checkpoint older than its MLflow run's newest continues in a new run (tagged ``branched_from``): in the
    same run it would log its steps again over the history the run went on to (see diana_lab.training.resume)."""
    if resume.run_id is None or uri is None:
        return resume
    newest, done = newest_checkpoint_steps(resume.run_id, uri), _resumed_steps(resume)
    if newest is None or newest <= done:
        return resume
    print(
        f"train.resume: {resume.source} is at {done} steps, but its MLflow run {resume.run_id} went on to "
        f"{newest}; continuing in a new MLflow run (tag branched_from) to keep that run's history as it is. "
        f"To continue from its newest checkpoint: train.resume={resume.run_id}"
    )
    return dataclasses.replace(resume, run_id=None, branched_from=resume.run_id)


def _check_budget_left(resume: ResumePoint, total_timesteps: int) -> None:
    """Refuse a budget the resumed model has already spent, before its MLflow run is reopened (a finished run
    would otherwise end FAILED, its ``run_dir`` tag pointing at the new, empty folder)."""
    done = _resumed_steps(resume)
    if total_timesteps <= done:
        raise UserError(
            f"train.total_timesteps={total_timesteps}: the resumed model has already trained {done} steps; "
            "set a larger total to continue"
        )


def _run_name(cfg: DictConfig, ctx: RunContext, tracking: TrackingConfig) -> str:
    if tracking.run_name:
        return tracking.run_name
    pick = {g: ctx.choices.get(g) or OmegaConf.select(cfg, f"{g}.name", default=g) for g in ("algo", "world", "sensor")}
    return f"{pick['algo']}-{pick['world']}-{pick['sensor']}-s{cfg.seed}"


class TrainingRun:
    """The state of one run between setup and teardown (kept so an interrupt can checkpoint it)."""

    def __init__(
        self,
        cfg: DictConfig,
        ctx: RunContext,
        typed: dict[str, Any],
        tracker: Tracker,
        resume: ResumePoint | None,
    ) -> None:
        self.cfg, self.ctx, self.tracker, self.resume = cfg, ctx, tracker, resume
        self.algo: AlgoConfig = typed["algo"]
        self.train_cfg: TrainConfig = typed["train"]
        self.eval_cfg: EvalConfig = typed["eval"]
        self.tracking_cfg: TrackingConfig = typed["tracking"]
        self.seed = int(cfg.seed)
        self.run_dir = ctx.run_dir
        self.venv: VecEnv | None = None
        self.model: BaseAlgorithm | None = None
        self.checkpoints: TrackedCheckpoints | None = None
        self.evaluator: PeriodicEvaluation | None = None
        self.progress: ProgressWithStats | None = None
        self.start_steps = 0
        self.learn_time = 0.0
        self.imitation: ImitationResult | None = None

    # ------------------------------------------------------------------ setup
    def log_run_metadata(self) -> None:
        t, commit = self.tracker, git_commit()
        # the option chosen per group; runs started without Hydra (notebooks, sweeps) fall back to its name
        named = {g: OmegaConf.select(self.cfg, f"{g}.name") for g in TAG_GROUPS if g != "experiment"}
        tags: dict[str, Any] = {
            **{g: v for g, v in named.items() if v is not None},
            **self.ctx.choices,
            "algo": self.algo.name,
            "seed": self.seed,
            "run_dir": str(self.run_dir.resolve()),
            "git_commit": commit,
            "mlflow.source.git.commit": commit,
            "git_dirty": git_dirty(),
            "overrides": self.ctx.override_string,
            HOST_TAG: cpu_model(),
            **self.ctx.tags,
        }
        if self.ctx.job_num is not None:
            tags["hydra_job"] = self.ctx.job_num
        if self.resume is not None:
            tags["resumed_from"] = self.resume.source
            if self.resume.branched_from:
                tags["branched_from"] = self.resume.branched_from
            if self.resume.changes:
                tags["resume_config_changes"] = truncate("; ".join(self.resume.changes))
        t.set_tags(tags)
        resolved = OmegaConf.to_container(self.cfg, resolve=True)
        t.log_params(_flat_missing(resolved, t.existing_params()))
        t.log_text(OmegaConf.to_yaml(self.cfg, resolve=True), "config_resolved.yaml")
        hydra_dir = self.run_dir / ".hydra"
        if hydra_dir.is_dir():
            t.log_artifacts(hydra_dir, ".hydra")
        write_run_info(self.run_dir, {"mlflow_run_id": t.run_id, "tracking_uri": t.uri, "algo": self.algo.name})

    def build(self) -> None:
        device = self.train_cfg.device
        imitation = self.train_cfg.imitation
        if self.resume is None:
            expert = imitation if imitation.enabled else None
            self.venv = make_training_env(self.cfg, self.train_cfg, self.seed, expert=expert)
            if self.algo.normalize:
                self.venv = wrap_normalize(self.venv, self.algo, self.algo.gamma)
            self.model = build_model(self.algo, self.venv, self.seed, device, overlap=self.train_cfg.overlap)
        else:
            ckpt = self.resume.checkpoint
            done = _resumed_steps(self.resume)
            # new episodes, not a replay of the first ones: the env seeds move on with the step count
            self.venv = make_training_env(self.cfg, self.train_cfg, self.seed + done)
            if self.algo.normalize:
                if ckpt.vecnormalize is not None:
                    self.venv = VecNormalize.load(str(ckpt.vecnormalize), self.venv)
                    self.venv.training, self.venv.norm_reward = True, self.algo.norm_reward
                else:
                    print(
                        f"warning: no VecNormalize statistics beside {ckpt.model}; starting them afresh",
                        file=sys.stderr,
                    )
                    self.venv = wrap_normalize(self.venv, self.algo, self.algo.gamma)
            self.model = load_model(self.algo, ckpt.model, self.venv, device, overlap=self.train_cfg.overlap)
            if ckpt.replay_buffer is not None and hasattr(self.model, "replay_buffer"):
                self.model.load_replay_buffer(str(ckpt.replay_buffer))
        formats: list[Any] = [MLflowOutputFormat(self.tracker)]
        if not self.train_cfg.progress_bar:
            formats.insert(0, HumanOutputFormat(sys.stdout))
        self.model.set_logger(Logger(folder=None, output_formats=formats))
        self.start_steps = self.model.num_timesteps

    def callbacks(self) -> list[BaseCallback]:
        tc = self.tracking_cfg
        self.checkpoints = TrackedCheckpoints(
            self.run_dir / "checkpoints",
            self.train_cfg.checkpoint_every,
            self.train_cfg.n_envs,
            self.tracker,
            upload=tc.log_checkpoints,
            upload_replay_buffer=tc.log_replay_buffer,
            off_policy=self.algo.off_policy,
        )
        self.evaluator = PeriodicEvaluation(
            functools.partial(make_env, env_config(self.cfg)),
            self.eval_cfg,
            self.tracker,
            self.run_dir / "best",
            on_eval=self.ctx.on_eval,
            final_follows=self.train_cfg.final_eval,
        )
        threads = phase_threads(self.train_cfg.torch_threads, self.train_cfg.update_threads, self.train_cfg.overlap)
        cbs: list[BaseCallback] = [InterruptCheck(), threads, EpisodeStats(), self.checkpoints, self.evaluator]
        if self.train_cfg.progress_bar:
            self.progress = ProgressWithStats()
            cbs.append(self.progress)
        return cbs

    # ------------------------------------------------------------------ phases
    def learn(self) -> None:
        assert self.model is not None
        # > 0: a resumed model's spent budget was refused before its run reopened (_check_budget_left)
        remaining = self.train_cfg.total_timesteps - self.model.num_timesteps
        callbacks = self.callbacks()
        if self.resume is None and self.train_cfg.imitation.enabled:
            self.imitation = imitate(self.model, self.venv, self.train_cfg.imitation, self.seed, self.tracker)
            self.tracker.set_tags({"imitation_steps": self.imitation.steps})
            assert self.evaluator is not None
            if self.eval_cfg.every > 0:  # where RL starts from, on the same suite as every later evaluation
                self.evaluator.init_callback(self.model)
                self.evaluator.evaluate()
        t0 = time.perf_counter()
        try:
            self.model.learn(
                remaining,
                callback=CallbackList(callbacks),
                log_interval=self.train_cfg.log_interval,
                reset_num_timesteps=self.resume is None,
                progress_bar=False,
            )
        finally:
            self.learn_time = time.perf_counter() - t0
            if self.progress is not None:
                self.progress.close()

    def interrupted(self) -> None:
        """Ctrl-C / SIGTERM: save a checkpoint of whatever has been trained so far."""
        if self.checkpoints is not None and getattr(self.checkpoints, "model", None) is not None:
            ckpt = self.checkpoints.save()
            print(f"\ninterrupted at {ckpt.steps} steps: checkpoint {ckpt.model}", file=sys.stderr)

    def finish(self) -> dict[str, Any]:
        """Final checkpoint and model, the final evaluation (files + ``eval_*``; with ``eval.sensor_noise``, once
        more per level in ``eval/sensor_noise/`` + ``eval_noise_<level>_*``), the best model if needed, and the
        final and best policies as MLflow models (:meth:`log_policy_models`)."""
        assert self.model is not None and self.checkpoints is not None and self.evaluator is not None
        self.checkpoints.save()
        for path in save_model(self.model, self.run_dir / "model"):
            self.tracker.log_artifact(path, "model")
        summary = self.final_evaluation() if self.train_cfg.final_eval else self.evaluator.last_summary or {}
        self.log_policy_models()
        return summary

    def final_evaluation(self) -> dict[str, Any]:
        """The final evaluation's files and ``eval_*`` metrics (see :meth:`finish`); the best model if needed."""
        assert self.model is not None and self.evaluator is not None
        out = self.run_dir / "eval"
        env = self.evaluator.env()  # the evaluation env (its dynamics already applied)
        policy = sb3_policy(self.model, self.model.get_vec_normalize_env(), self.eval_cfg)
        summary = evaluate(policy, env, self.eval_cfg, out)
        self.tracker.log_metrics(eval_metrics(summary), self.model.num_timesteps)
        if self.eval_cfg.sensor_noise:  # as python -m diana_lab.evaluate does: once per level, the same metric names
            levels = sweep_sensor_noise(policy, env, self.eval_cfg, out / "sensor_noise")
            for level, level_summary in levels.items():
                self.tracker.log_metrics(
                    eval_metrics(level_summary, f"eval_noise_{level:g}_"), self.model.num_timesteps
                )
        self.tracker.log_artifacts(out, "eval")
        spl = float(summary.get("spl", math.nan))
        if math.isfinite(spl) and spl > self.evaluator.best_spl:  # e.g. no periodic evaluation ran
            self.evaluator.best_spl = spl
            for path in save_model(self.model, self.run_dir / "best"):
                self.tracker.log_artifact(path, "best")
        return summary

    def log_policy_models(self) -> None:
        """The final policy as the MLflow model ``policy_model`` (registered as a new version of
        ``tracking.register_model`` when set) and the best one kept, if any, as ``best_policy_model``
        (:mod:`diana_lab.tracking.pyfunc_model`)."""
        if self.tracker.run_id is None:
            return
        from diana_lab.tracking.pyfunc_model import BEST_MODEL, FINAL_MODEL, log_policy_model

        assert self.model is not None
        overrides = self.run_dir / ".hydra" / "overrides.yaml"
        register = self.tracking_cfg.register_model
        steps = self.model.num_timesteps  # the final evaluation's step: its metrics are the model's
        info = log_policy_model(
            self.tracker, self.run_dir / "model", self.cfg, FINAL_MODEL, self.model, overrides, register, steps
        )
        if register is not None and info is not None:
            version = info.registered_model_version
            self.tracker.set_tags({"registered_model": f"{register}/{version}"})
            print(f"registered the final policy as models:/{register}/{version}")
        best = self.run_dir / "best"
        if (best / "model.zip").is_file():
            log_policy_model(self.tracker, best, self.cfg, BEST_MODEL, self.model, overrides)

    def result(self, status: str, summary: dict[str, Any]) -> TrainResult:
        steps = self.model.num_timesteps if self.model is not None else 0
        fps = (steps - self.start_steps) / self.learn_time if self.learn_time > 0 else math.nan
        best = self.evaluator.best_spl if self.evaluator is not None else -math.inf
        return TrainResult(
            status=status,
            run_dir=self.run_dir,
            algo=self.algo.name,
            num_timesteps=steps,
            wall_time_s=self.learn_time,
            fps=fps,
            run_id=self.tracker.run_id,
            tracking_uri=self.tracker.uri,
            eval_summary=summary,
            best_spl=best if math.isfinite(best) else math.nan,
            checkpoint=self.checkpoints.last.model if self.checkpoints and self.checkpoints.last else None,
            imitation_steps=self.imitation.steps if self.imitation else 0,
            imitation_time_s=self.imitation.wall_time_s if self.imitation else 0.0,
        )

    def close(self) -> None:
        if self.evaluator is not None:
            self.evaluator.close()
        if self.venv is not None:
            with contextlib.suppress(EOFError, BrokenPipeError, OSError):  # workers already gone after Ctrl-C
                self.venv.close()


def _flat_missing(resolved: Any, existing: dict[str, str]) -> dict[str, Any]:
    """The config's params that the run does not have yet (a resumed run keeps its original values)."""
    return {k: v for k, v in flatten(resolved).items() if k not in existing}


def train(cfg: DictConfig, ctx: RunContext) -> TrainResult:
    """Train, evaluate and track one run (see the module docstring). Interrupts propagate after cleanup,
    with the result attached as ``exc.result``."""
    typed = C.validate(cfg, [g for g in RUN_GROUPS if g in cfg])
    missing = [g for g in ("algo", "train", "eval", "tracking") if g not in typed]
    if missing:
        raise C.ConfigError(f"{', '.join(missing)}: missing from the config (add them to conf/config.yaml defaults)")
    train_cfg: TrainConfig = typed["train"]
    tracking: TrackingConfig = typed["tracking"]
    if train_cfg.torch_threads:
        import torch

        torch.set_num_threads(train_cfg.torch_threads)
    seed = cfg.get("seed")
    check_seed("seed", seed)  # the root key has no schema to check it
    set_random_seed(seed)
    uri = resolve_uri(tracking.uri) if tracking.enabled else None
    resume = find_resume_point(str(train_cfg.resume), uri, ctx.run_dir / "resume") if train_cfg.resume else None
    if resume is not None and resume.algo and resume.algo != typed["algo"].name:
        raise UserError(
            f"train.resume: {resume.source} was trained with algo={resume.algo}; pass algo={resume.algo} to continue it"
        )
    if typed["eval"].sensor_noise and not train_cfg.final_eval:
        raise C.ConfigError(
            f"eval.sensor_noise={list(typed['eval'].sensor_noise)}: sweeps the final evaluation, which "
            "train.final_eval=false turns off; drop one of them"
        )
    check_overlap(train_cfg.overlap, typed["algo"].off_policy, typed["algo"].name)
    imitation = train_cfg.imitation
    if imitation.enabled and imitation.expert == "astar_seen":  # the expert reads the policy's own sensor map
        check_perceivable(cfg, "train.imitation.expert=astar_seen")
    spaces = check_env(env_config(cfg), seed)  # a bad world, reward term, URDF... fails here, before any MLflow run
    if resume is not None:
        resume = _checked_resume(resume, cfg, *spaces, ctx.overrides)
        _check_budget_left(resume, train_cfg.total_timesteps)
        resume = _branch_if_stale(resume, uri)
    for world in training_worlds(cfg, train_cfg)[1:]:  # and so does a bad train.worlds entry
        check_env({**env_config(cfg), "world": world}, seed)
    tracker, run, status, summary = Tracker(), None, "FAILED", {}
    with interrupts_as_exceptions():
        try:
            try:
                with unwrapped_interrupts():  # an interrupt that native code wrapped is raised as itself
                    with uninterrupted():  # an interrupt while opening the run is raised once ``tracker`` holds it
                        if uri is not None:
                            run_name = _run_name(cfg, ctx, tracking)
                            tracker = MlflowTracker(
                                uri,
                                tracking.experiment,
                                run_name,
                                resume.run_id if resume else None,
                                parent_run_id=ctx.parent_run_id,
                            )
                    run = TrainingRun(cfg, ctx, typed, tracker, resume)
                    run.log_run_metadata()
                    run.build()
                    run.learn()
                    summary = run.finish()
                    status = "FINISHED"
            except KeyboardInterrupt as exc:
                status = "KILLED"
                if run is not None:
                    run.interrupted()
                    exc.result = run.result(status, summary)  # type: ignore[attr-defined]
                raise
            except StopRun as exc:  # a hook ended training on purpose (a pruned sweep trial)
                status = exc.status
                if run is not None:
                    exc.result = run.result(status, summary)  # type: ignore[attr-defined]
                raise
        finally:
            if run is not None:
                run.close()
            tracker.end(status)
    return run.result(status, summary)
