"""A scorecard: several policies on several evaluation suites, checked against targets.

A research target reads "on the Mars yard, success >= 0.95; in physics, tip-over <= 0.03; with sensor noise, at
most 5 points lower than without; and clearly better than ``bearing`` behind the same check". The card holds
those as data (``conf/scorecard.yaml``): *conditions* (a suite: overrides of the env and ``eval`` groups, and the
targets of the policy under test there), *entries* (what is evaluated on every condition: the policy under test
bare or behind a check, and the baselines beside it) and *comparisons* (an entry that must beat another). This
module parses and checks them; :mod:`diana_lab.scorecard` runs the evaluations.

A target is ``"<op> <number>"`` (``">= 0.95"``, ``"<= 0"``) or ``"<op> <condition> <+|-> <number>"``: the bound is
the same entry's value of the key on another condition, moved by the number (``">= yard - 0.05"``: at most 5
points under its yard figure). ``op`` is ``>=`` or ``<=``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from diana_lab.core.validation import ConfigError

__all__ = ["Comparison", "Condition", "Entry", "Target", "check", "compare", "parse_card"]

_TARGET = re.compile(r"^\s*(>=|<=)\s*(?:([A-Za-z_][\w-]*)\s*([+-])\s*)?([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*$")


@dataclass(frozen=True)
class Target:
    """``key`` (a summary key) ``op`` the bound: ``value``, or ``relative_to``'s value of ``key`` plus ``value``."""

    key: str
    op: str
    value: float
    relative_to: str | None = None
    text: str = ""

    def bound(self, summaries: Mapping[str, Mapping[str, Any]]) -> float:
        """The bound for one entry, given its summaries by condition (NaN where the reference is missing)."""
        if self.relative_to is None:
            return self.value
        ref = summaries.get(self.relative_to, {}).get(self.key)
        return math.nan if ref is None else float(ref) + self.value

    def met(self, value: float, bound: float) -> bool:
        if not (math.isfinite(value) and math.isfinite(bound)):
            return False
        return value >= bound - 1e-12 if self.op == ">=" else value <= bound + 1e-12


@dataclass(frozen=True)
class Condition:
    """One suite: ``overrides`` laid over the command line's, and the policy under test's ``targets`` there."""

    name: str
    overrides: tuple[str, ...]
    targets: tuple[Target, ...]


@dataclass(frozen=True)
class Entry:
    """What runs on every condition: ``overrides`` over the command line's (an entry without ``policy=`` runs
    the command line's policy); ``scored`` entries are checked against the conditions' targets."""

    name: str
    overrides: tuple[str, ...]
    scored: bool


@dataclass(frozen=True)
class Comparison:
    """``entry`` must beat ``over`` on ``key`` (higher is better) on every condition: their 95 % intervals apart."""

    entry: str
    over: str
    key: str


def parse_target(where: str, key: str, spec: Any, conditions: Sequence[str]) -> Target:
    """One target of ``where`` (``conditions.<name>.targets``); a malformed one names its key."""
    m = _TARGET.match(str(spec))
    if m is None:
        raise ConfigError(
            f"{where}.{key}: expected '>= <number>', '<= <number>' or '>= <condition> - <number>', got {spec!r}"
        )
    op, ref, sign, number = m.groups()
    value = float(number)
    if ref is not None:
        if ref not in conditions:
            known = list(conditions)
            raise ConfigError(f"{where}.{key}: {spec!r} refers to condition {ref!r}; expected one of {known}")
        value = -value if sign == "-" else value
    return Target(key=key, op=op, value=value, relative_to=ref, text=str(spec).strip())


def _overrides(where: str, node: Any) -> tuple[str, ...]:
    if node is None:
        return ()
    if isinstance(node, str) or not isinstance(node, Sequence):
        raise ConfigError(f"{where}: expected a list of overrides (e.g. [shield=veto]), got {node!r}")
    return tuple(str(o) for o in node)


def _mapping(where: str, node: Any) -> Mapping[str, Any]:
    if not isinstance(node, Mapping) or not node:
        raise ConfigError(f"{where}: expected a non-empty mapping, got {node!r}")
    return node


def _select(where: str, names: Any, known: Sequence[str]) -> list[str]:
    if names is None:
        return list(known)
    chosen = [str(n) for n in ([names] if isinstance(names, str) else names)]
    for n in chosen:
        if n not in known:
            raise ConfigError(f"{where}: no {n!r}; expected some of {list(known)}")
    if not chosen:
        raise ConfigError(f"{where}: expected at least one of {list(known)}")
    return chosen


