"""``python -m diana_lab.evaluate policy=<...> [world=... robot=... eval.*=...] [output=summary.json]``

Evaluates one policy on the fixed suite (``eval.episodes`` episodes from ``eval.seed``) and writes
``episodes.csv``, ``summary.json``, ``trajectories.png``, ``tilt.png`` and ``episode_0.gif`` into the Hydra
run directory; ``output=`` also writes the summary JSON there. ``policy=`` is an option of ``conf/policy/``
(``straight``, ``astar``, ``pretrained``, ...), a Stable-Baselines3 ``.zip`` (``vecnormalize.pkl`` beside it is
applied, a checkpoint's own ``rl_model_vecnormalize_<n>_steps.pkl`` for ``rl_model_<n>_steps.zip``; a run trained
with ``algo.normalize`` without them is refused), the MLflow run id of a training run or a registered model
version (``models:/<name>/<version>``, ``models:/<name>@<alias>``; see :mod:`diana_lab.evaluation.loading`)::

    python -m diana_lab.evaluate policy=astar world=mars_yard eval.episodes=100 output=astar.json
    python -m diana_lab.evaluate policy=<run id> +experiment=quick eval.dynamics=physics   # kinematic-trained
    python -m diana_lab.evaluate policy=model.zip +experiment=quick eval.sensor_noise=[0,0.5,1,2]

The env is the command line's: repeat the overrides the policy was trained with (``+experiment=quick`` above);
a refusal names those of the training's overrides the command line lacks, when the run recorded them.

* ``eval.dynamics`` null means the training's dynamics: the run's own when the policy comes with its
  training config (a run id, ``pretrained``, or a model with ``.hydra/config.yaml`` beside it), else the
  ``dynamics`` group. A ``dynamics=`` group chosen on the command line counts as ``eval.dynamics`` (it
  would otherwise be replaced by the training's without a word): ``policy=pretrained dynamics=physics``
  evaluates in physics, with any ``dynamics.<key>=`` settings; ``eval.dynamics`` naming another one is an error.
  ``dynamics.<key>=`` settings without a group change the training's dynamics (a key it lacks is an error).
* ``eval.sensor_noise=[...]`` evaluates once per level in ``noise_<level>/`` with ``sensor.noise_level`` set
  to it; a sensor configured without noise (``sensor.noise=none``) takes the ``realistic`` preset for the
  sweep. ``output`` then holds ``{"sensor_noise": {"<level>": summary, ...}}``.
* With ``tracking.enabled`` the evaluation is an MLflow run (``eval_<key>`` metrics, the files as artefacts),
  a child of the training run when the policy is a run id.

User mistakes (a missing model file, a policy trained on other observations) print one paragraph and exit
with status 2.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf, open_dict

from diana_lab.cli import UserError, hydra_app, output_file, task_overrides

__all__ = ["chosen_dynamics", "env_config", "main", "run"]

_ABSENT = object()  # OmegaConf.select's default: a key the config does not have


def chosen_dynamics(cfg: DictConfig, overrides: list[str]) -> list[str]:
    """Let a ``dynamics=<name>`` among the command line's ``overrides`` set ``eval.dynamics`` (in place): with
    ``eval.dynamics`` null the training's dynamics would replace it silently. Both set and different: an error.

    Returns the ``dynamics.<key>`` settings given without a ``dynamics=`` group (``dynamics.pose_noise.position_std``
    ...): :func:`env_config` lays them over the training's dynamics when that replaces the command line's, so
    that they are not dropped with it."""
    from diana_lab.config import override_keys

    keys = override_keys(overrides)
    if "dynamics" not in keys:
        return [k for k in keys if k.startswith("dynamics.")]
    name = str(cfg.dynamics.get("name"))
    if cfg.eval.get("dynamics") is None:
        with open_dict(cfg):
            cfg.eval.dynamics = name
    elif cfg.eval.dynamics != name:
        raise UserError(
            f"dynamics={name} and eval.dynamics={cfg.eval.dynamics}: expected one dynamics to evaluate in; "
            f"give either (eval.dynamics={cfg.eval.dynamics} takes conf/dynamics/{cfg.eval.dynamics}.yaml as it is, "
            f"dynamics={cfg.eval.dynamics} dynamics.<key>=... changes its settings)"
        )
    return []


def env_config(
    cfg: DictConfig, eval_dynamics: str | None, train_cfg: DictConfig | None, dynamics_keys: Sequence[str] = ()
) -> DictConfig:
    """The env groups to evaluate in: ``cfg``'s, with the dynamics of ``eval.dynamics`` (or of training, with
    ``cfg``'s values of ``dynamics_keys``, the command line's ``dynamics.<key>`` settings, laid over it)."""
    from diana_lab.config import compose

    env_cfg = OmegaConf.masked_copy(
        cfg,
        [g for g in ("world", "robot", "dynamics", "sensor", "action_space", "reward", "episode") if g in cfg],
    )
    with open_dict(env_cfg):
        if eval_dynamics is not None:
            if env_cfg.dynamics.get("name") != eval_dynamics:
                env_cfg.dynamics = compose([], config_name=f"dynamics/{eval_dynamics}").dynamics
        elif train_cfg is not None and "dynamics" in train_cfg:
            env_cfg.dynamics = train_cfg.dynamics
            name = train_cfg.dynamics.get("name")
            for key in dynamics_keys:
                if OmegaConf.select(env_cfg, key, default=_ABSENT) is _ABSENT:
                    raise UserError(
                        f"{key}: not a setting of the training's dynamics ({name}); choose the dynamics to evaluate "
                        f"in as well (dynamics=<name> {key}=...)"
                    )
                OmegaConf.update(env_cfg, key, OmegaConf.select(cfg, key), merge=False)
    return env_cfg


def _table(summaries: dict[str, dict[str, Any]], index: str) -> str:
    from diana_lab.evaluation.core import summary_table

    table = summary_table(summaries, index)
    counts = {k: (lambda v: f"{int(v)}") for k in ("episodes", "slow_successes")}
    return table.to_string(formatters=counts, float_format=lambda v: f"{v:.3f}")


def run(
    cfg: DictConfig, out_dir: Path, dynamics_keys: Sequence[str] = (), overrides: Sequence[str] = ()
) -> dict[str, Any]:
    """The evaluation behind the command (testable without Hydra); returns what ``output`` receives.
    ``dynamics_keys``: :func:`chosen_dynamics`'s; ``overrides``: the command line's (a refusal of a model
    trained in another env names the training's overrides missing from them)."""
    from diana_lab.config import to_object
    from diana_lab.envs.rover_nav import RoverNavEnv
    from diana_lab.evaluation.compatibility import check_spaces, settings_note
    from diana_lab.evaluation.core import evaluate, sweep_sensor_noise
    from diana_lab.evaluation.loading import load_policy
    from diana_lab.evaluation.metrics import to_json
    from diana_lab.evaluation.tracking import log_evaluation, tracking_settings
    from diana_lab.tracking.mlflow_run import writable_store

    if cfg.get("policy") is None:
        from diana_lab.evaluation.loading import POLICY_NAMES

        raise UserError(
            f"policy: expected an option of conf/policy/ ({', '.join(POLICY_NAMES)}, pretrained), a model .zip "
            "path or an MLflow run id, e.g. python -m diana_lab.evaluate policy=astar"
        )
    eval_cfg = to_object("eval", cfg.eval)
    # where the results go is checked before the evaluation, so a bad path does not waste it
    output = output_file(cfg.output) if cfg.get("output") else None
    enabled, uri, _ = tracking_settings(cfg)
    if enabled and uri:
        writable_store(uri)
    loaded = load_policy(cfg.policy, cfg, eval_cfg)
    if loaded.note:
        print(f"{loaded.label}: {loaded.note}")
    trained_robot = OmegaConf.select(loaded.train_cfg, "robot.name", default=None) if loaded.train_cfg else None
    if trained_robot is not None and trained_robot != cfg.robot.name:  # a transfer test, allowed, but said
        print(f"note: {loaded.label} was trained on robot={trained_robot}; evaluating it on robot={cfg.robot.name}")
    env = RoverNavEnv(config=env_config(cfg, eval_cfg.dynamics, loaded.train_cfg, dynamics_keys))
    try:
        if loaded.model is not None:
            check_spaces(loaded, env, cfg, overrides)
            if note := settings_note(loaded, cfg, overrides):
                print(note)
        if eval_cfg.sensor_noise:
            levels = sweep_sensor_noise(loaded.policy, env, eval_cfg, out_dir)
            summaries = {f"{level:g}": s for level, s in levels.items()}
            payload: dict[str, Any] = {"sensor_noise": summaries}
            (out_dir / "summary.json").write_text(to_json(payload))
            table = _table(summaries, "noise_level")
            prefixed = {f"eval_noise_{k}_": s for k, s in summaries.items()}
        else:
            payload = evaluate(loaded.policy, env, eval_cfg, out_dir)
            table = _table({loaded.label: payload}, "policy")
            prefixed = {"eval_": payload}
        dynamics = env.cfg["dynamics"].name
    finally:
        env.close()
    if output is not None:
        output.write_text(to_json(payload))
    print(
        f"\n{loaded.label} on {cfg.world.name} ({cfg.robot.name}, {dynamics}), {eval_cfg.episodes} episodes, "
        f"suite seed {eval_cfg.seed}:\n{table}\nresults in {out_dir}"
    )
    if enabled:
        params = {
            "policy": loaded.label,
            "world": cfg.world.name,
            "robot": cfg.robot.name,
            "dynamics": dynamics,
            "sensor": cfg.sensor.name,
            **{f"eval.{k}": v for k, v in vars(eval_cfg).items()},
        }
        run_id = log_evaluation(cfg, prefixed, out_dir, params, parent_run_id=loaded.run_id)
        print(f"MLflow run {run_id}" + (f" (child of {loaded.run_id})" if loaded.run_id else ""))
    return payload


@hydra_app(config_name="evaluate")
def main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig

    hydra_cfg = HydraConfig.get()
    overrides = task_overrides()
    dynamics_keys = chosen_dynamics(cfg, overrides)
    run(cfg, Path(hydra_cfg.runtime.output_dir), dynamics_keys, overrides)


if __name__ == "__main__":
    main()
