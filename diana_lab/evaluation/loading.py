"""Resolve the ``policy`` group of ``python -m diana_lab.evaluate`` (and of the export) into a :class:`Policy`.

The options (``conf/policy/<name>.yaml``, schemas in :mod:`diana_lab.config.policy`):

* ``straight``, ``astar`` (the whole map), ``astar_memory`` (what lay within 12 m of the rover so far: a DAgger
  expert) -- the classical baselines (:mod:`diana_lab.experts.oracle`), their keys settable
  (``policy=astar policy.spacing=0.8``);
* ``astar_seen`` -- ``astar_memory`` on the true cost maps, knowing only the cells the rover's own sensor map has hit
  (:mod:`diana_lab.experts.perceived`; needs ``sensor.elevation_map.memory``; the reference policy's DAgger
  expert);
* ``bearing`` -- the candidates of ``action_space=discrete`` ranked by the goal's bearing alone
  (:class:`~diana_lab.evaluation.policies.GoalBearing`): with ``eval.shield.enabled`` it drives behind the slope
  shield in the network's place, the non-learnt baseline of what the network adds there;
* ``model`` with ``policy.source`` (``policy=<source>`` for short):

  - a path to a Stable-Baselines3 ``.zip`` (or a folder holding ``model.zip``); a ``vecnormalize.pkl`` beside
    it is applied, and a ``.hydra/config.yaml`` beside it or one level up is read as the training config;
  - an MLflow run id (32 hex digits) of a training run, whose artefacts ``model/model.zip``,
    ``model/vecnormalize.pkl`` and ``.hydra/config.yaml`` are downloaded (the layout the runner logs);
  - a version of a registered model, ``models:/<name>/<version>`` or ``models:/<name>@<alias>``
    (``tracking.register_model``): the version's own files (the policy, its statistics and training config, in
    the MLflow model's ``policy`` artefact: :mod:`diana_lab.tracking.pyfunc_model`), its training run (the
    version's source run) recorded as the policy's run -- or, for a version registered from something else, that
    run's ``model/`` artefacts;
* ``pretrained`` -- the reference policy shipped in ``diana_lab/assets/policies/reference/`` (``model.zip``,
  its training config ``config.yaml`` and ``card.json``); evaluate it with ``+experiment=reference``, the
  preset it was trained with, so the env gives the observations it expects.

A model whose observation or action space differs from the env's is refused by the checks of
:mod:`diana_lab.evaluation.compatibility`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import re
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hydra.utils import get_object
from omegaconf import DictConfig, OmegaConf

from diana_lab.config import CONF_DIR, ConfigError, to_object
from diana_lab.config.policy import TRAINED, TrainedPolicyConfig, policy_options
from diana_lab.errors import UserError
from diana_lab.evaluation.compatibility import recorded_overrides
from diana_lab.evaluation.policies import GoalBearing, Policy, SB3Policy, ShieldedPolicy
from diana_lab.experts import check_perceivable

__all__ = [
    "POLICY_NAMES",
    "PRETRAINED_DIR",
    "LoadedPolicy",
    "load_policy",
    "load_sb3",
    "policy_config",
]

PRETRAINED_DIR = Path(__file__).resolve().parents[1] / "assets" / "policies" / "reference"
RUN_ID = re.compile(r"^[0-9a-f]{32}$")
REGISTRY = "models:/"
# models:/<name>/<version> or models:/<name>@<alias> (the names tracking.register_model accepts)
MODEL_VERSION = re.compile(r"models:/(?P<name>[^/@]+)(?:/(?P<version>[^/@]+)|@(?P<alias>[^/@]+))")
MODEL_ARTIFACT, VECNORM_ARTIFACT, CONFIG_ARTIFACT, OVERRIDES_ARTIFACT = (
    "model/model.zip",
    "model/vecnormalize.pkl",
    ".hydra/config.yaml",
    ".hydra/overrides.yaml",  # the training's command-line overrides, as Hydra writes them
)

# the module of a saved policy class -> the algorithm that loads it (on-policy actor-critics load as PPO:
# A2C and PPO share the policy and ``predict``)
ALGOS_BY_MODULE = {
    "stable_baselines3.sac": ("stable_baselines3", "SAC"),
    "stable_baselines3.td3": ("stable_baselines3", "TD3"),
    "stable_baselines3.ddpg": ("stable_baselines3", "TD3"),
    "stable_baselines3.dqn": ("stable_baselines3", "DQN"),
    "sb3_contrib.tqc": ("sb3_contrib", "TQC"),
    "sb3_contrib.common.recurrent": ("sb3_contrib", "RecurrentPPO"),
    "sb3_contrib.ppo_recurrent": ("sb3_contrib", "RecurrentPPO"),
    "sb3_contrib.trpo": ("sb3_contrib", "TRPO"),
    "sb3_contrib.ars": ("sb3_contrib", "ARS"),
}
ALGOS_BY_NAME = {
    "ppo": ("stable_baselines3", "PPO"),
    "a2c": ("stable_baselines3", "A2C"),
    "sac": ("stable_baselines3", "SAC"),
    "td3": ("stable_baselines3", "TD3"),
    "ddpg": ("stable_baselines3", "DDPG"),
    "tqc": ("sb3_contrib", "TQC"),
    "trpo": ("sb3_contrib", "TRPO"),
    "recurrent_ppo": ("sb3_contrib", "RecurrentPPO"),
    "recurrentppo": ("sb3_contrib", "RecurrentPPO"),
    "ppo_lstm": ("sb3_contrib", "RecurrentPPO"),
}


@dataclass
class LoadedPolicy:
    """A policy plus where it came from (for messages, MLflow tags and the training config)."""

    policy: Policy
    label: str  # "straight", "astar", the model path or "run <id>"
    run_id: str | None = None  # the MLflow training run, when the policy came from one
    train_cfg: DictConfig | None = None  # the training's resolved config, when known
    model: Any = None  # the SB3 model, when there is one
    note: str | None = None  # what a user should know about it (the shipped policy's card summary)
    train_overrides: list[str] | None = None  # the training's command-line overrides, when recorded


def _train_config(path: Path | None) -> DictConfig | None:
    return OmegaConf.load(path) if path is not None and path.is_file() else None


def _algo_class(model_zip: Path, train_cfg: DictConfig | None) -> type:
    """The SB3 algorithm class for a saved model: from the training config's ``algo`` when known, else from
    the module of the policy class recorded in the zip's ``data``."""
    import importlib

    target = OmegaConf.select(train_cfg, "algo._target_", default=None) if train_cfg is not None else None
    if isinstance(target, str) and "." in target:
        from hydra.utils import get_class

        with contextlib.suppress(Exception):
            return get_class(target)
    name = OmegaConf.select(train_cfg, "algo.name", default=None) if train_cfg is not None else None
    if isinstance(name, str) and name.lower() in ALGOS_BY_NAME:
        package, cls = ALGOS_BY_NAME[name.lower()]
        return getattr(importlib.import_module(package), cls)
    try:
        with zipfile.ZipFile(model_zip) as zf:
            data = json.loads(zf.read("data"))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
        raise UserError(f"policy: '{model_zip}' is not a Stable-Baselines3 model archive ({exc})") from exc
    module = str(data.get("policy_class", {}).get("__module__", ""))
    package, cls = next((v for k, v in ALGOS_BY_MODULE.items() if module.startswith(k)), ("stable_baselines3", "PPO"))
    return getattr(importlib.import_module(package), cls)