def parse_card(
    conditions: Any, entries: Any, comparisons: Any = None, only_conditions: Any = None, only_entries: Any = None
) -> tuple[list[Condition], list[Entry], list[Comparison]]:
    """The card's parts from plain containers (``conf/scorecard.yaml``), restricted to ``only_*`` (None: all).
    A relative target whose reference condition is left out, a comparison with an entry left out or an unknown
    name is an error naming its key."""
    cond_nodes = _mapping("conditions", conditions)
    entry_nodes = _mapping("entries", entries)
    run_conditions = _select("only.conditions", only_conditions, list(cond_nodes))
    run_entries = _select("only.entries", only_entries, list(entry_nodes))
    parsed_conditions = []
    for name in run_conditions:
        node = cond_nodes[name] or {}
        where = f"conditions.{name}"
        targets = tuple(
            parse_target(f"{where}.targets", k, v, list(cond_nodes)) for k, v in (node.get("targets") or {}).items()
        )
        for t in targets:
            if t.relative_to is not None and t.relative_to not in run_conditions:
                raise ConfigError(
                    f"{where}.targets.{t.key}: {t.text!r} needs condition {t.relative_to!r}, which is not run; "
                    f"add it to only.conditions"
                )
        parsed_conditions.append(Condition(name, _overrides(f"{where}.overrides", node.get("overrides")), targets))
    parsed_entries = [
        Entry(
            name,
            _overrides(f"entries.{name}.overrides", (entry_nodes[name] or {}).get("overrides")),
            bool((entry_nodes[name] or {}).get("scored", False)),
        )
        for name in run_entries
    ]
    parsed_comparisons = []
    for i, node in enumerate(comparisons or []):
        where = f"comparisons[{i}]"
        try:
            comp = Comparison(str(node["entry"]), str(node["over"]), str(node.get("key", "success_rate")))
        except (KeyError, TypeError) as exc:
            shape = "{entry: <name>, over: <name>, key: <summary key>}"
            raise ConfigError(f"{where}: expected {shape}, got {node!r}") from exc
        missing = [n for n in (comp.entry, comp.over) if n not in entry_nodes]
        if missing:
            raise ConfigError(f"{where}: no entry {missing[0]!r}; expected one of {list(entry_nodes)}")
        if comp.entry in run_entries and comp.over in run_entries:
            parsed_comparisons.append(comp)
    return parsed_conditions, parsed_entries, parsed_comparisons


def check(
    conditions: Sequence[Condition], entries: Sequence[Entry], summaries: Mapping[str, Mapping[str, Mapping[str, Any]]]
) -> list[dict[str, Any]]:
    """One row per scored entry, condition and target: the value, the bound and whether it is met.
    ``summaries[entry][condition]`` is an evaluation summary (:func:`~diana_lab.evaluation.metrics.summarize`)."""
    rows = []
    for entry in (e for e in entries if e.scored):
        own = summaries.get(entry.name, {})
        for cond in (c for c in conditions if c.name in own):  # a failed evaluation has no figures to check
            for t in cond.targets:
                value = float(own[cond.name].get(t.key, math.nan))
                bound = t.bound(own)
                rows.append(
                    {
                        "entry": entry.name,
                        "condition": cond.name,
                        "key": t.key,
                        "target": t.text,
                        "bound": bound,
                        "value": value,
                        "met": t.met(value, bound),
                    }
                )
    return rows


def compare(
    conditions: Sequence[Condition],
    comparisons: Sequence[Comparison],
    summaries: Mapping[str, Mapping[str, Mapping[str, Any]]],
) -> list[dict[str, Any]]:
    """One row per comparison and condition: both values, their 95 % intervals (the summary's ``<key>_ci95``)
    and ``clearly``: the entry's interval lies wholly above the other's."""
    rows = []
    for comp in comparisons:
        for cond in conditions:
            a, b = summaries[comp.entry][cond.name], summaries[comp.over][cond.name]
            a_lo, _ = a.get(f"{comp.key}_ci95", (math.nan, math.nan))
            _, b_hi = b.get(f"{comp.key}_ci95", (math.nan, math.nan))
            rows.append(
                {
                    "entry": comp.entry,
                    "over": comp.over,
                    "condition": cond.name,
                    "key": comp.key,
                    "value": float(a.get(comp.key, math.nan)),
                    "other": float(b.get(comp.key, math.nan)),
                    "clearly": bool(math.isfinite(a_lo) and math.isfinite(b_hi) and a_lo > b_hi),
                }
            )
    return rows
