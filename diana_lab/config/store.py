"""Registers every config schema in Hydra's ConfigStore under ``schema/<group>/<option>``.

Option files in ``conf/<group>/`` extend their schema (``defaults: [/schema/<group>/<kind>@_here_, _self_]``),
so Hydra rejects a misspelt key or a wrong type at composition time, and :func:`diana_lab.config.validate`
then runs each dataclass's ``__post_init__`` range checks.
"""

from __future__ import annotations

from hydra.core.config_store import ConfigStore

from diana_lab.config import sim

# group -> option kind -> schema. Later groups (sensor, env, run) add themselves with ``register``.
SCHEMAS: dict[str, dict[str, type]] = {
    "world": {
        "mars_yard": sim.MarsYardConfig,
        "flat": sim.FlatConfig,
        "hills": sim.HillsConfig,
        "craters": sim.CratersConfig,
        "dem": sim.DemConfig,
    },
    "robot": {"robot": sim.RobotConfig},
    "dynamics": {"kinematic": sim.KinematicConfig, "physics": sim.PhysicsConfig},
}


def register(group: str, kinds: dict[str, type]) -> None:
    SCHEMAS.setdefault(group, {}).update(kinds)


def store_schemas() -> None:
    cs = ConfigStore.instance()
    for group, kinds in SCHEMAS.items():
        for kind, schema in kinds.items():
            cs.store(group=f"schema/{group}", name=kind, node=schema)
