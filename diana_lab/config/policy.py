"""Config schemas of the ``policy`` group of ``python -m diana_lab.evaluate`` and ``python -m diana_lab.export``.

One option per evaluable policy (``conf/policy/<name>.yaml``): the classical baselines and planner experts with
their keys (``policy=astar policy.spacing=0.8``), ``pretrained`` (the shipped reference policy) and ``model``, a
trained policy named by ``policy.source`` (a model ``.zip``, a run folder, an MLflow run id or a registered model
version, ``models:/<name>/<version>`` or ``models:/<name>@<alias>``). ``policy=<path, run id or models:/...>`` is
read as ``policy=model policy.source=<it>`` (:func:`source_overrides`, which quotes it for Hydra's grammar).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from omegaconf import MISSING

from diana_lab.config.store import register
from diana_lab.core.validation import in_range, non_negative, positive

__all__ = [
    "AStarMemoryPolicyConfig",
    "AStarPolicyConfig",
    "BearingPolicyConfig",
    "SeenMapPolicyConfig",
    "StraightPolicyConfig",
    "TrainedPolicyConfig",
    "policy_options",
    "source_overrides",
]

TRAINED = "model"  # the option whose policy.source names a trained policy


@dataclass
class StraightPolicyConfig:
    _target_: str = "diana_lab.evaluation.policies.StraightLine"
    name: str = "straight"


@dataclass
class BearingPolicyConfig:
    _target_: str = "diana_lab.evaluation.policies.GoalBearing"
    name: str = "bearing"


@dataclass
class AStarPolicyConfig:
    """:class:`diana_lab.experts.AStarOracle`'s arguments (its docstring says what each does)."""

    _target_: str = "diana_lab.experts.AStarOracle"
    name: str = "astar"
    spacing: float = 0.95
    replan_distance: float = 0.5
    margin: float = 0.2
    obstacle_margin: float = 0.3
    snap: float = 1.0
    plain: bool = False
    receding: bool = False
    knowledge_radius: float | None = None
    knowledge_fov_deg: float | None = None
    knowledge_memory: bool = False

    def __post_init__(self) -> None:
        in_range("policy.spacing", self.spacing, 0.0, 1.0)
        positive("policy.spacing", self.spacing)
        positive("policy.replan_distance", self.replan_distance)
        for key in ("margin", "obstacle_margin", "snap"):
            non_negative(f"policy.{key}", getattr(self, key))
        if self.knowledge_radius is not None:
            positive("policy.knowledge_radius", self.knowledge_radius)
        if self.knowledge_fov_deg is not None:
            in_range("policy.knowledge_fov_deg", self.knowledge_fov_deg, 0.0, 360.0)
            positive("policy.knowledge_fov_deg", self.knowledge_fov_deg)


@dataclass
class AStarMemoryPolicyConfig(AStarPolicyConfig):
    name: str = "astar_memory"
    spacing: float = 0.8
    knowledge_radius: float | None = 12.0
    knowledge_memory: bool = True


@dataclass
class SeenMapPolicyConfig:
    """:class:`diana_lab.experts.SeenMapOracle`: needs ``sensor.elevation_map.memory=true``."""

    _target_: str = "diana_lab.experts.SeenMapOracle"
    name: str = "astar_seen"
    knowledge_radius: float = 12.0
    spacing: float = 0.8

    def __post_init__(self) -> None:
        positive("policy.knowledge_radius", self.knowledge_radius)
        in_range("policy.spacing", self.spacing, 0.0, 1.0)
        positive("policy.spacing", self.spacing)


@dataclass
class TrainedPolicyConfig:
    """A trained Stable-Baselines3 policy: ``policy.source`` is what to load."""

    name: str = TRAINED
    source: str = field(
        default=MISSING,
        metadata={
            "help": "a Stable-Baselines3 .zip, a run folder holding model/model.zip, an MLflow run id (32 hex "
            "digits), a registered model version (models:/<name>/<version> or models:/<name>@<alias>) or "
            "pretrained (e.g. policy=outputs/2026-12-06/12-00-00/model)"
        },
    )


register(
    "policy",
    {
        "straight": StraightPolicyConfig,
        "bearing": BearingPolicyConfig,
        "astar": AStarPolicyConfig,
        "astar_memory": AStarMemoryPolicyConfig,
        "astar_seen": SeenMapPolicyConfig,
        TRAINED: TrainedPolicyConfig,
        "pretrained": TrainedPolicyConfig,
    },
)


def policy_options(conf_dir: Path) -> list[str]:
    """The ``policy=`` options: the files of ``conf/policy/``."""
    return sorted(p.stem for p in (conf_dir / "policy").glob("*.yaml"))


def source_overrides(overrides: Sequence[str], conf_dir: Path) -> list[str]:
    """``overrides`` with ``policy=<value>`` that names no option of ``conf/policy/`` (a model path, a run folder,
    an MLflow run id) read as ``policy=model policy.source=<value>``; the rest unchanged."""
    options = set(policy_options(conf_dir))
    out: list[str] = []
    for item in overrides:
        key, sep, value = item.partition("=")
        if sep and key == "policy" and value and value not in options:
            out += [f"policy={TRAINED}", f"policy.source={_quoted(value)}"]
        else:
            out.append(item)
    return out


def _quoted(value: str) -> str:
    """A path Hydra's override grammar reads as one string (``:``, ``=``, spaces and brackets included)."""
    if value[:1] in "'\"" and value[-1:] == value[:1]:
        return value
    return "'" + value.replace("'", "\\'") + "'"
