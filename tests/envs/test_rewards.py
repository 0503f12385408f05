import math

import numpy as np
import pytest

from diana_lab.config import ConfigError, to_object
from diana_lab.envs.rewards import RewardContext, RewardManager
from diana_lab.sim.state import WaypointResult


def ctx(roll_deg=0.0, pitch_deg=0.0, outcome=None, prev=10.0, dist=8.0, heading=0.0, wp="reached", duration=5.0):
    rp = np.radians([[0.0, 0.0], [roll_deg, pitch_deg]])
    wr = WaypointResult(wp, duration, 2.0, np.zeros((2, 2)), np.zeros(2), rp)
    return RewardContext(prev, dist, heading, wr, outcome, 3)


def test_paper_constants_reproduce_hand_computed_values():
    manager = RewardManager(to_object("reward", "paper"))
    total, terms = manager(ctx(roll_deg=12.0, pitch_deg=3.0, heading=math.pi / 4, outcome="collision"))
    assert terms["progress"] == pytest.approx(600 * 2.0)
    assert terms["heading"] == pytest.approx(1.25 * (1 - 2 * math.sqrt(0.25)))
    assert terms["roll"] == pytest.approx(-661 * math.radians(7.0) ** 2)
    assert terms["pitch"] == 0.0  # inside the 5-degree deadband
    assert terms["collision"] == -400.0
    assert terms["goal"] == 0.0
    assert terms["step"] == -0.5
    assert total == pytest.approx(sum(terms.values()))


def test_heading_is_max_facing_the_goal_and_min_facing_away():
    manager = RewardManager(to_object("reward", "default"))
    w = manager.terms[[n for n, *_ in manager.terms].index("heading")][2]
    assert manager(ctx(heading=0.0))[1]["heading"] == pytest.approx(w)
    assert manager(ctx(heading=math.pi))[1]["heading"] == pytest.approx(-w)
    assert manager(ctx(heading=-math.pi))[1]["heading"] == pytest.approx(-w)


@pytest.mark.parametrize("deadband", [0.0, 5.0, 10.0])
def test_deadband_is_configurable(deadband):
    cfg = to_object(
        "reward",
        {
            "name": "t",
            "terms": {
                "roll": {
                    "fn": "diana_lab.envs.rewards.roll",
                    "weight": 1.0,
                    "params": {"deadband_deg": deadband},
                }
            },
        },
    )
    manager = RewardManager(cfg)
    assert manager(ctx(roll_deg=deadband - 0.5 if deadband else 0.0))[0] == 0.0
    assert manager(ctx(roll_deg=deadband + 4.0))[0] == pytest.approx(-(math.radians(4.0) ** 2))


def test_weight_zero_disables_a_term_and_goal_pays_on_success():
    cfg = to_object("reward", "default")
    cfg.terms["progress"].weight = 0.0
    total, terms = RewardManager(cfg)(ctx(outcome="success"))
    assert terms["progress"] == 0.0
    assert terms["goal"] == cfg.terms["goal"].weight


def test_unknown_term_function_or_parameter_is_a_clear_error():
    with pytest.raises(ConfigError, match=r"reward\.terms\.x\.fn"):
        RewardManager(to_object("reward", {"name": "t", "terms": {"x": {"fn": "diana_lab.envs.rewards.nope"}}}))
    with pytest.raises(ConfigError, match=r"reward\.terms\.roll\.params.*deadband"):
        RewardManager(
            to_object(
                "reward",
                {
                    "name": "t",
                    "terms": {"roll": {"fn": "diana_lab.envs.rewards.roll", "params": {"deadbnd_deg": 3}}},
                },
            )
        )


@pytest.mark.parametrize(("wp", "want"), [("reached", 0.0), ("stuck", -1.0), ("gave_up", -1.0), ("halted", -1.0)])
def test_stall_pays_for_a_waypoint_the_controller_could_not_finish(wp, want):
    from diana_lab.envs.rewards import stall

    assert stall(ctx(wp=wp)) == want
