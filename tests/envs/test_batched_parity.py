"""One truth: the batched env (``train.vec_env=batched``) against ``RoverNavEnv(dynamics="kinematic")``.

Both are driven from the same seeds (rover ``i`` and scalar env ``i`` seeded ``seed + i``, as a ``DummyVecEnv``
seeds its envs), so they draw the same episodes, and from the same actions, over whole episodes (auto-reset
included): every step's observation, weighted reward terms, done flag, outcome and episode length must agree, and
every episode's last observation (``terminal_observation``). Every world, action space, sensor encoding and the
noisy and guarded variants are covered.
"""

from __future__ import annotations

import numpy as np
import pytest

from diana_lab import config as C
from diana_lab.envs.batched import BatchedRoverEnv
from diana_lab.envs.rover_nav import RoverNavEnv
from diana_lab.training.envs import env_config, shared_world

N_ROVERS = 4
OBS_ATOL = 1e-6  # float32 observations: the plane fit's sums may round in another order than numpy's
REWARD_ATOL = 1e-9

SMALL_CAMERA = ["sensor=depth_camera", "sensor.width=24", "sensor.height=18"]
LIDAR_MAP = ["sensor=lidar3d", "sensor.horizontal_resolution_deg=8", "sensor.encoding=elevation_map"]

CASES = {
    "yard-square-depth": ["world=mars_yard", *SMALL_CAMERA],
    "yard-discrete-map-memory": [
        "world=mars_yard",
        "action_space=discrete",
        *LIDAR_MAP,
        "sensor.elevation_map.memory=true",
    ],
    "yard-discrete-world-frame": [
        "world=mars_yard",
        "action_space=discrete",
        "action_space.frame=world",
        *SMALL_CAMERA,
    ],
    "flat-circle-points": [
        "world=flat",
        "action_space=circle",
        "sensor.encoding=points",
        "episode.max_steps=15",
        *SMALL_CAMERA,
    ],
    "flat-near-goals-efficiency": [
        "world=flat",
        "action_space=discrete",
        "episode.min_distance=1",
        "episode.max_distance=3",
        "+reward.terms.efficiency={fn: diana_lab.envs.rewards.efficiency, weight: 10.0, params: {}}",
        *SMALL_CAMERA,
    ],
    "yard-discrete-path-progress": [
        "world=mars_yard",
        "action_space=discrete",
        "reward.terms.progress.weight=0",
        "+reward.terms.path={fn: diana_lab.envs.rewards.path_progress, weight: 1.0, params: {stride: 3}}",
        *SMALL_CAMERA,
    ],
    "hills-square-map-voxel": ["world=hills", "sensor.encoding=elevation_map", *SMALL_CAMERA],
    "craters-square-world-frame-map": ["world=craters", "action_space.frame=world", *LIDAR_MAP],
    "craters-circle-min-distance": [
        "world=craters",
        "action_space=circle",
        "action_space.min_distance=1",
        *SMALL_CAMERA,
    ],
    "yard-noise-pose-noise": [
        "world=mars_yard",
        *SMALL_CAMERA,
        "sensor.noise=realistic",
        "dynamics.pose_noise.position_std=0.05",
        "dynamics.pose_noise.yaw_std_deg=2",
        "dynamics.pose_noise.tilt_std_deg=1",
    ],
    "yard-tilt-guard-map-noise": [
        "world=mars_yard",
        "robot.tilt_guard_deg=20",
        "robot.guard_pause_s=1",
        *LIDAR_MAP,
        "sensor.elevation_map.memory=true",
        "sensor.noise=harsh",
    ],
    "yard-guard-map-hazards": [
        "world=mars_yard",
        "action_space=discrete",
        "robot.tilt_guard_deg=20",
        *LIDAR_MAP,
        "sensor.elevation_map.memory=true",
        "sensor.elevation_map.hazard_radius=0.75",
        "+reward.terms.stuck={fn: diana_lab.envs.rewards.stuck, weight: 3.0, params: {}}",
    ],
    "yard-guard-overshoot": [
        "world=mars_yard",
        "robot.tilt_guard_deg=12",
        "robot.tipover_deg=16",
        "dynamics.guard_overshoot=0.6",
        *SMALL_CAMERA,
    ],
    "hills-map-hazards-no-memory": [
        "world=hills",
        "robot.tilt_guard_deg=6",
        "sensor.encoding=elevation_map",
        "sensor.elevation_map.hazard_radius=1.0",
        *SMALL_CAMERA,
    ],
    "hills-curriculum-paper-reward": [
        "world=hills",
        "reward=paper",
        "episode.curriculum.enabled=true",
        "episode.curriculum.episodes=5",
        "episode.max_steps=12",
        *SMALL_CAMERA,
    ],
}


