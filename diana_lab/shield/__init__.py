"""The slope shield: the rover's own map checks a learnt policy's waypoints before they are driven.

numpy only (the detour's search needs numba too), so the onboard runtime (:mod:`diana_lab.deploy`) runs the same
code as the simulator's evaluation:

* :mod:`~diana_lab.shield.settings`: :class:`ShieldSettings`, the plain values (``eval.shield`` or a sidecar),
  checked when built (its keys: :class:`diana_lab.core.shield_rules.ShieldRules`);
* :mod:`~diana_lab.shield.rules`: the rules that may decide before the veto checks, by name, and
  :func:`register_rule` for one of your own;
* :mod:`~diana_lab.shield.slope_shield`: :class:`SlopeShield`, its map, its checks of a drive and the choice
  among the policy's candidates (the place rule, fallback, final approach, detour and route rule);
* :mod:`~diana_lab.shield.relief`: the relief check (slope, steps and roughness under the footprint);
* :mod:`~diana_lab.shield.detour`: the detour and the route rule, a least-cost search over the shield's map;
* :mod:`~diana_lab.shield.site_map`: :class:`SiteMap`, a map of the site made before the drive, which the search
  reads where the shield's map gives no slope;
* :mod:`~diana_lab.core.grid_search`: that search (numba), which the A* experts share.
"""

from diana_lab.shield.detour import Detour, SlopeCost
from diana_lab.shield.rules import RULES, Decision, register_rule
from diana_lab.shield.settings import ShieldSettings
from diana_lab.shield.site_map import SiteMap
from diana_lab.shield.slope_shield import VETO_CHECKS, SlopeShield

__all__ = [
    "RULES",
    "VETO_CHECKS",
    "Decision",
    "Detour",
    "ShieldSettings",
    "SiteMap",
    "SlopeCost",
    "SlopeShield",
    "register_rule",
]
