"""What a run knows about its Hydra launch: the output dir, the chosen option per group and the overrides.

Read from ``HydraConfig`` under ``python -m diana_lab``; tests and notebooks that compose a config without a
Hydra app pass a :class:`RunContext` of their own (any folder, no choices).

A caller that drives many runs (``python -m diana_lab.sweep``) also hands over hooks: ``parent_run_id`` nests
the MLflow run under its own (a study's trial), ``tags`` label it, and ``on_eval(step, summary)`` sees every
periodic evaluation -- it may raise :class:`StopRun` to end training early (pruning), which ends the run with
``StopRun.status`` instead of FAILED.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from diana_lab.tracking.names import TAG_GROUPS  # the groups tagged on a run (defined with the metric names)

__all__ = ["TAG_GROUPS", "EvalHook", "RunContext", "StopRun"]

EvalHook = Callable[[int, dict[str, Any]], None]  # (timesteps, evaluation summary)


class StopRun(Exception):
    """Raised by a hook to end training early on purpose (e.g. a pruned sweep trial): the run is cleaned up
    and its MLflow run ends with :attr:`status` rather than FAILED; the exception then propagates, with the
    partial result attached as ``exc.result``."""

    status = "KILLED"


@dataclass(frozen=True)
class RunContext:
    run_dir: Path
    choices: dict[str, str] = field(default_factory=dict)  # group -> option, e.g. {"algo": "ppo"}
    overrides: tuple[str, ...] = ()  # the command line's task overrides
    job_num: int | None = None  # index of the job in a multirun
    parent_run_id: str | None = None  # nest the MLflow run under this run (tag mlflow.parentRunId)
    tags: Mapping[str, Any] = field(default_factory=dict)  # extra MLflow tags of the run
    on_eval: EvalHook | None = None  # called after every periodic evaluation (may raise StopRun)

    @classmethod
    def from_hydra(cls) -> RunContext:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        from diana_lab.hydra_run import task_overrides

        hc = HydraConfig.get()
        choices = {g: str(v) for g, v in hc.runtime.choices.items() if g in TAG_GROUPS and v is not None}
        job_num = int(hc.job.num) if hc.mode == RunMode.MULTIRUN else None
        return cls(Path(hc.runtime.output_dir), choices, tuple(task_overrides()), job_num)

    @property
    def override_string(self) -> str:
        return " ".join(self.overrides)
