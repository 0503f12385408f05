"""``train.resume``: find the checkpoint a run continues from, and the MLflow run it keeps logging to.

Accepted: an MLflow run id (its Hydra run dir's newest checkpoint when that dir still exists, else the
newest checkpoint artefact, downloaded), a Hydra run dir (its ``checkpoints/``, else ``model/``), a
checkpoints dir, or a model ``.zip``. A run dir's ``run_info.json`` names its MLflow run, so resuming from a
path also continues the same MLflow run when the store is the same.
"""

from __future__ import annotations

import json
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from diana_lab.cli import UserError
from diana_lab.training.checkpoints import MODEL_RE, Checkpoint, latest_checkpoint

__all__ = ["RUN_INFO", "ResumePoint", "find_resume_point", "read_run_info", "write_run_info"]

RUN_INFO = "run_info.json"
RUN_ID = re.compile(r"^[0-9a-f]{32}$")


@dataclass(frozen=True)
class ResumePoint:
    checkpoint: Checkpoint  # ``steps`` is -1 for a plain model.zip (read from the model)
    run_id: str | None  # the MLflow run to continue, if known
    algo: str | None  # the algorithm the checkpoint was trained with, if known
    source: str  # for messages


def write_run_info(run_dir: Path, info: dict[str, Any]) -> None:
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / RUN_INFO).write_text(json.dumps(info, indent=2))


def read_run_info(run_dir: Path) -> dict[str, Any]:
    path = run_dir / RUN_INFO
    try:
        return json.loads(path.read_text()) if path.is_file() else {}
    except (OSError, ValueError):
        return {}


def _from_model_zip(path: Path) -> Checkpoint:
    m = MODEL_RE.match(path.name)
    if m:
        return Checkpoint.at(path.parent, int(m.group(1)))
    vecnorm = path.parent / "vecnormalize.pkl"
    return Checkpoint(-1, path, vecnorm if vecnorm.is_file() else None, None)


def _from_dir(directory: Path) -> Checkpoint | None:
    for d in (directory / "checkpoints", directory):
        found = latest_checkpoint(d)
        if found is not None:
            return found
    for model in (directory / "model" / "model.zip", directory / "model.zip"):
        if model.is_file():
            return _from_model_zip(model)
    return None


def _from_path(path: Path, uri: str | None) -> ResumePoint:
    ckpt = _from_model_zip(path) if path.is_file() else _from_dir(path)
    if ckpt is None:
        raise UserError(
            f"train.resume: no checkpoint (checkpoints/rl_model_<steps>_steps.zip) or model/model.zip under '{path}'"
        )
    if not zipfile.is_zipfile(ckpt.model):  # now, not once the resumed MLflow run is open
        raise UserError(f"train.resume: '{ckpt.model}' is not a Stable-Baselines3 model archive (not a zip file)")
    info: dict[str, Any] = {}
    for d in (path, path.parent, path.parent.parent):
        info = read_run_info(d)
        if info:
            break
    same_store = uri is not None and info.get("tracking_uri") == uri
    return ResumePoint(ckpt, info.get("mlflow_run_id") if same_store else None, info.get("algo"), str(path))


def _from_run(run_id: str, uri: str, download_dir: Path) -> ResumePoint:
    from mlflow.exceptions import MlflowException
    from mlflow.tracking import MlflowClient

    client = MlflowClient(uri)
    try:
        run = client.get_run(run_id)
    except MlflowException as exc:
        raise UserError(
            f"train.resume={run_id}: not a run dir or checkpoint path, and no MLflow run with this id in "
            f"'{uri}' (check tracking.uri)"
        ) from exc
    tags = run.data.tags
    local = Path(tags["run_dir"]) if tags.get("run_dir") else None
    if local is not None and (ckpt := _from_dir(local)) is not None:
        return ResumePoint(ckpt, run_id, tags.get("algo"), f"run {run_id} ({local})")
    names = [Path(a.path).name for a in client.list_artifacts(run_id, "checkpoints")]
    steps = [int(m.group(1)) for n in names if (m := MODEL_RE.match(n))]
    if not steps:
        raise UserError(f"train.resume={run_id}: the run has no checkpoint artefact and its run dir '{local}' is gone")
    best = max(steps)
    download_dir.mkdir(parents=True, exist_ok=True)
    for name in names:
        if name.endswith(f"_{best}_steps.zip") or name.endswith(f"_{best}_steps.pkl"):
            client.download_artifacts(run_id, f"checkpoints/{name}", str(download_dir))
    return ResumePoint(
        Checkpoint.at(download_dir / "checkpoints", best),
        run_id,
        tags.get("algo"),
        f"run {run_id} (downloaded checkpoint)",
    )


def find_resume_point(spec: str, uri: str | None, download_dir: Path) -> ResumePoint:
    """Resolve ``train.resume`` (see the module docstring); ``uri``: the tracking URI, ``None`` when off."""
    path = Path(spec).expanduser()
    if path.exists():
        return _from_path(path.resolve(), uri)
    if RUN_ID.match(spec) and uri is not None:
        return _from_run(spec, uri, download_dir)
    hint = "" if uri is not None else " (MLflow run ids need tracking.enabled=true)"
    raise UserError(
        f"train.resume={spec}: expected an MLflow run id, a Hydra run dir or a checkpoint .zip; no such path{hint}"
    )
