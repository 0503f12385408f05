"""Whether a saved policy fits the env it is about to drive, and what to tell the user when it does not.

A model whose observation space differs from the env's (another sensor, encoding or resolution) is refused
with a message naming the key and both shapes, and -- when the training config is known -- the config keys
that differ, since running it would only produce a shape error deep inside torch; a model over another action
space is refused the same way, since a categorical policy over 16 headings in an env of 64 would run without a
word. The message ends with what to do (:func:`rerun_advice`): the training's own env overrides, when its
``.hydra/overrides.yaml`` was kept (beside its ``config.yaml``, among a run's artefacts), else to repeat the
overrides it was trained with. Evaluation, ``train.resume`` and the exporter share these checks. A model whose
spaces fit but whose sensor or action-space settings differ runs, with a note naming them (:func:`settings_note`).
"""

from __future__ import annotations

import shlex
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gymnasium import spaces
from omegaconf import DictConfig, ListConfig, OmegaConf

from diana_lab.config import GROUPS, ConfigError

__all__ = [
    "check_action_space",
    "check_observation_space",
    "check_spaces",
    "config_differences",
    "flat_keys",
    "recorded_overrides",
    "rerun_advice",
    "settings_note",
]


def recorded_overrides(config: Path | None) -> list[str] | None:
    """The command-line overrides of the training whose ``.hydra/config.yaml`` is ``config``: Hydra's
    ``overrides.yaml`` beside it; ``None`` when it is not there (a model copied without it, the shipped policy)."""
    path = config.with_name("overrides.yaml") if config is not None else None
    if path is None or not path.is_file():
        return None
    try:
        loaded = OmegaConf.load(path)
    except Exception:  # unreadable: as good as not recorded
        return None
    return [str(o) for o in loaded] if isinstance(loaded, ListConfig) else None


MAX_LISTED_KEYS = 8  # differing config keys a refusal or a note names

# what an override sets the env with: a group of the env, or the preset that sets them (+experiment=quick)
_ENV_ROOTS = (*GROUPS, "experiment")


def _env_override(override: str) -> bool:
    key = override.lstrip("+~").split("=", 1)[0]
    return key.split(".", 1)[0].split("@", 1)[0] in _ENV_ROOTS


def rerun_advice(train_overrides: Sequence[str] | None, given: Sequence[str] = ()) -> str:
    """The end of a refusal of a model trained in another env than this command's: the training's overrides
    of the env (its groups and ``+experiment``) that ``given``, this command line's, lacks, ready to paste."""
    if train_overrides is None:
        return "Re-run with the overrides it was trained with (they are not recorded with the model)."
    env = [o for o in train_overrides if _env_override(o)]
    missing = [o for o in env if o not in set(given)]
    if missing:
        return f"Re-run with the training's overrides: {' '.join(shlex.quote(o) for o in missing)}"
    if not env:
        return "It was trained with the default env (no env overrides): drop the overrides that change these keys."
    return (
        f"It was trained with {' '.join(shlex.quote(o) for o in env)}: drop the other overrides that change these keys."
    )


def _shapes(space: spaces.Space) -> dict[str, tuple[tuple[int, ...], str]]:
    if isinstance(space, spaces.Dict):
        return {k: (tuple(s.shape or ()), str(s.dtype)) for k, s in space.spaces.items()}
    return {"<observation>": (tuple(space.shape or ()), str(space.dtype))}


