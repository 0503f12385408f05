"""``python -m diana_lab.compare``: the files it writes, and a clear exit 2 when nothing matches."""

from __future__ import annotations

import sys

import pandas as pd
import pytest
from PIL import Image


def run_compare(args: list[str]) -> int:
    from diana_lab.compare import main

    saved = sys.argv
    sys.argv = ["diana_lab.compare", *args, "hydra/job_logging=disabled", "hydra/hydra_logging=disabled"]
    try:
        main()
    except SystemExit as exc:
        return int(exc.code or 0)
    finally:
        sys.argv = saved
    return 0


def test_writes_tables_and_curves_of_the_selected_runs(store, tmp_path, capsys):
    uri, _ = store
    out = tmp_path / "cmp"
    code = run_compare(
        [f"tracking.uri={uri}", "filter=\"tags.world = 'flat'\"", "group_by=[algo,world]", f"output={out}"]
    )
    assert code == 0, capsys.readouterr().err
    names = {p.name for p in out.iterdir()}
    assert {"runs.csv", "runs.md", "groups.csv", "groups.md", "final_metrics.png"} <= names
    assert {"curves_eval_success_rate.png", "curves_eval_spl.png"} <= names
    runs = pd.read_csv(out / "runs.csv", dtype={"seed": str})
    assert len(runs) == 4 and set(runs["algo"]) == {"ppo", "a2c"}  # the evaluation run is left out
    assert {"world", "seed", "eval_success_rate", "eval_spl", "eval_tipover_rate"} <= set(runs.columns)
    groups = pd.read_csv(out / "groups.csv").set_index("group")
    assert groups.loc["algo=ppo / algo.learning_rate=0.0003", "runs"] == 2
    assert groups.loc["algo=ppo / algo.learning_rate=0.0003", "eval_spl_mean"] == pytest.approx(0.6)
    md = (out / "groups.md").read_text()
    assert "0.700 ± 0.141" in md  # success rate of the two seeds: mean ± sample std
    assert (out / ".hydra" / "config.yaml").is_file()  # the comparison's own record
    with Image.open(out / "curves_eval_spl.png") as im:
        assert im.size[0] > 300
    captured = capsys.readouterr()
    assert "4 runs in 3 groups" in captured.out
    assert "sharing seed" not in captured.err  # each group's runs have their own seeds


def test_no_matching_run_exits_2_naming_the_filter(store, tmp_path, capsys):
    uri, _ = store
    code = run_compare([f"tracking.uri={uri}", "filter=\"tags.algo = 'sac'\"", f"output={tmp_path / 'cmp'}"])
    assert code == 2
    err = capsys.readouterr().err
    assert "filter=\"tags.algo = 'sac'\": no runs match" in err and "Traceback" not in err


def test_typo_in_a_metric_warns_with_the_close_name(store, tmp_path, capsys):
    uri, _ = store
    code = run_compare([f"tracking.uri={uri}", "metrics=[eval_spl,eval_sucess_rate]", f"output={tmp_path / 'c'}"])
    assert code == 0
    assert "no selected run logged eval_sucess_rate (did you mean eval_success_rate" in capsys.readouterr().err


@pytest.mark.parametrize(("key", "value", "shown"), [("variants", "no", "'no'"), ("include_evaluations", "0", "0")])
def test_a_flag_that_is_not_true_or_false_exits_2_naming_the_key(store, tmp_path, capsys, key, value, shown):
    uri, _ = store
    code = run_compare([f"tracking.uri={uri}", f"{key}={value}", f"output={tmp_path / 'cmp'}"])
    assert code == 2  # bool("no") is True: the comparison would have run with the option the other way round
    assert f"{key}: expected true or false, got {shown}" in capsys.readouterr().err
    assert not (tmp_path / "cmp" / "groups.csv").exists()


def test_variants_false_is_honoured(store, tmp_path, capsys):
    uri, _ = store
    code = run_compare([f"tracking.uri={uri}", "variants=false", "group_by=[algo]", f"output={tmp_path / 'cmp'}"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "4 runs in 2 groups" in captured.out  # the two learning rates of PPO are one group
    # ... in which two runs have seed 0: their std is no spread over seeds, and the user is told so
    assert "warning: group 'algo=ppo' has runs sharing seed(s) 0" in captured.err


def test_group_by_a_tag_no_run_has_exits_2_naming_the_available_tags(store, tmp_path, capsys):
    uri, _ = store
    code = run_compare([f"tracking.uri={uri}", "group_by=[algoo,algo.learning_rate]", f"output={tmp_path / 'cmp'}"])
    assert code == 2
    err = capsys.readouterr().err
    assert "group_by=['algoo', 'algo.learning_rate']: no selected run has the tag(s) algoo, algo.learning_rate" in err
    assert "algo.learning_rate: config values, not tags" in err
    assert "the tags of these runs: action_space, algo, dynamics" in err and "mlflow.runName" not in err
    assert not (tmp_path / "cmp" / "groups.csv").exists()


def test_a_group_counting_a_run_that_did_not_finish_warns_naming_it(tmp_path, capsys):
    from mlflow.tracking import MlflowClient

    from .store import make_store

    uri = make_store(tmp_path / "store")
    client = MlflowClient(uri)
    killed = client.search_runs([client.get_experiment_by_name("diana_lab").experiment_id], "tags.algo = 'a2c'")[0]
    client.set_terminated(killed.info.run_id, "KILLED")  # as an interrupted run ends
    code = run_compare([f"tracking.uri={uri}", "group_by=[algo]", f"output={tmp_path / 'cmp'}"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "warning: group 'algo=a2c' counts 1 run(s) that did not finish: a2c-flat-depth_camera-s0 (KILLED)" in (
        captured.err
    )
    assert "group 'algo=ppo' counts" not in captured.err  # its runs all finished
    code = run_compare(
        [f"tracking.uri={uri}", "filter=\"attributes.status = 'FINISHED'\"", f"output={tmp_path / 'cmp2'}"]
    )
    captured = capsys.readouterr()
    assert code == 0 and "did not finish" not in captured.err and "3 runs in" in captured.out
