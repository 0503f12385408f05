"""``train.worlds``: one policy trained in several worlds at once, a world per training env."""

from __future__ import annotations

import json

import numpy as np
import pytest
from gymnasium import spaces

from diana_lab.config import ConfigError, compose, validate
from diana_lab.training.envs import make_training_env, training_worlds
from tests.presets import CAMERA_SQUARE

from .helpers import ALGO_TINY, TINY, run_in_process, runs, store_args

SMALL = [*CAMERA_SQUARE, "world=flat", "sensor.width=16", "sensor.height=12"]
SMALL += ["episode.max_steps=20"]


def _train(overrides: list[str]):
    cfg = compose(SMALL + overrides)
    return cfg, validate(cfg, ["train"])["train"]


def test_the_training_envs_cycle_through_the_worlds():
    """One env per world in turn (train.vec_env=dummy; the batched env splits its rovers the same way:
    tests/envs/test_batched_env.py)."""
    cfg, train = _train(["train.worlds=['craters world.seed=7',hills]", "train.n_envs=4", "train.vec_env=dummy"])
    venv = make_training_env(cfg, train, seed=3)
    try:
        worlds = [env.unwrapped.world for env in venv.envs]
        assert [w.name for w in worlds] == ["flat", "craters", "hills", "flat"]
        assert worlds[0] is worlds[3]  # one World per process and config, shared by its envs
        assert len(worlds[1].obstacles) > 0  # craters' rocks, as its own config builds them
        assert training_worlds(cfg, train)[1]["seed"] == 7  # the entry's own override
        obs = venv.reset()
        assert all(np.all(np.isfinite(v)) for v in obs.values())
        venv.step(np.stack([venv.action_space.sample() for _ in range(4)]))
    finally:
        venv.close()


def test_without_worlds_the_envs_are_seeded_as_make_vec_env_seeds_them():
    cfg, train = _train(["train.n_envs=2", "train.vec_env=dummy"])
    venv = make_training_env(cfg, train, seed=11)
    try:
        assert [env.unwrapped.world.name for env in venv.envs] == ["flat", "flat"]
        for i, env in enumerate(venv.envs):  # action space seed + i now, the env seed + i at its first reset
            reference = venv.action_space
            fresh = spaces.Box(reference.low, reference.high, dtype=reference.dtype, seed=11 + i)
            np.testing.assert_array_equal(env.action_space.sample(), fresh.sample())
        first = venv.reset()
        again = make_training_env(cfg, train, seed=11)
        try:
            for key, value in again.reset().items():
                np.testing.assert_array_equal(value, first[key])
        finally:
            again.close()
    finally:
        venv.close()


@pytest.mark.parametrize(
    ("entries", "match"),
    [
        ("[nope]", r"train\.worlds\[0\]: no world option 'nope'; expected one of .*mars_yard"),
        ("['craters seed=7']", r"train\.worlds\[0\]: expected a conf/world option"),
        ("['craters world.sed=7']", r"train\.worlds\[0\] \('craters world\.sed=7'\): Could not override 'world\.sed'"),
        ("['craters world.n_craters=-3']", r"train\.worlds\[0\] .*world\.n_craters"),
        ("[craters,hills]", r"train\.worlds: 3 worlds .* need train\.n_envs >= 3, got 2"),
    ],
)
def test_bad_worlds_name_the_entry(entries, match):
    with pytest.raises(ConfigError, match=match):
        cfg, train = _train([f"train.worlds={entries}", "train.n_envs=2"])
        training_worlds(cfg, train)


def test_a_run_trains_in_every_world_and_refuses_a_bad_one_before_it_starts(tmp_path):
    assert run_in_process([*TINY, "train.worlds=[nope]", *store_args(tmp_path, "bad")]) == 2
    assert runs(tmp_path)[1] == []  # no MLflow run left behind
    args = TINY + ALGO_TINY["ppo"] + ["train.worlds=[hills]", "eval.episodes=2", "eval.every=0"]
    assert run_in_process(args + store_args(tmp_path)) == 0
    (run,) = runs(tmp_path)[1]
    assert run.info.status == "FINISHED" and json.loads(run.data.params["train.worlds"]) == ["hills"]
    assert run.data.tags["world"] == "flat"  # evaluation, and the run's world tag, stay on `world`
