import numpy as np

from diana_lab.evaluation import AStarOracle, StraightLine, make_suite, run_suite
from diana_lab.evaluation.suite import reachable_goal


def test_same_seed_same_suite_other_seed_other_suite(flat_env):
    a = make_suite(flat_env, 6, 5, 5.0, 12.0)
    b = make_suite(flat_env, 6, 5, 5.0, 12.0)
    c = make_suite(flat_env, 6, 6, 5.0, 12.0)
    assert a == b
    assert a != c
    for ep in a:
        assert 5.0 <= np.hypot(*(ep.goal - ep.start)) <= 12.0
        assert reachable_goal(flat_env, ep.goal)


def test_suite_is_independent_of_training_draws(flat_env):
    first = make_suite(flat_env, 4, 11, 5.0, 12.0)
    drawn = flat_env.sampler.episodes_drawn
    for _ in range(3):
        flat_env.reset()  # training-style episodes move the env's generator and the curriculum counter
    assert flat_env.sampler.episodes_drawn == drawn + 3
    assert make_suite(flat_env, 4, 11, 5.0, 12.0) == first
    assert flat_env.sampler.episodes_drawn == drawn + 3  # building a suite leaves the curriculum alone


def test_every_policy_meets_the_same_episodes(flat_env):
    suite = make_suite(flat_env, 3, 2, 5.0, 12.0)
    cols = ["start_x", "start_y", "start_yaw", "goal_x", "goal_y", "straight_distance_m", "shortest_path_m"]
    a = run_suite(StraightLine(), flat_env, suite)[cols]
    b = run_suite(AStarOracle(), flat_env, suite)[cols]
    assert a.equals(b)
    np.testing.assert_array_equal(a[["start_x", "start_y"]].to_numpy(), [ep.start for ep in suite])


def test_impossible_suite_distances_name_the_eval_keys(flat_env):
    """The suite's distances are ``eval.*``: the error used to name ``episode.min_distance``, which the user never
    set; a training episode draw still names ``episode``."""
    import pytest

    from diana_lab.config import ConfigError

    with pytest.raises(ConfigError, match=r"^eval\.min_distance/max_distance: no start/goal pair 50\.0\.\.60\.0 m"):
        make_suite(flat_env, 2, 0, 50.0, 60.0)
    with pytest.raises(ConfigError, match=r"^episode\.min_distance/max_distance"):
        flat_env.unwrapped.sampler.sample(np.random.default_rng(0), 50.0, 60.0)
