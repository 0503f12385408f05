"""The gymnasium contract of diana_lab/RoverNav-v0, its episodes, terminations and info."""

import math
import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import diana_lab  # registers the env
from diana_lab.envs import ActionError
from diana_lab.envs.rover_nav import RoverNavEnv


def make(**kwargs) -> RoverNavEnv:
    """A small env on the camera set-up (``tests.presets.CAMERA_SQUARE``), with any group replaced."""
    for group, option in (
        ("world", "flat"),
        ("sensor", "depth_camera"),
        ("action_space", "square"),
        ("robot", "jackal"),
    ):
        kwargs.setdefault(group, option)
    return RoverNavEnv(**kwargs)


def goal_seeking_action(env: RoverNavEnv) -> np.ndarray:
    est = env.pose_estimate
    offset = env.goal - est.xy
    extent = env.mapping.extent * 0.9
    if np.hypot(*offset) > extent:
        offset = offset / np.hypot(*offset) * extent
    action = env.mapping.action_for(offset, est.yaw)
    return action if env.mapping.discrete else action.astype(np.float32)


def test_gym_make_works_with_defaults():
    env = gym.make("diana_lab/RoverNav-v0")
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert info["start_distance"] >= 8.0 - 1e-6
    env.close()


GRID = [  # every option of every group at least once (world x robot x dynamics x action_space x encoding)
    ["world=flat", "robot=jackal", "dynamics=kinematic", "action_space=square", "sensor=depth_camera"],
    [
        "world=hills",
        "robot=husky",
        "dynamics=kinematic",
        "action_space=circle",
        "sensor=lidar3d",
        "sensor.encoding=points",
    ],
    [
        "world=craters",
        "robot=rocker_bogie",
        "dynamics=kinematic",
        "action_space=square",
        "sensor.encoding=elevation_map",
    ],
    [
        "world=mars_yard",
        "robot=jackal",
        "dynamics=physics",
        "action_space=circle",
        "sensor=depth_camera_paper",
    ],
    [
        "world=flat",
        "robot=rocker_bogie",
        "dynamics=physics",
        "action_space=square",
        "sensor=lidar3d",
        "sensor.encoding=elevation_map",
        "action_space.frame=world",
    ],
    ["world=hills", "robot=jackal", "dynamics=kinematic", "action_space=discrete", "sensor=depth_camera"],
    [
        "world=flat",
        "robot=husky",
        "dynamics=kinematic",
        "action_space=discrete",
        "action_space.frame=world",
        "action_space.headings=8",
        "action_space.distances=[2.5]",
        "sensor=lidar3d",
        "sensor.encoding=elevation_map",
    ],
]


@pytest.mark.parametrize("overrides", GRID, ids=lambda o: "-".join(x.split("=")[1] for x in o))
def test_check_env_grid(overrides):
    from diana_lab.config import compose

    env = RoverNavEnv(config=compose(overrides))
    check_env(env, skip_render_check=True)
    env.close()


def test_seeded_resets_and_steps_are_identical():
    a, b = make(world="hills"), make(world="hills")
    oa, _ = a.reset(seed=7)
    ob, _ = b.reset(seed=7)
    for key in oa:
        np.testing.assert_array_equal(oa[key], ob[key])
    for _ in range(3):
        action = np.array([0.6, -0.2], dtype=np.float32)
        ra, rb = a.step(action), b.step(action)
        np.testing.assert_array_equal(ra[0]["goal"], rb[0]["goal"])
        assert ra[1] == rb[1]
    oc, _ = a.reset(seed=8)
    assert not np.array_equal(oa["goal"], oc["goal"])


@pytest.mark.parametrize("dynamics", ["kinematic", "physics"])
def test_scripted_goal_seeking_policy_succeeds_on_flat(dynamics):
    env = make(dynamics=dynamics)
    successes = 0
    for seed in range(3 if dynamics == "physics" else 5):
        env.reset(seed=seed)
        for _ in range(env.episode_cfg.max_steps):
            _, _, terminated, truncated, info = env.step(goal_seeking_action(env))
            if terminated or truncated:
                break
        successes += info.get("outcome") == "success"
        assert info["path_length"] >= info["start_distance"] - env.episode_cfg.goal_tolerance - 0.3
    assert successes == (3 if dynamics == "physics" else 5)
    env.close()


def test_discrete_waypoints_drive_a_scripted_policy_to_the_goal():
    env = make(action_space="discrete")
    assert env.action_space == gym.spaces.Discrete(48)
    for seed in range(4):
        env.reset(seed=seed)
        for _ in range(env.episode_cfg.max_steps):
            action = goal_seeking_action(env)
            assert env.action_space.contains(action)
            before = env.pose_estimate
            _, _, terminated, truncated, info = env.step(action)
            # the waypoint is the candidate, turned by the rover's heading (inside the map: no clamp here)
            want = before.xy + env.mapping.offset(action, before.yaw)
            np.testing.assert_allclose(info["waypoint"], want)
            if terminated or truncated:
                break
        assert info.get("outcome") == "success"
    env.close()


