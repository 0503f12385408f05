"""The torch-free runtime: its imports, its input checks, its geometry and encodings, its latency probe."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from diana_lab.deploy import Navigator, PolicySpec, Pose, measure_latency, optical_to_body, synthetic_cloud
from diana_lab.deploy.geometry import SensorModel
from diana_lab.deploy.spec import SensorSpec, sidecar_path
from diana_lab.sensing.camera import pinhole_pattern
from diana_lab.sensing.lidar import lidar_pattern


@pytest.fixture(scope="module")
def nav(depth_run):
    return Navigator.from_files(depth_run.onnx)


def test_importing_and_running_the_runtime_needs_no_torch_pybullet_open3d_or_hydra(depth_run):
    code = textwrap.dedent(f"""
        import sys
        import numpy as np
        from diana_lab.deploy import Navigator, synthetic_cloud
        nav = Navigator.from_files({str(depth_run.onnx)!r})
        wp = nav.next_waypoint((1.0, 2.0, 0.1, 0.0, 0.05, 0.3), (8.0, -3.0), synthetic_cloud(nav.spec.sensor))
        assert wp.shape == (2,) and np.all(np.isfinite(wp))
        print(sorted(m for m in ("torch", "pybullet", "open3d", "hydra", "omegaconf", "stable_baselines3")
                     if m in sys.modules))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_geometry_matches_the_training_patterns(depth_run):
    # (the rotations themselves are shared with the simulator: diana_lab.core.rotations)
    # every ray of the trained sensors lands in its own pixel
    spec = PolicySpec.load(sidecar_path(depth_run.onnx)).sensor
    for sensor, pattern in [
        (spec, pinhole_pattern(spec.width, spec.height, spec.hfov_deg, spec.vfov_deg)),
        (
            SensorSpec(
                type="lidar3d",
                mount_xyz=(0, 0, 0.3),
                mount_pitch_deg=0,
                min_range=0.3,
                max_range=20,
                beams=16,
                vfov_min_deg=-15,
                vfov_max_deg=15,
                columns=180,
            ),
            lidar_pattern(16, -15, 15, 180),
        ),
    ]:
        rays = pattern.reshape(-1, 3) * 5.0
        idx, pixel = SensorModel(sensor).locate(rays)
        np.testing.assert_array_equal(idx, np.arange(len(rays)))
        np.testing.assert_array_equal(pixel, np.arange(len(rays)))


@pytest.mark.parametrize(
    ("beams", "low", "high"), [(16, -15.0, 15.0), (1, 0.0, 0.0), (1, -5.0, 5.0), (32, -89.5, 89.5)]
)
def test_lidar_visibility_without_pixels_keeps_the_points_a_beam_would_return(beams, low, high):
    """``locate(pixels=False)`` (what the elevation map asks) tests the beams' elevation span with slopes, no
    arctan: the same points as rounding each elevation to its beam (the pixel row of ``locate``)."""
    spec = SensorSpec(
        type="lidar3d",
        mount_xyz=(0, 0, 0.3),
        mount_pitch_deg=0,
        min_range=0.3,
        max_range=20,
        beams=beams,
        vfov_min_deg=low,
        vfov_max_deg=high,
        columns=90,
    )
    model = SensorModel(spec)
    rng = np.random.default_rng(beams)
    points = rng.normal(size=(20_000, 3)) * rng.uniform(0.1, 25.0, (20_000, 1))
    points[:100, :2] = 0.0  # straight up or down
    fast, none = model.locate(points, pixels=False)
    by_beam, _ = model.locate(points)
    assert none is None
    np.testing.assert_array_equal(fast, by_beam)
    assert 0 < len(fast) < len(points)


def test_optical_frame_conversion():
    # optical frame: z forward, x right, y down
    np.testing.assert_array_equal(
        optical_to_body(np.array([[0, 0, 2.0], [1.0, 0, 0], [0, 1.0, 0]])), [[2, 0, 0], [0, -1, 0], [0, 0, -1]]
    )


