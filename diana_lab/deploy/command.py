"""``python -m diana_lab.export`` behind its Hydra entry: which config the exported files describe.

The graph and its sidecar must describe what the policy was trained with, so ``sensor``, ``action_space``,
``episode`` and ``robot`` come from its training config, and a command-line setting of those that would change
the files is refused, naming it (:func:`check_overrides`). The slope shield comes from the training config too,
with the command line's ``eval.shield.<key>`` settings laid over it (:func:`export_shield`): an evaluation
without the shield only changes its numbers, a bundle without it drives without it on the rover. A policy from an
MLflow run (a run id, a registered model version) is logged back to that run as the ONNX model ``policy_onnx``
(:mod:`diana_lab.deploy.tracking`) when ``tracking.enabled``.
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Sequence
from typing import Any

from omegaconf import DictConfig, OmegaConf

from diana_lab.config import ConfigError
from diana_lab.core.validation import positive_int
from diana_lab.deploy.export import check_opset, check_output, export_policy
from diana_lab.deploy.sidecar import action_spec, encoding_spec, sensor_spec
from diana_lab.deploy.spec import PolicySpec, sidecar_path
from diana_lab.evaluation.compatibility import flat_keys

__all__ = ["PRETRAINED_PRESET", "TRAINED_GROUPS", "check_overrides", "chosen_keys", "export_shield", "run"]

TRAINED_GROUPS = ("sensor", "action_space", "episode", "robot")  # what the export takes from the training config
# the shipped policy's preset: its config predates eval.shield, the preset holds the shield its card reports
PRETRAINED_PRESET = "+experiment=reference"


def chosen_keys(cfg: DictConfig, overrides: Sequence[str] | None) -> set[str]:
    """The keys of ``TRAINED_GROUPS`` and ``eval`` this export's command line set: those its ``overrides`` name
    (a group choice, ``robot=husky``, names its whole group), and those whose value differs from
    ``conf/export.yaml``'s, which is how a preset (``+experiment=...``) shows its choices, and all a config
    composed outside Hydra (``overrides`` None) can show."""
    from diana_lab.config import compose, override_keys

    # shield=<option> chooses every key of eval.shield, the group's package
    named = ["eval.shield" if n == "shield" else n for n in override_keys(overrides or ())]
    default = compose([], config_name="export")
    chosen = set()
    for group in (*TRAINED_GROUPS, "eval"):
        here, base = flat_keys(cfg.get(group), group), flat_keys(default.get(group), group)
        chosen |= {
            k
            for k in here.keys() | base.keys()
            if here.get(k) != base.get(k) or any(k == n or k.startswith(f"{n}.") for n in named)
        }
    return chosen


def _laid_over(base: Any, node: Any, prefix: str, keys: Sequence[str]) -> dict[str, Any]:
    """``base`` (a config node) with ``node``'s values of ``keys`` (``prefix.a.b``) laid over it; a key ``node``
    lacks (dropped by another group option) is dropped too."""
    out = OmegaConf.create(OmegaConf.to_container(base, resolve=True) if isinstance(base, DictConfig) else base or {})
    values = flat_keys(node, prefix)
    for key in keys:
        rel = key[len(prefix) + 1 :]
        if key in values:
            OmegaConf.update(out, rel, values[key], merge=False, force_add=True)
        elif isinstance(parent := OmegaConf.select(out, rel.rpartition(".")[0] or "."), DictConfig):
            parent.pop(rel.rpartition(".")[2], None)
    return OmegaConf.to_container(out)


def _shown(keys: Sequence[str], here: dict[str, Any], train: dict[str, Any]) -> str:
    """``key=value (training value)`` for the first few of ``keys``."""
    shown = [f"{k}={here.get(k)} (training {train.get(k, 'not set')})" for k in keys[:4]]
    return ", ".join(shown) + (f" and {len(keys) - 4} more" if len(keys) > 4 else "")


def export_shield(cfg: DictConfig, train_cfg: DictConfig | None, chosen: set[str], label: str) -> tuple[Any, str]:
    """The slope shield to export (``ShieldConfig``): the training's (``eval.shield`` of its config; for the
    shipped policy, whose config predates it, :data:`PRETRAINED_PRESET`'s) with the ``eval.shield`` keys this
    command line chose laid over it; the command line's when no training config is known. The evaluation
    takes the shield from the command line, where leaving it out only changes the numbers; a bundle exported
    without the shield the policy was trained behind drives without it on the rover. With it, the line to
    print when that differs from the command line's own (else "")."""
    from diana_lab.config import compose, to_object

    here = to_object("eval", cfg.eval).shield
    if train_cfg is not None and OmegaConf.select(train_cfg, "eval.shield", default=None) is not None:
        base, source = train_cfg.eval.shield, f"policy {label}'s training config"
    elif train_cfg is not None and label == "pretrained":
        base, source = compose([PRETRAINED_PRESET]).eval.shield, f"{PRETRAINED_PRESET}, the shipped policy's preset"
    else:
        return here, ""
    keys = sorted(k for k in chosen if k.startswith("eval.shield."))
    node = OmegaConf.to_container(cfg.eval, resolve=True)
    node["shield"] = {**node["shield"], **_laid_over(base, cfg.eval.shield, "eval.shield", keys)}
    shield = to_object("eval", node).shield

    def settings(s: Any) -> Any:
        return dataclasses.asdict(s) if s.enabled else None

    if settings(shield) == settings(here):
        return shield, ""
    given = f", with {', '.join(keys)} from the command line" if keys else ""
    on = shield.enabled
    return shield, (
        f"eval.shield: {'on' if on else 'off'} as in {source}{given}: the sidecar {'carries' if on else 'has'} "
        f"{'the' if on else 'no'} slope shield (eval.shield.enabled={str(not on).lower()} exports "
        f"{'without' if on else 'with'} it)"
    )


