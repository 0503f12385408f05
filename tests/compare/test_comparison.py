"""diana_lab.comparison on a store with known numbers: selection, groups over seeds, statistics, curves."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from diana_lab.comparison import (
    ComparisonError,
    assign_groups,
    compare_runs,
    learning_curves,
    load_runs,
    plot_learning_curves,
)

GROUP_BY = ("algo", "world", "reward")


def test_load_runs_filters_by_tag_and_metric_and_leaves_out_evaluations(store):
    uri, _ = store
    df = load_runs(uri, ["diana_lab"], "tags.algo = 'ppo' and metrics.eval_spl >= 0.5")
    assert sorted(df["params.seed"]) == ["0", "1"]  # the two seeds of the good config (0.7, 0.5)
    assert len(load_runs(uri, ["diana_lab"])) == 4
    assert len(load_runs(uri, ["diana_lab"], include_evaluations=True)) == 5


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"filter_string": "tags.algo = 'dqn'"}, "filter=\"tags.algo = 'dqn'\": no runs match"),
        ({"filter_string": "tags.algo === 'x'"}, "MLflow cannot use it"),
        ({"experiments": ["nope"]}, "experiments=['nope']: no such experiment"),
    ],
)
def test_load_runs_errors_name_what_to_change(store, kwargs, message):
    uri, _ = store
    args = {"experiments": ["diana_lab"], **kwargs}
    with pytest.raises(ComparisonError, match=message.replace("[", r"\[").replace("]", r"\]")):
        load_runs(uri, **args)


def test_missing_store_is_an_error_not_a_new_empty_database(tmp_path):
    with pytest.raises(ComparisonError, match="no MLflow store"):
        load_runs(f"sqlite:///{tmp_path}/missing.db", ["diana_lab"])
    assert not (tmp_path / "missing.db").exists()


def test_runs_differing_only_in_seed_form_one_group_and_other_params_split(store):
    uri, _ = store
    g = assign_groups(load_runs(uri, ["diana_lab"]), GROUP_BY)
    labels = dict(zip(zip(g["tags.algo"], g["params.algo.learning_rate"], g["seed"]), g["group"]))
    assert labels["ppo", "0.0003", "0"] == labels["ppo", "0.0003", "1"]  # seeds (and progress_bar) merged
    assert labels["ppo", "0.0003", "0"] == "algo=ppo / algo.learning_rate=0.0003"
    assert labels["ppo", "0.001", "0"] == "algo=ppo / algo.learning_rate=0.001"
    assert labels["a2c", "0.0007", "0"] == "algo=a2c"  # alone in its options: no variant needed
    assert g["group"].nunique() == 3
    lumped = assign_groups(load_runs(uri, ["diana_lab"]), GROUP_BY, variants=False)
    assert sorted(lumped["group"].unique()) == ["algo=a2c", "algo=ppo"]


def test_aggregate_gives_mean_and_sample_std_over_seeds(store):
    uri, _ = store
    c = compare_runs(uri, ["diana_lab"], "", metrics=["eval_success_rate", "eval_spl"], group_by=GROUP_BY)
    row = c.groups.set_index("group").loc["algo=ppo / algo.learning_rate=0.0003"]
    assert row["runs"] == 2 and row["seeds"] == "0,1"
    assert row["eval_success_rate_mean"] == pytest.approx(0.7)
    assert row["eval_success_rate_std"] == pytest.approx(np.std([0.8, 0.6], ddof=1))
    single = c.groups.set_index("group").loc["algo=a2c"]
    assert single["eval_spl_mean"] == pytest.approx(0.3) and math.isnan(single["eval_spl_std"])
    assert set(c.runs.columns) >= {"run_id", "group", "algo", "world", "seed", "eval_spl"}
    assert c.missing_metrics == {}


def test_unknown_metric_is_reported_with_close_names(store):
    uri, _ = store
    c = compare_runs(uri, ["diana_lab"], metrics=["eval_spl", "eval_spll"], curves=[])
    assert c.missing_metrics == {"eval_spll": ["eval_spl"]}
    assert c.runs["eval_spll"].isna().all()


def test_learning_curves_average_seeds_and_never_extrapolate():
    hist = pd.DataFrame(
        {
            "run_id": ["a", "a", "a", "b", "b", "c"],
            "metric": ["m"] * 6,
            "step": [100, 200, 300, 100, 250, 100],
            "value": [0.0, 0.4, 0.8, 0.2, 0.6, 0.5],
        }
    )
    curves = learning_curves(hist, pd.Series({"a": "g", "b": "g", "c": "h"})).set_index(["group", "step"])
    assert list(curves.loc["g"].index) == [100, 200, 250, 300]
    assert curves.loc[("g", 100), "mean"] == pytest.approx(0.1) and curves.loc[("g", 100), "n"] == 2
    assert curves.loc[("g", 200), "mean"] == pytest.approx((0.4 + 0.2 + 0.4 * 100 / 150) / 2)  # b interpolated
    assert curves.loc[("g", 300), "n"] == 1 and math.isnan(curves.loc[("g", 300), "std"])  # b ended at 250
    assert curves.loc[("h", 100), "mean"] == 0.5


def test_curves_from_the_store_follow_metric_history(store):
    uri, _ = store
    c = compare_runs(uri, ["diana_lab"], "tags.algo = 'ppo'", group_by=GROUP_BY)
    # only PPO selected: the labels name what differs between its groups, the learning rate
    good = c.curves[(c.curves["group"] == "algo.learning_rate=0.0003") & (c.curves["metric"] == "eval_spl")]
    assert list(good["step"]) == [100, 200, 300]
    assert list(good["mean"]) == pytest.approx([0.05, 0.4, 0.6])
    fig = plot_learning_curves(c.curves, "eval_spl")
    ax = fig.axes[0]
    assert len(ax.get_lines()) == 2 and len(ax.collections) >= 1  # two groups, a band for the two seeds
    assert {t.get_text() for t in ax.get_legend().get_texts()} == {
        "algo.learning_rate=0.0003 (n=2)",
        "algo.learning_rate=0.001 (n=1)",
    }


def test_runs_without_any_requested_metric_are_left_out_with_a_note(store):
    uri, _ = store
    c = compare_runs(uri, ["diana_lab"], metrics=["eval_spl"], curves=[], include_evaluations=True)
    assert len(c.runs) == 5 and c.skipped == []
    with pytest.raises(ComparisonError, match="none logged any of train/approx_kl"):
        compare_runs(uri, ["diana_lab"], metrics=["train/approx_kl"], curves=[])
    c = compare_runs(uri, ["diana_lab"], metrics=["train/reward_goal"], curves=[], include_evaluations=True)
    assert c.skipped == ["eval astar"] and len(c.runs) == 4


def test_group_by_an_option_group_the_runs_lack_is_one_shared_option(store):
    """Runs logged before a group's tag existed (or without a preset: ``experiment``) lack it: not an error."""
    uri, _ = store
    c = compare_runs(uri, ["diana_lab"], metrics=["eval_spl"], curves=[], group_by=["algo", "experiment"])
    assert set(c.groups["algo"]) == {"ppo", "a2c"} and set(c.groups["experiment"]) == {""}
    with pytest.raises(ComparisonError, match="no selected run has the tag"):
        compare_runs(uri, ["diana_lab"], metrics=["eval_spl"], curves=[], group_by=["algo", "wrld"])


