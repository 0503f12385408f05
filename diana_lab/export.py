"""``python -m diana_lab.export policy=<run id | model .zip | run folder | pretrained> output=policy.onnx``

Exports a trained policy for the rover's onboard computer: ``policy.onnx`` (observation normalisation,
network, deterministic action, action -> waypoint-offset mapping) and ``policy.json`` next to it (the
sensor model, encoding, action space and goal scaling the runtime needs). The policy is loaded exactly as
``python -m diana_lab.evaluate`` loads it (:func:`diana_lab.evaluation.loading.load_policy`). Run the
result with :class:`diana_lab.deploy.Navigator` (numpy + onnxruntime only); see ``docs/deploy.md``::

    python -m diana_lab.export policy=<run id> output=exports/policy.onnx
    python -m diana_lab.export policy=outputs/2025-01-01/12-00-00/model opset=18
"""

from __future__ import annotations

from omegaconf import DictConfig

from diana_lab.cli import hydra_app

__all__ = ["main"]


@hydra_app(config_name="export")
def main(cfg: DictConfig) -> None:
    from diana_lab.deploy.export import run

    run(cfg)


if __name__ == "__main__":
    main()
