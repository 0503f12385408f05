"""Small value checks with messages that name the key and what was expected: the config dataclasses' ``__post_init__``
and the onboard runtime's shield settings (numpy-free, so the runtime can use them without Hydra)."""

from __future__ import annotations

import math
from collections.abc import Sequence


class ConfigError(ValueError):
    """A config value that cannot work; the message names the key and what was expected."""


def boolean(key: str, value: object) -> bool:
    """A true/false option, returned: ``bool("no")`` is True, so anything but a real bool is refused, naming
    ``key``, rather than switching the option on (a schema-less key keeps the string Hydra was given)."""
    if not isinstance(value, bool):
        raise ConfigError(f"{key}: expected true or false, got {value!r}")
    return value


MAX_SEED = 2**32 - 1  # numpy's (and so SB3's and Optuna's samplers') seeds are 32-bit unsigned


def check_seed(key: str, value: object) -> None:
    """A seed numpy accepts, checked before the work: numpy's own error names no key."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_SEED:
        raise ConfigError(f"{key}: expected an integer from 0 to 2**32 - 1, got {value!r}")


def positive(key: str, value: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
        raise ConfigError(f"{key}: expected a positive number, got {value!r}")


def non_negative(key: str, value: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
        raise ConfigError(f"{key}: expected a number >= 0, got {value!r}")


def positive_int(key: str, value: int) -> None:
    """Resolutions and counts: a positive whole number (a bool is not one)."""
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise ConfigError(f"{key}: expected a positive integer, got {value!r}")


def non_negative_int(key: str, value: int, note: str = "") -> None:
    """A whole number >= 0; ``note`` says what 0 means (e.g. ``"0 disables"``)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ConfigError(f"{key}: expected an integer >= 0{f' ({note})' if note else ''}, got {value!r}")


def in_range(key: str, value: float, lo: float, hi: float, *, inclusive: bool = True) -> None:
    ok = lo <= value <= hi if inclusive else lo < value < hi
    if not (isinstance(value, int | float) and math.isfinite(value) and ok):
        bracket = f"[{lo}, {hi}]" if inclusive else f"({lo}, {hi})"
        raise ConfigError(f"{key}: expected a number in {bracket}, got {value!r}")


def ordered(key_lo: str, lo: float, key_hi: str, hi: float) -> None:
    if not lo < hi:
        raise ConfigError(f"{key_lo} ({lo}) must be smaller than {key_hi} ({hi})")


def one_of(key: str, value: str, options: Sequence[str]) -> None:
    if value not in options:
        raise ConfigError(f"{key}: expected one of {', '.join(map(repr, options))}, got {value!r}")


def length(key: str, value: Sequence, n: int) -> None:
    if len(value) != n:
        raise ConfigError(f"{key}: expected {n} values, got {len(value)} ({list(value)!r})")
