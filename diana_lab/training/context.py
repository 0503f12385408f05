"""What a run knows about its Hydra launch: the output dir, the chosen option per group and the overrides.

Read from ``HydraConfig`` under ``python -m diana_lab``; tests and notebooks that compose a config without a
Hydra app pass a :class:`RunContext` of their own (any folder, no choices).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["TAG_GROUPS", "RunContext"]

# the config groups whose chosen option becomes an MLflow tag (filterable in the UI: tags.world = "mars_yard")
TAG_GROUPS = (
    "world",
    "robot",
    "dynamics",
    "sensor",
    "action_space",
    "reward",
    "episode",
    "algo",
    "experiment",
)


@dataclass(frozen=True)
class RunContext:
    run_dir: Path
    choices: dict[str, str] = field(default_factory=dict)  # group -> option, e.g. {"algo": "ppo"}
    overrides: tuple[str, ...] = ()  # the command line's task overrides
    job_num: int | None = None  # index of the job in a multirun

    @classmethod
    def from_hydra(cls) -> RunContext:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        hc = HydraConfig.get()
        choices = {g: str(v) for g, v in hc.runtime.choices.items() if g in TAG_GROUPS and v is not None}
        job_num = int(hc.job.num) if hc.mode == RunMode.MULTIRUN else None
        return cls(Path(hc.runtime.output_dir), choices, tuple(hc.overrides.task), job_num)

    @property
    def override_string(self) -> str:
        return " ".join(self.overrides)
