"""A small MLflow store written directly with ``MlflowClient``: runs whose numbers the tests know exactly.

Four training runs -- PPO with seeds 0 and 1, PPO with another learning rate, A2C -- plus one evaluation
run of ``python -m diana_lab.evaluate``, named and tagged as the runner and the CLI log them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mlflow.entities import Metric, Param, RunTag
from mlflow.tracking import MlflowClient

GROUPS = {
    "world": "flat",
    "robot": "jackal",
    "sensor": "depth_camera",
    "dynamics": "kinematic",
    "action_space": "square",
    "reward": "default",
}
STEPS = (100, 200, 300)


@dataclass(frozen=True)
class FakeRun:
    algo: str
    seed: int
    lr: float
    success: tuple[float, ...]  # eval_success_rate at STEPS; the last one is the run's value
    spl: tuple[float, ...]


RUNS = (
    FakeRun("ppo", 0, 3e-4, (0.0, 0.5, 0.8), (0.0, 0.4, 0.7)),
    FakeRun("ppo", 1, 3e-4, (0.2, 0.5, 0.6), (0.1, 0.4, 0.5)),
    FakeRun("ppo", 0, 1e-3, (0.1, 0.1, 0.2), (0.1, 0.1, 0.1)),
    FakeRun("a2c", 0, 7e-4, (0.0, 0.0, 0.4), (0.0, 0.0, 0.3)),
)


def make_store(tmp: Path, experiment: str = "diana_lab") -> str:
    """Write :data:`RUNS` (and one evaluation run) into ``tmp/mlflow.db``; returns the store's URI."""
    uri = f"sqlite:///{tmp}/mlflow.db"
    client = MlflowClient(uri)
    exp = client.create_experiment(experiment, artifact_location=(tmp / "mlruns").as_uri())
    for r in RUNS:
        run = client.create_run(exp, run_name=f"{r.algo}-flat-depth_camera-s{r.seed}")
        rid = run.info.run_id
        tags = {**GROUPS, "algo": r.algo, "seed": str(r.seed), "overrides": f"algo={r.algo} seed={r.seed}"}
        params = {
            "seed": str(r.seed),
            "algo.name": r.algo,
            "algo.learning_rate": str(r.lr),
            "world.name": "flat",
            "train.total_timesteps": "300",
            "tracking.uri": uri,
            "train.progress_bar": str(r.seed == 0),  # bookkeeping: must not split a group
        }
        metrics = [Metric("eval_success_rate", v, 1000 + i, s) for i, (s, v) in enumerate(zip(STEPS, r.success))]
        metrics += [Metric("eval_spl", v, 1000 + i, s) for i, (s, v) in enumerate(zip(STEPS, r.spl))]
        metrics += [Metric("rollout/ep_rew_mean", -1.0 + s / 100, 1000 + i, s) for i, s in enumerate(STEPS)]
        metrics += [Metric("train/reward_progress", 2.0 * r.success[-1], 1000, STEPS[-1])]
        metrics += [Metric("train/reward_goal", 10.0 * r.success[-1], 1000, STEPS[-1])]
        client.log_batch(
            rid,
            metrics=metrics,
            params=[Param(k, v) for k, v in params.items()],
            tags=[RunTag(k, v) for k, v in tags.items()],
        )
        client.set_terminated(rid, "FINISHED")
    ev = client.create_run(exp, run_name="eval astar", tags={"diana_lab.kind": "evaluation", "world": "flat"})
    client.log_batch(ev.info.run_id, metrics=[Metric("eval_success_rate", 1.0, 0, 0), Metric("eval_spl", 0.9, 0, 0)])
    client.set_terminated(ev.info.run_id, "FINISHED")
    return uri


PAIRED = {  # learning rate -> seed -> (eval_spl, host_cpu): a baseline and a candidate on three seeds
    "0.0003": {0: (0.50, "cpu A"), 1: (0.60, "cpu A"), 2: (0.55, "cpu A")},
    "0.001": {0: (0.55, "cpu A"), 1: (0.62, "cpu A"), 2: (0.65, "cpu B")},
}


def make_paired_store(tmp: Path) -> str:
    """Two PPO configs (:data:`PAIRED`) on seeds 0-2, tagged with the CPU each trained on; seed 2 of the
    candidate trained on another kind of CPU. Returns the store's URI."""
    uri = f"sqlite:///{tmp}/mlflow.db"
    client = MlflowClient(uri)
    exp = client.create_experiment("diana_lab", artifact_location=(tmp / "mlruns").as_uri())
    for lr, seeds in PAIRED.items():
        for seed, (spl, host) in seeds.items():
            rid = client.create_run(exp, run_name=f"ppo-lr{lr}-s{seed}").info.run_id
            tags = {**GROUPS, "algo": "ppo", "seed": str(seed), "host_cpu": host}
            params = {"seed": str(seed), "algo.name": "ppo", "algo.learning_rate": lr}
            client.log_batch(
                rid,
                metrics=[Metric("eval_spl", spl, 1000, 300), Metric("eval_success_rate", spl + 0.2, 1000, 300)],
                params=[Param(k, v) for k, v in params.items()],
                tags=[RunTag(k, v) for k, v in tags.items()],
            )
            client.set_terminated(rid, "FINISHED")
    return uri
