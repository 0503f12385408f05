"""The kinematic model against PyBullet, waypoint by waypoint, and the tilt guard's overshoot that agrees best.

The platform trains in the kinematic model and is judged in physics too, so what the kinematic model calls safe
must be what keeps a PyBullet rover upright. This drives the physics rover from the episode sampler's starts to
random waypoints (a bearing uniform round the rover, a distance drawn from ``distances``: the discrete action
space's rings), at most ``waypoints`` per start, a failure ending the drive; before each waypoint the kinematic
model is put at the physics rover's pose and sent to the same waypoint, once for each candidate
``dynamics.guard_overshoot``. Each pair of outcomes is counted, and for tip-overs (the outcome the two disagree
on most: the kinematic guard halts a rover that physics' momentum carries over) the recall, precision and F1 of
the kinematic model's calls against physics'.

Only the kinematic model's ``guard_overshoot`` varies; every other setting is the run's ``dynamics`` (which must
be kinematic) and ``physics`` (``conf/dynamics/physics.yaml`` unless overridden, e.g. ``physics.friction=0.7``).

With a policy (:func:`calibrate_policy`) the waypoints are the policy's own, on the evaluation suite in physics:
:class:`KinematicTwin` stands in for the env's physics model and, before each waypoint, drives the kinematic
models from the physics rover's true pose to the same waypoint. It shows which of a policy's physics failures the
world it trained in would have shown it.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from diana_lab.core.validation import ConfigError, non_negative, positive, positive_int
from diana_lab.envs.episodes import EpisodeSampler
from diana_lab.sim.controller import TurnThenDrive
from diana_lab.sim.kinematic import KinematicDynamics
from diana_lab.sim.state import FAILURES

__all__ = [
    "Calibration",
    "CalibrationSetup",
    "KinematicTwin",
    "OvershootScore",
    "calibrate",
    "calibrate_policy",
    "format_report",
    "score_tipovers",
]


@dataclass(frozen=True)
class CalibrationSetup:
    """How many drives, and which overshoots to score (``conf/calibrate.yaml``)."""

    starts: int = 400
    waypoints: int = 8
    distances: tuple[float, ...] = (1.0, 2.0, 3.0)
    overshoots: tuple[float, ...] = (0.0, 0.1, 0.2, 0.3, 0.4)
    seed: int = 0

    def __post_init__(self) -> None:
        positive_int("starts", self.starts)
        positive_int("waypoints", self.waypoints)
        if not self.distances:
            raise ConfigError("distances: expected at least one waypoint distance (m), e.g. [1.0, 2.0, 3.0]")
        for d in self.distances:
            positive("distances", d)
        if not self.overshoots:
            raise ConfigError("overshoots: expected at least one dynamics.guard_overshoot (m) to score, e.g. [0, 0.2]")
        for o in self.overshoots:
            non_negative("overshoots", o)


@dataclass
class OvershootScore:
    """How one ``guard_overshoot`` agrees with physics: tip-over calls, and every pair of outcomes."""

    overshoot: float
    kinematic_tipovers: int
    agreed_tipovers: int
    recall: float  # of physics' tip-overs, the share the kinematic model also calls
    precision: float  # of the kinematic model's tip-overs, the share physics has too
    f1: float
    outcomes: dict[str, int] = field(default_factory=dict)  # "physics -> kinematic": count


@dataclass
class Calibration:
    waypoints: int
    starts: int  # episode starts: random drives', or the suite's episodes
    physics_outcomes: dict[str, int]
    scores: list[OvershootScore]
    policy_summary: dict[str, Any] | None = None  # the policy's suite in physics (calibrate_policy)

    @property
    def best(self) -> OvershootScore:
        """The overshoot with the highest tip-over F1 (the smallest on a tie; the smallest where no model tips)."""
        return max(self.scores, key=lambda s: (-1.0 if math.isnan(s.f1) else s.f1, -s.overshoot))

    def to_json(self) -> dict[str, Any]:
        return {
            "waypoints": self.waypoints,
            "starts": self.starts,
            "physics_outcomes": self.physics_outcomes,
            "best_overshoot": self.best.overshoot,
            "scores": [dataclasses.asdict(s) for s in self.scores],
            **({"policy_summary": self.policy_summary} if self.policy_summary is not None else {}),
        }


def score_tipovers(physics: Sequence[str], kinematic: Sequence[str], overshoot: float) -> OvershootScore:
    """Tip-over recall, precision and F1 of ``kinematic``'s outcomes against ``physics``' (waypoint by waypoint)."""
    if len(physics) != len(kinematic):
        raise ValueError(f"{len(physics)} physics outcomes against {len(kinematic)} kinematic ones")
    p = np.array([o == "tipover" for o in physics], dtype=bool)
    k = np.array([o == "tipover" for o in kinematic], dtype=bool)
    both = int(np.sum(p & k))
    recall = both / int(p.sum()) if p.any() else math.nan
    precision = both / int(k.sum()) if k.any() else math.nan
    f1 = 2 * both / int(p.sum() + k.sum()) if (p.any() or k.any()) else math.nan
    pairs = Counter(f"{a} -> {b}" for a, b in zip(physics, kinematic, strict=True))
    return OvershootScore(overshoot, int(k.sum()), both, recall, precision, f1, dict(pairs.most_common()))


def _check_kinematic(cfg: Any) -> None:
    if getattr(cfg, "name", None) != "kinematic":
        raise ConfigError(
            f"dynamics={getattr(cfg, 'name', cfg)}: calibrate scores the kinematic model "
            "against physics; expected dynamics=kinematic (the physics side is the 'physics' key)"
        )


def _twins(setup: CalibrationSetup, kinematic_cfg: Any, world: Any, robot: Any) -> list[KinematicDynamics]:
    return [
        KinematicDynamics(dataclasses.replace(kinematic_cfg, guard_overshoot=float(o)), world, robot)
        for o in setup.overshoots
    ]


def _calibration(
    setup: CalibrationSetup, starts: int, physics_out: list[str], kinematic_out: list[list[str]]
) -> Calibration:
    scores = [
        score_tipovers(physics_out, outs, float(o)) for o, outs in zip(setup.overshoots, kinematic_out, strict=True)
    ]
    return Calibration(len(physics_out), starts, dict(Counter(physics_out).most_common()), scores)


class KinematicTwin:
    """A physics dynamics model that, before each waypoint, sends ``kinematic`` models from its rover's true pose
    to the same waypoint (with their own controller, so the physics run is the one it would be without them) and
    records every outcome; everything else is the physics model's."""

    def __init__(self, physics: Any, kinematic: list[KinematicDynamics], controller: TurnThenDrive) -> None:
        self.physics, self.kinematic, self._controller = physics, kinematic, controller
        self.physics_out: list[str] = []
        self.kinematic_out: list[list[str]] = [[] for _ in kinematic]

    def execute(self, waypoint: np.ndarray, controller: TurnThenDrive, pose_estimate: Any = None) -> Any:
        st = self.physics.state
        for dyn, outs in zip(self.kinematic, self.kinematic_out, strict=True):
            dyn.reset(st.xy, st.yaw)
            self._controller.start()
            outs.append(dyn.execute(np.asarray(waypoint, dtype=float), self._controller).outcome)
        result = self.physics.execute(waypoint, controller, pose_estimate)
        self.physics_out.append(result.outcome)
        return result

    def __getattr__(self, name: str) -> Any:
        return getattr(self.physics, name)