def test_info_carries_what_evaluation_needs():
    env = make()
    env.reset(seed=1)
    _, reward, _, _, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
    for key in (
        "waypoint",
        "waypoint_outcome",
        "waypoint_reached",
        "sim_time",
        "path_length",
        "max_tilt_deg",
        "tilt_deg",
        "reward_terms",
        "distance_to_goal",
    ):
        assert key in info
    assert reward == pytest.approx(sum(info["reward_terms"].values()))
    assert info["sim_time"] > 0 and info["path_length"] == pytest.approx(3.5 - 0.2, abs=1e-6)


def test_fixed_episode_through_reset_options():
    env = make()
    _, info = env.reset(seed=0, options={"start": (0.0, 0.0), "goal": (10.0, 0.0), "yaw": 0.0})
    np.testing.assert_allclose(info["goal"], (10.0, 0.0))
    assert info["distance_to_goal"] == pytest.approx(10.0)
    with pytest.raises(ValueError, match="outside the map"):
        env.reset(options={"start": (0.0, 0.0), "goal": (100.0, 0.0)})
    with pytest.raises(ValueError, match="unknown key"):
        env.reset(options={"begin": (0.0, 0.0)})


def test_goal_vector_follows_the_named_layout():
    """GOAL_KEYS is what the deploy runtime and the rule-based policies read the goal vector by."""
    from diana_lab.envs import GOAL_KEYS

    env = make(world="hills")
    obs, info = env.reset(seed=3, options={"start": (-4.0, 2.0), "goal": (9.0, -6.0), "yaw": 2.0})
    g = dict(zip(GOAL_KEYS, obs["goal"].astype(np.float64), strict=True))
    est = env.pose_estimate
    dx, dy = 9.0 - est.xy[0], -6.0 - est.xy[1]
    error = math.atan2(dy, dx) - est.yaw
    assert g["distance"] * env.episode_cfg.distance_scale == pytest.approx(info["distance_to_goal"], rel=1e-5)
    heading = (g["sin_heading_error"], g["cos_heading_error"])
    assert heading == pytest.approx((math.sin(error), math.cos(error)), abs=1e-5)
    assert (g["sin_yaw"], g["cos_yaw"]) == pytest.approx((math.sin(est.yaw), math.cos(est.yaw)), abs=1e-5)
    assert (g["roll"], g["pitch"]) == pytest.approx((est.roll / (math.pi / 2), est.pitch / (math.pi / 2)), abs=1e-5)
    assert max(abs(g["roll"]), abs(g["pitch"])) > 1e-3, "the start should be on a slope, so roll/pitch mean something"


def test_bad_actions_raise_a_clear_error():
    env = make()
    env.reset(seed=0)
    with pytest.raises(ActionError, match="finite"):
        env.step(np.array([np.nan, 0.0]))
    env = make(action_space="discrete")
    env.reset(seed=0)
    with pytest.raises(ActionError, match=r"integer candidate index in \[0, 48\)"):
        env.step(np.array([1.0, 0.0], dtype=np.float32))  # a continuous policy's action on a discrete env
    with pytest.raises(ActionError, match="outside"):
        env.step(48)


def test_action_error_is_importable_where_users_look():
    """``from diana_lab import ActionError`` failed: it lived only in diana_lab.envs.action_spaces."""
    from diana_lab.envs import action_spaces

    assert diana_lab.ActionError is ActionError is action_spaces.ActionError
    assert issubclass(ActionError, ValueError) and "ActionError" in diana_lab.__all__
    env = make()
    env.reset(seed=0)
    with pytest.raises(diana_lab.ActionError, match="shape"):
        env.step(np.zeros(3, dtype=np.float32))


def test_waypoints_are_clamped_to_the_map():
    env = make()
    env.reset(seed=0, options={"start": (18.5, 0.0), "goal": (0.0, 0.0), "yaw": 0.0})
    _, _, terminated, _, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
    assert info["waypoint"][0] <= 20.0 - env.robot.radius - env.episode_cfg.map_margin + 1e-9
    assert info.get("outcome") != "out_of_bounds"


def run_until_done(env, action_fn, max_steps=200):
    for _ in range(max_steps):
        _, _, terminated, truncated, info = env.step(action_fn(env))
        if terminated or truncated:
            return terminated, truncated, info
    raise AssertionError("episode did not end")


