"""The JSON sidecar next to an exported ``policy.onnx``: everything the runtime must know besides the weights.

The ONNX graph only maps ``(goal, encoding)`` to a waypoint offset; building those two inputs from a raw
pose, goal and point cloud needs the sensor model, the encoding parameters, ``distance_scale`` and the
goal bounds the policy was trained with, and turning the offset into a world waypoint needs the action
frame. They are written by :mod:`diana_lab.deploy.export` and read here, with plain ``json`` and
dataclasses, so that the runtime never needs the Hydra config tree (or torch) on the rover.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from diana_lab.envs import GOAL_KEYS  # free of imports: the runtime stays light of the simulator

__all__ = ["FORMAT", "ActionSpec", "EncodingSpec", "PolicySpec", "SensorSpec", "sidecar_path"]

FORMAT = "diana_lab.deploy/1"  # bump when a field changes meaning; the runtime refuses other formats
SENSOR_TYPES = ("depth_camera", "lidar3d")
ENCODINGS = ("depth_image", "elevation_map", "points")
ACTION_SHAPES = ("square", "circle", "discrete")
SENSOR_FRAME = "body frame of the sensor: x forward (optical axis), y left, z up"


def sidecar_path(onnx_path: str | Path) -> Path:
    """``policy.onnx`` -> ``policy.json`` (the sidecar always sits next to the graph)."""
    return Path(onnx_path).with_suffix(".json")


def _need(node: dict[str, Any], key: str, where: str) -> Any:
    if key not in node:
        raise ValueError(f"{where}: missing key '{key}'")
    return node[key]


@dataclass(frozen=True)
class SensorSpec:
    """The ray pattern and mount of the simulated sensor the policy was trained with.

    ``mount_xyz`` is the sensor origin in the rover frame (x forward, y left, z up) and the sensor is pitched
    down by ``mount_pitch_deg``: a point ``p_s`` in the sensor frame is ``R_y(pitch) @ p_s + mount_xyz`` in
    the rover frame. Camera fields: ``width``, ``height``, ``hfov_deg``, ``vfov_deg``; lidar fields:
    ``beams``, ``vfov_min_deg``, ``vfov_max_deg``, ``columns`` (azimuth steps over 360 deg).
    """

    type: str
    mount_xyz: tuple[float, float, float]
    mount_pitch_deg: float
    min_range: float
    max_range: float
    width: int | None = None
    height: int | None = None
    hfov_deg: float | None = None
    vfov_deg: float | None = None
    beams: int | None = None
    vfov_min_deg: float | None = None
    vfov_max_deg: float | None = None
    columns: int | None = None
    frame: str = SENSOR_FRAME

    def __post_init__(self) -> None:
        if self.type not in SENSOR_TYPES:
            raise ValueError(f"sensor.type: expected one of {SENSOR_TYPES}, got {self.type!r}")
        needed = (
            ("width", "height", "hfov_deg", "vfov_deg")
            if self.type == "depth_camera"
            else ("beams", "vfov_min_deg", "vfov_max_deg", "columns")
        )
        missing = [k for k in needed if getattr(self, k) is None]
        if missing:
            raise ValueError(f"sensor: a {self.type} needs {', '.join(missing)}")
        if len(self.mount_xyz) != 3 or not 0 <= self.min_range < self.max_range:
            raise ValueError("sensor: expected mount_xyz of 3 numbers and 0 <= min_range < max_range")

    @property
    def image_shape(self) -> tuple[int, int]:
        """``(rows, cols)`` of the sensor's range image."""
        if self.type == "depth_camera":
            return int(self.height), int(self.width)  # type: ignore[arg-type]
        return int(self.beams), int(self.columns)  # type: ignore[arg-type]

    @property
    def mount_pitch(self) -> float:
        return math.radians(self.mount_pitch_deg)


@dataclass(frozen=True)
class EncodingSpec:
    """The observation encoding: its name, the tensor shape, and its parameters.

    ``params`` per encoding: ``depth_image``: ``no_return``; ``elevation_map``: ``cell_size``,
    ``extent_forward``, ``extent_back``, ``extent_side``, ``height_clip``, ``voxel_size``, ``outlier_removal``,
    ``nb_neighbors``, ``std_ratio``, ``unknown_height``, ``memory``, ``memory_radius``, ``hazard_radius`` (absent
    in older sidecars: 0, no stopped-drive channel); ``points``: ``n_points``, ``method``, ``voxel_size``,
    ``scale`` (xyz are divided by it).
    """

    name: str
    shape: tuple[int, ...]
    params: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.name not in ENCODINGS:
            raise ValueError(f"encoding.name: expected one of {ENCODINGS}, got {self.name!r}")

    def param(self, key: str) -> Any:
        return _need(self.params, key, f"encoding.params ({self.name})")