def load_sb3(
    model_zip: Path,
    vecnorm: Path | None = None,
    train_cfg: DictConfig | None = None,
    deterministic: bool = True,
    seed: int = 0,
) -> tuple[SB3Policy, Any]:
    """Load a saved SB3 model (and its VecNormalize statistics) as an :class:`SB3Policy`."""
    import pickle

    algo = _algo_class(model_zip, train_cfg)
    try:
        model = algo.load(str(model_zip), device="cpu")
    except Exception as exc:
        raise UserError(f"policy: could not load '{model_zip}' as a {algo.__name__} model ({exc})") from exc
    vn = None
    if vecnorm is not None and vecnorm.is_file():
        with open(vecnorm, "rb") as f:
            vn = pickle.load(f)  # VecNormalize without its venv: only its statistics are needed
        vn.training = False
    return SB3Policy(model, vn, deterministic=deterministic, seed=seed), model


def _vecnormalize_file(model_zip: Path, train_cfg: DictConfig | None) -> Path | None:
    """The observation statistics saved with ``model_zip``: a checkpoint's own
    (``rl_model_vecnormalize_<n>_steps.pkl``: the run's final ``vecnormalize.pkl`` would normalise its
    observations with other statistics), else ``vecnormalize.pkl`` beside it. A run that normalised
    (``algo.normalize``) without them is refused: the raw observations would run without a word."""
    from diana_lab.tracking.checkpoint_files import MODEL_RE, Checkpoint

    checkpoint = MODEL_RE.match(model_zip.name)
    expected = (
        Checkpoint.buffer_path(model_zip.parent, int(checkpoint.group(1)), "vecnormalize")
        if checkpoint
        else model_zip.parent / "vecnormalize.pkl"
    )
    path = expected if expected.is_file() else None
    if path is None and train_cfg is not None and OmegaConf.select(train_cfg, "algo.normalize", default=False):
        raise UserError(
            f"policy: '{model_zip}' was trained with algo.normalize=true, but its observation statistics "
            f"'{expected}' are missing; copy them beside the model (they were saved with it)"
        )
    return path


