"""On-policy learning whose next rollout is collected while the current one is learnt from (``train.overlap``).

Why: an on-policy update (PPO's epochs over the rollout) and the next rollout (the batched env's compiled
kernels and the policy's forward passes) each keep one core of a small machine busy, one after the other. Run
side by side, a rollout collected by a frozen copy of the policy in a background thread while the main thread
updates the live one, they share the cores instead (the env's kernels and torch's operations release the GIL).
The price is one update of lag: the rollout learnt from at update ``k`` was collected by the weights of update
``k - 1``. Left as it is, PPO would clip its ratio against the policy that collected the rollout, which the live one
has already moved away from: many more samples are clipped from the first epoch on, and the update learns less
(docs/batched.md). So before each update the rollout is re-centred, as decoupled PPO does (Hilton et al.
2022, "Batch size-invariance for policy optimization"): the stored ``log_probs`` become the live policy's (the
proximal policy the ratio is clipped round), and each advantage is weighted by the importance ratio of the live
policy to the one that collected it, truncated at 1 (V-trace's rho-bar, IMPALA). This is the asynchronous
actor-learner pattern (IMPALA, Sample Factory) with a single actor and a lag of one.

What stays as SB3 does it: the first rollout of every ``learn`` call is collected the usual way; every step's
callbacks (``on_step`` with ``infos``, ``dones``, ``rewards``, ``actions``), ``on_rollout_start``/``end``, the episode
info buffer and ``num_timesteps`` are replayed in the main thread, in step order, before the update that uses the
rollout, so evaluations, checkpoints and metrics see what they saw before, at the same step counts. No rollout is
collected beyond ``total_timesteps``, so nothing is lost or left running when ``learn`` returns. Only torch's global
random generator is drawn from in the background (action sampling); the update draws from numpy's (minibatch
order), so a seed gives the same run every time.
"""

from __future__ import annotations

import threading
from functools import cache
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.buffers import DictRolloutBuffer, RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.utils import obs_as_tensor
from stable_baselines3.common.vec_env import VecEnv

__all__ = ["OverlappedRollouts", "overlapped", "recentre"]


class _Rollout:
    """What a background rollout hands over besides its buffer: each step's record for the callbacks, and the
    error that ended it, if one did."""

    def __init__(self) -> None:
        self.steps: list[dict[str, Any]] = []
        self.error: BaseException | None = None