def flat_keys(node: Any, prefix: str = "") -> dict[str, Any]:
    """``{"a.b.c": value}`` of a config (a ``DictConfig``, resolved, or plain dicts; lists are values); ``{}`` for
    None."""
    if isinstance(node, DictConfig | ListConfig):
        node = OmegaConf.to_container(node, resolve=True)
    if node is None:
        return {}
    if not isinstance(node, dict):
        return {prefix: node}
    out: dict[str, Any] = {}
    for k, v in node.items():
        out.update(flat_keys(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


def config_differences(
    train_cfg: DictConfig | None,
    eval_cfg: DictConfig | None,
    groups: tuple[str, ...] = ("sensor", "world", "episode"),
    in_both_only: bool = False,
    ignore: frozenset[str] = frozenset(),
) -> list[str]:
    """``group.key: training X, here Y`` for the config keys that shape observations (when both are known);
    ``in_both_only``: only keys both configs have (one the training predates is not a difference it made);
    ``ignore``: full keys left out."""
    if train_cfg is None or eval_cfg is None:
        return []
    diffs = []
    for g in groups:
        a = flat_keys(train_cfg.get(g))
        b = flat_keys(eval_cfg.get(g))
        keys = set(a) & set(b) if in_both_only else set(a) | set(b)
        for k in sorted(keys):
            if a.get(k) != b.get(k) and f"{g}.{k}" not in ignore:
                diffs.append(f"{g}.{k}: training {a.get(k)!r}, here {b.get(k)!r}")
    return diffs


def check_observation_space(
    model_space: spaces.Space,
    env_space: spaces.Space,
    label: str,
    hints: list[str] | None = None,
    advice: str | None = None,
) -> None:
    """Refuse a policy trained on other observations (keys, shapes, dtypes); bounds may differ (goal distance
    bounds follow the world size, and the policy only ever sees the clipped values). ``advice`` ends the message
    (:func:`rerun_advice`)."""
    want, have = _shapes(model_space), _shapes(env_space)
    problems = []
    for k in sorted(set(want) | set(have)):
        if k not in have:
            problems.append(f"the policy expects observation key '{k}' {want[k][0]}, which this env does not give")
        elif k not in want:
            problems.append(f"this env gives observation key '{k}' {have[k][0]}, which the policy was not trained on")
        elif want[k] != have[k]:
            problems.append(
                f"observation '{k}' is {want[k][0]} {want[k][1]} for the policy but {have[k][0]} {have[k][1]} here"
            )
    if problems:
        raise _refusal(
            f"policy {label}: trained with other observation settings than this evaluation: {'; '.join(problems)}.",
            hints,
            "Evaluate with the sensor settings the policy was trained with (sensor=..., sensor.encoding=..., "
            "sensor.width/height).",
            advice,
        )


def check_action_space(
    model_space: spaces.Space,
    env_space: spaces.Space,
    label: str,
    hints: list[str] | None = None,
    advice: str | None = None,
) -> None:
    """Refuse a policy trained on another action space. A categorical policy over 16 headings in an env of 64
    would run without a word, its indices meaning other waypoints; over 64 in an env of 16, fail mid-episode.
    ``advice`` ends the message (:func:`rerun_advice`)."""

    def describe(space: spaces.Space) -> str:
        if isinstance(space, spaces.Discrete):
            return f"{space.n} candidate waypoints (discrete)"
        return f"a continuous {tuple(space.shape or ())} waypoint"

    same = type(model_space) is type(env_space) and (
        model_space.n == env_space.n
        if isinstance(model_space, spaces.Discrete)
        else tuple(model_space.shape or ()) == tuple(env_space.shape or ())
    )
    if not same:
        raise _refusal(
            f"policy {label}: trained on {describe(model_space)}, but this evaluation's action_space gives "
            f"{describe(env_space)}.",
            hints,
            "Evaluate with the action_space the policy was trained with (action_space=..., headings, distances).",
            advice,
        )


def check_spaces(loaded: Any, env: Any, cfg: DictConfig, overrides: Sequence[str] = ()) -> None:
    """Refuse ``loaded`` (a :class:`~diana_lab.evaluation.loading.LoadedPolicy` with a model) when its observations
    or actions are not ``env``'s, naming the config keys that differ from its training's (and the preset of the
    shipped policy, when left out), and ending with the training's overrides that ``overrides``, this command
    line's, lacks (or, not recorded, to repeat them)."""

    def hints(*groups: str) -> list[str]:
        diffs = config_differences(loaded.train_cfg, cfg, *((groups,) if groups else ()))
        # another group chosen than the shipped policy's (sensor.name: training lidar3d, here ...): no preset
        if loaded.label == "pretrained" and any(d.split(":", 1)[0].endswith(".name") for d in diffs):
            return ["add +experiment=reference (the shipped policy's training preset)", *diffs]
        return diffs

    # the shipped policy's preset is said above; a model without its training config gets the generic hint
    known = loaded.train_cfg is not None and loaded.label != "pretrained"
    advice = rerun_advice(loaded.train_overrides, overrides) if known else None
    model = loaded.model
    check_observation_space(model.observation_space, env.observation_space, loaded.label, hints(), advice)
    check_action_space(model.action_space, env.action_space, loaded.label, hints("action_space"), advice)


# the groups whose settings change what a policy's observations or actions mean without changing their shapes
NOTED_GROUPS = ("sensor", "action_space")
SPEED_ONLY_KEYS = frozenset({"sensor.nthreads"})  # how fast observations are made, not what they hold


def settings_note(loaded: Any, cfg: DictConfig, overrides: Sequence[str] = ()) -> str | None:
    """A note when ``loaded``'s spaces fit but it was trained with other sensor or action-space settings than
    ``cfg``'s: a lidar mounted elsewhere, another range, other drive lengths for as many candidates. It runs, and
    may be meant (a noise or transfer test), but its figures are then not those of the set-up it learnt in, and
    nothing else would say so. Keys the training's config lacks (it predates them) are left out."""
    if loaded.model is None:
        return None
    diffs = config_differences(loaded.train_cfg, cfg, NOTED_GROUPS, in_both_only=True, ignore=SPEED_ONLY_KEYS)
    if not diffs:
        return None
    more = f"; +{len(diffs) - MAX_LISTED_KEYS} more" if len(diffs) > MAX_LISTED_KEYS else ""
    advice = rerun_advice(loaded.train_overrides, overrides) if loaded.label != "pretrained" else None
    return (
        f"note: {loaded.label} was trained with other {' / '.join(NOTED_GROUPS)} settings than this evaluation's "
        f"({'; '.join(diffs[:MAX_LISTED_KEYS])}{more}); its spaces fit, so it runs as asked."
        + (f" {advice}" if advice else "")
    )


def _refusal(problem: str, hints: list[str] | None, fallback: str, advice: str | None) -> ConfigError:
    """The error refusing a model: ``problem``, then the config keys that differ from its training's (at most
    ``MAX_LISTED_KEYS``; ``fallback``, what to set, when they are not known), then ``advice``, what to re-run
    with."""
    hint = f"Differing config keys: {'; '.join(hints[:MAX_LISTED_KEYS])}." if hints else fallback
    return ConfigError(" ".join(part for part in (problem, hint, advice) if part))