def _from_dir(root: Path, model_zip: Path, eval_cfg: Any, label: str, run_id: str | None = None) -> LoadedPolicy:
    cfg_path = next(
        (
            p
            for p in (
                model_zip.parent / CONFIG_ARTIFACT,
                model_zip.parent.parent / CONFIG_ARTIFACT,
                root / CONFIG_ARTIFACT,
                root / "config.yaml",  # the shipped reference policy (no hidden folders in package data)
            )
            if p.is_file()
        ),
        None,
    )
    train_cfg = _train_config(cfg_path)
    overrides = recorded_overrides(cfg_path) if train_cfg is not None else None
    policy, model = load_sb3(
        model_zip,
        _vecnormalize_file(model_zip, train_cfg),
        train_cfg,
        deterministic=eval_cfg.deterministic,
        seed=eval_cfg.seed,
    )
    return LoadedPolicy(policy, label, run_id, train_cfg, model, train_overrides=overrides)


def _from_run(run_id: str, cfg: DictConfig, eval_cfg: Any) -> LoadedPolicy:
    import mlflow
    from mlflow.exceptions import MlflowException

    _use_store(run_id, cfg)
    with tempfile.TemporaryDirectory(prefix=f"diana_eval_{run_id[:8]}_") as tmp:
        dst = Path(tmp)  # everything is in memory once loaded: the download need not outlive this call
        try:
            model_zip = Path(
                mlflow.artifacts.download_artifacts(run_id=run_id, artifact_path=MODEL_ARTIFACT, dst_path=str(dst))
            )
        except (MlflowException, OSError) as exc:
            raise UserError(
                f"policy={run_id}: could not fetch the artefact '{MODEL_ARTIFACT}' of MLflow run {run_id} "
                f"from tracking URI '{mlflow.get_tracking_uri()}' ({str(exc).splitlines()[0]}); check "
                "tracking.uri and that the run finished training"
            ) from exc
        # optional: a run without VecNormalize, say, or logged without Hydra (no .hydra/)
        for extra in (VECNORM_ARTIFACT, CONFIG_ARTIFACT, OVERRIDES_ARTIFACT):
            with contextlib.suppress(MlflowException, OSError):
                mlflow.artifacts.download_artifacts(run_id=run_id, artifact_path=extra, dst_path=str(dst))
        return _from_dir(dst, model_zip, eval_cfg, f"run {run_id}", run_id)


def _use_store(spec: str, cfg: DictConfig) -> str:
    """Point MLflow at ``tracking.uri`` (refusing an SQLite store that is not there: MLflow would create an empty
    one to look in); the URI used."""
    import mlflow

    from diana_lab.tracking.mlflow_run import resolve_uri, sqlite_path

    uri = OmegaConf.select(cfg, "tracking.uri", default=None)
    if uri:
        db = sqlite_path(resolve_uri(str(uri)))
        if db is not None and not db.is_file():
            what = "a registered model" if spec.startswith(REGISTRY) else "an MLflow run id"
            raise UserError(
                f"policy={spec}: looks like {what}, but tracking.uri={uri} has no store at '{db}'; "
                "expected the tracking.uri the run was trained with (or a model path)"
            )
        mlflow.set_tracking_uri(resolve_uri(str(uri)))
    return mlflow.get_tracking_uri()