def test_collision_terminates_once():
    from diana_lab.sim.terrain import Terrain
    from diana_lab.sim.world import World
    from diana_lab.sim.worlds import _rock

    rocks = [
        _rock(np.random.default_rng(i), np.array([4.0, y]), 0.9, 0.0, f"r{i}")
        for i, y in enumerate(np.arange(-19.0, 19.5, 0.8))
    ]
    world = World("wall", Terrain(np.zeros((81, 81)), 40.0, 40.0), rocks)
    env = RoverNavEnv(world="flat", world_instance=world)
    env.reset(seed=0, options={"start": (0.0, 0.0), "goal": (12.0, 0.0), "yaw": 0.0})
    terminated, truncated, info = run_until_done(env, goal_seeking_action)
    assert (terminated, truncated, info["outcome"]) == (True, False, "collision")
    assert info["reward_terms"]["collision"] < 0


def test_tipover_and_timeout_and_stuck_are_reachable():
    from diana_lab.sim.terrain import Terrain
    from diana_lab.sim.world import World

    x = np.linspace(-20, 20, 161)
    ramp = np.tile(np.clip(x - 2.0, 0, None) * math.tan(math.radians(45)), (161, 1))
    world = World("ramp", Terrain(ramp, 40.0, 40.0))
    env = make(world_instance=world, episode={"min_distance": 1.0, "max_distance": 3.0})
    # along the 45-degree side slope (climbing only ~19 degrees, rolling ~43): the rover tips over
    env.reset(seed=0, options={"start": (1.5, -5.0), "goal": (1.8, 5.0), "yaw": math.pi / 2})
    terminated, _, info = run_until_done(
        env, lambda e: e.mapping.action_for(np.array([1.1, 3.0]), e.pose_estimate.yaw).astype(np.float32)
    )
    assert (terminated, info["outcome"]) == (True, "tipover")
    assert info["reward_terms"]["tipover"] < 0
    # straight up the ramp: stuck at its foot, the episode is truncated as "stuck"
    env.reset(seed=0, options={"start": (0.0, 0.0), "goal": (8.0, 0.0), "yaw": 0.0})
    terminated, truncated, info = run_until_done(env, lambda e: np.array([1.0, 0.0], dtype=np.float32))
    assert (terminated, truncated, info["outcome"]) == (False, True, "stuck")
    # a policy that only turns: the step limit ends it as a timeout
    env = make(episode={"max_steps": 5})
    env.reset(seed=0)
    terminated, truncated, info = run_until_done(
        env, lambda e: e.mapping.action_for(np.array([0.1, 0.0]), e.pose_estimate.yaw).astype(np.float32) * 0
    )
    assert (terminated, truncated) == (False, True) and info["outcome"] in ("timeout", "stuck")


def test_env_factory_pickles_for_subprocesses():
    from functools import partial

    factory = partial(RoverNavEnv, world="flat")
    env = pickle.loads(pickle.dumps(factory))()
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)


def test_rgb_array_render():
    env = make(render_mode="rgb_array")
    env.reset(seed=0)
    env.step(np.array([1.0, 0.0], dtype=np.float32))
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8
    assert frame.std() > 5  # not a blank image
    env.close()


def test_sampled_goals_are_reachable_inside_the_waypoint_clamp(mars_yard):
    env = RoverNavEnv(world="mars_yard", world_instance=mars_yard)
    margin = env.robot.radius + env.episode_cfg.map_margin
    for seed in range(200):
        _, info = env.reset(seed=seed)
        for point in (info["start"], info["goal"]):
            assert env.world.terrain.contains(point[0], point[1], margin=margin - 1e-9)


def test_flat_world_map_is_not_blank(flat_world):
    from diana_lab.envs.render import hillshade

    image = hillshade(flat_world)
    assert image.mean() > 60  # a visible mid tone, not black


def test_path_progress_adds_up_to_the_drivable_way_from_start_to_end(mars_yard):
    """The ``path_progress`` term telescopes: an episode's sum is the goal-distance field at the start minus at
    the rover's last true position; an env whose reward does not read the field builds none."""
    from diana_lab.config import compose

    term = "+reward.terms.way={fn: diana_lab.envs.rewards.path_progress, weight: 1.0, params: {}}"
    cfg = compose(["world=mars_yard", "sensor=depth_camera", "sensor.width=24", "sensor.height=18", term])
    env = RoverNavEnv(config=cfg, world_instance=mars_yard)
    assert env.goal_distance is not None
    assert RoverNavEnv(world="mars_yard", world_instance=mars_yard).goal_distance is None
    for seed in range(3):
        _, info = env.reset(seed=seed)
        field = env.goal_distance.field(info["goal"])
        at_start = env.goal_distance.at(field, *info["start"])
        assert at_start >= 0.9 * info["start_distance"]  # never much under the straight line (the grid's corners)
        total, done = 0.0, False
        while not done:
            _, _, terminated, truncated, info = env.step(goal_seeking_action(env))
            total += info["reward_terms"]["way"]
            done = terminated or truncated
        at_end = env.goal_distance.at(field, *info["position"][:2])
        assert total == pytest.approx(at_start - at_end, abs=1e-9)
        assert total != 0.0
