"""Deployment figures: the onboard policy's per-call latency in the ONNX runtime (:mod:`diana_lab.deploy`).

The policy is the shipped reference policy (``policy=pretrained``, the one issue 10's target names) with the
sensor and encoding it was trained on, behind the slope shield of ``+experiment=reference`` as it ships;
without it, an untrained PPO of the reference recipe (``conf/experiment/reference.yaml``: the same lidar,
elevation map with the episode's memory and network;
latency does not depend on the weights). Either is exported by :func:`diana_lab.deploy.export.export_policy`
to a temporary ``policy.onnx`` and loaded by :class:`diana_lab.deploy.Navigator` on one onnxruntime thread;
the note says which it was.
Each repeat is one :func:`diana_lab.deploy.measure_latency` run (``Navigator.next_waypoint``: goal vector and
encoding of a synthetic flat-ground cloud, then inference); the figures are the medians over the repeats of
each run's p50 and p99 of the per-call times (p99 is a tail of single calls, not of batch averages).
Targets (issue 10): <= 1 ms median and <= 2 ms p99 for the reference policy.

Without ``diana_lab.deploy`` or onnxruntime both keys are null with a note saying so.
"""

from __future__ import annotations

import importlib.util
import math
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from diana_lab.benchmarks.core import BenchContext, Figure, Target, figure_from_samples, measurement, repeat

__all__ = ["detour_latency", "hazcam_latency", "policy_latency", "sitemap_latency"]

KEYS = ("policy_latency_ms_p50", "policy_latency_ms_p99")
TARGETS = {"policy_latency_ms_p50": Target("<=", 1.0), "policy_latency_ms_p99": Target("<=", 2.0)}
DETOUR_KEYS = ("shield_detour_ms_p50", "shield_detour_ms_p99")
DETOUR_GOAL_M = 20.0  # the goal this far from each pose (the suite's goals lie 8..30 m away)
DETOUR_SEEN_M = 30.0  # half-width of the square of true ground the shield's map holds around each pose
HAZCAM_KEYS = ("hazcam_decision_ms_p50", "hazcam_decision_ms_p99")
SITEMAP_KEYS = ("sitemap_decision_ms_p50", "sitemap_decision_ms_p99")
GOAL_MARGIN_M = 1.0  # goals this far inside the map's edge at least (the suite's keep the rover's radius + margin)
MISSING_NOTE = "not measured: the deployment runtime (diana_lab.deploy, onnxruntime) is not installed"


