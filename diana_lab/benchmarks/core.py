"""What every benchmark shares: the figure record, its statistics and target, the registry, the context.

Why it is shaped this way:

* A *measurement* is one function ``fn(ctx) -> list[Figure]`` registered with :func:`measurement` under the
  figure keys it produces. Some figures are only meaningful side by side (open3d and PyBullet over the same
  poses, their ratio), so one measurement may produce several keys from interleaved repeats. Adding a
  figure (e.g. the ONNX policy latency once ``diana_lab/deploy`` exists) is one decorated function.
* Every figure is the median over ``repeats`` timed batches, after one untimed warm-up batch (first-call
  costs: scene building, caches, lazy imports), with p10/p90 to show the spread; a batch holds many
  operations so that each sample is long compared with the timer and with scheduler noise.
* Targets are those the issues set; ``met`` is ``None`` where there is none or the value is missing.
"""

from __future__ import annotations

import gc
import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Literal

import numpy as np
import yaml
from omegaconf import DictConfig, OmegaConf, open_dict

from diana_lab.core.validation import boolean, positive_int

__all__ = [
    "MEASUREMENTS",
    "BenchContext",
    "Figure",
    "Measurement",
    "Target",
    "figure_from_samples",
    "flag",
    "measurement",
    "repeat",
    "select",
]


@dataclass(frozen=True)
class Target:
    """A bound an issue sets on a figure: ``value <= bound`` (``op='<='``) or ``value >= bound``."""

    op: Literal["<=", ">="]
    value: float

    def met(self, value: float | None) -> bool | None:
        if value is None or not math.isfinite(value):
            return None
        return value <= self.value if self.op == "<=" else value >= self.value

    def __str__(self) -> str:
        return f"{self.op} {self.value:g}"


@dataclass
class Figure:
    """One benchmark figure as written to the JSON (see ``benchmarks/README.md`` for the keys)."""

    key: str
    unit: str
    value: float | None  # the median over the repeats
    p10: float | None = None
    p90: float | None = None
    n: int = 0  # timed repeats (batches) behind the median
    batch: str = ""  # what one repeat measures, e.g. "24 frames"
    target: Target | None = None
    note: str | None = None
    anchor: dict[str, Any] | None = None  # the reference this figure is compared with
    error: str | None = None  # set when the measurement failed; value is then None
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def met(self) -> bool | None:
        return self.target.met(self.value) if self.target is not None else None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "value": _round(self.value),
            "unit": self.unit,
            "p10": _round(self.p10),
            "p90": _round(self.p90),
            "n": self.n,
            "batch": self.batch,
            "target": {"op": self.target.op, "value": self.target.value} if self.target else None,
            "met": self.met,
            "anchor": {k: _round(v) if isinstance(v, float) else v for k, v in self.anchor.items()}
            if self.anchor
            else None,
            "note": self.note,
        }
        if self.error is not None:
            out["error"] = self.error
        out.update({k: _round(v) if isinstance(v, float) else v for k, v in self.extra.items()})
        return out


def _round(v: float | None, digits: int = 5) -> float | None:
    if v is None or not math.isfinite(v):
        return None
    return float(f"{v:.{digits}g}")


def figure_from_samples(key: str, unit: str, samples: Sequence[float], **kwargs: Any) -> Figure:
    """Median, p10 and p90 of per-repeat samples (NaN samples, e.g. an empty batch, are dropped)."""
    arr = np.asarray([s for s in samples if s is not None and math.isfinite(s)], dtype=np.float64)
    if arr.size == 0:
        return Figure(key, unit, None, n=0, **kwargs)
    p10, p50, p90 = np.percentile(arr, [10, 50, 90])
    return Figure(key, unit, float(p50), float(p10), float(p90), int(arr.size), **kwargs)


def repeat(sample: Callable[[], Any], repeats: int, warmup: int = 1) -> list[Any]:
    """Run ``sample`` ``warmup`` times untimed, then ``repeats`` times; a GC pass before each keeps a
    collection triggered by earlier garbage out of the timed batch."""
    for _ in range(warmup):
        sample()
    out = []
    for _ in range(repeats):
        gc.collect()
        out.append(sample())
    return out


