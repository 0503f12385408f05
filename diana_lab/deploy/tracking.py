"""The exported graph as an MLflow ONNX model of the training run it came from (``python -m diana_lab.export
policy=<run id>``): ``runs:/<run id>/policy_onnx``, with its sidecar (``policy.json``) among the model's files.

Logged only when the policy came from a run (a run id or a registered model version) and ``tracking.enabled``;
the model's input example is a few draws from the policy's observation space and its signature comes from
running the graph on them, so ``mlflow.pyfunc.load_model`` and ``mlflow models serve`` check their inputs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from diana_lab.deploy.spec import sidecar_path

__all__ = ["ONNX_MODEL", "log_onnx_model"]

ONNX_MODEL = "policy_onnx"  # the MLflow model's name in the run: runs:/<run id>/policy_onnx


def _example(model: Any, n: int = 2) -> dict[str, np.ndarray]:
    """``n`` seeded draws from the policy's dict observation space, as the graph's inputs (float32, batch first)."""
    space = model.observation_space
    space.seed(0)
    draws = [space.sample() for _ in range(n)]
    return {k: np.stack([d[k] for d in draws]).astype(np.float32) for k in space.spaces}


def log_onnx_model(output: Path, model: Any, run_id: str, uri: str) -> Any:
    """Log the graph at ``output`` (and its sidecar) to run ``run_id`` of the store at ``uri`` as the ONNX model
    :data:`ONNX_MODEL`; returns MLflow's ``ModelInfo``."""
    import mlflow
    import onnx
    import onnxruntime as ort
    from mlflow.models import infer_signature

    from diana_lab.tracking.logged_models import log_model_to_run

    example = _example(model)
    session = ort.InferenceSession(str(output), providers=["CPUExecutionProvider"])
    names = [o.name for o in session.get_outputs()]
    predicted = dict(zip(names, session.run(names, example)))
    return log_model_to_run(
        uri,
        run_id,
        ONNX_MODEL,
        mlflow.onnx,
        onnx_model=onnx.load(str(output)),
        signature=infer_signature(example, predicted),
        input_example=example,
        extra_files=[str(sidecar_path(output))],
        save_as_external_data=False,
        onnx_execution_providers=["CPUExecutionProvider"],  # what the export checked it with; any build has it
    )
