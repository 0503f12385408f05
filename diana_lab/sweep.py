"""``python -m diana_lab.sweep sweep=<name> [sweep.*=...] [config overrides]``: an Optuna study over training runs.

    python -m diana_lab.sweep sweep=reward_shaping sweep.n_trials=50
    python -m diana_lab.sweep sweep=ppo sweep.storage=postgresql+psycopg2://user:pw@db-host/optuna  # each machine
    python -m diana_lab.sweep sweep=sac 'sweep.seeds=[0,1,2]' world=hills

``sweep=<name>`` picks ``sweeps/<name>.yaml`` (search space, base overrides, objective, budget); it is short for
``sweep.name=<name>``. Every other config override applies to every trial. Rerunning the same command
continues the study; starting it on several machines (or twice on one) shares the trials. Ctrl-C or SIGTERM
marks the running trial FAIL and the MLflow runs KILLED, and exits with 130 / 143; rerun to continue.
See docs/sweeps.md.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from omegaconf import DictConfig

from diana_lab.cli import hydra_app, task_overrides

__all__ = ["expand_shorthand", "main"]


def expand_shorthand(argv: Sequence[str]) -> list[str]:
    """``sweep=<name>`` -> ``sweep.name=<name>``: the sweep node is typed, so Hydra would reject the string."""
    return [f"sweep.name={a.split('=', 1)[1]}" if a.startswith("sweep=") else a for a in argv]


@hydra_app(config_name="sweep")
def _task(cfg: DictConfig) -> float | None:
    from hydra.core.hydra_config import HydraConfig

    from diana_lab.sweeps.runner import run_sweep, summary_text
    from diana_lab.training.signals import interrupt_exit_code

    hc = HydraConfig.get()
    try:
        result = run_sweep(cfg, Path(hc.runtime.output_dir), tuple(task_overrides()))
    except KeyboardInterrupt as exc:
        print("\ninterrupted: the running trial is marked FAIL; rerun the same command to continue", file=sys.stderr)
        sys.exit(interrupt_exit_code(exc))
    print(summary_text(result, int(cfg.sweep.top)))
    return result.best_value


def main() -> None:
    sys.argv = [sys.argv[0], *expand_shorthand(sys.argv[1:])]
    _task()


main.task = _task.task  # type: ignore[attr-defined]

if __name__ == "__main__":
    main()
