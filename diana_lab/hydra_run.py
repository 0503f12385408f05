"""What the running Hydra app was asked: the command line's overrides, for the code that records or repeats them."""

from __future__ import annotations

from omegaconf import OmegaConf

__all__ = ["task_overrides"]


def task_overrides() -> list[str]:
    """The command line's overrides of the running Hydra app (``hydra.overrides.task``), as typed.

    Read unresolved: Hydra keeps them in a ListConfig, and iterating that resolves an override holding an
    interpolation (``'reward.terms.pitch.params.deadband_deg=${...roll.params.deadband_deg}'``, as a sweep's
    reproduce line carries) against the list, where a relative key is not found."""
    from hydra.core.hydra_config import HydraConfig

    return [str(o) for o in OmegaConf.to_container(HydraConfig.get().overrides.task, resolve=False)]
