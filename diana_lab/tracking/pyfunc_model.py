"""A trained policy as an MLflow model: ``mlflow.pyfunc.load_model("runs:/<run id>/policy_model")`` gives waypoints.

The training runner logs the final policy of every run as the MLflow model ``policy_model`` (and the best one of
its evaluations, when one was kept, as ``best_policy_model``) with :func:`log_policy_model`: a
:class:`PolicyModel` (``mlflow.pyfunc.PythonModel``) whose artefacts are the policy's own files, so the model
registry can hold it (``tracking.register_model=<name>``) and ``python -m diana_lab.evaluate`` /
``python -m diana_lab.export`` can load a registered version back (``policy=models:/<name>/<version>``, see
:mod:`diana_lab.evaluation.loading`).

The model's folder holds, under ``artifacts/policy/`` (:data:`POLICY_ARTIFACT`): ``model.zip`` (the
Stable-Baselines3 archive), ``vecnormalize.pkl`` (its observation statistics, when the run normalised),
``config.yaml`` (the training's resolved config) and ``overrides.yaml`` (its command line's overrides, when run
through Hydra) -- the layout the evaluation's loader reads from a run folder -- and, at its root,
``policy_model_code.py``, which builds the :class:`PolicyModel` when MLflow loads it (MLflow's models from code:
no pickled Python object in the model). The models' names do not clash with the run's own ``model/`` artefacts
(what ``policy=<run id>`` and ``train.resume`` read): in MLflow 3 a logged model lives beside the run's artefacts,
not among them.

Loading it needs ``diana_lab`` importable (the archive names its features extractor, and the policy maps its
actions with the env's own :class:`~diana_lab.envs.action_spaces.WaypointMapping`); ``diana_lab`` is not on a
package index, so serve it with ``env_manager=local`` from an environment that has it installed.
"""

from __future__ import annotations

import importlib.metadata
import pickle
import shutil
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from mlflow.pyfunc import PythonModel

from diana_lab.envs import GOAL_KEYS

__all__ = [
    "BEST_MODEL",
    "FINAL_MODEL",
    "POLICY_ARTIFACT",
    "PolicyModel",
    "example_observations",
    "log_policy_model",
    "policy_folder",
    "policy_signature",
]

FINAL_MODEL = "policy_model"  # the MLflow model of a run's final policy: runs:/<run id>/policy_model
BEST_MODEL = "best_policy_model"  # of the best policy its evaluations kept (the run's best/ artefacts)
POLICY_ARTIFACT = "policy"  # the pyfunc artefact (a folder) holding the policy's files
MODEL_FILE, VECNORM_FILE, CONFIG_FILE, OVERRIDES_FILE = "model.zip", "vecnormalize.pkl", "config.yaml", "overrides.yaml"
SIN_YAW, COS_YAW = GOAL_KEYS.index("sin_yaw"), GOAL_KEYS.index("cos_yaw")
MODEL_CODE = Path(__file__).with_name("policy_model_code.py")  # what MLflow runs to build the model when loading it
# the packages loading the model needs besides diana_lab itself (recorded with their installed versions)
REQUIREMENTS = ("mlflow", "stable-baselines3", "torch", "gymnasium", "numpy", "omegaconf", "hydra-core", "cloudpickle")


