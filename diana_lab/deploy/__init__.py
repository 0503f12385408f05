"""Onboard runtime of an exported policy: numpy + onnxruntime, no torch, no PyBullet, no Hydra.

    from diana_lab.deploy import Navigator
    nav = Navigator.from_files("policy.onnx")                 # reads policy.json next to it
    waypoint = nav.next_waypoint(pose, goal_xy, cloud)        # (x, y) in the world frame

``pose`` is the pose estimate ``(x, y, z, roll, pitch, yaw)`` (or a :class:`Pose`), ``goal_xy`` the goal in
the world frame and ``cloud`` the raw ``(N, 3)`` points in the sensor's body frame (x forward, y left,
z up). The graph and its ``policy.json`` sidecar come from ``python -m diana_lab.export`` (whose torch-side
code is :mod:`diana_lab.deploy.export` and whose config-side code is :mod:`diana_lab.deploy.sidecar`, neither
imported from here). open3d is imported only by the
``elevation_map`` and ``points`` encodings. See ``docs/deploy.md``.
"""

from diana_lab.deploy.geometry import optical_to_body
from diana_lab.deploy.inputs import Pose
from diana_lab.deploy.latency import measure_latency, synthetic_cloud
from diana_lab.deploy.navigator import Navigator
from diana_lab.deploy.spec import PolicySpec, sidecar_path

__all__ = ["Navigator", "PolicySpec", "Pose", "measure_latency", "optical_to_body", "sidecar_path", "synthetic_cloud"]
