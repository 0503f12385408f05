"""``python -m diana_lab [overrides]``: train an agent, evaluate it and track it in MLflow.

    python -m diana_lab algo=ppo world=mars_yard
    python -m diana_lab +experiment=quick
    python -m diana_lab -m algo=ppo,sac seed=0,1,2
    python -m diana_lab train.resume=<mlflow run id | run dir>

Ctrl-C or SIGTERM saves a checkpoint, marks the MLflow run KILLED and exits with 130 / 143.
"""

from __future__ import annotations

import sys

from omegaconf import DictConfig

from diana_lab.cli import hydra_app


@hydra_app(config_name="config")
def main(cfg: DictConfig) -> float | None:
    from diana_lab.training import RunContext, train
    from diana_lab.training.signals import interrupt_exit_code
    from diana_lab.training.summary import summary_text

    try:
        result = train(cfg, RunContext.from_hydra())
    except KeyboardInterrupt as exc:
        partial = getattr(exc, "result", None)
        if partial is not None:
            print(summary_text(partial), file=sys.stderr)
        sys.exit(interrupt_exit_code(exc))
    print(summary_text(result))
    return result.eval_summary.get("success_rate")  # a sweeper's objective


if __name__ == "__main__":
    main()
