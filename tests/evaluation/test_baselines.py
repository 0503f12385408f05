import math

import gymnasium as gym
import numpy as np
import pytest

from diana_lab.config import compose
from diana_lab.envs.rover_nav import RoverNavEnv
from diana_lab.evaluation import (
    AStarOracle,
    EpisodeSpec,
    StraightLine,
    run_episodes,
    run_suite,
    waypoint_action,
)
from diana_lab.evaluation.policies import SB3Policy
from tests.evaluation.conftest import SMALL_FLAT, small_env, wall_world

WALL_EPISODE = EpisodeSpec(np.array([-4.0, 0.5]), 0.3, np.array([4.0, -0.5]), seed=3)


def test_astar_drives_around_a_wall_of_rocks_that_straight_hits(wall_env):
    straight = run_suite(StraightLine(), wall_env, [WALL_EPISODE])
    assert straight.loc[0, "outcome"] == "collision"
    df, traces = run_episodes(AStarOracle(), wall_env, [WALL_EPISODE])
    row = df.iloc[0]
    assert row.outcome == "success", row.to_dict()
    assert abs(traces[0].xy[:, 1]).max() > 5.0  # went round an end of the 10 m wall
    # SPL's reference is the geodesic round the wall, not the 8 m straight line
    assert row.shortest_path_m > row.straight_distance_m + 2.0
    assert 0.5 < row.spl <= 1.0


def test_oracle_waypoints_stay_within_the_action_space(wall_env):
    oracle = AStarOracle()
    wall_env.reset(seed=0, options=WALL_EPISODE.reset_options())
    oracle.reset(wall_env)
    steps = np.hypot(*np.diff(np.vstack([WALL_EPISODE.start, oracle.waypoints]), axis=0).T)
    assert steps.max() <= wall_env.mapping.extent + 1e-9
    assert np.allclose(oracle.waypoints[-1], WALL_EPISODE.goal)


@pytest.mark.parametrize("shape", ["square", "circle"])
def test_waypoint_action_keeps_the_heading_to_far_targets(shape):
    from tests.evaluation.conftest import small_env

    env = small_env(f"action_space={shape}")
    try:
        env.reset(seed=0, options={"start": [0.0, 0.0], "goal": [8.0, 6.0], "yaw": 0.4})
        offset = env.mapping.offset(waypoint_action(env, np.array([8.0, 6.0])), env.pose_estimate.yaw)
        # a square clips each axis separately; the helper must shorten along the direction instead
        assert math.atan2(offset[1], offset[0]) == pytest.approx(math.atan2(6.0, 8.0), abs=1e-6)
        assert np.hypot(*offset) == pytest.approx(env.mapping.extent, rel=1e-5)
        near = env.mapping.offset(waypoint_action(env, np.array([1.0, -0.5])), env.pose_estimate.yaw)
        np.testing.assert_allclose(near, [1.0, -0.5], atol=1e-6)
    finally:
        env.close()


def test_baselines_speak_candidate_indices_to_a_discrete_env():
    env = small_env("action_space=discrete")
    wall = RoverNavEnv(config=compose([*SMALL_FLAT, "action_space=discrete"]), world_instance=wall_world())
    try:
        obs, _ = env.reset(seed=0, options={"start": [0.0, 0.0], "goal": [8.0, 6.0], "yaw": 0.4})
        action = StraightLine().act(obs, env)
        assert action.dtype == np.int64 and action.shape == () and env.action_space.contains(action)
        offset = env.mapping.offset(action, env.pose_estimate.yaw)
        # the farthest candidate within half a heading bin (22.5 / 2 deg) of the goal's bearing
        assert np.hypot(*offset) == pytest.approx(env.mapping.extent)
        assert abs(math.atan2(offset[1], offset[0]) - math.atan2(6.0, 8.0)) <= math.pi / 16 + 1e-9
        near = env.mapping.offset(waypoint_action(env, np.array([1.0, 0.3])), env.pose_estimate.yaw)
        assert np.hypot(*(near - [1.0, 0.3])) < 0.3  # the nearest candidate to a near target
        # the expert imitation learns from drives round the wall through the candidates too
        df, _ = run_episodes(AStarOracle(receding=True, spacing=0.8), wall, [WALL_EPISODE])
        assert df.iloc[0].outcome == "success", df.iloc[0].to_dict()
    finally:
        env.close()
        wall.close()


class FakeModel:
    def __init__(self, action_space=None):
        self.seen = []
        if action_space is not None:
            self.action_space = action_space

    def predict(self, obs, deterministic=True):
        self.seen.append((obs, deterministic))
        return np.array([0.5, 0.0], dtype=np.float32), None


class FakeVecNormalize:
    norm_obs = True

    def normalize_obs(self, obs):
        return {**obs, "goal": obs["goal"] * 0 + 7.0}


def test_sb3_policy_normalises_observations_and_predicts_deterministically(flat_env):
    model = FakeModel()
    policy = SB3Policy(model, FakeVecNormalize(), deterministic=True)
    obs, _ = flat_env.reset(seed=0)
    policy.reset(flat_env)
    action = policy.act(obs, flat_env)
    assert action.shape == (2,) and action.dtype == np.float32
    seen, deterministic = model.seen[0]
    assert deterministic and np.all(seen["goal"] == 7.0)
    assert not np.all(obs["goal"] == 7.0)  # the env's observation itself is left alone


