"""Env set-ups the test suite shares.

``CAMERA_SQUARE``: the depth camera, the square action space and no tilt guard -- the main command's defaults
before the batched lidar map (``conf/config.yaml``) became them. Most tests drive small envs with it: a camera is
cheap to cast and every algorithm drives a square. Tests of the main command's own defaults compose without it.
"""

CAMERA_SQUARE = ["sensor=depth_camera", "action_space=square", "robot.tilt_guard_deg=null"]
