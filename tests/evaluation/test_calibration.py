"""``python -m diana_lab.calibrate``: the kinematic model against PyBullet on the same waypoints, and the scoring
of each ``dynamics.guard_overshoot`` by its tip-overs."""

import json
import math

import numpy as np
import pytest

from diana_lab.core.validation import ConfigError
from diana_lab.evaluation.calibration import Calibration, CalibrationSetup, score_tipovers
from tests.entrypoints import run_in_process


def test_tipover_scores_count_the_waypoints_both_models_call_tipover():
    physics = ["tipover", "tipover", "reached", "halted", "tipover", "reached"]
    kinematic = ["tipover", "halted", "tipover", "halted", "reached", "reached"]
    s = score_tipovers(physics, kinematic, 0.2)
    assert (s.kinematic_tipovers, s.agreed_tipovers) == (2, 1)
    assert s.recall == pytest.approx(1 / 3) and s.precision == pytest.approx(1 / 2)
    assert s.f1 == pytest.approx(2 * 1 / (3 + 2))
    assert s.outcomes == {
        "tipover -> tipover": 1,
        "tipover -> halted": 1,
        "reached -> tipover": 1,
        "halted -> halted": 1,
        "tipover -> reached": 1,
        "reached -> reached": 1,
    }
    none = score_tipovers(["reached"], ["reached"], 0.0)
    assert math.isnan(none.recall) and math.isnan(none.precision) and math.isnan(none.f1)
    with pytest.raises(ValueError, match="2 physics outcomes against 1"):
        score_tipovers(["reached", "reached"], ["reached"], 0.0)


def test_the_best_overshoot_has_the_highest_f1_and_the_smallest_on_a_tie():
    physics = ["tipover", "tipover", "reached"]
    scores = [
        score_tipovers(physics, ["reached", "reached", "reached"], 0.0),
        score_tipovers(physics, ["tipover", "reached", "reached"], 0.1),
        score_tipovers(physics, ["tipover", "tipover", "reached"], 0.2),
        score_tipovers(physics, ["tipover", "tipover", "reached"], 0.3),
    ]
    assert Calibration(3, 1, {"tipover": 2, "reached": 1}, scores).best.overshoot == 0.2
    calm = [score_tipovers(["reached"], ["reached"], o) for o in (0.3, 0.1)]  # no tip-over anywhere: F1 undefined
    assert Calibration(1, 1, {"reached": 1}, calm).best.overshoot == 0.1


@pytest.mark.parametrize(
    "kwargs, key",
    [({"starts": 0}, "starts"), ({"waypoints": -1}, "waypoints"), ({"distances": ()}, "distances"),
     ({"distances": (1.0, 0.0)}, "distances"), ({"overshoots": (0.1, -0.2)}, "overshoots"),
     ({"overshoots": ()}, "overshoots")],
)  # fmt: skip
def test_bad_settings_name_their_key(kwargs, key):
    with pytest.raises(ConfigError, match=key):
        CalibrationSetup(**kwargs)


def run(tmp_path, *args):
    return run_in_process("diana_lab.calibrate", [*args, f"hydra.run.dir={tmp_path}/run"])


def test_calibrate_drives_both_models_and_writes_every_pair(tmp_path, capsys):
    out = tmp_path / "cal.json"
    args = ["starts=3", "waypoints=4", "overshoots=[0.0,0.3]", "seed=5"]
    assert run(tmp_path, *args, f"output={out}") == 0
    first = json.loads(out.read_text())
    printed = capsys.readouterr().out
    assert "best tip-over F1 at dynamics.guard_overshoot=" in printed
    n = first["waypoints"]
    assert 3 <= n <= 12 and sum(first["physics_outcomes"].values()) == n
    assert [s["overshoot"] for s in first["scores"]] == [0.0, 0.3]
    for s in first["scores"]:  # every waypoint is one pair of outcomes, the physics side the same for each
        assert sum(s["outcomes"].values()) == n
        physics_side: dict[str, int] = {}
        for pair, count in s["outcomes"].items():
            p = pair.split(" -> ")[0]
            physics_side[p] = physics_side.get(p, 0) + count
        assert physics_side == first["physics_outcomes"]
    again = tmp_path / "again.json"
    assert run(tmp_path, *args, f"output={again}") == 0
    assert json.loads(again.read_text()) == first  # same seed, same drives
    other = tmp_path / "other.json"
    assert run(tmp_path, "starts=3", "waypoints=4", "overshoots=[0.0,0.3]", "seed=6", f"output={other}") == 0
    assert json.loads(other.read_text()) != first


@pytest.mark.parametrize(
    "args, message",
    [(["dynamics=physics"], "expected dynamics=kinematic"), (["starts=0"], "starts"),
     (["physics=kinematic"], "physics: expected the physics dynamics option")],
)  # fmt: skip
def test_calibrate_refuses_bad_input_naming_the_key(tmp_path, capsys, args, message):
    assert run(tmp_path, "waypoints=1", *args) == 2
    assert message in capsys.readouterr().err


def test_with_a_policy_the_waypoints_are_its_own_and_physics_runs_as_in_evaluate(tmp_path):
    """The kinematic twins drive beside the physics rover without changing its run: the policy's summary is
    the one ``python -m diana_lab.evaluate ... eval.dynamics=physics`` gives on the same suite."""
    suite = ["policy=bearing", "eval.episodes=2", "eval.seed=3", "eval.min_distance=6", "eval.max_distance=10"]
    cal, ev = tmp_path / "cal.json", tmp_path / "eval.json"
    assert run(tmp_path, *suite, "overshoots=[0.0,0.2]", f"output={cal}") == 0
    argv = [*suite, "eval.dynamics=physics", "tracking.enabled=false", "eval.plots=false", "eval.video=false"]
    assert run_in_process("diana_lab.evaluate", [*argv, f"output={ev}", f"hydra.run.dir={tmp_path}/ev"]) == 0
    got, want = json.loads(cal.read_text()), json.loads(ev.read_text())
    assert got["starts"] == 2 and got["waypoints"] >= 2
    for key in ("success_rate", "spl", "tipover_rate", "stuck_rate"):
        assert got["policy_summary"][key] == pytest.approx(want[key]), key
    assert all(sum(s["outcomes"].values()) == got["waypoints"] for s in got["scores"])


def test_the_twin_records_both_models_and_is_the_physics_model_otherwise(flat_world):
    from diana_lab.config import build, to_object
    from diana_lab.evaluation.calibration import KinematicTwin
    from diana_lab.sim.controller import TurnThenDrive
    from diana_lab.sim.kinematic import KinematicDynamics

    robot = to_object("robot", "jackal")
    kin_cfg, phy_cfg = to_object("dynamics", "kinematic"), to_object("dynamics", "physics")
    physics = build(phy_cfg, flat_world, robot)
    twin = KinematicTwin(
        physics, [KinematicDynamics(kin_cfg, flat_world, robot)], TurnThenDrive(kin_cfg.controller, robot)
    )
    try:
        twin.reset(np.array([0.0, 0.0]), 0.0)  # delegated
        result = twin.execute(np.array([2.0, 0.0]), TurnThenDrive(phy_cfg.controller, robot))
        assert result.outcome == "reached" and twin.physics_out == ["reached"] and twin.kinematic_out == [["reached"]]
        assert twin.state.xy[0] == pytest.approx(physics.state.xy[0]) and twin.state.xy[0] > 1.5
    finally:
        physics.close()
