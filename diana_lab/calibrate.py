"""``python -m diana_lab.calibrate [world=...] [robot=...] [starts=N] ['overshoots=[...]'] [output=PATH.json]``

Scores the kinematic model against PyBullet on the same waypoints from the same poses, and which
``dynamics.guard_overshoot`` makes its tip-overs agree best with physics'
(:mod:`diana_lab.evaluation.calibration`)::

    python -m diana_lab.calibrate                                   # the Mars yard, the main command's rover
    python -m diana_lab.calibrate world=craters starts=200 output=calibration.json
"""

from __future__ import annotations

import json

from omegaconf import DictConfig, OmegaConf

from diana_lab.cli import hydra_app, output_file

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

    result = calibrate(setup, world, robot, kinematic, physics, C.to_object("episode", groups["episode"]), progress)
    guard = "no guard" if robot.tilt_guard_deg is None else f"guard {robot.tilt_guard_deg:g} deg"
    print(format_report(result, f"{world.name}, {robot.name}, {guard}, tip-over {robot.tipover_deg:g} deg"))
    if path is not None:
        path.write_text(json.dumps(result.to_json(), indent=2))
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
