"""A trial's config: ``conf/config.yaml`` composed with the override line that ``python -m diana_lab`` would get.

Trials are composed in the sweep's own process with Hydra's compose API (inside the running Hydra app, or a
fresh one in tests), so a trial is exactly ``python -m diana_lab <overrides>`` without paying for a new Python
process per trial. The chosen option of each group comes back too: it becomes the run's MLflow tags, as under
``python -m diana_lab``.
"""

from __future__ import annotations

from collections.abc import Sequence

from omegaconf import DictConfig, OmegaConf, open_dict

from diana_lab.config import CONF_DIR, ConfigError, store_schemas
from diana_lab.config import override_keys as _override_keys
from diana_lab.tracking.names import TAG_GROUPS

__all__ = ["compose_run", "override_keys"]


def _first_lines(exc: BaseException) -> str:
    """Hydra's message and, when it wraps one (``Error merging override ...``), the cause's first line."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip() and not ln.strip().startswith("See https")]
    text = " ".join(lines[:2]) or type(exc).__name__
    cause = exc.__cause__ or exc.__context__
    if cause is not None and str(cause).strip():
        text += f" ({str(cause).strip().splitlines()[0]})"
    return text


def compose_run(overrides: Sequence[str]) -> tuple[DictConfig, dict[str, str]]:
    """The composed config (without its ``hydra`` node) and the group choices, e.g. ``{"algo": "ppo"}``."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    store_schemas()

    def go() -> tuple[DictConfig, dict[str, str]]:
        try:
            cfg = compose(config_name="config", overrides=list(overrides), return_hydra_config=True)
        except Exception as exc:  # Hydra's composition errors name the override; keep their message
            raise ConfigError(_first_lines(exc)) from exc
        choices = {g: str(v) for g, v in cfg.hydra.runtime.choices.items() if g in TAG_GROUPS and v is not None}
        with open_dict(cfg):
            del cfg["hydra"]
        OmegaConf.set_struct(cfg, True)
        return cfg, choices

    if GlobalHydra.instance().is_initialized():
        return go()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return go()


def override_keys(overrides: Sequence[str]) -> set[str]:
    """The keys (or groups) that overrides set or delete: ``{"world", "reward.terms.goal.weight"}``."""
    return set(_override_keys(overrides, deletions=True))
