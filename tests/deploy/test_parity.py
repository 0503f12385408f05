"""The ONNX runtime drives like the torch policy: same observations from raw inputs, same waypoints.

Each case rolls a tiny untrained policy out in a small cratered world, records the pose estimate, the goal,
the raw returns in the sensor's body frame and the torch policy's waypoint, then replays the recording
through :class:`diana_lab.deploy.Navigator` (built from the exported files only).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from diana_lab.deploy import Navigator
from diana_lab.deploy.export import DEFAULT_OPSET, DYNAMO_MIN_OPSET

from .conftest import export_run
from .helpers import record, run_config

TOLERANCE_M = 1e-4
# the run the shield tests export: the reference recipe's kind of policy (lidar map with memory, 96 candidates)
SHIELDED_RUN = [
    "sensor=lidar3d",
    "sensor.encoding=elevation_map",
    "sensor.elevation_map.memory=true",
    "sensor.elevation_map.memory_radius=20",
    "action_space=discrete",
]


def replay(nav: Navigator, rec) -> dict[str, float]:
    """Max errors of the runtime against the recording: goal vector, encoding, waypoint."""
    key = nav.sensor_key
    err = {"goal": 0.0, "encoding": 0.0, "waypoint": 0.0}
    for pose, goal, cloud, obs, want, start, hazard in zip(
        rec.poses, rec.goals, rec.clouds, rec.observations, rec.waypoints, rec.starts, rec.hazards
    ):
        if start:
            nav.reset()
        if hazard is not None:  # what the rover's tilt guard (or a slope) reported of the last drive
            nav.report_hazard(hazard)
        built = nav.observation(pose, goal, cloud)
        err["goal"] = max(err["goal"], float(np.max(np.abs(built["goal"] - obs["goal"]))))
        err["encoding"] = max(err["encoding"], float(np.max(np.abs(built[key] - obs[key]))))
        err["waypoint"] = max(err["waypoint"], float(np.max(np.abs(nav.next_waypoint(pose, goal, cloud) - want))))
    return err


def shielded_replay(tmp_path, small_world, overrides, shield, n: int, site_map=None):
    """Train and export a run with ``overrides`` evaluated behind ``shield`` (its ``eval.shield.*`` overrides),
    record ``n`` of the simulator's shielded decisions and replay them through the runtime (handed ``site_map``):
    the simulator's policy, the runtime, the recording and the largest differences."""
    run = export_run(tmp_path / "run", run_config(*overrides), small_world, True, *shield)
    try:
        policy = run.loaded.policy
        rec = record(run.env, policy, n, seed=2)
        nav = Navigator.from_files(run.onnx, site_map=site_map)
        return policy, nav, rec, replay(nav, rec)
    finally:
        run.env.close()


def test_depth_image_waypoints_match_torch_on_1000_observations(depth_run):
    rec = record(depth_run.env, depth_run.loaded.policy, 1000, seed=3)
    nav = Navigator.from_files(depth_run.onnx)
    err = replay(nav, rec)
    print(f"depth_image parity over 1000 observations: {err}")
    assert err["goal"] == 0.0  # the same float64 maths, clipped to the same bounds
    assert err["encoding"] <= 1e-6  # depth x / max_range vs range * cos / max_range, float32
    assert err["waypoint"] <= TOLERANCE_M
    # the recording is not degenerate: waypoints reach the square's edge and fall inside it too
    reach = np.abs(rec.waypoints - np.array(rec.poses)[:, :2])
    assert reach.max() > 3.0 and np.median(reach) < 3.0


CASES = {
    # lidar + elevation map (open3d voxel grid), squashed SAC actor, disc with a minimum waypoint distance
    "lidar_elevation_sac_circle": [
        "sensor=lidar3d",
        "sensor.encoding=elevation_map",
        "sensor.noise=realistic",
        "action_space=circle",
        "action_space.min_distance=0.5",
        "algo=sac",
        "algo.buffer_size=64",
    ],
    # lidar + elevation map with memory: the runtime keeps the same episode map (reset at every episode start)
    "lidar_elevation_memory": [
        "sensor=lidar3d",
        "sensor.encoding=elevation_map",
        "sensor.elevation_map.memory=true",
        "sensor.elevation_map.memory_radius=20",
    ],
    # the main command's: the lidar map with memory read by the strips network over discrete candidates (the
    # graph's gathers along every heading and its argmax)
    "lidar_map_strips": [
        "sensor=lidar_map",
        "sensor.elevation_map.memory_radius=20",
        "action_space=discrete",
        "algo.extractor.elevation_encoder=strips",
    ],
    # the main command's kind of map with the stopped-drive channel, where a low tilt guard halts drives
    "lidar_map_hazards_strips": [
        *SHIELDED_RUN,
        "sensor.elevation_map.hazard_radius=0.75",
        "robot.tilt_guard_deg=8",
        "algo.extractor.elevation_encoder=strips",
    ],
    # depth camera + points (voxel then stride subsample, order-dependent), TD3, world-frame squares
    "camera_points_td3_world": [
        "sensor.encoding=points",
        "sensor.points.n_points=128",
        "action_space.frame=world",
        "algo=td3",
        "algo.buffer_size=64",
    ],
    # the paper's 112 x 112 camera: its adaptive pool does not divide, the graph holds the matmul form
    "paper_camera_circle": ["sensor=depth_camera_paper", "action_space=circle"],
    # a categorical A2C policy over 16 x 3 candidate waypoints: the graph's argmax and candidate lookup
    "camera_discrete_a2c": ["action_space=discrete", "algo=a2c"],
}
SLOW_CASES = {
    "lidar_depth_image": ["sensor=lidar3d"],
    "lidar_points_fps": [
        "sensor=lidar3d",
        "sensor.encoding=points",
        "sensor.points.method=fps",
        "sensor.points.n_points=96",
    ],
}


