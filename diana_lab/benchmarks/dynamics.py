"""Dynamics figures: kinematic waypoints per second, and the physics model's real-time factor per robot.

Both drive the same loop with sensors off: start where the episode sampler would (a traversable cell of the
cost map), hand the turn-then-drive controller a waypoint 3.5 m away in a random direction (half the
paper's 7 m action square), and start afresh after a failure (tip-over, collision, stuck, out of bounds),
as an episode would end there. Only ``execute`` is timed; resets (and the physics model's settling) are not.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from diana_lab.benchmarks.core import BenchContext, Figure, Stopwatch, Target, figure_from_samples, measurement, repeat

__all__ = ["WaypointDriver", "kinematic_waypoints", "physics_realtime"]

WAYPOINT_DISTANCE = 3.5  # m
KINEMATIC_TARGET = Target(">=", 5000.0)
PHYSICS_TARGET = Target(">=", 200.0)  # set for the Jackal, the paper's robot
GAZEBO_ANCHOR = {"name": "Gazebo + ROS 2 (DIANA-Gym), real time", "value": 1.0}


class WaypointDriver:
    """Drives one dynamics model from waypoint to waypoint; see the module docstring."""

    def __init__(self, ctx: BenchContext, dynamics_option: str, robot: str | None = None) -> None:
        from diana_lab import config as C
        from diana_lab.envs.episodes import EpisodeSampler
        from diana_lab.sim.controller import TurnThenDrive

        self.robot = ctx.robot(robot)
        dyn_cfg = ctx.typed("dynamics", f"dynamics={dynamics_option}")
        self.dynamics = C.build(dyn_cfg, ctx.world, self.robot)
        self.controller = TurnThenDrive(dyn_cfg.controller, self.robot)
        self.sampler = EpisodeSampler(ctx.typed("episode"), ctx.world, self.robot)
        self.rng = np.random.default_rng(ctx.seed)
        self.resets = 0
        self.reset()

    def reset(self) -> None:
        ep = self.sampler.sample(self.rng)
        self.dynamics.reset(ep.start, ep.yaw, self.rng)
        self.resets += 1

    def drive(self, waypoints: int, timer: Stopwatch) -> tuple[float, int]:
        """Execute ``waypoints`` waypoints (timing only ``execute``); returns simulated seconds, failures."""
        sim, failures = 0.0, 0
        for heading in self.rng.uniform(-math.pi, math.pi, waypoints):
            xy = self.dynamics.state.xy
            waypoint = np.array(
                [xy[0] + WAYPOINT_DISTANCE * math.cos(heading), xy[1] + WAYPOINT_DISTANCE * math.sin(heading)]
            )
            self.controller.start()
            with timer:
                result = self.dynamics.execute(waypoint, self.controller)
            sim += result.duration
            if result.failed:
                failures += 1
                self.reset()
        return sim, failures

    def close(self) -> None:
        self.dynamics.close()


@measurement("kinematic_waypoints_per_s")
def kinematic_waypoints(ctx: BenchContext) -> list[Figure]:
    n = ctx.size(3000, 400)
    driver = WaypointDriver(ctx, "kinematic")
    failures: list[float] = []

    def sample() -> float:
        timer = Stopwatch()
        _, failed = driver.drive(n, timer)
        failures.append(failed / n)
        return n / timer.seconds

    try:
        samples = repeat(sample, ctx.repeats)
    finally:
        driver.close()
    return [
        figure_from_samples(
            "kinematic_waypoints_per_s",
            "1/s",
            samples,
            batch=f"{n} waypoints",
            target=KINEMATIC_TARGET,
            note=f"{driver.robot.name}: KinematicDynamics.execute, {WAYPOINT_DISTANCE} m waypoints, sensors off, "
            "1 core",
            extra={"failure_rate": float(np.mean(failures))},
        )
    ]


def _realtime_factor(ctx: BenchContext, key: str, robot: str | None, waypoints: int) -> Figure:
    driver = WaypointDriver(ctx, "physics", robot)
    per_waypoint: list[float] = []
    failures: list[float] = []

    def sample() -> float:
        timer = Stopwatch()
        sim, failed = driver.drive(waypoints, timer)
        per_waypoint.append(sim / waypoints)
        failures.append(failed / waypoints)
        return sim / timer.seconds

    try:
        samples = repeat(sample, ctx.repeats)
    finally:
        driver.close()
    name = driver.robot.name
    extra: dict[str, Any] = {
        "sim_s_per_waypoint": float(np.mean(per_waypoint)),
        "failure_rate": float(np.mean(failures)),
    }
    return figure_from_samples(
        key,
        "x",
        samples,
        batch=f"{waypoints} waypoints",
        target=PHYSICS_TARGET if key == "physics_realtime_factor" else None,
        note=f"{name}: simulated s / wall s of PhysicsDynamics.execute, 1 core",
        anchor=GAZEBO_ANCHOR,
        extra=extra,
    )


@measurement("physics_realtime_factor", "physics_realtime_factor_husky", "physics_realtime_factor_rocker_bogie")
def physics_realtime(ctx: BenchContext) -> list[Figure]:
    n = ctx.size(12, 2)  # ~10 simulated s each: ~0.05 s (Jackal) to ~0.15 s (Husky) of wall time
    return [
        _realtime_factor(ctx, "physics_realtime_factor", "jackal", n),
        _realtime_factor(ctx, "physics_realtime_factor_husky", "husky", n),
        _realtime_factor(ctx, "physics_realtime_factor_rocker_bogie", "rocker_bogie", n),
    ]
