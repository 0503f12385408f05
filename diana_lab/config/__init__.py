"""Typed configuration: dataclass schemas, their registration in Hydra's ConfigStore, and helpers.

* :func:`compose` builds the full config from ``conf/`` (what every entry point and the env use).
* :func:`to_object` turns one group's node into its dataclass, running the range checks.
* :func:`build` calls a component's ``_target_`` with its typed config.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hydra.utils import get_object
from omegaconf import DictConfig, OmegaConf

from diana_lab.config import algo as _algo_schemas  # noqa: F401  (registers the algo schemas)
from diana_lab.config import env as _env_schemas  # noqa: F401  (registers its schemas)
from diana_lab.config import evaluation as _eval_schema  # noqa: F401  (registers the eval schema)
from diana_lab.config import policy as _policy_schemas  # noqa: F401  (registers the policy schemas)
from diana_lab.config import run as _run_schemas  # noqa: F401  (registers train, tracking)
from diana_lab.config import sensing as _sensor_schemas  # noqa: F401  (registers the sensor schemas)
from diana_lab.config import sweep as _sweep_schema  # noqa: F401  (registers the sweep schema)
from diana_lab.config.algo import check_action_space
from diana_lab.config.store import SCHEMAS, register, store_schemas
from diana_lab.core.validation import ConfigError

CONF_DIR = Path(__file__).resolve().parents[1] / "conf"  # inside the package: it travels with a wheel
GROUPS = ("world", "robot", "dynamics", "sensor", "action_space", "reward", "episode")
POLICY_CONFIGS = (
    "evaluate",
    "export",
    "calibrate",
    "scorecard",
)  # the top configs with a policy group (policy=<path> read as a source)

__all__ = [
    "CONF_DIR",
    "GROUPS",
    "POLICY_CONFIGS",
    "ConfigError",
    "build",
    "compose",
    "override_keys",
    "register",
    "store_schemas",
    "to_object",
    "validate",
]


def override_keys(overrides: Sequence[str], deletions: bool = False) -> list[str]:
    """The keys (or groups) command-line ``overrides`` name, in order, read by Hydra's own parser
    (``+experiment=reference`` -> ``experiment``); a deletion (``~key``) only with ``deletions``."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    if not overrides:
        return []
    parsed = OverridesParser.create().parse_overrides(list(overrides))
    return [o.key_or_group for o in parsed if deletions or not o.is_delete()]


def compose(overrides: Sequence[str] = (), config_name: str = "config") -> DictConfig:
    """Compose ``conf/<config_name>.yaml`` with Hydra overrides, outside a Hydra app (tests, env defaults);
    ``policy=<path or run id>`` reads as on the command line (:func:`diana_lab.config.policy.source_overrides`)."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    store_schemas()
    if config_name in POLICY_CONFIGS:
        from diana_lab.config.policy import source_overrides

        overrides = source_overrides(overrides, CONF_DIR)
    if GlobalHydra.instance().is_initialized():
        return hydra_compose(config_name=config_name, overrides=list(overrides))
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return hydra_compose(config_name=config_name, overrides=list(overrides))


def _schema_for(group: str, node: DictConfig | dict) -> type:
    kinds = SCHEMAS.get(group)
    if not kinds:
        raise ConfigError(f"{group}: no config schema is registered for this group")
    if len(kinds) == 1:
        return next(iter(kinds.values()))
    target = node.get("_target_")
    for schema in kinds.values():
        if (
            target is not None
            and getattr(schema, "_target_", None) == target
            and node.get("name") in (None, getattr(schema, "name", None))
        ):
            return schema
    name = node.get("name")
    if name in kinds:
        return kinds[name]
    raise ConfigError(f"{group}: unknown option {name!r}; expected one of {', '.join(sorted(kinds))}")


def to_object(group: str, node: Any) -> Any:
    """The dataclass for one group (from a dataclass, dict, DictConfig or an option name of ``conf/``)."""
    if dataclasses.is_dataclass(node) and not isinstance(node, type):
        return node
    if isinstance(node, str):
        if not (CONF_DIR / group / f"{node}.yaml").is_file():
            options = sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))
            raise ConfigError(f"{group}: unknown option {node!r}; expected one of {', '.join(options)}")
        node = compose([], config_name=f"{group}/{node}")[group]
    if isinstance(node, dict):
        node = OmegaConf.create(node)
    if not isinstance(node, DictConfig):
        raise ConfigError(f"{group}: expected a config mapping or an option name, got {type(node).__name__}")
    schema = _schema_for(group, node)
    try:
        if node._get_parent() is not None:  # a group of a composed config: resolve its ${...} against the root
            node = OmegaConf.create(OmegaConf.to_container(node, resolve=True))
        merged = OmegaConf.merge(OmegaConf.structured(schema), node)
        _check_required(group, schema, merged)
        return OmegaConf.to_object(merged)
    except ConfigError:
        raise
    except Exception as exc:  # OmegaConf validation errors: re-raise with the group name in front
        raise ConfigError(f"{group}: {exc}".split("\n    full_key")[0]) from exc


def _check_required(group: str, schema: type, node: DictConfig) -> None:
    """Name the keys of ``node`` left ``???`` (``world=dem`` without ``world.size_x``) and what each is, from
    its schema field's ``help`` metadata; OmegaConf would say only "missing mandatory value: size_x"."""
    missing = [str(k) for k in node if OmegaConf.is_missing(node, k)]
    if not missing:
        return
    helps = {f.name: f.metadata.get("help") for f in dataclasses.fields(schema)}
    option = f" for {group}={node.name}" if "name" not in missing and node.get("name") else ""
    raise ConfigError(
        "; ".join(
            f"{group}.{k}: missing, and required{option}"
            + (f": {helps[k]}" if helps.get(k) else " (it has no default)")
            for k in missing
        )
    )


def validate(cfg: DictConfig, groups: Sequence[str] = GROUPS, combinations: bool = True) -> dict[str, Any]:
    """Typed objects of every group present in ``cfg``; raises :class:`ConfigError` on impossible values,
    and (``combinations``) on groups that cannot work together (an ``algo`` that cannot drive the
    ``action_space``, the slope shield over a continuous one)."""
    typed = {g: to_object(g, cfg[g]) for g in groups if g in cfg}
    if not combinations:
        return typed
    if "algo" in typed and "action_space" in typed:
        check_action_space(typed["algo"], typed["action_space"].shape)
    shape = typed["action_space"].shape if "action_space" in typed else "discrete"
    if "eval" in typed and typed["eval"].shield.enabled and shape != "discrete":
        raise ConfigError(
            f"eval.shield.enabled with action_space.shape={shape}: the slope shield picks among a discrete action "
            "space's candidates; use action_space=discrete or eval.shield.enabled=false"
        )
    return typed


def build(cfg: Any, *args: Any, **kwargs: Any) -> Any:
    """Call ``cfg._target_`` with the typed config as its first argument."""
    return get_object(cfg._target_)(cfg, *args, **kwargs)
