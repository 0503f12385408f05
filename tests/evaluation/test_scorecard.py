"""``python -m diana_lab.scorecard``: policies on several suites, checked against targets."""

import json
import math

import pytest

from diana_lab.core.validation import ConfigError
from diana_lab.evaluation.scorecard import check, compare, parse_card, parse_target
from diana_lab.scorecard import merge_overrides
from tests.entrypoints import run_in_process

CONDITIONS = {
    "yard": {"overrides": [], "targets": {"success_rate": ">= 0.9", "tipover_rate": "<= 0"}},
    "noise": {"overrides": ["sensor.noise=realistic"], "targets": {"success_rate": ">= yard - 0.05"}},
}
ENTRIES = {"net": {"overrides": [], "scored": True}, "base": {"overrides": ["policy=bearing"]}}


def test_targets_read_absolute_and_relative_bounds():
    t = parse_target("c", "success_rate", ">= 0.95", ["yard"])
    assert (t.op, t.value, t.relative_to) == (">=", 0.95, None)
    r = parse_target("c", "success_rate", " >= yard - 0.05", ["yard"])
    assert (r.op, r.value, r.relative_to) == (">=", -0.05, "yard")
    assert r.bound({"yard": {"success_rate": 0.8}}) == pytest.approx(0.75)
    assert math.isnan(r.bound({}))
    assert parse_target("c", "tipover_rate", "<=0", []).met(0.0, 0.0)
    assert not parse_target("c", "tipover_rate", "<= 0", []).met(0.01, 0.0)
    assert not t.met(math.nan, 0.95)


@pytest.mark.parametrize(
    "spec, message",
    [("> 0.9", "expected '>= <number>'"), ("0.9", "expected"), (">= yard * 2", "expected"),
     (">= moon - 0.05", "refers to condition 'moon'")],
)  # fmt: skip
def test_a_malformed_target_names_its_key(spec, message):
    with pytest.raises(ConfigError, match=rf"conditions\.x\.targets\.spl: .*{message}"):
        parse_target("conditions.x.targets", "spl", spec, ["yard"])


def test_the_card_runs_what_is_chosen_and_refuses_what_cannot_be_checked():
    conds, entries, comps = parse_card(CONDITIONS, ENTRIES, [{"entry": "net", "over": "base"}], None, ["net", "base"])
    assert [c.name for c in conds] == ["yard", "noise"] and [e.name for e in entries] == ["net", "base"]
    assert entries[0].scored and not entries[1].scored and comps[0].key == "success_rate"
    assert conds[1].overrides == ("sensor.noise=realistic",)
    _, _, none = parse_card(CONDITIONS, ENTRIES, [{"entry": "net", "over": "base"}], None, ["net"])
    assert none == []  # a comparison with an entry left out is not made
    with pytest.raises(ConfigError, match=r"conditions\.noise\.targets\.success_rate: .*needs condition 'yard'"):
        parse_card(CONDITIONS, ENTRIES, None, ["noise"])
    with pytest.raises(ConfigError, match=r"only\.entries: no 'moon'"):
        parse_card(CONDITIONS, ENTRIES, None, None, ["moon"])
    with pytest.raises(ConfigError, match=r"comparisons\[0\]: no entry 'moon'"):
        parse_card(CONDITIONS, ENTRIES, [{"entry": "moon", "over": "base"}])
    with pytest.raises(ConfigError, match=r"entries\.net\.overrides: expected a list"):
        parse_card(CONDITIONS, {"net": {"overrides": "shield=veto"}})
    with pytest.raises(ConfigError, match="conditions: expected a non-empty mapping"):
        parse_card({}, ENTRIES)


def test_targets_and_comparisons_are_checked_per_entry_and_condition():
    conds, entries, comps = parse_card(CONDITIONS, ENTRIES, [{"entry": "net", "over": "base"}])
    summaries = {
        "net": {
            "yard": {"success_rate": 0.92, "tipover_rate": 0.01, "success_rate_ci95": [0.85, 0.96]},
            "noise": {"success_rate": 0.86, "success_rate_ci95": [0.78, 0.91]},
        },
        "base": {
            "yard": {"success_rate": 0.5, "success_rate_ci95": [0.4, 0.6]},
            "noise": {"success_rate": 0.8, "success_rate_ci95": [0.71, 0.87]},
        },
    }
    rows = {(r["condition"], r["key"]): r for r in check(conds, entries, summaries)}
    assert len(rows) == 3 and {r["entry"] for r in rows.values()} == {"net"}  # only scored entries
    assert rows[("yard", "success_rate")]["met"] and not rows[("yard", "tipover_rate")]["met"]
    assert rows[("noise", "success_rate")]["bound"] == pytest.approx(0.87)
    assert not rows[("noise", "success_rate")]["met"]  # 0.86 is 6 points under its own yard figure
    versus = {r["condition"]: r for r in compare(conds, comps, summaries)}
    assert versus["yard"]["clearly"] and not versus["noise"]["clearly"]  # 0.78 > 0.6; 0.78 < 0.87


