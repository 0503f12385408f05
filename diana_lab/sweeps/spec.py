"""A sweep file (``sweeps/<name>.yaml``): base overrides, search space, objective and budget.

The file is data a user edits by hand, so every mistake is reported as ``sweeps/<name>.yaml:<line>: <key>:
<what is wrong>`` -- the line comes from the YAML parser's marks -- and raised as a :class:`ConfigError`,
which the command line turns into one paragraph and exit status 2. Format::

    description: what the study is for
    base: [+experiment=quick, eval.video=false]   # overrides of every trial (before the command line's)
    objective: {metric: spl, direction: maximize}
    budget: {n_trials: 50, timesteps: 20000, eval_episodes: 20, eval_every: 5000}
    params:                                         # Hydra's sweep grammar, see diana_lab.sweeps.space
      reward.terms.goal.weight: tag(log, interval(1, 100))
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from diana_lab.config.sweep import DIRECTIONS, SweepConfig
from diana_lab.core.validation import ConfigError
from diana_lab.evaluation.metrics import SUMMARY_KEYS
from diana_lab.sweeps.space import Param, SpaceError, parse_entry

__all__ = ["BUDGET_KEYS", "METRICS", "SWEEPS_DIR", "SweepSpec", "available", "find_sweep", "load_spec"]

SWEEPS_DIR = Path(__file__).resolve().parent / "specs"  # the shipped search spaces, inside the package
METRICS = tuple(k for k in SUMMARY_KEYS if k != "episodes")  # what an objective can be
SECTIONS = {
    "description": None,
    "base": None,
    "objective": ("metric", "direction"),
    "budget": ("n_trials", "timesteps", "eval_episodes", "eval_every", "prune_after"),
    "params": None,
}
DEFAULTS = {"metric": "spl", "direction": "maximize", "n_trials": 20}
# budget entry -> the config key it sets in every trial
BUDGET_KEYS = {"timesteps": "train.total_timesteps", "eval_episodes": "eval.episodes", "eval_every": "eval.every"}


@dataclass(frozen=True)
class SweepSpec:
    name: str
    path: Path
    params: tuple[Param, ...]
    base: tuple[str, ...] = ()  # the file's base overrides plus its fixed ``params`` entries
    description: str = ""
    metric: str = "spl"
    direction: str = "maximize"
    n_trials: int = 20
    timesteps: int | None = None  # None: the composed config's train.total_timesteps
    eval_episodes: int | None = None  # None: the composed config's eval.episodes
    eval_every: int | None = None  # None: the composed config's eval.every; 0: no periodic evaluation
    prune_after: int = 0  # training steps before which the median pruner prunes no trial (early scores are noise)
    lines: dict[str, int] = field(default_factory=dict)  # param key -> line in the file (for later errors)

    def where(self, key: str | None = None) -> str:
        """``sweeps/x.yaml:12`` for the line of ``key`` (or just the file)."""
        line = self.lines.get(key) if key else None
        return f"{_display(self.path)}:{line}" if line else _display(self.path)

    def with_settings(self, cfg: SweepConfig) -> SweepSpec:
        """The spec with the command line's ``sweep.*`` values in place of the file's."""
        changes = {
            k: getattr(cfg, k)
            for k in ("metric", "direction", "n_trials", "timesteps", "eval_episodes", "eval_every", "prune_after")
            if getattr(cfg, k) is not None
        }
        if "metric" in changes:
            _check_metric(changes["metric"], "sweep.metric")
        return dataclasses.replace(self, **changes)


def _display(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(Path.cwd()))
    except ValueError:
        try:
            return str(path.resolve().relative_to(SWEEPS_DIR.parent))
        except ValueError:
            return str(path)


def available() -> list[str]:
    return sorted(p.stem for p in SWEEPS_DIR.glob("*.yaml"))


def find_sweep(name: str) -> Path:
    """``sweeps/<name>.yaml``, or ``name`` itself when it is a path to a YAML file."""
    if name.endswith((".yaml", ".yml")) or "/" in name:
        path = Path(name).expanduser()
        if not path.is_file():
            raise ConfigError(f"sweep.name={name}: no such sweep file")
        return path
    path = SWEEPS_DIR / f"{name}.yaml"
    if not path.is_file():
        raise ConfigError(
            f"sweep.name={name}: unknown sweep (no {_display(path)}); expected one of {', '.join(available())} "
            f"or a path to a sweep file"
        )
    return path


def _key_lines(node: yaml.Node | None, prefix: str = "") -> dict[str, int]:
    """``{"budget.n_trials": 7, "params.reward.terms.goal.weight": 12, "base[0]": 3, ...}`` (1-based lines)."""
    out: dict[str, int] = {}
    if isinstance(node, yaml.MappingNode):
        for key_node, value_node in node.value:
            key = f"{prefix}{key_node.value}"
            out[key] = key_node.start_mark.line + 1
            if not prefix:  # one level down: the keys of each section and the items of ``base``
                out.update(_key_lines(value_node, f"{key}."))
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            out[f"{prefix[:-1]}[{i}]"] = item.start_mark.line + 1
    return out


def _check_metric(metric: Any, where: str) -> None:
    if metric not in METRICS:
        raise ConfigError(f"{where}: unknown metric {metric!r}; expected one of {', '.join(METRICS)}")


def _positive_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value > 0


def load_spec(name: str) -> SweepSpec:
    """Read and check a sweep file (see the module docstring); every error names the file and line."""
    path = find_sweep(name)
    shown = _display(path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:  # a ValueError that would name neither the file nor what was expected
        raise ConfigError(f"{shown}: not a text file (expected a YAML sweep file, see docs/sweeps.md)") from exc
    except OSError as exc:
        raise ConfigError(f"{shown}: cannot read the sweep file ({exc.strerror or exc})") from exc
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text) or {}
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f":{mark.line + 1}" if mark is not None else ""
        why = str(getattr(exc, "problem", None) or exc).strip().splitlines()[0]
        raise ConfigError(f"{shown}{line}: not valid YAML ({why})") from exc
    lines = _key_lines(root)

    def fail(key: str, message: str) -> ConfigError:
        line = lines.get(key)
        return ConfigError(f"{shown}{f':{line}' if line else ''}: {key}: {message}")

    if not isinstance(data, dict):
        raise ConfigError(f"{shown}: expected a mapping with sections {', '.join(SECTIONS)}")
    for section, value in data.items():
        if section not in SECTIONS:
            raise fail(str(section), f"unknown section; expected one of {', '.join(SECTIONS)}")
        keys = SECTIONS[section]
        if keys is not None:
            if not isinstance(value, dict):
                raise fail(section, f"expected a mapping with keys {', '.join(keys)}")
            for k in value:
                if k not in keys:
                    raise fail(f"{section}.{k}", f"unknown key; expected one of {', '.join(keys)}")
    objective = data.get("objective") or {}
    budget = data.get("budget") or {}
    settings = {**DEFAULTS, **objective, **budget}
    if "metric" in objective:
        try:
            _check_metric(objective["metric"], "objective.metric")
        except ConfigError as exc:
            raise fail("objective.metric", str(exc).split(": ", 1)[1]) from None
    if settings["direction"] not in DIRECTIONS:
        raise fail("objective.direction", f"expected one of {', '.join(DIRECTIONS)}, got {settings['direction']!r}")
    for key in ("n_trials", "timesteps", "eval_episodes"):
        if key in budget and not _positive_int(budget[key]):
            raise fail(f"budget.{key}", f"expected a positive integer, got {budget[key]!r}")
    every = settings.get("eval_every")
    if every is not None and not (isinstance(every, int) and not isinstance(every, bool) and every >= 0):
        raise fail("budget.eval_every", f"expected an integer >= 0 (0: no pruning), got {every!r}")
    prune_after = settings.get("prune_after", 0)
    if not (isinstance(prune_after, int) and not isinstance(prune_after, bool) and prune_after >= 0):
        raise fail("budget.prune_after", f"expected an integer >= 0 (training steps), got {prune_after!r}")

    base_raw = data.get("base") or []
    if isinstance(base_raw, str):
        base_raw = base_raw.split()
    if not isinstance(base_raw, list):
        raise fail("base", "expected a list of overrides such as [+experiment=quick, world=flat]")
    base: list[str] = []
    for i, item in enumerate(base_raw):
        if not isinstance(item, str) or "=" not in item:
            raise fail(f"base[{i}]", f"expected an override key=value, got {item!r}")
        base.append(item)

    params_raw = data.get("params") or {}
    if not isinstance(params_raw, dict) or not params_raw:
        raise fail("params", "expected a mapping of config keys to search expressions, e.g. x: interval(0, 1)")
    params: list[Param] = []
    param_lines: dict[str, int] = {}
    for key, expression in params_raw.items():
        where = f"params.{key}"
        try:
            entry = parse_entry(str(key), expression)
        except SpaceError as exc:
            raise fail(where, str(exc)) from None
        if isinstance(entry, str):
            base.append(entry)
        else:
            params.append(entry)
            param_lines[entry.key] = lines.get(where, 0)
    if not params:
        raise fail("params", "no searched key (every entry is a fixed value)")
    return SweepSpec(
        name=path.stem,
        path=path,
        params=tuple(params),
        base=tuple(base),
        description=str(data.get("description") or ""),
        metric=settings["metric"],
        direction=settings["direction"],
        n_trials=settings["n_trials"],
        timesteps=settings.get("timesteps"),
        eval_episodes=settings.get("eval_episodes"),
        eval_every=every,
        prune_after=prune_after,
        lines=param_lines,
    )