def goal_on_map(terrain: Any, xy: np.ndarray, bearing: float, distance: float = DETOUR_GOAL_M) -> np.ndarray:
    """The point ``distance`` m from ``xy`` on the bearing nearest ``bearing`` (5 deg steps either way) that lies
    ``GOAL_MARGIN_M`` inside the map. A goal off the map would time searches the suite never asks for (its goals
    all lie on the map), and the Navigator warns of such goals when it holds a site map."""
    here = np.asarray(xy, dtype=np.float64)[:2]
    for k in range(73):  # 0, +5, -5, +10, -10, ... +180 deg
        a = bearing + math.radians(5.0 * ((k + 1) // 2) * (1 if k % 2 else -1))
        goal = here + distance * np.array([math.cos(a), math.sin(a)])
        if terrain.contains(goal[0], goal[1], GOAL_MARGIN_M):
            return goal
    raise ValueError(f"no point {distance:g} m from ({here[0]:.1f}, {here[1]:.1f}) lies on the map")


def _p50_p99(
    keys: tuple[str, str],
    runs: list[dict[str, Any]],
    batch: str,
    note: str,
    extra: dict[str, Any],
    targets: dict[str, Target] | None = None,
) -> list[Figure]:
    """The two figures ``keys`` (p50, p99 in ms): the medians over the repeats of each run's ``p50`` and ``p99``;
    ``batch`` may name the statistic as ``{stat}``."""
    return [
        figure_from_samples(
            key,
            "ms",
            [r[stat] for r in runs],
            batch=batch.format(stat=stat),
            target=(targets or {}).get(key),
            note=note,
            extra=extra,
        )
        for key, stat in zip(keys, ("p50", "p99"))
    ]


def _reference_navigator(folder: Path, preset: str = "reference", site_map: Any = None) -> Any:
    """Export the shipped reference policy behind the shield of ``+experiment=<preset>`` and load it as the rover
    would, handed ``site_map`` (None when it is not shipped)."""
    from diana_lab.config import compose, to_object
    from diana_lab.deploy import Navigator
    from diana_lab.deploy.export import export_policy
    from diana_lab.evaluation.loading import PRETRAINED_DIR, load_policy

    if not (PRETRAINED_DIR / "model.zip").is_file():
        return None
    from dataclasses import asdict

    from diana_lab.shield import ShieldSettings

    cfg = compose([f"+experiment={preset}"])  # as it ships: behind the preset's slope shield
    eval_cfg = to_object("eval", cfg.eval)
    loaded = load_policy("pretrained", cfg, eval_cfg)
    train = loaded.train_cfg
    shield = asdict(ShieldSettings.from_config(eval_cfg.shield, to_object("robot", train.robot)))
    path = folder / "policy.onnx"
    export_policy(
        loaded.model,
        loaded.policy.vecnormalize,
        to_object("sensor", train.sensor),
        to_object("action_space", train.action_space),
        to_object("episode", train.episode),
        path,
        source={"label": "benchmark (shipped reference policy)"},
        shield=shield if eval_cfg.shield.enabled else None,
    )
    return Navigator.from_files(path, threads=1, site_map=site_map)


def _recipe_navigator(seed: int, folder: Path) -> Any:
    """Export an untrained PPO of the reference recipe (``+experiment=reference``: its lidar, its encoding
    with the episode map, its network) and load it as the rover would: the reference policy's latency before
    its weights exist (latency does not depend on the weights)."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from diana_lab.agents.factory import build_model
    from diana_lab.config import compose, to_object
    from diana_lab.deploy import Navigator
    from diana_lab.deploy.export import export_policy
    from diana_lab.training.envs import env_config, make_env

    cfg = compose(["+experiment=reference"])
    groups = env_config(cfg)
    venv = DummyVecEnv([lambda: make_env(groups)])
    try:
        model = build_model(to_object("algo", cfg.algo), venv, seed, "cpu")
        path = folder / "policy.onnx"
        export_policy(
            model,
            None,
            to_object("sensor", cfg.sensor),
            to_object("action_space", cfg.action_space),
            to_object("episode", cfg.episode),
            path,
            source={"label": "benchmark (untrained PPO of the reference recipe)"},
        )
    finally:
        venv.close()
    return Navigator.from_files(path, threads=1)


@measurement(*KEYS)
def policy_latency(ctx: BenchContext) -> list[Figure]:
    if importlib.util.find_spec("diana_lab.deploy") is None or importlib.util.find_spec("onnxruntime") is None:
        return [Figure(key, "ms", None, note=MISSING_NOTE) for key in KEYS]
    from diana_lab.deploy import measure_latency

    calls = ctx.size(2000, 300)
    with tempfile.TemporaryDirectory(prefix="diana_bench_") as folder:
        nav = _reference_navigator(Path(folder))
        if nav is None:
            nav = _recipe_navigator(ctx.seed, Path(folder))
            which = "an untrained PPO of the reference recipe (+experiment=reference; no policy shipped yet)"
        else:
            which = "the shipped reference policy" + (" behind its slope shield" if nav.shield is not None else "")
        runs = repeat(lambda: measure_latency(nav, n=calls, warmup=0), ctx.repeats)
    split = {
        "encode_p50_ms": float(np.median([r["encode_p50"] for r in runs])),
        "infer_p50_ms": float(np.median([r["infer_p50"] for r in runs])),
    }
    spec = nav.spec
    note = (
        f"Navigator.next_waypoint (goal + {spec.encoding.name} encoding of a {spec.sensor.type} cloud + ONNX "
        f"inference), onnxruntime 1 thread, {which}, synthetic flat-ground cloud"
    )
    return _p50_p99(KEYS, runs, f"{calls} calls (statistic {{stat}} of the calls)", note, split, TARGETS)


@measurement(*DETOUR_KEYS)
def detour_latency(ctx: BenchContext) -> list[Figure]:
    """One decision of the slope shield's detour (:mod:`diana_lab.shield.detour`: the search over its map and the checks
    of the candidates in the search's order), which ``policy_latency`` never meets: its replay stands on one
    spot, and decisions from one spot do not count towards a stall. The shield is the reference preset's, its
    map the world's true ground sampled every 0.1 m over a square of ``DETOUR_SEEN_M`` m around each of the
    bench's poses (every cell known: the search's largest map), the goal ``DETOUR_GOAL_M`` m away on a random
    bearing (the nearest that keeps it on the map), the stall forced; the figures are the medians over the
    repeats of each run's p50 and p99."""
    import time

    from diana_lab.config import compose, to_object
    from diana_lab.core.candidates import candidate_offsets, turned
    from diana_lab.shield import ShieldSettings, SlopeShield

    cfg = compose(["+experiment=reference"])
    eval_cfg = to_object("eval", cfg.eval)
    action = to_object("action_space", cfg.action_space)
    settings = ShieldSettings.from_config(eval_cfg.shield, to_object("robot", cfg.robot))
    if settings.detour_after < 1:
        settings.detour_after = 4
    shield = SlopeShield(settings)
    offsets = candidate_offsets(action.headings, tuple(action.distances))
    rng = np.random.default_rng(ctx.seed)
    terrain = ctx.world.terrain
    g = np.arange(-DETOUR_SEEN_M, DETOUR_SEEN_M, 0.1) + 0.05
    gx, gy = np.meshgrid(g, g)
    cases = []
    for position, rpy in ctx.poses[: ctx.size(24, 6)]:
        xy = position[:2]
        pts = np.stack([gx.ravel() + xy[0], gy.ravel() + xy[1]])
        z = terrain.height_at(pts)
        goal = goal_on_map(terrain, xy, rng.uniform(-np.pi, np.pi))
        cases.append((np.column_stack([pts.T, z]), xy, float(rpy[2]), goal))

    def run() -> dict[str, float]:
        times, made = [], shield.detours
        for cloud, xy, yaw, goal in cases:
            shield.reset()
            shield.observe(cloud, xy)
            world = turned(offsets, yaw)
            for k in range(8):  # eight decisions from places along the way, each stalled
                start = xy + 0.3 * k * np.array([np.cos(yaw), np.sin(yaw)])
                shield.detour.best, shield.detour.since = 0.0, shield.detour.after  # stalled: no progress counts
                t0 = time.perf_counter()
                shield.choose(np.arange(len(world)), world, start, goal)
                times.append(1000.0 * (time.perf_counter() - t0))
        return {
            "p50": float(np.percentile(times, 50)),
            "p99": float(np.percentile(times, 99)),
            "n": len(times),
            "detours": shield.detours - made,
        }

    runs = repeat(run, ctx.repeats)
    note = (
        f"SlopeShield.choose with the detour driving (stall forced), reference preset's shield, map = the world's "
        f"true ground over {2 * DETOUR_SEEN_M:g} m squares, goals {DETOUR_GOAL_M:g} m away; {runs[0]['n']} decisions "
        f"a run, {runs[0]['detours']} of them driven by the detour (the rest found no way and chose as usual)"
    )
    return _p50_p99(DETOUR_KEYS, runs, f"{runs[0]['n']} decisions", note, {"detours_per_run": runs[0]["detours"]})


@measurement(*HAZCAM_KEYS)
def hazcam_latency(ctx: BenchContext) -> list[Figure]:
    """One onboard decision of the shipped policy behind ``+experiment=reference_hazcams``' shield: its four hazard
    cameras' frames mapped (:meth:`Navigator.map_for_shield`, in the body frame as a rover hands them over) and
    :meth:`Navigator.next_waypoint` (encoding, inference, the shield's checks with the relief check). The frames
    are cast in the bench's world from its poses, each decision 0.3 m on from the last along the heading (eight
    a pose, the map growing as on a drive), the goal ``DETOUR_GOAL_M`` m ahead (on the nearest bearing that keeps
    it on the map); the lidar cloud is the synthetic flat-ground one of ``policy_latency``. The figures are the
    medians over the repeats of each run's p50 and p99."""
    return _camera_decisions(ctx, "reference_hazcams", HAZCAM_KEYS)


@measurement(*SITEMAP_KEYS)
def sitemap_latency(ctx: BenchContext) -> list[Figure]:
    """As ``hazcam_latency``, behind ``+experiment=reference_sitemap``' shield: the Navigator is handed the bench
    world's site map (``SiteMap.from_terrain`` at the preset's cell), which the route rule's search reads on every
    decision where the cameras have seen nothing."""
    return _camera_decisions(ctx, "reference_sitemap", SITEMAP_KEYS)


def _camera_decisions(ctx: BenchContext, preset: str, keys: tuple[str, str]) -> list[Figure]:
    """The decisions of ``hazcam_latency`` behind the shield of ``+experiment=<preset>`` (figures ``keys``)."""
    if importlib.util.find_spec("diana_lab.deploy") is None or importlib.util.find_spec("onnxruntime") is None:
        return [Figure(key, "ms", None, note=MISSING_NOTE) for key in keys]
    import time

    from diana_lab.config import compose, to_object
    from diana_lab.deploy.latency import synthetic_cloud
    from diana_lab.evaluation.shield_cameras import ShieldCameras
    from diana_lab.shield import SiteMap

    cfg = compose([f"+experiment={preset}"])
    eval_cfg = to_object("eval", cfg.eval)
    cameras = ShieldCameras(eval_cfg.shield.cameras, to_object("sensor", cfg.sensor), ctx.world)
    cameras.reset(np.random.default_rng(ctx.seed))
    cell = eval_cfg.shield.site_map_cell
    site = SiteMap.from_terrain(ctx.world.terrain, cell) if cell > 0 else None
    with tempfile.TemporaryDirectory(prefix="diana_bench_") as folder:
        nav = _reference_navigator(Path(folder), preset, site)
        if nav is None:
            return [Figure(key, "ms", None, note="not measured: no reference policy shipped") for key in keys]
        cloud = synthetic_cloud(nav.spec.sensor)
        cases = []
        for position, rpy in ctx.poses[: ctx.size(12, 4)]:
            yaw = float(rpy[2])
            ahead = np.array([np.cos(yaw), np.sin(yaw), 0.0])
            steps = []
            for k in range(8):
                pos = np.asarray(position, dtype=np.float64) + 0.3 * k * ahead
                frames = cameras.body_frames(pos, rpy)
                steps.append(((pos[0], pos[1], pos[2], float(rpy[0]), float(rpy[1]), yaw), frames))
            goal = goal_on_map(ctx.world.terrain, np.asarray(position), yaw)
            cases.append((steps, goal))

        def run() -> dict[str, float]:
            times, mapping, points = [], [], []
            for steps, goal in cases:
                nav.reset()
                for pose, frames in steps:
                    t0 = time.perf_counter()
                    for pts, mount in frames:
                        nav.map_for_shield(pose, pts, mount)
                    t1 = time.perf_counter()
                    nav.next_waypoint(pose, goal, cloud)
                    times.append(1000.0 * (time.perf_counter() - t0))
                    mapping.append(1000.0 * (t1 - t0))
                    points.append(sum(len(p) for p, _ in frames))
            return {
                "p50": float(np.percentile(times, 50)),
                "p99": float(np.percentile(times, 99)),
                "map_p50": float(np.percentile(mapping, 50)),
                "n": len(times),
                "points": float(np.median(points)),
            }

        runs = repeat(run, ctx.repeats)
    with_site = ", the world's site map" if site is not None else ""
    note = (
        f"Navigator.map_for_shield x {len(cameras)} hazard-camera frames (median {runs[0]['points']:.0f} returns a "
        f"decision) + Navigator.next_waypoint behind the +experiment={preset} shield (relief check and "
        f"route rule on{with_site}), onnxruntime 1 thread, "
        f"frames cast in the bench's world; {runs[0]['n']} decisions a run"
    )
    extra = {
        "returns_per_decision": runs[0]["points"],
        "map_for_shield_p50_ms": float(np.median([r["map_p50"] for r in runs])),
    }
    return _p50_p99(keys, runs, f"{runs[0]['n']} decisions", note, extra)
