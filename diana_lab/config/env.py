"""Config schemas of the env groups: ``action_space``, ``reward`` and ``episode``."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from omegaconf import MISSING

from diana_lab.config.store import register
from diana_lab.core.validation import ConfigError, in_range, non_negative, one_of, ordered, positive

SHAPES = ("square", "circle", "discrete")


@dataclass
class ActionSpaceConfig:
    """Where the next waypoint may be: a square of side ``size`` or a disc of radius ``radius`` around the rover,
    or (``discrete``) one of a fixed set of candidates.

    ``discrete`` exists for imitation: the A* expert's choice is multimodal (round an obstacle on the left or
    on the right, a near or a far waypoint), and regressing a Gaussian mean on it averages the modes into a
    waypoint between them, often on the hazard itself; a categorical head over candidates picks one mode. The
    candidates are every pairing of ``headings`` evenly spaced bearings (the first straight ahead in the
    action frame, counter-clockwise) with the ``distances`` (m), heading-major: candidate ``k`` lies at bearing
    ``2 pi (k // len(distances)) / headings`` and distance ``distances[k % len(distances)]``. Every distance is
    at most ``size / 2``, so the candidates lie on the disc inscribed in the paper's square (and, with the
    default sizes, inside its 4 m disc too). ``frame=world`` takes the bearings in the map's axes (the first
    one along +x). ``min_distance`` must stay 0: the smallest of ``distances`` already says how close a
    waypoint may be.
    """

    name: str = MISSING
    shape: str = MISSING  # "square" | "circle" | "discrete"
    size: float = 7.0  # square side (m); for discrete, 2 x the largest allowed distance
    radius: float = 4.0  # circle radius (m)
    frame: str = "rover"  # "world": axes aligned with the map (paper); "rover": x forward, y left
    min_distance: float = 0.0  # waypoints closer than this are pushed out to it (0 keeps the mapping exact)
    headings: int = 16  # discrete: evenly spaced bearings, the first straight ahead
    distances: list[float] = field(default_factory=lambda: [1.0, 2.0, 3.0])  # discrete: ring radii (m), increasing

    def __post_init__(self) -> None:
        one_of("action_space.shape", self.shape, SHAPES)
        one_of("action_space.frame", self.frame, ("world", "rover"))
        positive("action_space.size", self.size)
        positive("action_space.radius", self.radius)
        non_negative("action_space.min_distance", self.min_distance)
        if self.shape == "discrete":
            self._check_candidates()
            return
        extent = self.size / 2 if self.shape == "square" else self.radius
        if self.min_distance >= extent:
            raise ConfigError(
                f"action_space.min_distance ({self.min_distance}) must be smaller than the shape's "
                f"half-extent ({extent})"
            )

    def _check_candidates(self) -> None:
        if isinstance(self.headings, bool) or not isinstance(self.headings, int) or self.headings < 2:
            raise ConfigError(
                f"action_space.headings: expected an integer >= 2 (one bearing alone could never turn), "
                f"got {self.headings!r}"
            )
        if not self.distances:
            raise ConfigError("action_space.distances: expected at least one distance (m)")
        reach = self.size / 2
        for i, d in enumerate(self.distances):
            if not (isinstance(d, int | float) and math.isfinite(d) and 0 < d <= reach):
                raise ConfigError(
                    f"action_space.distances[{i}]: expected a distance in (0, {reach}] m (action_space.size / 2, "
                    f"so that every candidate lies inside the square), got {d!r}"
                )
        if any(b <= a for a, b in zip(self.distances, self.distances[1:], strict=False)):
            raise ConfigError(
                f"action_space.distances: expected strictly increasing distances (distinct candidates), "
                f"got {list(self.distances)}"
            )
        if self.min_distance != 0:
            raise ConfigError(
                f"action_space.min_distance: expected 0 with shape discrete (the smallest of "
                f"action_space.distances is the nearest waypoint), got {self.min_distance!r}"
            )

    @property
    def extent(self) -> float:
        """How far from the rover a waypoint can lie along its own direction: the square's half side, the
        disc's radius, or the farthest candidate."""
        if self.shape == "square":
            return self.size / 2.0
        if self.shape == "circle":
            return self.radius
        return float(max(self.distances))