class PolicyModel(PythonModel):
    """A trained Stable-Baselines3 policy of diana_lab as an MLflow pyfunc: a batch of observations in, the waypoint
    the env would drive to for each one out (deterministic actions).

    Input: a dict of numpy arrays, one per key of the policy's dict observation, each with the batch first and
    ``float32`` as the env gives it -- ``goal`` ``(B, 7)`` (the goal vector, :data:`diana_lab.envs.GOAL_KEYS`:
    distance / ``episode.distance_scale``, sin and cos of the heading error, roll and pitch / (pi/2), sin and cos of
    the yaw) and the sensor encoding under its name: ``depth_image`` ``(B, 1, H, W)``, ``elevation_map``
    ``(B, C, H, W)`` or ``points`` ``(B, N, 3)`` (the model's signature gives the exact shapes). These are the raw
    observations: the training's VecNormalize statistics are applied inside, as they were in training. Over REST
    (``mlflow models serve``): ``{"inputs": {"goal": [[...]], "elevation_map": [[[[...]]]]}}``.

    Output: a dict of numpy arrays, batch first:

    * ``offset`` ``(B, 2)`` float64: the waypoint relative to the rover's (estimated) position in the world
      frame, in metres -- what the env adds to the position to get the next waypoint. With
      ``action_space.frame=rover`` it is turned by the yaw the observation's goal vector carries (its sin and cos,
      so to float32 precision);
    * ``local_offset`` ``(B, 2)`` float64: the same waypoint in the action's frame (the rover's, x forward and y
      left, for ``frame=rover``; the world's for ``frame=world``): the ONNX export's ``offset``;
    * ``action`` the policy's deterministic action: ``(B,)`` int64 candidate indices for a discrete action space,
      ``(B, 2)`` float32 in [-1, 1] otherwise.
    """

    # MLflow 3 wraps the predict of a PythonModel subclass for type-hint validation, warning (on every import) that
    # one without a hint gets none: this one's input is checked by its signature (named tensors), which no hint can
    # express, and by predict itself. MLflow's own models without hints set this to skip the wrapping.
    _skip_type_hint_validation = True

    def load_context(self, context: Any) -> None:
        self.load(Path(context.artifacts[POLICY_ARTIFACT]))

    def load(self, folder: Path) -> None:
        """Load the policy's files from ``folder`` (the ``policy`` artefact)."""
        from hydra.utils import get_class
        from omegaconf import OmegaConf

        from diana_lab.config import to_object
        from diana_lab.envs.action_spaces import WaypointMapping

        cfg = OmegaConf.load(folder / CONFIG_FILE)
        algo = get_class(str(OmegaConf.select(cfg, "algo._target_")))
        self.model = algo.load(str(folder / MODEL_FILE), device="cpu")
        self.vecnormalize = None
        if (folder / VECNORM_FILE).is_file():
            with open(folder / VECNORM_FILE, "rb") as f:
                self.vecnormalize = pickle.load(f)  # VecNormalize without its venv: only its statistics are used
            self.vecnormalize.training = False
        self.mapping = WaypointMapping(to_object("action_space", cfg.action_space))
        self.keys = tuple(self.model.observation_space.spaces)

    def predict(self, context: Any, model_input, params: dict[str, Any] | None = None) -> dict[str, np.ndarray]:
        obs = self._observations(model_input)
        raw_goal = obs["goal"]
        if self.vecnormalize is not None and getattr(self.vecnormalize, "norm_obs", False):
            obs = self.vecnormalize.normalize_obs(obs)
        actions, _ = self.model.predict(obs, deterministic=True)
        n = len(raw_goal)
        actions = np.asarray(actions).reshape((n,) if self.mapping.discrete else (n, 2))
        goal = raw_goal.astype(np.float64)
        yaws = np.arctan2(goal[:, SIN_YAW], goal[:, COS_YAW])
        local = np.stack([self.mapping.offset(a, 0.0) for a in actions])
        world = np.stack([self.mapping.offset(a, float(y)) for a, y in zip(actions, yaws)])
        action = actions.astype(np.int64) if self.mapping.discrete else actions.astype(np.float32)
        return {"offset": world, "local_offset": local, "action": action}

    def _observations(self, model_input: Any) -> dict[str, np.ndarray]:
        if not isinstance(model_input, Mapping):
            raise TypeError(
                f"PolicyModel.predict: expected a dict of arrays with the keys {list(self.keys)} (batch "
                f"first), got {type(model_input).__name__}"
            )
        missing = [k for k in self.keys if k not in model_input]
        if missing:
            raise ValueError(f"PolicyModel.predict: missing observation keys {missing}; expected {list(self.keys)}")
        obs = {k: np.asarray(model_input[k], dtype=np.float32) for k in self.keys}
        if obs["goal"].ndim != 2 or len(obs["goal"]) == 0:
            raise ValueError(
                f"PolicyModel.predict: 'goal' has shape {obs['goal'].shape}; expected (batch, 7) with batch >= 1"
            )
        space = self.model.observation_space
        for k, v in obs.items():
            want = tuple(space[k].shape)
            if v.shape[1:] != want or len(v) != len(obs["goal"]):
                raise ValueError(
                    f"PolicyModel.predict: '{k}' has shape {v.shape}; expected (batch, "
                    f"{', '.join(map(str, want))}) with the batch of 'goal' ({len(obs['goal'])})"
                )
        return obs


def policy_folder(model_dir: Path) -> Path | None:
    """The policy's files in a downloaded MLflow model folder (``MLmodel``'s path of its :data:`POLICY_ARTIFACT`),
    or ``None`` when the folder is not a :class:`PolicyModel` of diana_lab."""
    from mlflow.models import Model

    try:
        flavor = Model.load(str(model_dir)).flavors.get("python_function", {})
    except Exception:  # no MLmodel (a plain folder registered as a model), or an unreadable one
        return None
    rel = (flavor.get("artifacts") or {}).get(POLICY_ARTIFACT, {}).get("path")
    folder = model_dir / rel if rel else None
    return folder if folder is not None and (folder / MODEL_FILE).is_file() else None