def _model_version(spec: str, client: Any, uri: str) -> Any:
    """The registry's ``ModelVersion`` of ``spec`` (``models:/<name>/<version>`` or ``models:/<name>@<alias>``);
    a malformed URI, an unknown name, version or alias raise :class:`UserError` naming what exists."""
    from mlflow.exceptions import MlflowException

    m = MODEL_VERSION.fullmatch(spec)
    if m is None or (m["version"] is not None and not m["version"].isdigit()):
        raise UserError(
            f"policy={spec}: expected a registered model version, models:/<name>/<version> (a number) or "
            "models:/<name>@<alias>, e.g. policy=models:/rover_nav/3 or policy=models:/rover_nav@champion"
        )
    name, version, alias = m["name"], m["version"], m["alias"]
    try:
        registered = client.get_registered_model(name)
    except MlflowException as exc:
        known = sorted(r.name for r in client.search_registered_models(max_results=50))
        listed = ", ".join(known) if known else "none"
        raise UserError(
            f"policy={spec}: no registered model '{name}' at tracking URI '{uri}' (registered there: "
            f"{listed}); a training run registers its policy with tracking.register_model=<name>"
        ) from exc
    try:
        return client.get_model_version(name, version) if version else client.get_model_version_by_alias(name, alias)
    except MlflowException as exc:
        versions = sorted(int(v.version) for v in client.search_model_versions(f"name = '{name}'"))
        aliases = sorted(getattr(registered, "aliases", {}) or {})
        what = f"version {version}" if version else f"alias '{alias}'"
        raise UserError(
            f"policy={spec}: registered model '{name}' has no {what} (versions: "
            f"{', '.join(map(str, versions)) or 'none'}; aliases: {', '.join(aliases) or 'none'})"
        ) from exc


def _from_registry(spec: str, cfg: DictConfig, eval_cfg: Any) -> LoadedPolicy:
    """A registered model version (``models:/<name>/<version>`` or ``@<alias>``): its own policy files, its source
    run as the policy's run (an evaluation is logged as that run's child)."""
    import mlflow
    from mlflow.exceptions import MlflowException
    from mlflow.tracking import MlflowClient

    from diana_lab.tracking.pyfunc_model import MODEL_FILE, POLICY_ARTIFACT, policy_folder

    uri = _use_store(spec, cfg)
    version = _model_version(spec, MlflowClient(uri), uri)
    note = f"version {version.version} of registered model '{version.name}'" + (
        f", trained in MLflow run {version.run_id}" if version.run_id else ""
    )
    with tempfile.TemporaryDirectory(prefix="diana_eval_registry_") as tmp:
        try:
            local = Path(
                mlflow.artifacts.download_artifacts(
                    artifact_uri=f"models:/{version.name}/{version.version}", dst_path=tmp
                )
            )
        except (MlflowException, OSError) as exc:
            raise UserError(
                f"policy={spec}: could not fetch the files of version {version.version} of '{version.name}' from "
                f"tracking URI '{uri}' ({str(exc).splitlines()[0]})"
            ) from exc
        folder = policy_folder(local)
        loaded = _from_dir(folder, folder / MODEL_FILE, eval_cfg, spec, version.run_id) if folder else None
    if loaded is None and version.run_id and RUN_ID.match(version.run_id):  # registered from elsewhere: its run's
        loaded = _from_run(version.run_id, cfg, eval_cfg)  # own model/ artefacts
        loaded.label = spec
    if loaded is not None:
        loaded.note = note
        return loaded
    raise UserError(
        f"policy={spec}: version {version.version} of '{version.name}' is not a diana_lab policy (no "
        f"artifacts/{POLICY_ARTIFACT}/{MODEL_FILE} in it) and names no training run to load one from"
    )


# every policy ``policy=`` accepts by name besides ``pretrained`` and ``model`` (the files of ``conf/policy/``)
POLICY_NAMES = tuple(o for o in policy_options(CONF_DIR) if o not in (TRAINED, "pretrained"))


def policy_config(spec: Any) -> Any:
    """The typed ``policy`` config of ``spec``: the group's node, an option's name, or the source of a trained
    policy (a path or a run id; what ``policy=<path>`` is short for)."""
    if isinstance(spec, str):
        name = spec.strip()
        return (
            to_object("policy", name)
            if name in POLICY_NAMES or name == "pretrained"
            else TrainedPolicyConfig(source=name)
        )
    return to_object("policy", spec)


