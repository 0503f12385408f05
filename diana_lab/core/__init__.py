"""The numpy-only core that the simulator, the training code and the onboard runtime share.

``rotations`` (frames), ``candidates`` (a discrete action space's waypoints), ``height_memory`` (the map fused
over an episode) and ``grid_search`` (the numba least-cost search of the expert and the shield): what a policy was
trained on and what it drives with are built by this same code. Nothing here imports torch, open3d, PyBullet or
Hydra (``tests/test_layers.py`` holds it to that).
"""
