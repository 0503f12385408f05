"""The slope shield's rules and their parameters, defined once.

``eval.shield`` (:class:`diana_lab.config.evaluation.ShieldConfig`) and the settings the shield itself and the
onboard runtime read (:class:`diana_lab.shield.settings.ShieldSettings`, also the sidecar's ``shield`` node) both
extend :class:`ShieldRules`, so a key is added, defaulted and checked in one place. Numpy-free: the runtime reads it
without Hydra. A key a sidecar written before it lacks takes its default, which turns its rule off.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from diana_lab.core.validation import (
    ConfigError,
    boolean,
    in_range,
    non_negative,
    non_negative_int,
    positive,
    positive_int,
)

__all__ = ["DEFAULT_RULES", "ShieldRules"]

# the rules that may decide before the veto checks, in the order they are asked (diana_lab.shield.rules)
DEFAULT_RULES = ("approach", "detour", "route")


@dataclass
class ShieldRules:
    """What the shield checks before a candidate waypoint is driven, and which rules may decide first.

    Among the policy's ``top_k`` most probable candidates the first whose straight drive the checks allow is driven
    (the veto checks: slope, hazards felt, obstacles, peaks, relief). Before them, each rule named in ``rules`` may
    choose a drive, in that order; a rule whose parameter is 0 or false never decides."""

    cell_size: float = 0.2  # m: the shield's own height map of the sensor's returns (finer than the policy's)
    limit_deg: float = 25.0  # veto a drive where the map shows a pitch or roll above this (unknown ground passes)
    top_k: int = 16  # candidates tried, most probable first
    spacing: float = 0.2  # m between the checks along the drive
    radius: float = 64.0  # m: half-width of the square the map covers around the episode's first pose
    # m: veto a drive passing this close to where the wheels met ground they could not drive (the tilt guard
    # tripped, or a slope held the rover); 0: off
    hazard_radius: float = 0.0
    # m: veto a drive where anything in the rover's footprint rises this far above its highest wheel probe; 0: off
    obstacle_height: float = 0.0
    min_range: float = 0.0  # m: returns nearer the sensor than this are not mapped (dust); 0: every return
    # m: among the allowed drives, the first ending this far from every place the rover stood (no loops); 0: off
    revisit_radius: float = 0.0
    # m: veto a drive where a footprint cell stands this far above its neighbours (peak_rank: their median at 0,
    # else the k-th highest), judged with at least peak_min_known of the 8 known; 0: off
    peak_height: float = 0.0
    peak_rank: int = 0
    peak_min_known: int = 7
    # smooth ground (median block roughness within smooth_radius under smooth_roughness) lowers the obstacle
    # limit to smooth_obstacle_height: there a low rise is a rock, not relief; 0: off
    smooth_roughness: float = 0.0
    smooth_obstacle_height: float = 0.0  # m, below obstacle_height
    smooth_radius: float = 3.0  # m
    # the relief check (diana_lab.shield.relief): veto a drive crossing a footprint steeper, more stepped or
    # rougher than these, judged where relief_min_known footprint cells are known
    relief: bool = False
    relief_slope_deg: float = 22.0
    relief_step: float = 0.08  # m, de-tilted, between neighbouring cells
    relief_roughness: float = 0.065  # m RMS about the footprint's plane
    relief_min_known: int = 8
    relief_unseen_from: float = 0.0  # m along a drive beyond which a cell the check cannot judge vetoes it; 0: off
    # the rules that may decide before the veto checks, in order (diana_lab.shield.rules; a rule of your own is a
    # function registered there plus its name here)
    rules: list[str] = field(default_factory=lambda: list(DEFAULT_RULES))
    # approach: the goal this near, the shortest candidate passing within approach_tolerance of it; 0: off
    approach_radius: float = 0.0
    approach_tolerance: float = 0.3  # m; under episode.goal_tolerance, so the drive's own error is allowed for
    # detour: after detour_after decisions without coming detour_progress m nearer the goal than ever, the allowed
    # drive of least length + cost to go over the shield's map, searched within detour_margin; 0: off
    detour_after: int = 0
    detour_progress: float = 0.5  # m
    detour_margin: float = 10.0  # m
    # route: only the allowed drives within route_tolerance m of the least length + cost to go are open to the
    # policy, its most probable of them driven
    route: bool = False
    route_tolerance: float = 1.0  # m
    # the search's cost of slope (detour and route): a cell steeper than slope_cost_from_deg costs its length times
    # 1 + weight x (its share of the span up to slope_cost_to_deg)^2; 0: length only
    slope_cost_weight: float = 0.0
    slope_cost_from_deg: float = 15.0
    slope_cost_to_deg: float = 22.0
    # m: the search reads a map of the site made before the drive (diana_lab.shield.site_map), averaged over
    # squares this wide, where the shield's own map shows nothing; needs detour or route; 0: none
    site_map_cell: float = 0.0

    def check_rules(self, where: str) -> None:
        """Raise a :class:`ConfigError` naming ``<where>.<key>`` for a value no rule can work with."""
        positive(f"{where}.cell_size", self.cell_size)
        in_range(f"{where}.limit_deg", self.limit_deg, 0.0, 90.0, inclusive=False)
        positive_int(f"{where}.top_k", self.top_k)
        positive(f"{where}.spacing", self.spacing)
        positive(f"{where}.radius", self.radius)
        for key in ("hazard_radius", "obstacle_height", "min_range", "revisit_radius", "peak_height"):
            non_negative(f"{where}.{key}", getattr(self, key))
        for key, lo in (("peak_rank", 0), ("peak_min_known", 1)):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= 8:
                raise ConfigError(f"{where}.{key}: expected an integer in {lo}..8, got {value!r}")
        non_negative(f"{where}.smooth_roughness", self.smooth_roughness)
        non_negative(f"{where}.smooth_obstacle_height", self.smooth_obstacle_height)
        positive(f"{where}.smooth_radius", self.smooth_radius)
        if self.smooth_roughness > 0 and not 0 < self.smooth_obstacle_height < self.obstacle_height:
            raise ConfigError(
                f"{where}.smooth_obstacle_height: with {where}.smooth_roughness > 0, expected a height above 0 and "
                f"below {where}.obstacle_height ({self.obstacle_height}), got {self.smooth_obstacle_height}"
            )
        self.relief = boolean(f"{where}.relief", self.relief)
        in_range(f"{where}.relief_slope_deg", self.relief_slope_deg, 0.0, 90.0, inclusive=False)
        positive(f"{where}.relief_step", self.relief_step)
        positive(f"{where}.relief_roughness", self.relief_roughness)
        if isinstance(self.relief_min_known, bool) or not isinstance(self.relief_min_known, int):
            raise ConfigError(f"{where}.relief_min_known: expected an integer >= 3, got {self.relief_min_known!r}")
        if self.relief_min_known < 3:
            raise ConfigError(
                f"{where}.relief_min_known: expected an integer >= 3 (a plane needs 3), got {self.relief_min_known}"
            )
        non_negative(f"{where}.relief_unseen_from", self.relief_unseen_from)
        if self.relief_unseen_from > 0 and not self.relief:
            raise ConfigError(
                f"{where}.relief_unseen_from={self.relief_unseen_from}: expected {where}.relief=true with it (the "
                "cells it keeps off are those the relief check cannot judge), or 0"
            )
        if isinstance(self.rules, str) or not all(isinstance(r, str) for r in self.rules):
            raise ConfigError(
                f"{where}.rules: expected a list of rule names, e.g. {list(DEFAULT_RULES)}, got {self.rules!r}"
            )
        if len(set(self.rules)) != len(self.rules):
            raise ConfigError(f"{where}.rules: expected each rule once, got {list(self.rules)}")
        non_negative(f"{where}.approach_radius", self.approach_radius)
        positive(f"{where}.approach_tolerance", self.approach_tolerance)
        non_negative_int(f"{where}.detour_after", self.detour_after, "0: off")
        positive(f"{where}.detour_progress", self.detour_progress)
        positive(f"{where}.detour_margin", self.detour_margin)
        self.route = boolean(f"{where}.route", self.route)
        non_negative(f"{where}.route_tolerance", self.route_tolerance)
        non_negative(f"{where}.slope_cost_weight", self.slope_cost_weight)
        in_range(f"{where}.slope_cost_from_deg", self.slope_cost_from_deg, 0.0, 90.0, inclusive=False)
        in_range(f"{where}.slope_cost_to_deg", self.slope_cost_to_deg, 0.0, 90.0, inclusive=False)
        if not self.slope_cost_from_deg < self.slope_cost_to_deg:
            raise ConfigError(
                f"{where}.slope_cost_to_deg: expected more than {where}.slope_cost_from_deg "
                f"({self.slope_cost_from_deg}), got {self.slope_cost_to_deg}"
            )
        non_negative(f"{where}.site_map_cell", self.site_map_cell)
        if self.site_map_cell > 0 and not (self.detour_after > 0 or self.route):
            raise ConfigError(
                f"{where}.site_map_cell={self.site_map_cell}: the site map is read by the shield's search, which runs "
                f"only with {where}.detour_after > 0 or {where}.route=true; set one, or 0 for no site map"
            )