def load_policy(spec: Any, cfg: DictConfig, eval_cfg: Any) -> LoadedPolicy:
    """The policy of ``spec`` (the ``policy`` group's node, or a name, path or run id: see the module docstring);
    user mistakes raise :class:`UserError`.

    With ``eval.shield.enabled`` a learnt discrete policy (and ``bearing``, a ranking too) drives behind the slope
    shield (:class:`~diana_lab.evaluation.policies.ShieldedPolicy`); the baselines plan for themselves and run
    without it (the note says so)."""
    try:
        typed = policy_config(spec)
    except ConfigError as exc:
        raise UserError(str(exc)) from exc
    loaded = _load(typed, cfg, eval_cfg)
    shield = getattr(eval_cfg, "shield", None)  # None: the baselines' callers pass no evaluation settings
    if shield is None or not shield.enabled:
        return loaded
    if isinstance(loaded.policy, (SB3Policy, GoalBearing)):
        try:
            loaded.policy = ShieldedPolicy(loaded.policy, shield, int(getattr(eval_cfg, "seed", 0)))
        except ConfigError as exc:
            raise UserError(str(exc)) from exc
        return loaded
    unshielded = f"eval.shield applies to learnt discrete policies; policy={loaded.label} runs without it"
    loaded.note = f"{loaded.note} ({unshielded})" if loaded.note else unshielded
    return loaded


def _classical(typed: Any, cfg: DictConfig) -> LoadedPolicy:
    """A baseline or planner expert built from its option's keys (``policy.<key>``)."""
    name = typed.name
    if name == "bearing":
        shape = OmegaConf.select(cfg, "action_space.shape")
        if shape != "discrete":
            raise UserError(
                f"policy=bearing ranks a discrete action space's candidates, but action_space.shape={shape}; use "
                "action_space=discrete (or a preset with it, e.g. +experiment=reference)"
            )
    if name == "astar_seen":  # reads the env's own sensor map: refuse a config that keeps none
        try:
            check_perceivable(cfg, f"policy={name}")
        except ConfigError as exc:
            raise UserError(str(exc)) from exc
    kwargs = {f.name: getattr(typed, f.name) for f in dataclasses.fields(typed) if f.name not in ("_target_", "name")}
    try:
        policy = get_object(typed._target_)(**kwargs)
    except ValueError as exc:
        raise UserError(f"policy={name}: {exc}") from exc
    policy.name = name  # what the plots' titles and the tables call it
    return LoadedPolicy(policy, name)


def _load(typed: Any, cfg: DictConfig, eval_cfg: Any) -> LoadedPolicy:
    if not isinstance(typed, TrainedPolicyConfig):
        return _classical(typed, cfg)
    spec = str(typed.source).strip()
    if spec == "pretrained":
        model_zip = PRETRAINED_DIR / "model.zip"
        if not model_zip.is_file():
            raise UserError(
                f"policy=pretrained: the reference policy's weights are missing: not shipped with this install "
                f"(expected '{model_zip}'; reinstall the package with its data). Use a baseline "
                f"({', '.join(POLICY_NAMES)}), a model file (policy=path/to/model.zip) or the "
                "MLflow run id of a training run."
            )
        loaded = _from_dir(PRETRAINED_DIR, model_zip, eval_cfg, "pretrained")
        loaded.policy.name = "pretrained"  # what the plots' titles and the tables call it
        card = PRETRAINED_DIR / "card.json"
        if card.is_file():
            loaded.note = json.loads(card.read_text()).get("summary")
        return loaded
    if spec.startswith(REGISTRY):
        return _from_registry(spec, cfg, eval_cfg)
    path = Path(spec).expanduser()
    if path.is_dir():
        path = path / "model.zip" if (path / "model.zip").is_file() else path / MODEL_ARTIFACT
    if path.is_file():
        return _from_dir(path.parent, path.resolve(), eval_cfg, str(path))
    if RUN_ID.match(spec):
        return _from_run(spec, cfg, eval_cfg)
    raise UserError(
        f"policy={spec}: no such model file or folder '{path.resolve()}'. Expected an option of conf/policy/ "
        f"({', '.join(POLICY_NAMES)}), 'pretrained', the path of a "
        "Stable-Baselines3 .zip (with vecnormalize.pkl beside it if the run normalised observations), an MLflow "
        "run id (32 hex digits) or a registered model version (models:/<name>/<version> or models:/<name>@<alias>)."
    )