def test_groups_whose_runs_share_a_seed_are_reported():
    from diana_lab.comparison.groups import aggregate, repeated_seeds

    table = pd.DataFrame(
        {
            "group": ["a", "a", "a", "b", "b", "c", "c"],
            "seed": ["1", "1", "2", "", "", "0", "10"],
            "variant": "",
            "m": [0.5, 0.7, 0.6, 0.1, 0.2, 0.3, 0.4],
        }
    )
    assert repeated_seeds(table) == {"a": ["1"], "b": ["?"]}  # c's seeds differ: a spread over seeds
    seeds = aggregate(table, (), ["m"]).set_index("group")["seeds"]
    assert seeds.to_dict() == {"a": "1,1,2", "b": "?,?", "c": "0,10"}


def test_configs_that_differ_beyond_the_label_are_never_one_group():
    """Labels name three values, each cut to 24 characters; runs were grouped by label, so a sweep's trials
    that differed only in a fourth key (or past the cut) were averaged as if they were seeds of one config."""
    long = "x" * 40
    runs = pd.DataFrame(
        {
            "run_id": [f"r{i}" for i in range(7)],
            "tags.algo": "ppo",
            "tags.seed": ["0", "1", "0", "0", "0", "0", "0"],
            "params.a": ["1", "1", "2", "1", "1", "1", "1"],
            "params.b": "1",
            "params.c": "1",
            "params.d": ["1", "1", "1", "2", "1", "1", "1"],
            "params.e": ["1", "1", "1", "1", "2", "1", "1"],
            "params.f": ["1", "1", "1", "1", "1", f"{long}1", f"{long}2"],  # differ past the cut
        }
    )
    g = assign_groups(runs, ("algo",))
    assert g["group"].nunique() == 6  # runs 0 and 1 (seeds 0 and 1 of one config) together, the rest apart
    assert g.loc[0, "group"] == g.loc[1, "group"]
    assert g.loc[5, "group"] != g.loc[6, "group"]
    # the labels of configs the first three values do not tell apart name what does
    assert "d=2" in g.loc[3, "group"] and "e=2" in g.loc[4, "group"]


