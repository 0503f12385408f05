"""The onboard policy: pose estimate + goal + raw point cloud -> the next world-frame waypoint.

Needs numpy and onnxruntime only (open3d for the ``elevation_map``/``points`` encodings, numba for a sidecar
whose shield has the detour on, ``detour_after`` > 0, as the reference policy's does). The ONNX graph
holds the network, the observation normalisation, the action clipping and the action -> waypoint-offset
mapping (square or Shirley-Chiu disc, ``min_distance``); the offset comes out in the action frame, and
:meth:`Navigator.waypoint` turns it by the pose's yaw (``action_space.frame=rover``) and adds the position
here in float64, so the graph needs no pose input beyond the observation.

The waypoint is NOT clamped to a map: the simulator keeps waypoints inside its world, a rover has no such
edge (clamp it in the position controller if your site has one).
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from diana_lab.core.candidates import candidate_offsets, turned
from diana_lab.deploy.encoding import CloudEncoder, make_cloud_encoder
from diana_lab.deploy.inputs import Pose, check_cloud, check_goal, goal_vector
from diana_lab.deploy.spec import PolicySpec, sidecar_path
from diana_lab.shield import ShieldSettings, SiteMap, SlopeShield

__all__ = ["Navigator", "session_options"]

PoseLike = Pose | Any


def session_options(threads: int = 1) -> ort.SessionOptions:
    """One inference thread by default: the onboard computer runs localisation and control beside it, and
    a policy this small gains nothing from more (thread hand-offs cost more than its convolutions)."""
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    opts.log_severity_level = 3  # errors only: no per-session warnings on the rover's console
    return opts


class Navigator:
    """An exported policy with its sidecar. Build with :meth:`from_files`; call :meth:`next_waypoint`."""

    def __init__(
        self,
        spec: PolicySpec,
        model_path: str | Path,
        threads: int = 1,
        providers: list[str] | None = None,
        site_map: SiteMap | None = None,
    ) -> None:
        self.spec = spec
        self.model_path = Path(model_path)
        self.threads = int(threads)
        self.session = ort.InferenceSession(
            str(self.model_path), session_options(self.threads), providers=providers or ["CPUExecutionProvider"]
        )
        self.sensor_key = spec.encoding.name
        self._check_graph()
        self.encoder: CloudEncoder = make_cloud_encoder(spec.sensor, spec.encoding)
        self._low = np.asarray(spec.goal_low, dtype=np.float32)
        self._high = np.asarray(spec.goal_high, dtype=np.float32)
        self._rotate = spec.action_space.frame == "rover"
        self.shield: SlopeShield | None = None  # the slope shield, when the sidecar asks for it
        if spec.shield is not None:
            self.shield = SlopeShield(ShieldSettings.from_dict(spec.shield))
            act = spec.action_space
            self._candidates = candidate_offsets(int(act.headings), tuple(act.distances))  # type: ignore[arg-type]
            self._candidates32 = self._candidates.astype(np.float32)  # the graph's own table (its offsets)
        self._use_site_map(site_map)

    @classmethod
    def from_files(
        cls,
        onnx_path: str | Path,
        sidecar: str | Path | None = None,
        threads: int = 1,
        providers: list[str] | None = None,
        site_map: SiteMap | None = None,
    ) -> Navigator:
        """Load ``policy.onnx`` and its sidecar (``policy.json`` next to it unless ``sidecar`` is given); a
        ``site_map`` for a policy evaluated with one (see :meth:`_use_site_map`)."""
        onnx_path = Path(onnx_path)
        if not onnx_path.is_file():
            raise FileNotFoundError(f"onnx_path: no such file '{onnx_path}'")
        spec = PolicySpec.load(sidecar if sidecar is not None else sidecar_path(onnx_path))
        return cls(spec, onnx_path, threads, providers, site_map)

    def _use_site_map(self, site_map: SiteMap | None) -> None:
        """Hand the shield's search the site map (:mod:`diana_lab.shield.site_map`, in the pose estimate's frame).
        A policy evaluated with one (the sidecar's ``shield.site_map_cell`` > 0) needs one: without it the search
        takes unseen ground as drivable and the rover no longer drives as evaluated."""
        self._site_map: SiteMap | None = None
        self._site_warned = False  # the off-the-map warning given since the last reset
        expected = float(self.spec.shield.get("site_map_cell", 0.0)) if self.spec.shield is not None else 0.0
        if site_map is None:
            if expected > 0:
                raise ValueError(
                    f"site_map: this policy's shield was evaluated with a site map of {expected:g} m cells "
                    "(shield.site_map_cell in its sidecar); pass site_map=SiteMap(heights, origin, cell) with the "
                    "site's elevation model (docs/deploy.md)"
                )
            return
        if not isinstance(site_map, SiteMap):
            raise ValueError(f"site_map: expected a diana_lab.shield.SiteMap, got {type(site_map).__name__}")
        if self.shield is None or self.shield.detour is None:
            raise ValueError(
                "site_map: this policy's sidecar has no shield search to read it (a slope shield with detour_after "
                "> 0 or route)"
            )
        if expected == 0:
            warnings.warn(
                "site_map: this policy was evaluated without a site map (its sidecar's shield.site_map_cell is 0); "
                "its search reads this one, so it drives otherwise than evaluated",
                RuntimeWarning,
                stacklevel=3,
            )
        elif not math.isclose(site_map.cell, expected, rel_tol=1e-6):
            warnings.warn(
                f"site_map: its cells are {site_map.cell:g} m, the policy was evaluated with {expected:g} m ones "
                "(the sidecar's shield.site_map_cell); coarser cells blur walls the search should see",
                RuntimeWarning,
                stacklevel=3,
            )
        self.shield.use_site_map(site_map)
        self._site_map = site_map

    def _warn_off_site_map(self, xy: np.ndarray, goal: np.ndarray) -> None:
        """Warn, once per traverse, when the rover or its goal stands off the site map: the search takes ground
        off it as drivable (as without a map), most likely a map in another frame than the pose estimates'."""
        site = self._site_map
        assert site is not None
        gx, _ = site.gradient_at(np.array([xy[0], goal[0]]), np.array([xy[1], goal[1]]))
        off = [name for name, v in zip(("the rover", "the goal"), gx, strict=True) if np.isnan(v)]
        if off:
            self._site_warned = True
            ny, nx = site.heights.shape
            x0, y0 = site.origin
            warnings.warn(
                f"site_map: {' and '.join(off)} off the map (rover at ({xy[0]:.1f}, {xy[1]:.1f}), goal at "
                f"({goal[0]:.1f}, {goal[1]:.1f}); the map covers x {x0:g}..{x0 + nx * site.cell:g}, y "
                f"{y0:g}..{y0 + ny * site.cell:g} m): the search takes ground off it as drivable. Is the map in the "
                "pose estimates' frame?",
                RuntimeWarning,
                stacklevel=3,
            )

    def _check_graph(self) -> None:
        got = {i.name: list(i.shape) for i in self.session.get_inputs()}
        for name, shape in self.spec.inputs.items():
            if name not in got or [d if isinstance(d, int) else -1 for d in got[name]] != list(shape):
                raise ValueError(
                    f"model '{self.model_path}': input '{name}' {shape} from the sidecar does not "
                    f"match the graph's inputs {got}; were they exported together?"
                )
        outputs = [o.name for o in self.session.get_outputs()]
        if "offset" not in outputs:
            raise ValueError(f"model '{self.model_path}': no 'offset' output (outputs: {outputs})")
        if self.spec.shield is not None and "logits" not in outputs:
            raise ValueError(
                f"model '{self.model_path}': the sidecar asks for the slope shield, which needs the graph's 'logits' "
                f"output (outputs: {outputs}); re-export the policy with this diana_lab version"
            )

    def reset(self) -> None:
        """Start a new traverse (a new goal): an ``elevation_map`` with memory (and the slope shield) forget
        the last map. The simulator resets them with every episode; a rover must call this whenever it takes a
        new goal."""
        self.encoder.reset()
        if self.shield is not None:
            self.shield.reset()
        self._site_warned = False

    def report_hazard(self, xy: Any) -> None:
        """Tell the navigator where the wheels met ground they could not drive (world ``(x, y)``): where the
        rover's tilt fault protection stopped a drive, or a slope held it; report it before the next decision.
        A policy trained with the map's stopped-drive channel (``sensor.elevation_map.hazard_radius``) sees it
        from then on, and the slope shield keeps later waypoints its ``shield.hazard_radius`` away from it,
        both until :meth:`reset` (the simulator does the same with the dynamics' ``hazard_xy``). With neither,
        nothing is kept."""
        try:
            point = np.asarray(xy, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            point = np.zeros(0)
        if point.shape != (2,) or not np.all(np.isfinite(point)):
            raise ValueError(f"report_hazard: expected a finite world (x, y), got {xy!r}")
        self.encoder.mark_hazard(point)
        if self.shield is not None:
            self.shield.mark_hazard(point)

    def map_for_shield(self, pose: PoseLike, cloud: Any, sensor_xyz: Any, drop_invalid: bool = False) -> None:
        """Map another depth sensor's returns into the slope shield's map only (a hazard camera: the policy
        does not see them), before the decision's :meth:`next_waypoint`, as the simulator does with
        ``eval.shield.cameras``.

        Args:
            pose: the pose estimate the cloud was taken at (as :meth:`next_waypoint`'s).
            cloud: ``(N, 3)`` points in the rover's body frame (x forward, y left, z up, from the base origin):
                transform the camera's own frame first.
            sensor_xyz: the camera's position in the rover's body frame (the shield's ``min_range`` is from it).
            drop_invalid: ignore NaN/inf points instead of raising.
        """
        if self.shield is None:
            raise ValueError("map_for_shield: this policy's sidecar has no slope shield (export it with one)")
        mount = np.asarray(sensor_xyz, dtype=np.float64).reshape(-1)
        if mount.shape != (3,) or not np.all(np.isfinite(mount)):
            raise ValueError(f"map_for_shield: expected sensor_xyz a finite (x, y, z), got {sensor_xyz!r}")
        p = Pose.of(pose)
        pts = check_cloud(cloud, drop_invalid)
        self.shield.observe_rover(pts, (p.x, p.y, p.z), (p.roll, p.pitch, p.yaw), mount)

    # ------------------------------------------------------------------ steps (public for tests and tools)
    def observation(self, pose: PoseLike, goal: Any, cloud: Any, drop_invalid: bool = False) -> dict[str, np.ndarray]:
        """The policy's observation (unbatched), built as the env builds it."""
        return self._observation(Pose.of(pose), check_goal(goal), check_cloud(cloud, drop_invalid))

    def offset(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """The waypoint offset in the action frame (float64, (2,)) for one unbatched observation."""
        feeds = {k: np.ascontiguousarray(obs[k], dtype=np.float32)[None] for k in self.spec.inputs}
        (out,) = self.session.run(["offset"], feeds)
        return out[0].astype(np.float64)

    def waypoint(self, pose: PoseLike, offset: np.ndarray) -> np.ndarray:
        """World waypoint = position + offset (turned by the yaw when the action frame is the rover's)."""
        return self._waypoint(Pose.of(pose), offset)

    def decide(self, pose: PoseLike, obs: dict[str, np.ndarray], points: Any, goal: Any = None) -> np.ndarray:
        """The waypoint offset (action frame, float64) for an observation: the graph's, or behind the slope
        shield the candidate it lets through, after mapping ``points`` (the sensor-frame cloud) into its map.
        ``goal`` (world ``(x, y)``) lets the shield's final approach (``approach_radius``) drive for it."""
        return self._decide(Pose.of(pose), obs, check_cloud(points), None if goal is None else check_goal(goal))

    # ------------------------------------------------------------------ the call a rover makes
    def next_waypoint(self, pose: PoseLike, goal: Any, cloud: Any, drop_invalid: bool = False) -> np.ndarray:
        """The next waypoint ``(x, y)`` in the world frame.

        Args:
            pose: the pose estimate, a :class:`Pose` or ``(x, y, z, roll, pitch, yaw)`` (world frame, rad).
            goal: ``(x, y)`` in the world frame.
            cloud: ``(N, 3)`` raw points in the sensor's body frame (x forward, y left, z up; convert a ROS
                optical-frame cloud with :func:`diana_lab.deploy.optical_to_body`).
            drop_invalid: ignore NaN/inf points instead of raising.
        """
        p = Pose.of(pose)  # every input checked once; the steps below trust them
        pts = check_cloud(cloud, drop_invalid)
        g = check_goal(goal)
        if self._site_map is not None and not self._site_warned:
            self._warn_off_site_map(p.xy, g)
        return self._waypoint(p, self._decide(p, self._observation(p, g, pts), pts, g))

    def _observation(self, p: Pose, goal: np.ndarray, pts: np.ndarray) -> dict[str, np.ndarray]:
        if not len(self.encoder.visible_rover_points(pts)):  # kept: the encoding and the shield ask again
            sensor = self.spec.sensor
            raise ValueError(
                f"cloud: none of its {len(pts)} points lies within the trained {sensor.type}'s field of view and "
                f"range ({sensor.min_range:g}-{sensor.max_range:g} m); expected metres in the sensor's body frame "
                "(x forward, y left, z up: convert an optical-frame cloud with optical_to_body). A view with no "
                "returns is treated as a sensor failure, not as free space"
            )
        return {
            "goal": goal_vector(p, goal, self.spec.distance_scale, self._low, self._high),
            self.sensor_key: self.encoder(pts, p),
        }

    def _waypoint(self, p: Pose, offset: np.ndarray) -> np.ndarray:
        local = np.asarray(offset, dtype=np.float64)
        if self._rotate:
            c, s = math.cos(p.yaw), math.sin(p.yaw)
            local = np.array([c * local[0] - s * local[1], s * local[0] + c * local[1]])
        return p.xy + local

    def _decide(self, p: Pose, obs: dict[str, np.ndarray], pts: np.ndarray, goal: np.ndarray | None) -> np.ndarray:
        if self.shield is None:
            return self.offset(obs)
        fused = getattr(self.encoder, "fused_points", None)  # the encoding's own world points, if the same
        mount = self.encoder.sensor.mount
        if fused is not None:
            if self.shield.cfg.min_range > 0:  # the same returns, in the same order: the same mask
                fused = self.shield.far_points(fused, self.encoder.visible_rover_points(pts), mount)
            self.shield.observe(fused, p.xy)
        else:
            rpy = (p.roll, p.pitch, p.yaw)
            self.shield.observe_rover(self.encoder.visible_rover_points(pts), (p.x, p.y, p.z), rpy, mount)
        ranked = self.ranking(obs)[: self.shield.cfg.top_k]
        local = self._candidates[ranked]
        j = self.shield.choose(np.arange(len(ranked)), turned(local, p.yaw) if self._rotate else local, p.xy, goal)
        return self._candidates32[ranked[j]].astype(np.float64)

    def ranking(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """A discrete policy's candidates, its choice (the graph's ``action``) first, then by decreasing logit."""
        feeds = {k: np.ascontiguousarray(obs[k], dtype=np.float32)[None] for k in self.spec.inputs}
        action, logits = self.session.run(["action", "logits"], feeds)
        first = int(action[0])
        order = np.argsort(-logits[0], kind="stable")
        if order[0] == first:  # the graph's argmax is the first largest logit: the usual case
            return order
        return np.concatenate([[first], order[order != first]]).astype(np.int64)
