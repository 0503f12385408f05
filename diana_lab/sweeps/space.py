"""Search spaces in Hydra's override grammar, mapped to Optuna distributions.

Users who know the Hydra Optuna sweeper already write ``key: interval(0.1, 5)``; the text is parsed by Hydra's
own override parser (so quoting, numbers and nesting follow Hydra exactly) and mapped the way that plugin maps
it, onto the Optuna >= 3 distributions (the plugin itself pins optuna < 3):

* ``interval(a, b)``                  -> ``FloatDistribution(a, b)``
* ``tag(log, interval(a, b))``        -> ``FloatDistribution(a, b, log=True)``
* ``int(interval(a, b))``             -> ``IntDistribution(a, b)`` (``tag(log, ...)`` for log scale)
* ``range(a, b[, step])``             -> ``IntDistribution`` / stepped ``FloatDistribution`` over the values
  Hydra's ``range`` yields: like Python's, ``b`` itself is excluded
* ``choice(x, y, ...)``               -> ``CategoricalDistribution`` (values keep their type; lists become text)
* anything else (``key: 3``)          -> a fixed override applied to every trial

A sampled value goes back into an override with :meth:`Param.override`, so a trial is composed exactly like
``python -m diana_lab key=value`` would be.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import ChoiceSweep, IntervalSweep, Override, RangeSweep, Transformer
from optuna.distributions import BaseDistribution, CategoricalDistribution, FloatDistribution, IntDistribution

from diana_lab.core.validation import ConfigError

__all__ = ["Param", "SpaceError", "format_value", "parse_entry"]

KNOWN_TAGS = frozenset({"log"})
_PLAIN = re.compile(r"^[A-Za-z0-9_.:/+-]+$")


class SpaceError(ConfigError):
    """A search-space entry that cannot be parsed or mapped; the caller adds the file and line."""


def format_value(value: Any) -> str:
    """``value`` as Hydra override text: numbers in full precision, strings quoted only when needed."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else {math.inf: "inf", -math.inf: "-inf"}.get(value, "nan")
    if isinstance(value, list | tuple):
        return "[" + ",".join(format_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ",".join(f"{k}:{format_value(v)}" for k, v in value.items()) + "}"
    text = str(value)
    if _PLAIN.match(text) and text not in ("true", "false", "null"):
        return text
    return "'" + text.replace("\\", "\\\\").replace("'", "\\'") + "'"


@dataclass(frozen=True)
class Param:
    """One searched key: the Hydra key (``reward.terms.goal.weight``), its Optuna distribution, and the override
    text of each categorical choice (so ``choice([64,64],[128,128])`` round-trips)."""

    key: str
    distribution: BaseDistribution
    expression: str
    choice_text: tuple[str, ...] = ()

    def override(self, value: Any) -> str:
        if isinstance(self.distribution, CategoricalDistribution) and self.choice_text:
            return f"{self.key}={self.choice_text[self.distribution.to_internal_repr(value)]}"
        if isinstance(self.distribution, IntDistribution):
            value = int(value)
        return f"{self.key}={format_value(value)}"

    def ends(self) -> tuple[Any, ...]:
        """The values that bound what a trial can get -- low and high end, or every choice: composing each
        checks the key, its type and its range before a trial does (a bad high end would fail only there)."""
        d = self.distribution
        return tuple(d.choices) if isinstance(d, CategoricalDistribution) else (d.low, d.high)


def _choices(override: Override) -> tuple[list[Any], tuple[str, ...]]:
    """Choice values for Optuna (which stores only str, int, float, bool and None: lists and dicts become their
    override text) and the override text of each."""
    choices: list[Any] = []
    text: list[str] = []
    for v in override.sweep_iterator(transformer=Transformer.identity):
        if isinstance(v, list | dict):
            choices.append(format_value(v))
        elif v is None or isinstance(v, str | int | float | bool):
            choices.append(v)
        else:
            raise SpaceError(f"choice value {v!r} of type {type(v).__name__} is not supported")
        text.append(format_value(v))
    if len(set(map(repr, choices))) != len(choices):
        raise SpaceError(f"choice values must be distinct, got {choices}")
    return choices, tuple(text)


def _range(value: RangeSweep, override: Override) -> tuple[BaseDistribution, tuple[str, ...]]:
    if value.shuffle:
        raise SpaceError("shuffle(...) has no meaning for a sampler; use choice(...) or range(...)")
    values = list(override.sweep_iterator(transformer=Transformer.identity))
    if not values:
        raise SpaceError(f"range({value.start}, {value.stop}, {value.step}) is empty (the end is excluded)")
    log = "log" in value.tags
    if all(isinstance(v, int) and not isinstance(v, bool) for v in (value.start, value.stop, value.step)):
        step = int(value.step)
        if step <= 0:
            raise SpaceError(f"range(...) needs a positive step, got {step}")
        if log and step != 1:
            raise SpaceError("tag(log, range(...)) needs step 1 (Optuna's log scale has no step)")
        if log and int(values[0]) <= 0:
            raise SpaceError(f"tag(log, range(...)) needs a start > 0, got {values[0]}")
        return IntDistribution(int(values[0]), int(values[-1]), log=log, step=step), ()
    if log:
        raise SpaceError("tag(log, range(...)) works on integers only; use tag(log, interval(a, b)) for floats")
    step = float(value.step)
    if step <= 0:
        raise SpaceError(f"range(...) needs a positive step, got {step}")
    low = float(value.start)
    high = low + step * (len(values) - 1)
    return FloatDistribution(low, round(high, 12), step=step), ()


def _interval(value: IntervalSweep) -> BaseDistribution:
    log = "log" in value.tags
    start, end = value.start, value.end
    if start is None or end is None or not start < end:
        raise SpaceError(f"interval({start}, {end}) needs low < high")
    if log and start <= 0:
        raise SpaceError(f"tag(log, interval({start}, {end})) needs low > 0 (a log scale cannot reach 0)")
    if isinstance(start, int) and isinstance(end, int):  # int(interval(a, b))
        return IntDistribution(start, end, log=log)
    return FloatDistribution(float(start), float(end), log=log)


def _distribution(override: Override) -> tuple[BaseDistribution, tuple[str, ...]]:
    value = override.value()
    tags = set(getattr(value, "tags", set()) or set())
    unknown = tags - KNOWN_TAGS
    if unknown:
        raise SpaceError(f"unknown tag(s) {sorted(unknown)}; the only tag with a meaning here is 'log'")
    if isinstance(value, ChoiceSweep):
        if tags:
            raise SpaceError("tag(log, ...) applies to interval(...) or range(...), not to choice(...)")
        choices, text = _choices(override)
        return CategoricalDistribution(choices), text
    if isinstance(value, RangeSweep):
        return _range(value, override)
    if isinstance(value, IntervalSweep):
        return _interval(value), ()
    raise SpaceError(f"{type(value).__name__} sweeps are not supported; use interval, range or choice")


def parse_entry(key: str, expression: Any) -> Param | str:
    """A :class:`Param` for a sweep expression, or the override text of a fixed value (``key=value``)."""
    if isinstance(expression, dict | list):
        raise SpaceError(
            f"expected one expression such as interval(0.1, 5) or choice(1, 2), got a YAML "
            f"{type(expression).__name__}; quote it to pass a fixed value"
        )
    text = f"{key}={format_value(expression) if not isinstance(expression, str) else expression}"
    try:
        (override,) = OverridesParser.create().parse_overrides([text])
    except Exception as exc:  # Hydra's OverrideParseException: keep its first lines, they say what is wrong
        lines = [ln for ln in str(exc).splitlines() if ln.strip() and not ln.startswith("See https")]
        raise SpaceError(f"cannot parse '{text}': {' '.join(lines[-1:]) or type(exc).__name__}") from exc
    if not override.is_sweep_override():
        return text
    if override.get_key_element() != override.key_or_group or override.package is not None:
        raise SpaceError(f"'{override.get_key_element()}': a searched key takes no +, ~ or @package prefix")
    try:
        distribution, choice_text = _distribution(override)
    except SpaceError:
        raise
    except Exception as exc:  # Optuna's own checks (e.g. low > high for a stepped range)
        raise SpaceError(str(exc)) from exc
    return Param(
        key=override.key_or_group, distribution=distribution, expression=str(expression), choice_text=choice_text
    )