def test_a_key_a_run_never_logged_counts_as_null():
    """Runs made before an opt-in key existed lack its param; those made after log its default, None. They are
    one config; a run that set the key is another."""
    runs = pd.DataFrame(
        {
            "run_id": ["old", "new", "set"],
            "tags.algo": "ppo",
            "tags.seed": ["0", "1", "2"],
            "params.algo.learning_rate": "0.0005",
            "params.algo.learning_rate_end": [np.nan, "None", "0.0"],
        }
    )
    g = assign_groups(runs, ("algo",))
    assert g.loc[0, "group"] == g.loc[1, "group"] != g.loc[2, "group"]
    assert "learning_rate_end=0.0" in g.loc[2, "group"]
    assert g.loc[0, "group"] == "algo.learning_rate_end=unset"  # a word, not a blank after the "="


def test_with_many_groups_the_bar_legend_covers_no_bar(tmp_path):
    from diana_lab.comparison.plots import plot_final_metrics, save_figure

    groups = pd.DataFrame(
        [
            {"group": f"algo.learning_rate={i}e-4, algo.n_steps={64 * i}", "eval_spl_mean": 0.9, "eval_spl_std": 0.05}
            for i in range(1, 10)
        ]
    )
    fig = plot_final_metrics(groups, ["eval_spl"])
    save_figure(fig, tmp_path / "bars.png")  # lays the figure out
    (ax,) = fig.axes
    renderer = fig.canvas.get_renderer()
    legend, plot_area = ax.get_legend().get_window_extent(renderer), ax.get_window_extent(renderer)
    assert legend.x0 >= plot_area.x1  # beside the axes, not over the bars (they reach 0.95 of the height)


def test_groups_counting_runs_that_did_not_finish_are_reported():
    from diana_lab.comparison.groups import unfinished_runs

    table = pd.DataFrame(
        {
            "run_id": ["r0", "r1", "r2", "r3"],
            "run_name": ["ppo-s0", "ppo-s1", "", "a2c-s0"],
            "status": ["FINISHED", "KILLED", "RUNNING", "FINISHED"],
            "group": ["a", "a", "a", "b"],
        }
    )
    assert unfinished_runs(table) == {"a": ["ppo-s1 (KILLED)", "r2 (RUNNING)"]}
    assert unfinished_runs(table.assign(status="FINISHED")) == {}