# both exporters the export uses: TorchScript at the default opset, dynamo from 18 (export.exporter_for)
EXPORTERS = {"torchscript": DEFAULT_OPSET, "dynamo": DYNAMO_MIN_OPSET}


@pytest.mark.parametrize("exporter", EXPORTERS)
@pytest.mark.parametrize(
    "name",
    [*CASES, *(pytest.param(n, marks=pytest.mark.slow) for n in SLOW_CASES)],
)
def test_other_sensors_and_action_spaces_match_torch(name, exporter, tmp_path, small_world):
    overrides = {**CASES, **SLOW_CASES}[name]
    normalize = name != "camera_points_td3_world"
    opset = EXPORTERS[exporter]
    run = export_run(tmp_path / "run", run_config(*overrides), small_world, normalize, opset=opset)
    try:
        rec = record(run.env, run.loaded.policy, 150, seed=1)
        nav = Navigator.from_files(run.onnx)
        err = replay(nav, rec)
    finally:
        run.env.close()
    print(f"{name} parity over 150 observations, {exporter} exporter: {err}")
    if "hazards" in name:  # drives were stopped, so the stopped-drive channel was compared with marks in it
        assert sum(h is not None for h in rec.hazards) >= 3
    assert nav.spec.opset == opset and nav.spec.source["exporter"] == exporter
    assert err["goal"] == 0.0
    assert err["encoding"] <= 1e-6
    assert err["waypoint"] <= TOLERANCE_M


def test_behind_the_slope_shield_the_runtime_drives_like_the_simulators_shielded_policy(tmp_path, small_world):
    """The sidecar carries the shield; the runtime maps the cloud itself and walks the graph's logits: the same
    waypoints as the simulator's ``ShieldedPolicy``, including where it vetoed the policy's choice (by the map's
    slopes, by what rises within the footprint, by peaks, by the hazards the tilt guard reported), where it drove
    straight for the goal (its final approach) and where, stalled, it drove round what blocked it (its detour)."""
    overrides = [
        *SHIELDED_RUN,
        "robot.tilt_guard_deg=12",  # halts often on this small rough world: hazards for the shield
    ]
    # strict: many vetoes, by the map and by the hazards the tilt guard reports
    shield = [
        "eval.shield.enabled=true",
        "eval.shield.limit_deg=6",
        "eval.shield.radius=20",
        "eval.shield.hazard_radius=0.5",
        "eval.shield.min_range=1.0",  # the runtime then maps the cloud itself, leaving out the near returns
        "eval.shield.obstacle_height=0.05",  # and what rises above the wheels within the footprint
        "eval.shield.approach_radius=30",  # and drives straight for the goal when it can (the whole small world)
        "eval.shield.peak_height=0.02",  # and cells over their 2nd highest neighbour (84 vetoes, 90 without)
        "eval.shield.peak_rank=2",
        "eval.shield.peak_min_known=5",
        "eval.shield.smooth_roughness=0.05",  # and, on ground that smooth, rises over 0.03 m
        "eval.shield.smooth_obstacle_height=0.03",
        "eval.shield.detour_after=2",  # and, stalled, drives round what its map shows blocking the goal
    ]
    policy, nav, rec, err = shielded_replay(tmp_path, small_world, overrides, shield, 150)
    counts = f"vetoes {policy.shield.vetoes}, approaches {policy.shield.approaches}, detours {policy.shield.detours}"
    print(f"shielded parity over 150 observations: {err}; {counts}")
    assert nav.spec.shield is not None and nav.spec.shield["limit_deg"] == 6.0
    assert nav.spec.shield["hazard_radius"] == 0.5 and nav.spec.shield["min_range"] == 1.0
    assert nav.spec.shield["obstacle_height"] == 0.05
    peak = nav.spec.shield
    assert (peak["peak_height"], peak["peak_rank"], peak["peak_min_known"]) == (0.02, 2, 5)
    assert (peak["smooth_roughness"], peak["smooth_obstacle_height"], peak["smooth_radius"]) == (0.05, 0.03, 3.0)
    assert nav.shield.vetoed_by == policy.shield.vetoed_by and nav.shield.vetoed_by["smooth"] > 0
    assert sum(h is not None for h in rec.hazards) > 0  # the guard tripped, and the runtime was told
    assert nav.shield.vetoes == policy.shield.vetoes > 10  # the shield changed course, the same times in both
    assert nav.shield.approaches == policy.shield.approaches > 0  # and made the final approach, the same times
    assert (peak["detour_after"], peak["detour_progress"], peak["detour_margin"]) == (2, 0.5, 10.0)
    assert nav.shield.detours == policy.shield.detours > 0  # and the detour, the same times
    assert err["encoding"] <= 1e-6
    assert err["waypoint"] <= TOLERANCE_M