@dataclass
class TermConfig:
    """One reward term: a plain function ``fn(ctx, **params) -> float``, scaled by ``weight`` (0 disables it)."""

    fn: str = MISSING
    weight: float = 1.0
    params: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def checked(cls, name: str, value: Any) -> TermConfig:
        """A term from its config mapping, every key checked and named (``reward.terms.<name>.<key>``)."""
        if isinstance(value, TermConfig):
            return value
        where = f"reward.terms.{name}"
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a mapping {{fn, weight, params}}, got {value!r}")
        unknown = sorted(set(value) - {"fn", "weight", "params"})
        if unknown:
            raise ConfigError(f"{where}: unknown key(s) {unknown}; a term has fn, weight and params")
        fn, weight, params = value.get("fn"), value.get("weight", 1.0), value.get("params") or {}
        if not isinstance(fn, str) or not fn or fn == MISSING:
            raise ConfigError(f"{where}.fn: expected a function's dotted path (module.function), got {fn!r}")
        if isinstance(weight, bool) or not isinstance(weight, int | float) or not math.isfinite(weight):
            raise ConfigError(f"{where}.weight: expected a number, got {weight!r}")
        if not isinstance(params, Mapping):
            raise ConfigError(f"{where}.params: expected a mapping of keyword arguments, got {params!r}")
        return cls(fn, float(weight), dict(params))


@dataclass
class RewardConfig:
    """``terms``: name -> ``{fn, weight, params}``. The values are untyped in the schema so that a term can be
    added from the command line (``'+reward.terms.mine={fn: mymod.my_term, weight: 0.5}'``): OmegaConf refuses
    a plain mapping as a new value of a ``Dict[str, TermConfig]``. Each is checked into a :class:`TermConfig`
    here, naming its keys."""

    name: str = MISSING
    terms: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.terms:
            raise ConfigError("reward.terms: expected at least one reward term")
        self.terms = {str(key): TermConfig.checked(str(key), term) for key, term in self.terms.items()}


@dataclass
class CurriculumConfig:
    enabled: bool = False
    start_max_distance: float = 10.0  # the goal distance range starts at [min_distance, this] ...
    episodes: int = 2000  # ... and widens linearly to max_distance over this many episodes (per env)


@dataclass
class EpisodeConfig:
    """How episodes are drawn and when they end."""

    name: str = "default"
    min_distance: float = 8.0  # start-goal straight-line distance range (m)
    max_distance: float = 30.0
    goal_tolerance: float = 0.5  # success within this distance of the goal (m)
    max_steps: int = 60  # waypoints per episode before the time limit (truncated)
    max_time_s: float = 900.0  # simulated seconds per episode before the time limit (truncated)
    stuck_steps: int = 6  # this many waypoints in a row ...
    stuck_distance: float = 0.25  # ... with less net displacement than this (m): the episode ends as "stuck"
    map_margin: float = 0.5  # waypoints are clamped this far (plus the robot radius) inside the map
    distance_scale: float = 50.0  # goal distance is observed as distance / distance_scale
    curriculum: CurriculumConfig = field(default_factory=CurriculumConfig)

    def __post_init__(self) -> None:
        non_negative("episode.min_distance", self.min_distance)
        ordered("episode.min_distance", self.min_distance, "episode.max_distance", self.max_distance)
        positive("episode.goal_tolerance", self.goal_tolerance)
        positive("episode.max_steps", self.max_steps)
        positive("episode.max_time_s", self.max_time_s)
        positive("episode.stuck_steps", self.stuck_steps)
        non_negative("episode.stuck_distance", self.stuck_distance)
        non_negative("episode.map_margin", self.map_margin)
        positive("episode.distance_scale", self.distance_scale)
        if self.curriculum.enabled:
            in_range(
                "episode.curriculum.start_max_distance",
                self.curriculum.start_max_distance,
                self.min_distance,
                self.max_distance,
            )
            positive("episode.curriculum.episodes", self.curriculum.episodes)


register("action_space", {"action_space": ActionSpaceConfig})
register("reward", {"reward": RewardConfig})
register("episode", {"episode": EpisodeConfig})