# ---------------------------------------------------------------------------------------------- logging
def example_observations(model: Any, n: int = 2) -> dict[str, np.ndarray]:
    """Up to ``n`` raw observations for the model's input example: the training env's last ones (unnormalised),
    else draws from the observation space (seeded, so the example repeats)."""
    vecnorm = model.get_vec_normalize_env()
    obs = vecnorm.get_original_obs() if vecnorm is not None else getattr(model, "_last_obs", None)
    keys = tuple(model.observation_space.spaces)
    if isinstance(obs, Mapping) and all(k in obs and len(obs[k]) for k in keys):
        return {k: np.asarray(obs[k][:n], dtype=np.float32) for k in keys}
    space = model.observation_space
    space.seed(0)
    draws = [space.sample() for _ in range(n)]
    return {k: np.stack([d[k] for d in draws]).astype(np.float32) for k in keys}


def policy_signature(observation_space: Any, discrete: bool) -> Any:
    """The model's signature: one named float32 tensor per observation key in, ``offset``, ``local_offset`` and
    ``action`` out (batch first, of any size)."""
    from mlflow.models import ModelSignature
    from mlflow.types import Schema, TensorSpec

    inputs = Schema(
        [
            TensorSpec(np.dtype(np.float32), (-1, *observation_space[k].shape), k)
            for k in tuple(observation_space.spaces)
        ]
    )
    action = (
        TensorSpec(np.dtype(np.int64), (-1,), "action")
        if discrete
        else TensorSpec(np.dtype(np.float32), (-1, 2), "action")
    )
    outputs = Schema(
        [
            TensorSpec(np.dtype(np.float64), (-1, 2), "offset"),
            TensorSpec(np.dtype(np.float64), (-1, 2), "local_offset"),
            action,
        ]
    )
    return ModelSignature(inputs=inputs, outputs=outputs)


def _requirements(algo_target: str) -> list[str]:
    """Pinned requirements of the installed packages loading needs (``+local`` labels such as torch's ``+cpu``
    dropped: no index serves them); ``sb3-contrib`` too for its algorithms."""
    names = [*REQUIREMENTS, *(["sb3-contrib"] if algo_target.startswith("sb3_contrib") else [])]
    out = []
    for name in names:
        try:
            out.append(f"{name}=={importlib.metadata.version(name).split('+')[0]}")
        except importlib.metadata.PackageNotFoundError:
            out.append(name)
    return out


def _policy_folder(model_dir: Path, config_yaml: str, overrides: Path | None, dst: Path) -> Path:
    folder = dst / POLICY_ARTIFACT
    folder.mkdir(parents=True)
    shutil.copy2(model_dir / MODEL_FILE, folder / MODEL_FILE)
    if (model_dir / VECNORM_FILE).is_file():
        shutil.copy2(model_dir / VECNORM_FILE, folder / VECNORM_FILE)
    (folder / CONFIG_FILE).write_text(config_yaml)
    if overrides is not None and overrides.is_file():
        shutil.copy2(overrides, folder / OVERRIDES_FILE)
    return folder


def log_policy_model(
    tracker: Any,
    model_dir: Path,
    cfg: Any,
    name: str,
    model: Any,
    overrides: Path | None = None,
    register: str | None = None,
    step: int = 0,
) -> Any:
    """Log the policy saved in ``model_dir`` (``model.zip``, ``vecnormalize.pkl`` when normalised) to the tracker's
    run as the MLflow model ``name`` (a :class:`PolicyModel` with its signature and an input example of ``model``'s
    last observations); ``cfg``: the training's config, ``overrides``: its ``.hydra/overrides.yaml``; ``register``:
    a registered model name to add it to as a new version; ``step``: the run's metrics at that step are linked to
    the model (its evaluation, in the UI's model page). Returns MLflow's ``ModelInfo`` (its
    ``registered_model_version`` set when registered), or ``None`` without an MLflow run."""
    if getattr(tracker, "run_id", None) is None or getattr(tracker, "uri", None) is None:
        return None
    import mlflow
    from omegaconf import OmegaConf

    from diana_lab.tracking.logged_models import log_model_to_run

    target = str(OmegaConf.select(cfg, "algo._target_", default="") or "")
    discrete = hasattr(model.action_space, "n")
    with tempfile.TemporaryDirectory(prefix="diana_policy_model_") as tmp:
        folder = _policy_folder(Path(model_dir), OmegaConf.to_yaml(cfg, resolve=True), overrides, Path(tmp))
        metadata = {
            "diana_lab_version": _version("diana_lab"),
            "observation_keys": list(model.observation_space.spaces),
            "action_space": str(OmegaConf.select(cfg, "action_space.shape", default="")),
            "action_frame": str(OmegaConf.select(cfg, "action_space.frame", default="")),
            "algo": target,
        }
        return log_model_to_run(
            tracker.uri,
            tracker.run_id,
            name,
            mlflow.pyfunc,
            python_model=str(MODEL_CODE),  # models from code: the model holds this file, no pickled object
            artifacts={POLICY_ARTIFACT: str(folder)},
            signature=policy_signature(model.observation_space, discrete),
            input_example=example_observations(model),
            pip_requirements=_requirements(target),
            metadata=metadata,
            registered_model_name=register,
            step=int(step),
        )


def _version(name: str) -> str:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return "unknown"