@dataclass(frozen=True)
class ActionSpec:
    """The action-to-waypoint mapping baked into the graph (``frame`` is applied by the runtime).

    ``discrete``: the graph picks one of ``headings x len(distances)`` candidate offsets (argmax of the
    policy's logits); candidate ``k`` lies at bearing ``2 pi (k // len(distances)) / headings`` (from the
    frame's x axis, counter-clockwise) and distance ``distances[k % len(distances)]`` (m). The graph's
    ``offset`` output is the same waypoint offset in the action frame as for the continuous shapes.
    """

    shape: str  # square | circle | discrete
    size: float
    radius: float
    frame: str  # rover: the graph's offset is turned by the yaw; world: used as is
    min_distance: float = 0.0
    headings: int | None = None  # discrete only: evenly spaced bearings, the first along the frame's x axis
    distances: tuple[float, ...] | None = None  # discrete only: the candidates' distances (m), increasing

    def __post_init__(self) -> None:
        if self.shape not in ACTION_SHAPES or self.frame not in ("rover", "world"):
            raise ValueError(
                f"action_space: expected shape square|circle|discrete and frame rover|world, got {self.shape!r}, "
                f"{self.frame!r}"
            )
        if self.shape == "discrete" and not (self.headings and self.distances):
            raise ValueError("action_space: a discrete action space needs headings and distances")

    @property
    def extent(self) -> float:
        """Half side of the square, radius of the disc, or the farthest candidate (m)."""
        if self.shape == "discrete":
            return float(max(self.distances or (0.0,)))
        return self.size / 2.0 if self.shape == "square" else self.radius


@dataclass(frozen=True)
class PolicySpec:
    """The whole sidecar. ``inputs``/``outputs`` give the ONNX tensor names and shapes (-1: batch)."""

    sensor: SensorSpec
    encoding: EncodingSpec
    action_space: ActionSpec
    distance_scale: float
    goal_low: tuple[float, ...]
    goal_high: tuple[float, ...]
    inputs: dict[str, list[int]]
    outputs: dict[str, list[int]]
    goal_keys: tuple[str, ...] = GOAL_KEYS
    normalization: dict[str, Any] = field(default_factory=dict)
    source: dict[str, Any] = field(default_factory=dict)
    diana_lab_version: str = ""
    opset: int = 17
    format: str = FORMAT
    # the slope shield the runtime drives behind (diana_lab.shield.slope_shield.ShieldSettings as a dict); None: off
    shield: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        if len(self.goal_low) != len(GOAL_KEYS) or len(self.goal_high) != len(GOAL_KEYS):
            raise ValueError(f"goal_low/goal_high: expected {len(GOAL_KEYS)} numbers each")
        if not self.distance_scale > 0:
            raise ValueError(f"distance_scale: expected > 0, got {self.distance_scale}")
        if set(self.inputs) != {"goal", self.encoding.name}:
            raise ValueError(f"inputs: expected 'goal' and '{self.encoding.name}', got {sorted(self.inputs)}")
        if self.shield is not None:
            if self.action_space.shape != "discrete" or "logits" not in self.outputs:
                raise ValueError(
                    "shield: the slope shield ranks a discrete policy's candidates by the graph's 'logits' output; "
                    f"this sidecar has action_space.shape={self.action_space.shape} and outputs {sorted(self.outputs)}"
                )
            from diana_lab.shield import ShieldSettings

            ShieldSettings.from_dict(self.shield)  # a ConfigError (a ValueError) naming shield.<key>

    def to_json(self) -> str:
        node = asdict(self)
        node["sensor"] = {k: v for k, v in node["sensor"].items() if v is not None}  # the other type's fields
        node["action_space"] = {k: v for k, v in node["action_space"].items() if v is not None}  # discrete's
        return json.dumps(node, indent=1) + "\n"

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.write_text(self.to_json())
        return path

    @classmethod
    def from_dict(cls, node: dict[str, Any], where: str = "sidecar") -> PolicySpec:
        fmt = node.get("format")
        if fmt != FORMAT:
            raise ValueError(f"{where}: format {fmt!r} is not {FORMAT!r} (exported by another diana_lab version?)")
        try:
            sensor = dict(_need(node, "sensor", where))
            sensor["mount_xyz"] = tuple(float(v) for v in _need(sensor, "mount_xyz", f"{where}.sensor"))
            enc = dict(_need(node, "encoding", where))
            enc["shape"] = tuple(int(v) for v in _need(enc, "shape", f"{where}.encoding"))
            action = dict(_need(node, "action_space", where))
            if action.get("distances") is not None:
                action["distances"] = tuple(float(v) for v in action["distances"])
            rest = {k: v for k, v in node.items() if k not in ("sensor", "encoding", "action_space")}
            for key in ("goal_low", "goal_high", "goal_keys"):
                if key in rest:
                    rest[key] = tuple(rest[key])
            return cls(
                sensor=SensorSpec(**sensor),
                encoding=EncodingSpec(**enc),
                action_space=ActionSpec(**action),
                **rest,
            )
        except TypeError as exc:  # an unknown or missing dataclass field
            raise ValueError(f"{where}: {exc}") from exc

    @classmethod
    def load(cls, path: str | Path) -> PolicySpec:
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"sidecar: no such file '{path}' (export writes it next to the .onnx)")
        try:
            node = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"sidecar '{path}': not valid JSON ({exc})") from exc
        return cls.from_dict(node, f"sidecar '{path}'")
