"""The package as a user installs it: a built wheel, in a fresh virtual environment, run from another folder.

The wheel must carry what the entry points read at run time (the Hydra config tree, the sweep files, the assets),
so that nothing depends on a checkout. The fresh venv gets only the wheel; its dependencies come from this test's
own environment through a path entry (no download), which exposes none of the checkout's files.
"""

from __future__ import annotations

import os
import site
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """A venv holding the built wheel of this checkout; its python."""
    tmp = tmp_path_factory.mktemp("wheel")
    dist = tmp / "dist"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(dist), str(ROOT)],
        check=True,
        cwd=tmp,
    )
    (wheel,) = dist.glob("diana_lab-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for needed in ("diana_lab/conf/config.yaml", "diana_lab/conf/sensor/lidar_map.yaml",
                   "diana_lab/conf/policy/straight.yaml", "diana_lab/conf/shield/reference.yaml",
                   "diana_lab/sweeps/specs/reward_shaping.yaml", "diana_lab/assets/marsyard2022/LICENSE"):  # fmt: skip
        assert any(n == needed or n.startswith(needed) for n in names), needed
    env_dir = tmp / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    target = next((env_dir / "lib").glob("python3*/site-packages"))
    # the wheel's files, unpacked as pip would (no pip in the fresh venv: nothing downloaded)
    zipfile.ZipFile(wheel).extractall(target)
    # the dependencies: this environment's site-packages as a plain path entry (its .pth files, the checkout's
    # editable install among them, are not processed from there)
    (target / "deps.pth").write_text("\n".join(p for p in site.getsitepackages() if "site-packages" in p) + "\n")
    return python


def run(python: Path, cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "HYDRA_FULL_ERROR")}
    return subprocess.run([str(python), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_the_installed_wheel_runs_from_another_folder(installed, tmp_path):
    where = run(installed, tmp_path, "-c", "import diana_lab, pathlib; print(pathlib.Path(diana_lab.__file__).parent)")
    assert where.returncode == 0, where.stderr
    assert not Path(where.stdout.strip()).is_relative_to(ROOT)  # the wheel's copy, not the checkout's
    job = run(installed, tmp_path, "-m", "diana_lab", "--cfg", "job")
    assert job.returncode == 0, job.stderr
    assert "lidar_map" in job.stdout and "world:" in job.stdout
    evaluation = run(installed, tmp_path, "-m", "diana_lab.evaluate", "policy=straight", "eval.episodes=2",
                     "eval.video=false", "eval.plots=false", "tracking.enabled=false")  # fmt: skip
    assert evaluation.returncode == 0, evaluation.stderr
    env = run(installed, tmp_path, "-c", "import gymnasium as gym, diana_lab; e = gym.make('diana_lab/RoverNav-v0'); "
              "o, _ = e.reset(seed=0); print(sorted(o))")  # fmt: skip
    assert env.returncode == 0, env.stderr
    assert "elevation_map" in env.stdout and "goal" in env.stdout
    sweeps = run(installed, tmp_path, "-c", "from diana_lab.sweeps.spec import available; print(available())")
    assert "reward_shaping" in sweeps.stdout, sweeps.stderr