def calibrate_policy(setup: CalibrationSetup, policy: Any, env: Any, kinematic_cfg: Any, eval_cfg: Any) -> Calibration:
    """The pairs of the module docstring on ``policy``'s own waypoints: its suite (``eval_cfg.episodes`` from
    ``eval_cfg.seed``) in ``env``, whose dynamics must be physics."""
    from diana_lab.evaluation.metrics import summarize
    from diana_lab.evaluation.runner import run_episodes
    from diana_lab.evaluation.suite import make_suite

    _check_kinematic(kinematic_cfg)
    base = env.unwrapped
    if base.cfg["dynamics"].name != "physics":
        raise ConfigError(f"physics: expected the physics dynamics option, got {base.cfg['dynamics'].name!r}")
    twin = KinematicTwin(
        base.dynamics,
        _twins(setup, kinematic_cfg, base.world, base.robot),
        TurnThenDrive(kinematic_cfg.controller, base.robot),
    )
    base.dynamics = twin
    try:
        suite = make_suite(env, eval_cfg.episodes, eval_cfg.seed, eval_cfg.min_distance, eval_cfg.max_distance)
        df, _ = run_episodes(policy, env, suite)
    finally:
        base.dynamics = twin.physics
    result = _calibration(setup, eval_cfg.episodes, twin.physics_out, twin.kinematic_out)
    summary = summarize(df, eval_cfg.min_goal_speed)
    result.policy_summary = {
        k: summary[k] for k in ("success_rate", "spl", "tipover_rate", "stuck_rate") if k in summary
    }
    return result


