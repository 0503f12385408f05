"""Success rate against wall time for MLflow runs side by side (the README's learning-curve figure).

    python benchmarks/learning_curve.py --uri sqlite:///mlflow.db --out docs/img/learning_curve.png \
        --run <run id>=<label> --run <run id>=<label>

Each run's periodic and final evaluations (``eval_success_rate``, logged at their timesteps) are placed at the
wall time they were logged, from the run's start; the timesteps are printed beside them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from mlflow.tracking import MlflowClient


def curve(client: MlflowClient, run_id: str, metric: str) -> list[tuple[float, int, float]]:
    """``(minutes since the run started, timesteps, value)`` of every logged ``metric``, in order."""
    run = client.get_run(run_id)
    start = run.info.start_time
    history = sorted(client.get_metric_history(run_id, metric), key=lambda m: (m.timestamp, m.step))
    return [((m.timestamp - start) / 60_000.0, m.step, m.value) for m in history]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--uri", required=True, help="MLflow tracking URI")
    parser.add_argument("--run", action="append", required=True, help="<run id>=<label>, once per run")
    parser.add_argument("--metric", default="eval_success_rate")
    parser.add_argument("--out", required=True, type=Path)
    args = parser.parse_args()
    client = MlflowClient(args.uri)
    fig, ax = plt.subplots(figsize=(7, 4))
    for entry in args.run:
        run_id, _, label = entry.partition("=")
        points = curve(client, run_id, args.metric)
        if not points:
            raise SystemExit(f"--run {entry}: run {run_id} logged no {args.metric}")
        minutes, steps, values = zip(*points)
        ax.plot(minutes, values, marker="o", label=label or run_id)
        for m, s, v in points:
            print(f"{label or run_id}: {m:6.1f} min  {s:>9,} steps  {args.metric} {v:.3f}")
    ax.set_xlabel("wall time (min)")
    ax.set_ylabel(args.metric.replace("_", " "))
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=120)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
