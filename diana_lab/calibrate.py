"""``python -m diana_lab.calibrate [world=...] [robot=...] [starts=N] ['overshoots=[...]'] [output=PATH.json]``

Scores the kinematic model against PyBullet on the same waypoints from the same poses, and which
``dynamics.guard_overshoot`` makes its tip-overs agree best with physics'
(:mod:`diana_lab.evaluation.calibration`)::

    python -m diana_lab.calibrate                                   # the Mars yard, the main command's rover
    python -m diana_lab.calibrate world=craters starts=200 output=calibration.json
    python -m diana_lab.calibrate policy=<run id> eval.seed=1002    # the policy's own waypoints, its suite

With a policy, the env groups are the command line's, as for ``python -m diana_lab.evaluate``: repeat the
overrides the policy was trained with.
"""

from __future__ import annotations

import json
from typing import Any

from omegaconf import DictConfig, OmegaConf, open_dict

from diana_lab.cli import hydra_app, output_file, task_overrides

__all__ = ["main"]


@hydra_app(config_name="calibrate")
def main(cfg: DictConfig) -> None:
    from diana_lab import config as C
    from diana_lab.evaluation.calibration import CalibrationSetup, calibrate, format_report
    from diana_lab.training.envs import env_config, shared_world

    setup = CalibrationSetup(
        starts=cfg.starts,
        waypoints=cfg.waypoints,
        distances=tuple(OmegaConf.to_container(cfg.distances)),  # type: ignore[arg-type]
        overshoots=tuple(OmegaConf.to_container(cfg.overshoots)),  # type: ignore[arg-type]
        seed=cfg.seed,
    )
    path = output_file(cfg.output) if cfg.output is not None else None
    groups = env_config(cfg)
    world = shared_world(groups["world"])
    robot = C.to_object("robot", groups["robot"])
    kinematic = C.to_object("dynamics", groups["dynamics"])
    physics = C.to_object("dynamics", cfg.physics)
    if physics.name != "physics":
        raise C.ConfigError(f"physics: expected the physics dynamics option, got {physics.name!r}")

    def progress(start: int, waypoints: int) -> None:
        if start % 50 == 0 or start == setup.starts:
            print(f"{start}/{setup.starts} starts, {waypoints} waypoints", flush=True)

    if cfg.get("policy") is not None:
        result = _policy_calibration(cfg, setup, kinematic)
    else:
        episode = C.to_object("episode", groups["episode"])
        result = calibrate(setup, world, robot, kinematic, physics, episode, progress)
    guard = "no guard" if robot.tilt_guard_deg is None else f"guard {robot.tilt_guard_deg:g} deg"
    print(format_report(result, f"{world.name}, {robot.name}, {guard}, tip-over {robot.tipover_deg:g} deg"))
    if path is not None:
        path.write_text(json.dumps(result.to_json(), indent=2))
        print(f"wrote {path}")


def _policy_calibration(cfg: DictConfig, setup: Any, kinematic: Any) -> Any:
    """:func:`~diana_lab.evaluation.calibration.calibrate_policy` on the policy of ``cfg.policy``, in an env of the
    command line's groups with the ``physics`` key's dynamics."""
    from diana_lab import config as C
    from diana_lab.envs.rover_nav import RoverNavEnv
    from diana_lab.evaluation.calibration import calibrate_policy
    from diana_lab.evaluation.compatibility import check_spaces, settings_note
    from diana_lab.evaluation.loading import load_policy

    eval_cfg = C.to_object("eval", cfg.eval)
    loaded = load_policy(cfg.policy, cfg, eval_cfg)
    groups = OmegaConf.masked_copy(cfg, ["world", "robot", "sensor", "action_space", "reward", "episode"])
    with open_dict(groups):
        groups.dynamics = cfg.physics
    env = RoverNavEnv(config=groups)
    try:
        if loaded.model is not None:  # trained on other observations or actions: refused as evaluate refuses it
            check_spaces(loaded, env, cfg, task_overrides())
            if note := settings_note(loaded, cfg, task_overrides()):
                print(note)
        print(f"{loaded.label}: {eval_cfg.episodes} episodes of suite seed {eval_cfg.seed} in physics", flush=True)
        return calibrate_policy(setup, loaded.policy, env, kinematic, eval_cfg)
    finally:
        env.close()


if __name__ == "__main__":
    main()
