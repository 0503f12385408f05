"""Groups against a baseline, paired by seed: the statistics, the host check and naming the baseline."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from diana_lab.comparison import ComparisonError, compare_runs
from diana_lab.comparison.paired import mixed_host_groups, paired_differences, resolve_baseline
from diana_lab.tracking.host import cpu_model

from .store import make_paired_store
from .test_compare_cli import run_compare


def table(rows: list[tuple[str, str, float, str]]) -> pd.DataFrame:
    """A runs table: (group, seed, eval_spl, host_cpu) per run, ids r0, r1, ..."""
    return pd.DataFrame(
        {
            "run_id": [f"r{i:08d}" for i in range(len(rows))],
            "group": [r[0] for r in rows],
            "seed": [r[1] for r in rows],
            "eval_spl": [r[2] for r in rows],
            "host_cpu": [r[3] for r in rows],
        }
    )


BASE = [("A", "0", 0.50, "x"), ("A", "1", 0.60, "x"), ("A", "2", 0.40, "x"), ("A", "3", 0.70, "x")]


def test_differences_are_taken_seed_by_seed_over_the_shared_seeds_only():
    # B beats A by 0.04-0.06 on each shared seed, though both groups' own spread over seeds (0.1-0.2) dwarfs that
    b = [("B", "0", 0.55, "x"), ("B", "1", 0.64, "x"), ("B", "2", 0.46, "x"), ("B", "9", 0.10, "x")]
    row = paired_differences(table(BASE + b), "A", ["eval_spl"]).iloc[0]
    d = np.array([0.05, 0.04, 0.06])
    assert row["group"] == "B" and row["pairs"] == 3 and row["seeds"] == "0,1,2"  # seeds 3 and 9 unpaired
    assert row["baseline_mean"] == pytest.approx(0.5) and row["group_mean"] == pytest.approx(0.55)
    assert row["diff_mean"] == pytest.approx(d.mean()) and row["diff_std"] == pytest.approx(d.std(ddof=1))
    t = d.mean() / (d.std(ddof=1) / math.sqrt(3))
    assert row["t"] == pytest.approx(t) and row["p_two_sided"] == pytest.approx(2 * stats.t.sf(t, 2))
    half = stats.t.ppf(0.975, 2) * d.std(ddof=1) / math.sqrt(3)
    assert (row["ci95_low"], row["ci95_high"]) == pytest.approx((d.mean() - half, d.mean() + half))
    assert row["ci95_low"] > 0  # the paired interval excludes 0
    assert row["hosts"] == "same"


def test_one_pair_gives_a_difference_without_spread_and_no_shared_seed_gives_none():
    t = table([*BASE, ("B", "1", 0.65, "x"), ("C", "7", 0.9, "x")])
    out = paired_differences(t, "A", ["eval_spl"]).set_index("group")
    assert out.loc["B", "pairs"] == 1 and out.loc["B", "diff_mean"] == pytest.approx(0.05)
    assert all(math.isnan(out.loc["B", k]) for k in ("diff_std", "t", "ci95_low", "ci95_high", "p_two_sided"))
    assert out.loc["C", "pairs"] == 0 and math.isnan(out.loc["C", "diff_mean"])


def test_runs_repeating_a_seed_count_once_with_their_mean():
    t = table([*BASE, ("B", "0", 0.60, "x"), ("B", "0", 0.70, "x"), ("B", "1", 0.60, "x")])
    row = paired_differences(t, "A", ["eval_spl"]).iloc[0]
    assert row["pairs"] == 2 and row["diff_mean"] == pytest.approx(((0.65 - 0.50) + 0.0) / 2)


@pytest.mark.parametrize(
    ("hosts_b", "expected"),
    [
        (("x", "x"), "same"),
        (("x", "y"), "mixed (1 of 2 pairs)"),
        (("", "x"), "unknown"),
        (("y", ""), "mixed (1 of 2 pairs)"),  # one pair is known to differ: that outweighs the unknown one
        (("x", "x", "y", ""), "mixed (1 of 2 pairs)"),  # seed 1 run three times, one untagged: still known mixed
    ],
)
def test_hosts_say_whether_each_pair_trained_on_one_kind_of_cpu(hosts_b, expected):
    seeds = ["0", *["1"] * (len(hosts_b) - 1)]  # B's runs: seed 0, then seed 1 (once or more)
    t = table([*BASE, *(("B", s, 0.5, h) for s, h in zip(seeds, hosts_b, strict=True))])
    assert paired_differences(t, "A", ["eval_spl"]).iloc[0]["hosts"] == expected


def test_groups_trained_on_several_kinds_of_cpu_are_named():
    t = table([*BASE, ("B", "0", 0.5, "y"), ("B", "1", 0.5, "z"), ("B", "2", 0.5, "")])
    assert mixed_host_groups(t) == {"B": ["y", "z"]}


@pytest.mark.parametrize(
    ("name", "expected"),
    [("algo=ppo / lr=1", "algo=ppo / lr=1"), ("lr=2", "algo=ppo / lr=2"), ("r00000001", "algo=ppo / lr=2")],
)
def test_the_baseline_is_a_label_a_part_of_one_or_a_run_id(name, expected):
    t = pd.DataFrame({"run_id": ["r00000000", "r00000001"], "group": ["algo=ppo / lr=1", "algo=ppo / lr=2"]})
    assert resolve_baseline(t, name) == expected


@pytest.mark.parametrize(("name", "why"), [("lr=", "is part of 2 group labels"), ("sac", "is no group's label")])
def test_a_baseline_naming_no_group_or_several_is_an_error_listing_the_groups(name, why):
    t = pd.DataFrame({"run_id": ["r00000000", "r00000001"], "group": ["algo=ppo / lr=1", "algo=ppo / lr=2"]})
    with pytest.raises(ComparisonError, match=why) as err:
        resolve_baseline(t, name)
    assert f"baseline={name!r}" in str(err.value) and "\n  algo=ppo / lr=1\n  algo=ppo / lr=2" in str(err.value)


def test_compare_runs_pairs_the_stored_runs_by_seed(tmp_path):
    uri = make_paired_store(tmp_path)
    c = compare_runs(uri, ["diana_lab"], metrics=["eval_spl"], curves=[], baseline="learning_rate=0.0003")
    assert c.baseline == "algo.learning_rate=0.0003"
    row = c.paired.iloc[0]
    assert row["group"] == "algo.learning_rate=0.001" and row["pairs"] == 3
    assert row["diff_mean"] == pytest.approx(np.mean([0.05, 0.02, 0.10]))
    assert row["hosts"] == "mixed (1 of 3 pairs)"  # seed 2 of the candidate trained on cpu B
    assert c.mixed_hosts == {"algo.learning_rate=0.001": ["cpu A", "cpu B"]}
    assert set(c.runs["host_cpu"]) == {"cpu A", "cpu B"}


def test_cli_writes_the_paired_table_and_warns_of_mixed_hosts(tmp_path, capsys):
    uri = make_paired_store(tmp_path / "store")
    out = tmp_path / "cmp"
    code = run_compare([f"tracking.uri={uri}", "baseline='learning_rate=0.0003'", "curves=[]", f"output={out}"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    paired = pd.read_csv(out / "paired.csv").set_index("metric")
    assert paired.loc["eval_spl", "pairs"] == 3 and paired.loc["eval_spl", "diff_mean"] == pytest.approx(0.0566667)
    md = (out / "paired.md").read_text()
    assert "Against the baseline group 'algo.learning_rate=0.0003'" in md and "+0.057" in md
    assert "paired by seed" in captured.out and "mixed (1 of 3 pairs)" in captured.out
    assert "trained on different kinds of CPU" in captured.err and "2 kinds of CPU (cpu A; cpu B)" in captured.err


def test_cli_without_a_baseline_writes_no_paired_table(tmp_path, capsys):
    uri = make_paired_store(tmp_path / "store")
    code = run_compare([f"tracking.uri={uri}", "curves=[]", f"output={tmp_path / 'cmp'}"])
    assert code == 0, capsys.readouterr().err
    assert not (tmp_path / "cmp" / "paired.csv").exists()


def test_cli_baseline_naming_no_group_exits_2(tmp_path, capsys):
    uri = make_paired_store(tmp_path / "store")
    code = run_compare([f"tracking.uri={uri}", "baseline=sac", f"output={tmp_path / 'cmp'}"])
    err = capsys.readouterr().err
    assert code == 2 and "baseline='sac' is no group's label" in err and "Traceback" not in err
    assert not (tmp_path / "cmp" / "groups.csv").exists()


def test_cpu_model_reads_the_model_name(tmp_path):
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nvendor_id\t: X\nmodel name\t: Intel(R)  Xeon(R) Processor @ 2.80GHz\n")
    assert cpu_model.__wrapped__(info) == "Intel(R) Xeon(R) Processor @ 2.80GHz"
    assert cpu_model.__wrapped__(tmp_path / "missing")  # falls back to the platform's name, never empty
    assert cpu_model() == cpu_model()