class OverlappedRollouts:
    """Mixin for an :class:`~stable_baselines3.common.on_policy_algorithm.OnPolicyAlgorithm`: ``collect_rollouts``
    hands over the rollout a background thread collected during the previous update and starts the next one.
    Use :func:`overlapped` to get the class (``overlapped(PPO)``)."""

    _overlap_thread: threading.Thread | None
    _overlap_rollout: _Rollout | None
    _overlap_actor: ActorCriticPolicy | None
    _overlap_spare: RolloutBuffer | None
    _overlap_stop: threading.Event

    def _excluded_save_params(self) -> list[str]:
        return [
            *super()._excluded_save_params(),  # type: ignore[misc]
            "_overlap_thread",
            "_overlap_rollout",
            "_overlap_actor",
            "_overlap_spare",
            "_overlap_stop",
        ]

    def _overlap_state(self) -> None:
        if not hasattr(self, "_overlap_stop"):
            self._overlap_thread = self._overlap_rollout = self._overlap_actor = self._overlap_spare = None
            self._overlap_stop = threading.Event()

    def learn(self, *args: Any, **kwargs: Any) -> Any:
        self._overlap_state()
        try:
            return super().learn(*args, **kwargs)  # type: ignore[misc]
        finally:
            self._discard_pending()  # only set when learn stops early (a callback, Ctrl-C, an error)

    def collect_rollouts(
        self, env: VecEnv, callback: BaseCallback, rollout_buffer: RolloutBuffer, n_rollout_steps: int
    ) -> bool:
        algo: OnPolicyAlgorithm = self  # type: ignore[assignment]
        self._overlap_state()
        handed_over = self._overlap_thread is not None  # collected in the background during the last update
        if not handed_over:
            if not super().collect_rollouts(env, callback, rollout_buffer, n_rollout_steps):  # type: ignore[misc]
                return False
        elif not self._hand_over(callback):
            return False
        if algo.num_timesteps < algo._total_timesteps:  # the loop goes on: the next rollout is needed
            self._start(env, n_rollout_steps)
        if handed_over:  # while the next rollout is collected
            recentre(algo, algo.rollout_buffer)
        return True

    # ------------------------------------------------------------------ the main thread
    def _hand_over(self, callback: BaseCallback) -> bool:
        """Wait for the background rollout, make its buffer the one the update reads, and replay its steps'
        callbacks in order (``False``: a callback stopped training)."""
        algo: OnPolicyAlgorithm = self  # type: ignore[assignment]
        assert self._overlap_thread is not None and self._overlap_rollout is not None
        self._overlap_thread.join()
        rollout = self._overlap_rollout
        self._overlap_thread = self._overlap_rollout = None
        if rollout.error is not None:
            raise rollout.error
        assert self._overlap_spare is not None
        algo.rollout_buffer, self._overlap_spare = self._overlap_spare, algo.rollout_buffer
        callback.on_rollout_start()
        for step in rollout.steps:
            algo.num_timesteps += algo.env.num_envs  # type: ignore[union-attr]
            callback.update_locals(step)
            if not callback.on_step():
                return False
            algo._update_info_buffer(step["infos"], step["dones"])
        callback.on_rollout_end()
        return True

    def _start(self, env: VecEnv, n_steps: int) -> None:
        """Snapshot the live weights into the actor and start collecting the next rollout with them."""
        algo: OnPolicyAlgorithm = self  # type: ignore[assignment]
        if self._overlap_actor is None:
            self._overlap_actor = algo.policy_class(  # type: ignore[call-arg]
                algo.observation_space, algo.action_space, algo.lr_schedule, use_sde=algo.use_sde, **algo.policy_kwargs
            ).to(algo.device)
            buffer_cls = DictRolloutBuffer if isinstance(algo.observation_space, spaces.Dict) else RolloutBuffer
            self._overlap_spare = buffer_cls(
                algo.n_steps,
                algo.observation_space,  # type: ignore[arg-type]
                algo.action_space,
                device=algo.device,
                gamma=algo.gamma,
                gae_lambda=algo.gae_lambda,
                n_envs=algo.n_envs,
            )
        self._overlap_actor.load_state_dict(algo.policy.state_dict())
        self._overlap_actor.set_training_mode(False)
        self._overlap_stop.clear()
        self._overlap_rollout = rollout = _Rollout()
        self._overlap_thread = threading.Thread(
            target=self._collect, args=(env, n_steps, rollout), name="overlapped-rollout", daemon=True
        )
        self._overlap_thread.start()

    def _discard_pending(self) -> None:
        if getattr(self, "_overlap_thread", None) is not None:
            self._overlap_stop.set()
            self._overlap_thread.join()  # type: ignore[union-attr]
            self._overlap_thread = self._overlap_rollout = None

    # ------------------------------------------------------------------ the background thread
    def _collect(self, env: VecEnv, n_steps: int, rollout: _Rollout) -> None:
        """SB3's ``collect_rollouts`` with the actor, into the spare buffer, recording what the callbacks read."""
        try:
            self._collect_steps(env, n_steps, rollout)
        except BaseException as exc:  # handed to the main thread at the hand-over
            rollout.error = exc

    def _collect_steps(self, env: VecEnv, n_steps: int, rollout: _Rollout) -> None:
        algo: OnPolicyAlgorithm = self  # type: ignore[assignment]
        actor, buffer = self._overlap_actor, self._overlap_spare
        assert actor is not None and buffer is not None
        buffer.reset()
        if algo.use_sde:
            actor.reset_noise(env.num_envs)
        new_obs = dones = None
        for n in range(n_steps):
            if self._overlap_stop.is_set():
                return
            if algo.use_sde and algo.sde_sample_freq > 0 and n % algo.sde_sample_freq == 0:
                actor.reset_noise(env.num_envs)
            with torch.no_grad():
                actions, values, log_probs = actor(obs_as_tensor(algo._last_obs, algo.device))  # type: ignore[arg-type]
            actions = actions.cpu().numpy()
            clipped = actions
            if isinstance(algo.action_space, spaces.Box):
                if actor.squash_output:
                    clipped = actor.unscale_action(clipped)
                else:
                    clipped = np.clip(actions, algo.action_space.low, algo.action_space.high)
            new_obs, rewards, dones, infos = env.step(clipped)
            rollout.steps.append(
                {
                    "infos": infos,
                    "dones": dones,
                    "rewards": rewards.copy(),
                    "actions": actions,
                    "clipped_actions": clipped,
                    "values": values,
                    "log_probs": log_probs,
                }
            )
            if isinstance(algo.action_space, spaces.Discrete):
                actions = actions.reshape(-1, 1)
            for idx, done in enumerate(dones):  # a time limit's end: bootstrap from the value (SB3 issue 633)
                info = infos[idx]
                if done and info.get("terminal_observation") is not None and info.get("TimeLimit.truncated", False):
                    terminal_obs = actor.obs_to_tensor(info["terminal_observation"])[0]
                    with torch.no_grad():
                        rewards[idx] += algo.gamma * actor.predict_values(terminal_obs)[0]  # type: ignore[arg-type]
            buffer.add(algo._last_obs, actions, rewards, algo._last_episode_starts, values, log_probs)  # type: ignore[arg-type]
            algo._last_obs, algo._last_episode_starts = new_obs, dones  # type: ignore[assignment]
        with torch.no_grad():
            last_values = actor.predict_values(obs_as_tensor(new_obs, algo.device))  # type: ignore[arg-type]
        buffer.compute_returns_and_advantage(last_values=last_values, dones=dones)  # type: ignore[arg-type]