def check_overrides(cfg: DictConfig, train_cfg: DictConfig, chosen: set[str], shield: Any, label: str) -> None:
    """Refuse command-line settings of ``TRAINED_GROUPS`` that would change the exported files: the export takes
    those groups from the training config, since the files must describe what the policy was trained with,
    and a replaced setting must not pass unseen. Settings that do not reach the files (the simulator's, a robot
    without a shield to size) are named in one line."""
    from diana_lab.config import to_object
    from diana_lab.errors import UserError
    from diana_lab.shield import ShieldSettings

    def exported(group: str, node: Any) -> Any:
        obj = to_object(group, node)
        if group == "sensor":
            return sensor_spec(obj), encoding_spec(obj)
        if group == "action_space":
            return action_spec(obj)
        if group == "episode":
            return float(obj.distance_scale)
        return ShieldSettings.from_config(shield, obj) if shield.enabled else None  # robot: the shield's size

    unused = []
    for group in TRAINED_GROUPS:
        if group not in train_cfg:
            continue  # the command line's is used
        here, train = flat_keys(cfg.get(group), group), flat_keys(train_cfg[group], group)
        keys = sorted(k for k in chosen if k.startswith(f"{group}.") and here.get(k) != train.get(k))
        if not keys:
            continue
        name = f"{group}.name"
        # another option of the group (robot=husky): named as chosen, not key by key
        shown = f"{group}={here.get(name)} (training {train.get(name)})" if name in keys else _shown(keys, here, train)
        want = exported(group, train_cfg[group])
        try:
            changed = exported(group, _laid_over(train_cfg[group], cfg.get(group), group, keys)) != want
        except ConfigError:  # settings that do not fit the training's option
            changed = True
        if changed:
            raise UserError(
                f"{shown}: policy {label} was trained with other {group} settings, and the "
                f"export takes sensor, action_space, episode and robot from its training config (the exported files "
                f"must describe what the policy was trained with); expected no such overrides: drop them to export "
                f"with the training's"
            )
        unused.append(shown)
    if unused:
        print(f"note: not in the exported files, so not checked against policy {label}'s training: {'; '.join(unused)}")