def test_with_hazard_cameras_and_the_relief_check_the_runtime_drives_like_the_simulator(tmp_path, small_world):
    """``eval.shield.cameras`` feed the simulator's shield; on a rover the same returns, turned into the body
    frame, go to :meth:`Navigator.map_for_shield` before each decision, and the relief check on the pooled mean
    map (and the unseen ground past ``relief_unseen_from``) vetoes the same drives."""
    from diana_lab.evaluation.shield_cameras import ShieldCameras

    overrides = SHIELDED_RUN
    shield = [
        "eval.shield.enabled=true",
        "eval.shield.radius=20",
        "eval.shield.min_range=1.0",
        "eval.shield.relief=true",
        "eval.shield.relief_slope_deg=8",  # strict on this small world: many relief vetoes
        "eval.shield.relief_unseen_from=0.8",
        "eval.shield.detour_after=2",
        "eval.shield.cameras=[{yaw_deg:0,width:64,height:48},{yaw_deg:90,width:64,height:48}]",
    ]
    run = export_run(tmp_path / "run", run_config(*overrides), small_world, True, *shield)
    fed: list[list[tuple[np.ndarray, np.ndarray]]] = []  # per decision: (body-frame points, mount) per camera
    feed = ShieldCameras.feed

    def recording_feed(self, shield_, position, rpy):
        fed.append(self.body_frames(position, rpy))  # the same casts again (noise-free): what a rover hands over
        feed(self, shield_, position, rpy)

    ShieldCameras.feed = recording_feed
    try:
        policy = run.loaded.policy
        rec = record(run.env, policy, 120, seed=2)
        nav = Navigator.from_files(run.onnx)
        err = {"waypoint": 0.0}
        for pose, goal, cloud, want, start, hazard, cams in zip(
            rec.poses, rec.goals, rec.clouds, rec.waypoints, rec.starts, rec.hazards, fed, strict=True
        ):
            if start:
                nav.reset()
            if hazard is not None:
                nav.report_hazard(hazard)
            for points, mount in cams:
                nav.map_for_shield(pose, points, mount)
            err["waypoint"] = max(err["waypoint"], float(np.max(np.abs(nav.next_waypoint(pose, goal, cloud) - want))))
    finally:
        ShieldCameras.feed = feed
        run.env.close()
    print(f"hazard-camera parity over 120 decisions: {err}; relief vetoes {policy.shield.vetoed_by['relief']}")
    assert nav.spec.shield["relief"] is True and nav.spec.shield["relief_slope_deg"] == 8.0
    assert nav.spec.shield["relief_unseen_from"] == 0.8
    assert nav.shield.vetoed_by == policy.shield.vetoed_by and policy.shield.vetoed_by["relief"] > 5
    assert err["waypoint"] <= TOLERANCE_M
    with pytest.raises(ValueError, match="sensor_xyz"):
        nav.map_for_shield(rec.poses[0], fed[0][0][0], (0.0, 1.0))


def test_with_the_route_rule_the_runtime_drives_like_the_simulator(tmp_path, small_world):
    """``eval.shield.route`` (and the search's slope cost) in the sidecar: at every decision the runtime opens the
    same drives to the policy as the simulator's shield, and turns from its choice the same times."""
    shield = [
        "eval.shield.enabled=true",
        "eval.shield.radius=20",
        "eval.shield.limit_deg=8",  # strict on this small world: walls for the search
        "eval.shield.route=true",
        "eval.shield.route_tolerance=0.5",
        "eval.shield.slope_cost_weight=10",
        "eval.shield.slope_cost_from_deg=2",
        "eval.shield.slope_cost_to_deg=8",
    ]
    policy, nav, _, err = shielded_replay(tmp_path, small_world, SHIELDED_RUN, shield, 120)
    print(f"route-rule parity over 120 decisions: {err}; routes {policy.shield.routes}")
    assert nav.spec.shield["route"] is True and nav.spec.shield["route_tolerance"] == 0.5
    assert nav.spec.shield["slope_cost_weight"] == 10.0
    assert nav.shield.routes == policy.shield.routes > 5  # the rule turned from the policy, the same times
    assert err["waypoint"] <= TOLERANCE_M


