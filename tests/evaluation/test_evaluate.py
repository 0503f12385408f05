import json

import imageio.v3 as iio
import pytest

from diana_lab.evaluation import AStarOracle, EvalConfig, StraightLine, eval_env, evaluate, sweep_sensor_noise
from diana_lab.evaluation.core import noise_sensor
from diana_lab.evaluation.metrics import SUMMARY_KEYS


def test_evaluate_writes_csv_summary_plots_and_gif(flat_env, tmp_path):
    cfg = EvalConfig(episodes=2, seed=3, min_distance=4.0, max_distance=8.0)
    summary = evaluate(AStarOracle(), flat_env, cfg, tmp_path)
    for name in ("episodes.csv", "summary.json", "trajectories.png", "tilt.png", "episode_0.gif"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert json.loads((tmp_path / "summary.json").read_text()) == json.loads(json.dumps(summary))
    assert set(SUMMARY_KEYS) <= set(summary) and summary["episodes"] == 2
    frames = iio.imread(tmp_path / "episode_0.gif", index=None)
    assert frames.ndim == 4 and len(frames) >= 2  # the reset frame plus one per waypoint
    assert frames.shape[2] > frames.shape[1]  # map, third-person view and depth image side by side
    assert len((tmp_path / "episodes.csv").read_text().splitlines()) == 3


def test_plots_and_video_can_be_switched_off(flat_env, tmp_path):
    evaluate(
        StraightLine(),
        flat_env,
        EvalConfig(episodes=1, video=False, plots=False, min_distance=4.0, max_distance=8.0),
        tmp_path,
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["episodes.csv", "summary.json"]


def test_eval_dynamics_builds_a_physics_env_on_the_same_world(flat_env):
    assert eval_env(flat_env, EvalConfig()) is flat_env  # null: the env's own dynamics
    assert eval_env(flat_env, EvalConfig(dynamics="kinematic")) is flat_env
    env = eval_env(flat_env, EvalConfig(dynamics="physics"))
    try:
        assert env is not flat_env and env.cfg["dynamics"].name == "physics"
        assert env.world is flat_env.world
        assert env.cfg["sensor"] == flat_env.cfg["sensor"]
    finally:
        env.close()


def test_noise_sweep_uses_the_realistic_preset_for_a_noiseless_sensor(flat_env, tmp_path):
    sensor = flat_env.cfg["sensor"]
    assert sensor.noise == "none"
    assert noise_sensor(sensor, 0.5).noise == "realistic" and noise_sensor(sensor, 0.5).noise_level == 0.5
    cfg = EvalConfig(episodes=1, sensor_noise=[0.0, 2.0], video=False, plots=False, min_distance=4.0, max_distance=8.0)
    results = sweep_sensor_noise(StraightLine(), flat_env, cfg, tmp_path)
    assert list(results) == [0.0, 2.0]
    assert (tmp_path / "noise_0" / "summary.json").is_file() and (tmp_path / "noise_2" / "summary.json").is_file()
    assert len((tmp_path / "sensor_noise.csv").read_text().splitlines()) == 3


def test_eval_config_rejects_bad_values():
    from diana_lab.config import ConfigError

    with pytest.raises(ConfigError, match=r"eval\.dynamics"):
        EvalConfig(dynamics="gazebo")
    with pytest.raises(ConfigError, match=r"eval\.episodes"):
        EvalConfig(episodes=0)
    with pytest.raises(ConfigError, match=r"eval\.sensor_noise"):
        EvalConfig(sensor_noise=[-1.0])