def test_sb3_policy_returns_a_candidate_index_for_a_categorical_model(flat_env):
    class DiscreteModel(FakeModel):
        def predict(self, obs, deterministic=True):
            return np.array(5), None  # what SB3 returns for one observation of a Discrete space

    policy = SB3Policy(DiscreteModel(gym.spaces.Discrete(48)), deterministic=True)
    obs, _ = flat_env.reset(seed=0)
    action = policy.act(obs, flat_env)
    assert action.dtype == np.int64 and action.shape == () and int(action) == 5


def test_receding_oracle_drives_round_the_wall_too(wall_env):
    df, traces = run_episodes(AStarOracle(receding=True, spacing=0.8), wall_env, [WALL_EPISODE])
    assert df.iloc[0].outcome == "success", df.iloc[0].to_dict()
    assert abs(traces[0].xy[:, 1]).max() > 5.0


def test_oracle_knowledge_radius_hides_the_wall_until_it_is_near(wall_env):
    """Knowing only 2 m around it, the oracle first heads straight for the goal (the wall at x = 0 is 4 m
    off); with the whole map it turns away at once. Both still get round in the end (it replans)."""
    first = {}
    for name, oracle in (
        ("full", AStarOracle(receding=True, spacing=0.8)),
        ("local", AStarOracle(spacing=0.8, knowledge_radius=2.0)),
    ):
        obs, _ = wall_env.reset(seed=0, options=WALL_EPISODE.reset_options())
        oracle.reset(wall_env)
        offset = wall_env.mapping.offset(oracle.act(obs, wall_env), wall_env.pose_estimate.yaw)
        first[name] = math.degrees(math.atan2(offset[1], offset[0]))
    to_goal = math.degrees(math.atan2(*(WALL_EPISODE.goal - WALL_EPISODE.start)[::-1]))
    assert abs(first["local"] - to_goal) < 3.0
    assert abs(first["full"] - to_goal) > 20.0
    df, _ = run_episodes(AStarOracle(spacing=0.8, knowledge_radius=2.0), wall_env, [WALL_EPISODE])
    assert df.iloc[0].outcome in ("success", "stuck", "timeout")  # never drives into the wall
    with pytest.raises(ValueError, match="knowledge_radius"):
        AStarOracle(knowledge_radius=0.0)
    with pytest.raises(ValueError, match="knowledge_fov_deg"):
        AStarOracle(knowledge_radius=5.0, knowledge_fov_deg=400.0)


def test_receding_oracle_chooses_among_the_discrete_candidates_themselves():
    # not the nearest candidate to a free waypoint: the look-ahead scores exactly the actions the policy has
    wall = RoverNavEnv(
        config=compose([*SMALL_FLAT, "action_space=discrete", "action_space.headings=32"]), world_instance=wall_world()
    )
    try:
        oracle = AStarOracle(receding=True, spacing=0.8)
        obs, _ = wall.reset(seed=0, options={"start": [-4.0, 0.5], "goal": [4.0, -0.5], "yaw": 0.3})
        oracle.reset(wall)
        for _ in range(5):
            action = oracle.act(obs, wall)
            est = wall.pose_estimate
            offsets = wall.mapping.world_offsets(est.yaw)
            np.testing.assert_allclose(oracle.waypoints[0] - est.xy, offsets[int(action)], atol=1e-9)
            obs, _, terminated, truncated, _ = wall.step(action)
            if terminated or truncated:
                break
    finally:
        wall.close()


@pytest.mark.parametrize("frame", ["rover", "world"])
def test_the_bearing_ranking_puts_the_candidate_nearest_the_goals_bearing_first(frame):
    from diana_lab.evaluation.policies import GoalBearing

    env = small_env("action_space=discrete", f"action_space.frame={frame}")
    try:
        policy = GoalBearing()
        obs, _ = env.reset(seed=0, options={"start": [-6.0, -2.0], "goal": [5.0, 4.0], "yaw": 2.2})
        policy.reset(env)
        order = policy.ranking(obs)
        assert sorted(order) == list(range(env.action_space.n))  # every candidate, once
        offsets = env.mapping.world_offsets(env.pose_estimate.yaw)
        to_goal = np.arctan2(4.0 - env.pose_estimate.xy[1], 5.0 - env.pose_estimate.xy[0])
        gaps = np.abs(np.angle(np.exp(1j * (np.arctan2(offsets[:, 1], offsets[:, 0]) - to_goal))))
        assert np.all(np.diff(np.round(gaps[order], 9)) >= 0)  # nearest bearing first
        lengths = np.hypot(*offsets.T)
        assert lengths[order[0]] == pytest.approx(lengths.max())  # and the longest drive of that bearing
        # alone (no shield) it drives the straight line: on open ground it reaches the goal
        df = run_suite(policy, env, [EpisodeSpec(np.array([-6.0, -2.0]), 2.2, np.array([5.0, 4.0]), seed=1)])
        assert df.loc[0, "outcome"] == "success"
    finally:
        env.close()


def test_the_bearing_ranking_needs_a_discrete_action_space():
    from diana_lab.cli import UserError
    from diana_lab.config import to_object
    from diana_lab.evaluation.loading import load_policy

    cfg = compose([*SMALL_FLAT, "action_space=square"])
    with pytest.raises(UserError, match=r"policy=bearing .*action_space.shape=square"):
        load_policy("bearing", cfg, to_object("eval", cfg.eval))