def test_depth_image_keeps_the_nearest_return_and_drops_what_the_sensor_cannot_see(nav):
    spec = nav.spec.sensor
    centre = np.array([[4.0, 0.0, 0.0]])
    img = nav.encoder(np.vstack([centre, centre * 0.5, centre * 1.5]), Pose.of(np.zeros(6)))[0]
    assert img.min() == pytest.approx(2.0 / spec.max_range)  # the nearest of three returns in one pixel
    assert np.sum(img < 1.0) == 1
    # too far, too near, behind, outside the field of view: all "no return"
    unseen = np.array([[spec.max_range + 1.0, 0, 0], [0.05, 0, 0], [-3.0, 0, 0], [1.0, 5.0, 0]])
    assert np.all(nav.encoder(unseen, Pose.of(np.zeros(6))) == 1.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"pose": (0.0, 0.0, 0.0, math.nan, 0.0, 0.0)}, "pose: expected finite"),
        ({"pose": (0.0, 0.0, 0.0)}, r"pose: expected shape \(6,\)"),
        ({"pose": "north"}, "pose: expected 6 numbers"),
        ({"goal": (1.0, 2.0, 3.0)}, r"goal: expected shape \(2,\)"),
        ({"goal": (math.inf, 2.0)}, "goal: expected finite"),
        ({"cloud": np.zeros((0, 3))}, "cloud: no points"),
        ({"cloud": np.ones((3, 40))}, r"cloud: expected shape \(N, 3\)"),
        ({"cloud": np.array([[1.0, 0.0, 0.0], [np.nan, 0.0, 0.0]])}, "cloud: 1 of 2 points are NaN.*drop_invalid"),
        ({"pose": Pose("a", 0.0, 0.0, 0.0, 0.0, 0.0)}, "pose: expected 6 numbers"),
        ({"pose": (0.0, 0.0, 0.0, 10.0, 0.0, 0.0)}, r"pose: roll and pitch are radians"),  # degrees
        ({"drop_invalid": "no"}, "drop_invalid: expected True or False"),
        # nothing the trained sensor could see (millimetres, an optical-frame cloud, one far point): it used to
        # encode as "no returns" and drive, the shield taking the unseen ground as free
        ({"cloud": "mm"}, "cloud: none of its .* points lies within the trained depth_camera's field of view"),
        ({"cloud": "optical"}, "cloud: none of its .* points lies within"),
        ({"cloud": np.array([[1e5, 0.0, 0.0]])}, "cloud: none of its 1 points lies within"),
    ],
)
def test_bad_inputs_raise_value_errors_naming_the_argument(nav, kwargs, match):
    cloud = synthetic_cloud(nav.spec.sensor)
    args = {"pose": (0.0, 0.0, 0.0, 0.0, 0.0, 0.0), "goal": (5.0, 0.0), "cloud": cloud}
    args.update(kwargs)
    if isinstance(args["cloud"], str):
        # millimetres; or body-frame points read as optical ones (z forward: every point behind the camera)
        args["cloud"] = cloud * 1000.0 if args["cloud"] == "mm" else cloud[:, [1, 2, 0]] * np.array([1.0, 1.0, -1.0])
    with pytest.raises(ValueError, match=match):
        nav.next_waypoint(**args)


def test_invalid_points_can_be_dropped_and_poses_given_either_way(nav):
    cloud = synthetic_cloud(nav.spec.sensor)
    pose = Pose(1.0, -2.0, 0.3, 0.05, -0.02, 2.0)
    want = nav.next_waypoint(pose, (6.0, 4.0), cloud)
    organised = np.vstack([cloud, np.full((10, 3), np.nan)])
    np.testing.assert_array_equal(nav.next_waypoint(pose, (6.0, 4.0), organised, drop_invalid=True), want)
    np.testing.assert_array_equal(nav.next_waypoint((1.0, -2.0, 0.3, 0.05, -0.02, 2.0), [6.0, 4.0], cloud), want)
    with pytest.raises(ValueError, match="cloud: no points"):
        nav.next_waypoint(pose, (6.0, 4.0), np.full((4, 3), np.nan), drop_invalid=True)


@pytest.mark.parametrize("xy", [(1.0,), (1.0, np.nan), "here", (1.0, 2.0, 3.0)])
def test_a_hazard_report_must_be_a_finite_point(nav, xy):
    with pytest.raises(ValueError, match="report_hazard: expected a finite world"):
        nav.report_hazard(xy)


def test_without_the_shield_a_hazard_report_changes_nothing(nav):
    cloud = synthetic_cloud(nav.spec.sensor)
    pose = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    want = nav.next_waypoint(pose, (5.0, 0.0), cloud)
    assert nav.shield is None
    nav.report_hazard((*want,))  # right where the policy drives
    np.testing.assert_array_equal(nav.next_waypoint(pose, (5.0, 0.0), cloud), want)


def test_rover_frame_offsets_turn_with_the_yaw(nav):
    offset = np.array([1.0, 0.5])
    np.testing.assert_allclose(nav.waypoint((2.0, 3.0, 0, 0, 0, math.pi / 2), offset), [1.5, 4.0])


def test_a_sidecar_from_another_format_or_graph_is_refused(depth_run, tmp_path):
    node = json.loads(sidecar_path(depth_run.onnx).read_text())
    (tmp_path / "policy.onnx").write_bytes(depth_run.onnx.read_bytes())
    (tmp_path / "policy.json").write_text(json.dumps({**node, "format": "diana_lab.deploy/0"}))
    with pytest.raises(ValueError, match=r"format 'diana_lab\.deploy/0'"):
        Navigator.from_files(tmp_path / "policy.onnx")
    node["encoding"]["shape"] = [1, 24, 32]
    node["sensor"].update(width=32, height=24)
    node["inputs"]["depth_image"] = [-1, 1, 24, 32]
    (tmp_path / "policy.json").write_text(json.dumps(node))
    with pytest.raises(ValueError, match=r"input 'depth_image'.*does not match"):
        Navigator.from_files(tmp_path / "policy.onnx")
    with pytest.raises(FileNotFoundError, match="sidecar"):
        Navigator.from_files(tmp_path / "policy.onnx", sidecar=tmp_path / "missing.json")


def test_measure_latency_reports_percentiles_on_one_thread(depth_run):
    nav = Navigator.from_files(depth_run.onnx, threads=2)
    stats = measure_latency(nav, n=30, warmup=2)
    assert set(stats) >= {"p50", "p99", "encode_p50", "infer_p50"}
    assert 0 < stats["p50"] <= stats["p99"] and stats["n"] == 30
    with pytest.raises(ValueError, match="n: expected a positive"):
        measure_latency(nav, n=0)
