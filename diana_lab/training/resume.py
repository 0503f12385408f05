"""``train.resume``: find the checkpoint a run continues from, and the MLflow run it keeps logging to.

Accepted: an MLflow run id (its Hydra run dir's newest checkpoint when that dir still exists, else the
newest checkpoint artefact, downloaded), a Hydra run dir (its ``checkpoints/``, else ``model/``), a
checkpoints dir, or a model ``.zip``. A run dir's ``run_info.json`` names its MLflow run, so resuming from a
path also continues the same MLflow run when the store is the same -- unless that run has a newer checkpoint
than the one resumed (it was resumed and trained on since): its logged history would then be overwritten from an
older point, so training goes on in a new MLflow run tagged ``branched_from`` instead.

:func:`check_resumable` compares the env the run continues in with the one it was trained in (its
``.hydra/config.yaml``): other observations or actions are an error naming the config keys that differ (and
the training's overrides to repeat, from the ``.hydra/overrides.yaml`` beside it), other settings (reward,
world, dynamics...) are allowed -- fine-tuning elsewhere is a use -- but reported.
"""

from __future__ import annotations

import contextlib
import json
import re
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
from omegaconf import DictConfig, OmegaConf

from diana_lab.config import GROUPS
from diana_lab.errors import UserError
from diana_lab.evaluation.compatibility import config_differences, recorded_overrides, rerun_advice
from diana_lab.training.checkpoints import MODEL_RE, Checkpoint, latest_checkpoint

__all__ = [
    "RUN_INFO",
    "ResumePoint",
    "check_resumable",
    "find_resume_point",
    "newest_checkpoint_steps",
    "read_run_info",
    "write_run_info",
]

RUN_INFO = "run_info.json"
CONFIG = ".hydra/config.yaml"  # the training's composed config, in its run dir and among its MLflow artefacts
OVERRIDES = ".hydra/overrides.yaml"  # its command line's overrides, beside it
RUN_ID = re.compile(r"^[0-9a-f]{32}$")


@dataclass(frozen=True)
class ResumePoint:
    checkpoint: Checkpoint  # ``steps`` is -1 for a plain model.zip (read from the model)
    run_id: str | None  # the MLflow run to continue, if known
    algo: str | None  # the algorithm the checkpoint was trained with, if known
    source: str  # for messages
    config: Path | None = None  # the training's .hydra/config.yaml, if known
    changes: tuple[str, ...] = ()  # the env settings that differ from the training's (check_resumable's)
    branched_from: str | None = None  # the MLflow run a stale checkpoint came from (continued in a new run)


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
    config = next((c for d in (path, path.parent, path.parent.parent) if (c := d / CONFIG).is_file()), None)
    return ResumePoint(ckpt, info.get("mlflow_run_id") if same_store else None, info.get("algo"), str(path), config)


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
        config = local / CONFIG if (local / CONFIG).is_file() else None
        return ResumePoint(ckpt, run_id, tags.get("algo"), f"run {run_id} ({local})", config)
    names = [Path(a.path).name for a in client.list_artifacts(run_id, "checkpoints")]
    steps = [int(m.group(1)) for n in names if (m := MODEL_RE.match(n))]
    if not steps:
        raise UserError(f"train.resume={run_id}: the run has no checkpoint artefact and its run dir '{local}' is gone")
    best = max(steps)
    # into checkpoints/ of their own: download_artifacts puts a file artefact in the folder it is given
    ckpt_dir = download_dir / "checkpoints"
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    for name in names:
        if name.endswith(f"_{best}_steps.zip") or name.endswith(f"_{best}_steps.pkl"):
            client.download_artifacts(run_id, f"checkpoints/{name}", str(ckpt_dir))
    config = None
    with contextlib.suppress(MlflowException, OSError):  # a run logged without its .hydra/: nothing to compare
        config = Path(client.download_artifacts(run_id, CONFIG, str(download_dir)))
        client.download_artifacts(run_id, OVERRIDES, str(download_dir))  # beside it, for check_resumable's advice
    return ResumePoint(
        Checkpoint.at(ckpt_dir, best),
        run_id,
        tags.get("algo"),
        f"run {run_id} (downloaded checkpoint)",
        config,
    )


def newest_checkpoint_steps(run_id: str, uri: str) -> int | None:
    """The most steps of any checkpoint MLflow run ``run_id`` has: in its run dir (its ``run_dir`` tag, the
    latest folder it trained in) or among its artefacts; ``None`` if it has none or cannot be read."""
    from mlflow.exceptions import MlflowException
    from mlflow.tracking import MlflowClient

    client = MlflowClient(uri)
    try:
        run = client.get_run(run_id)
        names = [Path(a.path).name for a in client.list_artifacts(run_id, "checkpoints")]
    except MlflowException:
        return None
    steps = [int(m.group(1)) for n in names if (m := MODEL_RE.match(n))]
    local = run.data.tags.get("run_dir")
    if local and (found := latest_checkpoint(Path(local) / "checkpoints")) is not None:
        steps.append(found.steps)
    return max(steps, default=None)


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


def check_resumable(
    resume: ResumePoint,
    cfg: DictConfig,
    observation_space: gym.Space,
    action_space: gym.Space,
    overrides: Sequence[str] = (),
) -> list[str]:
    """Refuse to continue ``resume``'s model in ``cfg``'s env, whose spaces are given, when its observation or
    action space differs (SB3 would refuse too, after the MLflow run is open and without saying which setting
    changed), ending with the training's overrides that ``overrides``, this command line's, lacks; return the
    config keys of the env groups that differ from the training's (``reward.weights.goal: training 10.0, here
    20.0``)."""
    from stable_baselines3.common.save_util import load_from_zip_file

    train_cfg = OmegaConf.load(resume.config) if resume.config is not None else None
    diffs = config_differences(train_cfg, cfg, GROUPS)
    data, _, _ = load_from_zip_file(resume.checkpoint.model, load_data=True, device="cpu")
    assert data is not None
    for kind, saved, here in (
        ("observation", data.get("observation_space"), observation_space),
        ("action", data.get("action_space"), action_space),
    ):
        if saved is not None and saved != here:  # SB3's own rule: equal spaces, bounds included
            if isinstance(saved, gym.spaces.Dict) and isinstance(here, gym.spaces.Dict):
                shown = "; ".join(
                    f"'{k}' {saved.spaces.get(k)} there, {here.spaces.get(k)} here"
                    for k in sorted(set(saved.spaces) | set(here.spaces))
                    if saved.spaces.get(k) != here.spaces.get(k)
                )
            else:
                shown = f"{saved} there, {here} here"
            keys = f" Differing config keys: {'; '.join(diffs[:8])}." if diffs else ""
            advice = rerun_advice(recorded_overrides(resume.config), overrides) if train_cfg is not None else ""
            raise UserError(
                f"train.resume: {resume.source} was trained on another {kind} space than this config gives "
                f"({shown}); continue it with the settings it was trained with.{keys}"
                + (f" {advice}" if advice else "")
            )
    return diffs
