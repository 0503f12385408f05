"""Checkpoints: SB3's CheckpointCallback plus saving on demand (interrupt, end), MLflow upload and pruning.

Every checkpoint is ``<dir>/rl_model_<steps>_steps.zip`` with ``rl_model_vecnormalize_<steps>_steps.pkl``
(when observations are normalised) and, for off-policy algorithms, ``rl_model_replay_buffer_<steps>_steps.pkl``
(SB3's names). Replay buffers are hundreds of MB, so only the newest one is kept on disk and none is uploaded
unless ``tracking.log_replay_buffer``; the model and the statistics go to MLflow under ``checkpoints/``.
:func:`latest_checkpoint` finds what ``train.resume`` continues from.
"""

from __future__ import annotations

from pathlib import Path

from stable_baselines3.common.callbacks import CheckpointCallback

from diana_lab.tracking.checkpoint_files import MODEL_RE, PREFIX, Checkpoint, latest_checkpoint  # noqa: F401
from diana_lab.tracking.mlflow_run import Tracker

__all__ = ["PREFIX", "Checkpoint", "TrackedCheckpoints", "latest_checkpoint"]


class TrackedCheckpoints(CheckpointCallback):
    """Checkpoint every ``every`` env steps (0: only when :meth:`save` is called), upload, prune buffers."""

    def __init__(
        self,
        directory: Path,
        every: int,
        n_envs: int,
        tracker: Tracker,
        upload: bool = True,
        upload_replay_buffer: bool = False,
        off_policy: bool = False,
    ) -> None:
        save_freq = max(every // n_envs, 1) if every > 0 else 0
        super().__init__(
            save_freq=save_freq,
            save_path=str(directory),
            name_prefix=PREFIX,
            save_replay_buffer=off_policy,
            save_vecnormalize=True,
        )
        self.directory = Path(directory)
        self.tracker, self.upload, self.upload_replay_buffer = tracker, upload, upload_replay_buffer
        self.last: Checkpoint | None = None

    def _on_step(self) -> bool:
        if self.save_freq > 0 and self.n_calls % self.save_freq == 0:
            self.save()
        return True

    def save(self) -> Checkpoint:
        """Write a checkpoint at the current step count (again only if the step count moved on)."""
        self.num_timesteps = self.model.num_timesteps  # also called outside the training loop
        if self.last is not None and self.last.steps == self.num_timesteps:
            return self.last
        self.directory.mkdir(parents=True, exist_ok=True)
        self.model.save(self._checkpoint_path(extension="zip"))
        if self.save_replay_buffer and getattr(self.model, "replay_buffer", None) is not None:
            self.model.save_replay_buffer(self._checkpoint_path("replay_buffer_", extension="pkl"))
        vecnorm = self.model.get_vec_normalize_env()
        if vecnorm is not None:
            vecnorm.save(self._checkpoint_path("vecnormalize_", extension="pkl"))
        self.last = Checkpoint.at(self.directory, self.num_timesteps)
        self._prune_replay_buffers()
        if self.upload:
            for path in (
                self.last.model,
                self.last.vecnormalize,
                self.last.replay_buffer if self.upload_replay_buffer else None,
            ):
                if path is not None:
                    self.tracker.log_artifact(path, "checkpoints")
        return self.last

    def _prune_replay_buffers(self) -> None:
        keep = self.last.replay_buffer if self.last is not None else None
        for p in self.directory.glob(f"{PREFIX}_replay_buffer_*_steps.pkl"):
            if p != keep:
                p.unlink(missing_ok=True)