def run(cfg: DictConfig, overrides: Sequence[str] | None = None) -> PolicySpec:
    """``python -m diana_lab.export``: load ``cfg.policy`` with the evaluation's loader, export it. ``overrides``:
    the command line's (Hydra's ``overrides.task``), which tell a setting chosen there from a default."""
    from diana_lab.config import to_object
    from diana_lab.config.evaluation import ShieldConfig
    from diana_lab.errors import UserError, output_file
    from diana_lab.evaluation.loading import load_policy

    if cfg.get("policy") is None:
        raise UserError(
            "policy: expected policy=<MLflow run id | model .zip or run folder | pretrained>, e.g. "
            "python -m diana_lab.export policy=outputs/run/model output=policy.onnx"
        )
    out = output_file(cfg.output)  # before loading: a path that cannot be written fails naming `output`
    check_output(out)
    positive_int("opset", cfg.opset)  # opset=abc: int() would fail naming no key
    check_opset(cfg.opset)
    chosen = chosen_keys(cfg, overrides)
    # loaded without the shield: the export takes the bare policy, and decides the shield once it knows the training's
    eval_cfg = dataclasses.replace(to_object("eval", cfg.eval), shield=ShieldConfig())
    loaded = load_policy(cfg.policy, cfg, eval_cfg)
    if loaded.model is None:
        raise UserError(f"policy={loaded.label}: a classical baseline, not a trained policy; nothing to export")
    train_cfg = loaded.train_cfg
    if train_cfg is None:
        print(
            f"warning: no training config found with {loaded.label}; the sidecar takes sensor, action_space, "
            "episode, robot and eval.shield from this command's config -- make sure they match the training run"
        )
    shield_cfg, shield_note = export_shield(cfg, train_cfg, chosen, loaded.label)
    if train_cfg is not None:
        check_overrides(cfg, train_cfg, chosen, shield_cfg, loaded.label)
    if shield_note:
        print(shield_note)

    def group(name: str) -> Any:
        node = train_cfg[name] if train_cfg is not None and name in train_cfg else cfg[name]
        return to_object(name, node)

    source = {
        "policy": str(cfg.policy.get("source")),  # the run id, path or 'pretrained' it was exported from
        "label": loaded.label,
        "run_id": loaded.run_id,
        "config": "training" if train_cfg is not None else "command line",
    }
    shield = None
    if shield_cfg.enabled:  # the runtime drives behind the slope shield too, with the training robot's size
        from diana_lab.shield import ShieldSettings

        shield = dataclasses.asdict(ShieldSettings.from_config(shield_cfg, group("robot")))
    spec = export_policy(
        loaded.model,
        loaded.policy.vecnormalize,
        group("sensor"),
        group("action_space"),
        group("episode"),
        out,
        int(cfg.opset),
        source,
        shield,
    )
    if loaded.run_id is not None and OmegaConf.select(cfg, "tracking.enabled", default=False):
        import mlflow
        from mlflow.exceptions import MlflowException

        from diana_lab.deploy.tracking import ONNX_MODEL, log_onnx_model

        try:
            log_onnx_model(out, loaded.model, loaded.run_id, mlflow.get_tracking_uri())  # the loader's store
            print(
                f"logged {out.name} and its sidecar to MLflow run {loaded.run_id} as runs:/{loaded.run_id}/{ONNX_MODEL}"
            )
        except (MlflowException, OSError) as exc:  # the files are written and checked: say so, and go on
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            print(f"warning: could not log {out.name} to MLflow run {loaded.run_id} ({first})", file=sys.stderr)
    site_cell = float(spec.shield.get("site_map_cell", 0.0)) if spec.shield is not None else 0.0
    site = f", site_map=SiteMap(heights, origin, {site_cell:g})" if site_cell > 0 else ""
    print(
        f"wrote {out} ({out.stat().st_size / 1024:.0f} kB) and {sidecar_path(out)}: {spec.encoding.name} "
        f"{spec.encoding.shape} from a {spec.sensor.type}, {spec.action_space.shape} action space "
        f"({spec.action_space.frame} frame); load with diana_lab.deploy.Navigator.from_files('{out}'{site})"
    )
    return spec
