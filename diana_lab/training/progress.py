"""SB3's progress bar (tqdm + rich) showing the training speed and the recent success rate.

The rich bar does not draw tqdm's postfix, so the figures go into the description, refreshed about
twice a second rather than on every step.
"""

from __future__ import annotations

import time

import numpy as np
from stable_baselines3.common.callbacks import ProgressBarCallback

__all__ = ["ProgressWithStats"]


class ProgressWithStats(ProgressBarCallback):
    def __init__(self, refresh_s: float = 0.5) -> None:
        super().__init__()
        self.refresh_s = refresh_s
        self._t0 = self._last = 0.0
        self._n0 = 0

    def _on_training_start(self) -> None:
        super()._on_training_start()
        self._t0 = self._last = time.perf_counter()
        self._n0 = self.model.num_timesteps

    def _on_step(self) -> bool:
        super()._on_step()
        now = time.perf_counter()
        if now - self._last >= self.refresh_s:
            self._last = now
            self.pbar.set_description_str(self.stats(now), refresh=False)
        return True

    def stats(self, now: float | None = None) -> str:
        elapsed = max((now or time.perf_counter()) - self._t0, 1e-9)
        fps = (self.model.num_timesteps - self._n0) / elapsed
        buf = self.model.ep_success_buffer
        success = f"{np.mean(buf):.0%}" if len(buf) else "-"
        return f"{fps:.0f} fps, success {success}"

    def close(self) -> None:
        """Close the bar when training ends early (an interrupt skips ``_on_training_end``)."""
        pbar = getattr(self, "pbar", None)
        if pbar is not None and not pbar.disable:
            pbar.close()
