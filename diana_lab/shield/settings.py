"""The slope shield's settings as plain values, checked when they are built.

Why a module of its own: the simulator builds them from ``eval.shield`` and the robot's geometry
(:meth:`ShieldSettings.from_config`), the exporter writes them into the sidecar and the onboard runtime reads them
back (:meth:`ShieldSettings.from_dict`, numpy only). Checking them here means a bad sidecar is refused when it is
read, naming the bad key, not when the rover first decides. Keys a sidecar written before them lacks take their
defaults, which turn the rule they belong to off.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from diana_lab.shield.detour import SlopeCost
from diana_lab.shield.relief import ReliefLimits

if TYPE_CHECKING:  # numpy only at run time: the onboard runtime imports this module without Hydra
    from diana_lab.config.evaluation import ShieldConfig
    from diana_lab.config.sim import RobotConfig

__all__ = ["RELIEF_MARGIN", "ShieldSettings"]

# the relief check: a footprint this much wider than the rover's (m; the cost map judges a cell by the ground
# round it, and a wheel meets a step before the body's circle does)
RELIEF_MARGIN = 0.1


@dataclass
class ShieldSettings:
    """What the shield needs, as plain values (``eval.shield`` and the robot's geometry; the sidecar's
    ``shield`` node onboard)."""

    limit_deg: float
    top_k: int
    cell_size: float
    spacing: float
    radius: float
    half_base: float  # half the distance between the outermost axles (m)
    half_track: float  # half the track width (m)
    hazard_radius: float = 0.0  # m; 0: hazards felt are not used (sidecars written before the key: off)
    obstacle_height: float = 0.0  # m above the highest wheel probe within the footprint; 0: off (older sidecars)
    footprint_radius: float = 0.0  # m: the rover's footprint, what the obstacle check searches
    min_range: float = 0.0  # m: returns nearer the sensor are not mapped; 0: all (older sidecars)
    revisit_radius: float = 0.0  # m: prefer drives ending this far from where the rover stood; 0: off (older sidecars)
    peak_height: float = 0.0  # m a map cell in the footprint may stand over its neighbours; 0: off (older sidecars)
    approach_radius: float = 0.0  # m: the goal this near, drive straight for it when allowed; 0: off (older sidecars)
    approach_tolerance: float = 0.3  # m: how near the goal the final approach's drive must pass
    peak_rank: int = 0  # the peak check's reference: 0 the neighbours' median (older sidecars), k the k-th highest
    peak_min_known: int = 7  # neighbours that must be known for the peak check to judge a cell (older sidecars: 7)
    smooth_roughness: float = 0.0  # m: ground this smooth lowers the obstacle limit; 0: off (older sidecars)
    smooth_obstacle_height: float = 0.0  # m: the obstacle limit on smooth ground
    smooth_radius: float = 3.0  # m: the ground around the rover that roughness is judged on
    detour_after: int = 0  # decisions without progress before the detour drives; 0: off (older sidecars)
    detour_progress: float = 0.5  # m nearer the goal than ever that count as progress
    detour_margin: float = 10.0  # m around the rover and the goal that the detour's search covers
    relief: bool = False  # the relief check (diana_lab.shield.relief) on the map's mean layer; off (older sidecars)
    relief_slope_deg: float = 22.0  # a footprint plane steeper than this is a hazard
    relief_step: float = 0.08  # m: a de-tilted step between neighbouring footprint cells over this is one
    relief_roughness: float = 0.065  # m RMS about the footprint plane over this is one
    relief_min_known: int = 8  # footprint cells that must be known for a cell to be judged
    relief_unseen_from: float = 0.0  # m along a drive beyond which a cell the check cannot judge vetoes it; 0: off
    route: bool = False  # the route rule (diana_lab.shield.detour): off (older sidecars)
    route_tolerance: float = 1.0  # m over the least length + cost to go that a drive open to the policy may cost
    slope_cost_weight: float = (
        0.0  # the search's cost of slope (diana_lab.shield.detour.SlopeCost); 0: off (older sidecars)
    )
    slope_cost_from_deg: float = 15.0
    slope_cost_to_deg: float = 22.0
    # m: the site map's cells the search was evaluated with (diana_lab.shield.site_map); 0: none (older sidecars).
    # Onboard the Navigator is handed the map itself; this says one is expected.
    site_map_cell: float = 0.0

    @classmethod
    def from_config(cls, cfg: ShieldConfig, robot: RobotConfig) -> ShieldSettings:
        return cls(
            limit_deg=float(cfg.limit_deg),
            top_k=int(cfg.top_k),
            cell_size=float(cfg.cell_size),
            spacing=float(cfg.spacing),
            radius=float(cfg.radius),
            half_base=(max(robot.axle_x) - min(robot.axle_x)) / 2.0,
            half_track=float(robot.track_width) / 2.0,
            hazard_radius=float(cfg.hazard_radius),
            obstacle_height=float(cfg.obstacle_height),
            footprint_radius=float(robot.radius),
            min_range=float(cfg.min_range),
            revisit_radius=float(cfg.revisit_radius),
            peak_height=float(cfg.peak_height),
            approach_radius=float(cfg.approach_radius),
            approach_tolerance=float(cfg.approach_tolerance),
            peak_rank=int(cfg.peak_rank),
            peak_min_known=int(cfg.peak_min_known),
            smooth_roughness=float(cfg.smooth_roughness),
            smooth_obstacle_height=float(cfg.smooth_obstacle_height),
            smooth_radius=float(cfg.smooth_radius),
            detour_after=int(cfg.detour_after),
            detour_progress=float(cfg.detour_progress),
            detour_margin=float(cfg.detour_margin),
            relief=bool(cfg.relief),
            relief_slope_deg=float(cfg.relief_slope_deg),
            relief_step=float(cfg.relief_step),
            relief_roughness=float(cfg.relief_roughness),
            relief_min_known=int(cfg.relief_min_known),
            relief_unseen_from=float(cfg.relief_unseen_from),
            route=bool(cfg.route),
            route_tolerance=float(cfg.route_tolerance),
            slope_cost_weight=float(cfg.slope_cost_weight),
            slope_cost_from_deg=float(cfg.slope_cost_from_deg),
            slope_cost_to_deg=float(cfg.slope_cost_to_deg),
            site_map_cell=float(cfg.site_map_cell),
        )

    @classmethod
    def from_dict(cls, node: dict[str, Any]) -> ShieldSettings:
        return cls(**node)

    def __post_init__(self) -> None:
        if not (0.0 < self.limit_deg < 90.0 and self.top_k >= 1 and self.spacing > 0):
            raise ValueError(f"ShieldSettings: expected 0 < limit_deg < 90, top_k >= 1, spacing > 0, got {self}")
        if not (self.half_base > 0 and self.half_track > 0):
            raise ValueError(f"ShieldSettings: expected a positive wheelbase and track, got {self}")
        if not self.min_range >= 0:
            raise ValueError(f"ShieldSettings: expected min_range >= 0, got {self.min_range}")
        if not self.revisit_radius >= 0:
            raise ValueError(f"ShieldSettings: expected revisit_radius >= 0, got {self.revisit_radius}")
        if not self.peak_height >= 0 or (self.peak_height > 0 and not self.footprint_radius > 0):
            raise ValueError(
                "ShieldSettings: expected peak_height >= 0 and, with it, a positive footprint_radius, got "
                f"{self.peak_height}, {self.footprint_radius}"
            )
        if not (0 <= self.peak_rank <= 8 and 1 <= self.peak_min_known <= 8):
            raise ValueError(
                "ShieldSettings: expected peak_rank in 0..8 and peak_min_known in 1..8, got "
                f"{self.peak_rank}, {self.peak_min_known}"
            )
        if not (self.approach_radius >= 0 and self.approach_tolerance > 0):
            raise ValueError(
                "ShieldSettings: expected approach_radius >= 0 and approach_tolerance > 0, got "
                f"{self.approach_radius}, {self.approach_tolerance}"
            )
        if not self.hazard_radius >= 0:
            raise ValueError(f"ShieldSettings: expected hazard_radius >= 0, got {self.hazard_radius}")
        if not (self.obstacle_height >= 0 and (self.obstacle_height == 0 or self.footprint_radius > 0)):
            raise ValueError(
                "ShieldSettings: expected obstacle_height >= 0 and, with it, a positive footprint_radius, got "
                f"{self.obstacle_height}, {self.footprint_radius}"
            )
        if not (
            self.smooth_roughness >= 0
            and self.smooth_radius > 0
            and (self.smooth_roughness == 0 or 0 < self.smooth_obstacle_height < self.obstacle_height)
        ):
            raise ValueError(
                "ShieldSettings: expected smooth_roughness >= 0, a positive smooth_radius and, with smooth_roughness, "
                "0 < smooth_obstacle_height < obstacle_height, got "
                f"{self.smooth_roughness}, {self.smooth_radius}, {self.smooth_obstacle_height}, "
                f"{self.obstacle_height}"
            )
        if not (self.detour_after >= 0 and self.detour_progress > 0 and self.detour_margin > 0):
            raise ValueError(
                "ShieldSettings: expected detour_after >= 0, a positive detour_progress and detour_margin, got "
                f"{self.detour_after}, {self.detour_progress}, {self.detour_margin}"
            )
        if not self.relief_unseen_from >= 0:
            raise ValueError(
                f"ShieldSettings: expected relief_unseen_from >= 0 m (0: off), got {self.relief_unseen_from}"
            )
        if not self.site_map_cell >= 0 or (self.site_map_cell > 0 and not (self.detour_after > 0 or self.route)):
            raise ValueError(
                "ShieldSettings: expected site_map_cell >= 0 m and, with it, a search to read the map (detour_after "
                f"> 0 or route), got {self.site_map_cell}, {self.detour_after}, {self.route}"
            )
        if not self.route_tolerance >= 0:
            raise ValueError(f"ShieldSettings: expected route_tolerance >= 0 m, got {self.route_tolerance}")
        self.relief_limits()  # raises for bad relief settings
        self.slope_cost()  # and for a bad slope cost

    def relief_limits(self) -> ReliefLimits | None:
        """The relief check's limits (:mod:`diana_lab.shield.relief`), on a footprint :data:`RELIEF_MARGIN` wider
        than the rover's; None with the check off."""
        if not self.relief:
            return None
        try:
            return ReliefLimits(
                self.relief_slope_deg,
                self.relief_step,
                self.relief_roughness,
                self.footprint_radius + RELIEF_MARGIN,
                self.relief_min_known,
            )
        except ValueError as exc:
            raise ValueError(f"ShieldSettings: the relief check's settings: {exc}") from exc

    def slope_cost(self) -> SlopeCost:
        """The search's cost of slope (:class:`~diana_lab.shield.detour.SlopeCost`; weight 0: none)."""
        try:
            return SlopeCost(self.slope_cost_weight, self.slope_cost_from_deg, self.slope_cost_to_deg)
        except ValueError as exc:
            raise ValueError(f"ShieldSettings: the search's slope cost: {exc}") from exc
