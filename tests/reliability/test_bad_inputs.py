"""Bad input to every entry point, as a user types it: one table, each row a real ``python -m ...`` process.

Every row must end with a non-zero exit status, a message on stderr that names the key or file and what was
expected (no Python traceback), and nothing half-written in the MLflow store: no run, or -- when the mistake
can only show once a run is open -- exactly one FAILED run (none of the rows needs that today; the table
says so per row). Rows that fail at composition or at the range checks (about a second each) run by
default; rows that need the training or evaluation stack imported, an env built or a model trained are
``slow``.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from .helpers import TINY_EVAL, run_cli, run_statuses, train_tiny_model

# a budget that cannot take long even if a row unexpectedly starts training
TRAIN_BUDGET = [
    "train.total_timesteps=64",
    "train.n_envs=1",
    "train.progress_bar=false",
    "train.checkpoint_every=0",
    "eval.every=0",
    "eval.episodes=1",
    "eval.video=false",
    "eval.plots=false",
    "algo.n_steps=32",
    "algo.batch_size=32",
    "algo.n_epochs=1",
]
DEM = ["world=dem", "world.size_x=20", "world.size_y=20"]
RUN_ID = "0123456789abcdef0123456789abcdef"  # well-formed, in no store
EVAL_ARGS = tuple(TINY_EVAL)
HINT = "(set HYDRA_FULL_ERROR=1 for the full traceback)"


@dataclass(frozen=True)
class Bad:
    """One row: ``module`` run with ``args`` must exit ``code`` with every ``expect`` string on stderr."""

    id: str
    module: str
    args: tuple[str, ...]
    expect: tuple[str, ...]
    code: int = 2  # 2: our one-paragraph user error; 1: Hydra's composition error
    slow: bool = False
    failed_run: bool = False  # a run may have been opened: exactly one FAILED run is then allowed


TRAIN, EVAL, EXPORT = "diana_lab", "diana_lab.evaluate", "diana_lab.export"

ROWS = [
    # ---- composition (Hydra, exit 1): misspelt options and keys, wrong types
    Bad("misspelt-group-option", TRAIN, ("world=marsyard",), ("world/marsyard", "mars_yard"), 1),
    Bad("misspelt-key", TRAIN, ("world.sizex=3",), ("world.sizex",), 1),
    Bad("wrong-type", TRAIN, ("train.total_timesteps=abc",), ("train.total_timesteps", "Integer"), 1),
    Bad("flag-not-a-bool", EVAL, ("policy=straight", "eval.video=maybe"), ("eval.video", "not a valid bool"), 1),
    Bad("unknown-algorithm", TRAIN, ("algo=ppx",), ("algo/ppx", "ppo"), 1),
    Bad("reward-weight-type", TRAIN, ("reward.terms.progress.weight=abc",), ("reward.terms.progress.weight", "number")),
    Bad("reward-term-without-fn", TRAIN, ("+reward.terms.mine.weight=1",), ("reward.terms.mine.fn", "dotted path")),
    Bad("key-of-another-option", TRAIN, ("sensor=lidar3d", "sensor.width=16"), ("sensor.width", "Lidar3d"), 1),
    Bad("evaluate-misspelt-option", EVAL, ("policy=astar", "world=marsyard"), ("world/marsyard",), 1),
    Bad("compare-unknown-option", "diana_lab.compare", ("no_such_option=1",), ("no_such_option",), 1),
    Bad("sweep-unknown-option", "diana_lab.sweep", ("sweep.no_such_key=1",), ("sweep.no_such_key",), 1),
    # ---- range checks (exit 2 in about a second, before the training stack is imported)
    Bad("negative-world-size", TRAIN, ("world=flat", "world.size_x=-1"), ("world.size_x", "positive")),
    Bad("zero-cruise-speed", TRAIN, ("robot.cruise_speed=0",), ("robot.cruise_speed", "positive")),
    Bad("negative-guard-overshoot", TRAIN, ("dynamics.guard_overshoot=-0.1",), ("dynamics.guard_overshoot",)),
    Bad("calibrate-misspelt-key", "diana_lab.calibrate", ("start=3",), ("start",), 1),
    Bad("negative-turn-speed", TRAIN, ("robot.turn_speed=-1",), ("robot.turn_speed", "positive")),
    Bad(
        "episode-min-above-max",
        TRAIN,
        ("episode.min_distance=30", "episode.max_distance=8"),
        ("episode.min_distance", "episode.max_distance", "smaller"),
    ),
    Bad(
        "sensor-min-range-above-max",
        TRAIN,
        ("sensor.min_range=5", "sensor.max_range=1"),
        ("sensor.min_range", "sensor.max_range", "smaller"),
    ),
    Bad("rock-size-reversed", TRAIN, ("world=craters", "world.rock_size=[1,0.5]"), ("world.rock_size", "smaller")),
    Bad("square-size-zero", TRAIN, ("action_space.size=0",), ("action_space.size", "positive")),
    Bad("circle-radius-zero", TRAIN, ("action_space=circle", "action_space.radius=0"), ("action_space.radius",)),
    Bad("camera-width-zero", TRAIN, ("sensor=depth_camera", "sensor.width=0"), ("sensor.width", "positive integer")),
    Bad("lidar-beams-zero", TRAIN, ("sensor=lidar3d", "sensor.beams=0"), ("sensor.beams", "positive integer")),
    Bad("fov-180", TRAIN, ("sensor=depth_camera", "sensor.hfov_deg=180"), ("sensor.hfov_deg", "(0.0, 180.0)")),
    Bad("unknown-encoding", TRAIN, ("sensor.encoding=pointcloud",), ("sensor.encoding", "elevation_map")),
    Bad("unknown-noise-preset", TRAIN, ("sensor.noise=extreme",), ("sensor.noise", "realistic")),
    Bad("unknown-device", TRAIN, ("train.device=gpu",), ("train.device", "cuda")),
    Bad("zero-envs", TRAIN, ("train.n_envs=0",), ("train.n_envs", "positive integer")),
    Bad(
        "register-model-bad-name",
        TRAIN,
        ("tracking.register_model=my/policy",),
        ("tracking.register_model", "my/policy"),
    ),
    Bad("physics-time-step", TRAIN, ("dynamics=physics", "dynamics.time_step=1"), ("dynamics.time_step",)),
    Bad("dem-without-path", TRAIN, tuple(DEM), ("world.path: missing, and required for world=dem", "elevation file")),
    Bad(
        "dem-without-size",
        TRAIN,
        ("world=dem", "world.path={files}/flat.npy", "world.size_y=20"),
        ("world.size_x: missing, and required for world=dem: the DEM's extent along x in metres",),
    ),
    Bad("evaluate-episodes-zero", EVAL, ("policy=astar", "eval.episodes=0"), ("eval.episodes", "positive")),
    Bad("evaluate-unknown-dynamics", EVAL, ("policy=astar", "eval.dynamics=gazebo"), ("eval.dynamics", "physics")),
    Bad("evaluate-negative-goal-speed", EVAL, ("policy=astar", "eval.min_goal_speed=-0.1"), ("eval.min_goal_speed",)),
    # numpy's own "expected non-negative integer" named no key, and training had opened its run first
    Bad("evaluate-negative-suite-seed", EVAL, ("policy=straight", "eval.seed=-5"), ("eval.seed", "2**32 - 1", "-5")),
    Bad("train-negative-suite-seed", TRAIN, ("eval.seed=-5",), ("eval.seed", "2**32 - 1")),
    Bad("negative-world-seed", EVAL, ("policy=straight", "world=craters", "world.seed=-3"), ("world.seed", "-3")),
    Bad("seed-of-a-fixed-world", EVAL, ("policy=straight", "world.seed=5"), ("world.seed=5", "not procedural")),
    Bad("run-dir-under-a-file", TRAIN, ("hydra.run.dir={files}/afile/run",), ("hydra.run.dir", "afile", "file")),
    # ---- need the world, env or training stack built (seconds each): slow
    Bad(
        "reward-fn-typo",
        TRAIN,
        ("reward.terms.progress.fn=diana_lab.envs.rewards.progres",),
        ("reward.terms.progress.fn", "progres"),
        slow=True,
    ),
    Bad(
        "reward-param-unknown",
        TRAIN,
        ("+reward.terms.progress.params.scal=2",),
        ("reward.terms.progress.params", "scal", "accepts"),
        slow=True,
    ),
    Bad(
        "reward-param-zero-scale",
        TRAIN,
        ("+reward.terms.progress.params.scale=0",),
        ("reward.terms.progress.params", "ZeroDivisionError", "finite"),
        slow=True,
    ),
    Bad("dem-not-a-tiff", TRAIN, (*DEM, "world.path={files}/text.tif"), ("world.path", "text.tif"), slow=True),
    Bad("dem-with-nan", TRAIN, (*DEM, "world.path={files}/nan.npy"), ("world.path", "nan.npy", "NaN"), slow=True),
    Bad(
        "dem-missing",
        TRAIN,
        (*DEM, "world.path={files}/missing.tif"),
        ("world.path", "missing.tif", "not found"),
        slow=True,
    ),
    Bad(
        "obstacle-mesh-missing",
        TRAIN,
        (*DEM, "world.path={files}/flat.npy", "world.obstacles=[{files}/missing_rock.obj]"),
        ("world.obstacles[0]", "missing_rock.obj", "not found"),
        slow=True,
    ),
    Bad(
        "tracking-uri-unwritable",
        TRAIN,
        ("tracking.uri=sqlite:////proc/nope/mlflow.db",),
        ("tracking.uri", "/proc/nope"),
        slow=True,
    ),
    Bad(
        "tracking-uri-file-in-the-way",
        TRAIN,
        ("tracking.uri=sqlite:///{files}/afile/mlflow.db",),
        ("tracking.uri", "afile", "a file is in the way"),
        slow=True,
    ),
    Bad("seed-not-an-integer", TRAIN, ("seed=abc",), ("seed", "integer"), slow=True),
    Bad("seed-negative", TRAIN, ("seed=-1",), ("seed", "2**32 - 1", "-1"), slow=True),
    Bad(
        "export-opset-not-a-number",
        EXPORT,
        ("policy={files}/random.zip", "output={tmp}/policy.onnx", "opset=abc"),  # refused before loading
        ("opset", "positive integer", "abc"),
    ),
    Bad(
        "physics-urdf-missing",
        TRAIN,
        ("dynamics=physics", "robot.urdf=package:urdf/nope.urdf"),
        ("robot.urdf", "nope.urdf"),
        slow=True,
    ),
    Bad(
        "goal-distances-beyond-the-world",
        TRAIN,
        ("episode.min_distance=100", "episode.max_distance=200"),
        ("episode.min_distance", "larger world"),
        slow=True,
    ),
    Bad("resume-unknown-run-id", TRAIN, (f"train.resume={RUN_ID}",), ("train.resume", RUN_ID), slow=True),
    Bad(
        "resume-from-random-bytes",
        TRAIN,
        ("train.resume={files}/random.zip",),
        ("train.resume", "random.zip", "Stable-Baselines3"),
        slow=True,
    ),
    Bad("evaluate-without-policy", EVAL, EVAL_ARGS, ("policy", "astar"), slow=True),
    Bad(
        "site-map-cell-wider-than-the-world",
        EVAL,
        ("policy=pretrained", "+experiment=reference_sitemap", "eval.episodes=1", "eval.shield.site_map_cell=1000"),
        ("eval.shield.site_map_cell=1000", "2 x 2 squares"),
        slow=True,
    ),
    Bad(
        "evaluate-random-bytes-model",
        EVAL,
        ("policy={files}/random.zip", *EVAL_ARGS),
        ("random.zip", "Stable-Baselines3 model archive"),
        slow=True,
    ),
    Bad(
        "evaluate-other-camera-resolution",
        EVAL,
        ("policy={model}", *EVAL_ARGS),
        ("depth_image", "(1, 12, 16)", "(1, 48, 64)", "sensor.width", "sensor.height"),
        slow=True,
    ),
    Bad(
        "evaluate-other-encoding",
        EVAL,
        ("policy={model}", *EVAL_ARGS, "sensor.width=16", "sensor.height=12", "sensor.encoding=elevation_map"),
        ("depth_image", "elevation_map", "sensor.encoding"),
        slow=True,
    ),
    Bad(
        "evaluate-unknown-run-id",
        EVAL,
        (f"policy={RUN_ID}", *EVAL_ARGS),
        (f"policy={RUN_ID}", "tracking.uri", "has no store at"),  # and creates none
        slow=True,
    ),
    Bad(
        "evaluate-output-unwritable",
        EVAL,
        ("policy=straight", *EVAL_ARGS, "output=/proc/nope/summary.json"),
        ("output=/proc/nope/summary.json",),
        slow=True,
    ),
    Bad(
        "evaluate-tracking-uri-unwritable",
        EVAL,
        ("policy=straight", *EVAL_ARGS, "tracking.uri=sqlite:////proc/nope/mlflow.db"),
        ("tracking.uri", "/proc/nope"),
        slow=True,
    ),
    Bad(
        "evaluate-tracking-server-down",  # failed with a traceback after the evaluation
        EVAL,
        ("policy=straight", *EVAL_ARGS, "tracking.uri=http://127.0.0.1:9"),
        ("tracking.uri=http://127.0.0.1:9", "does not answer"),
        slow=True,
    ),
    Bad(
        "tracking-uri-database-without-driver",
        TRAIN,
        ("tracking.uri=postgresql://u@127.0.0.1:9/db",),
        ("tracking.uri=postgresql", "psycopg"),
        slow=True,
    ),
    Bad(
        "export-random-bytes-model",
        EXPORT,
        ("policy={files}/random.zip", "output={tmp}/policy.onnx"),
        ("random.zip", "Stable-Baselines3 model archive"),
        slow=True,
    ),
    Bad(
        "export-output-under-a-file",
        EXPORT,
        ("policy={model}", "output={files}/afile/policy.onnx"),
        ("output=", "afile", "a file is in the way"),
        slow=True,
    ),
]


def _param(row: Bad) -> Any:
    """The row as a pytest param named by its id, marked slow when it is."""
    return pytest.param(row, id=row.id, marks=[pytest.mark.slow] if row.slow else [])


@pytest.fixture(scope="module")
def bad_files(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The broken inputs the rows name: a text file called .tif, a DEM with a NaN cell, a flat DEM (for the
    obstacle row), random bytes called .zip, and a regular file where a folder is expected."""
    d = tmp_path_factory.mktemp("bad_files")
    (d / "text.tif").write_text("this is not a TIFF\n")
    heights = np.zeros((41, 41))
    np.save(d / "flat.npy", heights)
    heights[3, 4] = np.nan
    np.save(d / "nan.npy", heights)
    (d / "random.zip").write_bytes(np.random.default_rng(0).bytes(4096))
    (d / "afile").write_text("a file, not a folder\n")
    return d


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A PPO model trained for 32 steps with a 16 x 12 depth camera (for the observation-space rows)."""
    return train_tiny_model(tmp_path_factory.mktemp("tiny_model"))


def _command(row: Bad, tmp: Path, files: Path, model: Path | None) -> list[str]:
    def fill(arg: str) -> str:
        return arg.format(files=files, tmp=tmp, model=model)

    args = [fill(a) for a in row.args]
    keys = {a.lstrip("+").split("=", 1)[0] for a in args}
    base: list[str] = []
    if row.module == TRAIN:
        base += [a for a in TRAIN_BUDGET if a.split("=", 1)[0] not in keys]
        if "world" not in keys:
            base.append("world=flat")  # keeps the rows that build a world cheap
    if row.module in (TRAIN, EVAL) and "tracking.uri" not in keys:
        base.append(f"tracking.uri=sqlite:///{tmp}/mlflow.db")
    if "hydra.run.dir" not in keys:
        base.append(f"hydra.run.dir={tmp}/run")
    return [*base, *args]


@pytest.mark.parametrize("row", [_param(r) for r in ROWS])
def test_bad_input_is_refused_with_one_paragraph_naming_it(
    row: Bad, tmp_path: Path, bad_files: Path, request: pytest.FixtureRequest
) -> None:
    if importlib.util.find_spec(row.module) is None:
        pytest.skip(f"{row.module} does not exist in this checkout")
    model = request.getfixturevalue("tiny_model") if any("{model}" in a for a in row.args) else None
    proc = run_cli(row.module, _command(row, tmp_path, bad_files, model), cwd=tmp_path)
    err = proc.stderr
    assert proc.returncode == row.code, f"exit {proc.returncode}\n{err}"
    assert "Traceback" not in err, err
    for text in row.expect:
        assert text in err, f"{text!r} not in:\n{err}"
    if row.code == 2:  # ours: "error: <one paragraph, maybe wrapped>" and the HYDRA_FULL_ERROR hint last
        lines = err.rstrip().splitlines()
        start = next(i for i, line in enumerate(lines) if line.startswith("error: "))
        assert lines[-1] == HINT and all(line.strip() for line in lines[start:]), err
    statuses = run_statuses(tmp_path / "mlflow.db")
    assert statuses in (None, []) or (row.failed_run and statuses == ["FAILED"]), statuses


def test_full_error_mode_shows_the_traceback(tmp_path: Path) -> None:
    """HYDRA_FULL_ERROR=1 is the developer's way to see where a refusal came from."""
    args = [*TRAIN_BUDGET, "robot.cruise_speed=0", f"tracking.uri=sqlite:///{tmp_path}/mlflow.db"]
    proc = run_cli(TRAIN, [*args, f"hydra.run.dir={tmp_path}/run"], cwd=tmp_path, full_error=True)
    assert proc.returncode != 0
    assert "Traceback" in proc.stderr and "robot.cruise_speed" in proc.stderr, proc.stderr


def test_the_table_covers_thirty_distinct_mistakes() -> None:
    """The issue asks for at least 30 rows; ids must be unique so that a failure names its row."""
    ids = [r.id for r in ROWS]
    assert len(ids) >= 30 and len(set(ids)) == len(ids)
