"""Training progress on the console: a bar on a terminal, one plain line per interval anywhere else.

Both show the speed and how the last 100 episodes ended: success beside the failures that matter on rough
ground (tip-over, stuck, timeout; collision too once any happens). On a terminal it is SB3's progress bar
(tqdm + rich; the rich bar does not draw tqdm's postfix, so the figures go into the description, refreshed about
twice a second). When stdout is not a terminal (a cluster job, ``nohup``, a pipe) a bar would only appear at the
end, so a line is printed every ``line_interval_s`` seconds instead, and once at the end. Under a Hydra job those
lines reach the job's log file with the rest of the console (``diana_lab.run_log``); while a bar is drawn, the same
plain line goes to the log file alone, as often and once at the end, so the file never holds the bar.
"""

from __future__ import annotations

import sys
import time
from collections import Counter, deque
from typing import TextIO

from stable_baselines3.common.callbacks import BaseCallback, ProgressBarCallback

from diana_lab.run_log import log_only

__all__ = ["ProgressWithStats", "outcome_rates"]

SHOWN = ("success", "tipover", "stuck", "timeout")


def outcome_rates(outcomes: deque[str] | list[str]) -> str:
    """``success 62% tip-over 21% stuck 9% timeout 8%`` (collision and the rest only when they happened)."""
    if not outcomes:
        return "no episode ended yet"
    counts, n = Counter(outcomes), len(outcomes)
    names = [*SHOWN, *sorted(k for k in counts if k not in SHOWN)]
    label = {"tipover": "tip-over"}
    return " ".join(f"{label.get(k, k)} {counts[k] / n:.0%}" for k in names if k in SHOWN or counts[k])


class ProgressWithStats(BaseCallback):
    """The bar (``bar=True``; default: whether ``stream`` is a terminal) or the plain lines."""

    def __init__(
        self,
        refresh_s: float = 0.5,
        line_interval_s: float = 30.0,
        bar: bool | None = None,
        stream: TextIO | None = None,
        window: int = 100,
    ) -> None:
        super().__init__()
        self.stream = stream if stream is not None else sys.stdout
        self.bar = self.stream.isatty() if bar is None else bar
        self.refresh_s = refresh_s if self.bar else line_interval_s
        self.line_interval_s = line_interval_s
        self._logged = 0.0  # when the bar's plain line last went to the log file
        self.outcomes: deque[str] = deque(maxlen=window)
        self._bar: ProgressBarCallback | None = None
        self._t0 = self._last = 0.0
        self._n0 = 0
        self._total = 0

    def _on_training_start(self) -> None:
        self._t0 = self._last = self._logged = time.perf_counter()
        self._n0 = self.model.num_timesteps
        self._total = self.locals["total_timesteps"]
        if self.bar:
            self._bar = ProgressBarCallback()
            self._bar.init_callback(self.model)
            self._bar.on_training_start(self.locals, self.globals)

    def _on_step(self) -> bool:
        for info, done in zip(self.locals.get("infos", ()), self.locals.get("dones", ())):
            if done:
                self.outcomes.append(str(info.get("outcome", "timeout")))
        if self._bar is not None:
            self._bar.update_locals(self.locals)
            self._bar.on_step()
        now = time.perf_counter()
        if now - self._last >= self.refresh_s:
            self._last = now
            self.show(now)
        return True

    def stats(self, now: float | None = None) -> str:
        elapsed = max((now or time.perf_counter()) - self._t0, 1e-9)
        fps = (self.model.num_timesteps - self._n0) / elapsed
        return f"{fps:.0f} steps/s | {outcome_rates(self.outcomes)}"

    def line(self, now: float | None = None) -> str:
        """The plain progress line: steps, share of the budget, elapsed and remaining time, the stats."""
        now = now or time.perf_counter()
        done, total = self.model.num_timesteps, max(self._total, 1)
        elapsed = now - self._t0
        rate = (done - self._n0) / max(elapsed, 1e-9)
        left = max(total - done, 0) / rate if rate > 0 else float("nan")
        eta = f"{left / 60:.1f} min left" if left == left else "-"
        return (
            f"[train] {done:,}/{total:,} steps ({done / total:.0%}) | {elapsed / 60:.1f} min, {eta} | {self.stats(now)}"
        )

    def show(self, now: float | None = None) -> None:
        if self._bar is not None:
            now = now or time.perf_counter()
            self._bar.pbar.set_description_str(self.stats(now), refresh=False)
            if now - self._logged >= self.line_interval_s:
                self._logged = now
                log_only(self.line(now))
        else:
            print(self.line(now), file=self.stream, flush=True)

    def _on_training_end(self) -> None:
        if self._bar is not None:
            self._bar.on_training_end()
            self._bar = None
            log_only(self.line())
        else:
            self.show()

    def close(self) -> None:
        """Close the bar when training ends early (an interrupt skips ``_on_training_end``)."""
        bar = self._bar
        if bar is not None:
            pbar = getattr(bar, "pbar", None)
            if pbar is not None and not pbar.disable:
                pbar.close()
            self._bar = None
            log_only(self.line())  # where the log file's account of the interrupted training ends