def _actions(env: BatchedRoverEnv, rng: np.random.Generator) -> np.ndarray:
    if env.mapping.discrete:
        return rng.integers(0, env.action_space.n, env.num_envs)
    return rng.uniform(-1.1, 1.1, (env.num_envs, 2)).astype(np.float32)  # a little beyond [-1, 1]: clipped


def _close(a: np.ndarray, b: np.ndarray, atol: float, what: str) -> None:
    np.testing.assert_allclose(
        np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64), rtol=0, atol=atol, err_msg=what
    )


def drive_both(overrides: list[str], steps: int, seed: int = 7, marked: list[float] | None = None) -> dict[str, int]:
    """Step the batched env and ``N_ROVERS`` scalar envs with the same actions; assert they agree; return the
    outcomes of the episodes that ended (episodes of at most 12 steps unless ``overrides`` say otherwise, so that
    the resets are compared too). ``marked`` collects each step's share of map cells in the stopped-drive
    channel (the map's third), when there is one."""
    groups = env_config(C.compose(["episode.max_steps=12", *overrides]))
    world = shared_world(groups["world"])
    batched = BatchedRoverEnv(groups, N_ROVERS, world_instances=[world])
    scalar = [RoverNavEnv(config=groups, world_instance=world) for _ in range(N_ROVERS)]
    key = batched.sensor_key
    try:
        batched.seed(seed)
        obs = batched.reset()
        for i, env in enumerate(scalar):
            o, _ = env.reset(seed=seed + i)
            _close(obs["goal"][i], o["goal"], OBS_ATOL, f"reset goal {i}")
            _close(obs[key][i], o[key], OBS_ATOL, f"reset {key} {i}")
        rng = np.random.default_rng(seed)
        outcomes: dict[str, int] = {}
        for t in range(steps):
            actions = _actions(batched, rng)
            obs, rewards, dones, infos = batched.step(actions)
            assert np.all(np.isfinite(batched.last_reward_terms)), f"step {t}: a reward term is not finite"
            if marked is not None and obs[key].ndim == 4 and obs[key].shape[1] == 3:
                marked.append(float(obs[key][:, 2].mean()))
            for i, env in enumerate(scalar):
                o, r, terminated, truncated, info = env.step(actions[i])
                where = f"step {t} rover {i}"
                _close(
                    batched.last_reward_terms[i], list(info["reward_terms"].values()), REWARD_ATOL, f"{where}: terms"
                )
                np.testing.assert_allclose(rewards[i], r, rtol=1e-6, atol=1e-5, err_msg=f"{where}: reward (float32)")
                assert bool(dones[i]) == (terminated or truncated), where
                if terminated or truncated:
                    assert infos[i]["outcome"] == info["outcome"], where
                    assert infos[i]["is_success"] == (info["outcome"] == "success"), where
                    assert infos[i]["TimeLimit.truncated"] == (truncated and not terminated), where
                    assert infos[i]["episode"]["l"] == info["steps"], where
                    terms = infos[i]["episode_reward_terms"]
                    assert list(terms) == list(info["reward_terms"]), where
                    for k in ("goal", key):
                        _close(infos[i]["terminal_observation"][k], o[k], OBS_ATOL, f"{where}: terminal {k}")
                    outcomes[info["outcome"]] = outcomes.get(info["outcome"], 0) + 1
                    o, _ = env.reset()
                _close(obs["goal"][i], o["goal"], OBS_ATOL, f"{where}: goal")
                _close(obs[key][i], o[key], OBS_ATOL, f"{where}: {key}")
        return outcomes
    finally:
        batched.close()
        for env in scalar:
            env.close()


