"""Comparable runs: a real tiny run logs only the names of docs/metrics.md, ``eval_<key>`` from the periodic,
the final and the CLI's evaluation, and tags every config group, so one MLflow filter finds them."""

from __future__ import annotations

import re
from pathlib import Path

import mlflow
import pytest

from diana_lab.comparison import load_runs
from diana_lab.comparison.runs import using_store
from diana_lab.evaluation.metrics import SUMMARY_KEYS
from tests.training.helpers import ALGO_TINY, TINY, run_in_process, runs, store_args

DOC = Path(__file__).resolve().parents[2] / "docs" / "metrics.md"
GROUP_TAGS = ("world", "robot", "sensor", "algo", "action_space", "reward", "dynamics")


def documented() -> list[re.Pattern[str]]:
    """The first-column names of the doc's tables, ``<placeholder>`` matching any name part."""
    names = []
    for line in DOC.read_text().splitlines():
        cells = line.split("|")
        if line.startswith("|") and len(cells) > 2:
            names += re.findall(r"`([^`]+)`", cells[1])
    return [
        re.compile(re.sub(r"<[^>]+>", "[A-Za-z0-9_.]+", re.escape(n).replace(r"\<", "<").replace(r"\>", ">")))
        for n in names
    ]


def test_documented_eval_rows_are_the_summary_keys():
    names = {p.pattern for p in documented() if p.pattern.startswith("eval_")}
    assert {f"eval_{k}" for k in SUMMARY_KEYS} <= names


def tiny_run(tmp: Path, algo: str, *extra: str) -> None:
    assert (
        run_in_process([f"algo={algo}", *TINY, *ALGO_TINY[algo], *extra, *store_args(tmp, f"{algo}{len(extra)}")]) == 0
    )


def undocumented(metrics: set[str]) -> set[str]:
    patterns = documented()
    return {m for m in metrics if not any(p.fullmatch(m) for p in patterns)}


def test_training_and_cli_evaluation_use_the_same_names_and_one_filter_finds_them(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    tiny_run(tmp_path, "ppo")
    client, (run,) = runs(tmp_path)
    rid = run.info.run_id
    assert undocumented(set(run.data.metrics)) == set()
    assert {"eval_success_rate", "eval_spl", "eval_spl_ci95_lo", "train/reward_progress", "time/fps"} <= set(
        run.data.metrics
    )
    assert not any(m.startswith("eval/") for m in run.data.metrics)  # the old names are gone
    assert {t: run.data.tags[t] for t in GROUP_TAGS} == {
        "world": "flat",
        "robot": "jackal",
        "sensor": "depth_camera",
        "algo": "ppo",
        "action_space": "discrete",  # the default's (the tiny runs of tests/training/helpers.py pin the camera)
        "reward": "default",
        "dynamics": "kinematic",
    }
    steps = [m.step for m in client.get_metric_history(rid, "eval_success_rate")]
    assert steps[0] == 128 and steps[-1] >= 256  # periodic evaluations, then the final one (step = timesteps)

    from diana_lab.config import compose
    from diana_lab.evaluate import run as evaluate

    uri = f"sqlite:///{tmp_path}/mlflow.db"
    cfg = compose(
        ["world=flat", "sensor=depth_camera", "robot.tilt_guard_deg=null", "sensor.width=16", "sensor.height=12",
         "episode.max_steps=20", "eval.episodes=2",
         "eval.video=false", "eval.plots=false", f"tracking.uri={uri}", f"policy={rid}"],
        config_name="evaluate",
    )  # fmt: skip
    (tmp_path / "ev").mkdir()
    evaluate(cfg, tmp_path / "ev")
    (child,) = client.search_runs([run.info.experiment_id], f"tags.mlflow.parentRunId = '{rid}'")
    assert undocumented(set(child.data.metrics)) == set()
    assert set(child.data.metrics) <= set(run.data.metrics)  # the CLI's names are the runner's
    assert child.data.tags["algo"] == "ppo" and child.data.tags["diana_lab.kind"] == "evaluation"

    with using_store(uri):  # mlflow.search_runs reads the process-wide URI; restored afterwards
        found = mlflow.search_runs(
            experiment_names=["diana_lab"], filter_string="tags.algo = 'ppo' and metrics.eval_spl >= 0"
        )
        assert mlflow.search_runs(experiment_names=["diana_lab"], filter_string="tags.algo = 'sac'").empty
    assert set(found["run_id"]) == {rid, child.info.run_id}
    assert list(load_runs(uri, ["diana_lab"], "tags.algo = 'ppo' and metrics.eval_spl >= 0")["run_id"]) == [rid]


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["a2c", "sac", "td3", "ddpg", "tqc"])
def test_every_algorithm_logs_documented_names(tmp_path, algo):
    tiny_run(tmp_path, algo)
    _, (run,) = runs(tmp_path)
    assert undocumented(set(run.data.metrics)) == set()
    assert "eval_spl" in run.data.metrics and run.data.tags["algo"] == algo
