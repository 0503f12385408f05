"""The slope shield's settings as plain values, checked when they are built.

Why a module of its own: the simulator builds them from ``eval.shield`` and the robot's geometry
(:meth:`ShieldSettings.from_config`), the exporter writes them into the sidecar and the onboard runtime reads them
back (:meth:`ShieldSettings.from_dict`, numpy only). Checking them here means a bad sidecar is refused when it is
read, naming the bad key, not when the rover first decides. The keys themselves are defined once, in
:class:`diana_lab.core.shield_rules.ShieldRules`.
"""

from __future__ import annotations

from dataclasses import MISSING, dataclass, fields
from typing import TYPE_CHECKING, Any

from diana_lab.core.shield_rules import ShieldRules
from diana_lab.core.validation import ConfigError
from diana_lab.shield.detour import SlopeCost
from diana_lab.shield.relief import ReliefLimits
from diana_lab.shield.rules import RULES

if TYPE_CHECKING:  # numpy only at run time: the onboard runtime imports this module without Hydra
    from diana_lab.config.sim import RobotConfig

__all__ = ["RELIEF_MARGIN", "ShieldSettings"]

# the relief check: a footprint this much wider than the rover's (m; the cost map judges a cell by the ground
# round it, and a wheel meets a step before the body's circle does)
RELIEF_MARGIN = 0.1


def known_rules(key: str, names: list[str]) -> None:
    """Refuse, naming ``key``, a rule name :mod:`diana_lab.shield.rules` has no function for."""
    unknown = [name for name in names if name not in RULES]
    if unknown:
        raise ConfigError(
            f"{key}: unknown rules {unknown}; expected names of {sorted(RULES)} "
            "(diana_lab.shield.register_rule adds one)"
        )


@dataclass(kw_only=True)
class ShieldSettings(ShieldRules):
    """What the shield needs: its rules (:class:`ShieldRules`, from ``eval.shield`` or the sidecar's ``shield``
    node) and the robot's geometry."""

    half_base: float  # half the distance between the outermost axles (m)
    half_track: float  # half the track width (m)
    footprint_radius: float = 0.0  # m: the rover's footprint, what the obstacle and peak checks search

    @classmethod
    def from_config(cls, cfg: ShieldRules, robot: RobotConfig) -> ShieldSettings:
        """``eval.shield`` (or any :class:`ShieldRules`) and the robot's geometry."""
        rules = {f.name: getattr(cfg, f.name) for f in fields(ShieldRules)}
        rules["rules"] = list(rules["rules"])
        known_rules("eval.shield.rules", rules["rules"])
        return cls(
            **rules,
            half_base=(max(robot.axle_x) - min(robot.axle_x)) / 2.0,
            half_track=float(robot.track_width) / 2.0,
            footprint_radius=float(robot.radius),
        )

    @classmethod
    def from_dict(cls, node: dict[str, Any]) -> ShieldSettings:
        """A sidecar's ``shield`` node; a key it does not know, or a geometry key it lacks, is refused, naming it."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(node) - known)
        if unknown:
            raise ConfigError(f"shield: unknown keys {unknown}; expected keys of {sorted(known)}")
        required = {f.name for f in fields(cls) if f.default is MISSING and f.default_factory is MISSING}
        if missing := sorted(required - set(node)):
            raise ConfigError(f"shield: missing keys {missing} (the robot's geometry)")
        return cls(**node)

    def __post_init__(self) -> None:
        self.check_rules("shield")
        known_rules("shield.rules", self.rules)
        if not (self.half_base > 0 and self.half_track > 0):
            raise ValueError(f"ShieldSettings: expected a positive wheelbase and track, got {self}")
        for key in ("peak_height", "obstacle_height"):
            if getattr(self, key) > 0 and not self.footprint_radius > 0:
                raise ValueError(f"shield.{key}: needs the rover's footprint (a positive footprint_radius)")
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
