"""``./dev``: help and mistakes are answered before the set-up (which creates ``.venv`` and installs packages).

Each case runs a copy of the script in a temporary folder, with ``dpkg``, ``apt-get``, ``sudo`` and ``python3``
replaced on ``PATH`` by stubs that leave a mark and fail: a set-up that starts shows, and installs nothing.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
STUBS = ("dpkg", "apt-get", "sudo", "python3")
USAGE = ("./dev run [hydra overrides]", "./dev test [pytest args]", "./dev help")


@pytest.fixture
def checkout(tmp_path: Path) -> Path:
    """A folder holding a copy of ``dev`` and a ``bin/`` of set-up stubs that write ``set_up_ran``."""
    shutil.copy2(ROOT / "dev", tmp_path / "dev")
    stubs = tmp_path / "bin"
    stubs.mkdir()
    for name in STUBS:
        stub = stubs / name
        stub.write_text(f'#!/bin/sh\necho "{name} $*" >> "{tmp_path}/set_up_ran"\nexit 97\n')
        stub.chmod(0o755)
    return tmp_path


def dev(checkout: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PATH": f"{checkout / 'bin'}{os.pathsep}{os.environ['PATH']}"}
    return subprocess.run(
        ["bash", str(checkout / "dev"), *args], cwd=checkout, env=env, capture_output=True, text=True, timeout=60
    )


@pytest.mark.parametrize("args", [(), ("help",), ("-h",), ("--help",)], ids=["none", "help", "-h", "--help"])
def test_help_prints_the_usage_and_sets_nothing_up(checkout, args):
    """``./dev`` alone used to start a 200k-step training, after the whole set-up."""
    proc = dev(checkout, *args)
    assert proc.returncode == 0, proc.stderr
    for line in USAGE:
        assert line in proc.stdout
    assert not proc.stdout.startswith("#") and "set -euo" not in proc.stdout  # the comment block only
    assert not (checkout / "set_up_ran").exists() and not (checkout / ".venv").exists()


@pytest.mark.parametrize(
    ("args", "expected"),
    [(("nonsense",), "unknown command 'nonsense'"), (("py",), "py: expected a module")],
    ids=["unknown", "py-without-module"],
)
def test_a_mistake_exits_2_with_the_usage_before_any_set_up(checkout, args, expected):
    """An unknown command used to be refused only after the set-up (a .venv, pip installs)."""
    proc = dev(checkout, *args)
    assert proc.returncode == 2, proc.stderr
    assert expected in proc.stderr and "./dev run [hydra overrides]" in proc.stderr
    assert not (checkout / "set_up_ran").exists() and not (checkout / ".venv").exists()


def test_the_stubs_catch_a_set_up(checkout):
    """The check above can fail: a command that does set up runs into the stubs."""
    proc = dev(checkout, "setup")
    assert proc.returncode != 0
    assert (checkout / "set_up_ran").exists()
