"""The calibration of MIKASA-Robo-VLA's base camera, a rig constant: every MIKASA task mounts it alike (``look_at``
eye (0.3, 0, 0.6) m, target (-0.1, 0, 0.1) m, a 90-degree field of view, 128x128 pixels). Measured once from the
simulator (``get_sensor_params``) and shipped, as a real rig's calibration is: a writer casts pixels onto the table
with it and never asks the live simulator (tests/test_mikasa_calibration.py checks it against the simulator's).
"""

from __future__ import annotations

import numpy as np

#: OpenCV intrinsics (3x3) of the 128x128 base camera
BASE_CAMERA_INTRINSIC = np.array([[64.0, 0.0, 64.0], [0.0, 64.0, 64.0], [0.0, 0.0, 1.0]])
#: world-to-camera extrinsics (3x4, OpenCV axes) of the base camera
BASE_CAMERA_EXTRINSIC = np.array([[0.0, 1.0, 0.0, 0.0],
                                  [0.78086877, 0.0, -0.62469506, 0.14055645],
                                  [-0.62469506, 0.0, -0.78086877, 0.6559298]])
BASE_CAMERA_SIZE = 128

__all__ = ["BASE_CAMERA_EXTRINSIC", "BASE_CAMERA_INTRINSIC", "BASE_CAMERA_SIZE"]
