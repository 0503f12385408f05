"""The rules that may choose a drive before the slope shield's veto checks, by name (``eval.shield.rules``).

:meth:`diana_lab.shield.slope_shield.SlopeShield.choose` asks each rule its settings name, in their order; the first
to return a candidate decides, and if none does the policy's first allowed candidate is driven. A rule is a function
``fn(shield, decision) -> index into decision.offsets | None``; add one with :func:`register_rule` and name it in
``eval.shield.rules`` (the sidecar carries the list, so the onboard runtime must register it too).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the shield passes itself; importing it here would be a cycle
    from diana_lab.shield.slope_shield import SlopeShield

__all__ = ["RULES", "Decision", "Rule", "register_rule"]


@dataclass(frozen=True)
class Decision:
    """One decision's inputs, as every rule sees them."""

    offsets: np.ndarray  # (K, 2) world-frame drives of the policy's top_k candidates, most probable first
    start: np.ndarray  # (2,) the rover's world xy
    goal: np.ndarray | None  # (2,) the goal's world xy; None where the caller gave none
    fresh: np.ndarray  # (K,) bool: the drive ends away from every place the rover stood (the place rule)
    stalled: bool  # no progress towards the goal for detour_after decisions


Rule = Callable[["SlopeShield", Decision], "int | None"]
RULES: dict[str, Rule] = {}


def register_rule(name: str) -> Callable[[Rule], Rule]:
    """Register ``fn`` under ``name`` for ``eval.shield.rules``; a name taken already is refused."""

    def add(fn: Rule) -> Rule:
        if name in RULES:
            raise ValueError(f"register_rule: a shield rule named {name!r} exists already ({RULES[name]})")
        RULES[name] = fn
        return fn

    return add


@register_rule("approach")
def approach(shield: SlopeShield, d: Decision) -> int | None:
    """The goal within ``approach_radius``: the shortest drive passing near it, if the checks allow it."""
    if d.goal is None or shield.cfg.approach_radius <= 0:
        return None
    j = shield.approach(d.offsets, d.start, d.goal)
    shield.approaches += j is not None
    return j


@register_rule("detour")
def detour(shield: SlopeShield, d: Decision) -> int | None:
    """Stalled (``detour_after``): the allowed drive of least length + cost to go over the shield's map."""
    if not d.stalled:
        return None
    j = shield.detour.choose(shield, d.offsets, d.start, d.goal, d.fresh)
    shield.detours += j is not None
    return j


@register_rule("route")
def route(shield: SlopeShield, d: Decision) -> int | None:
    """``route``: the policy's most probable of the allowed drives on a near-least-cost way to the goal."""
    if not shield.cfg.route or d.goal is None:
        return None
    j = shield.detour.route(shield, d.offsets, d.start, d.goal, d.fresh, shield.cfg.route_tolerance)
    shield.routes += j is not None and j != 0  # turned from the policy's choice
    return j
