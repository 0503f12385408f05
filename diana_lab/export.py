"""``python -m diana_lab.export policy=<run id | models:/NAME/VERSION | model .zip | run folder | pretrained>``

Exports a trained policy for the rover's onboard computer: ``policy.onnx`` (observation normalisation,
network, deterministic action, action -> waypoint-offset mapping) and ``policy.json`` next to it (the
sensor model, encoding, action space and goal scaling the runtime needs). The policy is loaded exactly as
``python -m diana_lab.evaluate`` loads it (:func:`diana_lab.evaluation.loading.load_policy`); the sidecar takes
``sensor``, ``action_space``, ``episode``, ``robot`` and ``eval.shield`` from its training config, and refuses
command-line settings of the first four that would change it (:func:`diana_lab.deploy.command.run`). A policy
from an MLflow run (a run id, a registered model version) is also logged back to that run as the ONNX model
``policy_onnx``. Run the result with :class:`diana_lab.deploy.Navigator` (numpy + onnxruntime only); see
``docs/deploy.md``::

    python -m diana_lab.export policy=<run id> output=exports/policy.onnx
    python -m diana_lab.export policy=models:/rover_nav@champion output=exports/policy.onnx
    python -m diana_lab.export policy=outputs/2025-01-01/12-00-00/model opset=18
"""

from __future__ import annotations

from omegaconf import DictConfig

from diana_lab.cli import hydra_app, task_overrides

__all__ = ["main"]


@hydra_app(config_name="export", combinations=False)  # action_space: the training's
def main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig

    from diana_lab.deploy.command import run

    # the command line's overrides tell a setting chosen there (eval.shield.enabled=false, robot=jackal) from a
    # default; called outside this app (a composed config; another app's config left behind in the process), only
    # the settings that differ from the defaults show
    ours = HydraConfig.initialized() and HydraConfig.get().job.config_name == "export"
    run(cfg, task_overrides() if ours else None)


if __name__ == "__main__":
    main()