def test_with_a_site_map_the_runtime_drives_like_the_simulator(tmp_path, small_world):
    """``eval.shield.site_map_cell``: the simulator's search reads the world's site map where its map has seen
    nothing; onboard the Navigator is handed the same map (``site_map=``) and drives alike. Handed a flat map
    instead, it drives otherwise (the map is used), and handed none it refuses to start."""
    from diana_lab.shield import SiteMap

    shield = [
        "eval.shield.enabled=true",
        "eval.shield.radius=20",
        "eval.shield.limit_deg=8",  # strict on this small world: walls for the search, seen or not
        "eval.shield.route=true",
        "eval.shield.route_tolerance=0.5",
        "eval.shield.site_map_cell=0.25",
    ]
    site = SiteMap.from_terrain(small_world.terrain, 0.25)
    policy, nav, rec, err = shielded_replay(tmp_path, small_world, SHIELDED_RUN, shield, 120, site_map=site)
    print(f"site-map parity over 120 decisions: {err}; routes {policy.shield.routes}")
    assert nav.spec.shield["site_map_cell"] == 0.25
    assert policy.shield.detour.site_map is not None
    assert np.array_equal(policy.shield.detour.site_map.heights, site.heights)
    assert nav.shield.routes == policy.shield.routes > 5
    assert err["waypoint"] <= TOLERANCE_M
    flat = SiteMap(np.zeros_like(site.heights), site.origin, site.cell)
    other = Navigator(nav.spec, nav.model_path, site_map=flat)
    assert replay(other, rec)["waypoint"] > 0.5
    with pytest.raises(ValueError, match=r"site_map: .*site_map_cell"):
        Navigator(nav.spec, nav.model_path)
    with pytest.warns(RuntimeWarning, match=r"site_map: its cells are 0.5 m, .* 0.25 m"):
        Navigator(nav.spec, nav.model_path, site_map=SiteMap(site.heights[::2, ::2], site.origin, 0.5))
    # a map in another frame (say UTM) covers neither the rover nor its goal: said once per traverse
    elsewhere = Navigator(nav.spec, nav.model_path, site_map=SiteMap(site.heights, (1000.0, 1000.0), site.cell))
    with pytest.warns(RuntimeWarning, match=r"site_map: the rover and the goal off the map .* frame"):
        elsewhere.next_waypoint(rec.poses[0], rec.goals[0], rec.clouds[0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        elsewhere.next_waypoint(rec.poses[1], rec.goals[1], rec.clouds[1])  # not again until reset
        nav.reset()
        nav.next_waypoint(rec.poses[0], rec.goals[0], rec.clouds[0])  # the right map: no warning
    elsewhere.reset()
    with pytest.warns(RuntimeWarning, match="off the map"):
        elsewhere.next_waypoint(rec.poses[0], rec.goals[0], rec.clouds[0])
    with pytest.raises(ValueError, match=r"site_map: expected a diana_lab\.shield\.SiteMap"):
        Navigator(nav.spec, nav.model_path, site_map=site.heights)


def test_a_site_map_for_a_policy_without_a_shield_search_is_refused(depth_run):
    from diana_lab.shield import SiteMap

    with pytest.raises(ValueError, match=r"site_map: .*no shield search"):
        Navigator.from_files(depth_run.onnx, site_map=SiteMap(np.zeros((3, 3)), (0, 0), 1.0))


def test_a_site_map_for_a_policy_evaluated_without_one_is_used_with_a_warning(tmp_path, small_world):
    from diana_lab.shield import SiteMap

    shield = ["eval.shield.enabled=true", "eval.shield.radius=20", "eval.shield.route=true"]
    run = export_run(tmp_path / "run", run_config(*SHIELDED_RUN), small_world, True, *shield)
    run.env.close()
    site = SiteMap.from_terrain(small_world.terrain, 0.25)
    with pytest.warns(RuntimeWarning, match="evaluated without a site map"):
        nav = Navigator.from_files(run.onnx, site_map=site)
    assert nav.shield.detour.site_map is site


def test_map_for_shield_needs_a_shield_and_a_camera_position(depth_run):
    nav = Navigator.from_files(depth_run.onnx)
    with pytest.raises(ValueError, match="no slope shield"):
        nav.map_for_shield((0, 0, 0, 0, 0, 0), np.zeros((3, 3)), (0.0, 0.0, 1.0))
