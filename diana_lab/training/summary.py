"""The table printed when a run ends: what was trained, how fast, how well, and where to look next."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

__all__ = ["TrainResult", "summary_frame", "summary_text"]


@dataclass
class TrainResult:
    status: str  # FINISHED | KILLED | FAILED
    run_dir: Path
    algo: str
    num_timesteps: int
    wall_time_s: float
    fps: float  # env steps per second of this session's training (evaluations excluded)
    run_id: str | None = None
    tracking_uri: str | None = None
    eval_summary: dict[str, Any] = field(default_factory=dict)  # the final evaluation's summary
    best_spl: float = math.nan
    checkpoint: Path | None = None  # the newest checkpoint (what train.resume continues from)
    imitation_steps: int = 0  # env steps of the imitation stage (train.imitation), not in num_timesteps
    imitation_time_s: float = 0.0

    @property
    def model_path(self) -> Path:
        return self.run_dir / "model" / "model.zip"


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return "-" if not math.isfinite(value) else f"{value:.3g}"
    return str(value)


def summary_frame(r: TrainResult) -> pd.DataFrame:
    s = r.eval_summary
    rows: list[tuple[str, Any]] = [
        ("status", r.status),
        ("algo", r.algo),
        ("timesteps", r.num_timesteps),
        ("wall time (s)", round(r.wall_time_s, 1)),
        ("training FPS", round(r.fps, 1)),
    ]
    if r.imitation_steps:
        rows += [("imitation steps", r.imitation_steps), ("imitation time (s)", round(r.imitation_time_s, 1))]
    for key, label in (
        ("episodes", "eval episodes"),
        ("success_rate", "eval success rate"),
        ("spl", "eval SPL"),
        ("tipover_rate", "eval tip-over rate"),
        ("stuck_rate", "eval stuck rate"),
        ("timeout_rate", "eval timeout rate"),
        ("collision_rate", "eval collision rate"),
        ("mean_path_length_m", "eval path length (m)"),
    ):
        if key in s:
            rows.append((label, s[key]))
    rows += [("best eval SPL", r.best_spl), ("run dir", r.run_dir)]
    if r.status == "FINISHED":
        rows.append(("model", r.model_path))
    if r.checkpoint is not None:
        rows.append(("last checkpoint", r.checkpoint))
    if r.run_id:
        rows.append(("MLflow run id", r.run_id))
    return pd.DataFrame({"": [k for k, _ in rows], "value": [_fmt(v) for _, v in rows]})


def summary_text(r: TrainResult) -> str:
    lines = [summary_frame(r).to_string(index=False, header=False)]
    if r.tracking_uri:
        lines.append(f"dashboard: mlflow ui --backend-store-uri {r.tracking_uri}")
    if r.status == "KILLED" and r.checkpoint is not None:
        lines.append(f"continue:  python -m diana_lab train.resume={r.run_id or r.run_dir} <same overrides>")
    return "\n".join(lines)
