import dataclasses
import math
import re

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


def double_progress(ctx: RewardContext, scale: float = 2.0) -> float:
    """A user's own term, for the test below: ``scale`` times the progress made."""
    return scale * (ctx.prev_distance - ctx.distance)


def test_a_term_of_ones_own_is_added_from_the_command_line_and_reported_per_step():
    """``{fn, weight, params}`` is data: a new term needs no code in the package and no config file."""
    from diana_lab.config import compose
    from diana_lab.envs.rover_nav import RoverNavEnv
    from diana_lab.training.envs import env_config

    mine = "+reward.terms.mine={fn: tests.envs.test_rewards.double_progress, weight: 0.5, params: {scale: 3.0}}"
    cfg = compose(["world=flat", "sensor=depth_camera", "sensor.width=16", "sensor.height=12", mine])
    reward = to_object("reward", cfg.reward)
    assert reward.terms["mine"].fn.endswith("double_progress") and reward.terms["mine"].params == {"scale": 3.0}
    assert RewardManager(reward)(ctx(prev=10.0, dist=8.0))[1]["mine"] == pytest.approx(0.5 * 3.0 * 2.0)
    env = RoverNavEnv(config=env_config(cfg))
    try:
        env.reset(seed=0)
        _, total, *_, info = env.step(env.action_space.sample())
        assert "mine" in info["reward_terms"] and total == pytest.approx(sum(info["reward_terms"].values()))
    finally:
        env.close()
    # the same, one key at a time
    keys = ["+reward.terms.mine.fn=tests.envs.test_rewards.double_progress", "+reward.terms.mine.weight=0.25"]
    assert to_object("reward", compose(keys).reward).terms["mine"].weight == 0.25


@pytest.mark.parametrize(
    ("term", "named"),
    [
        ({"weight": 1.0}, r"reward\.terms\.x\.fn: expected a function's dotted path"),
        ({"fn": "diana_lab.envs.rewards.goal", "wieght": 1.0}, r"reward\.terms\.x: unknown key\(s\) \['wieght'\]"),
        ({"fn": "diana_lab.envs.rewards.goal", "weight": "heavy"}, r"reward\.terms\.x\.weight: expected a number"),
        ({"fn": "diana_lab.envs.rewards.goal", "params": [1]}, r"reward\.terms\.x\.params: expected a mapping"),
        (3.0, r"reward\.terms\.x: expected a mapping"),
    ],
)
def test_a_malformed_term_is_refused_naming_its_key(term, named):
    with pytest.raises(ConfigError, match=named):
        to_object("reward", {"name": "t", "terms": {"x": term}})


@pytest.mark.parametrize(("outcome", "want"), [("stuck", -1.0), ("timeout", 0.0), (None, 0.0), ("tipover", 0.0)])
def test_stuck_pays_only_on_the_step_an_episode_ends_stuck(outcome, want):
    from diana_lab.envs.rewards import stuck

    assert stuck(ctx(outcome=outcome)) == want


@pytest.mark.parametrize(
    ("outcome", "path", "start", "want"),
    [
        ("success", 25.0, 20.0, 0.8),  # a path 1.25 times the straight line
        ("success", 19.6, 20.0, 1.0),  # the goal reached within tolerance before the full straight line: capped
        ("success", 0.0, 0.3, 0.0),  # started within tolerance: nothing driven, nothing to pay for
        ("stuck", 25.0, 20.0, 0.0),
        (None, 25.0, 20.0, 0.0),
    ],
)
def test_efficiency_pays_a_success_for_how_short_its_path_was(outcome, path, start, want):
    from diana_lab.envs.rewards import efficiency

    assert efficiency(dataclasses.replace(ctx(outcome=outcome), path_length=path, start_distance=start)) == (
        pytest.approx(want)
    )