RECENTRE_BATCH = 4096  # samples per forward pass when re-centring a rollout


def recentre(algo: OnPolicyAlgorithm, buffer: RolloutBuffer, rho_bar: float = 1.0) -> None:
    """Make a rollout collected by an older policy one the live policy can be updated on with PPO's clipping
    (decoupled PPO, see the module docstring): ``log_probs`` <- the live policy's log-probabilities of the stored
    actions, ``advantages`` *= min(rho_bar, live / collecting probability). ``returns`` (the value targets) stay."""
    policy = algo.policy
    policy.set_training_mode(False)
    n = buffer.buffer_size * buffer.n_envs
    if isinstance(buffer.observations, dict):
        obs = {k: v.reshape(n, *v.shape[2:]) for k, v in buffer.observations.items()}
    else:
        obs = buffer.observations.reshape(n, *buffer.observations.shape[2:])
    actions = buffer.actions.reshape(n, -1)
    live = np.empty(n, dtype=np.float32)
    with torch.no_grad():
        for lo in range(0, n, RECENTRE_BATCH):
            part = slice(lo, lo + RECENTRE_BATCH)
            o = {k: v[part] for k, v in obs.items()} if isinstance(obs, dict) else obs[part]
            a = torch.as_tensor(actions[part], device=algo.device)
            if isinstance(algo.action_space, spaces.Discrete):
                a = a.long().flatten()
            _, log_prob, _ = policy.evaluate_actions(obs_as_tensor(o, algo.device), a)  # type: ignore[arg-type]
            live[part] = log_prob.cpu().numpy()
    live = live.reshape(buffer.log_probs.shape)
    buffer.advantages *= np.minimum(rho_bar, np.exp(live - buffer.log_probs))
    buffer.log_probs = live


@cache
def overlapped(cls: type[OnPolicyAlgorithm]) -> type[OnPolicyAlgorithm]:
    """``cls`` (PPO, A2C or another on-policy algorithm) with :class:`OverlappedRollouts`; its saved models load
    into ``cls`` and back."""
    if not issubclass(cls, OnPolicyAlgorithm):
        raise TypeError(f"overlapped: {cls.__name__} is not an on-policy algorithm (PPO, A2C)")
    return type(f"Overlapped{cls.__name__}", (OverlappedRollouts, cls), {"__module__": __name__})
