"""Runs the selected measurements one after another and assembles the result document.

Measurements run in one process, in the order of the registry (the table's order), so that every figure of
one run shares the machine state recorded next to them. A measurement that raises does not stop the
others: its keys get ``value: null`` and an ``error`` message, and :func:`run` reports the failure.
"""

from __future__ import annotations

import datetime as dt
import sys
import time
import traceback
from typing import Any

from omegaconf import DictConfig, OmegaConf

# importing the measurement modules registers them (in this order: the order of the table)
from diana_lab.benchmarks import batched, deploy, dynamics, envs, sensing, training  # noqa: F401
from diana_lab.benchmarks.core import MEASUREMENTS, BenchContext, Figure, flag, select
from diana_lab.benchmarks.machine import library_versions, load_average, machine_info, pin_threads
from diana_lab.benchmarks.report import SCHEMA_VERSION, figures_table, write_json
from diana_lab.errors import output_file

__all__ = ["ORDER", "PROFILE", "run"]

PROFILE = "profile"  # only=[profile]: the cProfile of env.step alone
ORDER = (
    "sensor_vs_pybullet",
    "elevation_map",
    "sensor_112",
    "physics_realtime",
    "kinematic_waypoints",
    "env_steps_kinematic",
    "env_steps_physics",
    "vec_env_scaling",
    "batched_env_steps",
    "train_fps",
    "expert_label_ms",
    "policy_latency",
    "detour_latency",
    "hazcam_latency",
    "sitemap_latency",
    "rss_per_env",
    "rss_per_rover",
)
ANCHORS = {
    "gazebo_realtime_factor": 1.0,  # DIANA-Gym simulated in Gazebo at real time
    "diana_gym_env_steps_per_s": 6.7,  # DIANA-Gym's best: at most ~6.7 env steps per second
}


def _only(cfg: DictConfig) -> list[str] | None:
    only = cfg.get("only")
    if only is None:
        return None
    if isinstance(only, str):
        return [only]
    return [str(k) for k in OmegaConf.to_container(only)]


def _measure(ctx: BenchContext, name: str) -> list[Figure]:
    m = MEASUREMENTS[name]
    t0 = time.perf_counter()
    try:
        figures = m.fn(ctx)
    except Exception as exc:  # a broken area must not hide the others' figures
        traceback.print_exc(file=sys.stderr)
        message = f"{type(exc).__name__}: {exc}".splitlines()[0]
        figures = [Figure(key, "", None, error=message) for key in m.keys]
    print(f"  {name}: {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return figures


def run(cfg: DictConfig, command: str | None = None) -> dict[str, Any]:
    """Measure, print the table, write ``cfg.output`` (when set); returns the result document.

    Every option is checked before the first measurement, the output paths included: minutes of figures must
    not be lost to a typo or to ``output`` naming a folder."""
    start, started = time.perf_counter(), dt.datetime.now(dt.UTC)
    ctx = BenchContext(cfg)
    only = _only(cfg)
    want_profile = flag(cfg, "profile") or (only is not None and PROFILE in only)
    names_only = None if only is None else [k for k in only if k != PROFILE]
    selected = [] if names_only == [] else select(names_only)
    ordered = [n for n in ORDER if n in {m.name for m in selected}]
    ordered += [m.name for m in selected if m.name not in ordered]
    output = output_file(cfg.output) if cfg.get("output") else None
    out = cfg.get("profile_output")
    profile_path = output_file(out, "profile_output") if want_profile and out else None

    machine = machine_info()
    threads = pin_threads()
    mode = "quick" if ctx.quick else "full"
    print(
        f"diana_lab bench ({mode}, {ctx.repeats} repeats): load average {machine['load_avg_before']} on "
        f"{machine['cores']} cores, {machine['cpu_busy_pct_before']}% busy",
        file=sys.stderr,
    )
    figures: dict[str, dict[str, Any]] = {}
    for name in ordered:
        for fig in _measure(ctx, name):
            figures[fig.key] = fig.to_json()

    if want_profile:
        from diana_lab.benchmarks.profiling import profile_env_step

        print(profile_env_step(ctx, profile_path))

    machine["load_avg_after"] = load_average()
    result: dict[str, Any] = {
        "schema": SCHEMA_VERSION,
        "command": command or "diana_lab.benchmarks.suite.run (in process)",
        "date": started.isoformat(timespec="seconds"),  # when the run started
        "mode": mode,
        "repeats": ctx.repeats,
        "wall_time_s": round(time.perf_counter() - start, 1),
        "machine": machine,
        "versions": library_versions(),
        "threads": threads,
        "config": {
            **{g: str(OmegaConf.select(cfg, f"{g}.name")) for g in ("world", "robot", "sensor", "algo")},
            "sensor_backend": ctx.backend,  # the ray caster every sensor figure used
        },
        "anchors": ANCHORS,
        "figures": figures,
        "errors": {k: f["error"] for k, f in figures.items() if f.get("error")},
    }
    if profile_path is not None:
        result["profile"] = str(profile_path)
    if figures:
        print(f"\n{figures_table(figures)}")
    print(
        f"\nload average before {machine['load_avg_before']}, after {machine['load_avg_after']} "
        f"({machine['cores']} cores, {machine['cpu_model']}); {result['wall_time_s']} s"
    )
    if output is not None:
        write_json(result, output)
        print(f"wrote {output}")
    return result