def test_every_built_in_term_of_the_batched_env_computes_what_the_scalar_term_does():
    """The batched env's array form of each built-in term against the scalar function, rover by rover, over
    random steps that cover every outcome (the parity tests' random drives seldom reach a goal)."""
    from diana_lab.envs.batched.rewards import BUILT_IN, BatchContext

    rng = np.random.default_rng(3)
    outcomes = np.array(["", "success", "collision", "tipover", "out_of_bounds", "stuck", "timeout"])
    waypoints = np.array(["reached", "stuck", "gave_up", "halted", "collision", "tipover"])
    contexts = []
    for k in range(200):
        c = ctx(
            roll_deg=rng.uniform(-30, 30),
            pitch_deg=rng.uniform(-30, 30),
            outcome=str(outcomes[k % len(outcomes)]) or None,
            prev=rng.uniform(0, 30),
            dist=rng.uniform(0, 30),
            heading=rng.uniform(-4, 4),
            wp=str(waypoints[k % len(waypoints)]),
            duration=rng.uniform(0, 20),
        )
        path = 0.0 if k % 11 == 0 else rng.uniform(0.1, 60)
        step, start = int(rng.integers(1, 60)), rng.uniform(0, 30)
        way = rng.uniform(0, 40, size=2)
        contexts.append(
            dataclasses.replace(
                c, step=step, path_length=path, start_distance=start, prev_path_to_goal=way[0], path_to_goal=way[1]
            )
        )
    batch = BatchContext(
        prev_distance=np.array([c.prev_distance for c in contexts]),
        distance=np.array([c.distance for c in contexts]),
        heading_error=np.array([c.heading_error for c in contexts]),
        max_abs_roll=np.array([np.abs(c.waypoint.trace_rp[:, 0]).max() for c in contexts]),
        max_abs_pitch=np.array([np.abs(c.waypoint.trace_rp[:, 1]).max() for c in contexts]),
        duration=np.array([c.waypoint.duration for c in contexts]),
        waypoint_outcome=np.array([c.waypoint.outcome for c in contexts]),
        outcome=np.array([c.outcome or "" for c in contexts]),
        step=np.array([c.step for c in contexts]),
        path_length=np.array([c.path_length for c in contexts]),
        start_distance=np.array([c.start_distance for c in contexts]),
        context=contexts.__getitem__,
        prev_path_to_goal=np.array([c.prev_path_to_goal for c in contexts]),
        path_to_goal=np.array([c.path_to_goal for c in contexts]),
    )
    for fn, array_form in BUILT_IN.items():
        want = [fn(c) for c in contexts]
        np.testing.assert_allclose(array_form(batch), want, rtol=1e-12, atol=1e-12, err_msg=fn.__name__)
        assert len(set(want)) > 1 or fn.__name__ == "step", f"{fn.__name__}: the random steps do not exercise it"


def _path_term(params: str = "{}", weight: float = 1.0) -> list[str]:
    return [f"+reward.terms.way={{fn: diana_lab.envs.rewards.path_progress, weight: {weight}, params: {params}}}"]


def _manager(overrides: list[str]) -> RewardManager:
    from diana_lab.config import compose

    return RewardManager(to_object("reward", compose(overrides)["reward"]))


def test_path_progress_pays_the_metres_gained_along_the_drivable_way():
    from diana_lab.envs.rewards import path_progress

    c = dataclasses.replace(ctx(prev=10.0, dist=8.0), prev_path_to_goal=14.0, path_to_goal=11.5)
    assert path_progress(c) == pytest.approx(2.5)  # not the straight line's 2.0
    assert path_progress(c, scale=2.0) == pytest.approx(1.25)
    back = dataclasses.replace(c, prev_path_to_goal=11.5, path_to_goal=14.0)
    assert path_progress(back) == pytest.approx(-2.5)


def test_the_goal_distance_field_is_asked_for_only_by_a_weighted_term_that_reads_it():
    assert RewardManager(to_object("reward", "default")).goal_field is None
    assert _manager(_path_term()).goal_field == (2, 10.0)
    wanted = _manager(_path_term("{stride: 3, untraversable_cost: 4}"))
    assert wanted.goal_field == (3, 4.0)
    assert _manager(_path_term(weight=0.0)).goal_field is None


@pytest.mark.parametrize(
    ("params", "key"),
    [
        ("{stride: 0}", "reward.terms.way.params.stride"),
        ("{stride: 1.5}", "reward.terms.way.params.stride"),
        ("{untraversable_cost: 0.5}", "reward.terms.way.params.untraversable_cost"),
        ("{untraversable_cost: .inf}", "reward.terms.way.params.untraversable_cost"),
    ],
)
def test_a_bad_goal_distance_field_is_named(params, key):
    with pytest.raises(ConfigError, match=re.escape(key)):
        _manager(_path_term(params))


def test_two_terms_reading_different_fields_are_refused():
    both = [
        *_path_term("{stride: 2}"),
        "+reward.terms.way2={fn: diana_lab.envs.rewards.path_progress, weight: 1.0, params: {stride: 3}}",
    ]
    with pytest.raises(ConfigError, match="different"):
        _manager(both)
