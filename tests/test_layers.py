"""The package's imports point one way: core <- sim <- sensing/planning/shield <- envs <- agents/experts/tracking <-
training/evaluation/deploy/... <- entry points; and the onboard runtime imports no torch, PyBullet or Hydra.

Read from the source (every ``import`` statement, those inside functions too), so a late import that dodges a
cycle at run time still counts.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "diana_lab"

# a unit's layer; a unit may import only units of a lower layer (or itself)
LAYERS = {
    "errors": 0,
    "hydra_run": 0,
    "run_log": 0,
    "core": 0,
    "config": 1,
    "sim": 2,
    "sensing": 3,
    "shield": 3,
    "planning": 4,
    "envs": 5,
    "agents": 6,
    "experts": 6,
    "tracking": 6,
    "evaluation": 7,
    "deploy": 8,
    "training": 8,
    "comparison": 8,
    "sweeps": 9,
    "benchmarks": 9,
    "cli": 10,
    "__main__": 11,
    "evaluate": 11,
    "sweep": 11,
    "compare": 11,
    "export": 11,
    "bench": 11,
    "calibrate": 11,
    "scorecard": 12,  # runs evaluate's run() per suite
}
ENTRY_POINTS = {"cli", "__main__", "evaluate", "sweep", "compare", "export", "bench", "calibrate", "scorecard"}


def unit(module: str) -> str:
    """``diana_lab.<unit>[.…]`` -> ``<unit>``; the package itself (and its ``__init__``) -> ``diana_lab``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] != "__init__" else "diana_lab"


def imports() -> dict[str, set[str]]:
    """unit -> the units its modules import (every ``import`` and ``from ... import`` of ``diana_lab``)."""
    edges: dict[str, set[str]] = defaultdict(set)
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        src = unit(".".join(rel.parts))
        for node in ast.walk(ast.parse(path.read_text())):
            targets = []
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("diana_lab"):
                targets = [node.module] if node.module != "diana_lab" else [f"diana_lab.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names if a.name.startswith("diana_lab")]
            edges[src] |= {unit(t) for t in targets} - {src}
    return edges


def test_every_unit_has_a_layer():
    units = {unit(".".join(p.relative_to(PACKAGE.parent).with_suffix("").parts)) for p in PACKAGE.rglob("*.py")}
    assert units - {"diana_lab"} <= set(LAYERS), sorted(units - {"diana_lab"} - set(LAYERS))


def test_imports_point_down_the_layers():
    wrong = [
        f"{src} -> {dst}"
        for src, dsts in imports().items()
        for dst in dsts
        if src != "diana_lab" and dst != "diana_lab" and LAYERS[dst] >= LAYERS[src]
    ]
    assert not wrong, wrong


def test_no_library_module_imports_the_entry_points():
    wrong = [
        f"{src} -> {dst}" for src, dsts in imports().items() if src not in ENTRY_POINTS for dst in dsts & ENTRY_POINTS
    ]
    assert not wrong, wrong


def test_the_onboard_runtime_imports_no_torch_pybullet_or_hydra():
    probe = (
        "import sys; from diana_lab.deploy import Navigator; from diana_lab.shield import SlopeShield, SiteMap; "
        "import diana_lab.core.height_memory, diana_lab.core.grid_search; "
        "print(sorted(m for m in ('torch', 'pybullet', 'hydra', 'stable_baselines3', 'open3d') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", out