class Stopwatch:
    """Accumulates wall time of the timed sections only (``with sw: ...``), so set-up stays outside."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self._t0 = 0.0

    def __enter__(self) -> Stopwatch:
        self._t0 = time.perf_counter()
        return self

    def __exit__(self, *exc: object) -> None:
        self.seconds += time.perf_counter() - self._t0


# ----------------------------------------------------------------------------------------------- context


def flag(cfg: DictConfig, key: str) -> bool:
    """A true/false option (absent: false), strictly (:func:`~diana_lab.core.validation.boolean`)."""
    return boolean(key, cfg.get(key, False))


class BenchContext:
    """The composed config, the mode (quick or full) and what several measurements share (world, poses).

    Every measurement uses the composed config's groups (defaults: mars_yard, Jackal, the 64 x 48 depth
    camera), with open3d casts pinned to one thread (``sensor.nthreads=1``; the heightfield caster always
    runs on one). The ray-casting backend is the run's ``sensor.backend`` (e.g. ``sensor.backend=open3d`` on
    the command line), also for the figures that pick their own sensor option.
    """

    def __init__(self, cfg: DictConfig) -> None:
        self.cfg = cfg.copy()
        with open_dict(self.cfg):
            self.cfg.sensor.nthreads = 1
        self.quick = flag(cfg, "quick")
        repeats = cfg.get("repeats")
        if repeats is not None:  # 0 must not mean "the default", nor 2.7 quietly become 2
            positive_int("repeats", repeats)
        self.repeats: int = repeats or (3 if self.quick else 7)
        self.seed = int(cfg.get("seed", 0))
        self.backend = str(self.cfg.sensor.get("backend", "heightfield"))

    def size(self, full: int, quick: int) -> int:
        """Operations per timed batch in the current mode."""
        return quick if self.quick else full

    def env_groups(self, *overrides: str) -> dict[str, Any]:
        """Plain env groups (what the training env factories carry) with Hydra-style overrides applied."""
        from diana_lab import config as C
        from diana_lab.training.envs import env_config

        cfg = self.cfg
        if overrides:
            cfg = self.cfg.copy()
            for o in overrides:
                key, value = o.split("=", 1)
                group = key.split(".", 1)[0]
                if "." not in key:  # a whole option: compose it like the command line would
                    node = C.compose([], config_name=f"{group}/{value}")[group]
                    with open_dict(cfg):
                        cfg[group] = node
                        if group == "sensor":  # a new sensor option keeps the run's caster settings
                            cfg.sensor.nthreads = 1
                            cfg.sensor.backend = self.backend
                else:
                    OmegaConf.update(cfg, key, yaml.safe_load(value), force_add=False)
        return env_config(cfg)

    @cached_property
    def world(self) -> Any:
        """This process's world of the composed config (shared with the envs built by ``make_env``)."""
        from diana_lab.training.envs import shared_world

        return shared_world(self.env_groups()["world"])

    def robot(self, name: str | None = None) -> Any:
        from diana_lab import config as C

        return C.to_object("robot", name if name is not None else self.cfg.robot)

    def typed(self, group: str, *overrides: str) -> Any:
        from diana_lab import config as C

        return C.to_object(group, self.env_groups(*overrides)[group])

    @cached_property
    def poses(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """256 rover poses on the world: uniform position (2 m from the edges), uniform heading, and the
        height, roll and pitch the kinematic model gives there (a rover standing on the terrain)."""
        from diana_lab.sim.kinematic import KinematicDynamics

        dyn = KinematicDynamics(self.typed("dynamics", "dynamics=kinematic"), self.world, self.robot())
        rng = np.random.default_rng(self.seed)
        x0, x1, y0, y1 = self.world.bounds
        out = []
        for _ in range(256):
            xy = rng.uniform([x0 + 2.0, y0 + 2.0], [x1 - 2.0, y1 - 2.0])
            st = dyn.reset(xy, float(rng.uniform(-math.pi, math.pi)))
            out.append((st.position.copy(), st.rpy.copy()))
        return out


# ----------------------------------------------------------------------------------------------- registry


MeasureFn = Callable[[BenchContext], list[Figure]]


@dataclass(frozen=True)
class Measurement:
    name: str
    keys: tuple[str, ...]  # the figure keys it produces
    fn: MeasureFn


MEASUREMENTS: dict[str, Measurement] = {}


def measurement(*keys: str) -> Callable[[MeasureFn], MeasureFn]:
    """Register ``fn(ctx) -> [Figure, ...]`` as the producer of ``keys`` (in the order of the table)."""

    def decorator(fn: MeasureFn) -> MeasureFn:
        MEASUREMENTS[fn.__name__] = Measurement(fn.__name__, keys, fn)
        return fn

    return decorator


def all_keys() -> list[str]:
    return [k for m in MEASUREMENTS.values() for k in m.keys]


def select(only: Iterable[str] | None) -> list[Measurement]:
    """The measurements that produce any of the figure keys (or measurement names) in ``only``."""
    if only is None:
        return list(MEASUREMENTS.values())
    wanted = {str(k) for k in only}
    unknown = wanted - set(all_keys()) - set(MEASUREMENTS)
    if unknown:
        raise ValueError(
            f"only: unknown figure(s) {sorted(unknown)}; expected some of {', '.join(sorted(all_keys()))} (or profile)"
        )
    return [m for m in MEASUREMENTS.values() if m.name in wanted or wanted & set(m.keys)]
