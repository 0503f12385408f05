"""``train.overlap``: the next rollout collected in the background during each update, one update of lag."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.utils import set_random_seed

from diana_lab.agents.factory import build_model
from diana_lab.agents.overlap import overlapped
from diana_lab.config import ConfigError, compose, to_object
from diana_lab.training.threads import check_overlap
from tests.training.helpers import TINY

from .fake_env import FakeRoverEnv

N_ENVS, N_STEPS = 2, 16
ROLLOUT = N_ENVS * N_STEPS


def _model(overlap: bool, name: str = "ppo", seed: int = 0, env_fn=None):
    extra = ["algo.batch_size=16", "algo.n_epochs=2", "algo.learning_rate=0.003"] if name == "ppo" else []
    cfg = to_object("algo", compose([f"algo={name}", f"algo.n_steps={N_STEPS}", "algo.net_arch=[16]", *extra]).algo)
    env = make_vec_env(env_fn or (lambda: FakeRoverEnv(candidates=4)), n_envs=N_ENVS, seed=seed)
    return build_model(cfg, env, seed=seed, overlap=overlap)


class _Record(BaseCallback):
    """What SB3's callbacks see: ``num_timesteps`` and the step's locals at every ``on_step``, the rollout ends."""

    def __init__(self, stop_at: int | None = None) -> None:
        super().__init__()
        self.steps: list[int] = []
        self.dones: list[np.ndarray] = []
        self.rollouts = 0
        self.stop_at = stop_at

    def _on_step(self) -> bool:
        self.steps.append(self.num_timesteps)
        self.dones.append(np.array(self.locals["dones"]))
        assert len(self.locals["infos"]) == N_ENVS and self.locals["rewards"].shape == (N_ENVS,)
        return self.stop_at is None or self.num_timesteps < self.stop_at

    def _on_rollout_end(self) -> None:
        self.rollouts += 1


def _states_before_each_update(model) -> list[dict[str, torch.Tensor]]:
    states: list[dict[str, torch.Tensor]] = []
    train = model.train

    def recorded() -> None:
        states.append({k: v.clone() for k, v in model.policy.state_dict().items()})
        train()

    model.train = recorded
    return states


def test_each_rollout_is_collected_one_update_before_and_recentred_on_the_live_policy(monkeypatch):
    """Rollout 2 is collected while update 1 runs, by the weights before update 1; before update 2 its log-probs
    become those of the weights update 2 starts from, its advantages weighted by min(1, live / collecting)."""
    from diana_lab.agents import overlap

    seen: list[dict[str, np.ndarray]] = []
    recentre = overlap.recentre

    def recorded(algo, buffer, *args):
        before = {"log_probs": buffer.log_probs.copy(), "advantages": buffer.advantages.copy()}
        recentre(algo, buffer, *args)
        seen.append({**before, "live": buffer.log_probs.copy(), "weighted": buffer.advantages.copy()})

    monkeypatch.setattr(overlap, "recentre", recorded)
    model = _model(overlap=True)
    states = _states_before_each_update(model)
    model.learn(3 * ROLLOUT)
    assert len(states) == 3 and len(seen) == 2  # rollout 0 was collected the usual way, by the live policy
    buf = model.rollout_buffer  # rollout 2, flattened by the update
    spaces = model.observation_space.spaces
    obs = {k: torch.as_tensor(v.reshape(ROLLOUT, *spaces[k].shape)) for k, v in buf.observations.items()}
    actions = torch.as_tensor(buf.actions.reshape(-1))

    def log_probs(state):
        model.policy.load_state_dict(state)
        with torch.no_grad():
            return model.policy.evaluate_actions(obs, actions)[1].numpy()

    def flat(a):  # (n_steps, n_envs) in SB3's flattening order
        return a.swapaxes(0, 1).reshape(-1)

    collected, live = seen[-1]["log_probs"], seen[-1]["live"]
    np.testing.assert_allclose(log_probs(states[1]), flat(collected), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(log_probs(states[2]), flat(live), rtol=1e-5, atol=1e-6)
    assert not np.allclose(collected, live, rtol=1e-5, atol=1e-6)  # the live weights had moved on
    weight = np.minimum(1.0, np.exp(live - collected))
    np.testing.assert_allclose(seen[-1]["weighted"], seen[-1]["advantages"] * weight, rtol=1e-5, atol=1e-7)
    assert (weight < 1).any()


def test_callbacks_see_the_steps_counts_and_locals_of_sb3s_own_loop():
    seen = {}
    for overlap in (False, True):
        model, record = _model(overlap), _Record()
        model.learn(4 * ROLLOUT, callback=record)
        seen[overlap] = record
        assert model.num_timesteps == 4 * ROLLOUT and record.rollouts == 4
        assert len(model.ep_info_buffer) > 0  # the Monitor's episodes reached the info buffer
        assert model._overlap_thread is None if overlap else True  # nothing left running
    assert seen[True].steps == seen[False].steps == list(range(N_ENVS, 4 * ROLLOUT + 1, N_ENVS))
    # the same env seeds and episode length: the episodes end at the same steps either way
    assert [d.tolist() for d in seen[True].dones] == [d.tolist() for d in seen[False].dones]


def test_same_seed_same_weights_other_seed_other_weights():
    """On the batched env (the FakeRoverEnv's observations are not seeded): the background thread draws the
    actions from torch's generator while the update draws the minibatches from numpy's."""
    from diana_lab import config as C
    from diana_lab.training.envs import make_training_env

    overrides = [o for o in TINY if not o.startswith("hydra/")] + ["algo.n_steps=32", "algo.batch_size=32"]
    cfg = C.compose(overrides, config_name="config")
    typed = C.validate(cfg, ["algo", "train"])

    def trained(seed: int) -> dict[str, torch.Tensor]:
        set_random_seed(seed)
        venv = make_training_env(cfg, typed["train"], seed)
        model = build_model(typed["algo"], venv, seed, overlap=True)
        model.learn(4 * 2 * 32)
        venv.close()
        assert type(model).__name__ == "OverlappedPPO"
        return model.policy.state_dict()

    a, b, c = trained(0), trained(0), trained(1)
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not all(torch.equal(a[k], c[k]) for k in a)


def test_a_callback_that_stops_training_leaves_nothing_running():
    model, record = _model(overlap=True), _Record(stop_at=ROLLOUT + 2 * N_ENVS)
    model.learn(10 * ROLLOUT, callback=record)
    assert record.steps[-1] == ROLLOUT + 2 * N_ENVS  # stopped in the first rollout collected in the background
    assert model._overlap_thread is None
    assert not [t for t in threading.enumerate() if t.name == "overlapped-rollout"]
    model.learn(2 * ROLLOUT, reset_num_timesteps=False)  # and it learns on from there
    assert model.num_timesteps >= 3 * ROLLOUT


class _Broken(FakeRoverEnv):
    def step(self, action):
        self.calls = getattr(self, "calls", 0) + 1
        if self.calls > N_STEPS + 3:
            raise RuntimeError("terrain file vanished")
        return super().step(action)


def test_an_env_error_in_the_background_is_raised_in_learn():
    model = _model(overlap=True, env_fn=lambda: _Broken(candidates=4))
    with pytest.raises(RuntimeError, match="terrain file vanished"):
        model.learn(4 * ROLLOUT)
    assert model._overlap_thread is None


def test_a_saved_model_loads_into_the_plain_class_and_back(tmp_path):
    model = _model(overlap=True)
    model.learn(2 * ROLLOUT)
    model.save(tmp_path / "m.zip")
    plain = PPO.load(tmp_path / "m.zip", device="cpu")
    again = overlapped(PPO).load(tmp_path / "m.zip", env=model.env, device="cpu")
    obs = model.env.reset()
    for other in (plain, again):
        np.testing.assert_array_equal(
            other.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0]
        )
    again.learn(2 * ROLLOUT, reset_num_timesteps=False)
    assert again.num_timesteps == 4 * ROLLOUT


def test_a2c_overlaps_too():
    model, record = _model(overlap=True, name="a2c"), _Record()
    before = {k: v.clone() for k, v in model.policy.state_dict().items()}
    model.learn(3 * ROLLOUT, callback=record)
    assert type(model).__name__ == "OverlappedA2C" and record.rollouts == 3
    assert not all(torch.equal(before[k], v) for k, v in model.policy.state_dict().items())


def test_overlap_is_refused_for_an_off_policy_algorithm_naming_the_key():
    check_overlap(True, off_policy=False, algo_name="ppo")
    check_overlap(False, off_policy=True, algo_name="sac")
    with pytest.raises(ConfigError, match=r"train.overlap=true: algo=sac is off-policy"):
        check_overlap(True, off_policy=True, algo_name="sac")
    with pytest.raises(TypeError, match="not an on-policy algorithm"):
        overlapped(SAC)