def test_later_overrides_win_over_the_command_lines():
    base = ["policy=model", "policy.source=/m.zip", "eval.seed=3", "+experiment=quick", "shield=off"]
    got = merge_overrides(base, ("world=craters",), ("policy=bearing", "shield=veto"))
    assert got == ["eval.seed=3", "+experiment=quick", "world=craters", "policy=bearing", "shield=veto"]


def run(tmp_path, *args):
    quiet = ["tracking.enabled=false", "eval.plots=false", "eval.video=false", "comparisons=[]"]
    return run_in_process("diana_lab.scorecard", [*quiet, *args, f"hydra.run.dir={tmp_path}/run"])


def test_the_card_holds_each_evaluation_as_evaluate_gives_it(tmp_path, capsys):
    suite = ["world=flat", "eval.episodes=2", "eval.seed=3", "eval.min_distance=6", "eval.max_distance=10"]
    out = tmp_path / "card.json"
    args = [*suite, "policy=straight", "only.conditions=[yard,noise]", "only.entries=[network,bearing + veto]"]
    assert run(tmp_path, *args, f"output={out}") == 0
    card = json.loads(out.read_text())
    printed = capsys.readouterr().out
    assert "targets met:" in printed and "scorecard" in printed
    ev = tmp_path / "ev.json"
    argv = [*suite, "policy=bearing", "shield=veto", "sensor.noise=realistic", "tracking.enabled=false"]
    argv += ["eval.plots=false", "eval.video=false", f"output={ev}", f"hydra.run.dir={tmp_path}/ev"]
    assert run_in_process("diana_lab.evaluate", argv) == 0
    want = json.loads(ev.read_text())
    got = card["summaries"]["bearing + veto"]["noise"]
    for key in ("success_rate", "spl", "mean_path_length_m", "collision_rate"):
        assert got[key] == pytest.approx(want[key]), key
    keys = {(r["entry"], r["condition"], r["key"]) for r in card["targets"]}  # network's only: it is scored
    assert ("network", "noise", "success_rate") in keys and all(e == "network" for e, _, _ in keys)
    noise = next(r for r in card["targets"] if r["condition"] == "noise")
    assert noise["bound"] == pytest.approx(card["summaries"]["network"]["yard"]["success_rate"] - 0.05)
    assert (tmp_path / "run" / "noise" / "bearing_veto" / "episodes.csv").is_file()


def test_a_failing_evaluation_is_recorded_and_the_rest_go_on(tmp_path, capsys):
    args = ["world=flat", "eval.episodes=1", "only.conditions=[yard]", "only.entries=[network,straight]"]
    assert run(tmp_path, *args, "policy=/nowhere/model.zip") == 2
    card = json.loads((tmp_path / "run" / "card.json").read_text())
    assert "error" in card["summaries"]["network"]["yard"]
    assert card["summaries"]["straight"]["yard"]["episodes"] == 1
    assert "1 evaluation(s) failed (network on yard)" in capsys.readouterr().err


BAD_CRATERS = 'conditions.craters.overrides=["world=craters","world.n_craters=-1"]'


@pytest.mark.parametrize(
    "args, message",
    [(["world=flat"], "policy: expected the policy under test"),
     (["policy=straight", "only.conditions=[moon]"], "only.conditions: no 'moon'"),
     (["policy=straight", "only.conditions=[noise]"], "needs condition 'yard'"),
     (["policy=straight", "only.conditions=[craters]", BAD_CRATERS],
      "conditions.craters x entries.network: world.n_craters: expected a number >= 0"),
     (["policy=straight", "only.conditions=[yard]", 'conditions.yard.overrides=["robot=moon"]'], "robot=moon")],
)  # fmt: skip
def test_bad_input_stops_before_any_evaluation(tmp_path, capsys, args, message):
    assert run(tmp_path, *args) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "run" / "yard").exists()


def test_every_entry_runs_the_command_lines_suite_even_behind_a_preset_that_sets_its_own(tmp_path):
    """``+experiment=reference`` sets ``eval.episodes: 50``; in the card the suite stays the command line's."""
    preset = '+entries.preset={overrides: ["policy=straight", "+experiment=reference"]}'  # an entry of one's own
    # no eval.episodes on the command line: the card's own (100) must hold for the preset's entry too
    args = ["world=flat", "eval.seed=4", "eval.min_distance=6", "eval.max_distance=7", "only.conditions=[yard]", preset]
    assert run(tmp_path, *args, "only.entries=[preset,straight]") == 0
    card = json.loads((tmp_path / "run" / "card.json").read_text())
    assert card["summaries"]["preset"]["yard"]["episodes"] == card["summaries"]["straight"]["yard"]["episodes"] == 100
    assert card["summaries"]["preset"]["yard"]["success_rate"] == card["summaries"]["straight"]["yard"]["success_rate"]