@pytest.mark.parametrize("case", sorted(CASES))
def test_batched_env_matches_the_scalar_env(case: str) -> None:
    marked: list[float] = []
    outcomes = drive_both(CASES[case], steps=40, marked=marked)
    assert sum(outcomes.values()) >= 2, f"too few episodes ended to compare resets: {outcomes}"
    if "hazard" in case:  # the stopped-drive channel was exercised: spots marked, and forgotten at resets
        assert max(marked) > 0 and min(marked) < max(marked), f"the channel never changed: {marked}"
    if case == "yard-guard-overshoot":  # tip-overs past the guard's trip were compared
        assert outcomes.get("tipover", 0) >= 1, outcomes
    if case == "flat-near-goals-efficiency":  # the efficiency term was compared where it pays
        assert outcomes.get("success", 0) >= 2, outcomes
    if case == "yard-discrete-path-progress":  # the field was rebuilt at the resets compared
        assert sum(outcomes.values()) >= 3, outcomes
    if case == "yard-guard-map-hazards":  # the stuck term was compared where it pays
        assert outcomes.get("stuck", 0) >= 1, outcomes


def test_batched_env_matches_on_a_dem_with_obstacles(tmp_path) -> None:
    """``world=dem``: the user's own heights (a tilted plane with bumps) and an obstacle mesh."""
    import open3d as o3d

    y, x = np.mgrid[0:81, 0:81] / 80.0
    heights = 0.8 * x + 0.6 * np.sin(7 * x) * np.cos(5 * y)
    np.save(tmp_path / "site.npy", heights)
    box = o3d.geometry.TriangleMesh.create_box(1.0, 1.0, 1.0)
    box.translate((2.0, 1.0, -1.0))
    o3d.io.write_triangle_mesh(str(tmp_path / "box.obj"), box)
    overrides = [
        "world=dem",
        f"world.path={tmp_path / 'site.npy'}",
        "world.size_x=20",
        "world.size_y=20",
        f"world.obstacles=[{tmp_path / 'box.obj'}]",
        "episode.min_distance=4",
        "episode.max_distance=10",
        *SMALL_CAMERA,
    ]
    outcomes = drive_both(overrides, steps=40)
    assert sum(outcomes.values()) >= 2, outcomes


def test_episode_returns_add_up_the_steps_rewards() -> None:
    """``info["episode"]["r"]`` (what SB3's ``ep_rew_mean`` reads) is the sum of the episode's rewards, and the
    per-term sums add up to it."""
    groups = env_config(C.compose(["world=flat", *SMALL_CAMERA, "episode.max_steps=5"]))
    env = BatchedRoverEnv(groups, 3, world_instances=[shared_world(groups["world"])])
    env.seed(0)
    env.reset()
    rng = np.random.default_rng(0)
    running = np.zeros(3)
    ended = 0
    for _ in range(12):
        _, rewards, dones, infos = env.step(_actions(env, rng))
        running += rewards
        for i in np.flatnonzero(dones):
            assert infos[i]["episode"]["r"] == pytest.approx(running[i], abs=1e-4)
            assert sum(infos[i]["episode_reward_terms"].values()) == pytest.approx(running[i], abs=1e-4)
            running[i] = 0.0
            ended += 1
    assert ended >= 3
