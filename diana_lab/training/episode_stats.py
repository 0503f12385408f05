"""Per-term reward sums and outcome rates of recent training episodes, into the SB3 logger.

The env reports every weighted reward term per step (``info["reward_terms"]``) and the episode's ``outcome``;
summing the terms over an episode splits the return into what the agent was paid for, which is how a
misweighted term shows up (e.g. a heading bonus worth more than reaching the goal). Logged as
``train/reward_<term>`` (mean episode sum) and ``train/outcome_<outcome>`` (fraction of episodes), over the
last ``window`` episodes like SB3's own ``rollout/ep_rew_mean``.
"""

from __future__ import annotations

from collections import Counter, deque

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

__all__ = ["OUTCOMES", "EpisodeStats"]

OUTCOMES = ("success", "collision", "tipover", "out_of_bounds", "sim_error", "timeout", "stuck")


class EpisodeStats(BaseCallback):
    def __init__(self, window: int = 100) -> None:
        super().__init__()
        self.window = window
        self.episodes: deque[dict[str, float]] = deque(maxlen=window)
        self.outcomes: deque[str] = deque(maxlen=window)
        self._running: list[dict[str, float]] = []
        self._new = False  # episodes finished since the last record (off-policy rollouts are single steps)

    def _on_training_start(self) -> None:
        self._running = [{} for _ in range(self.training_env.num_envs)]

    def _on_step(self) -> bool:
        infos, dones = self.locals.get("infos", ()), self.locals.get("dones", ())
        for i, (info, done) in enumerate(zip(infos, dones)):
            acc = self._running[i]
            for term, value in info.get("reward_terms", {}).items():
                acc[term] = acc.get(term, 0.0) + float(value)
            if done:
                # the batched env sums the terms itself and reports them once, at the episode's end
                self.episodes.append(info.get("episode_reward_terms", acc))
                self.outcomes.append(str(info.get("outcome", "timeout")))
                self._running[i] = {}
                self._new = True
        return True

    def _on_rollout_end(self) -> None:
        self.record()

    def record(self) -> None:
        if not self._new:
            return
        self._new = False
        terms = sorted({t for ep in self.episodes for t in ep})
        for term in terms:
            self.logger.record(f"train/reward_{term}", float(np.mean([ep.get(term, 0.0) for ep in self.episodes])))
        counts = Counter(self.outcomes)
        for outcome in sorted(set(OUTCOMES) | set(counts)):
            self.logger.record(f"train/outcome_{outcome}", counts.get(outcome, 0) / len(self.outcomes))