def calibrate(
    setup: CalibrationSetup,
    world: Any,
    robot: Any,
    kinematic_cfg: Any,
    physics_cfg: Any,
    episode_cfg: Any,
    progress: Callable[[int, int], None] | None = None,
) -> Calibration:
    """Drive the pairs of the module docstring; ``progress(start, waypoints so far)`` after each start."""
    from diana_lab import config as C

    _check_kinematic(kinematic_cfg)
    physics = C.build(physics_cfg, world, robot)
    kinematic = _twins(setup, kinematic_cfg, world, robot)
    physics_ctl = TurnThenDrive(physics_cfg.controller, robot)
    kinematic_ctl = TurnThenDrive(kinematic_cfg.controller, robot)
    sampler = EpisodeSampler(episode_cfg, world, robot)
    rng = np.random.default_rng(setup.seed)
    physics_out: list[str] = []
    kinematic_out: list[list[str]] = [[] for _ in kinematic]
    try:
        for start in range(setup.starts):
            episode = sampler.sample(rng)
            physics.reset(episode.start, episode.yaw)
            for _ in range(setup.waypoints):
                st = physics.state
                bearing = float(rng.uniform(-math.pi, math.pi))
                distance = float(rng.choice(np.asarray(setup.distances, dtype=float)))
                waypoint = st.xy + distance * np.array([math.cos(bearing), math.sin(bearing)])
                for dyn, outs in zip(kinematic, kinematic_out, strict=True):
                    dyn.reset(st.xy, st.yaw)
                    kinematic_ctl.start()
                    outs.append(dyn.execute(waypoint, kinematic_ctl).outcome)
                physics_ctl.start()
                result = physics.execute(waypoint, physics_ctl)
                physics_out.append(result.outcome)
                if result.outcome in FAILURES:
                    break
            if progress is not None:
                progress(start + 1, len(physics_out))
    finally:
        physics.close()
    return _calibration(setup, setup.starts, physics_out, kinematic_out)


def format_report(cal: Calibration, where: str) -> str:
    """The table ``python -m diana_lab.calibrate`` prints."""
    n = cal.waypoints
    tips = cal.physics_outcomes.get("tipover", 0)
    origin = f"{cal.starts} episodes of the policy" if cal.policy_summary is not None else f"{cal.starts} starts"
    lines = [
        f"kinematic model against physics, {where}: {n} waypoints from {origin}",
        "physics: " + ", ".join(f"{k} {v} ({v / n:.1%})" for k, v in cal.physics_outcomes.items()),
        *(
            ["the policy in physics: " + ", ".join(f"{k} {v:.3f}" for k, v in cal.policy_summary.items())]
            if cal.policy_summary is not None
            else []
        ),
        "",
        f"{'guard_overshoot':>15}  {'kinematic tip-overs':>19}  {'both':>5}  {'recall':>6}  {'precision':>9}  "
        f"{'F1':>5}",
    ]
    for s in cal.scores:
        lines.append(
            f"{s.overshoot:>15.2f}  {s.kinematic_tipovers:>19d}  {s.agreed_tipovers:>5d}  {s.recall:>6.2f}  "
            f"{s.precision:>9.2f}  {s.f1:>5.2f}"
        )
    best = cal.best
    lines += [
        "",
        f"physics tip-overs: {tips}; best tip-over F1 at dynamics.guard_overshoot={best.overshoot:g}",
        "its outcomes (physics -> kinematic): " + ", ".join(f"{k} {v}" for k, v in best.outcomes.items()),
    ]
    return "\n".join(lines)
